// File access over EtherCAT (mailbox type 4, ETG.1000.6 §5.8): a TFTP-like file transfer, used
// above all for firmware updates in BOOTSTRAP.
//
//   mailbox data: opcode(1) reserved(1) then by opcode
//     1 read request, 2 write request: password(4) file name(rest)
//     3 data:                         packet number(4) data(rest)
//     4 ack:                          packet number(4)
//     5 error:                        error code(4) error text(rest, optional)
//     6 busy:                         done(2) entire(2)
// Names and texts are not NUL-terminated on the wire; a decoder stops at a NUL if one is there.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kFoeHeaderSize = 6;

enum class FoeOpcode : std::uint8_t {
  read_request = 1,
  write_request = 2,
  data = 3,
  ack = 4,
  error = 5,
  busy = 6,
};

// "read request", "write request", "data", "ack", "error", "busy"; "reserved" for other values.
std::string_view to_string(FoeOpcode opcode) noexcept;

enum class FoeErrorCode : std::uint32_t {
  not_defined = 0x8000,
  not_found = 0x8001,
  access_denied = 0x8002,
  disk_full = 0x8003,
  illegal = 0x8004,
  packet_number_wrong = 0x8005,
  already_exists = 0x8006,
  no_user = 0x8007,
  bootstrap_only = 0x8008,
  not_in_bootstrap = 0x8009,
  no_rights = 0x800A,
  program_error = 0x800B,
  checksum_error = 0x800C,
};

// "file not found", ...; "unknown FoE error" for codes outside the table.
std::string_view foe_error_text(std::uint32_t code) noexcept;

struct FoeReadRequest {
  std::uint32_t password = 0;
  std::string file_name{};

  friend bool operator==(const FoeReadRequest&, const FoeReadRequest&) = default;
};

struct FoeWriteRequest {
  std::uint32_t password = 0;
  std::string file_name{};

  friend bool operator==(const FoeWriteRequest&, const FoeWriteRequest&) = default;
};

struct FoeData {
  std::uint32_t packet_number = 0;   // 1 for the first packet
  std::vector<std::uint8_t> data{};  // a packet shorter than the mailbox allows ends the file

  friend bool operator==(const FoeData&, const FoeData&) = default;
};

struct FoeAck {
  std::uint32_t packet_number = 0;

  friend bool operator==(const FoeAck&, const FoeAck&) = default;
};

struct FoeError {
  std::uint32_t code = 0;  // a FoeErrorCode value
  std::string text{};

  friend bool operator==(const FoeError&, const FoeError&) = default;
};

// The slave is not ready for the next packet yet; done/entire tell its progress.
struct FoeBusy {
  std::uint16_t done = 0;
  std::uint16_t entire = 0;

  friend bool operator==(const FoeBusy&, const FoeBusy&) = default;
};

using FoeMessage =
    std::variant<FoeReadRequest, FoeWriteRequest, FoeData, FoeAck, FoeError, FoeBusy>;

FoeOpcode opcode_of(const FoeMessage& message) noexcept;

// Decodes the data of a type-4 mailbox.
Result<FoeMessage> decode_foe(Bytes data);
// The mailbox data of a message. Fails (invalid_argument) when a name or text holds a NUL or the
// message exceeds 65535 bytes.
Result<std::vector<std::uint8_t>> encode_foe(const FoeMessage& message);

}  // namespace ecat::wire
