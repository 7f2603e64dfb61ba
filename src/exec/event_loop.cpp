#include <pthread.h>

#include <ecat/exec/event_loop.hpp>

namespace ecat::exec {

EventLoop::~EventLoop() {
  stop();
  join();
}

void EventLoop::post(std::function<void()> work) {
  {
    std::lock_guard lock(mutex_);
    queue_.push_back(std::move(work));
  }
  wake_.notify_one();
}

EventLoop::TimerId EventLoop::call_at(Clock::time_point when, std::function<void()> work) {
  TimerId id = 0;
  {
    std::lock_guard lock(mutex_);
    id = next_timer_++;
    timers_.emplace(when, std::make_pair(id, std::move(work)));
  }
  wake_.notify_one();
  return id;
}

bool EventLoop::cancel(TimerId id) {
  std::lock_guard lock(mutex_);
  for (auto it = timers_.begin(); it != timers_.end(); ++it) {
    if (it->second.first == id) {
      timers_.erase(it);
      return true;
    }
  }
  return false;
}

std::size_t EventLoop::pending() const {
  std::lock_guard lock(mutex_);
  return queue_.size() + timers_.size();
}

// Runs the posted work and the timers that are due; if there was none, waits (up to
// `wait_until`) for more. Returns false once stopped.
bool EventLoop::run_one_batch(Clock::time_point wait_until) {
  std::deque<std::function<void()>> batch;
  {
    std::unique_lock lock(mutex_);
    auto due = [&] {
      return stop_ || !queue_.empty() ||
             (!timers_.empty() && timers_.begin()->first <= Clock::now());
    };
    while (!due()) {
      auto until = wait_until;
      if (!timers_.empty() && timers_.begin()->first < until) until = timers_.begin()->first;
      if (until <= Clock::now()) break;
      if (until == Clock::time_point::max()) {
        wake_.wait(lock);
      } else {
        wake_.wait_until(lock, until);
      }
      if (Clock::now() >= wait_until && !due()) return !stop_;
    }
    if (stop_) return false;
    batch.swap(queue_);
    const auto now = Clock::now();
    while (!timers_.empty() && timers_.begin()->first <= now) {
      batch.push_back(std::move(timers_.begin()->second.second));
      timers_.erase(timers_.begin());
    }
  }
  for (auto& work : batch) {
    work();
    std::lock_guard lock(mutex_);
    if (stop_) {
      // Keep what was not run for a later run().
      return false;
    }
  }
  return true;
}

void EventLoop::run() {
  loop_thread_ = std::this_thread::get_id();
  while (run_one_batch(Clock::time_point::max())) {
  }
  loop_thread_ = std::thread::id{};
}

void EventLoop::run_until(Clock::time_point deadline) {
  loop_thread_ = std::this_thread::get_id();
  {
    std::lock_guard lock(mutex_);
    stop_ = false;
  }
  while (Clock::now() < deadline) {
    if (!run_one_batch(deadline)) break;
  }
  loop_thread_ = std::thread::id{};
}

void EventLoop::reset() {
  std::lock_guard lock(mutex_);
  stop_ = false;
}

void EventLoop::stop() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
}

void EventLoop::start_thread(std::string name) {
  join();
  {
    std::lock_guard lock(mutex_);
    stop_ = false;
  }
  thread_ = std::thread([this, name = std::move(name)] {
    pthread_setname_np(pthread_self(), name.substr(0, 15).c_str());
    run();
  });
}

void EventLoop::join() {
  if (thread_.joinable() && thread_.get_id() != std::this_thread::get_id()) thread_.join();
}

}  // namespace ecat::exec
