// Captures through libpcap: one reader (pcap_fopen_offline_with_tstamp_precision on a FILE we
// opened ourselves, or on an fmemopen'd buffer for bytes in memory) and one writer (pcap_dump on a
// nanosecond "dead" handle, into a file or an open_memstream buffer).
#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>

#include <fcntl.h>
#include <fmt/format.h>
#include <pcap/pcap.h>
#include <sys/stat.h>
#include <unistd.h>

#include <ecat/capture/capture_file.hpp>
#include <ecat/log.hpp>

#include "core/read_file.hpp"

namespace ecat::capture {

namespace {

using wire::Bytes;

constexpr std::uint32_t kPcapngSectionHeader = 0x0A0D0D0A;
// The snapshot length written into our files: libpcap's own maximum (MAXIMUM_SNAPLEN), which
// its readers accept for every link type we write.
constexpr int kWriteSnapLength = 262144;

constexpr std::uint16_t kEtherTypeIpv4 = 0x0800;
constexpr std::uint8_t kIpProtocolUdp = 17;
constexpr std::size_t kIpv4MinHeader = 20;
constexpr std::size_t kUdpHeader = 8;
constexpr std::size_t kSllHeader = 16;
constexpr std::size_t kSll2Header = 20;
constexpr std::uint16_t kSllOutgoing = 4;

// libpcap's words for a file that ends inside a header or record.
bool says_truncated(std::string_view message) noexcept {
  return message.find("truncated") != std::string_view::npos;
}

Errc read_error_code(std::string_view message) noexcept {
  if (says_truncated(message)) return Errc::truncated;
  if (message.find("error reading dump file") != std::string_view::npos) return Errc::io_error;
  return Errc::malformed;
}

std::optional<EtherCatPacket> from_udp_ipv4(Bytes ip, EtherCatPacket packet,
                                            std::uint16_t port) noexcept {
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
  if (source_port != port && destination_port != port) {
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
                                              EtherCatPacket packet,
                                              std::uint16_t udp_port) noexcept {
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
  if (ether_type == kEtherTypeIpv4) return from_udp_ipv4(payload, packet, udp_port);
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

struct CaptureFile::Impl {
  std::vector<std::uint8_t> bytes;  // from_bytes: the buffer libpcap reads through fmemopen
  FILE* stream = nullptr;           // until libpcap owns it
  pcap_t* handle = nullptr;         // owns `stream` once opened (pcap_close closes it)

  Impl() = default;
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;
  ~Impl() {
    if (handle != nullptr) {
      pcap_close(handle);
    } else if (stream != nullptr) {
      std::fclose(stream);
    }
  }
};

CaptureFile::CaptureFile(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
CaptureFile::CaptureFile(CaptureFile&&) noexcept = default;
CaptureFile& CaptureFile::operator=(CaptureFile&&) noexcept = default;
CaptureFile::~CaptureFile() = default;

Result<CaptureFile> CaptureFile::open(const std::string& path) {
  // libpcap reads whatever it is given: a directory, a device or an endless pipe is refused
  // before it starts, with the project's named errors (and the 1 GiB cap on captures).
  if (auto regular = check_regular_file(path, FileKind::capture); !regular) {
    return regular.error();
  }
  // Opened without blocking (a FIFO swapped in since the check must not hang the open) and
  // checked again on the descriptor that is read.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    const int error = errno;
    return Error(Errc::io_error,
                 fmt::format("cannot open capture '{}': {}", path, std::strerror(error)));
  }
  struct stat info {};
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode) ||
      static_cast<std::uint64_t>(info.st_size) > max_file_bytes(FileKind::capture)) {
    ::close(fd);
    return Error(Errc::invalid_argument,
                 fmt::format("capture '{}' changed while it was opened: no longer a regular "
                             "file of at most {}",
                             path, describe_size(max_file_bytes(FileKind::capture))));
  }
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);
  auto impl = std::make_unique<Impl>();
  impl->stream = ::fdopen(fd, "rb");
  if (impl->stream == nullptr) {
    const int error = errno;
    ::close(fd);
    return Error(Errc::io_error,
                 fmt::format("cannot read capture '{}': {}", path, std::strerror(error)));
  }
  return start(std::move(impl), path);
}

Result<CaptureFile> CaptureFile::from_bytes(std::vector<std::uint8_t> bytes, std::string name) {
  if (bytes.empty()) {
    // fmemopen refuses an empty buffer: say what libpcap would.
    return Error(Errc::truncated,
                 fmt::format("capture '{}' is empty: not a pcap or pcapng file", name));
  }
  auto impl = std::make_unique<Impl>();
  impl->bytes = std::move(bytes);
  impl->stream = ::fmemopen(impl->bytes.data(), impl->bytes.size(), "rb");
  if (impl->stream == nullptr) {
    const int error = errno;
    return Error(Errc::io_error, fmt::format("capture '{}': cannot read it from memory: {}", name,
                                             std::strerror(error)));
  }
  return start(std::move(impl), std::move(name));
}

Result<CaptureFile> CaptureFile::start(std::unique_ptr<Impl> impl, std::string name) {
  // The format, for callers that say which it is (libpcap reads both the same way).
  std::array<std::uint8_t, 4> magic{};
  const std::size_t got = std::fread(magic.data(), 1, magic.size(), impl->stream);
  const bool pcapng = got == magic.size() && wire::load_le32(magic.data()) == kPcapngSectionHeader;
  std::rewind(impl->stream);

  std::array<char, PCAP_ERRBUF_SIZE> error{};
  impl->handle = pcap_fopen_offline_with_tstamp_precision(impl->stream, PCAP_TSTAMP_PRECISION_NANO,
                                                          error.data());
  if (impl->handle == nullptr) {
    // libpcap leaves the stream to us when it fails (Impl closes it).
    const std::string_view why(error.data());
    ECAT_LOG(LogLevel::debug, "capture",
             fmt::format("libpcap refused capture '{}': {}", name, why));
    if (why.find("unknown file format") != std::string_view::npos) {
      return Error(Errc::malformed,
                   fmt::format("capture '{}' is neither pcap nor pcapng (libpcap: {})", name, why));
    }
    return Error(read_error_code(why),
                 fmt::format("capture '{}' is not a readable pcap or pcapng file: {}", name, why));
  }
  impl->stream = nullptr;  // pcap_close closes it now
  CaptureFile file(std::move(impl));
  file.name_ = std::move(name);
  file.format_ = pcapng ? CaptureFormat::pcapng : CaptureFormat::pcap;
  file.link_type_ = pcap_datalink(file.impl_->handle);
  ECAT_LOG(LogLevel::debug, "capture",
           fmt::format("reading capture '{}' ({}, link type {})", file.name_,
                       pcapng ? "pcapng" : "pcap", file.link_type_));
  return file;
}

Result<std::optional<Packet>> CaptureFile::next() {
  if (!impl_ || impl_->handle == nullptr) {
    return Error(Errc::invalid_argument, fmt::format("capture '{}' is not open", name_));
  }
  pcap_pkthdr* header = nullptr;
  const u_char* data = nullptr;
  const int status = pcap_next_ex(impl_->handle, &header, &data);
  if (status == PCAP_ERROR_BREAK) return std::optional<Packet>{};  // the end of the file
  if (status != 1) {
    const std::string_view why(pcap_geterr(impl_->handle));
    return Error(read_error_code(why),
                 fmt::format("capture '{}': cannot read packet {}: {}", name_, count_ + 1, why));
  }
  Packet packet;
  packet.number = ++count_;
  // Opened with nanosecond precision, so tv_usec holds nanoseconds. Unsigned arithmetic: a
  // damaged pcapng time far beyond 2262 wraps instead of overflowing.
  packet.timestamp_ns =
      static_cast<std::int64_t>(static_cast<std::uint64_t>(header->ts.tv_sec) * 1'000'000'000u +
                                static_cast<std::uint64_t>(header->ts.tv_usec));
  packet.link_type = link_type_;
  packet.data = wire::Bytes(data, header->caplen);
  packet.original_length = header->len;
  return std::optional<Packet>(packet);
}

// ---------------------------------------------------------------------------------------------
// Writing

namespace {

struct DeadCloser {
  void operator()(pcap_t* handle) const noexcept { pcap_close(handle); }
};
using DeadHandle = std::unique_ptr<pcap_t, DeadCloser>;

DeadHandle dead_handle(int link_type) {
  return DeadHandle(pcap_open_dead_with_tstamp_precision(link_type, kWriteSnapLength,
                                                         PCAP_TSTAMP_PRECISION_NANO));
}

// Writes the packets through `dumper`; false when the stream failed.
bool dump_all(pcap_dumper_t* dumper, std::span<const OutputPacket> packets) {
  for (const auto& p : packets) {
    const std::int64_t t = std::max<std::int64_t>(p.timestamp_ns, 0);
    pcap_pkthdr header{};
    header.ts.tv_sec = static_cast<time_t>(t / 1'000'000'000);
    header.ts.tv_usec = static_cast<suseconds_t>(t % 1'000'000'000);  // nanoseconds
    header.len = static_cast<bpf_u_int32>(p.data.size());
    header.caplen = static_cast<bpf_u_int32>(
        std::min<std::size_t>(p.data.size(), static_cast<std::size_t>(kWriteSnapLength)));
    pcap_dump(reinterpret_cast<u_char*>(dumper), &header, p.data.data());
  }
  return pcap_dump_flush(dumper) == 0;
}

}  // namespace

std::vector<std::uint8_t> encode_pcap(std::span<const OutputPacket> packets, int link_type) {
  const DeadHandle dead = dead_handle(link_type);
  char* buffer = nullptr;
  std::size_t size = 0;
  FILE* stream = dead ? ::open_memstream(&buffer, &size) : nullptr;
  if (stream == nullptr) throw std::bad_alloc();
  pcap_dumper_t* dumper = pcap_dump_fopen(dead.get(), stream);
  if (dumper == nullptr) {
    std::fclose(stream);
    std::free(buffer);
    throw std::bad_alloc();
  }
  const bool ok = dump_all(dumper, packets);
  pcap_dump_close(dumper);  // closes the stream: buffer and size are final
  std::vector<std::uint8_t> out;
  if (ok && buffer != nullptr) out.assign(buffer, buffer + size);
  std::free(buffer);
  if (!ok) throw std::bad_alloc();  // a memory stream fails only for want of memory
  return out;
}

Result<void> write_pcap(const std::string& path, std::span<const OutputPacket> packets,
                        int link_type) {
  const DeadHandle dead = dead_handle(link_type);
  if (!dead) return Error(Errc::io_error, fmt::format("cannot create capture '{}'", path));
  // Opened here rather than by pcap_dump_open, which would take "-" to mean standard output.
  FILE* stream = std::fopen(path.c_str(), "wbe");
  if (stream == nullptr) {
    const int error = errno;
    return Error(Errc::io_error,
                 fmt::format("cannot create capture '{}': {}", path, std::strerror(error)));
  }
  pcap_dumper_t* dumper = pcap_dump_fopen(dead.get(), stream);
  if (dumper == nullptr) {
    const std::string why = pcap_geterr(dead.get());
    std::fclose(stream);
    return Error(Errc::io_error, fmt::format("cannot write capture '{}': {}", path, why));
  }
  const bool ok = dump_all(dumper, packets);
  pcap_dump_close(dumper);
  if (!ok) {
    const int error = errno;
    return Error(Errc::io_error,
                 fmt::format("cannot write capture '{}': {}", path, std::strerror(error)));
  }
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

std::optional<EtherCatPacket> extract_ethercat(int link_type, Bytes packet,
                                               std::uint16_t udp_port) noexcept {
  EtherCatPacket result;
  switch (link_type) {
    case kLinkTypeEthernet: {
      if (packet.size() < wire::kEthernetHeaderSize) return std::nullopt;
      result.source = link_address(packet.subspan(6, 6), 6);
      return from_ether_type(wire::load_be16(packet.data() + 12),
                             packet.subspan(wire::kEthernetHeaderSize), result, udp_port);
    }
    case kLinkTypeLinuxSll: {
      // packet type(2) ARPHRD(2) address length(2) address(8) protocol(2)
      if (packet.size() < kSllHeader) return std::nullopt;
      result.outgoing = wire::load_be16(packet.data()) == kSllOutgoing;
      result.source = link_address(packet.subspan(6, 8), wire::load_be16(packet.data() + 4));
      return from_ether_type(wire::load_be16(packet.data() + 14), packet.subspan(kSllHeader),
                             result, udp_port);
    }
    case kLinkTypeLinuxSll2: {
      // protocol(2) reserved(2) ifindex(4) ARPHRD(2) packet type(1) address length(1) address(8)
      if (packet.size() < kSll2Header) return std::nullopt;
      result.outgoing = packet[10] == kSllOutgoing;
      result.source = link_address(packet.subspan(12, 8), packet[11]);
      return from_ether_type(wire::load_be16(packet.data()), packet.subspan(kSll2Header), result,
                             udp_port);
    }
    default:
      return std::nullopt;
  }
}

}  // namespace ecat::capture
