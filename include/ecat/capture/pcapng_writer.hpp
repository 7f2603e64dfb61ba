// Writing pcapng: one section, one interface (nanosecond timestamps, if_tsresol = 9), one
// Enhanced Packet Block per packet with the epb_flags option saying whether the packet came in
// or went out (draft-ietf-opsawg-pcapng, "Enhanced Packet Block" and "epb_flags").
//
// Our own encoder because libpcap cannot write pcapng (pcap_dump_open writes classic pcap only,
// which has no place for a packet's direction). Reading stays with libpcap: CaptureFile reads
// what this writes (the round-trip test), tshark too.
#pragma once

#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/capture/capture_file.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::capture {

enum class PacketDirection : std::uint8_t { unknown, inbound, outbound };

struct PcapngPacket {
  std::int64_t timestamp_ns = 0;  // since the Unix epoch; before it is written as 0
  wire::Bytes data;
  PacketDirection direction = PacketDirection::unknown;  // unknown: no epb_flags option
  std::uint32_t original_length = 0;                     // 0: data.size()
};

// epb_flags bits 0-1: 01 inbound, 10 outbound (00: not known).
constexpr std::uint32_t kEpbFlagsInbound = 0x1;
constexpr std::uint32_t kEpbFlagsOutbound = 0x2;

// The encoder. `interface_name` goes into the IDB's if_name option when not empty.
struct PcapngInterface {
  int link_type = kLinkTypeEthernet;
  std::string name{};
  std::uint32_t snap_length = 262144;
};
std::vector<std::uint8_t> encode_pcapng_header(const PcapngInterface& interface);
// Appends one EPB for `packet` to `out` (data longer than snap_length is cut to it).
void encode_pcapng_packet(std::vector<std::uint8_t>& out, const PcapngPacket& packet,
                          std::uint32_t snap_length = 262144);
// A whole file in memory.
std::vector<std::uint8_t> encode_pcapng(std::span<const PcapngPacket> packets,
                                        const PcapngInterface& interface = {});

// An EtherCAT frame as an Ethernet II frame (EtherType 0x88A4) for captures of links that carry
// no Ethernet header of their own (UDP, in-process): destination broadcast, source
// kCaptureMasterMac for frames the master sent and the same with bit 1 of its first byte set for
// frames coming back (what ESCs do to the source address, and what `ecat decode` reads the
// direction from). The frame is padded to 60 bytes as on the wire.
constexpr wire::MacAddress kCaptureMasterMac{0x00, 0x00, 0x5e, 0x00, 0x53, 0x00};  // RFC 7042
std::vector<std::uint8_t> ethernet_for_capture(wire::Bytes ethercat_frame, bool from_master);

// A pcapng file written packet by packet (buffered; flush() pushes it to the file). Errors name
// the file (Errc::io_error with the system's reason).
class PcapngWriter {
 public:
  static Result<PcapngWriter> create(const std::string& path, const PcapngInterface& interface);
  PcapngWriter(PcapngWriter&&) noexcept;
  PcapngWriter& operator=(PcapngWriter&&) noexcept;
  ~PcapngWriter();  // closes (errors then are lost: call close())

  Result<void> write(const PcapngPacket& packet);
  Result<void> flush();
  Result<void> close();
  std::uint64_t packets() const noexcept { return packets_; }
  const std::string& path() const noexcept { return path_; }

 private:
  PcapngWriter() = default;
  Result<void> failed(std::string_view what);
  std::FILE* file_ = nullptr;
  std::string path_;
  std::uint32_t snap_length_ = 262144;
  std::uint64_t packets_ = 0;
  std::vector<std::uint8_t> scratch_;
};

Result<void> write_pcapng(const std::string& path, std::span<const PcapngPacket> packets,
                          const PcapngInterface& interface = {});

}  // namespace ecat::capture
