// Packet captures, read and written through libpcap: pcap and pcapng files (both byte orders,
// microsecond and nanosecond pcap, every pcapng timestamp resolution, times delivered in
// nanoseconds), and finding the EtherCAT frame a captured packet carries — raw EtherCAT
// (EtherType 0x88A4, optionally VLAN-tagged) or EtherCAT over UDP/IPv4 (port 0x88A4 on either
// side), on Ethernet and Linux cooked (SLL, SLL2) link types.
//
// This is the one reader of captures: `ecat decode`, the simulator's capture tools
// (`ecat sim profile/verify`) and their tests all go through it. libpcap is private to the
// library: no public header includes it.
#pragma once

#include <cstdint>
#include <memory>
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

// Reads a capture packet by packet (libpcap underneath, nanosecond timestamps). Packets of link
// types extract_ethercat() does not understand are still returned (link_type says what they
// are). All packets of a file have the file's link type: libpcap refuses a pcapng file whose
// interfaces differ in link type.
class CaptureFile {
 public:
  // Opens the file. Errors: those of check_regular_file (absent, unreadable, not a regular file,
  // larger than 1 GiB), malformed/truncated (not a capture, or a damaged header), each naming the
  // file and libpcap's reason.
  static Result<CaptureFile> open(const std::string& path);
  // The same for bytes already in memory (kept by the CaptureFile); `name` is used in messages.
  static Result<CaptureFile> from_bytes(std::vector<std::uint8_t> bytes,
                                        std::string name = "capture");

  CaptureFile(CaptureFile&&) noexcept;
  CaptureFile& operator=(CaptureFile&&) noexcept;
  ~CaptureFile();

  // The next packet, nullopt at the end, or an error naming the damaged record (truncated when
  // the file ends inside it, malformed otherwise, io_error when the system failed to read).
  Result<std::optional<Packet>> next();

  CaptureFormat format() const noexcept { return format_; }
  const std::string& name() const noexcept { return name_; }
  // The link-layer header type of the file's packets (kLinkType*, or any other LINKTYPE_ value).
  int link_type() const noexcept { return link_type_; }

 private:
  struct Impl;
  explicit CaptureFile(std::unique_ptr<Impl> impl);
  static Result<CaptureFile> start(std::unique_ptr<Impl> impl, std::string name);

  std::unique_ptr<Impl> impl_;
  std::string name_;
  CaptureFormat format_ = CaptureFormat::pcap;
  int link_type_ = kLinkTypeEthernet;
  std::uint64_t count_ = 0;
};

// A packet to write.
struct OutputPacket {
  std::int64_t timestamp_ns = 0;  // before the epoch is written as 0
  wire::Bytes data;
};

// A nanosecond-resolution pcap file of `link_type` holding `packets`, as written by libpcap.
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
// too short to tell). EtherCAT over UDP is recognised on `udp_port` (source or destination):
// 0x88A4 unless a capture used another (ecat sim --udp and ecat's UDP links take any port).
std::optional<EtherCatPacket> extract_ethercat(
    int link_type, wire::Bytes packet, std::uint16_t udp_port = wire::kEtherCatUdpPort) noexcept;

}  // namespace ecat::capture
