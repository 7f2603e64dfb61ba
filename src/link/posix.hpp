// Private helpers shared by the socket links: file descriptors, deadlines, the interrupt eventfd,
// atomic statistics and recvmsg with kernel timestamps.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include <sys/socket.h>
#include <time.h>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::link::detail {

class UniqueFd {
 public:
  UniqueFd() = default;
  explicit UniqueFd(int fd) noexcept : fd_(fd) {}
  UniqueFd(UniqueFd&& other) noexcept : fd_(other.release()) {}
  UniqueFd& operator=(UniqueFd&& other) noexcept {
    if (this != &other) reset(other.release());
    return *this;
  }
  UniqueFd(const UniqueFd&) = delete;
  UniqueFd& operator=(const UniqueFd&) = delete;
  ~UniqueFd() { reset(); }

  int get() const noexcept { return fd_; }
  bool valid() const noexcept { return fd_ >= 0; }
  int release() noexcept {
    int fd = fd_;
    fd_ = -1;
    return fd;
  }
  void reset(int fd = -1) noexcept;

 private:
  int fd_ = -1;
};

std::int64_t monotonic_ns() noexcept;

// Sleeps while `word` holds `expected`, at most until `until_ns` on CLOCK_MONOTONIC (-1: no
// limit). Returns at once when the word differs; may return early (spuriously).
void futex_wait_until(std::atomic<std::uint32_t>& word, std::uint32_t expected,
                      std::int64_t until_ns) noexcept;
void futex_wake_all(std::atomic<std::uint32_t>& word) noexcept;

// "message: strerror(err)" with the given code.
Error os_error(Errc code, std::string message, int err);

// A receive deadline. Timeouts beyond a day count as "wait forever" so that callers may pass
// nanoseconds::max() without overflowing the clock arithmetic.
class Deadline {
 public:
  explicit Deadline(std::chrono::nanoseconds timeout) noexcept;
  bool infinite() const noexcept { return infinite_; }
  bool expired() const noexcept { return !infinite_ && monotonic_ns() >= end_ns_; }
  std::int64_t remaining_ns() const noexcept;  // 0 when expired; meaningless when infinite
  std::int64_t end_ns() const noexcept { return end_ns_; }

 private:
  std::int64_t end_ns_ = 0;
  bool infinite_ = false;
};

// Wakes a receive() blocked in ppoll(). The atomic flag is the truth; the eventfd only exists to
// wake ppoll. A wake-up whose flag was already consumed is drained and ignored, so an interrupt is
// never reported twice.
class Interrupter {
 public:
  Result<void> open(std::string_view link_name);
  void signal() noexcept;
  // True (and cleared) when an interrupt is pending.
  bool consume() noexcept;
  bool pending() const noexcept { return pending_.load(std::memory_order_acquire); }
  void drain() noexcept;
  int fd() const noexcept { return fd_.get(); }

 private:
  UniqueFd fd_;
  std::atomic<bool> pending_{false};
};

// An in-process link's Link::wait_fd: an eventfd the reader opens at its first wait_fd() call;
// from then on the writer signals it after every change the reader may wait for (a frame, an
// interrupt, a close) and the reader drains it whenever it finds nothing to receive, so it is
// readable while something may be waiting. Before it is opened, signal() and drain() cost one
// atomic load.
class WakeFd {
 public:
  WakeFd() = default;
  WakeFd(const WakeFd&) = delete;
  WakeFd& operator=(const WakeFd&) = delete;
  ~WakeFd();
  // The reader only. -1 when no eventfd can be created.
  int get_or_open() noexcept;
  // The reader's Link::wait_fd: get_or_open(), and signalled at once when it was opened now and
  // `waiting()` (asked after opening, under the writer's lock) finds something already queued,
  // since what came before it was opened signalled nothing.
  template <class Waiting>
  int wait_fd(Waiting&& waiting) {
    if (opened()) return get_or_open();
    const int fd = get_or_open();
    if (waiting()) signal();
    return fd;
  }
  bool opened() const noexcept { return fd_.load(std::memory_order_seq_cst) >= 0; }
  void signal() noexcept;
  void drain() noexcept;

 private:
  std::atomic<int> fd_{-1};
};

// Lets close() release a socket while another thread may be inside send() or receive() on it:
// every call enters the guard, and the socket is closed by whoever leaves last after close().
// Without this, a receive() about to call recvmsg() could read from an unrelated file that reused
// the descriptor number.
class UseGuard {
 public:
  explicit UseGuard(UniqueFd& fd) noexcept : fd_(&fd) {}
  // For resources that are more than one descriptor: `release(context)` frees them.
  using ReleaseFunction = void (*)(void* context) noexcept;
  UseGuard(ReleaseFunction release_function, void* context) noexcept
      : release_(release_function), context_(context) {}
  UseGuard(const UseGuard&) = delete;
  UseGuard& operator=(const UseGuard&) = delete;

  // False when the link is closed; then the caller must not touch the socket (and not leave()).
  bool enter() noexcept {
    users_.fetch_add(1);
    if (closed_.load()) {
      leave();
      return false;
    }
    return true;
  }
  void leave() noexcept {
    if (users_.fetch_sub(1) == 1 && closed_.load()) release();
  }
  // Marks the link closed; releases the socket now or when the last user leaves.
  void close() noexcept {
    closed_.store(true);
    if (users_.load() == 0) release();
  }
  bool closed() const noexcept { return closed_.load(); }

 private:
  void release() noexcept {
    if (released_.exchange(true)) return;
    if (fd_ != nullptr) {
      fd_->reset();
    } else {
      release_(context_);
    }
  }
  std::atomic<int> users_{0};
  std::atomic<bool> closed_{false};
  std::atomic<bool> released_{false};
  UniqueFd* fd_ = nullptr;
  ReleaseFunction release_ = nullptr;
  void* context_ = nullptr;
};

// enter()/leave() as a scope.
class UseScope {
 public:
  explicit UseScope(UseGuard& guard) noexcept : guard_(guard), entered_(guard.enter()) {}
  ~UseScope() {
    if (entered_) guard_.leave();
  }
  UseScope(const UseScope&) = delete;
  UseScope& operator=(const UseScope&) = delete;
  explicit operator bool() const noexcept { return entered_; }

 private:
  UseGuard& guard_;
  bool entered_;
};

enum class WaitResult { readable, woken, timeout };

// ppoll()s `fd` for input together with the interrupter until the deadline. Never sleeps past it.
Result<WaitResult> wait_readable(int fd, Interrupter& interrupter, const Deadline& deadline,
                                 std::string_view link_name);

// LinkStats with relaxed atomic counters, so that stats() may be read from any thread.
struct AtomicLinkStats {
  std::atomic<std::uint64_t> frames_sent{0};
  std::atomic<std::uint64_t> frames_received{0};
  std::atomic<std::uint64_t> bytes_sent{0};
  std::atomic<std::uint64_t> bytes_received{0};
  std::atomic<std::uint64_t> frames_ignored{0};
  std::atomic<std::uint64_t> send_errors{0};
  std::atomic<std::uint64_t> receive_errors{0};
  std::atomic<std::uint64_t> frames_dropped{0};

  static void add(std::atomic<std::uint64_t>& counter, std::uint64_t n = 1) noexcept {
    counter.fetch_add(n, std::memory_order_relaxed);
  }
  void sent(std::size_t bytes) noexcept {
    add(frames_sent);
    add(bytes_sent, bytes);
  }
  void received(std::size_t bytes) noexcept {
    add(frames_received);
    add(bytes_received, bytes);
  }
  LinkStats snapshot() const noexcept;
};

// One recvmsg(MSG_DONTWAIT) with room for a kernel receive timestamp.
struct Datagram {
  std::size_t size = 0;
  bool truncated = false;         // larger than the buffer; the rest was discarded
  std::int64_t timestamp_ns = 0;  // CLOCK_MONOTONIC
  bool would_block = false;
  int error = 0;  // errno of a failed call other than EAGAIN / EINTR
};
Datagram receive_datagram(int fd, wire::MutableBytes buffer, sockaddr* from,
                          socklen_t* from_length) noexcept;

// Asks the kernel for SO_TIMESTAMPNS receive stamps; false when it refuses.
bool enable_receive_timestamps(int fd) noexcept;

// SO_RCVBUFFORCE (privileged, ignores rmem_max) falling back to SO_RCVBUF.
Result<void> set_receive_buffer(int fd, std::size_t bytes, std::string_view link_name);
Result<void> set_busy_poll(int fd, int microseconds, std::string_view link_name);

}  // namespace ecat::link::detail
