#include <fmt/format.h>

#include <ecat/link/xdp_link.hpp>

#if ECAT_HAVE_XDP

#include <algorithm>
#include <array>
#include <bit>
#include <cerrno>
#include <cstddef>
#include <cstring>
#include <mutex>
#include <thread>
#include <vector>

#include <bpf/bpf.h>
#include <linux/bpf.h>
#include <linux/if_link.h>
#include <linux/if_xdp.h>
#include <net/if.h>
#include <net/if_arp.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <xdp/xsk.h>

#include "link/posix.hpp"

#ifndef SO_PREFER_BUSY_POLL
#define SO_PREFER_BUSY_POLL 69
#endif
#ifndef SO_BUSY_POLL_BUDGET
#define SO_BUSY_POLL_BUDGET 70
#endif

namespace ecat::link {

bool xdp_link_available() noexcept {
  return true;
}

namespace {

constexpr std::string_view kPrivileges =
    "AF_XDP needs CAP_NET_ADMIN, CAP_NET_RAW and CAP_BPF: run as root or grant them with "
    "`setcap cap_net_admin,cap_net_raw,cap_bpf+ep <binary>`";

std::string link_name(const XdpLinkOptions& options) {
  if (options.queue_id == 0) return "xdp:" + options.interface;
  return fmt::format("xdp:{},queue={}", options.interface, options.queue_id);
}

bool power_of_two_in(std::uint32_t value, std::uint32_t low, std::uint32_t high) {
  return value >= low && value <= high && std::has_single_bit(value);
}

Result<void> validate(const XdpLinkOptions& o) {
  const std::string& name = o.interface;
  if (name.empty()) {
    return Error(Errc::invalid_argument, "xdp link: the network interface name is empty");
  }
  if (name.size() >= IFNAMSIZ || name.find('/') != std::string::npos ||
      name.find('\0') != std::string::npos) {
    return Error(Errc::invalid_argument,
                 fmt::format("xdp link: '{}' is not a valid network interface name", name));
  }
  if (!power_of_two_in(o.rx_frames, 8, 4096) || !power_of_two_in(o.tx_frames, 8, 4096)) {
    return Error(Errc::invalid_argument,
                 fmt::format("xdp link on '{}': rx_frames ({}) and tx_frames ({}) must be powers "
                             "of two from 8 to 4096",
                             name, o.rx_frames, o.tx_frames));
  }
  if (o.busy_poll_us < 0) {
    return Error(Errc::invalid_argument,
                 fmt::format("xdp link on '{}': busy_poll_us must not be negative (got {})", name,
                             o.busy_poll_us));
  }
  if (o.queue_id > 4095) {
    return Error(Errc::invalid_argument,
                 fmt::format("xdp link on '{}': queue {} is beyond any interface's queues", name,
                             o.queue_id));
  }
  return ok();
}

// An errno from a libxdp/libbpf call (they return -errno) as an Error naming the step.
Error call_error(const std::string& name, std::string_view what, int err) {
  if (err == EPERM || err == EACCES) {
    return detail::os_error(Errc::permission_denied,
                            fmt::format("{}: {}: {}", name, what, kPrivileges), err);
  }
  return detail::os_error(Errc::io_error, fmt::format("{}: {}", name, what), err);
}

// ---- The XDP program ------------------------------------------------------------------------
// Hands EtherCAT frames (EtherType 0x88A4, untagged or behind one 802.1Q tag) to the socket bound
// to the queue they arrived on (the XSKMAP entry of rx_queue_index) and every other frame to the
// kernel (XDP_PASS; also when no socket is bound there: the low bits of bpf_redirect_map's flags
// are the action when the lookup fails). Written as instructions rather than compiled from C so
// that building ecat needs no BPF compiler and the program cannot drift from this text.

// The value a 16-bit load from the packet gives for big-endian `value` on this host.
constexpr std::int32_t wire_u16(std::uint16_t value) {
  if constexpr (std::endian::native == std::endian::little) {
    return static_cast<std::int32_t>(static_cast<std::uint16_t>((value >> 8) | (value << 8)));
  } else {
    return value;
  }
}

constexpr bpf_insn insn(std::uint8_t code, std::uint8_t dst, std::uint8_t src, std::int16_t off,
                        std::int32_t imm) {
  bpf_insn i{};
  i.code = code;
  i.dst_reg = dst & 0x0F;
  i.src_reg = src & 0x0F;
  i.off = off;
  i.imm = imm;
  return i;
}

std::array<bpf_insn, 21> ethercat_program(int xsks_map_fd) {
  constexpr std::uint8_t ldx_w = BPF_LDX | BPF_MEM | BPF_W;
  constexpr std::uint8_t ldx_h = BPF_LDX | BPF_MEM | BPF_H;
  constexpr std::uint8_t mov_x = BPF_ALU64 | BPF_MOV | BPF_X;
  constexpr std::uint8_t mov_k = BPF_ALU64 | BPF_MOV | BPF_K;
  constexpr std::uint8_t add_k = BPF_ALU64 | BPF_ADD | BPF_K;
  constexpr std::uint8_t jgt_x = BPF_JMP | BPF_JGT | BPF_X;
  constexpr std::uint8_t jeq_k = BPF_JMP | BPF_JEQ | BPF_K;
  constexpr std::uint8_t jne_k = BPF_JMP | BPF_JNE | BPF_K;
  constexpr std::int32_t ethercat = wire_u16(wire::kEtherTypeEtherCat);
  constexpr std::int32_t vlan = wire_u16(wire::kEtherTypeVlan);
  constexpr auto data = static_cast<std::int16_t>(offsetof(xdp_md, data));
  constexpr auto data_end = static_cast<std::int16_t>(offsetof(xdp_md, data_end));
  constexpr auto queue = static_cast<std::int16_t>(offsetof(xdp_md, rx_queue_index));
  // Jump offsets count from the next instruction; "pass" is instruction 19.
  return {{
      insn(ldx_w, 2, 1, data, 0),      // 0: r2 = ctx->data
      insn(ldx_w, 3, 1, data_end, 0),  // 1: r3 = ctx->data_end
      insn(mov_x, 4, 2, 0, 0),         // 2: r4 = r2
      insn(add_k, 4, 0, 0, 14),        // 3: r4 += 14 (Ethernet header)
      insn(jgt_x, 4, 3, 14, 0),        // 4: if r4 > r3 goto pass
      insn(ldx_h, 5, 2, 12, 0),        // 5: r5 = EtherType
      insn(jeq_k, 5, 0, 6, ethercat),  // 6: if EtherCAT goto redirect
      insn(jne_k, 5, 0, 11, vlan),     // 7: if not 802.1Q goto pass
      insn(mov_x, 4, 2, 0, 0),         // 8: r4 = r2
      insn(add_k, 4, 0, 0, 18),        // 9: r4 += 18 (with the tag)
      insn(jgt_x, 4, 3, 8, 0),         // 10: if r4 > r3 goto pass
      insn(ldx_h, 5, 2, 16, 0),        // 11: r5 = inner EtherType
      insn(jne_k, 5, 0, 6, ethercat),  // 12: if not EtherCAT goto pass
      // redirect:
      insn(ldx_w, 2, 1, queue, 0),                               // 13: r2 = ctx->rx_queue_index
      insn(BPF_LD | BPF_DW | BPF_IMM, 1, BPF_PSEUDO_MAP_FD, 0,   // 14: r1 = the XSKMAP
           xsks_map_fd),                                         //
      insn(0, 0, 0, 0, 0),                                       // 15: (its upper half)
      insn(mov_k, 3, 0, 0, XDP_PASS),                            // 16: r3 = XDP_PASS if absent
      insn(BPF_JMP | BPF_CALL, 0, 0, 0, BPF_FUNC_redirect_map),  // 17: r0 = redirect
      insn(BPF_JMP | BPF_EXIT, 0, 0, 0, 0),                      // 18: return r0
      // pass:
      insn(mov_k, 0, 0, 0, XDP_PASS),        // 19: r0 = XDP_PASS
      insn(BPF_JMP | BPF_EXIT, 0, 0, 0, 0),  // 20: return r0
  }};
}

// Everything open() makes: released together, in the order the kernel wants.
struct Resources {
  void* umem_area = nullptr;
  std::size_t umem_size = 0;
  xsk_umem* umem = nullptr;
  xsk_socket* xsk = nullptr;
  xsk_ring_prod fill{};
  xsk_ring_cons completion{};
  xsk_ring_cons rx{};
  xsk_ring_prod tx{};
  detail::UniqueFd map;
  detail::UniqueFd program;
  detail::UniqueFd attachment;  // the BPF link: closing it detaches the program
  // Sending: UMEM addresses of transmit frames not in flight (a stack; never reallocated).
  std::vector<std::uint64_t> tx_free;
  std::size_t tx_free_count = 0;
  // Receiving: the frame the last receive() returned, given back to the fill ring by the next.
  std::optional<std::uint64_t> rx_held;

  Resources() = default;
  Resources(const Resources&) = delete;
  Resources& operator=(const Resources&) = delete;
  ~Resources() {
    attachment.reset();
    if (xsk != nullptr) xsk_socket__delete(xsk);
    if (umem != nullptr) (void)xsk_umem__delete(umem);
    if (umem_area != nullptr) ::munmap(umem_area, umem_size);
    program.reset();
    map.reset();
  }

  int fd() const noexcept { return xsk_socket__fd(xsk); }
  std::uint8_t* frame(std::uint64_t address) const noexcept {
    return static_cast<std::uint8_t*>(xsk_umem__get_data(umem_area, address));
  }
};

struct InterfaceFacts {
  int ifindex = 0;
  wire::MacAddress mac{};
  std::size_t max_frame = wire::kMaxFrameSize;
};

Result<InterfaceFacts> interface_facts(const std::string& name) {
  InterfaceFacts facts;
  const unsigned ifindex = ::if_nametoindex(name.c_str());
  if (ifindex == 0) {
    if (errno == ENODEV || errno == ENXIO) {
      return Error(Errc::not_found,
                   fmt::format("network interface '{}' does not exist (see `ip link`)", name));
    }
    return detail::os_error(Errc::io_error,
                            fmt::format("cannot look up network interface '{}'", name), errno);
  }
  facts.ifindex = static_cast<int>(ifindex);
  detail::UniqueFd probe(::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0));
  if (!probe.valid()) {
    return detail::os_error(Errc::io_error, "cannot open a socket to read interface flags", errno);
  }
  ifreq request{};
  std::memcpy(request.ifr_name, name.c_str(), name.size() + 1);
  if (::ioctl(probe.get(), SIOCGIFFLAGS, &request) != 0) {
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
  if (::ioctl(probe.get(), SIOCGIFHWADDR, &request) != 0) {
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
  std::memcpy(facts.mac.data(), request.ifr_hwaddr.sa_data, facts.mac.size());
  std::memset(&request.ifr_ifru, 0, sizeof request.ifr_ifru);
  if (::ioctl(probe.get(), SIOCGIFMTU, &request) == 0 && request.ifr_mtu > 0) {
    facts.max_frame =
        std::min<std::size_t>(wire::kMaxFrameSize, static_cast<std::size_t>(request.ifr_mtu));
  }
  return facts;
}

Result<void> set_int_option(int fd, int option, int value, const std::string& name,
                            std::string_view what) {
  if (::setsockopt(fd, SOL_SOCKET, option, &value, sizeof value) == 0) return ok();
  const int err = errno;
  if (err == EPERM || err == EACCES) {
    return detail::os_error(Errc::permission_denied,
                            fmt::format("{}: {} needs CAP_NET_ADMIN", name, what), err);
  }
  return detail::os_error(Errc::unsupported, fmt::format("{}: the kernel refused {}", name, what),
                          err);
}

Result<void> load_program(Resources& r, const std::string& name) {
  const auto program = ethercat_program(r.map.get());
  bpf_prog_load_opts options{};
  options.sz = sizeof options;
  options.expected_attach_type = BPF_XDP;
  int fd = bpf_prog_load(BPF_PROG_TYPE_XDP, "ecat_ethercat", "Apache-2.0", program.data(),
                         program.size(), &options);
  if (fd >= 0) {
    r.program.reset(fd);
    return ok();
  }
  const int err = -fd;
  if (err == EPERM) return call_error(name, "loading the XDP program (bpf)", err);
  // Load again with the verifier's log, to say why.
  std::array<char, 4096> log{};
  bpf_prog_load_opts logged = options;
  logged.log_size = static_cast<std::uint32_t>(log.size());
  logged.log_buf = log.data();
  logged.log_level = 1;
  fd = bpf_prog_load(BPF_PROG_TYPE_XDP, "ecat_ethercat", "Apache-2.0", program.data(),
                     program.size(), &logged);
  if (fd >= 0) {  // it worked the second time
    r.program.reset(fd);
    return ok();
  }
  std::string why(log.data(), ::strnlen(log.data(), log.size()));
  while (!why.empty() && (why.back() == '\n' || why.back() == '\0'))
    why.pop_back();
  if (const auto last = why.rfind('\n'); last != std::string::npos) why = why.substr(last + 1);
  return detail::os_error(Errc::unsupported,
                          fmt::format("{}: the kernel refused the XDP program{}", name,
                                      why.empty() ? std::string() : " (verifier: " + why + ")"),
                          err);
}

// Attaches the program through a BPF link in the mode asked for; automatic tries the driver's
// XDP first. Returns whether native XDP is in use.
Result<bool> attach_program(Resources& r, const XdpLinkOptions& o, int ifindex,
                            const std::string& name) {
  const auto attach = [&](std::uint32_t flags) {
    bpf_link_create_opts options{};
    options.sz = sizeof options;
    options.flags = flags;
    return bpf_link_create(r.program.get(), ifindex, BPF_XDP, &options);
  };
  int fd = -EOPNOTSUPP;
  bool native = o.attach != XdpAttachMode::generic;
  if (native) {
    fd = attach(XDP_FLAGS_DRV_MODE);
    if (fd < 0 && o.attach == XdpAttachMode::automatic && fd != -EBUSY && fd != -EPERM) {
      native = false;
    }
  }
  if (!native) fd = attach(XDP_FLAGS_SKB_MODE);
  if (fd >= 0) {
    r.attachment.reset(fd);
    return native;
  }
  const int err = -fd;
  const char* mode = native ? "native (driver)" : "generic";
  if (err == EBUSY || err == EEXIST) {
    return Error(Errc::busy,
                 fmt::format("{}: network interface '{}' already has an XDP program in {} mode "
                             "(another XdpLink, or see `ip link show {}`)",
                             name, o.interface, mode, o.interface));
  }
  if (err == EOPNOTSUPP || err == EINVAL) {
    return detail::os_error(
        Errc::unsupported,
        fmt::format("{}: the driver of '{}' cannot run XDP in {} mode{}", name, o.interface, mode,
                    native ? " (try generic mode: xdp:IFACE,generic)" : ""),
        err);
  }
  return call_error(name, fmt::format("attaching the XDP program in {} mode", mode), err);
}

Result<std::unique_ptr<Resources>> make_resources(const XdpLinkOptions& o,
                                                  const InterfaceFacts& facts, XdpLinkInfo& info) {
  const std::string name = link_name(o);
  auto r = std::make_unique<Resources>();
  const std::uint32_t frames = o.rx_frames + o.tx_frames;

  // The UMEM: every frame the link will ever use, allocated once.
  r->umem_size = std::size_t{frames} * XdpLink::kFrameSize;
  void* area = ::mmap(nullptr, r->umem_size, PROT_READ | PROT_WRITE,
                      MAP_PRIVATE | MAP_ANONYMOUS | MAP_POPULATE, -1, 0);
  if (area == MAP_FAILED) {
    return detail::os_error(Errc::io_error,
                            fmt::format("{}: cannot map {} bytes for the UMEM", name, r->umem_size),
                            errno);
  }
  r->umem_area = area;
  xsk_umem_config umem_config{};
  umem_config.fill_size = o.rx_frames;
  umem_config.comp_size = o.tx_frames;
  umem_config.frame_size = XdpLink::kFrameSize;
  umem_config.frame_headroom = 0;
  umem_config.flags = 0;
  if (const int e = xsk_umem__create(&r->umem, r->umem_area, r->umem_size, &r->fill, &r->completion,
                                     &umem_config);
      e != 0) {
    r->umem = nullptr;
    if (-e == EAFNOSUPPORT) {
      return Error(Errc::unsupported,
                   fmt::format("{}: this kernel has no AF_XDP sockets (CONFIG_XDP_SOCKETS)", name));
    }
    if (-e == ENOMEM || -e == ENOBUFS) {
      return detail::os_error(Errc::io_error,
                              fmt::format("{}: cannot register {} bytes of UMEM (locked memory: "
                                          "raise `ulimit -l`, or run with CAP_IPC_LOCK)",
                                          name, r->umem_size),
                              -e);
    }
    return call_error(name, "creating the UMEM (xsk_umem__create)", -e);
  }

  xsk_socket_config socket_config{};
  socket_config.rx_size = o.rx_frames;
  socket_config.tx_size = o.tx_frames;
  socket_config.libxdp_flags = XSK_LIBXDP_FLAGS__INHIBIT_PROG_LOAD;  // our own program
  socket_config.xdp_flags = 0;
  std::uint16_t bind_flags = XDP_USE_NEED_WAKEUP;
  if (o.copy == XdpCopyMode::copy) bind_flags |= XDP_COPY;
  if (o.copy == XdpCopyMode::zero_copy) bind_flags |= XDP_ZEROCOPY;
  socket_config.bind_flags = bind_flags;
  // A socket closed on this queue a moment ago still holds it: the kernel lets go of the queue in
  // deferred work after the close. Give that up to half a second before calling the queue busy.
  int created = 0;
  for (int attempt = 0; attempt < 250; ++attempt) {
    created = xsk_socket__create(&r->xsk, o.interface.c_str(), o.queue_id, r->umem, &r->rx, &r->tx,
                                 &socket_config);
    if (created != -EBUSY) break;
    r->xsk = nullptr;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  if (created != 0) {
    r->xsk = nullptr;
    const int err = -created;
    if (err == EOPNOTSUPP && o.copy == XdpCopyMode::zero_copy) {
      return Error(Errc::unsupported,
                   fmt::format("{}: the driver of '{}' has no zero-copy AF_XDP (use copy mode)",
                               name, o.interface));
    }
    if (err == EINVAL) {
      return detail::os_error(Errc::not_found,
                              fmt::format("{}: cannot bind an AF_XDP socket to queue {} of '{}' "
                                          "(does it have that many queues? see `ethtool -l {}`)",
                                          name, o.queue_id, o.interface, o.interface),
                              err);
    }
    if (err == EBUSY) {
      return Error(Errc::busy, fmt::format("{}: queue {} of '{}' already has an AF_XDP socket",
                                           name, o.queue_id, o.interface));
    }
    if (err == EAFNOSUPPORT) {
      return Error(Errc::unsupported,
                   fmt::format("{}: this kernel has no AF_XDP sockets (CONFIG_XDP_SOCKETS)", name));
    }
    return call_error(name, "creating the AF_XDP socket (xsk_socket__create)", err);
  }
  const int fd = r->fd();

  xdp_options mode{};
  socklen_t mode_length = sizeof mode;
  info.zero_copy = ::getsockopt(fd, SOL_XDP, XDP_OPTIONS, &mode, &mode_length) == 0 &&
                   (mode.flags & XDP_OPTIONS_ZEROCOPY) != 0;

  // Every receive frame waits in the fill ring; the transmit frames are ours.
  std::uint32_t index = 0;
  if (xsk_ring_prod__reserve(&r->fill, o.rx_frames, &index) != o.rx_frames) {
    return Error(Errc::internal,
                 fmt::format("{}: the fill ring has no room for {} frames", name, o.rx_frames));
  }
  for (std::uint32_t i = 0; i < o.rx_frames; ++i)
    *xsk_ring_prod__fill_addr(&r->fill, index + i) = std::uint64_t{i} * XdpLink::kFrameSize;
  xsk_ring_prod__submit(&r->fill, o.rx_frames);
  r->tx_free.resize(o.tx_frames);
  for (std::uint32_t i = 0; i < o.tx_frames; ++i)
    r->tx_free[i] = std::uint64_t{o.rx_frames + i} * XdpLink::kFrameSize;
  r->tx_free_count = o.tx_frames;

  if (o.busy_poll_us > 0) {
    if (auto e = set_int_option(fd, SO_PREFER_BUSY_POLL, 1, name, "SO_PREFER_BUSY_POLL"); !e)
      return std::move(e).error();
    if (auto e = set_int_option(fd, SO_BUSY_POLL, o.busy_poll_us, name,
                                fmt::format("SO_BUSY_POLL of {} us", o.busy_poll_us));
        !e)
      return std::move(e).error();
    if (auto e = set_int_option(fd, SO_BUSY_POLL_BUDGET, 16, name, "SO_BUSY_POLL_BUDGET"); !e)
      return std::move(e).error();
    info.busy_poll = true;
  }

  // The socket goes into the map before the program is attached: no EtherCAT frame arrives at an
  // empty entry (those would go to the kernel anyway).
  const int map = bpf_map_create(BPF_MAP_TYPE_XSKMAP, "ecat_xsks", sizeof(std::uint32_t),
                                 sizeof(int), o.queue_id + 1, nullptr);
  if (map < 0) return call_error(name, "creating the XSKMAP (bpf)", -map);
  r->map.reset(map);
  const std::uint32_t key = o.queue_id;
  if (const int e = bpf_map_update_elem(r->map.get(), &key, &fd, 0); e < 0) {
    return call_error(name, "putting the socket into the XSKMAP (bpf)", -e);
  }
  if (auto loaded = load_program(*r, name); !loaded) return std::move(loaded).error();
  auto attached = attach_program(*r, o, facts.ifindex, name);
  if (!attached) return std::move(attached).error();
  info.native = *attached;
  return r;
}

}  // namespace

struct XdpLink::Impl {
  XdpLinkOptions options;
  std::string name;
  XdpLinkInfo info;
  wire::MacAddress source_mac{};
  std::unique_ptr<Resources> resources;
  detail::UseGuard guard{&Impl::release, this};
  detail::Interrupter interrupter;
  detail::AtomicLinkStats stats;

  std::mutex responder_mutex;
  wire::MacAddress reply_destination = wire::kBroadcastMac;
  wire::MacAddress reply_source{};

  static void release(void* self) noexcept { static_cast<Impl*>(self)->resources.reset(); }

  Error closed() const { return Error(Errc::closed, fmt::format("{}: link is closed", name)); }
  Error down() const {
    return Error(Errc::io_error, fmt::format("{}: the link is not open (reopen it)", name));
  }

  // Transmit frames the kernel has finished with go back on the free stack.
  void reclaim(Resources& r) noexcept {
    std::uint32_t index = 0;
    const std::uint32_t n = xsk_ring_cons__peek(&r.completion, options.tx_frames, &index);
    for (std::uint32_t i = 0; i < n; ++i) {
      if (r.tx_free_count < r.tx_free.size()) {
        r.tx_free[r.tx_free_count++] = *xsk_ring_cons__comp_addr(&r.completion, index + i);
      }
    }
    if (n > 0) xsk_ring_cons__release(&r.completion, n);
  }

  // Hands a receive frame back to the kernel (room is certain: the fill ring holds every
  // receive frame).
  static void refill(Resources& r, std::uint64_t address) noexcept {
    std::uint32_t index = 0;
    if (xsk_ring_prod__reserve(&r.fill, 1, &index) != 1) return;
    *xsk_ring_prod__fill_addr(&r.fill, index) = address;
    xsk_ring_prod__submit(&r.fill, 1);
  }

  // Asks the kernel to transmit what the ring holds (copy mode always needs this).
  Result<void> kick(Resources& r) {
    for (int attempt = 0;; ++attempt) {
      if (::sendto(r.fd(), nullptr, 0, MSG_DONTWAIT, nullptr, 0) >= 0) return ok();
      const int err = errno;
      if (err == EINTR) continue;
      // The driver is busy or its queue full: the frame stays in the ring and goes with the
      // next kick; a few immediate retries usually get it out now.
      if ((err == EAGAIN || err == EBUSY || err == ENOBUFS) && attempt < 8) continue;
      if (err == EAGAIN || err == EBUSY || err == ENOBUFS) return ok();
      detail::AtomicLinkStats::add(stats.send_errors);
      if (err == ENETDOWN || err == ENXIO) {
        return Error(Errc::io_error,
                     fmt::format("{}: cannot send, the network interface is down", name));
      }
      return detail::os_error(Errc::io_error, fmt::format("{}: send failed", name), err);
    }
  }
};

Result<std::unique_ptr<XdpLink>> XdpLink::open(XdpLinkOptions options) {
  if (auto valid = validate(options); !valid) return std::move(valid).error();
  auto facts = interface_facts(options.interface);
  if (!facts) return std::move(facts).error();
  auto impl = std::make_unique<Impl>();
  impl->name = link_name(options);
  impl->info.interface_index = facts->ifindex;
  impl->info.interface_mac = facts->mac;
  impl->info.queue_id = options.queue_id;
  impl->info.max_frame = facts->max_frame;
  impl->source_mac = options.source_mac.value_or(facts->mac);
  impl->reply_source = impl->source_mac;
  auto resources = make_resources(options, *facts, impl->info);
  if (!resources) return std::move(resources).error();
  impl->resources = std::move(*resources);
  if (auto r = impl->interrupter.open(impl->name); !r) return std::move(r).error();
  impl->options = std::move(options);
  return std::unique_ptr<XdpLink>(new XdpLink(std::move(impl)));
}

XdpLink::XdpLink(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

XdpLink::~XdpLink() {
  close();
}

Result<void> XdpLink::send(wire::Bytes ethercat_frame) {
  Impl& s = *impl_;
  if (ethercat_frame.size() > s.info.max_frame) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: frame of {} bytes exceeds the {}-byte maximum", s.name,
                             ethercat_frame.size(), s.info.max_frame));
  }
  detail::UseScope use(s.guard);
  if (!use) return s.closed();
  if (!s.resources) return s.down();
  Resources& r = *s.resources;

  s.reclaim(r);
  if (r.tx_free_count == 0) {
    if (auto k = s.kick(r); !k) return k;
    s.reclaim(r);
  }
  if (r.tx_free_count == 0) {
    detail::AtomicLinkStats::add(s.stats.frames_dropped);
    return Error(Errc::busy, fmt::format("{}: all {} transmit frames are in flight", s.name,
                                         s.options.tx_frames));
  }
  const std::uint64_t address = r.tx_free[--r.tx_free_count];

  wire::EthernetHeader header;
  header.destination = wire::kBroadcastMac;
  header.source = s.source_mac;
  header.ether_type = wire::kEtherTypeEtherCat;
  if (s.options.responder) {
    std::lock_guard lock(s.responder_mutex);
    header.destination = s.reply_destination;
    header.source = s.reply_source;
  }
  const wire::Bytes out = wire::encode_ethernet(header, ethercat_frame,
                                                wire::MutableBytes(r.frame(address), kFrameSize));
  if (out.empty()) {
    r.tx_free[r.tx_free_count++] = address;
    return Error(Errc::internal, fmt::format("{}: Ethernet encoding of a {}-byte frame failed",
                                             s.name, ethercat_frame.size()));
  }
  std::uint32_t index = 0;
  if (xsk_ring_prod__reserve(&r.tx, 1, &index) != 1) {
    r.tx_free[r.tx_free_count++] = address;
    detail::AtomicLinkStats::add(s.stats.frames_dropped);
    return Error(Errc::busy, fmt::format("{}: the transmit ring is full", s.name));
  }
  xdp_desc* desc = xsk_ring_prod__tx_desc(&r.tx, index);
  desc->addr = address;
  desc->len = static_cast<std::uint32_t>(out.size());
  desc->options = 0;
  xsk_ring_prod__submit(&r.tx, 1);
  if (!s.info.zero_copy || xsk_ring_prod__needs_wakeup(&r.tx)) {
    if (auto k = s.kick(r); !k) return k;
  }
  s.stats.sent(ethercat_frame.size());
  return ok();
}

Result<std::optional<ReceivedFrame>> XdpLink::receive(std::chrono::nanoseconds timeout) {
  Impl& s = *impl_;
  const detail::Deadline deadline(timeout);
  detail::UseScope use(s.guard);
  if (!use) return s.closed();
  if (!s.resources) return s.down();
  Resources& r = *s.resources;
  if (r.rx_held) {
    Impl::refill(r, *r.rx_held);
    r.rx_held.reset();
  }
  const bool never_sleep = s.options.spin || s.info.busy_poll;

  bool first_read = true;
  for (;;) {
    if (s.guard.closed()) return s.closed();
    // As RawLink: a frame that has arrived is taken before a pending interrupt is honoured.
    if (!first_read && s.interrupter.consume()) return std::optional<ReceivedFrame>{};
    first_read = false;

    std::uint32_t index = 0;
    if (xsk_ring_cons__peek(&r.rx, 1, &index) == 1) {
      const xdp_desc* desc = xsk_ring_cons__rx_desc(&r.rx, index);
      const std::uint64_t address = desc->addr;
      const std::uint32_t length = desc->len;
      xsk_ring_cons__release(&r.rx, 1);
      const std::int64_t stamp = detail::monotonic_ns();
      const std::uint64_t base = address & ~std::uint64_t{kFrameSize - 1};
      const bool fits = address - base + length <= kFrameSize;
      const auto decoded = fits ? wire::decode_ethernet(wire::Bytes(r.frame(address), length))
                                : wire::EthernetDecodeResult{};
      if (!decoded) {
        Impl::refill(r, base);
        detail::AtomicLinkStats::add(s.stats.frames_ignored);
        if (deadline.expired()) return std::optional<ReceivedFrame>{};
        continue;
      }
      r.rx_held = base;
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
      frame.timestamp_ns = stamp;
      frame.source = eth.header.source;
      return std::optional<ReceivedFrame>(frame);
    }

    if (s.interrupter.consume()) return std::optional<ReceivedFrame>{};
    if (deadline.expired()) return std::optional<ReceivedFrame>{};
    if (never_sleep) {
      // With busy polling, recvfrom runs the device's NAPI poll in this thread; in zero-copy
      // mode it also tells the driver the fill ring has frames again.
      if (s.info.busy_poll || xsk_ring_prod__needs_wakeup(&r.fill)) {
        (void)::recvfrom(r.fd(), nullptr, 0, MSG_DONTWAIT, nullptr, nullptr);
      }
      continue;
    }
    auto waited = detail::wait_readable(r.fd(), s.interrupter, deadline, s.name);
    if (!waited) {
      detail::AtomicLinkStats::add(s.stats.receive_errors);
      return std::move(waited).error();
    }
    if (*waited == detail::WaitResult::woken && s.guard.closed()) return s.closed();
    if (*waited != detail::WaitResult::readable) return std::optional<ReceivedFrame>{};
  }
}

void XdpLink::interrupt() {
  impl_->interrupter.signal();
}

Result<void> XdpLink::reopen() {
  Impl& s = *impl_;
  detail::UseScope use(s.guard);
  if (!use) return s.closed();
  // The old program must go before a new one can be attached: the link is down meanwhile.
  s.resources.reset();
  auto facts = interface_facts(s.options.interface);
  if (!facts) return std::move(facts).error().context(fmt::format("reopening {}", s.name));
  XdpLinkInfo info = s.info;
  info.interface_index = facts->ifindex;
  info.interface_mac = facts->mac;
  info.max_frame = facts->max_frame;
  auto fresh = make_resources(s.options, *facts, info);
  if (!fresh) return std::move(fresh).error().context(fmt::format("reopening {}", s.name));
  s.resources = std::move(*fresh);
  s.info = info;
  s.source_mac = s.options.source_mac.value_or(facts->mac);
  {
    std::lock_guard lock(s.responder_mutex);
    s.reply_source = s.source_mac;
  }
  return ok();
}

void XdpLink::close() {
  impl_->guard.close();
  impl_->interrupter.signal();
}

std::string XdpLink::name() const {
  return impl_->name;
}

LinkStats XdpLink::stats() const {
  return impl_->stats.snapshot();
}

std::size_t XdpLink::max_frame_size() const {
  return impl_->info.max_frame;
}

int XdpLink::wait_fd() {
  Impl& s = *impl_;
  if (s.options.spin || s.info.busy_poll) return -1;
  detail::UseScope use(s.guard);
  return use && s.resources ? s.resources->fd() : -1;
}

XdpLinkInfo XdpLink::info() const {
  return impl_->info;
}

wire::MacAddress XdpLink::source_mac() const noexcept {
  return impl_->source_mac;
}

}  // namespace ecat::link

#else  // !ECAT_HAVE_XDP: this build has no AF_XDP link; open() says so and nothing else runs.

namespace ecat::link {

bool xdp_link_available() noexcept {
  return false;
}

struct XdpLink::Impl {};

Result<std::unique_ptr<XdpLink>> XdpLink::open(XdpLinkOptions options) {
  return Error(Errc::unsupported,
               fmt::format("xdp link on '{}': this build of ecat has no AF_XDP link (libxdp and "
                           "libbpf were not found when it was built: install libxdp-dev and "
                           "libbpf-dev, e.g. with scripts/setup, and build again); use "
                           "raw:{} instead",
                           options.interface, options.interface));
}

// Never constructed (open() always fails); defined so that the class is complete.
XdpLink::XdpLink(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
XdpLink::~XdpLink() = default;
Result<void> XdpLink::send(wire::Bytes) {
  return Error(Errc::unsupported, "xdp link: not built");
}
Result<std::optional<ReceivedFrame>> XdpLink::receive(std::chrono::nanoseconds) {
  return Error(Errc::unsupported, "xdp link: not built");
}
void XdpLink::interrupt() {}
void XdpLink::close() {}
Result<void> XdpLink::reopen() {
  return Error(Errc::unsupported, "xdp link: not built");
}
std::string XdpLink::name() const {
  return "xdp";
}
LinkStats XdpLink::stats() const {
  return {};
}
std::size_t XdpLink::max_frame_size() const {
  return 0;
}
int XdpLink::wait_fd() {
  return -1;
}
XdpLinkInfo XdpLink::info() const {
  return {};
}
wire::MacAddress XdpLink::source_mac() const noexcept {
  return {};
}

}  // namespace ecat::link

#endif
