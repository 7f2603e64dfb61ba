// Servo drive profile over EtherCAT (mailbox type 5, ETG.1000.6 §5.9 / IEC 61800-7-304): reading
// and writing the IDN parameters of SERCOS drives.
//
//   mailbox data: SoE header(4) then data, or the error code(2) when the error flag is set
//     byte 0: opcode[2:0] incomplete[3] error[4] drive number[7:5]
//     byte 1: element flags (which elements of the IDN are read/written)
//     word 1: IDN, or the number of fragments left when incomplete
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kSoeHeaderSize = 4;

enum class SoeOpcode : std::uint8_t {
  read_request = 1,
  read_response = 2,
  write_request = 3,
  write_response = 4,
  notification = 5,
  slave_info = 6,
};

// "read request", ...; "reserved" for other values.
std::string_view to_string(SoeOpcode opcode) noexcept;

// Element flags.
constexpr std::uint8_t kSoeElementDataState = 0x01;
constexpr std::uint8_t kSoeElementName = 0x02;
constexpr std::uint8_t kSoeElementAttribute = 0x04;
constexpr std::uint8_t kSoeElementUnit = 0x08;
constexpr std::uint8_t kSoeElementMinimum = 0x10;
constexpr std::uint8_t kSoeElementMaximum = 0x20;
constexpr std::uint8_t kSoeElementValue = 0x40;
constexpr std::uint8_t kSoeElementDefault = 0x80;

struct SoeHeader {
  SoeOpcode opcode = SoeOpcode::read_request;
  bool incomplete = false;
  bool error = false;
  std::uint8_t drive_number = 0;  // 0..7
  std::uint8_t elements = 0;      // kSoeElement* flags
  std::uint16_t idn = 0;          // the IDN, or fragments left when incomplete

  friend bool operator==(const SoeHeader&, const SoeHeader&) = default;
};

Result<void> encode_soe_header(const SoeHeader& header, ByteWriter& out);
Result<SoeHeader> decode_soe_header(Bytes data);

struct SoeMessage {
  SoeHeader header{};
  std::optional<std::uint16_t> error_code{};  // present exactly when header.error
  std::vector<std::uint8_t> data{};           // the element data (after the error code, if any)

  friend bool operator==(const SoeMessage&, const SoeMessage&) = default;
};

// Decodes the data of a type-5 mailbox.
Result<SoeMessage> decode_soe(Bytes data);
Result<std::vector<std::uint8_t>> encode_soe(const SoeMessage& message);

// "S-0-0001", "P-0-0123", "S-7-4095": S or P (bit 15), parameter set (bits 14..12) and data block
// number (bits 11..0).
std::string format_idn(std::uint16_t idn);

}  // namespace ecat::wire
