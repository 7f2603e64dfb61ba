// A mutex for tasks on one EventLoop: `auto guard = co_await mutex.lock();` suspends the task (not
// the thread) until the mutex is free. Used where a multi-step exchange must not interleave with
// another task's, such as one slave's mailbox: two SDO transfers to the same slave at once would
// otherwise mix their segments.
//
// Fairness: waiters get the mutex in the order they asked for it. Unlocking hands the mutex to the
// first waiter directly (nobody can barge in between) and resumes it through EventLoop::post, never
// inline, so a long chain of waiters cannot grow the stack and the unlocking task keeps running
// until it suspends.
//
// Loop-thread only (like everything on the control thread). A task must not be destroyed while it
// waits for the mutex.
#pragma once

#include <coroutine>
#include <cstddef>
#include <deque>
#include <optional>
#include <utility>

#include <ecat/exec/event_loop.hpp>

namespace ecat::exec {

class AsyncMutex {
 public:
  // Unlocks on destruction (or unlock()). Move-only; an empty guard owns nothing.
  class Guard {
   public:
    Guard() = default;
    Guard(Guard&& other) noexcept : mutex_(std::exchange(other.mutex_, nullptr)) {}
    Guard& operator=(Guard&& other) noexcept {
      if (this != &other) {
        unlock();
        mutex_ = std::exchange(other.mutex_, nullptr);
      }
      return *this;
    }
    Guard(const Guard&) = delete;
    Guard& operator=(const Guard&) = delete;
    ~Guard() { unlock(); }

    void unlock() noexcept {
      if (mutex_ != nullptr) std::exchange(mutex_, nullptr)->unlock();
    }
    bool owns(const AsyncMutex& mutex) const noexcept { return mutex_ == &mutex; }
    explicit operator bool() const noexcept { return mutex_ != nullptr; }

   private:
    friend class AsyncMutex;
    explicit Guard(AsyncMutex* mutex) noexcept : mutex_(mutex) {}
    AsyncMutex* mutex_ = nullptr;
  };

  class LockAwaiter {
   public:
    explicit LockAwaiter(AsyncMutex& mutex) noexcept : mutex_(mutex) {}
    bool await_ready() noexcept {
      if (mutex_.locked_) return false;
      mutex_.locked_ = true;
      return true;
    }
    void await_suspend(std::coroutine_handle<> waiter) { mutex_.waiters_.push_back(waiter); }
    // Either the mutex was free, or unlock() handed it over before resuming this task.
    Guard await_resume() noexcept { return Guard(&mutex_); }

   private:
    AsyncMutex& mutex_;
  };

  explicit AsyncMutex(EventLoop& loop) noexcept : loop_(loop) {}
  AsyncMutex(const AsyncMutex&) = delete;
  AsyncMutex& operator=(const AsyncMutex&) = delete;

  [[nodiscard]] LockAwaiter lock() noexcept { return LockAwaiter(*this); }
  // The mutex now, or an empty optional when it is taken.
  std::optional<Guard> try_lock() noexcept {
    if (locked_) return std::nullopt;
    locked_ = true;
    return Guard(this);
  }

  bool locked() const noexcept { return locked_; }
  std::size_t waiters() const noexcept { return waiters_.size(); }

 private:
  void unlock() noexcept {
    if (waiters_.empty()) {
      locked_ = false;
      return;
    }
    // Ownership passes to the first waiter now; it runs when the loop gets to it.
    const auto next = waiters_.front();
    waiters_.pop_front();
    loop_.post([next] { next.resume(); });
  }

  EventLoop& loop_;
  bool locked_ = false;
  std::deque<std::coroutine_handle<>> waiters_;
};

}  // namespace ecat::exec
