// Reading packet captures (pcap and pcapng, through libpcap) and finding the EtherCAT frames in
// them: raw EtherCAT (EtherType 0x88A4, optionally VLAN-tagged) and EtherCAT over UDP/IPv4
// (port 0x88A4 on either side), on Ethernet and Linux cooked (SLL, SLL2) link types.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

struct pcap;

namespace ecat::tool {

struct CapturedPacket {
  std::uint64_t number = 0;       // 1-based position in the file
  std::int64_t timestamp_ns = 0;  // since the Unix epoch
  wire::Bytes data;               // captured bytes; valid until the next call to next()
  std::uint32_t original_length = 0;
};

class CaptureReader {
 public:
  // Fails with Errc::io_error naming the file and libpcap's reason, or Errc::unsupported when the
  // link type is not one extract_ethercat() understands.
  static Result<CaptureReader> open(const std::string& path);

  // The next packet, std::nullopt at the end of the file, or an error when the file is damaged.
  Result<std::optional<CapturedPacket>> next();

  int link_type() const noexcept { return link_type_; }
  const std::string& path() const noexcept { return path_; }

 private:
  struct Closer {
    void operator()(pcap* handle) const noexcept;
  };
  CaptureReader(std::unique_ptr<pcap, Closer> handle, std::string path, int link_type)
      : handle_(std::move(handle)), path_(std::move(path)), link_type_(link_type) {}

  std::unique_ptr<pcap, Closer> handle_;
  std::string path_;
  int link_type_ = 0;
  std::uint64_t count_ = 0;
};

enum class Encapsulation : std::uint8_t { ethernet, udp };
std::string_view to_string(Encapsulation encapsulation) noexcept;

struct EtherCatPacket {
  Encapsulation encapsulation = Encapsulation::ethernet;
  bool vlan = false;
  std::optional<wire::MacAddress> source;  // absent when the link layer has no 6-byte address
  wire::Bytes frame;                       // EtherCAT frame header + datagrams (+ padding)
};

bool link_type_supported(int link_type) noexcept;

// The EtherCAT frame a packet carries, or std::nullopt when it carries none (other protocols,
// packets too short to tell).
std::optional<EtherCatPacket> extract_ethercat(int link_type, wire::Bytes packet) noexcept;

}  // namespace ecat::tool
