#include <cstring>
#include <fstream>
#include <iterator>

#include <fmt/format.h>

#include <ecat/capture/capture_file.hpp>

#include "core/read_file.hpp"

namespace ecat::capture {

namespace {

using wire::Bytes;

constexpr std::uint32_t kPcapMagicMicro = 0xA1B2C3D4;
constexpr std::uint32_t kPcapMagicNano = 0xA1B23C4D;
constexpr std::size_t kPcapHeaderSize = 24;
constexpr std::size_t kPcapRecordHeaderSize = 16;
constexpr std::uint32_t kPcapngSectionHeader = 0x0A0D0D0A;
constexpr std::uint32_t kPcapngByteOrderMagic = 0x1A2B3C4D;
constexpr std::uint32_t kPcapngInterfaceDescription = 1;
constexpr std::uint32_t kPcapngObsoletePacket = 2;
constexpr std::uint32_t kPcapngSimplePacket = 3;
constexpr std::uint32_t kPcapngEnhancedPacket = 6;
constexpr std::uint16_t kOptionEnd = 0;
constexpr std::uint16_t kOptionTimestampResolution = 9;
constexpr std::uint16_t kOptionTimestampOffset = 14;
constexpr std::uint32_t kMaxPacketBytes = 1u << 24;

constexpr std::uint16_t kEtherTypeIpv4 = 0x0800;
constexpr std::uint8_t kIpProtocolUdp = 17;
constexpr std::size_t kIpv4MinHeader = 20;
constexpr std::size_t kUdpHeader = 8;
constexpr std::size_t kSllHeader = 16;
constexpr std::size_t kSll2Header = 20;
constexpr std::uint16_t kSllOutgoing = 4;

std::uint32_t load_be32(const std::uint8_t* p) noexcept {
  return (static_cast<std::uint32_t>(p[0]) << 24) | (static_cast<std::uint32_t>(p[1]) << 16) |
         (static_cast<std::uint32_t>(p[2]) << 8) | p[3];
}

std::uint64_t load_be64(const std::uint8_t* p) noexcept {
  return (static_cast<std::uint64_t>(load_be32(p)) << 32) | load_be32(p + 4);
}

std::uint32_t swap32(std::uint32_t v) noexcept {
  return (v >> 24) | ((v >> 8) & 0xFF00u) | ((v << 8) & 0xFF0000u) | (v << 24);
}

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
  packet.udp_source_port = source_port;
  packet.udp_destination_port = destination_port;
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

bool link_type_supported(int link_type) noexcept {
  return link_type == kLinkTypeEthernet || link_type == kLinkTypeLinuxSll ||
         link_type == kLinkTypeLinuxSll2;
}

// ---------------------------------------------------------------------------------------------
// Reading

Result<CaptureFile> CaptureFile::open(const std::string& path) {
  auto bytes = read_binary_file(path, FileKind::capture);
  if (!bytes) return std::move(bytes).error();
  return from_bytes(std::move(*bytes), path);
}

Result<CaptureFile> CaptureFile::from_bytes(std::vector<std::uint8_t> bytes, std::string name) {
  CaptureFile file;
  file.bytes_ = std::move(bytes);
  file.name_ = std::move(name);
  if (auto ok = file.read_file_header(); !ok) return ok.error();
  return file;
}

Error CaptureFile::damaged(std::size_t offset, const std::string& what) const {
  return Error(Errc::malformed,
               fmt::format("capture '{}': {} at byte offset {}", name_, what, offset));
}

std::uint16_t CaptureFile::u16(std::size_t offset) const noexcept {
  return big_endian_ ? wire::load_be16(&bytes_[offset]) : wire::load_le16(&bytes_[offset]);
}

std::uint32_t CaptureFile::u32(std::size_t offset) const noexcept {
  return big_endian_ ? load_be32(&bytes_[offset]) : wire::load_le32(&bytes_[offset]);
}

Result<void> CaptureFile::read_file_header() {
  if (bytes_.size() < 4) {
    return Error(Errc::truncated, fmt::format("capture '{}' is {} bytes long: too short for a "
                                              "pcap or pcapng header",
                                              name_, bytes_.size()));
  }
  const std::uint32_t magic = wire::load_le32(bytes_.data());
  if (magic == kPcapngSectionHeader) {
    format_ = CaptureFormat::pcapng;
    return {};  // the section header is read as the first block
  }
  for (bool big : {false, true}) {
    const std::uint32_t m = big ? swap32(magic) : magic;
    if (m != kPcapMagicMicro && m != kPcapMagicNano) continue;
    format_ = CaptureFormat::pcap;
    big_endian_ = big;
    nanoseconds_ = m == kPcapMagicNano;
    if (bytes_.size() < kPcapHeaderSize) {
      return Error(Errc::truncated,
                   fmt::format("capture '{}': pcap file header needs {} bytes, the file has {}",
                               name_, kPcapHeaderSize, bytes_.size()));
    }
    pcap_link_type_ = static_cast<int>(u32(20) & 0x0FFFFFFF);
    offset_ = kPcapHeaderSize;
    return {};
  }
  return Error(Errc::malformed,
               fmt::format("capture '{}' is neither pcap nor pcapng (first 4 bytes {:08X})", name_,
                           load_be32(bytes_.data())));
}

Result<std::optional<Packet>> CaptureFile::next() {
  return format_ == CaptureFormat::pcap ? next_pcap() : next_pcapng();
}

Result<std::optional<Packet>> CaptureFile::next_pcap() {
  if (offset_ == bytes_.size()) return std::optional<Packet>{};
  if (bytes_.size() - offset_ < kPcapRecordHeaderSize) {
    return Error(Errc::truncated, fmt::format("capture '{}': packet {} record header is cut off "
                                              "at byte offset {}",
                                              name_, count_ + 1, offset_));
  }
  const std::uint32_t seconds = u32(offset_);
  const std::uint32_t fraction = u32(offset_ + 4);
  const std::uint32_t captured = u32(offset_ + 8);
  const std::uint32_t original = u32(offset_ + 12);
  const std::size_t data = offset_ + kPcapRecordHeaderSize;
  if (captured > kMaxPacketBytes || captured > bytes_.size() - data) {
    return Error(Errc::truncated,
                 fmt::format("capture '{}': packet {} claims {} captured bytes at byte offset {}, "
                             "{} remain",
                             name_, count_ + 1, captured, offset_, bytes_.size() - data));
  }
  Packet packet;
  packet.number = ++count_;
  packet.timestamp_ns = static_cast<std::int64_t>(seconds) * 1'000'000'000 +
                        static_cast<std::int64_t>(fraction) * (nanoseconds_ ? 1 : 1000);
  packet.link_type = pcap_link_type_;
  packet.data = Bytes(&bytes_[data], captured);
  packet.original_length = original;
  offset_ = data + captured;
  return std::optional<Packet>(packet);
}

std::int64_t CaptureFile::pcapng_time_ns(const Interface& interface,
                                         std::uint64_t ticks) const noexcept {
  std::uint64_t ns = 0;
  if (!interface.binary) {
    if (interface.resolution <= 9) {
      std::uint64_t scale = 1;
      for (int i = interface.resolution; i < 9; ++i)
        scale *= 10;
      ns = ticks * scale;
    } else {
      std::uint64_t scale = 1;
      for (int i = 9; i < interface.resolution && i < 28; ++i)
        scale *= 10;
      ns = ticks / scale;
    }
  } else {
    // ticks / 2^r seconds: the whole seconds and the remainder separately, so nothing overflows
    // (finer than 2^-32 s is below a nanosecond: those bits are dropped first).
    int r = interface.resolution;
    if (r > 32) {
      ticks >>= (r - 32);
      r = 32;
    }
    const std::uint64_t whole = ticks >> r;
    const std::uint64_t rest = ticks & ((std::uint64_t{1} << r) - 1);
    ns = whole * 1'000'000'000u + ((rest * 1'000'000'000u) >> r);
  }
  // Modular arithmetic: absurd offsets in a damaged file wrap instead of overflowing.
  return static_cast<std::int64_t>(ns +
                                   static_cast<std::uint64_t>(interface.offset_s) * 1'000'000'000u);
}

Result<void> CaptureFile::read_section_header(std::size_t offset, std::size_t length) {
  // block type(4) length(4) byte-order magic(4) major(2) minor(2) section length(8)
  if (length < 28) return damaged(offset, fmt::format("section header block of {} bytes", length));
  const std::uint32_t magic = wire::load_le32(&bytes_[offset + 8]);
  if (magic == kPcapngByteOrderMagic) {
    big_endian_ = false;
  } else if (swap32(magic) == kPcapngByteOrderMagic) {
    big_endian_ = true;
  } else {
    return damaged(offset + 8, fmt::format("section header byte-order magic {:08X}", magic));
  }
  interfaces_.clear();
  return {};
}

Result<void> CaptureFile::read_interface(std::size_t offset, std::size_t length) {
  // block type(4) length(4) link type(2) reserved(2) snap length(4) options ... length(4)
  if (length < 20) {
    return damaged(offset, fmt::format("interface description block of {} bytes", length));
  }
  Interface interface;
  interface.link_type = u16(offset + 8);
  std::size_t pos = offset + 16;
  const std::size_t end = offset + length - 4;
  while (pos + 4 <= end) {
    const std::uint16_t code = u16(pos);
    const std::uint16_t size = u16(pos + 2);
    if (code == kOptionEnd) break;
    const std::size_t padded = (static_cast<std::size_t>(size) + 3u) & ~std::size_t{3};
    if (padded > end - pos - 4) {
      return damaged(pos,
                     fmt::format("interface option {} of {} bytes overruns its block", code, size));
    }
    if (code == kOptionTimestampResolution && size >= 1) {
      const std::uint8_t v = bytes_[pos + 4];
      interface.binary = (v & 0x80) != 0;
      interface.resolution = static_cast<std::uint8_t>(v & 0x7F);
      if ((interface.binary && interface.resolution > 63) ||
          (!interface.binary && interface.resolution > 27)) {
        return damaged(pos, fmt::format("timestamp resolution option {:#04x}", v));
      }
    } else if (code == kOptionTimestampOffset && size >= 8) {
      const std::uint64_t v =
          big_endian_ ? load_be64(&bytes_[pos + 4]) : wire::load_le64(&bytes_[pos + 4]);
      interface.offset_s = static_cast<std::int64_t>(v);
    }
    pos += 4 + padded;
  }
  interfaces_.push_back(interface);
  return {};
}

Result<std::optional<Packet>> CaptureFile::next_pcapng() {
  while (offset_ < bytes_.size()) {
    const std::size_t block = offset_;
    if (bytes_.size() - block < 12) {
      return Error(Errc::truncated, fmt::format("capture '{}': block header cut off at byte "
                                                "offset {}",
                                                name_, block));
    }
    const std::uint32_t raw_type = wire::load_le32(&bytes_[block]);
    if (raw_type == kPcapngSectionHeader) {
      // The byte order of the section decides how its own length is read.
      const std::uint32_t magic = wire::load_le32(&bytes_[block + 8]);
      big_endian_ = magic != kPcapngByteOrderMagic;
    }
    const std::uint32_t type = raw_type == kPcapngSectionHeader ? raw_type : u32(block);
    const std::uint32_t length = u32(block + 4);
    if (length < 12 || length % 4 != 0 || length > bytes_.size() - block) {
      return Error(length > bytes_.size() - block ? Errc::truncated : Errc::malformed,
                   fmt::format("capture '{}': block of type {:#x} at byte offset {} has length "
                               "{} ({} bytes remain)",
                               name_, type, block, length, bytes_.size() - block));
    }
    if (u32(block + length - 4) != length) {
      return damaged(block + length - 4,
                     fmt::format("block of type {:#x}: trailing length {} differs from {}", type,
                                 u32(block + length - 4), length));
    }
    offset_ = block + length;
    switch (type) {
      case kPcapngSectionHeader:
        if (auto ok = read_section_header(block, length); !ok) return ok.error();
        break;
      case kPcapngInterfaceDescription:
        if (auto ok = read_interface(block, length); !ok) return ok.error();
        break;
      case kPcapngEnhancedPacket:
      case kPcapngObsoletePacket: {
        // EPB: interface(4) ts high(4) ts low(4) captured(4) original(4) data
        // OPB: interface(2) drops(2) ts high(4) ts low(4) captured(4) original(4) data
        if (length < 32) return damaged(block, fmt::format("packet block of {} bytes", length));
        const std::uint32_t interface_id =
            type == kPcapngEnhancedPacket ? u32(block + 8) : u16(block + 8);
        if (interface_id >= interfaces_.size()) {
          return damaged(block + 8,
                         fmt::format("packet {} names interface {}, but {} are described",
                                     count_ + 1, interface_id, interfaces_.size()));
        }
        const std::uint64_t ticks =
            (static_cast<std::uint64_t>(u32(block + 12)) << 32) | u32(block + 16);
        const std::uint32_t captured = u32(block + 20);
        if (captured > length - 32) {
          return damaged(block + 20, fmt::format("packet {} claims {} captured bytes in a block "
                                                 "of {}",
                                                 count_ + 1, captured, length));
        }
        Packet packet;
        packet.number = ++count_;
        packet.timestamp_ns = pcapng_time_ns(interfaces_[interface_id], ticks);
        packet.link_type = interfaces_[interface_id].link_type;
        packet.data = Bytes(&bytes_[block + 28], captured);
        packet.original_length = u32(block + 24);
        return std::optional<Packet>(packet);
      }
      case kPcapngSimplePacket: {
        // original length(4) data; the captured part is what the block holds.
        if (interfaces_.empty()) {
          return damaged(block, "simple packet block before any interface description");
        }
        if (length < 16)
          return damaged(block, fmt::format("simple packet block of {} bytes", length));
        const std::uint32_t original = u32(block + 8);
        const std::size_t held = std::min<std::size_t>(original, length - 16);
        Packet packet;
        packet.number = ++count_;
        packet.timestamp_ns = 0;  // simple packets carry no time
        packet.link_type = interfaces_[0].link_type;
        packet.data = Bytes(&bytes_[block + 12], held);
        packet.original_length = original;
        return std::optional<Packet>(packet);
      }
      default:
        break;  // statistics, name resolution, custom blocks ...
    }
  }
  return std::optional<Packet>{};
}

// ---------------------------------------------------------------------------------------------
// Writing

std::vector<std::uint8_t> encode_pcap(std::span<const OutputPacket> packets, int link_type) {
  std::size_t size = kPcapHeaderSize;
  for (const auto& p : packets)
    size += kPcapRecordHeaderSize + p.data.size();
  std::vector<std::uint8_t> out(size);
  wire::store_le32(&out[0], kPcapMagicNano);
  wire::store_le16(&out[4], 2);
  wire::store_le16(&out[6], 4);
  wire::store_le32(&out[16], 65535);
  wire::store_le32(&out[20], static_cast<std::uint32_t>(link_type));
  std::size_t pos = kPcapHeaderSize;
  for (const auto& p : packets) {
    const std::int64_t t = p.timestamp_ns < 0 ? 0 : p.timestamp_ns;
    wire::store_le32(&out[pos], static_cast<std::uint32_t>(t / 1'000'000'000));
    wire::store_le32(&out[pos + 4], static_cast<std::uint32_t>(t % 1'000'000'000));
    wire::store_le32(&out[pos + 8], static_cast<std::uint32_t>(p.data.size()));
    wire::store_le32(&out[pos + 12], static_cast<std::uint32_t>(p.data.size()));
    if (!p.data.empty()) std::memcpy(&out[pos + 16], p.data.data(), p.data.size());
    pos += kPcapRecordHeaderSize + p.data.size();
  }
  return out;
}

Result<void> write_pcap(const std::string& path, std::span<const OutputPacket> packets,
                        int link_type) {
  const auto bytes = encode_pcap(packets, link_type);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Error(Errc::io_error, fmt::format("cannot create capture '{}'", path));
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  if (!out) return Error(Errc::io_error, fmt::format("cannot write capture '{}'", path));
  return {};
}

// ---------------------------------------------------------------------------------------------
// EtherCAT frames in packets

std::string_view to_string(Encapsulation encapsulation) noexcept {
  switch (encapsulation) {
    case Encapsulation::ethernet:
      return "ethernet";
    case Encapsulation::udp:
      return "udp";
  }
  return "unknown";
}

std::optional<EtherCatPacket> extract_ethercat(int link_type, Bytes packet) noexcept {
  EtherCatPacket result;
  switch (link_type) {
    case kLinkTypeEthernet: {
      if (packet.size() < wire::kEthernetHeaderSize) return std::nullopt;
      result.source = link_address(packet.subspan(6, 6), 6);
      return from_ether_type(wire::load_be16(packet.data() + 12),
                             packet.subspan(wire::kEthernetHeaderSize), result);
    }
    case kLinkTypeLinuxSll: {
      // packet type(2) ARPHRD(2) address length(2) address(8) protocol(2)
      if (packet.size() < kSllHeader) return std::nullopt;
      result.outgoing = wire::load_be16(packet.data()) == kSllOutgoing;
      result.source = link_address(packet.subspan(6, 8), wire::load_be16(packet.data() + 4));
      return from_ether_type(wire::load_be16(packet.data() + 14), packet.subspan(kSllHeader),
                             result);
    }
    case kLinkTypeLinuxSll2: {
      // protocol(2) reserved(2) ifindex(4) ARPHRD(2) packet type(1) address length(1) address(8)
      if (packet.size() < kSll2Header) return std::nullopt;
      result.outgoing = packet[10] == kSllOutgoing;
      result.source = link_address(packet.subspan(12, 8), packet[11]);
      return from_ether_type(wire::load_be16(packet.data()), packet.subspan(kSll2Header), result);
    }
    default:
      return std::nullopt;
  }
}

}  // namespace ecat::capture
