// The master's event hub: a bounded lock-free queue that any thread publishes into without
// waiting or allocating, and one dispatcher thread that hands each event to the subscribers
// (callbacks and pull queues) and to the library log (include/ecat/log.hpp). See
// include/ecat/master/events.hpp for the public side.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include <ecat/master/events.hpp>

namespace ecat::master {

// An event of `kind` about `name`, with `detail` (both cut to fit). Allocation-free.
inline Event make_event(EventKind kind, std::string_view name = {},
                        std::string_view detail = {}) noexcept {
  Event e;
  e.kind = kind;
  e.set_name(name);
  e.set_detail(detail);
  return e;
}

// Formats the detail in place (cut to fit), without allocating: usable on the cycle thread.
template <class... Args>
void format_detail(Event& event, fmt::format_string<Args...> format, Args&&... args) noexcept {
  auto& buffer = event.detail_buffer;
  try {
    const auto end =
        fmt::format_to_n(buffer.data(), buffer.size() - 1, format, std::forward<Args>(args)...);
    *(end.size < buffer.size() ? end.out : buffer.data() + buffer.size() - 1) = '\0';
  } catch (...) {
    buffer[0] = '\0';
  }
}

class EventHub {
 public:
  // `capacity` is rounded up to a power of two.
  explicit EventHub(std::size_t capacity = 1024);
  ~EventHub();
  EventHub(const EventHub&) = delete;
  EventHub& operator=(const EventHub&) = delete;

  // Any thread: lock-free, allocation-free, never waits (at most one futex wake when the
  // dispatcher sleeps). Stamps time_ns when it is 0. False when the queue is full: the event is
  // dropped and counted, and every subscriber is told it missed it.
  bool publish(const Event& event) noexcept;

  EventSubscriptionId subscribe(EventCallback callback);
  // After it returns the callback is not called again (unless called from inside a callback,
  // where the event being delivered may still reach the others).
  bool unsubscribe(EventSubscriptionId id);
  std::shared_ptr<EventQueue> open_queue(std::size_t capacity);

  EventStats stats() const noexcept;
  // Waits until every event published before the call was dispatched, up to `timeout`.
  bool flush(std::chrono::nanoseconds timeout);

 private:
  struct Cell {
    std::atomic<std::size_t> sequence{0};
    Event event;
  };
  struct Subscriber {
    EventSubscriptionId id = 0;
    EventCallback callback;
    std::uint64_t seen_dropped = 0;  // the hub's drop count at the last delivery
  };
  class Queue;

  bool pop(Event& out) noexcept;
  void run();
  void deliver(Event& event);
  void log_event(const Event& event, std::uint64_t dropped);

  std::vector<Cell> cells_;
  std::size_t mask_ = 0;
  alignas(64) std::atomic<std::size_t> enqueue_at_{0};
  alignas(64) std::atomic<std::size_t> dequeue_at_{0};
  alignas(64) std::atomic<std::uint32_t> wake_{0};
  std::atomic<std::uint64_t> published_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> delivered_{0};
  std::atomic<bool> stopping_{false};

  std::mutex subscribers_mutex_;  // the lists below; never held while a callback runs
  std::vector<std::shared_ptr<Subscriber>> subscribers_;
  std::vector<std::weak_ptr<Queue>> queues_;
  EventSubscriptionId next_id_ = 1;
  std::mutex delivering_;  // held by the dispatcher while it delivers one event
  std::uint64_t sequence_ = 0;
  std::uint64_t logged_dropped_ = 0;  // dispatcher only: the drop count last logged

  std::mutex flushed_mutex_;
  std::condition_variable flushed_;
  std::thread dispatcher_;
};

}  // namespace ecat::master
