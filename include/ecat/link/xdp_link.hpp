// EtherCAT directly on Ethernet (EtherType 0x88A4) through a Linux AF_XDP socket (libxdp's xsk
// API) on one queue of one network interface: frames bypass the kernel's network stack between
// the driver and the link's own memory (the UMEM).
//
// The link attaches a small XDP program of its own to the interface that hands the socket only
// EtherCAT frames (untagged or behind one 802.1Q tag) arriving on its queue; every other frame
// goes on to the kernel as before, so the host's own traffic on the interface is untouched. The
// program is attached through a BPF link owned by this process: it is gone when the link closes
// or the process ends, however it ends. One XdpLink per interface: a second one (or any other
// program attached in the same mode) is refused with Errc::busy. A capture on the interface
// (tcpdump) no longer sees the EtherCAT frames the program redirects; record with a
// RecordingLink (`--pcap`) instead.
//
// Copy mode where the driver has no zero-copy AF_XDP support (veth, most virtual devices),
// zero-copy where it has, unless the options force one. Needs CAP_NET_ADMIN, CAP_NET_RAW and
// CAP_BPF (or root); a build of ecat without libxdp has this class but open() then fails with
// Errc::unsupported saying so (xdp_link_available() tells beforehand).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {

enum class XdpAttachMode : std::uint8_t {
  automatic,  // the driver's own (native) XDP, else the kernel's generic XDP
  native,     // the driver's XDP only (fails with Errc::unsupported when it has none)
  generic,    // the kernel's generic (SKB) XDP: every driver, slower
};

enum class XdpCopyMode : std::uint8_t {
  automatic,  // zero-copy where the driver supports it, else copy
  copy,       // always copy (XDP_COPY)
  zero_copy,  // zero-copy or fail (XDP_ZEROCOPY)
};

struct XdpLinkOptions {
  // Network interface name, e.g. "eth0".
  std::string interface = {};
  // The receive queue the socket is bound to. Only frames the interface delivers on this queue
  // reach the link: on a multi-queue NIC steer EtherCAT there (ethtool -N ... or one queue only).
  std::uint32_t queue_id = 0;
  XdpAttachMode attach = XdpAttachMode::automatic;
  XdpCopyMode copy = XdpCopyMode::automatic;
  // SO_BUSY_POLL on the socket (with SO_PREFER_BUSY_POLL and a budget of 16): while receive()
  // waits, the kernel polls the device queue for this long per call instead of waiting for an
  // interrupt, and receive() never sleeps (0 = off). Needs CAP_NET_ADMIN; costs a CPU core
  // while waiting. Helps with drivers that have NAPI busy polling.
  int busy_poll_us = 0;
  // receive() never sleeps: it checks the receive ring until the frame or the deadline comes.
  bool spin = false;
  // Frames of the UMEM for receiving and for sending (each kFrameSize bytes, allocated once at
  // open and never again). Powers of two from 8 to 4096.
  std::uint32_t rx_frames = 256;
  std::uint32_t tx_frames = 64;
  // Ethernet source address of sent frames; the interface's own address when absent.
  std::optional<wire::MacAddress> source_mac{};
  // For a simulated segment serving on this interface, as RawLinkOptions::responder: replies go
  // to the destination of the last request, from its source with bit 1 of the first byte set.
  bool responder = false;
};

// What open() found and chose.
struct XdpLinkInfo {
  int interface_index = 0;
  wire::MacAddress interface_mac{};
  std::uint32_t queue_id = 0;
  bool native = false;     // the driver's XDP (else generic)
  bool zero_copy = false;  // the socket is in zero-copy mode (else copy)
  bool busy_poll = false;  // SO_BUSY_POLL took
  std::size_t max_frame = 0;
};

// True when this build of ecat has the AF_XDP link (libxdp and libbpf were found).
bool xdp_link_available() noexcept;

class XdpLink final : public Link {
 public:
  static constexpr std::size_t kFrameSize = 4096;  // one UMEM frame

  // Errors: Errc::unsupported when ecat was built without libxdp or the driver (in the mode
  // asked for) cannot run XDP or AF_XDP; Errc::not_found when the interface or queue does not
  // exist; Errc::permission_denied without the capabilities; Errc::busy when the interface
  // already has an XDP program in that mode; Errc::invalid_argument for bad options;
  // Errc::io_error otherwise (the interface down, a system call failing). Every message names
  // the interface and what failed.
  static Result<std::unique_ptr<XdpLink>> open(XdpLinkOptions options);

  ~XdpLink() override;

  Result<void> send(wire::Bytes ethercat_frame) override;
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override;
  void interrupt() override;
  void close() override;
  // Everything anew with the same options (the interface may have been recreated).
  Result<void> reopen() override;
  std::string name() const override;  // "xdp:IFACE" (",queue=N" when not queue 0)
  LinkStats stats() const override;
  std::size_t max_frame_size() const override;
  // The XSK socket (readable while the receive ring holds frames); -1 with `spin` or busy
  // polling (receive() never sleeps), while failed or closed.
  int wait_fd() override;

  XdpLinkInfo info() const;
  wire::MacAddress source_mac() const noexcept;

  struct Impl;

 private:
  explicit XdpLink(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::link
