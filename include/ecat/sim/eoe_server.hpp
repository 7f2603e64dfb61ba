// The slave side of EoE (Ethernet over EtherCAT, mailbox type 2) for a simulated device: a tiny
// network node behind the ring, served through the device's CoeServer
// (CoeServer::set_protocol_handler(wire::MailboxType::eoe, ...)), which keeps the mailbox
// mechanics (counters, repeats, queued replies).
//
// What it does:
//  - Reassembles the master's fragments (ETG.1000.6 §5.7: fragment 0 announces the frame's size
//    in 32-byte blocks, later ones their offset; one frame number per frame). A lost or
//    out-of-order fragment, a frame beyond its announced size or beyond 1518 bytes drops the
//    frame and is counted.
//  - Answers, for its MAC address and IPv4 address, ARP requests (an ARP reply) and ICMP echo
//    requests (an echo reply, both checksums recomputed). Only the plainest IPv4 is taken: no
//    options, no fragments, header and ICMP checksums right; every other frame is dropped and
//    counted (what kind of drop in the stats). Replies are padded to the 60-byte Ethernet
//    minimum, as real MACs send them.
//  - Set IP Parameter: takes MAC, IP, subnet, gateway, DNS server and name (answers success), or
//    refuses with "no IP support" when configured so. The other request types are answered with
//    "unsupported frame type".
//  - Sends its replies fragmented to the size of its reply mailbox, one frame number per frame.
// Fault hooks leave out one fragment of a reply, ignore one fragment of a request, or drop a
// reply altogether.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include <ecat/sim/coe_server.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/eoe.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::sim {

class Esc;

struct EoeServerConfig {
  // A locally administered unicast address (bit 1 of the first byte set, bit 0 clear).
  std::array<std::uint8_t, 6> mac{0x02, 0x00, 0x0A, 0xCE, 0x00, 0x01};
  // None: the device has no address until the master sets one (it answers nothing until then).
  std::optional<std::uint32_t> ip{};  // 192.168.1.2 is 0xC0A80102
  std::uint32_t subnet_mask = 0xFFFFFF00;
  bool ip_support = true;  // false: Set IP Parameter is refused with "no IP support"
};

enum class EoeFaultKind : std::uint8_t {
  drop_reply_fragment,    // the next reply frame that has fragment number `value` goes without it
  drop_request_fragment,  // fragment number `value` of the next request frame is ignored
  drop_reply,             // the next reply frame is not sent at all
  // the next reply frame that has fragment number `value` (1..) carries a wrong fragment offset
  // (one block more than the bytes sent before it): the master's reassembly must drop the frame
  corrupt_fragment_offset,
};
// "drop_reply_fragment", "drop_request_fragment", "drop_reply", "corrupt_fragment_offset".
std::string_view to_string(EoeFaultKind kind) noexcept;

struct EoeFaultRule {
  EoeFaultKind kind = EoeFaultKind::drop_reply_fragment;
  std::uint8_t value = 0;  // a fragment number (0..63)
  bool once = true;        // removed after it fired; otherwise until clear_faults()
};

struct EoeServerStats {
  std::uint64_t fragments_received = 0;
  std::uint64_t frames_received = 0;    // complete frames reassembled
  std::uint64_t frames_dropped = 0;     // reassembly abandoned (lost / out-of-order / oversize)
  std::uint64_t fragments_dropped = 0;  // fragments of no open frame, undecodable EoE messages
  std::uint64_t arp_replies = 0;
  std::uint64_t icmp_replies = 0;
  std::uint64_t not_for_us = 0;   // another destination MAC or IP, an ARP for another address
  std::uint64_t unsupported = 0;  // other EtherTypes, IP protocols, ICMP types, IP options ...
  std::uint64_t malformed = 0;    // truncated headers, bad lengths, wrong checksums
  std::uint64_t frames_sent = 0;
  std::uint64_t fragments_sent = 0;
  std::uint64_t set_ip_requests = 0;
  std::uint64_t other_requests = 0;  // answered with "unsupported frame type"
  std::uint64_t faults_applied = 0;
};

class EoeServer {
 public:
  // `mailbox` carries the replies (it must outlive this server).
  EoeServer(CoeServer& mailbox, EoeServerConfig config);

  // The CoeServer protocol handler for wire::MailboxType::eoe.
  std::vector<MailboxReply> handle(Esc& esc, const wire::MailboxHeader& header, wire::Bytes data);
  // Power-up: addresses back to the configuration, reassembly dropped (faults, stats kept).
  void power_up();

  // The answer to one Ethernet frame: an ARP or ICMP echo reply, or nothing (counted why).
  std::optional<std::vector<std::uint8_t>> respond(std::span<const std::uint8_t> frame);
  // The mailbox data of the fragments of `frame` for a reply mailbox of `max_data` bytes of
  // data (the next frame number is used up). Empty when the frame cannot be sent.
  std::vector<std::vector<std::uint8_t>> fragments(std::span<const std::uint8_t> frame,
                                                   std::size_t max_data);
  // Sends a frame of the device's own (gratuitous ARP, a test's frame) through the mailbox.
  void send_frame(Esc& esc, std::span<const std::uint8_t> frame);

  const std::array<std::uint8_t, 6>& mac() const noexcept { return mac_; }
  std::optional<std::uint32_t> ip() const noexcept { return ip_; }
  // What the last Set IP Parameter request set (empty before one).
  const wire::EoeIpParameters& ip_parameters() const noexcept { return parameters_; }

  void add_fault(const EoeFaultRule& rule) { faults_.push_back(rule); }
  void clear_faults() { faults_.clear(); }
  const std::vector<EoeFaultRule>& faults() const noexcept { return faults_; }

  const EoeServerStats& stats() const noexcept { return stats_; }
  const EoeServerConfig& config() const noexcept { return config_; }

 private:
  std::optional<std::vector<std::uint8_t>> take_fragment(const wire::EoeFragment& fragment);
  std::optional<EoeFaultRule> take_fault(EoeFaultKind kind);
  std::vector<MailboxReply> reply_frame(Esc& esc, std::span<const std::uint8_t> frame);
  std::optional<std::vector<std::uint8_t>> answer_arp(std::span<const std::uint8_t> frame);
  std::optional<std::vector<std::uint8_t>> answer_ipv4(std::span<const std::uint8_t> frame);

  CoeServer& mailbox_;
  EoeServerConfig config_;
  std::array<std::uint8_t, 6> mac_;
  std::optional<std::uint32_t> ip_;
  wire::EoeIpParameters parameters_;
  std::vector<EoeFaultRule> faults_;
  EoeServerStats stats_;
  std::uint8_t tx_frame_number_ = 0;
  // The request frame being reassembled.
  bool open_ = false;
  std::uint8_t rx_frame_number_ = 0;
  std::uint8_t next_fragment_ = 0;
  std::size_t announced_ = 0;
  std::optional<std::uint8_t> skip_fragment_;  // drop_request_fragment armed for this frame
  std::vector<std::uint8_t> rx_;
};

// The EoE server of a device built on StandardApplication whose SII declares EoE, or nullptr.
EoeServer* eoe_server_of(Esc& esc) noexcept;

// The Internet checksum (RFC 1071) of `data`: the ones' complement of the ones' complement sum
// of its 16-bit big-endian words (an odd last byte padded with zero).
std::uint16_t internet_checksum(std::span<const std::uint8_t> data) noexcept;

}  // namespace ecat::sim
