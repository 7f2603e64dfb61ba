#include <algorithm>
#include <array>
#include <cstring>

#include <fmt/format.h>

#include <ecat/wire/frame.hpp>

namespace ecat::wire {

namespace {

constexpr std::uint16_t kLengthMask = 0x07FF;
constexpr std::uint16_t kCirculatingBit = 0x4000;
constexpr std::uint16_t kMoreFollowsBit = 0x8000;
constexpr unsigned kFrameTypeShift = 12;

constexpr std::array<std::string_view, kCommandCount> kCommandNames{
    "NOP", "APRD", "APWR", "APRW", "FPRD", "FPWR", "FPRW", "BRD",
    "BWR", "BRW",  "LRD",  "LWR",  "LRW",  "ARMW", "FRMW",
};

// Decoding never allocates, so errors are plain aggregates built on the spot.
DecodeError make_error(DecodeErrc code, std::size_t datagram, std::size_t offset,
                       std::size_t expected, std::size_t actual) noexcept {
  DecodeError error;
  error.code = code;
  error.datagram = static_cast<std::uint16_t>(datagram);
  error.offset = static_cast<std::uint32_t>(offset);
  error.expected = static_cast<std::uint32_t>(expected);
  error.actual = static_cast<std::uint32_t>(actual);
  return error;
}

DatagramHeader read_datagram_header(const std::uint8_t* p) noexcept {
  DatagramHeader header;
  header.command = static_cast<Command>(p[0]);
  header.index = p[1];
  header.address = load_le32(p + 2);
  const std::uint16_t length_field = load_le16(p + 6);
  header.length = static_cast<std::uint16_t>(length_field & kLengthMask);
  header.circulating = (length_field & kCirculatingBit) != 0;
  header.more_follows = (length_field & kMoreFollowsBit) != 0;
  header.irq = load_le16(p + 8);
  return header;
}

}  // namespace

std::string_view to_string(Command command) noexcept {
  const auto value = static_cast<std::size_t>(command);
  return value < kCommandCount ? kCommandNames[value] : std::string_view{};
}

std::optional<Command> command_from_byte(std::uint8_t value) noexcept {
  if (value >= kCommandCount) return std::nullopt;
  return static_cast<Command>(value);
}

Addressing addressing_of(Command command) noexcept {
  switch (command) {
    case Command::nop:
      return Addressing::none;
    case Command::aprd:
    case Command::apwr:
    case Command::aprw:
    case Command::armw:
      return Addressing::position;
    case Command::fprd:
    case Command::fpwr:
    case Command::fprw:
    case Command::frmw:
      return Addressing::station;
    case Command::brd:
    case Command::bwr:
    case Command::brw:
      return Addressing::broadcast;
    case Command::lrd:
    case Command::lwr:
    case Command::lrw:
      return Addressing::logical;
  }
  return Addressing::none;
}

bool command_reads(Command command) noexcept {
  switch (command) {
    case Command::aprd:
    case Command::fprd:
    case Command::brd:
    case Command::lrd:
    case Command::aprw:
    case Command::fprw:
    case Command::brw:
    case Command::lrw:
    case Command::armw:
    case Command::frmw:
      return true;
    default:
      return false;
  }
}

bool command_writes(Command command) noexcept {
  switch (command) {
    case Command::apwr:
    case Command::fpwr:
    case Command::bwr:
    case Command::lwr:
    case Command::aprw:
    case Command::fprw:
    case Command::brw:
    case Command::lrw:
    case Command::armw:
    case Command::frmw:
      return true;
    default:
      return false;
  }
}

std::string_view to_string(DecodeErrc code) noexcept {
  switch (code) {
    case DecodeErrc::truncated_ethernet_header:
      return "truncated_ethernet_header";
    case DecodeErrc::not_ethercat:
      return "not_ethercat";
    case DecodeErrc::truncated_frame_header:
      return "truncated_frame_header";
    case DecodeErrc::unsupported_frame_type:
      return "unsupported_frame_type";
    case DecodeErrc::frame_length_mismatch:
      return "frame_length_mismatch";
    case DecodeErrc::truncated_datagram_header:
      return "truncated_datagram_header";
    case DecodeErrc::truncated_datagram:
      return "truncated_datagram";
    case DecodeErrc::more_follows_past_end:
      return "more_follows_past_end";
    case DecodeErrc::unknown_command:
      return "unknown_command";
    case DecodeErrc::empty_frame:
      return "empty_frame";
  }
  return "unknown_decode_error";
}

std::string DecodeError::describe() const {
  const auto where = fmt::format("datagram {} at byte {}", datagram, offset);
  switch (code) {
    case DecodeErrc::truncated_ethernet_header:
      return fmt::format("Ethernet header truncated: {} bytes needed, {} present", expected,
                         actual);
    case DecodeErrc::not_ethercat:
      return fmt::format("EtherType 0x{:04X} at byte {} is not EtherCAT (0x{:04X})", actual, offset,
                         expected);
    case DecodeErrc::truncated_frame_header:
      return fmt::format("EtherCAT frame header truncated: {} bytes needed, {} present", expected,
                         actual);
    case DecodeErrc::unsupported_frame_type:
      return fmt::format(
          "EtherCAT frame header at byte {}: type {} is not supported (expected {}, datagrams)",
          offset, actual, expected);
    case DecodeErrc::frame_length_mismatch:
      if (offset == 0) {
        return fmt::format(
            "EtherCAT frame header length {} exceeds the {} bytes present after the header", actual,
            expected);
      }
      if (actual > expected) {
        return fmt::format(
            "{}: the datagram chain runs to {} bytes, past the frame header length {}", where,
            actual, expected);
      }
      return fmt::format(
          "datagram chain ends after datagram {} at {} bytes but the frame header length is {} "
          "(byte {} is neither a datagram nor zero padding)",
          datagram, actual, expected, offset);
    case DecodeErrc::truncated_datagram_header:
      return fmt::format("{}: datagram header needs {} bytes, {} left in the frame", where,
                         expected, actual);
    case DecodeErrc::truncated_datagram:
      return fmt::format(
          "{}: length {} runs past the end of the frame ({} bytes left for data and WKC)", where,
          expected, actual);
    case DecodeErrc::more_follows_past_end:
      return fmt::format(
          "{}: more-follows is set but the frame ends after this datagram (at byte {})", where,
          expected);
    case DecodeErrc::unknown_command:
      return fmt::format("{}: unknown command 0x{:02X} (commands are 0x00..0x{:02X})", where,
                         actual, expected);
    case DecodeErrc::empty_frame:
      return fmt::format("EtherCAT frame has no datagrams (header length {}, at least {} needed)",
                         actual, expected);
  }
  return fmt::format("undecodable frame ({})", to_string(code));
}

Error DecodeError::to_error() const {
  switch (code) {
    case DecodeErrc::truncated_ethernet_header:
    case DecodeErrc::truncated_frame_header:
    case DecodeErrc::truncated_datagram_header:
    case DecodeErrc::truncated_datagram:
    case DecodeErrc::more_follows_past_end:
      return Error(Errc::truncated, describe());
    default:
      return Error(Errc::malformed, describe());
  }
}

// ---------------------------------------------------------------------------------------------
// Iteration: the chain has been validated by decode_frame, so these only re-read it. The bounds
// checks keep a misused iterator (dereferencing end(), a default-constructed one) harmless.

DatagramView FrameView::Iterator::operator*() const noexcept {
  DatagramView view;
  if (offset_ > body_.size() || body_.size() - offset_ < kDatagramOverhead) return view;
  const std::uint8_t* p = body_.data() + offset_;
  view.header = read_datagram_header(p);
  if (body_.size() - offset_ - kDatagramOverhead < view.header.length) return DatagramView{};
  view.data = body_.subspan(offset_ + kDatagramHeaderSize, view.header.length);
  view.wkc = load_le16(p + kDatagramHeaderSize + view.header.length);
  return view;
}

FrameView::Iterator& FrameView::Iterator::operator++() noexcept {
  if (remaining_ == 0) return *this;
  if (offset_ <= body_.size() && body_.size() - offset_ >= kDatagramOverhead) {
    const std::size_t length = load_le16(body_.data() + offset_ + 6) & kLengthMask;
    offset_ = std::min(body_.size(), offset_ + kDatagramOverhead + length);
  } else {
    offset_ = body_.size();
  }
  --remaining_;
  return *this;
}

// ---------------------------------------------------------------------------------------------
// Decoding

struct FrameDecoder {
  static FrameDecodeResult decode(Bytes frame) noexcept {
    FrameDecodeResult result;
    const std::size_t size = frame.size();
    if (size < kFrameHeaderSize) {
      result.error = make_error(DecodeErrc::truncated_frame_header, 0, 0, kFrameHeaderSize, size);
      return result;
    }
    const std::uint16_t header = load_le16(frame.data());
    // Bit 11 is reserved; like an ESC we ignore it rather than reject a frame over it.
    const unsigned type = header >> kFrameTypeShift;
    if (type != kFrameTypeDatagrams) {
      result.error =
          make_error(DecodeErrc::unsupported_frame_type, 0, 0, kFrameTypeDatagrams, type);
      return result;
    }
    const std::size_t header_length = header & kLengthMask;
    if (header_length == 0) {
      result.error = make_error(DecodeErrc::empty_frame, 0, 0, kDatagramOverhead, 0);
      return result;
    }
    if (header_length > size - kFrameHeaderSize) {
      result.error = make_error(DecodeErrc::frame_length_mismatch, 0, 0, size - kFrameHeaderSize,
                                header_length);
      return result;
    }
    const std::size_t limit = kFrameHeaderSize + header_length;

    // The walk is bounded by the bytes present, not by the header length, so that a chain that
    // overruns the header length into bytes that are there is told apart from a truncated one.
    std::size_t offset = kFrameHeaderSize;
    std::size_t number = 0;
    for (;; ++number) {
      if (size - offset < kDatagramHeaderSize) {
        result.error = make_error(DecodeErrc::truncated_datagram_header, number, offset,
                                  kDatagramHeaderSize, size - offset);
        return result;
      }
      const std::uint8_t* p = frame.data() + offset;
      if (p[0] >= kCommandCount) {
        result.error =
            make_error(DecodeErrc::unknown_command, number, offset, kCommandCount - 1, p[0]);
        return result;
      }
      const std::uint16_t length_field = load_le16(p + 6);
      const std::size_t length = length_field & kLengthMask;
      const std::size_t left = size - offset - kDatagramHeaderSize;
      if (left < length + kWorkingCounterSize) {
        result.error = make_error(DecodeErrc::truncated_datagram, number, offset, length, left);
        return result;
      }
      const std::size_t end = offset + kDatagramOverhead + length;
      if (end > limit) {
        result.error = make_error(DecodeErrc::frame_length_mismatch, number, offset, header_length,
                                  end - kFrameHeaderSize);
        return result;
      }
      if ((length_field & kMoreFollowsBit) != 0) {
        if (end == limit) {
          result.error = make_error(DecodeErrc::more_follows_past_end, number, offset, end, 0);
          return result;
        }
        offset = end;
        continue;
      }
      // Some masters count their zero padding in the header length (seen in real captures), so
      // a chain that ends early is accepted when everything up to the header length is zero.
      for (std::size_t i = end; i < limit; ++i) {
        if (frame[i] != 0) {
          result.error = make_error(DecodeErrc::frame_length_mismatch, number, i, header_length,
                                    end - kFrameHeaderSize);
          return result;
        }
      }
      FrameView view;
      view.body_ = frame.subspan(kFrameHeaderSize, end - kFrameHeaderSize);
      view.header_length_ = static_cast<std::uint16_t>(header_length);
      view.count_ = number + 1;
      view.end_offset_ = view.body_.size();
      result.frame = view;
      return result;
    }
  }
};

FrameDecodeResult decode_frame(Bytes ethercat_frame) noexcept {
  return FrameDecoder::decode(ethercat_frame);
}

// ---------------------------------------------------------------------------------------------
// Encoding

FrameBuilder::FrameBuilder(MutableBytes buffer) noexcept : buffer_(buffer) {}

bool FrameBuilder::fits(std::size_t data_length) const noexcept {
  if (data_length > kMaxDatagramLength) return false;
  const std::size_t needed = footprint(data_length);
  return size_ <= buffer_.size() && buffer_.size() - size_ >= needed &&
         size_ - kFrameHeaderSize + needed <= kLengthMask;
}

std::optional<MutableBytes> FrameBuilder::add(const DatagramHeader& header, Bytes data,
                                              std::uint16_t wkc) noexcept {
  if (!data.empty() && data.size() != header.length) return std::nullopt;
  if (!fits(header.length)) return std::nullopt;
  if (static_cast<std::size_t>(header.command) >= kCommandCount) return std::nullopt;

  if (count_ > 0) {
    std::uint8_t* previous = buffer_.data() + last_datagram_offset_ + 6;
    store_le16(previous, static_cast<std::uint16_t>(load_le16(previous) | kMoreFollowsBit));
  }
  std::uint8_t* p = buffer_.data() + size_;
  p[0] = static_cast<std::uint8_t>(header.command);
  p[1] = header.index;
  store_le32(p + 2, header.address);
  std::uint16_t length_field = header.length;
  if (header.circulating) length_field |= kCirculatingBit;
  store_le16(p + 6, length_field);
  store_le16(p + 8, header.irq);
  const MutableBytes area{p + kDatagramHeaderSize, header.length};
  if (data.empty()) {
    std::fill(area.begin(), area.end(), std::uint8_t{0});
  } else {
    std::memcpy(area.data(), data.data(), data.size());
  }
  store_le16(p + kDatagramHeaderSize + header.length, wkc);

  last_datagram_offset_ = size_;
  size_ += footprint(header.length);
  ++count_;
  return area;
}

Bytes FrameBuilder::finish() noexcept {
  if (buffer_.size() < kFrameHeaderSize) return {};
  const auto length = static_cast<std::uint16_t>(size_ - kFrameHeaderSize);
  store_le16(buffer_.data(),
             static_cast<std::uint16_t>(length | (kFrameTypeDatagrams << kFrameTypeShift)));
  return Bytes{buffer_.data(), size_};
}

void FrameBuilder::reset() noexcept {
  size_ = kFrameHeaderSize;
  count_ = 0;
  last_datagram_offset_ = 0;
}

// ---------------------------------------------------------------------------------------------
// Ethernet II

std::string to_string(const MacAddress& mac) {
  return fmt::format("{:02x}:{:02x}:{:02x}:{:02x}:{:02x}:{:02x}", mac[0], mac[1], mac[2], mac[3],
                     mac[4], mac[5]);
}

EthernetDecodeResult decode_ethernet(Bytes ethernet_frame) noexcept {
  EthernetDecodeResult result;
  const std::size_t size = ethernet_frame.size();
  if (size < kEthernetHeaderSize) {
    result.error =
        make_error(DecodeErrc::truncated_ethernet_header, 0, 0, kEthernetHeaderSize, size);
    return result;
  }
  EthernetHeader header;
  std::memcpy(header.destination.data(), ethernet_frame.data(), header.destination.size());
  std::memcpy(header.source.data(), ethernet_frame.data() + 6, header.source.size());
  std::size_t type_offset = 12;
  header.ether_type = load_be16(ethernet_frame.data() + type_offset);
  if (header.ether_type == kEtherTypeVlan) {
    if (size < kEthernetHeaderSize + kVlanTagSize) {
      result.error = make_error(DecodeErrc::truncated_ethernet_header, 0, 0,
                                kEthernetHeaderSize + kVlanTagSize, size);
      return result;
    }
    header.vlan_tci = load_be16(ethernet_frame.data() + 14);
    type_offset += kVlanTagSize;
    header.ether_type = load_be16(ethernet_frame.data() + type_offset);
  }
  if (header.ether_type != kEtherTypeEtherCat) {
    result.error =
        make_error(DecodeErrc::not_ethercat, 0, type_offset, kEtherTypeEtherCat, header.ether_type);
    return result;
  }
  result.frame = EthernetView{header, ethernet_frame.subspan(type_offset + 2)};
  return result;
}

Bytes encode_ethernet(const EthernetHeader& header, Bytes payload, MutableBytes out) noexcept {
  const std::size_t header_size =
      kEthernetHeaderSize + (header.vlan_tci.has_value() ? kVlanTagSize : 0);
  const std::size_t size = std::max(header_size + payload.size(), kEthernetMinFrameSize);
  if (out.size() < size) return {};
  std::uint8_t* p = out.data();
  std::memcpy(p, header.destination.data(), header.destination.size());
  std::memcpy(p + 6, header.source.data(), header.source.size());
  std::size_t offset = 12;
  if (header.vlan_tci) {
    store_be16(p + offset, kEtherTypeVlan);
    store_be16(p + offset + 2, *header.vlan_tci);
    offset += kVlanTagSize;
  }
  store_be16(p + offset, header.ether_type);
  offset += 2;
  // memmove: callers may have built the payload in place, right after the header in `out`.
  if (!payload.empty()) std::memmove(p + offset, payload.data(), payload.size());
  std::fill(p + offset + payload.size(), p + size, std::uint8_t{0});
  return Bytes{p, size};
}

}  // namespace ecat::wire
