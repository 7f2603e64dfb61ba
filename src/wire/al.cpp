#include <algorithm>
#include <array>

#include <fmt/format.h>

#include <ecat/wire/al.hpp>

namespace ecat::wire {
namespace {

// Texts follow the ETG.1000.6 / ETG.1020 AL status code table.
constexpr std::array kAlStatusCodes{
    AlStatusCodeInfo{0x0000, "No error"},
    AlStatusCodeInfo{0x0001, "Unspecified error"},
    AlStatusCodeInfo{0x0002, "No memory"},
    AlStatusCodeInfo{0x0003, "Invalid device setup"},
    AlStatusCodeInfo{0x0004, "Invalid revision"},
    AlStatusCodeInfo{0x0006, "SII/EEPROM information does not match firmware"},
    AlStatusCodeInfo{0x0007, "Firmware update not successful, old firmware still running"},
    AlStatusCodeInfo{0x000E, "License error"},
    AlStatusCodeInfo{0x0011, "Invalid requested state change"},
    AlStatusCodeInfo{0x0012, "Unknown requested state"},
    AlStatusCodeInfo{0x0013, "Bootstrap not supported"},
    AlStatusCodeInfo{0x0014, "No valid firmware"},
    AlStatusCodeInfo{0x0015, "Invalid mailbox configuration (bootstrap)"},
    AlStatusCodeInfo{0x0016, "Invalid mailbox configuration (PREOP)"},
    AlStatusCodeInfo{0x0017, "Invalid sync manager configuration"},
    AlStatusCodeInfo{0x0018, "No valid inputs available"},
    AlStatusCodeInfo{0x0019, "No valid outputs"},
    AlStatusCodeInfo{0x001A, "Synchronization error"},
    AlStatusCodeInfo{0x001B, "Sync manager watchdog"},
    AlStatusCodeInfo{0x001C, "Invalid sync manager types"},
    AlStatusCodeInfo{0x001D, "Invalid output configuration"},
    AlStatusCodeInfo{0x001E, "Invalid input configuration"},
    AlStatusCodeInfo{0x001F, "Invalid watchdog configuration"},
    AlStatusCodeInfo{0x0020, "Slave needs cold start"},
    AlStatusCodeInfo{0x0021, "Slave needs INIT"},
    AlStatusCodeInfo{0x0022, "Slave needs PREOP"},
    AlStatusCodeInfo{0x0023, "Slave needs SAFEOP"},
    AlStatusCodeInfo{0x0024, "Invalid input mapping"},
    AlStatusCodeInfo{0x0025, "Invalid output mapping"},
    AlStatusCodeInfo{0x0026, "Inconsistent settings"},
    AlStatusCodeInfo{0x0027, "FreeRun not supported"},
    AlStatusCodeInfo{0x0028, "SyncMode not supported"},
    AlStatusCodeInfo{0x0029, "FreeRun needs 3-buffer mode"},
    AlStatusCodeInfo{0x002A, "Background watchdog"},
    AlStatusCodeInfo{0x002B, "No valid inputs and outputs"},
    AlStatusCodeInfo{0x002C, "Fatal sync error"},
    AlStatusCodeInfo{0x002D, "No sync error"},
    AlStatusCodeInfo{0x002E, "Cycle time too small"},
    AlStatusCodeInfo{0x0030, "Invalid DC SYNC configuration"},
    AlStatusCodeInfo{0x0031, "Invalid DC latch configuration"},
    AlStatusCodeInfo{0x0032, "PLL error"},
    AlStatusCodeInfo{0x0033, "DC sync IO error"},
    AlStatusCodeInfo{0x0034, "DC sync timeout error"},
    AlStatusCodeInfo{0x0035, "DC invalid sync cycle time"},
    AlStatusCodeInfo{0x0036, "DC Sync0 cycle time"},
    AlStatusCodeInfo{0x0037, "DC Sync1 cycle time"},
    AlStatusCodeInfo{0x0041, "MBX_AOE"},
    AlStatusCodeInfo{0x0042, "MBX_EOE"},
    AlStatusCodeInfo{0x0043, "MBX_COE"},
    AlStatusCodeInfo{0x0044, "MBX_FOE"},
    AlStatusCodeInfo{0x0045, "MBX_SOE"},
    AlStatusCodeInfo{0x004F, "MBX_VOE"},
    AlStatusCodeInfo{0x0050, "EEPROM no access"},
    AlStatusCodeInfo{0x0051, "EEPROM error"},
    AlStatusCodeInfo{0x0052, "External hardware not ready"},
    AlStatusCodeInfo{0x0060, "Slave restarted locally"},
    AlStatusCodeInfo{0x0061, "Device identification value updated"},
    AlStatusCodeInfo{0x0070, "Detected module ident list does not match"},
    AlStatusCodeInfo{0x0080, "Supply voltage too low"},
    AlStatusCodeInfo{0x0081, "Supply voltage too high"},
    AlStatusCodeInfo{0x0082, "Temperature too low"},
    AlStatusCodeInfo{0x0083, "Temperature too high"},
    AlStatusCodeInfo{0x00F0, "Application controller available"},
};

static_assert(std::is_sorted(kAlStatusCodes.begin(), kAlStatusCodes.end(),
                             [](const AlStatusCodeInfo& a, const AlStatusCodeInfo& b) {
                               return a.code < b.code;
                             }),
              "the AL status code table must stay sorted for binary search");

Error invalid_state(const char* what, std::uint16_t raw) {
  return Error(Errc::malformed, fmt::format("{} 0x{:04x}: state code {} is not an AL state "
                                            "(1 INIT, 2 PREOP, 3 BOOT, 4 SAFEOP, 8 OP)",
                                            what, raw, raw & 0x0Fu));
}

}  // namespace

std::string_view to_string(AlState state) noexcept {
  switch (state) {
    case AlState::init:
      return "INIT";
    case AlState::preop:
      return "PREOP";
    case AlState::bootstrap:
      return "BOOT";
    case AlState::safeop:
      return "SAFEOP";
    case AlState::op:
      return "OP";
  }
  return "UNKNOWN";
}

std::optional<AlState> al_state_from_code(std::uint8_t code) noexcept {
  switch (code) {
    case 1:
      return AlState::init;
    case 2:
      return AlState::preop;
    case 3:
      return AlState::bootstrap;
    case 4:
      return AlState::safeop;
    case 8:
      return AlState::op;
    default:
      return std::nullopt;
  }
}

std::uint16_t AlControl::encode() const noexcept {
  return static_cast<std::uint16_t>(encode_al_control(state, acknowledge_error) |
                                    (request_id ? kAlControlIdRequest : 0));
}

Result<AlControl> AlControl::decode(std::uint16_t raw) {
  const auto state = al_state_from_code(static_cast<std::uint8_t>(raw & 0x0Fu));
  if (!state) return invalid_state("AL control", raw);
  AlControl c;
  c.state = *state;
  c.acknowledge_error = (raw & kAlControlErrorAcknowledge) != 0;
  c.request_id = (raw & kAlControlIdRequest) != 0;
  return c;
}

Result<AlControl> AlControl::decode(Bytes bytes) {
  if (bytes.empty() || bytes.size() > 2) {
    return Error(bytes.empty() ? Errc::truncated : Errc::malformed,
                 fmt::format("AL control (0x0120) needs 1 or 2 bytes, got {}", bytes.size()));
  }
  return decode(bytes.size() == 2 ? load_le16(bytes.data()) : bytes[0]);
}

std::uint16_t AlStatus::encode() const noexcept {
  return static_cast<std::uint16_t>(static_cast<std::uint16_t>(state) |
                                    (error ? kAlStatusError : 0) |
                                    (id_loaded ? kAlStatusIdLoaded : 0));
}

Result<AlStatus> AlStatus::decode(std::uint16_t raw) {
  const auto state = al_state_from_code(static_cast<std::uint8_t>(raw & 0x0Fu));
  if (!state) return invalid_state("AL status", raw);
  AlStatus s;
  s.state = *state;
  s.error = (raw & kAlStatusError) != 0;
  s.id_loaded = (raw & kAlStatusIdLoaded) != 0;
  return s;
}

Result<AlStatus> AlStatus::decode(Bytes bytes) {
  switch (bytes.size()) {
    case 1:
      return decode(std::uint16_t{bytes[0]});
    case 2:
    case 6:
      return decode(load_le16(bytes.data()));
    default:
      return Error(bytes.empty() ? Errc::truncated : Errc::malformed,
                   fmt::format("AL status (0x0130) needs 1, 2 or 6 bytes, got {}", bytes.size()));
  }
}

Result<AlStatusBlock> decode_al_status_block(Bytes bytes) {
  if (bytes.size() != 6) {
    return Error(
        bytes.size() < 6 ? Errc::truncated : Errc::malformed,
        fmt::format("AL status block (0x0130..0x0135) needs 6 bytes, got {}", bytes.size()));
  }
  auto status = AlStatus::decode(load_le16(bytes.data()));
  if (!status) return std::move(status).error();
  return AlStatusBlock{*status, load_le16(&bytes[4])};
}

std::span<const AlStatusCodeInfo> al_status_codes() noexcept {
  return kAlStatusCodes;
}

std::optional<std::string_view> al_status_code_name(std::uint16_t code) noexcept {
  const auto* it =
      std::lower_bound(kAlStatusCodes.begin(), kAlStatusCodes.end(), code,
                       [](const AlStatusCodeInfo& info, std::uint16_t c) { return info.code < c; });
  if (it == kAlStatusCodes.end() || it->code != code) return std::nullopt;
  return it->text;
}

std::string al_status_code_text(std::uint16_t code) {
  if (auto name = al_status_code_name(code)) return std::string(*name);
  if (code >= al_status::kFirstVendorSpecific) {
    return fmt::format("vendor-specific AL status code 0x{:04x}", code);
  }
  return fmt::format("unknown AL status code 0x{:04x}", code);
}

}  // namespace ecat::wire
