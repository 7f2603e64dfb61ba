// The control thread: a single-threaded event loop that runs the master, slave and DC logic.
// Everything that happens on it happens one step at a time, so that logic needs no locks.
// Other threads hand it work with post(); the bus hands it transaction completions the same way.
//
// Posted work goes through one lock-free queue (a Treiber stack the loop drains and reverses), so
// it runs in posting order whichever way it was posted. post(Work&) neither allocates nor locks:
// the bus thread completes a co_awaited transaction that way (exec/transact.hpp), with a node that
// lives in the awaiting coroutine's frame. post(std::function) wraps the function in a node of its
// own (one allocation). The loop sleeps on a futex, woken by a poster only when it sleeps.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>  // kept for the files that relied on it
#include <cstdint>
#include <deque>  // kept for the files that relied on it
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

  // A work item the poster owns: post(Work&) links it into the queue without allocating. It must
  // stay alive, and must not be posted again, until its function has run (or, when the loop is
  // destroyed with it still queued, been called with run == false).
  class Work {
   public:
    using Function = void (*)(Work& self, bool run);
    explicit Work(Function function) noexcept : function_(function) {}
    Work(const Work&) = delete;
    Work& operator=(const Work&) = delete;

   protected:
    ~Work() = default;

   private:
    friend class EventLoop;
    Function function_;
    Work* next_ = nullptr;
  };

  EventLoop() = default;
  ~EventLoop();
  EventLoop(const EventLoop&) = delete;
  EventLoop& operator=(const EventLoop&) = delete;

  // Queues `work` to run on the loop thread, in posting order. Callable from any thread, also
  // before the loop runs and after it stopped (the work then runs on the next run, or never).
  void post(std::function<void()> work);
  // The same without allocating or locking (at most one futex wake, when the loop sleeps).
  void post(Work& work) noexcept;

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

  // Runs the loop on a thread of its own until stop() + join(). `name` is the thread's name as
  // ps and perf show it (at most 15 characters are kept).
  void start_thread(std::string name = "ecat-control");
  void join();

  bool in_loop_thread() const noexcept { return loop_thread_.load() == std::this_thread::get_id(); }
  std::size_t pending() const;

 private:
  bool run_one_batch(Clock::time_point wait_until);
  void push(Work& work) noexcept;
  void wake() noexcept;
  // Loop thread: moves what was posted to the back of the local run list. True when anything was.
  bool drain_posted();
  void discard_all() noexcept;

  // Posted work, newest first (any thread pushes, the loop thread takes all at once).
  std::atomic<Work*> posted_{nullptr};
  std::atomic<std::size_t> posted_count_{0};
  // Bumped by every post, timer change and stop; the loop sleeps on it (a futex) while idle.
  std::atomic<std::uint32_t> wake_seq_{0};
  std::atomic<bool> sleeping_{false};
  std::atomic<bool> stop_{false};
  // Loop thread: drained work not run yet, oldest first.
  Work* local_head_ = nullptr;
  Work* local_tail_ = nullptr;

  mutable std::mutex mutex_;  // guards the timers
  std::multimap<Clock::time_point, std::pair<TimerId, std::function<void()>>> timers_;
  TimerId next_timer_ = 1;
  std::atomic<std::thread::id> loop_thread_{};
  std::thread thread_;
};

}  // namespace ecat::exec
