// EtherCAT directly on Ethernet (EtherType 0x88A4) through a Linux AF_PACKET socket bound to one
// network interface. Needs CAP_NET_RAW.
#pragma once

#include <cstddef>
#include <memory>
#include <optional>
#include <string>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {

struct RawLinkOptions {
  // Network interface name, e.g. "eth0".
  std::string interface = {};
  // Ethernet source address of sent frames; the interface's own address when absent.
  std::optional<wire::MacAddress> source_mac{};
  // SO_BUSY_POLL: the kernel polls the device queue for this long before sleeping in a blocking
  // receive (0 = off). Only helps with drivers that support busy polling; needs CAP_NET_ADMIN
  // above net.core.busy_read.
  int busy_poll_us = 0;
  // receive() never sleeps: it retries a non-blocking read until the frame or the deadline comes.
  // Lowest latency, costs one CPU core while waiting.
  bool spin = false;
  // SO_RCVBUF in bytes (0 = kernel default).
  std::size_t receive_buffer_bytes = 0;
  // Ask the kernel for receive timestamps (SO_TIMESTAMPNS).
  bool kernel_timestamps = true;
  // For a simulated segment serving on this interface: replies are sent to the destination of the
  // last received frame, from its source address with bit 1 of the first byte set, as a real ESC
  // rewrites it, so that the master can tell its request from the segment's reply.
  bool responder = false;
  // Attach a kernel filter so that only EtherCAT frames reach the socket. Cheaper on a shared
  // network, but foreign frames are then not counted in frames_ignored.
  bool kernel_filter = false;
};

class RawLink final : public Link {
 public:
  // Errors: Errc::not_found when the interface does not exist, Errc::permission_denied without
  // CAP_NET_RAW, Errc::io_error when the interface is down or the socket cannot be set up.
  static Result<std::unique_ptr<RawLink>> open(RawLinkOptions options);

  ~RawLink() override;

  Result<void> send(wire::Bytes ethercat_frame) override;
  // Sends with these Ethernet addresses instead of the link's own (or, for a responder, the last
  // request's): a simulated segment with two master ports sends a reply out of the port the ring
  // leads it to, with the address of the port that sent the request.
  Result<void> send_as(wire::Bytes ethercat_frame, const wire::MacAddress& source,
                       const wire::MacAddress& destination);
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override;
  void interrupt() override;
  void close() override;
  // A new socket on the same interface, set up as open() does (the interface may have been
  // recreated with another index; it must be up again).
  Result<void> reopen() override;
  std::string name() const override;
  LinkStats stats() const override;
  // The smaller of wire::kMaxFrameSize and the interface MTU.
  std::size_t max_frame_size() const override;
  // The socket (readable while frames wait); -1 with `spin` (receive() never sleeps) or closed.
  int wait_fd() override;

  int interface_index() const noexcept;
  // The interface's hardware address (not the override).
  wire::MacAddress interface_mac() const noexcept;
  // The address sent frames carry (the override when one was given).
  wire::MacAddress source_mac() const noexcept;
  // False on kernels without PACKET_IGNORE_OUTGOING (before 4.20): the link then drops its own
  // frames in user space, by packet type.
  bool ignores_outgoing_in_kernel() const noexcept;
  bool has_kernel_timestamps() const noexcept;

  struct Impl;

 private:
  explicit RawLink(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::link
