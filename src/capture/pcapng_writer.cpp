// pcapng blocks (draft-ietf-opsawg-pcapng), little-endian, written as the host would on the
// platforms we build for; the byte-order magic tells readers which order it is, so we always write
// little-endian and say so.
//
//   SHB  0x0A0D0D0A  len  0x1A2B3C4D  major 1  minor 0  section length -1 (unknown)  [opts]  len
//   IDB  0x00000001  len  linktype(16) reserved(16) snaplen(32)  if_name(2) if_tsresol(9)=9  len
//   EPB  0x00000006  len  interface 0  ts high  ts low  captured  original  data(pad 4)
//                         epb_flags(2)=direction  opt_endofopt  len
// Every block's body is a multiple of 4 bytes; options are code(16) length(16) value(pad 4).
#include <algorithm>
#include <cerrno>
#include <cstring>
#include <utility>

#include <fmt/format.h>

#include <ecat/capture/pcapng_writer.hpp>

namespace ecat::capture {

namespace {

constexpr std::uint32_t kBlockShb = 0x0A0D0D0A;
constexpr std::uint32_t kBlockIdb = 0x00000001;
constexpr std::uint32_t kBlockEpb = 0x00000006;
constexpr std::uint32_t kByteOrderMagic = 0x1A2B3C4D;
constexpr std::uint16_t kOptEnd = 0;
constexpr std::uint16_t kOptShbUserAppl = 4;
constexpr std::uint16_t kOptIfName = 2;
constexpr std::uint16_t kOptIfTsresol = 9;
constexpr std::uint16_t kOptEpbFlags = 2;
constexpr std::uint8_t kNanoseconds = 9;  // if_tsresol: 10^-9 s

void put16(std::vector<std::uint8_t>& out, std::uint16_t v) {
  out.push_back(static_cast<std::uint8_t>(v));
  out.push_back(static_cast<std::uint8_t>(v >> 8));
}
void put32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  put16(out, static_cast<std::uint16_t>(v));
  put16(out, static_cast<std::uint16_t>(v >> 16));
}
void set32(std::vector<std::uint8_t>& out, std::size_t at, std::uint32_t v) {
  for (int i = 0; i < 4; ++i)
    out[at + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(v >> (8 * i));
}
void pad4(std::vector<std::uint8_t>& out) {
  while (out.size() % 4 != 0)
    out.push_back(0);
}
void option(std::vector<std::uint8_t>& out, std::uint16_t code, const void* value,
            std::size_t length) {
  put16(out, code);
  put16(out, static_cast<std::uint16_t>(length));
  const auto* bytes = static_cast<const std::uint8_t*>(value);
  out.insert(out.end(), bytes, bytes + length);
  pad4(out);
}

// Starts a block at out.size(); finish_block writes both length fields.
std::size_t begin_block(std::vector<std::uint8_t>& out, std::uint32_t type) {
  const std::size_t start = out.size();
  put32(out, type);
  put32(out, 0);
  return start;
}
void finish_block(std::vector<std::uint8_t>& out, std::size_t start) {
  pad4(out);
  const auto length = static_cast<std::uint32_t>(out.size() - start + 4);
  put32(out, length);
  set32(out, start + 4, length);
}

}  // namespace

std::vector<std::uint8_t> encode_pcapng_header(const PcapngInterface& interface) {
  std::vector<std::uint8_t> out;
  std::size_t shb = begin_block(out, kBlockShb);
  put32(out, kByteOrderMagic);
  put16(out, 1);
  put16(out, 0);
  put32(out, 0xFFFFFFFF);  // section length: not known (we stream)
  put32(out, 0xFFFFFFFF);
  constexpr std::string_view kApplication = "ecat";
  option(out, kOptShbUserAppl, kApplication.data(), kApplication.size());
  option(out, kOptEnd, nullptr, 0);
  finish_block(out, shb);

  std::size_t idb = begin_block(out, kBlockIdb);
  put16(out, static_cast<std::uint16_t>(interface.link_type));
  put16(out, 0);
  put32(out, interface.snap_length);
  if (!interface.name.empty()) {
    // An option value is at most 65535 bytes.
    option(out, kOptIfName, interface.name.data(),
           std::min<std::size_t>(interface.name.size(), 256));
  }
  option(out, kOptIfTsresol, &kNanoseconds, 1);
  option(out, kOptEnd, nullptr, 0);
  finish_block(out, idb);
  return out;
}

void encode_pcapng_packet(std::vector<std::uint8_t>& out, const PcapngPacket& packet,
                          std::uint32_t snap_length) {
  const std::size_t captured = std::min<std::size_t>(packet.data.size(), snap_length);
  const auto original =
      packet.original_length != 0
          ? std::max<std::uint32_t>(packet.original_length, static_cast<std::uint32_t>(captured))
          : static_cast<std::uint32_t>(packet.data.size());
  const auto ts = static_cast<std::uint64_t>(std::max<std::int64_t>(packet.timestamp_ns, 0));
  std::size_t epb = begin_block(out, kBlockEpb);
  put32(out, 0);  // interface 0
  put32(out, static_cast<std::uint32_t>(ts >> 32));
  put32(out, static_cast<std::uint32_t>(ts));
  put32(out, static_cast<std::uint32_t>(captured));
  put32(out, original);
  out.insert(out.end(), packet.data.begin(),
             packet.data.begin() + static_cast<std::ptrdiff_t>(captured));
  pad4(out);
  if (packet.direction != PacketDirection::unknown) {
    std::uint8_t flags[4]{};
    const std::uint32_t value =
        packet.direction == PacketDirection::inbound ? kEpbFlagsInbound : kEpbFlagsOutbound;
    for (int i = 0; i < 4; ++i)
      flags[i] = static_cast<std::uint8_t>(value >> (8 * i));
    option(out, kOptEpbFlags, flags, 4);
    option(out, kOptEnd, nullptr, 0);
  }
  finish_block(out, epb);
}

std::vector<std::uint8_t> encode_pcapng(std::span<const PcapngPacket> packets,
                                        const PcapngInterface& interface) {
  auto out = encode_pcapng_header(interface);
  for (const auto& packet : packets)
    encode_pcapng_packet(out, packet, interface.snap_length);
  return out;
}

std::vector<std::uint8_t> ethernet_for_capture(wire::Bytes ethercat_frame, bool from_master) {
  wire::EthernetHeader header;
  header.destination = wire::kBroadcastMac;
  header.source = kCaptureMasterMac;
  if (!from_master) header.source[0] |= 0x02;
  std::vector<std::uint8_t> out(std::max<std::size_t>(14 + ethercat_frame.size(), 60) + 4);
  const wire::Bytes framed = wire::encode_ethernet(header, ethercat_frame, out);
  out.resize(framed.size());
  return out;
}

// ---- PcapngWriter -------------------------------------------------------------------------------

Result<PcapngWriter> PcapngWriter::create(const std::string& path,
                                          const PcapngInterface& interface) {
  PcapngWriter writer;
  writer.path_ = path;
  writer.snap_length_ = interface.snap_length;
  writer.file_ = std::fopen(path.c_str(), "wbe");
  if (writer.file_ == nullptr) {
    const int error = errno;
    return Error(Errc::io_error,
                 fmt::format("cannot create capture '{}': {}", path, std::strerror(error)));
  }
  const auto header = encode_pcapng_header(interface);
  if (std::fwrite(header.data(), 1, header.size(), writer.file_) != header.size()) {
    return std::move(writer.failed("writing its header")).error();
  }
  return writer;
}

PcapngWriter::PcapngWriter(PcapngWriter&& other) noexcept
    : file_(std::exchange(other.file_, nullptr)),
      path_(std::move(other.path_)),
      snap_length_(other.snap_length_),
      packets_(other.packets_),
      scratch_(std::move(other.scratch_)) {}

PcapngWriter& PcapngWriter::operator=(PcapngWriter&& other) noexcept {
  if (this != &other) {
    if (file_ != nullptr) std::fclose(file_);
    file_ = std::exchange(other.file_, nullptr);
    path_ = std::move(other.path_);
    snap_length_ = other.snap_length_;
    packets_ = other.packets_;
    scratch_ = std::move(other.scratch_);
  }
  return *this;
}

PcapngWriter::~PcapngWriter() {
  if (file_ != nullptr) std::fclose(file_);
}

Result<void> PcapngWriter::failed(std::string_view what) {
  const int error = errno;
  return Error(Errc::io_error, fmt::format("cannot write capture '{}' ({}): {}", path_, what,
                                           std::strerror(error)));
}

Result<void> PcapngWriter::write(const PcapngPacket& packet) {
  if (file_ == nullptr) return Error(Errc::closed, fmt::format("capture '{}' is closed", path_));
  scratch_.clear();
  encode_pcapng_packet(scratch_, packet, snap_length_);
  if (std::fwrite(scratch_.data(), 1, scratch_.size(), file_) != scratch_.size()) {
    return failed(fmt::format("packet {}", packets_ + 1));
  }
  ++packets_;
  return ok();
}

Result<void> PcapngWriter::flush() {
  if (file_ == nullptr) return ok();
  if (std::fflush(file_) != 0) return failed("flushing");
  return ok();
}

Result<void> PcapngWriter::close() {
  if (file_ == nullptr) return ok();
  const bool flushed = std::fflush(file_) == 0;
  const int error = errno;
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!flushed || !closed) {
    errno = flushed ? errno : error;
    return failed("closing");
  }
  return ok();
}

Result<void> write_pcapng(const std::string& path, std::span<const PcapngPacket> packets,
                          const PcapngInterface& interface) {
  auto writer = PcapngWriter::create(path, interface);
  if (!writer) return std::move(writer).error();
  for (const auto& packet : packets) {
    if (auto written = writer->write(packet); !written) return written;
  }
  return writer->close();
}

}  // namespace ecat::capture
