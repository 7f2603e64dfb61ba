// EtherCAT over UDP: each UDP datagram's payload is one EtherCAT frame (header + datagrams), on
// port 0x88A4 (34980) by default. Used to reach a simulated segment (`ecat sim --udp`) and by that
// simulator to serve; it needs no privileges.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::link {

struct UdpLinkOptions {
  enum class Mode : std::uint8_t {
    // Sends to one peer (host:port) and receives only from it.
    client,
    // Listens on host:port and send() replies to the sender of the most recent datagram. A
    // segment has one master: while one host is heard from (see peer_hold), datagrams from other
    // hosts are ignored (counted in frames_ignored and foreign_frames()).
    server,
  };
  Mode mode = Mode::client;
  // Client: the peer (IPv4 or IPv6 address, or a name resolved once, at open). Server: the local
  // address to listen on; empty means loopback (127.0.0.1), "*" every address (IPv6 and IPv4
  // where the system allows).
  std::string host{};
  // Client: the peer's port. Server: the port to listen on; 0 picks a free one (see local_port()).
  std::uint16_t port = wire::kEtherCatUdpPort;
  // Server only: how long the master's host keeps the segment after its last datagram before
  // another host may take over.
  std::chrono::nanoseconds peer_hold = std::chrono::seconds(1);
  // Client only: the local address and port to send from (empty / 0: chosen by the kernel).
  std::string bind_address{};
  std::uint16_t bind_port = 0;
  // SO_RCVBUF in bytes (0 = kernel default).
  std::size_t receive_buffer_bytes = 0;
  bool kernel_timestamps = true;
  // receive() retries a non-blocking read instead of sleeping (see RawLinkOptions::spin).
  bool spin = false;
};

class UdpLink final : public Link {
 public:
  // Errors: Errc::not_found for a host name that does not resolve, Errc::busy for a port in use,
  // Errc::permission_denied for a privileged port, Errc::invalid_argument for bad options,
  // Errc::io_error otherwise.
  static Result<std::unique_ptr<UdpLink>> open(UdpLinkOptions options);
  static Result<std::unique_ptr<UdpLink>> connect(std::string host,
                                                  std::uint16_t port = wire::kEtherCatUdpPort);
  static Result<std::unique_ptr<UdpLink>> serve(std::string address,
                                                std::uint16_t port = wire::kEtherCatUdpPort);

  ~UdpLink() override;

  // Client: one datagram to the peer. Server: one datagram to the sender of the most recently
  // received datagram (Errc::wrong_state before anything was received).
  Result<void> send(wire::Bytes ethercat_frame) override;
  // A refused port (ICMP port unreachable: nobody listens at the peer) is counted in
  // receive_errors and waited through, the way a raw link sees a silent wire.
  Result<std::optional<ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override;
  void interrupt() override;
  void close() override;
  // A new socket with the same options (a server on the port it had).
  Result<void> reopen() override;
  // "udp:127.0.0.1:34980" (client: the peer) or "udp-server:[::]:34980" (server: the local end).
  std::string name() const override;
  LinkStats stats() const override;

  // The bound local port (useful after port 0).
  std::uint16_t local_port() const noexcept;
  // "address:port" of the peer replies go to; empty for a server that has not heard from anyone.
  std::string peer() const;
  // Server: datagrams ignored because another host held the segment.
  std::uint64_t foreign_frames() const noexcept;
  bool has_kernel_timestamps() const noexcept;

  struct Impl;

 private:
  explicit UdpLink(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::link
