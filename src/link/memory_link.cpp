#include <array>
#include <atomic>
#include <cstring>
#include <exception>
#include <mutex>
#include <vector>

#include <fmt/format.h>
#include <pthread.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/wire/frame.hpp>

#include "link/posix.hpp"

namespace ecat::link {

namespace {

// A bounded FIFO of frames in slots allocated once, at construction.
class FrameQueue {
 public:
  explicit FrameQueue(std::size_t depth) : slots_(depth == 0 ? 1 : depth) {}

  bool push(wire::Bytes frame, std::int64_t timestamp_ns) noexcept {
    if (count_ == slots_.size() || frame.size() > wire::kMaxFrameSize) return false;
    Slot& slot = slots_[(head_ + count_) % slots_.size()];
    if (!frame.empty()) std::memcpy(slot.data.data(), frame.data(), frame.size());
    slot.size = frame.size();
    slot.timestamp_ns = timestamp_ns;
    ++count_;
    return true;
  }

  // Copies the oldest frame into `out` (at least kMaxFrameSize bytes) and removes it.
  ReceivedFrame pop_into(wire::MutableBytes out) noexcept {
    const Slot& slot = slots_[head_];
    if (slot.size != 0) std::memcpy(out.data(), slot.data.data(), slot.size);
    ReceivedFrame frame;
    frame.frame = wire::Bytes(out.data(), slot.size);
    frame.timestamp_ns = slot.timestamp_ns;
    head_ = (head_ + 1) % slots_.size();
    --count_;
    return frame;
  }

  bool empty() const noexcept { return count_ == 0; }
  void clear() noexcept {
    head_ = 0;
    count_ = 0;
  }

 private:
  struct Slot {
    std::array<std::uint8_t, wire::kMaxFrameSize> data;
    std::size_t size = 0;
    std::int64_t timestamp_ns = 0;
  };
  std::vector<Slot> slots_;
  std::size_t head_ = 0;
  std::size_t count_ = 0;
};

// The lock of one direction's queue. It is priority-inheriting: the master's cycle thread
// (SCHED_FIFO) that finds it held by the other end's thread (the embedded simulator, at normal
// priority) lends that thread its priority until it lets go. With a plain mutex the cycle thread
// waited until the scheduler gave the preempted holder the CPU back: milliseconds on a busy
// machine, far beyond a 125 us cycle (docs/BENCHMARKS.md, "Cycle-start lateness").
class PiMutex {
 public:
  PiMutex() noexcept {
    pthread_mutexattr_t attr;
    bool inherits = pthread_mutexattr_init(&attr) == 0;
    inherits = inherits && pthread_mutexattr_setprotocol(&attr, PTHREAD_PRIO_INHERIT) == 0 &&
               pthread_mutex_init(&mutex_, &attr) == 0;
    if (!inherits) (void)pthread_mutex_init(&mutex_, nullptr);  // a system without PI futexes
    (void)pthread_mutexattr_destroy(&attr);
  }
  ~PiMutex() { (void)pthread_mutex_destroy(&mutex_); }
  PiMutex(const PiMutex&) = delete;
  PiMutex& operator=(const PiMutex&) = delete;
  void lock() noexcept { (void)pthread_mutex_lock(&mutex_); }
  void unlock() noexcept { (void)pthread_mutex_unlock(&mutex_); }

 private:
  pthread_mutex_t mutex_{};
};

// One direction of a memory pair. The reader sleeps on `sequence` (a futex) without the lock, so
// a reader woken by its timeout returns without touching the lock at all when nothing came, and a
// writer never has to take a lock the reader holds to wake it.
struct Channel {
  explicit Channel(std::size_t depth) : queue(depth) {}
  PiMutex mutex;
  FrameQueue queue;            // guarded by mutex
  bool writer_closed = false;  // guarded by mutex
  bool reader_closed = false;  // guarded by mutex
  bool interrupt = false;      // for the reader; guarded by mutex
  // Bumped after every change the reader may wait for (frame, interrupt, close); the reader
  // sleeps while it holds the value it read under the lock.
  std::atomic<std::uint32_t> sequence{0};
  std::atomic<std::uint32_t> sleepers{0};
  detail::WakeFd wake;  // the reader's Link::wait_fd

  // After a change made under the lock (and the lock released).
  void changed() noexcept {
    sequence.fetch_add(1, std::memory_order_seq_cst);
    if (sleepers.load(std::memory_order_seq_cst) != 0) detail::futex_wake_all(sequence);
    wake.signal();
  }
};

Error too_large(const std::string& name, std::size_t size) {
  return Error(Errc::invalid_argument,
               fmt::format("{}: frame of {} bytes exceeds the {}-byte maximum", name, size,
                           wire::kMaxFrameSize));
}

class MemoryLink final : public Link {
 public:
  MemoryLink(std::string name, std::string peer_name, std::shared_ptr<Channel> in,
             std::shared_ptr<Channel> out)
      : name_(std::move(name)),
        peer_name_(std::move(peer_name)),
        in_(std::move(in)),
        out_(std::move(out)) {}
  ~MemoryLink() override { close(); }

  Result<void> send(wire::Bytes frame) override {
    if (frame.size() > wire::kMaxFrameSize) return too_large(name_, frame.size());
    if (closed_.load(std::memory_order_acquire)) return closed_error();
    bool queued = false;
    {
      std::lock_guard lock(out_->mutex);
      if (out_->reader_closed) {
        return Error(Errc::closed, fmt::format("{}: the peer {} is closed", name_, peer_name_));
      }
      queued = out_->queue.push(frame, detail::monotonic_ns());
    }
    if (!queued) {
      detail::AtomicLinkStats::add(stats_.frames_dropped);
      return ok();
    }
    out_->changed();
    stats_.sent(frame.size());
    return ok();
  }

  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    // Beyond a day counts as forever, which also keeps now + timeout from overflowing.
    const bool forever = timeout >= std::chrono::hours(24);
    const std::int64_t deadline =
        forever ? -1 : detail::monotonic_ns() + std::max<std::int64_t>(timeout.count(), 0);
    for (;;) {
      std::uint32_t seen = 0;
      {
        std::unique_lock lock(in_->mutex);
        if (in_->reader_closed) return closed_error();
        if (!in_->queue.empty()) {
          const ReceivedFrame frame = in_->queue.pop_into(rx_);
          lock.unlock();
          stats_.received(frame.frame.size());
          return std::optional<ReceivedFrame>(frame);
        }
        in_->wake.drain();  // nothing waits: quiet until the next change
        if (in_->interrupt) {
          in_->interrupt = false;
          return std::optional<ReceivedFrame>{};
        }
        if (in_->writer_closed) {
          return Error(Errc::closed, fmt::format("{}: the peer {} closed", name_, peer_name_));
        }
        seen = in_->sequence.load(std::memory_order_seq_cst);
      }
      // Sleep without the lock until something changes or the deadline passes.
      for (;;) {
        if (!forever && detail::monotonic_ns() >= deadline) {
          // Nothing came: done without the lock. Something that raced the timeout still wins.
          if (in_->sequence.load(std::memory_order_seq_cst) == seen) {
            return std::optional<ReceivedFrame>{};
          }
          break;
        }
        in_->sleepers.fetch_add(1, std::memory_order_seq_cst);
        detail::futex_wait_until(in_->sequence, seen, deadline);
        in_->sleepers.fetch_sub(1, std::memory_order_seq_cst);
        if (in_->sequence.load(std::memory_order_seq_cst) != seen) break;
      }
    }
  }

  void interrupt() override {
    {
      std::lock_guard lock(in_->mutex);
      in_->interrupt = true;
    }
    in_->changed();
  }

  void close() override {
    if (closed_.exchange(true)) return;
    {
      std::lock_guard lock(out_->mutex);
      out_->writer_closed = true;
    }
    out_->changed();
    {
      std::lock_guard lock(in_->mutex);
      in_->reader_closed = true;
      in_->queue.clear();
    }
    in_->changed();
  }

  std::string name() const override { return name_; }
  LinkStats stats() const override { return stats_.snapshot(); }

  int wait_fd() override {
    if (closed_.load(std::memory_order_acquire)) return -1;
    return in_->wake.wait_fd([&] {
      std::lock_guard lock(in_->mutex);
      return !in_->queue.empty() || in_->interrupt || in_->writer_closed;
    });
  }

 private:
  Error closed_error() const {
    return Error(Errc::closed, fmt::format("{}: link is closed", name_));
  }

  std::string name_;
  std::string peer_name_;
  std::shared_ptr<Channel> in_;
  std::shared_ptr<Channel> out_;
  std::atomic<bool> closed_{false};
  detail::AtomicLinkStats stats_;
  std::array<std::uint8_t, wire::kMaxFrameSize> rx_{};
};

class FunctionLink final : public Link, private ReplySink {
 public:
  FunctionLink(FrameHandler handler, FunctionLinkOptions options)
      : handler_(std::move(handler)),
        name_(std::move(options.name)),
        replies_(options.reply_queue_depth) {}

  Result<void> send(wire::Bytes frame) override {
    if (frame.size() > wire::kMaxFrameSize) return too_large(name_, frame.size());
    if (closed_.load(std::memory_order_acquire)) return closed_error();
    stats_.sent(frame.size());
    if (!handler_) return ok();
    try {
      handler_(frame, *this);
    } catch (const std::exception& e) {
      return Error(Errc::internal, fmt::format("{}: the frame handler threw: {}", name_, e.what()));
    } catch (...) {
      return Error(Errc::internal, fmt::format("{}: the frame handler threw", name_));
    }
    return ok();
  }

  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds /*timeout*/) override {
    if (closed_.load(std::memory_order_acquire)) return closed_error();
    std::unique_lock lock(mutex_);
    if (replies_.empty()) {
      interrupted_.store(false);
      wake_.drain();
      return std::optional<ReceivedFrame>{};
    }
    const ReceivedFrame frame = replies_.pop_into(rx_);
    lock.unlock();
    stats_.received(frame.frame.size());
    return std::optional<ReceivedFrame>(frame);
  }

  void interrupt() override { interrupted_.store(true); }

  void close() override {
    closed_.store(true, std::memory_order_release);
    std::lock_guard lock(mutex_);
    replies_.clear();
  }

  std::string name() const override { return name_; }
  LinkStats stats() const override { return stats_.snapshot(); }

  // Replies are queued by send() (any thread): signalled from then on.
  int wait_fd() override {
    if (closed_.load(std::memory_order_acquire)) return -1;
    return wake_.wait_fd([&] {
      std::lock_guard lock(mutex_);
      return !replies_.empty();
    });
  }

 private:
  bool reply(wire::Bytes frame) override {
    bool queued = false;
    {
      std::lock_guard lock(mutex_);
      queued = replies_.push(frame, detail::monotonic_ns());
    }
    if (!queued) detail::AtomicLinkStats::add(stats_.frames_dropped);
    if (queued) wake_.signal();
    return queued;
  }

  Error closed_error() const {
    return Error(Errc::closed, fmt::format("{}: link is closed", name_));
  }

  FrameHandler handler_;
  std::string name_;
  std::mutex mutex_;
  FrameQueue replies_;
  std::atomic<bool> closed_{false};
  std::atomic<bool> interrupted_{false};
  detail::WakeFd wake_;
  detail::AtomicLinkStats stats_;
  std::array<std::uint8_t, wire::kMaxFrameSize> rx_{};
};

}  // namespace

std::pair<std::unique_ptr<Link>, std::unique_ptr<Link>> make_memory_link_pair(
    std::size_t queue_depth) {
  auto a_to_b = std::make_shared<Channel>(queue_depth);
  auto b_to_a = std::make_shared<Channel>(queue_depth);
  std::unique_ptr<Link> a = std::make_unique<MemoryLink>("memory:a", "memory:b", b_to_a, a_to_b);
  std::unique_ptr<Link> b = std::make_unique<MemoryLink>("memory:b", "memory:a", a_to_b, b_to_a);
  return {std::move(a), std::move(b)};
}

std::unique_ptr<Link> make_function_link(FrameHandler handler, FunctionLinkOptions options) {
  return std::make_unique<FunctionLink>(std::move(handler), std::move(options));
}

}  // namespace ecat::link
