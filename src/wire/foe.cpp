#include <type_traits>

#include <fmt/format.h>

#include <ecat/wire/foe.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {

std::string_view to_string(FoeOpcode opcode) noexcept {
  switch (opcode) {
    case FoeOpcode::read_request:
      return "read request";
    case FoeOpcode::write_request:
      return "write request";
    case FoeOpcode::data:
      return "data";
    case FoeOpcode::ack:
      return "ack";
    case FoeOpcode::error:
      return "error";
    case FoeOpcode::busy:
      return "busy";
  }
  return "reserved";
}

std::string_view foe_error_text(std::uint32_t code) noexcept {
  switch (static_cast<FoeErrorCode>(code)) {
    case FoeErrorCode::not_defined:
      return "not defined";
    case FoeErrorCode::not_found:
      return "file not found";
    case FoeErrorCode::access_denied:
      return "access denied";
    case FoeErrorCode::disk_full:
      return "disk full";
    case FoeErrorCode::illegal:
      return "illegal";
    case FoeErrorCode::packet_number_wrong:
      return "packet number wrong";
    case FoeErrorCode::already_exists:
      return "file already exists";
    case FoeErrorCode::no_user:
      return "no user";
    case FoeErrorCode::bootstrap_only:
      return "bootstrap access only";
    case FoeErrorCode::not_in_bootstrap:
      return "not in bootstrap";
    case FoeErrorCode::no_rights:
      return "no access rights";
    case FoeErrorCode::program_error:
      return "program error";
    case FoeErrorCode::checksum_error:
      return "checksum error";
  }
  return "unknown FoE error";
}

FoeOpcode opcode_of(const FoeMessage& message) noexcept {
  return static_cast<FoeOpcode>(message.index() + 1);
}

Result<FoeMessage> decode_foe(Bytes data) {
  detail::FieldReader r(data, "FoE");
  const std::uint8_t opcode = r.u8("opcode");
  (void)r.u8("reserved");
  if (!r.ok()) return r.error();
  switch (static_cast<FoeOpcode>(opcode)) {
    case FoeOpcode::read_request:
    case FoeOpcode::write_request: {
      const std::uint32_t password = r.u32("password");
      std::string name = detail::text_field(r.rest());
      if (!r.ok()) return r.error();
      if (opcode == static_cast<std::uint8_t>(FoeOpcode::read_request)) {
        return FoeMessage{FoeReadRequest{password, std::move(name)}};
      }
      return FoeMessage{FoeWriteRequest{password, std::move(name)}};
    }
    case FoeOpcode::data: {
      FoeData m;
      m.packet_number = r.u32("packet number");
      Bytes payload = r.rest();
      if (!r.ok()) return r.error();
      m.data.assign(payload.begin(), payload.end());
      return FoeMessage{std::move(m)};
    }
    case FoeOpcode::ack: {
      FoeAck m{r.u32("packet number")};
      if (!r.ok()) return r.error();
      return FoeMessage{m};
    }
    case FoeOpcode::error: {
      FoeError m;
      m.code = r.u32("error code");
      m.text = detail::text_field(r.rest());
      if (!r.ok()) return r.error();
      return FoeMessage{std::move(m)};
    }
    case FoeOpcode::busy: {
      FoeBusy m;
      m.done = r.u16("done");
      m.entire = r.u16("entire");
      if (!r.ok()) return r.error();
      return FoeMessage{m};
    }
  }
  return detail::malformed(
      "FoE", fmt::format("opcode {} at offset 0 is not an FoE opcode (1..6)", opcode));
}

Result<std::vector<std::uint8_t>> encode_foe(const FoeMessage& message) {
  std::vector<std::uint8_t> out{static_cast<std::uint8_t>(opcode_of(message)), 0};
  auto body = std::visit(
      [&out](const auto& m) -> Result<void> {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, FoeReadRequest> || std::is_same_v<T, FoeWriteRequest>) {
          if (detail::holds_nul(m.file_name)) {
            return detail::invalid_argument("FoE", "file name holds a NUL character");
          }
          detail::append_u32(out, m.password);
          detail::append(out, detail::as_bytes(m.file_name));
        } else if constexpr (std::is_same_v<T, FoeData>) {
          detail::append_u32(out, m.packet_number);
          detail::append(out, m.data);
        } else if constexpr (std::is_same_v<T, FoeAck>) {
          detail::append_u32(out, m.packet_number);
        } else if constexpr (std::is_same_v<T, FoeError>) {
          if (detail::holds_nul(m.text)) {
            return detail::invalid_argument("FoE", "error text holds a NUL character");
          }
          detail::append_u32(out, m.code);
          detail::append(out, detail::as_bytes(m.text));
        } else {
          static_assert(std::is_same_v<T, FoeBusy>);
          detail::append_u16(out, m.done);
          detail::append_u16(out, m.entire);
        }
        return ok();
      },
      message);
  if (!body) return std::move(body).error();
  if (out.size() > detail::kMaxMailboxData) {
    return detail::invalid_argument(
        "FoE", fmt::format("{} bytes exceed the mailbox length limit of 65535", out.size()));
  }
  return out;
}

}  // namespace ecat::wire
