#include "capture_reader.hpp"

#include <array>
#include <cstring>

#include <fmt/format.h>
#include <pcap/pcap.h>

#include "core/read_file.hpp"

namespace ecat::tool {

void CaptureReader::Closer::operator()(pcap* handle) const noexcept {
  if (handle != nullptr) pcap_close(handle);
}

Result<CaptureReader> CaptureReader::open(const std::string& path) {
  // libpcap reads whatever it is given: a directory, a device or an endless pipe must be refused
  // before it starts.
  if (auto regular = check_regular_file(path, FileKind::capture); !regular) {
    return regular.error();
  }
  std::array<char, PCAP_ERRBUF_SIZE> error{};
  std::unique_ptr<pcap, Closer> handle(pcap_open_offline_with_tstamp_precision(
      path.c_str(), PCAP_TSTAMP_PRECISION_NANO, error.data()));
  if (!handle) {
    return Error(Errc::io_error, fmt::format("cannot open capture '{}': {}", path, error.data()));
  }
  const int link_type = pcap_datalink(handle.get());
  if (!link_type_supported(link_type)) {
    const char* name = pcap_datalink_val_to_name(link_type);
    return Error(Errc::unsupported,
                 fmt::format("capture '{}': link type {} ({}) is not supported (Ethernet, Linux "
                             "cooked SLL and SLL2 are)",
                             path, link_type, name != nullptr ? name : "unknown"));
  }
  return CaptureReader(std::move(handle), path, link_type);
}

Result<std::optional<CapturedPacket>> CaptureReader::next() {
  pcap_pkthdr* header = nullptr;
  const u_char* data = nullptr;
  const int status = pcap_next_ex(handle_.get(), &header, &data);
  if (status == PCAP_ERROR_BREAK) return std::optional<CapturedPacket>{};
  if (status != 1) {
    return Error(Errc::io_error, fmt::format("capture '{}': cannot read packet {}: {}", path_,
                                             count_ + 1, pcap_geterr(handle_.get())));
  }
  CapturedPacket packet;
  packet.number = ++count_;
  // Opened with nanosecond precision, so tv_usec holds nanoseconds.
  packet.timestamp_ns = static_cast<std::int64_t>(header->ts.tv_sec) * 1'000'000'000 +
                        static_cast<std::int64_t>(header->ts.tv_usec);
  packet.data = wire::Bytes(data, header->caplen);
  packet.original_length = header->len;
  return std::optional<CapturedPacket>(packet);
}

}  // namespace ecat::tool
