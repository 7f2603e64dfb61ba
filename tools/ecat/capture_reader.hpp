// Reading packet captures (pcap and pcapng, through libpcap) for `ecat decode`; the EtherCAT frames
// in them are found by ecat::capture::extract_ethercat (raw EtherCAT, optionally VLAN-tagged, and
// EtherCAT over UDP/IPv4, on Ethernet and Linux cooked SLL/SLL2 link types).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include <ecat/capture/capture_file.hpp>
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

// Finding the EtherCAT frame in a captured packet lives in the library (the simulator's capture
// tools use it too).
using capture::Encapsulation;
using capture::EtherCatPacket;
using capture::extract_ethercat;
using capture::link_type_supported;
using capture::to_string;

}  // namespace ecat::tool
