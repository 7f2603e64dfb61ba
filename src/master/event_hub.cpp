#include "master/event_hub.hpp"

#include <algorithm>
#include <bit>
#include <chrono>

#include <fmt/format.h>
#include <pthread.h>

#include <ecat/log.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/states.hpp>

namespace ecat::master {

namespace {

// The library log's view of an event: state changes at info (losses at warn), faults and
// failures at warn, the link failing at error, counters at debug.
LogLevel log_level_of(const Event& e) noexcept {
  switch (e.kind) {
    case EventKind::master_state:
      return e.to == static_cast<std::uint8_t>(MasterState::recovering) ||
                     e.to == static_cast<std::uint8_t>(MasterState::activation_blocked)
                 ? LogLevel::warn
                 : LogLevel::info;
    case EventKind::slave_state:
      return e.to == static_cast<std::uint8_t>(SlaveState::down) ? LogLevel::warn : LogLevel::info;
    case EventKind::domain_state:
      return e.to == static_cast<std::uint8_t>(DomainState::stopped) ? LogLevel::warn
                                                                     : LogLevel::info;
    case EventKind::domain_health:
      return e.to != 0 ? LogLevel::info : LogLevel::warn;
    case EventKind::fault_raised:
    case EventKind::activation_failed:
    case EventKind::dc_lost:
    case EventKind::sdo_failed:
    case EventKind::mailbox_failed:
      return LogLevel::warn;
    case EventKind::fault_cleared:
    case EventKind::recovery_step:
    case EventKind::dc_locked:
    case EventKind::link_up:
    case EventKind::link_reopened:
      return LogLevel::info;
    case EventKind::link_redundancy:
    case EventKind::hotconnect_lost:
    case EventKind::hotconnect_refused:
      return LogLevel::warn;
    case EventKind::hotconnect_appeared:
    case EventKind::hotconnect_ready:
      return LogLevel::info;
    case EventKind::link_down:
      return LogLevel::error;
    case EventKind::frames_lost:
    case EventKind::timeouts:
      return LogLevel::debug;
  }
  return LogLevel::info;
}

std::string_view log_subsystem_of(EventKind kind) noexcept {
  switch (kind) {
    case EventKind::slave_state:
    case EventKind::sdo_failed:
    case EventKind::mailbox_failed:
    case EventKind::activation_failed:
      return "slave";
    case EventKind::domain_state:
    case EventKind::domain_health:
      return "domain";
    case EventKind::dc_locked:
    case EventKind::dc_lost:
      return "dc";
    case EventKind::link_down:
    case EventKind::link_up:
    case EventKind::link_reopened:
    case EventKind::link_redundancy:
      return "link";
    case EventKind::frames_lost:
    case EventKind::timeouts:
      return "bus";
    default:
      return "master";
  }
}

std::int64_t steady_now_ns() noexcept {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

// A pull subscription: its own bounded queue, filled by the dispatcher.
class EventHub::Queue final : public EventQueue {
 public:
  explicit Queue(std::size_t capacity, std::uint64_t dropped_now)
      : capacity_(std::max<std::size_t>(1, capacity)), seen_dropped_(dropped_now) {}

  // Dispatcher thread.
  void push(const Event& event, std::uint64_t hub_dropped) {
    {
      std::lock_guard lock(mutex_);
      if (closed_) return;
      // What the hub dropped since the last event handed to this queue, it missed too.
      pending_missed_ += hub_dropped - seen_dropped_;
      missed_ += hub_dropped - seen_dropped_;
      seen_dropped_ = hub_dropped;
      if (items_.size() >= capacity_) {
        ++pending_missed_;
        ++missed_;
        return;
      }
      items_.push_back(Item{event, pending_missed_});
      pending_missed_ = 0;
    }
    ready_.notify_one();
  }

  std::optional<Item> next(std::chrono::nanoseconds timeout) override {
    std::unique_lock lock(mutex_);
    const auto deadline = std::chrono::steady_clock::now() +
                          std::min<std::chrono::nanoseconds>(timeout, std::chrono::hours(24));
    ready_.wait_until(lock, deadline, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    Item item = items_.front();
    items_.pop_front();
    return item;
  }

  std::uint64_t missed() const noexcept override {
    std::lock_guard lock(mutex_);
    return missed_;
  }

  void close() override {
    {
      std::lock_guard lock(mutex_);
      closed_ = true;
    }
    ready_.notify_all();
  }

 private:
  const std::size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<Item> items_;
  std::uint64_t seen_dropped_;
  std::uint64_t pending_missed_ = 0;
  std::uint64_t missed_ = 0;
  bool closed_ = false;
};

EventHub::EventHub(std::size_t capacity)
    : cells_(std::bit_ceil(std::max<std::size_t>(2, capacity))), mask_(cells_.size() - 1) {
  for (std::size_t i = 0; i < cells_.size(); ++i)
    cells_[i].sequence.store(i, std::memory_order_relaxed);
  dispatcher_ = std::thread([this] {
    pthread_setname_np(pthread_self(), "ecat-events");
    run();
  });
}

EventHub::~EventHub() {
  stopping_.store(true, std::memory_order_release);
  wake_.fetch_add(1, std::memory_order_release);
  wake_.notify_one();
  dispatcher_.join();
  std::lock_guard lock(subscribers_mutex_);
  for (const auto& weak : queues_) {
    if (auto queue = weak.lock()) queue->close();
  }
}

// A bounded multi-producer queue after Dmitry Vyukov's design: each cell's sequence number says
// whether it is free for the producer at that position or filled for the consumer.
bool EventHub::publish(const Event& event) noexcept {
  std::size_t at = enqueue_at_.load(std::memory_order_relaxed);
  Cell* cell = nullptr;
  for (;;) {
    cell = &cells_[at & mask_];
    const std::size_t sequence = cell->sequence.load(std::memory_order_acquire);
    const auto difference = static_cast<std::intptr_t>(sequence) - static_cast<std::intptr_t>(at);
    if (difference == 0) {
      if (enqueue_at_.compare_exchange_weak(at, at + 1, std::memory_order_relaxed)) break;
    } else if (difference < 0) {
      dropped_.fetch_add(1, std::memory_order_relaxed);
      return false;  // full
    } else {
      at = enqueue_at_.load(std::memory_order_relaxed);
    }
  }
  cell->event = event;
  if (cell->event.time_ns == 0) cell->event.time_ns = steady_now_ns();
  cell->sequence.store(at + 1, std::memory_order_release);
  published_.fetch_add(1, std::memory_order_relaxed);
  wake_.fetch_add(1, std::memory_order_release);
  wake_.notify_one();
  return true;
}

bool EventHub::pop(Event& out) noexcept {
  std::size_t at = dequeue_at_.load(std::memory_order_relaxed);
  for (;;) {
    Cell& cell = cells_[at & mask_];
    const std::size_t sequence = cell.sequence.load(std::memory_order_acquire);
    const auto difference =
        static_cast<std::intptr_t>(sequence) - static_cast<std::intptr_t>(at + 1);
    if (difference == 0) {
      if (dequeue_at_.compare_exchange_weak(at, at + 1, std::memory_order_relaxed)) {
        out = cell.event;
        cell.sequence.store(at + mask_ + 1, std::memory_order_release);
        return true;
      }
    } else if (difference < 0) {
      return false;  // empty
    } else {
      at = dequeue_at_.load(std::memory_order_relaxed);
    }
  }
}

void EventHub::run() {
  Event event;
  for (;;) {
    const std::uint32_t woken = wake_.load(std::memory_order_acquire);
    while (pop(event))
      deliver(event);
    { std::lock_guard lock(flushed_mutex_); }
    flushed_.notify_all();
    if (stopping_.load(std::memory_order_acquire)) return;
    wake_.wait(woken, std::memory_order_acquire);
  }
}

void EventHub::deliver(Event& event) {
  std::vector<std::shared_ptr<Subscriber>> subscribers;
  std::vector<std::shared_ptr<Queue>> queues;
  {
    std::lock_guard lock(subscribers_mutex_);
    subscribers = subscribers_;
    queues.reserve(queues_.size());
    std::erase_if(queues_, [&](const std::weak_ptr<Queue>& weak) {
      auto queue = weak.lock();
      if (!queue) return true;  // its owner let it go
      queues.push_back(std::move(queue));
      return false;
    });
  }
  event.sequence = ++sequence_;
  const std::uint64_t dropped = dropped_.load(std::memory_order_relaxed);
  std::lock_guard delivering(delivering_);
  for (const auto& s : subscribers) {
    const std::uint64_t missed = dropped - s->seen_dropped;
    s->seen_dropped = dropped;
    try {
      s->callback(event, missed);
    } catch (...) {
      // A subscriber's exception is its own: the stream goes on for the others.
    }
  }
  for (const auto& q : queues)
    q->push(event, dropped);
  log_event(event, dropped);
  delivered_.fetch_add(1, std::memory_order_release);
}

// Dispatcher thread: every event goes to the library log too, whether anyone subscribed or not
// (the dispatcher drains the queue either way), so the cycle thread never formats or logs.
void EventHub::log_event(const Event& event, std::uint64_t dropped) {
  if (dropped != logged_dropped_ && log_enabled(LogLevel::warn)) {
    log(LogLevel::warn, "master",
        fmt::format("event queue full: {} events dropped", dropped - logged_dropped_));
  }
  logged_dropped_ = dropped;
  const LogLevel level = log_level_of(event);
  if (!log_enabled(level)) return;
  try {
    log(level, log_subsystem_of(event.kind), describe(event));
  } catch (...) {
    // Out of memory describing the event: the log loses it, the subscribers had it.
  }
}

EventSubscriptionId EventHub::subscribe(EventCallback callback) {
  auto subscriber = std::make_shared<Subscriber>();
  subscriber->callback = std::move(callback);
  subscriber->seen_dropped = dropped_.load(std::memory_order_relaxed);
  std::lock_guard lock(subscribers_mutex_);
  subscriber->id = next_id_++;
  subscribers_.push_back(subscriber);
  return subscriber->id;
}

bool EventHub::unsubscribe(EventSubscriptionId id) {
  bool found = false;
  {
    std::lock_guard lock(subscribers_mutex_);
    found = std::erase_if(subscribers_, [&](const auto& s) { return s->id == id; }) > 0;
  }
  // Wait for a delivery in progress to end, unless this is that delivery's own callback.
  if (found && std::this_thread::get_id() != dispatcher_.get_id()) {
    std::lock_guard delivering(delivering_);
  }
  return found;
}

std::shared_ptr<EventQueue> EventHub::open_queue(std::size_t capacity) {
  auto queue = std::make_shared<Queue>(capacity, dropped_.load(std::memory_order_relaxed));
  std::lock_guard lock(subscribers_mutex_);
  queues_.push_back(queue);
  return queue;
}

EventStats EventHub::stats() const noexcept {
  EventStats out;
  out.published = published_.load(std::memory_order_relaxed);
  out.dropped = dropped_.load(std::memory_order_relaxed);
  out.delivered = delivered_.load(std::memory_order_acquire);
  return out;
}

bool EventHub::flush(std::chrono::nanoseconds timeout) {
  const std::uint64_t target = published_.load(std::memory_order_acquire);
  std::unique_lock lock(flushed_mutex_);
  return flushed_.wait_for(lock, timeout,
                           [&] { return delivered_.load(std::memory_order_acquire) >= target; });
}

}  // namespace ecat::master
