// EtherCAT frames and datagrams: commands, headers, encoding into caller buffers and validating,
// allocation-free decoding. Also the Ethernet II and UDP encapsulations.
//
// Layout (all little-endian):
//   EtherCAT frame header (2): length[10:0] | reserved[11] | type[15:12] (1 = datagrams)
//   datagram: cmd(1) idx(1) address(4) len_field(2) irq(2) data(len) wkc(2)
//     len_field = length[10:0] | reserved[13:11] | circulating[14] | more_follows[15]
//     address   = ADP (position or station, low 16) | ADO (register offset, high 16), or a 32-bit
//                 logical address for LRD/LWR/LRW.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::uint16_t kEtherTypeEtherCat = 0x88A4;
constexpr std::uint16_t kEtherTypeVlan = 0x8100;
constexpr std::uint16_t kEtherCatUdpPort = 0x88A4;  // 34980
constexpr std::size_t kEthernetHeaderSize = 14;
constexpr std::size_t kVlanTagSize = 4;
constexpr std::size_t kEthernetMinFrameSize = 60;  // without FCS; shorter frames are padded
constexpr std::size_t kEthernetMtu = 1500;
constexpr std::size_t kFrameHeaderSize = 2;
constexpr std::size_t kDatagramHeaderSize = 10;
constexpr std::size_t kWorkingCounterSize = 2;
constexpr std::size_t kDatagramOverhead = kDatagramHeaderSize + kWorkingCounterSize;
constexpr std::size_t kMaxDatagramLength = 0x7FF;  // 11-bit length field
// Largest EtherCAT frame (header + datagrams) that fits one standard Ethernet frame.
constexpr std::size_t kMaxFrameSize = kEthernetMtu;
// Largest data of one datagram that is alone in a frame.
constexpr std::size_t kMaxSingleDatagramData = kMaxFrameSize - kFrameHeaderSize - kDatagramOverhead;
constexpr std::uint8_t kFrameTypeDatagrams = 1;

enum class Command : std::uint8_t {
  nop = 0,
  aprd = 1,
  apwr = 2,
  aprw = 3,
  fprd = 4,
  fpwr = 5,
  fprw = 6,
  brd = 7,
  bwr = 8,
  brw = 9,
  lrd = 10,
  lwr = 11,
  lrw = 12,
  armw = 13,
  frmw = 14,
};
constexpr std::size_t kCommandCount = 15;

// "APRD", "LRW", ...; "cmd(0x1f)" style text is never returned: unknown values are not Commands.
std::string_view to_string(Command command) noexcept;
std::optional<Command> command_from_byte(std::uint8_t value) noexcept;
// Auto-increment (APxx, ARMW), configured-address (FPxx, FRMW), broadcast (Bxx), logical (Lxx).
enum class Addressing : std::uint8_t { none, position, station, broadcast, logical };
Addressing addressing_of(Command command) noexcept;
bool command_reads(Command command) noexcept;   // data flows slave -> master
bool command_writes(Command command) noexcept;  // data flows master -> slave

// Address helpers. Auto-increment addresses are the negated position (slave 0 is 0x0000, slave 1
// is 0xFFFF, ...); each slave increments ADP as the datagram passes and acts where it is zero.
constexpr std::uint32_t physical_address(std::uint16_t adp, std::uint16_t ado) noexcept {
  return static_cast<std::uint32_t>(adp) | (static_cast<std::uint32_t>(ado) << 16);
}
constexpr std::uint16_t position_adp(std::uint16_t position) noexcept {
  return static_cast<std::uint16_t>(0x10000u - position);
}

struct DatagramHeader {
  Command command = Command::nop;
  std::uint8_t index = 0;
  std::uint32_t address = 0;
  std::uint16_t length = 0;  // data bytes, at most kMaxDatagramLength
  bool circulating = false;
  bool more_follows = false;  // set by the encoder; decoded as received
  std::uint16_t irq = 0;

  std::uint16_t adp() const noexcept { return static_cast<std::uint16_t>(address); }
  std::uint16_t ado() const noexcept { return static_cast<std::uint16_t>(address >> 16); }
  friend bool operator==(const DatagramHeader&, const DatagramHeader&) = default;
};

struct DatagramView {
  DatagramHeader header;
  Bytes data;  // header.length bytes, pointing into the decoded buffer
  std::uint16_t wkc = 0;
};

// Why a frame did not decode. Carries numbers instead of text so that decoding never allocates;
// describe() turns it into a message such as
//   "datagram 2 at byte 36: length 40 runs past the end of the frame (14 bytes left)".
enum class DecodeErrc : std::uint8_t {
  truncated_ethernet_header,
  not_ethercat,  // EtherType (after an optional VLAN tag) is not 0x88A4
  truncated_frame_header,
  unsupported_frame_type,  // frame header type is not 1
  frame_length_mismatch,   // header length exceeds the bytes present, or is shorter than the chain
  truncated_datagram_header,
  truncated_datagram,     // datagram data + WKC run past the end
  more_follows_past_end,  // more-follows set on a datagram that ends the frame
  unknown_command,
  empty_frame,  // header length 0 / no datagrams
};
std::string_view to_string(DecodeErrc code) noexcept;

struct DecodeError {
  DecodeErrc code{};
  std::uint16_t datagram = 0;  // 0-based datagram number, where one applies
  std::uint32_t offset = 0;    // byte offset in the decoded buffer where the problem was found
  std::uint32_t expected = 0;  // what the format required (a length, a type, ...)
  std::uint32_t actual = 0;    // what was there
  std::string describe() const;
  Error to_error() const;  // Errc::malformed or Errc::truncated with describe() as message
};

// Validated view of one EtherCAT frame (header + datagram chain). Iterating it re-reads the
// already-validated bytes, so it allocates nothing.
class FrameView {
 public:
  class Iterator {
   public:
    using value_type = DatagramView;
    using difference_type = std::ptrdiff_t;
    Iterator() = default;
    DatagramView operator*() const noexcept;
    Iterator& operator++() noexcept;
    Iterator operator++(int) noexcept {
      auto copy = *this;
      ++*this;
      return copy;
    }
    friend bool operator==(const Iterator& a, const Iterator& b) noexcept {
      return a.offset_ == b.offset_ && a.remaining_ == b.remaining_;
    }

   private:
    friend class FrameView;
    Iterator(Bytes body, std::size_t offset, std::size_t remaining) noexcept
        : body_(body), offset_(offset), remaining_(remaining) {}
    Bytes body_;
    std::size_t offset_ = 0;
    std::size_t remaining_ = 0;
  };

  std::uint16_t header_length() const noexcept { return header_length_; }
  std::size_t datagram_count() const noexcept { return count_; }
  Iterator begin() const noexcept { return Iterator(body_, 0, count_); }
  Iterator end() const noexcept { return Iterator(body_, end_offset_, 0); }
  // The datagram chain (without the 2-byte frame header and without trailing padding).
  Bytes body() const noexcept { return body_; }

 private:
  friend struct FrameDecoder;
  Bytes body_;
  std::uint16_t header_length_ = 0;
  std::size_t count_ = 0;
  std::size_t end_offset_ = 0;
};

// Decodes an EtherCAT frame: 2-byte header followed by the datagram chain. Bytes after the chain
// (Ethernet padding) are ignored. Validates the whole chain before returning.
//
// Offsets in a DecodeError count from the first byte of `ethercat_frame` (the frame header is at
// byte 0, the first datagram at byte 2). Decisions where the format leaves room:
//  - Reserved bits (frame header bit 11, datagram length-field bits 11..13) are ignored, as an ESC
//    ignores them; the encoder always writes them as zero.
//  - A chain that ends before the header length is accepted when every byte up to the header
//    length is zero: some masters count their zero padding in the header length (real captures
//    do this). Any non-zero byte there is a frame_length_mismatch.
//  - A chain that runs past the header length into bytes that are present is a
//    frame_length_mismatch; past the bytes present it is truncated_datagram(_header).
//  - frame_length_mismatch fields: header length beyond the bytes present: offset 0, expected =
//    bytes present after the header, actual = header length. Otherwise expected = header length,
//    actual = chain length (actual > expected: chain too long, offset = that datagram; actual <
//    expected: offset = the first non-zero byte after the chain).
struct FrameDecodeResult {
  std::optional<FrameView> frame;
  DecodeError error;  // meaningful only when !frame
  explicit operator bool() const noexcept { return frame.has_value(); }
};
FrameDecodeResult decode_frame(Bytes ethercat_frame) noexcept;

// Builds an EtherCAT frame (header + datagrams) into a caller-owned buffer; never allocates.
// add() reserves a datagram and returns its data area (already filled from `data` when given,
// zero-filled otherwise) or an empty optional when the datagram does not fit. finish() sets the
// more-follows bits and the frame header and returns the encoded bytes.
class FrameBuilder {
 public:
  explicit FrameBuilder(MutableBytes buffer) noexcept;

  // header.length is the data length; header.more_follows is ignored (the builder sets it on every
  // datagram but the last). `data` is either empty or exactly header.length bytes. Refused (empty
  // optional) when the length exceeds kMaxDatagramLength, the buffer has no room, the frame's
  // datagram bytes would exceed the 11-bit header length, or the command is not a Command.
  std::optional<MutableBytes> add(const DatagramHeader& header, Bytes data = {},
                                  std::uint16_t wkc = 0) noexcept;
  // Bytes a further datagram with `data_length` bytes of data would need.
  static constexpr std::size_t footprint(std::size_t data_length) noexcept {
    return kDatagramOverhead + data_length;
  }
  bool fits(std::size_t data_length) const noexcept;
  std::size_t datagram_count() const noexcept { return count_; }
  std::size_t size() const noexcept { return size_; }  // frame bytes so far, header included
  bool empty() const noexcept { return count_ == 0; }
  // Writes the frame header (length = datagram bytes, type 1) and returns the frame. May be called
  // again after further add()s. Empty span when the buffer cannot hold even the header.
  Bytes finish() noexcept;
  void reset() noexcept;  // forgets all datagrams; the buffer is reused from the start

 private:
  MutableBytes buffer_;
  std::size_t size_ = kFrameHeaderSize;
  std::size_t count_ = 0;
  std::size_t last_datagram_offset_ = 0;
};

// Ethernet II.
using MacAddress = std::array<std::uint8_t, 6>;
constexpr MacAddress kBroadcastMac{0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF};
std::string to_string(const MacAddress& mac);

struct EthernetHeader {
  MacAddress destination{};
  MacAddress source{};
  std::optional<std::uint16_t> vlan_tci;  // present when the frame carried an 802.1Q tag
  std::uint16_t ether_type = kEtherTypeEtherCat;
};

struct EthernetView {
  EthernetHeader header;
  Bytes payload;  // everything after the (VLAN and) EtherType fields, padding included
};

struct EthernetDecodeResult {
  std::optional<EthernetView> frame;
  DecodeError error;
  explicit operator bool() const noexcept { return frame.has_value(); }
};
// Accepts an untagged or 802.1Q-tagged frame whose EtherType is 0x88A4. Otherwise not_ethercat
// with offset = the EtherType field (12, or 16 after a VLAN tag) and actual = the EtherType, so a
// caller can still dissect other protocols (EtherCAT over UDP/IPv4) from there.
EthernetDecodeResult decode_ethernet(Bytes ethernet_frame) noexcept;

// Writes header + payload into `out` and pads to kEthernetMinFrameSize with zeros. Returns the
// frame bytes, or an empty span when `out` is too small. The payload may already sit at its final
// place in `out` (right after the header).
Bytes encode_ethernet(const EthernetHeader& header, Bytes payload, MutableBytes out) noexcept;

// EtherCAT over UDP: the UDP payload is the EtherCAT frame itself (header + datagrams), sent to
// port 0x88A4. These exist so that callers do not need to know that.
inline FrameDecodeResult decode_udp_payload(Bytes udp_payload) noexcept {
  return decode_frame(udp_payload);
}

}  // namespace ecat::wire
