// CoE emergency messages (CoE service 1; CiA 301 EMCY): an error code, the error register
// (object 0x1001) and 5 manufacturer-specific bytes.
//
//   mailbox data: CoE header(2) error code(2) error register(1) data(5)
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

constexpr std::size_t kEmergencySize = 10;  // mailbox data, CoE header included

struct Emergency {
  std::uint16_t error_code = 0;
  std::uint8_t error_register = 0;
  std::array<std::uint8_t, 5> data{};

  friend bool operator==(const Emergency&, const Emergency&) = default;
};

// Decodes mailbox data whose CoE service is "emergency".
Result<Emergency> decode_emergency(Bytes coe);
// Writes the 10 bytes of mailbox data (CoE header included).
Result<void> encode_emergency(const Emergency& emergency, ByteWriter& out);

// The CiA 301 text for an error code: the exact code when it is a well-known one ("following
// error" for 0x8611, "CAN overrun (objects lost)" for 0x8110), otherwise its class ("current,
// device output side" for 0x23xx, "monitoring" for 0x8xxx, "device specific" for 0xFFxx).
// "unknown error code class" when the code is in no CiA 301 class (0xA000..0xEFFF).
std::string_view emergency_error_text(std::uint16_t error_code) noexcept;

}  // namespace ecat::wire
