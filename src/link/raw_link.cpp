#include <array>
#include <cerrno>
#include <cstring>
#include <mutex>

#include <arpa/inet.h>
#include <fmt/format.h>
#include <linux/filter.h>
#include <linux/if_packet.h>
#include <net/ethernet.h>
#include <net/if.h>
#include <net/if_arp.h>
#include <sys/ioctl.h>
#include <sys/socket.h>

#include <ecat/link/raw_link.hpp>

#include "link/posix.hpp"

#ifndef PACKET_IGNORE_OUTGOING
#define PACKET_IGNORE_OUTGOING 23
#endif
#ifndef PACKET_QDISC_BYPASS
#define PACKET_QDISC_BYPASS 20
#endif

namespace ecat::link {

namespace {

// Room for the largest Ethernet frame we send: header + a full MTU of EtherCAT frame.
constexpr std::size_t kTxBufferSize = wire::kEthernetHeaderSize + wire::kMaxFrameSize;
// Larger than any standard frame, so that oversized (jumbo) foreign frames show up as truncated
// and are ignored instead of being cut silently.
constexpr std::size_t kRxBufferSize = 2048;

std::string permission_message() {
  return "raw sockets need CAP_NET_RAW: run as root or grant it with "
         "`setcap cap_net_raw,cap_net_admin+ep <binary>`";
}

Result<void> validate_interface_name(const std::string& name) {
  if (name.empty()) {
    return Error(Errc::invalid_argument, "raw link: the network interface name is empty");
  }
  if (name.size() >= IFNAMSIZ) {
    return Error(Errc::invalid_argument,
                 fmt::format("network interface name '{}' is {} characters long; Linux allows at "
                             "most {}",
                             name, name.size(), IFNAMSIZ - 1));
  }
  if (name.find('/') != std::string::npos || name.find('\0') != std::string::npos) {
    return Error(Errc::invalid_argument,
                 fmt::format("network interface name '{}' contains an invalid character", name));
  }
  return ok();
}

// Only EtherCAT frames, untagged or behind one 802.1Q tag (the kernel normally strips the tag
// before packet sockets see the frame, so the tagged branch is a fallback).
Result<void> attach_ethercat_filter(int fd, const std::string& name) {
  static constexpr std::array<sock_filter, 7> kProgram{{
      {BPF_LD | BPF_H | BPF_ABS, 0, 0, 12},
      {BPF_JMP | BPF_JEQ | BPF_K, 3, 0, wire::kEtherTypeEtherCat},
      {BPF_JMP | BPF_JEQ | BPF_K, 0, 3, wire::kEtherTypeVlan},
      {BPF_LD | BPF_H | BPF_ABS, 0, 0, 16},
      {BPF_JMP | BPF_JEQ | BPF_K, 0, 1, wire::kEtherTypeEtherCat},
      {BPF_RET | BPF_K, 0, 0, 0xFFFF},
      {BPF_RET | BPF_K, 0, 0, 0},
  }};
  sock_fprog program{static_cast<unsigned short>(kProgram.size()),
                     const_cast<sock_filter*>(kProgram.data())};
  if (::setsockopt(fd, SOL_SOCKET, SO_ATTACH_FILTER, &program, sizeof program) != 0) {
    return detail::os_error(
        Errc::io_error, fmt::format("{}: cannot attach the EtherCAT socket filter", name), errno);
  }
  return ok();
}

}  // namespace

struct RawLink::Impl {
  RawLinkOptions options;
  int ifindex = 0;
  wire::MacAddress interface_mac{};
  wire::MacAddress source_mac{};
  std::size_t max_frame = wire::kMaxFrameSize;
  bool ignore_outgoing_in_kernel = false;
  bool kernel_timestamps = false;
  detail::UniqueFd socket;
  detail::UseGuard guard{socket};
  detail::Interrupter interrupter;
  detail::AtomicLinkStats stats;
  sockaddr_ll destination{};

  // Responder mode: addresses of the last received request (written by receive, read by send).
  std::mutex responder_mutex;
  wire::MacAddress reply_destination = wire::kBroadcastMac;
  wire::MacAddress reply_source{};

  std::array<std::uint8_t, kTxBufferSize> tx{};
  std::array<std::uint8_t, kRxBufferSize> rx{};
};

Result<std::unique_ptr<RawLink>> RawLink::open(RawLinkOptions options) {
  if (auto valid = validate_interface_name(options.interface); !valid)
    return std::move(valid).error();
  const std::string& name = options.interface;

  const unsigned ifindex = ::if_nametoindex(name.c_str());
  if (ifindex == 0) {
    if (errno == ENODEV || errno == ENXIO) {
      return Error(Errc::not_found,
                   fmt::format("network interface '{}' does not exist (see `ip link`)", name));
    }
    return detail::os_error(Errc::io_error,
                            fmt::format("cannot look up network interface '{}'", name), errno);
  }

  auto impl = std::make_unique<Impl>();
  impl->ifindex = static_cast<int>(ifindex);

  // Protocol 0 receives nothing until bind(), so no foreign frame is queued before the options
  // (filter, ignore-outgoing) are in place.
  const int fd = ::socket(AF_PACKET, SOCK_RAW | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    const int err = errno;
    if (err == EPERM || err == EACCES) {
      return Error(Errc::permission_denied,
                   fmt::format("cannot open a raw socket on '{}': {}", name, permission_message()));
    }
    return detail::os_error(Errc::io_error, fmt::format("cannot open a raw socket on '{}'", name),
                            err);
  }
  impl->socket.reset(fd);

  ifreq request{};
  std::memcpy(request.ifr_name, name.c_str(), name.size() + 1);
  if (::ioctl(fd, SIOCGIFFLAGS, &request) != 0) {
    return detail::os_error(Errc::io_error,
                            fmt::format("cannot read the flags of network interface '{}'", name),
                            errno);
  }
  if ((request.ifr_flags & IFF_UP) == 0) {
    return Error(
        Errc::io_error,
        fmt::format("network interface '{}' is down (bring it up with `ip link set {} up`)", name,
                    name));
  }

  std::memset(&request.ifr_ifru, 0, sizeof request.ifr_ifru);
  if (::ioctl(fd, SIOCGIFHWADDR, &request) != 0) {
    return detail::os_error(
        Errc::io_error, fmt::format("cannot read the MAC address of network interface '{}'", name),
        errno);
  }
  if (request.ifr_hwaddr.sa_family != ARPHRD_ETHER) {
    return Error(Errc::unsupported,
                 fmt::format("network interface '{}' is not an Ethernet interface (ARP hardware "
                             "type {})",
                             name, request.ifr_hwaddr.sa_family));
  }
  std::memcpy(impl->interface_mac.data(), request.ifr_hwaddr.sa_data, impl->interface_mac.size());
  impl->source_mac = options.source_mac.value_or(impl->interface_mac);
  impl->reply_source = impl->source_mac;

  std::memset(&request.ifr_ifru, 0, sizeof request.ifr_ifru);
  if (::ioctl(fd, SIOCGIFMTU, &request) == 0 && request.ifr_mtu > 0) {
    impl->max_frame =
        std::min<std::size_t>(wire::kMaxFrameSize, static_cast<std::size_t>(request.ifr_mtu));
  }

  const int on = 1;
  impl->ignore_outgoing_in_kernel =
      ::setsockopt(fd, SOL_PACKET, PACKET_IGNORE_OUTGOING, &on, sizeof on) == 0;
  // Best effort: skipping the qdisc only saves latency; frames still go out without it.
  (void)::setsockopt(fd, SOL_PACKET, PACKET_QDISC_BYPASS, &on, sizeof on);
  if (options.kernel_timestamps) impl->kernel_timestamps = detail::enable_receive_timestamps(fd);
  if (auto r = detail::set_receive_buffer(fd, options.receive_buffer_bytes, name); !r) {
    return std::move(r).error();
  }
  if (auto r = detail::set_busy_poll(fd, options.busy_poll_us, name); !r) {
    return std::move(r).error();
  }
  if (options.kernel_filter) {
    if (auto r = attach_ethercat_filter(fd, name); !r) return std::move(r).error();
  }

  sockaddr_ll bind_address{};
  bind_address.sll_family = AF_PACKET;
  bind_address.sll_protocol = htons(ETH_P_ALL);
  bind_address.sll_ifindex = impl->ifindex;
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&bind_address), sizeof bind_address) != 0) {
    const int err = errno;
    if (err == ENETDOWN) {
      return Error(Errc::io_error,
                   fmt::format("network interface '{}' is down (bring it up with `ip link set {} "
                               "up`)",
                               name, name));
    }
    return detail::os_error(Errc::io_error,
                            fmt::format("cannot bind a raw socket to network interface '{}'", name),
                            err);
  }

  impl->destination.sll_family = AF_PACKET;
  impl->destination.sll_protocol = htons(wire::kEtherTypeEtherCat);
  impl->destination.sll_ifindex = impl->ifindex;
  impl->destination.sll_halen = ETH_ALEN;
  std::memcpy(impl->destination.sll_addr, wire::kBroadcastMac.data(), ETH_ALEN);

  if (auto r = impl->interrupter.open(name); !r) return std::move(r).error();
  impl->options = std::move(options);
  return std::unique_ptr<RawLink>(new RawLink(std::move(impl)));
}

RawLink::RawLink(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

RawLink::~RawLink() {
  close();
}

Result<void> RawLink::send(wire::Bytes ethercat_frame) {
  Impl& s = *impl_;
  wire::EthernetHeader header;
  header.destination = wire::kBroadcastMac;
  header.source = s.source_mac;
  if (s.options.responder) {
    std::lock_guard lock(s.responder_mutex);
    header.destination = s.reply_destination;
    header.source = s.reply_source;
  }
  return send_as(ethercat_frame, header.source, header.destination);
}

Result<void> RawLink::send_as(wire::Bytes ethercat_frame, const wire::MacAddress& source,
                              const wire::MacAddress& destination) {
  Impl& s = *impl_;
  if (ethercat_frame.size() > s.max_frame) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: frame of {} bytes exceeds the {}-byte maximum",
                             s.options.interface, ethercat_frame.size(), s.max_frame));
  }
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.options.interface));

  wire::EthernetHeader header;
  header.destination = destination;
  header.source = source;
  header.ether_type = wire::kEtherTypeEtherCat;
  const wire::Bytes out = wire::encode_ethernet(header, ethercat_frame, s.tx);
  if (out.empty()) {
    return Error(Errc::internal, fmt::format("{}: Ethernet encoding of a {}-byte frame failed",
                                             s.options.interface, ethercat_frame.size()));
  }
  ssize_t n = 0;
  do {
    n = ::sendto(s.socket.get(), out.data(), out.size(), 0,
                 reinterpret_cast<const sockaddr*>(&s.destination), sizeof s.destination);
  } while (n < 0 && errno == EINTR);
  if (n < 0) {
    const int err = errno;
    detail::AtomicLinkStats::add(s.stats.send_errors);
    if (err == ENETDOWN || err == ENXIO) {
      return Error(Errc::io_error, fmt::format("{}: cannot send, the network interface is down",
                                               s.options.interface));
    }
    return detail::os_error(Errc::io_error, fmt::format("{}: send failed", s.options.interface),
                            err);
  }
  if (static_cast<std::size_t>(n) != out.size()) {
    detail::AtomicLinkStats::add(s.stats.send_errors);
    return Error(Errc::io_error,
                 fmt::format("{}: sent {} of {} bytes", s.options.interface, n, out.size()));
  }
  s.stats.sent(ethercat_frame.size());
  return ok();
}

Result<std::optional<ReceivedFrame>> RawLink::receive(std::chrono::nanoseconds timeout) {
  Impl& s = *impl_;
  const detail::Deadline deadline(timeout);
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.options.interface));

  bool first_read = true;
  for (;;) {
    if (s.guard.closed()) {
      return Error(Errc::closed, fmt::format("{}: link is closed", s.options.interface));
    }
    // A frame that has arrived is taken before a pending interrupt is honoured; after a frame
    // this link ignored, the interrupt is honoured at once (a flood cannot hold the caller).
    if (!first_read && s.interrupter.consume()) return std::optional<ReceivedFrame>{};
    first_read = false;
    sockaddr_ll from{};
    socklen_t from_length = sizeof from;
    const detail::Datagram d = detail::receive_datagram(
        s.socket.get(), s.rx, reinterpret_cast<sockaddr*>(&from), &from_length);
    if (d.error != 0) {
      detail::AtomicLinkStats::add(s.stats.receive_errors);
      if (d.error == ENETDOWN) {
        return Error(Errc::io_error,
                     fmt::format("{}: the network interface went down", s.options.interface));
      }
      return detail::os_error(Errc::io_error,
                              fmt::format("{}: receive failed", s.options.interface), d.error);
    }
    if (d.would_block) {
      if (s.interrupter.consume()) return std::optional<ReceivedFrame>{};
      if (deadline.expired()) return std::optional<ReceivedFrame>{};
      if (s.options.spin) continue;
      auto waited =
          detail::wait_readable(s.socket.get(), s.interrupter, deadline, s.options.interface);
      if (!waited) return std::move(waited).error();
      if (*waited == detail::WaitResult::woken && s.guard.closed()) {
        return Error(Errc::closed, fmt::format("{}: link is closed", s.options.interface));
      }
      if (*waited != detail::WaitResult::readable) return std::optional<ReceivedFrame>{};
      continue;
    }

    // The kernel hands our own frames back only when PACKET_IGNORE_OUTGOING is missing.
    const bool own = from.sll_pkttype == PACKET_OUTGOING;
    const auto decoded = (own || d.truncated)
                             ? wire::EthernetDecodeResult{}
                             : wire::decode_ethernet(wire::Bytes(s.rx.data(), d.size));
    if (!decoded) {
      detail::AtomicLinkStats::add(s.stats.frames_ignored);
      if (deadline.expired()) return std::optional<ReceivedFrame>{};
      continue;
    }
    const wire::EthernetView& eth = *decoded.frame;
    if (s.options.responder) {
      std::lock_guard lock(s.responder_mutex);
      s.reply_destination = eth.header.destination;
      s.reply_source = eth.header.source;
      s.reply_source[0] |= 0x02;
    }
    s.stats.received(eth.payload.size());
    ReceivedFrame frame;
    frame.frame = eth.payload;
    frame.timestamp_ns = d.timestamp_ns;
    frame.source = eth.header.source;
    return std::optional<ReceivedFrame>(frame);
  }
}

int RawLink::wait_fd() {
  if (impl_->options.spin) return -1;
  // Read inside the guard: a close() from another thread releases the socket only after.
  detail::UseScope use(impl_->guard);
  return use ? impl_->socket.get() : -1;
}

void RawLink::interrupt() {
  impl_->interrupter.signal();
}

Result<void> RawLink::reopen() {
  Impl& s = *impl_;
  detail::UseScope use(s.guard);
  if (!use) return Error(Errc::closed, fmt::format("{}: link is closed", s.options.interface));
  auto fresh = open(s.options);
  if (!fresh) {
    return std::move(fresh).error().context(fmt::format("reopening {}", s.options.interface));
  }
  Impl& f = *(*fresh)->impl_;
  s.socket = std::move(f.socket);
  s.ifindex = f.ifindex;
  s.interface_mac = f.interface_mac;
  s.source_mac = f.source_mac;
  s.max_frame = f.max_frame;
  s.ignore_outgoing_in_kernel = f.ignore_outgoing_in_kernel;
  s.kernel_timestamps = f.kernel_timestamps;
  s.destination = f.destination;
  {
    std::lock_guard lock(s.responder_mutex);
    s.reply_source = f.reply_source;
  }
  return ok();
}

void RawLink::close() {
  impl_->guard.close();
  impl_->interrupter.signal();
}

std::string RawLink::name() const {
  return impl_->options.interface;
}

LinkStats RawLink::stats() const {
  return impl_->stats.snapshot();
}

std::size_t RawLink::max_frame_size() const {
  return impl_->max_frame;
}

int RawLink::interface_index() const noexcept {
  return impl_->ifindex;
}

wire::MacAddress RawLink::interface_mac() const noexcept {
  return impl_->interface_mac;
}

wire::MacAddress RawLink::source_mac() const noexcept {
  return impl_->source_mac;
}

bool RawLink::ignores_outgoing_in_kernel() const noexcept {
  return impl_->ignore_outgoing_in_kernel;
}

bool RawLink::has_kernel_timestamps() const noexcept {
  return impl_->kernel_timestamps;
}

}  // namespace ecat::link
