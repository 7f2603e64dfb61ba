#include <algorithm>
#include <array>
#include <cstring>

#include <fmt/format.h>

#include <ecat/wire/coe.hpp>
#include <ecat/wire/emergency.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {
namespace {

struct CodeText {
  std::uint16_t code;
  std::string_view text;
};

// Individually defined codes (CiA 301 Table 21; 0x861x from CiA 402), ascending.
constexpr std::array<CodeText, 13> kExactCodes{{
    {0x0000, "no error"},
    {0x8110, "CAN overrun (objects lost)"},
    {0x8120, "CAN in error passive mode"},
    {0x8130, "life guard error or heartbeat error"},
    {0x8140, "recovered from bus off"},
    {0x8150, "CAN-ID collision"},
    {0x8210, "PDO not processed due to length error"},
    {0x8220, "PDO length exceeded"},
    {0x8230, "DAM MPDO not processed, destination object not available"},
    {0x8240, "unexpected SYNC data length"},
    {0x8250, "RPDO timeout"},
    {0x8611, "following error"},
    {0x8612, "reference limit"},
}};

// Classes by high byte (xx00..xxFF), ascending.
constexpr std::array<CodeText, 18> kByteClasses{{
    {0x00, "error reset or no error"},
    {0x10, "generic error"},
    {0x21, "current, device input side"},
    {0x22, "current inside the device"},
    {0x23, "current, device output side"},
    {0x31, "mains voltage"},
    {0x32, "voltage inside the device"},
    {0x33, "output voltage"},
    {0x41, "ambient temperature"},
    {0x42, "device temperature"},
    {0x61, "internal software"},
    {0x62, "user software"},
    {0x63, "data set"},
    {0x81, "communication"},
    {0x82, "protocol error"},
    {0x90, "external error"},
    {0xF0, "additional functions"},
    {0xFF, "device specific"},
}};

// Classes by high nibble (x000..xFFF).
constexpr std::array<std::string_view, 16> kNibbleClasses{
    "error reset or no error",
    "generic error",
    "current",
    "voltage",
    "temperature",
    "device hardware",
    "device software",
    "additional modules",
    "monitoring",
    "external error",
    "unknown error code class",
    "unknown error code class",
    "unknown error code class",
    "unknown error code class",
    "unknown error code class",
    "additional functions",
};

template <class Table, class Key>
const CodeText* find(const Table& table, Key key) {
  auto it = std::lower_bound(table.begin(), table.end(), key,
                             [](const CodeText& e, Key k) { return e.code < k; });
  return it != table.end() && it->code == key ? &*it : nullptr;
}

}  // namespace

std::string_view emergency_error_text(std::uint16_t error_code) noexcept {
  if (const auto* exact = find(kExactCodes, error_code)) return exact->text;
  if (const auto* cls = find(kByteClasses, static_cast<std::uint16_t>(error_code >> 8))) {
    return cls->text;
  }
  return kNibbleClasses[error_code >> 12];
}

Result<Emergency> decode_emergency(Bytes coe) {
  constexpr std::string_view what = "CoE emergency";
  detail::FieldReader r(coe, what);
  const std::uint16_t coe_header = r.u16("CoE header");
  Emergency e;
  e.error_code = r.u16("error code");
  e.error_register = r.u8("error register");
  Bytes data = r.bytes("manufacturer data", e.data.size());
  if (!r.ok()) return r.error();
  const auto service = coe_header >> 12;
  if (service != static_cast<unsigned>(CoeService::emergency)) {
    return detail::malformed(
        what, fmt::format("CoE service {} at offset 0 is not emergency (1)", service));
  }
  std::copy(data.begin(), data.end(), e.data.begin());
  return e;
}

Result<void> encode_emergency(const Emergency& emergency, ByteWriter& out) {
  if (out.remaining() < kEmergencySize) {
    return detail::no_room("CoE emergency", kEmergencySize, out.remaining());
  }
  out.u16(static_cast<std::uint16_t>(static_cast<unsigned>(CoeService::emergency) << 12));
  out.u16(emergency.error_code);
  out.u8(emergency.error_register);
  out.bytes(emergency.data);
  return ok();
}

}  // namespace ecat::wire
