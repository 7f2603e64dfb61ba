#include <array>
#include <cerrno>
#include <cstring>
#include <mutex>

#include <arpa/inet.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <ecat/link/udp_link.hpp>

#include "link/posix.hpp"

namespace ecat::link {

namespace {

// Larger than any frame we accept, so that an oversized datagram shows up as truncated and is
// ignored instead of being cut silently.
constexpr std::size_t kRxBufferSize = 2048;

struct AddrInfoDeleter {
  void operator()(addrinfo* list) const noexcept { ::freeaddrinfo(list); }
};
using AddrInfoList = std::unique_ptr<addrinfo, AddrInfoDeleter>;

std::string format_address(const sockaddr* address, socklen_t length) {
  std::array<char, NI_MAXHOST> host{};
  std::array<char, NI_MAXSERV> service{};
  if (::getnameinfo(address, length, host.data(), host.size(), service.data(), service.size(),
                    NI_NUMERICHOST | NI_NUMERICSERV) != 0) {
    return "?";
  }
  if (address->sa_family == AF_INET6) return fmt::format("[{}]:{}", host.data(), service.data());
  return fmt::format("{}:{}", host.data(), service.data());
}

std::string format_host(const std::string& host, std::uint16_t port) {
  if (host.find(':') != std::string::npos) return fmt::format("[{}]:{}", host, port);
  return fmt::format("{}:{}", host, port);
}

Result<AddrInfoList> resolve(const std::string& host, std::uint16_t port, int family, int flags,
                             std::string_view what) {
  addrinfo hints{};
  hints.ai_family = family;
  hints.ai_socktype = SOCK_DGRAM;
  hints.ai_protocol = IPPROTO_UDP;
  hints.ai_flags = flags | AI_NUMERICSERV;
  const std::string service = std::to_string(port);
  addrinfo* list = nullptr;
  const int rc =
      ::getaddrinfo(host.empty() ? nullptr : host.c_str(), service.c_str(), &hints, &list);
  if (rc != 0) {
    const Errc code = (rc == EAI_NONAME || rc == EAI_NODATA || rc == EAI_FAMILY)
                          ? Errc::not_found
                          : (rc == EAI_AGAIN ? Errc::timeout : Errc::io_error);
    const char* reason = rc == EAI_SYSTEM ? std::strerror(errno) : ::gai_strerror(rc);
    return Error(code, fmt::format("cannot resolve {} '{}': {}", what, host, reason));
  }
  return AddrInfoList(list);
}

Error bind_error(const sockaddr* address, socklen_t length, int err) {
  const std::string where = format_address(address, length);
  if (err == EADDRINUSE) {
    return Error(Errc::busy, fmt::format("UDP address {} is already in use", where));
  }
  if (err == EACCES || err == EPERM) {
    return detail::os_error(Errc::permission_denied,
                            fmt::format("cannot bind UDP address {} (ports below 1024 need "
                                        "CAP_NET_BIND_SERVICE)",
                                        where),
                            err);
  }
  if (err == EADDRNOTAVAIL) {
    return Error(
        Errc::not_found,
        fmt::format("cannot bind UDP address {}: no local interface has that address", where));
  }
  return detail::os_error(Errc::io_error, fmt::format("cannot bind UDP address {}", where), err);
}

}  // namespace

struct UdpLink::Impl {
  UdpLinkOptions options;
  std::string name;
  std::uint16_t local_port = 0;
  bool kernel_timestamps = false;
  detail::UniqueFd socket;
  detail::UseGuard guard{socket};
  detail::Interrupter interrupter;
  detail::AtomicLinkStats stats;

  // Server: the sender of the most recent datagram (written by receive, read by send), and the
  // host it is pinned to (see UdpLinkOptions::peer_hold).
  mutable std::mutex peer_mutex;
  sockaddr_storage peer{};
  socklen_t peer_length = 0;
  std::int64_t peer_heard_ns = 0;
  std::atomic<std::uint64_t> foreign_frames{0};

  // Takes a datagram's sender as the peer unless another host is the peer and was heard from
  // within the hold time. Another port of the same host (a master restarted there) takes over.
  bool accept_peer(const sockaddr_storage& from, socklen_t from_length) {
    const std::int64_t now = detail::monotonic_ns();
    std::lock_guard lock(peer_mutex);
    const bool held = peer_length != 0 && !same_host(peer, from) &&
                      now - peer_heard_ns < options.peer_hold.count();
    if (held) return false;
    peer = from;
    peer_length = from_length;
    peer_heard_ns = now;
    return true;
  }

  static bool same_host(const sockaddr_storage& a, const sockaddr_storage& b) {
    if (a.ss_family != b.ss_family) return false;
    if (a.ss_family == AF_INET) {
      return reinterpret_cast<const sockaddr_in&>(a).sin_addr.s_addr ==
             reinterpret_cast<const sockaddr_in&>(b).sin_addr.s_addr;
    }
    if (a.ss_family == AF_INET6) {
      return std::memcmp(&reinterpret_cast<const sockaddr_in6&>(a).sin6_addr,
                         &reinterpret_cast<const sockaddr_in6&>(b).sin6_addr,
                         sizeof(in6_addr)) == 0;
    }
    return false;
  }

  std::array<std::uint8_t, kRxBufferSize> rx{};

  Result<void> configure(int fd) {
    if (options.kernel_timestamps) kernel_timestamps = detail::enable_receive_timestamps(fd);
    return detail::set_receive_buffer(fd, options.receive_buffer_bytes, "UDP link");
  }

  void remember_local_port() {
    sockaddr_storage local{};
    socklen_t length = sizeof local;
    if (::getsockname(socket.get(), reinterpret_cast<sockaddr*>(&local), &length) != 0) return;
    if (local.ss_family == AF_INET) {
      local_port = ntohs(reinterpret_cast<const sockaddr_in*>(&local)->sin_port);
    } else if (local.ss_family == AF_INET6) {
      local_port = ntohs(reinterpret_cast<const sockaddr_in6*>(&local)->sin6_port);
    }
  }

  Result<void> open_client();
  Result<void> open_server();
  Result<void> bind_server(const sockaddr* address, socklen_t length, bool dual_stack);
};

Result<void> UdpLink::Impl::open_client() {
  if (options.host.empty()) {
    return Error(Errc::invalid_argument, "UDP link: no peer host given");
  }
  if (options.port == 0) {
    return Error(Errc::invalid_argument,
                 fmt::format("UDP link to '{}': port 0 is not a valid destination", options.host));
  }
  auto peers = resolve(options.host, options.port, AF_UNSPEC, 0, "host");
  if (!peers) return std::move(peers).error();

  std::optional<Error> last_error;
  for (const addrinfo* a = peers->get(); a != nullptr; a = a->ai_next) {
    detail::UniqueFd fd(::socket(a->ai_family, SOCK_DGRAM | SOCK_CLOEXEC, IPPROTO_UDP));
    if (!fd.valid()) {
      last_error = detail::os_error(Errc::io_error, "cannot open a UDP socket", errno);
      continue;
    }
    if (!options.bind_address.empty() || options.bind_port != 0) {
      auto locals = resolve(options.bind_address, options.bind_port, a->ai_family, AI_PASSIVE,
                            "local address");
      if (!locals) {
        last_error = std::move(locals).error();
        continue;
      }
      const addrinfo* local = locals->get();
      if (::bind(fd.get(), local->ai_addr, local->ai_addrlen) != 0) {
        last_error = bind_error(local->ai_addr, local->ai_addrlen, errno);
        continue;
      }
    }
    if (::connect(fd.get(), a->ai_addr, a->ai_addrlen) != 0) {
      last_error = detail::os_error(
          Errc::io_error,
          fmt::format("cannot reach UDP peer {}", format_address(a->ai_addr, a->ai_addrlen)),
          errno);
      continue;
    }
    if (auto r = configure(fd.get()); !r) return r;
    std::memcpy(&peer, a->ai_addr, a->ai_addrlen);
    peer_length = static_cast<socklen_t>(a->ai_addrlen);
    name = "udp:" + format_address(a->ai_addr, a->ai_addrlen);
    socket = std::move(fd);
    remember_local_port();
    return ok();
  }
  if (last_error) {
    return last_error->context(
        fmt::format("cannot open UDP link to {}", format_host(options.host, options.port)));
  }
  return Error(Errc::not_found, fmt::format("host '{}' has no address", options.host));
}

Result<void> UdpLink::Impl::bind_server(const sockaddr* address, socklen_t length,
                                        bool dual_stack) {
  detail::UniqueFd fd(::socket(address->sa_family, SOCK_DGRAM | SOCK_CLOEXEC, IPPROTO_UDP));
  if (!fd.valid()) return detail::os_error(Errc::io_error, "cannot open a UDP socket", errno);
  // No SO_REUSEADDR: for UDP it would let a second server bind the same port and silently take
  // over its datagrams; UDP has no TIME_WAIT that it would be needed for.
  if (address->sa_family == AF_INET6) {
    const int v6only = dual_stack ? 0 : 1;
    (void)::setsockopt(fd.get(), IPPROTO_IPV6, IPV6_V6ONLY, &v6only, sizeof v6only);
  }
  if (::bind(fd.get(), address, length) != 0) return bind_error(address, length, errno);
  if (auto r = configure(fd.get()); !r) return r;
  socket = std::move(fd);
  remember_local_port();
  sockaddr_storage local{};
  socklen_t local_length = sizeof local;
  if (::getsockname(socket.get(), reinterpret_cast<sockaddr*>(&local), &local_length) == 0) {
    name = "udp-server:" + format_address(reinterpret_cast<const sockaddr*>(&local), local_length);
  } else {
    name = "udp-server:" + format_address(address, length);
  }
  return ok();
}

Result<void> UdpLink::Impl::open_server() {
  if (options.host.empty()) {
    // Loopback unless told otherwise: a simulated segment is reachable from this machine only.
    sockaddr_in loopback{};
    loopback.sin_family = AF_INET;
    loopback.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    loopback.sin_port = htons(options.port);
    return bind_server(reinterpret_cast<const sockaddr*>(&loopback), sizeof loopback, false);
  }
  if (options.host == "*") {
    // Every address: one dual-stack IPv6 socket where IPv6 exists, plain IPv4 otherwise.
    sockaddr_in6 any6{};
    any6.sin6_family = AF_INET6;
    any6.sin6_addr = in6addr_any;
    any6.sin6_port = htons(options.port);
    auto r6 = bind_server(reinterpret_cast<const sockaddr*>(&any6), sizeof any6, true);
    if (r6) return r6;
    if (r6.error().code() == Errc::busy || r6.error().code() == Errc::permission_denied) return r6;
    sockaddr_in any4{};
    any4.sin_family = AF_INET;
    any4.sin_addr.s_addr = htonl(INADDR_ANY);
    any4.sin_port = htons(options.port);
    return bind_server(reinterpret_cast<const sockaddr*>(&any4), sizeof any4, false);
  }
  auto locals = resolve(options.host, options.port, AF_UNSPEC, AI_PASSIVE, "listen address");
  if (!locals) return std::move(locals).error();
  std::optional<Error> last_error;
  for (const addrinfo* a = locals->get(); a != nullptr; a = a->ai_next) {
    auto r = bind_server(a->ai_addr, a->ai_addrlen, false);
    if (r) return r;
    last_error = std::move(r).error();
  }
  if (last_error) return *last_error;
  return Error(Errc::not_found, fmt::format("listen address '{}' has no address", options.host));
}

Result<std::unique_ptr<UdpLink>> UdpLink::open(UdpLinkOptions options) {
  auto impl = std::make_unique<Impl>();
  impl->options = std::move(options);
  auto opened = impl->options.mode == UdpLinkOptions::Mode::client ? impl->open_client()
                                                                   : impl->open_server();
  if (!opened) return std::move(opened).error();
  if (auto r = impl->interrupter.open(impl->name); !r) return std::move(r).error();
  return std::unique_ptr<UdpLink>(new UdpLink(std::move(impl)));
}

Result<std::unique_ptr<UdpLink>> UdpLink::connect(std::string host, std::uint16_t port) {
  UdpLinkOptions options;
  options.host = std::move(host);
  options.port = port;
  return open(std::move(options));
}

Result<std::unique_ptr<UdpLink>> UdpLink::serve(std::string address, std::uint16_t port) {
  UdpLinkOptions options;
  options.mode = UdpLinkOptions::Mode::server;
  options.host = std::move(address);
  options.port = port;
  return open(std::move(options));
}

UdpLink::UdpLink(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

UdpLink::~UdpLink() {
  close();
}

Result<void> UdpLink::send(wire::Bytes ethercat_frame) {
  Impl& s = *impl_;
  if (ethercat_frame.size() > wire::kMaxFrameSize) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: frame of {} bytes exceeds the {}-byte maximum", s.name,
                             ethercat_frame.size(), wire::kMaxFrameSize));
  }
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.name));

  const bool server = s.options.mode == UdpLinkOptions::Mode::server;
  sockaddr_storage to{};
  socklen_t to_length = 0;
  if (server) {
    std::lock_guard lock(s.peer_mutex);
    to = s.peer;
    to_length = s.peer_length;
    if (to_length == 0) {
      return Error(Errc::wrong_state,
                   fmt::format("{}: no client has sent a frame yet, so there is nobody to reply to",
                               s.name));
    }
  }
  ssize_t n = 0;
  // A connected socket reports an earlier ICMP "port unreachable" on the next call, without
  // sending; one retry sends this frame.
  for (int attempt = 0; attempt < 2; ++attempt) {
    do {
      n = server ? ::sendto(s.socket.get(), ethercat_frame.data(), ethercat_frame.size(), 0,
                            reinterpret_cast<const sockaddr*>(&to), to_length)
                 : ::send(s.socket.get(), ethercat_frame.data(), ethercat_frame.size(), 0);
    } while (n < 0 && errno == EINTR);
    if (n >= 0 || errno != ECONNREFUSED) break;
  }
  if (n < 0) {
    const int err = errno;
    detail::AtomicLinkStats::add(s.stats.send_errors);
    return detail::os_error(Errc::io_error, fmt::format("{}: send failed", s.name), err);
  }
  s.stats.sent(ethercat_frame.size());
  return ok();
}

Result<std::optional<ReceivedFrame>> UdpLink::receive(std::chrono::nanoseconds timeout) {
  Impl& s = *impl_;
  const detail::Deadline deadline(timeout);
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.name));
  const bool server = s.options.mode == UdpLinkOptions::Mode::server;

  bool first_read = true;
  for (;;) {
    if (s.guard.closed()) return Error(Errc::closed, fmt::format("{}: link is closed", s.name));
    // A frame that has arrived is taken before a pending interrupt is honoured; after a frame
    // this link ignored, the interrupt is honoured at once (a flood cannot hold the caller).
    if (!first_read && s.interrupter.consume()) return std::optional<ReceivedFrame>{};
    first_read = false;
    sockaddr_storage from{};
    socklen_t from_length = sizeof from;
    const detail::Datagram d = detail::receive_datagram(
        s.socket.get(), s.rx, server ? reinterpret_cast<sockaddr*>(&from) : nullptr,
        server ? &from_length : nullptr);
    if (d.error != 0) {
      detail::AtomicLinkStats::add(s.stats.receive_errors);
      if (d.error == ECONNREFUSED) {
        if (deadline.expired()) return std::optional<ReceivedFrame>{};
        continue;
      }
      return detail::os_error(Errc::io_error, fmt::format("{}: receive failed", s.name), d.error);
    }
    if (d.would_block) {
      if (s.interrupter.consume()) return std::optional<ReceivedFrame>{};
      if (deadline.expired()) return std::optional<ReceivedFrame>{};
      if (s.options.spin) continue;
      auto waited = detail::wait_readable(s.socket.get(), s.interrupter, deadline, s.name);
      if (!waited) return std::move(waited).error();
      if (*waited == detail::WaitResult::woken && s.guard.closed()) {
        return Error(Errc::closed, fmt::format("{}: link is closed", s.name));
      }
      if (*waited != detail::WaitResult::readable) return std::optional<ReceivedFrame>{};
      continue;
    }
    if (d.truncated || d.size < wire::kFrameHeaderSize || d.size > wire::kMaxFrameSize) {
      detail::AtomicLinkStats::add(s.stats.frames_ignored);
      if (deadline.expired()) return std::optional<ReceivedFrame>{};
      continue;
    }
    if (server && !s.accept_peer(from, from_length)) {
      detail::AtomicLinkStats::add(s.stats.frames_ignored);
      detail::AtomicLinkStats::add(s.foreign_frames);
      if (deadline.expired()) return std::optional<ReceivedFrame>{};
      continue;
    }
    s.stats.received(d.size);
    ReceivedFrame frame;
    frame.frame = wire::Bytes(s.rx.data(), d.size);
    frame.timestamp_ns = d.timestamp_ns;
    return std::optional<ReceivedFrame>(frame);
  }
}

void UdpLink::interrupt() {
  impl_->interrupter.signal();
}

Result<void> UdpLink::reopen() {
  Impl& s = *impl_;
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.name));
  // A fresh socket with the same options; a server keeps the port it had (even one the kernel
  // picked), so that the peer finds it again.
  auto fresh = std::make_unique<Impl>();
  fresh->options = s.options;
  if (s.options.mode == UdpLinkOptions::Mode::server) fresh->options.port = s.local_port;
  auto opened = fresh->options.mode == UdpLinkOptions::Mode::client ? fresh->open_client()
                                                                    : fresh->open_server();
  if (!opened) return std::move(opened).error().context(fmt::format("reopening {}", s.name));
  s.socket = std::move(fresh->socket);
  s.kernel_timestamps = fresh->kernel_timestamps;
  return ok();
}

void UdpLink::close() {
  impl_->guard.close();
  impl_->interrupter.signal();
}

std::string UdpLink::name() const {
  return impl_->name;
}

LinkStats UdpLink::stats() const {
  return impl_->stats.snapshot();
}

std::uint16_t UdpLink::local_port() const noexcept {
  return impl_->local_port;
}

std::uint64_t UdpLink::foreign_frames() const noexcept {
  return impl_->foreign_frames.load(std::memory_order_relaxed);
}

std::string UdpLink::peer() const {
  std::lock_guard lock(impl_->peer_mutex);
  if (impl_->peer_length == 0) return {};
  return format_address(reinterpret_cast<const sockaddr*>(&impl_->peer), impl_->peer_length);
}

bool UdpLink::has_kernel_timestamps() const noexcept {
  return impl_->kernel_timestamps;
}

}  // namespace ecat::link
