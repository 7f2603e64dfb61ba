#include "capture_reader.hpp"

#include <array>
#include <cstring>

#include <fmt/format.h>
#include <pcap/pcap.h>

namespace ecat::tool {

namespace {

using wire::Bytes;

constexpr std::uint16_t kEtherTypeIpv4 = 0x0800;
constexpr std::uint8_t kIpProtocolUdp = 17;
constexpr std::size_t kIpv4MinHeader = 20;
constexpr std::size_t kUdpHeader = 8;
constexpr std::size_t kSllHeader = 16;
constexpr std::size_t kSll2Header = 20;

std::optional<EtherCatPacket> from_udp_ipv4(Bytes ip, EtherCatPacket packet) noexcept {
  if (ip.size() < kIpv4MinHeader || (ip[0] >> 4) != 4) return std::nullopt;
  const std::size_t header = static_cast<std::size_t>(ip[0] & 0x0F) * 4;
  if (header < kIpv4MinHeader || header > ip.size() || ip[9] != kIpProtocolUdp) {
    return std::nullopt;
  }
  // Only the first fragment starts with the UDP header.
  if ((wire::load_be16(ip.data() + 6) & 0x1FFF) != 0) return std::nullopt;
  // The IP total length trims Ethernet padding; a capture may hold fewer bytes than it says.
  const std::size_t total = wire::load_be16(ip.data() + 2);
  if (total >= header && total < ip.size()) ip = ip.first(total);
  const Bytes udp = ip.subspan(header);
  if (udp.size() < kUdpHeader) return std::nullopt;
  const std::uint16_t source_port = wire::load_be16(udp.data());
  const std::uint16_t destination_port = wire::load_be16(udp.data() + 2);
  if (source_port != wire::kEtherCatUdpPort && destination_port != wire::kEtherCatUdpPort) {
    return std::nullopt;
  }
  std::size_t end = wire::load_be16(udp.data() + 4);
  if (end < kUdpHeader || end > udp.size()) end = udp.size();
  packet.encapsulation = Encapsulation::udp;
  packet.frame = udp.subspan(kUdpHeader, end - kUdpHeader);
  return packet;
}

// Dispatches on the EtherType of a link layer that has already been stripped.
std::optional<EtherCatPacket> from_ether_type(std::uint16_t ether_type, Bytes payload,
                                              EtherCatPacket packet) noexcept {
  if (ether_type == wire::kEtherTypeVlan) {
    if (payload.size() < wire::kVlanTagSize) return std::nullopt;
    packet.vlan = true;
    ether_type = wire::load_be16(payload.data() + 2);
    payload = payload.subspan(wire::kVlanTagSize);
  }
  if (ether_type == wire::kEtherTypeEtherCat) {
    packet.encapsulation = Encapsulation::ethernet;
    packet.frame = payload;
    return packet;
  }
  if (ether_type == kEtherTypeIpv4) return from_udp_ipv4(payload, packet);
  return std::nullopt;
}

std::optional<wire::MacAddress> link_address(Bytes address, std::size_t length) noexcept {
  if (length != 6 || address.size() < 6) return std::nullopt;
  wire::MacAddress mac{};
  std::memcpy(mac.data(), address.data(), mac.size());
  return mac;
}

}  // namespace

void CaptureReader::Closer::operator()(pcap* handle) const noexcept {
  if (handle != nullptr) pcap_close(handle);
}

Result<CaptureReader> CaptureReader::open(const std::string& path) {
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
  packet.data = Bytes(data, header->caplen);
  packet.original_length = header->len;
  return std::optional<CapturedPacket>(packet);
}

std::string_view to_string(Encapsulation encapsulation) noexcept {
  switch (encapsulation) {
    case Encapsulation::ethernet:
      return "ethernet";
    case Encapsulation::udp:
      return "udp";
  }
  return "unknown";
}

bool link_type_supported(int link_type) noexcept {
  return link_type == DLT_EN10MB || link_type == DLT_LINUX_SLL || link_type == DLT_LINUX_SLL2;
}

std::optional<EtherCatPacket> extract_ethercat(int link_type, Bytes packet) noexcept {
  EtherCatPacket result;
  switch (link_type) {
    case DLT_EN10MB: {
      if (packet.size() < wire::kEthernetHeaderSize) return std::nullopt;
      result.source = link_address(packet.subspan(6, 6), 6);
      return from_ether_type(wire::load_be16(packet.data() + 12),
                             packet.subspan(wire::kEthernetHeaderSize), result);
    }
    case DLT_LINUX_SLL: {
      // packet type(2) ARPHRD(2) address length(2) address(8) protocol(2)
      if (packet.size() < kSllHeader) return std::nullopt;
      result.source = link_address(packet.subspan(6, 8), wire::load_be16(packet.data() + 4));
      return from_ether_type(wire::load_be16(packet.data() + 14), packet.subspan(kSllHeader),
                             result);
    }
    case DLT_LINUX_SLL2: {
      // protocol(2) reserved(2) ifindex(4) ARPHRD(2) packet type(1) address length(1) address(8)
      if (packet.size() < kSll2Header) return std::nullopt;
      result.source = link_address(packet.subspan(12, 8), packet[11]);
      return from_ether_type(wire::load_be16(packet.data()), packet.subspan(kSll2Header), result);
    }
    default:
      return std::nullopt;
  }
}

}  // namespace ecat::tool
