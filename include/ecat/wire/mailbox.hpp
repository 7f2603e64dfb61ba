// The EtherCAT mailbox (ETG.1000.6 §5.5): the 6-byte header every mailbox protocol (CoE, EoE, FoE,
// SoE, ...) sits behind, the counter rules, and the mailbox error reply (type 0).
//
// Layout (little-endian):
//   length(2)   bytes of mailbox data after this header
//   address(2)  station address of the source (master -> slave: 0 for the master)
//   byte 4      channel[5:0] | priority[7:6]
//   byte 5      type[3:0] | counter[6:4] | reserved[7]
//   data(length)
// Mailbox SyncManagers have a fixed size, so a mailbox buffer is usually longer than 6 + length;
// the bytes after the data are padding and are ignored.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kMailboxHeaderSize = 6;
constexpr std::uint8_t kMailboxMaxChannel = 0x3F;
constexpr std::uint8_t kMailboxMaxPriority = 3;
constexpr std::uint8_t kMailboxMaxCounter = 7;

// The protocol carried in a mailbox. Values 6..14 are reserved; a decoded header may still hold
// them (the enum's underlying type keeps any 4-bit value).
enum class MailboxType : std::uint8_t {
  error = 0x0,  // mailbox error reply from the slave
  aoe = 0x1,    // ADS over EtherCAT
  eoe = 0x2,    // Ethernet over EtherCAT
  coe = 0x3,    // CANopen over EtherCAT
  foe = 0x4,    // File access over EtherCAT
  soe = 0x5,    // Servo drive profile over EtherCAT
  voe = 0xF,    // vendor specific
};

// "error", "AoE", "EoE", "CoE", "FoE", "SoE", "VoE"; "reserved" for the other values.
std::string_view to_string(MailboxType type) noexcept;

struct MailboxHeader {
  std::uint16_t length = 0;  // bytes of data after the header
  std::uint16_t address = 0;
  std::uint8_t channel = 0;   // 0..63
  std::uint8_t priority = 0;  // 0..3
  MailboxType type = MailboxType::coe;
  std::uint8_t counter = 0;  // 0..7; 0 only before the first exchange (see next_mailbox_counter)

  friend bool operator==(const MailboxHeader&, const MailboxHeader&) = default;
};

// A decoded mailbox: the header and a view of its data (exactly header.length bytes).
struct Mailbox {
  MailboxHeader header{};
  Bytes data{};
};

// The counter for the next request: 1..7, wrapping from 7 back to 1. 0 is not part of the cycle
// (a slave treats 0 as "counter not used"), so next_mailbox_counter(0) is 1.
constexpr std::uint8_t next_mailbox_counter(std::uint8_t counter) noexcept {
  return static_cast<std::uint8_t>((counter & 0x07) % kMailboxMaxCounter + 1);
}

// Encodes the 6 header bytes. Fails (invalid_argument) when channel, priority, counter or type do
// not fit their bit fields, or when the writer has no room.
Result<void> encode_mailbox_header(const MailboxHeader& header, ByteWriter& out);
// Decodes the 6 header bytes at the start of `bytes` (no check of the length field).
Result<MailboxHeader> decode_mailbox_header(Bytes bytes);
// Decodes a mailbox buffer: the header, then a data view of header.length bytes, which must fit in
// the buffer. Bytes after the data (SyncManager padding) are ignored.
Result<Mailbox> decode_mailbox(Bytes buffer);

// Writes header (with length set to data.size()) and data to the start of `out` and zero-fills the
// rest, because a mailbox SyncManager is written whole. Returns 6 + data.size().
Result<std::size_t> encode_mailbox(MailboxHeader header, Bytes data, MutableBytes out);
// Same, into a new vector of exactly 6 + data.size() bytes.
Result<std::vector<std::uint8_t>> encode_mailbox(MailboxHeader header, Bytes data);

// ---------------------------------------------------------------------------------------------
// Mailbox error reply (mailbox type 0): service type u16 (always 0x0001) then a detail code u16.

constexpr std::uint16_t kMailboxErrorService = 0x0001;
constexpr std::size_t kMailboxErrorReplySize = 4;

enum class MailboxErrorCode : std::uint16_t {
  syntax = 0x01,                 // the 6-byte mailbox header is syntactically wrong
  unsupported_protocol = 0x02,   // the mailbox type is not supported
  invalid_channel = 0x03,        // the channel field holds a wrong value
  service_not_supported = 0x04,  // the protocol service is not supported
  invalid_header = 0x05,         // the protocol header (after the mailbox header) is wrong
  size_too_short = 0x06,         // the mailbox data is too short
  no_more_memory = 0x07,         // the slave lacks resources to process the mailbox
  invalid_size = 0x08,           // the data length is inconsistent
  service_in_work = 0x09,        // the service is already in use
};

struct MailboxErrorReply {
  std::uint16_t detail = 0;  // a MailboxErrorCode value (kept raw: slaves may send others)

  friend bool operator==(const MailboxErrorReply&, const MailboxErrorReply&) = default;
};

// "invalid header", "size too short", ...; "unknown mailbox error 0x00nn" for other codes.
std::string mailbox_error_text(std::uint16_t detail);

// Decodes the data of a type-0 mailbox. The service type must be 0x0001.
Result<MailboxErrorReply> decode_mailbox_error(Bytes data);
Result<void> encode_mailbox_error(const MailboxErrorReply& reply, ByteWriter& out);

}  // namespace ecat::wire
