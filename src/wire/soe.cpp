#include <fmt/format.h>

#include <ecat/wire/soe.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {
namespace {

constexpr std::uint8_t kIncomplete = 0x08;
constexpr std::uint8_t kError = 0x10;

}  // namespace

std::string_view to_string(SoeOpcode opcode) noexcept {
  switch (opcode) {
    case SoeOpcode::read_request:
      return "read request";
    case SoeOpcode::read_response:
      return "read response";
    case SoeOpcode::write_request:
      return "write request";
    case SoeOpcode::write_response:
      return "write response";
    case SoeOpcode::notification:
      return "notification";
    case SoeOpcode::slave_info:
      return "slave info";
  }
  return "reserved";
}

Result<void> encode_soe_header(const SoeHeader& h, ByteWriter& out) {
  const auto opcode = static_cast<unsigned>(h.opcode);
  if (opcode > 0x07 || h.drive_number > 0x07) {
    return detail::invalid_argument(
        "SoE header",
        fmt::format("opcode {} or drive number {} exceeds 7", opcode, h.drive_number));
  }
  if (out.remaining() < kSoeHeaderSize) {
    return detail::no_room("SoE header", kSoeHeaderSize, out.remaining());
  }
  std::uint8_t control = static_cast<std::uint8_t>(opcode | (h.drive_number << 5));
  if (h.incomplete) control |= kIncomplete;
  if (h.error) control |= kError;
  out.u8(control);
  out.u8(h.elements);
  out.u16(h.idn);
  return ok();
}

Result<SoeHeader> decode_soe_header(Bytes data) {
  detail::FieldReader r(data, "SoE header");
  const std::uint8_t control = r.u8("control");
  SoeHeader h;
  h.elements = r.u8("elements");
  h.idn = r.u16("IDN");
  if (!r.ok()) return r.error();
  h.opcode = static_cast<SoeOpcode>(control & 0x07);
  h.incomplete = (control & kIncomplete) != 0;
  h.error = (control & kError) != 0;
  h.drive_number = static_cast<std::uint8_t>(control >> 5);
  return h;
}

Result<SoeMessage> decode_soe(Bytes data) {
  auto header = decode_soe_header(data);
  if (!header) return std::move(header).error();
  detail::FieldReader r(data, "SoE");
  (void)r.bytes("SoE header", kSoeHeaderSize);
  SoeMessage m;
  m.header = *header;
  if (header->error) m.error_code = r.u16("error code");
  Bytes rest = r.rest();
  if (!r.ok()) return r.error();
  m.data.assign(rest.begin(), rest.end());
  return m;
}

Result<std::vector<std::uint8_t>> encode_soe(const SoeMessage& message) {
  if (message.header.error != message.error_code.has_value()) {
    return detail::invalid_argument(
        "SoE", "an error code must be present exactly when the error flag is set");
  }
  std::vector<std::uint8_t> out(kSoeHeaderSize);
  ByteWriter w(MutableBytes{out});
  if (auto r = encode_soe_header(message.header, w); !r) return std::move(r).error();
  if (message.error_code) detail::append_u16(out, *message.error_code);
  detail::append(out, message.data);
  if (out.size() > detail::kMaxMailboxData) {
    return detail::invalid_argument(
        "SoE", fmt::format("{} bytes exceed the mailbox length limit of 65535", out.size()));
  }
  return out;
}

std::string format_idn(std::uint16_t idn) {
  return fmt::format("{}-{}-{:04}", (idn & 0x8000) ? 'P' : 'S', (idn >> 12) & 0x07, idn & 0x0FFF);
}

}  // namespace ecat::wire
