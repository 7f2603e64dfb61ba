// The control thread: a single-threaded event loop that runs the master, slave and DC logic.
// Everything that happens on it happens one step at a time, so that logic needs no locks.
// Other threads hand it work with post(); the bus hands it transaction completions the same way.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>

namespace ecat::exec {

using Clock = std::chrono::steady_clock;

class EventLoop {
 public:
  using TimerId = std::uint64_t;

  EventLoop() = default;
  ~EventLoop();
  EventLoop(const EventLoop&) = delete;
  EventLoop& operator=(const EventLoop&) = delete;

  // Queues `work` to run on the loop thread, in posting order. Callable from any thread, also
  // before the loop runs and after it stopped (the work then runs on the next run, or never).
  void post(std::function<void()> work);

  // Runs `work` on the loop thread at `when` (or as soon as possible after). Returns an id for
  // cancel(). Callable from any thread.
  TimerId call_at(Clock::time_point when, std::function<void()> work);
  TimerId call_after(Clock::duration delay, std::function<void()> work) {
    return call_at(Clock::now() + delay, std::move(work));
  }
  // Cancels a timer that has not fired yet; returns whether it was pending.
  bool cancel(TimerId id);

  // Runs on the calling thread until stop(). Work posted before is run. A stopped loop stays
  // stopped: reset() before running it again.
  void run();
  void reset();
  // Runs whatever is due now, then waits for more until `deadline`; returns when idle at the
  // deadline or when stopped. For tests that drive the loop by hand.
  void run_until(Clock::time_point deadline);
  // Makes run() return after the work item it is executing (callable from any thread).
  void stop();

  // Runs the loop on a thread of its own until stop() + join().
  void start_thread(std::string name = "ecat-control");
  void join();

  bool in_loop_thread() const noexcept { return loop_thread_.load() == std::this_thread::get_id(); }
  std::size_t pending() const;

 private:
  bool run_one_batch(Clock::time_point wait_until);

  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::function<void()>> queue_;
  std::multimap<Clock::time_point, std::pair<TimerId, std::function<void()>>> timers_;
  TimerId next_timer_ = 1;
  bool stop_ = false;
  std::atomic<std::thread::id> loop_thread_{};
  std::thread thread_;
};

}  // namespace ecat::exec
