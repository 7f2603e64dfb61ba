// Coroutine tasks for control-plane sequences: a slave's INIT -> PREOP walk, an SDO transfer, DC
// initialisation. Written as straight-line code with co_await, run on the EventLoop (the control
// thread), many at once: while one waits for the bus, the others run, and the bus packs all of
// their datagrams into shared frames.
//
//   exec::Task<Result<std::uint16_t>> read_al_status(Context& ctx, std::uint16_t station) {
//     bus::Transaction tx;
//     tx.fprd(station, wire::reg::kAlStatus, 2);
//     auto reply = co_await exec::transact(ctx.loop, ctx.bus, std::move(tx));
//     if (!reply) co_return reply.error();
//     co_return wire::load_le16(reply->data(0).data());
//   }
//
// Tasks are lazy (they start when awaited or spawned), single-owner, and never throw: an
// exception escaping a task is a bug and terminates.
#pragma once

#include <chrono>
#include <condition_variable>
#include <coroutine>
#include <cstddef>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

#include <ecat/exec/event_loop.hpp>

namespace ecat::exec {

template <class T>
class Task;

namespace detail {

struct TaskPromiseBase {
  std::coroutine_handle<> continuation;

  std::suspend_always initial_suspend() noexcept { return {}; }
  struct FinalAwaiter {
    bool await_ready() noexcept { return false; }
    template <class Promise>
    std::coroutine_handle<> await_suspend(std::coroutine_handle<Promise> h) noexcept {
      auto next = h.promise().continuation;
      return next ? next : std::noop_coroutine();
    }
    void await_resume() noexcept {}
  };
  FinalAwaiter final_suspend() noexcept { return {}; }
  [[noreturn]] void unhandled_exception() noexcept { std::terminate(); }
};

template <class T>
struct TaskPromise : TaskPromiseBase {
  std::optional<T> value;
  Task<T> get_return_object() noexcept;
  template <class U>
  void return_value(U&& v) {
    value.emplace(std::forward<U>(v));
  }
};

template <>
struct TaskPromise<void> : TaskPromiseBase {
  Task<void> get_return_object() noexcept;
  void return_void() noexcept {}
};

}  // namespace detail

template <class T = void>
class [[nodiscard]] Task {
 public:
  using promise_type = detail::TaskPromise<T>;
  using Handle = std::coroutine_handle<promise_type>;

  Task() = default;
  explicit Task(Handle h) noexcept : handle_(h) {}
  Task(Task&& other) noexcept : handle_(std::exchange(other.handle_, {})) {}
  Task& operator=(Task&& other) noexcept {
    if (this != &other) {
      if (handle_) handle_.destroy();
      handle_ = std::exchange(other.handle_, {});
    }
    return *this;
  }
  Task(const Task&) = delete;
  Task& operator=(const Task&) = delete;
  ~Task() {
    if (handle_) handle_.destroy();
  }

  bool valid() const noexcept { return static_cast<bool>(handle_); }

  // Awaiting a task starts it; the awaiter resumes when it finishes (symmetric transfer, so long
  // chains of tasks do not grow the stack).
  bool await_ready() const noexcept { return !handle_ || handle_.done(); }
  std::coroutine_handle<> await_suspend(std::coroutine_handle<> awaiting) noexcept {
    handle_.promise().continuation = awaiting;
    return handle_;
  }
  T await_resume() {
    if constexpr (!std::is_void_v<T>) return std::move(*handle_.promise().value);
  }

 private:
  Handle handle_;
};

namespace detail {
template <class T>
Task<T> TaskPromise<T>::get_return_object() noexcept {
  return Task<T>(std::coroutine_handle<TaskPromise<T>>::from_promise(*this));
}
inline Task<void> TaskPromise<void>::get_return_object() noexcept {
  return Task<void>(std::coroutine_handle<TaskPromise<void>>::from_promise(*this));
}

// A coroutine that starts at once and frees itself when done: the root of a spawned task.
struct Detached {
  struct promise_type {
    Detached get_return_object() noexcept { return {}; }
    std::suspend_never initial_suspend() noexcept { return {}; }
    std::suspend_never final_suspend() noexcept { return {}; }
    void return_void() noexcept {}
    [[noreturn]] void unhandled_exception() noexcept { std::terminate(); }
  };
};

template <class T, class Sink>
Detached run_detached(Task<T> task, Sink sink) {
  if constexpr (std::is_void_v<T>) {
    co_await std::move(task);
    sink();
  } else {
    sink(co_await std::move(task));
  }
}
}  // namespace detail

// Starts `task` on the loop thread and forgets it; `on_done` (optional) gets its result there.
template <class T, class OnDone>
void spawn(EventLoop& loop, Task<T> task, OnDone on_done) {
  auto shared = std::make_shared<Task<T>>(std::move(task));
  loop.post([shared, on_done = std::move(on_done)]() mutable {
    detail::run_detached(std::move(*shared), std::move(on_done));
  });
}
template <class T>
void spawn(EventLoop& loop, Task<T> task) {
  if constexpr (std::is_void_v<T>) {
    spawn(loop, std::move(task), [] {});
  } else {
    spawn(loop, std::move(task), [](T&&) {});
  }
}

// Suspends the calling task for `delay` (other tasks run meanwhile).
struct SleepAwaiter {
  EventLoop& loop;
  Clock::duration delay;
  bool await_ready() const noexcept { return delay <= Clock::duration::zero(); }
  void await_suspend(std::coroutine_handle<> h) {
    loop.call_after(delay, [h] { h.resume(); });
  }
  void await_resume() const noexcept {}
};
inline SleepAwaiter sleep_for(EventLoop& loop, Clock::duration delay) {
  return {loop, delay};
}

// Lets the other ready tasks run before continuing.
inline SleepAwaiter yield(EventLoop& loop) {
  return {loop, Clock::duration(1)};
}

// Runs all tasks concurrently on the loop and resumes with their results in order.
template <class T>
Task<std::vector<T>> when_all(EventLoop& loop, std::vector<Task<T>> tasks) {
  (void)loop;
  struct State {
    std::size_t remaining = 0;
    std::vector<std::optional<T>> results;
    std::coroutine_handle<> parent;
  };
  State state;
  state.results.resize(tasks.size());
  struct Awaiter {
    State& state;
    std::vector<Task<T>>& tasks;
    bool await_ready() const noexcept { return tasks.empty(); }
    bool await_suspend(std::coroutine_handle<> parent) {
      state.parent = parent;
      // One extra count while starting, so no child can resume the parent from in here.
      state.remaining = tasks.size() + 1;
      for (std::size_t i = 0; i < tasks.size(); ++i) {
        detail::run_detached(std::move(tasks[i]), [&s = state, i](T&& value) {
          s.results[i].emplace(std::move(value));
          if (--s.remaining == 0) s.parent.resume();
        });
      }
      return --state.remaining != 0;  // false: everything finished already, continue now
    }
    void await_resume() const noexcept {}
  };
  co_await Awaiter{state, tasks};
  std::vector<T> out;
  out.reserve(state.results.size());
  for (auto& r : state.results)
    out.push_back(std::move(*r));
  co_return out;
}

// Runs `task` on the loop (which runs on another thread) and blocks the calling thread until the
// task finishes or `timeout` passes: the bridge from application threads to the control loop.
// Returns nullopt on timeout (the task keeps running to its end; its result is dropped). Must not
// be called on the loop thread (it would wait for itself).
template <class T>
std::optional<T> run_blocking(EventLoop& loop, Task<T> task, std::chrono::nanoseconds timeout) {
  struct Shared {
    std::mutex mutex;
    std::condition_variable done;
    std::optional<T> value;
  };
  auto shared = std::make_shared<Shared>();
  spawn(loop, std::move(task), [shared](T&& value) {
    std::lock_guard lock(shared->mutex);
    shared->value.emplace(std::move(value));
    shared->done.notify_all();
  });
  std::unique_lock lock(shared->mutex);
  shared->done.wait_for(lock, timeout, [&] { return shared->value.has_value(); });
  return std::move(shared->value);
}

}  // namespace ecat::exec
