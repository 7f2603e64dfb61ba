// Packet captures without libpcap: reading pcap and pcapng files (both byte orders, microsecond
// and nanosecond pcap, every pcapng timestamp resolution and offset), writing nanosecond pcap
// files, and finding the EtherCAT frame a captured packet carries — raw EtherCAT (EtherType
// 0x88A4, optionally VLAN-tagged) or EtherCAT over UDP/IPv4 (port 0x88A4 on either side), on
// Ethernet and Linux cooked (SLL, SLL2) link types.
//
// The simulator's capture tools (`ecat sim profile/verify`) and their tests read captures through
// this; the `ecat decode` command keeps libpcap for reading and shares extract_ethercat().
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::capture {

// Link-layer header types (tcpdump.org LINKTYPE_*; libpcap's DLT_* values are the same for these).
constexpr int kLinkTypeEthernet = 1;
constexpr int kLinkTypeLinuxSll = 113;
constexpr int kLinkTypeLinuxSll2 = 276;

bool link_type_supported(int link_type) noexcept;

struct Packet {
  std::uint64_t number = 0;       // 1-based position among the file's packets
  std::int64_t timestamp_ns = 0;  // since the Unix epoch
  int link_type = kLinkTypeEthernet;
  wire::Bytes data;  // captured bytes; valid until the next call to next()
  std::uint32_t original_length = 0;
};

enum class CaptureFormat : std::uint8_t { pcap, pcapng };

// Reads a capture held in memory, packet by packet. Packets of link types extract_ethercat() does
// not understand are still returned (their link_type says what they are).
class CaptureFile {
 public:
  // Reads the whole file. Errors: io_error (cannot read), malformed/truncated (not a capture, or
  // damaged: the message names the offset and the field).
  static Result<CaptureFile> open(const std::string& path);
  // The same for bytes already in memory; `name` is used in messages.
  static Result<CaptureFile> from_bytes(std::vector<std::uint8_t> bytes,
                                        std::string name = "capture");

  // The next packet, nullopt at the end, or an error naming the damaged record.
  Result<std::optional<Packet>> next();

  CaptureFormat format() const noexcept { return format_; }
  const std::string& name() const noexcept { return name_; }

 private:
  struct Interface {
    int link_type = kLinkTypeEthernet;
    // Timestamp units: value * 10^-exponent s (decimal) or value * 2^-exponent s (binary).
    std::uint8_t resolution = 6;
    bool binary = false;
    std::int64_t offset_s = 0;
  };

  CaptureFile() = default;
  Result<void> read_file_header();
  Result<std::optional<Packet>> next_pcap();
  Result<std::optional<Packet>> next_pcapng();
  Result<void> read_section_header(std::size_t offset, std::size_t length);
  Result<void> read_interface(std::size_t offset, std::size_t length);
  std::int64_t pcapng_time_ns(const Interface& interface, std::uint64_t ticks) const noexcept;
  std::uint16_t u16(std::size_t offset) const noexcept;
  std::uint32_t u32(std::size_t offset) const noexcept;
  Error damaged(std::size_t offset, const std::string& what) const;

  std::vector<std::uint8_t> bytes_;
  std::string name_;
  CaptureFormat format_ = CaptureFormat::pcap;
  bool big_endian_ = false;
  bool nanoseconds_ = false;  // pcap only
  int pcap_link_type_ = kLinkTypeEthernet;
  std::size_t offset_ = 0;
  std::uint64_t count_ = 0;
  std::vector<Interface> interfaces_;  // pcapng: the current section's interfaces
};

// A packet to write.
struct OutputPacket {
  std::int64_t timestamp_ns = 0;
  wire::Bytes data;
};

// A nanosecond-resolution pcap file of `link_type` holding `packets`.
std::vector<std::uint8_t> encode_pcap(std::span<const OutputPacket> packets,
                                      int link_type = kLinkTypeEthernet);
Result<void> write_pcap(const std::string& path, std::span<const OutputPacket> packets,
                        int link_type = kLinkTypeEthernet);

// ---- EtherCAT in captured packets -----------------------------------------------------------

enum class Encapsulation : std::uint8_t { ethernet, udp };
std::string_view to_string(Encapsulation encapsulation) noexcept;

struct EtherCatPacket {
  Encapsulation encapsulation = Encapsulation::ethernet;
  bool vlan = false;
  std::optional<wire::MacAddress> source;  // absent when the link layer has no 6-byte address
  // Linux cooked captures say whether the capturing host sent the packet.
  std::optional<bool> outgoing;
  std::uint16_t udp_source_port = 0;  // UDP only
  std::uint16_t udp_destination_port = 0;
  wire::Bytes frame;  // EtherCAT frame header + datagrams (+ padding)
};

// The EtherCAT frame a packet carries, or nullopt when it carries none (other protocols, packets
// too short to tell).
std::optional<EtherCatPacket> extract_ethercat(int link_type, wire::Bytes packet) noexcept;

}  // namespace ecat::capture
