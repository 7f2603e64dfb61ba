#include "link/posix.hpp"

#include <array>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>
#include <linux/futex.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/syscall.h>
#include <unistd.h>

namespace ecat::link::detail {

namespace {

constexpr std::int64_t kNsPerSecond = 1'000'000'000;
// Longer timeouts are treated as "forever": nobody waits a day for one EtherCAT frame.
constexpr std::int64_t kForeverNs = 86'400 * kNsPerSecond;
// A kernel stamp older than this was taken before a wall-clock step, not before the packet came.
constexpr std::int64_t kMaxTimestampAgeNs = 10 * kNsPerSecond;

std::int64_t to_ns(const timespec& ts) noexcept {
  return static_cast<std::int64_t>(ts.tv_sec) * kNsPerSecond + ts.tv_nsec;
}

std::int64_t clock_ns(clockid_t clock) noexcept {
  timespec ts{};
  clock_gettime(clock, &ts);
  return to_ns(ts);
}

// SO_TIMESTAMPNS stamps are CLOCK_REALTIME; ReceivedFrame promises CLOCK_MONOTONIC. The age of the
// stamp on the realtime clock is the same on the monotonic clock.
std::int64_t realtime_stamp_to_monotonic(const timespec& stamp) noexcept {
  const std::int64_t real_now = clock_ns(CLOCK_REALTIME);
  const std::int64_t mono_now = clock_ns(CLOCK_MONOTONIC);
  const std::int64_t age = real_now - to_ns(stamp);
  if (age < 0 || age > kMaxTimestampAgeNs) return mono_now;
  return mono_now - age;
}

}  // namespace

void UniqueFd::reset(int fd) noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
}

std::int64_t monotonic_ns() noexcept {
  return clock_ns(CLOCK_MONOTONIC);
}

namespace {
std::uint32_t* futex_word(std::atomic<std::uint32_t>& word) noexcept {
  static_assert(sizeof(std::atomic<std::uint32_t>) == sizeof(std::uint32_t));
  return reinterpret_cast<std::uint32_t*>(&word);  // NOLINT: the futex ABI wants the word itself
}
}  // namespace

void futex_wait_until(std::atomic<std::uint32_t>& word, std::uint32_t expected,
                      std::int64_t until_ns) noexcept {
  if (until_ns < 0) {
    (void)syscall(SYS_futex, futex_word(word), FUTEX_WAIT_PRIVATE, expected, nullptr, nullptr, 0);
    return;
  }
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(until_ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(until_ns % 1'000'000'000);
  // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC time.
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAIT_BITSET_PRIVATE, expected, &ts, nullptr,
                FUTEX_BITSET_MATCH_ANY);
}

void futex_wake_all(std::atomic<std::uint32_t>& word) noexcept {
  (void)syscall(SYS_futex, futex_word(word), FUTEX_WAKE_PRIVATE, INT32_MAX, nullptr, nullptr, 0);
}

Error os_error(Errc code, std::string message, int err) {
  message += ": ";
  message += std::strerror(err);
  return Error(code, std::move(message));
}

Deadline::Deadline(std::chrono::nanoseconds timeout) noexcept {
  const std::int64_t ns = timeout.count() < 0 ? 0 : static_cast<std::int64_t>(timeout.count());
  if (ns >= kForeverNs) {
    infinite_ = true;
  } else {
    end_ns_ = monotonic_ns() + ns;
  }
}

std::int64_t Deadline::remaining_ns() const noexcept {
  const std::int64_t left = end_ns_ - monotonic_ns();
  return left > 0 ? left : 0;
}

Result<void> Interrupter::open(std::string_view link_name) {
  const int fd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (fd < 0) {
    return os_error(Errc::io_error,
                    fmt::format("{}: cannot create the interrupt eventfd", link_name), errno);
  }
  fd_.reset(fd);
  return ok();
}

WakeFd::~WakeFd() {
  const int fd = fd_.load();
  if (fd >= 0) ::close(fd);
}

int WakeFd::get_or_open() noexcept {
  int fd = fd_.load(std::memory_order_seq_cst);
  if (fd >= 0) return fd;
  fd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (fd >= 0) fd_.store(fd, std::memory_order_seq_cst);
  return fd;
}

void WakeFd::signal() noexcept {
  const int fd = fd_.load(std::memory_order_seq_cst);
  if (fd < 0) return;
  const std::uint64_t one = 1;
  [[maybe_unused]] const auto n = ::write(fd, &one, sizeof one);
}

void WakeFd::drain() noexcept {
  const int fd = fd_.load(std::memory_order_seq_cst);
  if (fd < 0) return;
  std::uint64_t value = 0;
  [[maybe_unused]] const auto n = ::read(fd, &value, sizeof value);
}

void Interrupter::signal() noexcept {
  pending_.store(true, std::memory_order_release);
  if (fd_.valid()) {
    const std::uint64_t one = 1;
    // A full counter (impossible in practice) still leaves the eventfd readable: nothing to do.
    [[maybe_unused]] const auto n = ::write(fd_.get(), &one, sizeof one);
  }
}

bool Interrupter::consume() noexcept {
  if (!pending_.load(std::memory_order_relaxed)) return false;
  if (!pending_.exchange(false, std::memory_order_acquire)) return false;
  drain();
  return true;
}

void Interrupter::drain() noexcept {
  if (!fd_.valid()) return;
  std::uint64_t value = 0;
  [[maybe_unused]] const auto n = ::read(fd_.get(), &value, sizeof value);
}

Result<WaitResult> wait_readable(int fd, Interrupter& interrupter, const Deadline& deadline,
                                 std::string_view link_name) {
  for (;;) {
    std::array<pollfd, 2> fds{};
    fds[0].fd = fd;
    fds[0].events = POLLIN;
    fds[1].fd = interrupter.fd();
    fds[1].events = POLLIN;
    timespec ts{};
    const timespec* timeout = nullptr;
    if (!deadline.infinite()) {
      const std::int64_t left = deadline.remaining_ns();
      ts.tv_sec = static_cast<time_t>(left / kNsPerSecond);
      ts.tv_nsec = static_cast<long>(left % kNsPerSecond);
      timeout = &ts;
    }
    const int n = ::ppoll(fds.data(), fds.size(), timeout, nullptr);
    if (n < 0) {
      if (errno == EINTR) {
        if (deadline.expired()) return WaitResult::timeout;
        continue;
      }
      return os_error(Errc::io_error, fmt::format("{}: poll failed", link_name), errno);
    }
    if (n == 0) return WaitResult::timeout;
    // A frame first: the interrupt stays pending and ends the next wait (POLLERR / POLLHUP also
    // count as readable: the next recvmsg reports what happened).
    if (fds[0].revents != 0) return WaitResult::readable;
    if (fds[1].revents != 0) {
      // Only a pending flag makes this an interrupt; a late eventfd write whose flag an earlier
      // receive already consumed is just drained.
      if (interrupter.consume()) return WaitResult::woken;
      interrupter.drain();
    }
    if (deadline.expired()) return WaitResult::timeout;
  }
}

LinkStats AtomicLinkStats::snapshot() const noexcept {
  LinkStats s;
  s.frames_sent = frames_sent.load(std::memory_order_relaxed);
  s.frames_received = frames_received.load(std::memory_order_relaxed);
  s.bytes_sent = bytes_sent.load(std::memory_order_relaxed);
  s.bytes_received = bytes_received.load(std::memory_order_relaxed);
  s.frames_ignored = frames_ignored.load(std::memory_order_relaxed);
  s.send_errors = send_errors.load(std::memory_order_relaxed);
  s.receive_errors = receive_errors.load(std::memory_order_relaxed);
  s.frames_dropped = frames_dropped.load(std::memory_order_relaxed);
  return s;
}

Datagram receive_datagram(int fd, wire::MutableBytes buffer, sockaddr* from,
                          socklen_t* from_length) noexcept {
  Datagram result;
  iovec iov{buffer.data(), buffer.size()};
  alignas(cmsghdr) std::array<std::uint8_t, CMSG_SPACE(sizeof(timespec)) + 64> control{};
  msghdr msg{};
  msg.msg_name = from;
  msg.msg_namelen = from_length != nullptr ? *from_length : 0;
  msg.msg_iov = &iov;
  msg.msg_iovlen = 1;
  msg.msg_control = control.data();
  msg.msg_controllen = control.size();
  ssize_t n = 0;
  do {
    n = ::recvmsg(fd, &msg, MSG_DONTWAIT);
  } while (n < 0 && errno == EINTR);
  if (n < 0) {
    if (errno == EAGAIN || errno == EWOULDBLOCK) {
      result.would_block = true;
    } else {
      result.error = errno;
    }
    return result;
  }
  if (from_length != nullptr) *from_length = msg.msg_namelen;
  result.size = static_cast<std::size_t>(n);
  result.truncated = (msg.msg_flags & MSG_TRUNC) != 0;
  for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
    if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS &&
        c->cmsg_len >= CMSG_LEN(sizeof(timespec))) {
      timespec stamp{};
      std::memcpy(&stamp, CMSG_DATA(c), sizeof stamp);
      result.timestamp_ns = realtime_stamp_to_monotonic(stamp);
    }
  }
  if (result.timestamp_ns == 0) result.timestamp_ns = monotonic_ns();
  return result;
}

bool enable_receive_timestamps(int fd) noexcept {
  const int on = 1;
  return ::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on) == 0;
}

Result<void> set_receive_buffer(int fd, std::size_t bytes, std::string_view link_name) {
  if (bytes == 0) return ok();
  if (bytes > 1u << 30) {
    return Error(
        Errc::invalid_argument,
        fmt::format("{}: receive buffer of {} bytes is larger than 1 GiB", link_name, bytes));
  }
  const int size = static_cast<int>(bytes);
  if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &size, sizeof size) == 0) return ok();
  if (::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, sizeof size) == 0) return ok();
  return os_error(Errc::io_error,
                  fmt::format("{}: cannot set the receive buffer to {} bytes", link_name, bytes),
                  errno);
}

Result<void> set_busy_poll(int fd, int microseconds, std::string_view link_name) {
  if (microseconds == 0) return ok();
  if (microseconds < 0) {
    return Error(
        Errc::invalid_argument,
        fmt::format("{}: busy_poll_us must not be negative (got {})", link_name, microseconds));
  }
  if (::setsockopt(fd, SOL_SOCKET, SO_BUSY_POLL, &microseconds, sizeof microseconds) == 0) {
    return ok();
  }
  const int err = errno;
  if (err == EPERM || err == EACCES) {
    return os_error(
        Errc::permission_denied,
        fmt::format("{}: SO_BUSY_POLL of {} us needs CAP_NET_ADMIN", link_name, microseconds), err);
  }
  return os_error(Errc::unsupported, fmt::format("{}: the kernel refused SO_BUSY_POLL", link_name),
                  err);
}

}  // namespace ecat::link::detail
