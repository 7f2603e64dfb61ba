// The application layer (AL) state machine as the ESC registers show it: AL control (0x0120),
// AL status (0x0130) and the AL status codes (0x0134) of ETG.1000.6 / ETG.1020.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

enum class AlState : std::uint8_t {
  init = 1,
  preop = 2,
  bootstrap = 3,
  safeop = 4,
  op = 8,
};

// "INIT", "PREOP", "BOOT", "SAFEOP", "OP".
std::string_view to_string(AlState state) noexcept;
// The state a 4-bit state code names, or nullopt for any other value.
std::optional<AlState> al_state_from_code(std::uint8_t code) noexcept;

// AL control (0x0120): requested state in bits 3..0, error acknowledge in bit 4, device
// identification request in bit 5.
constexpr std::uint16_t kAlControlErrorAcknowledge = 0x0010;
constexpr std::uint16_t kAlControlIdRequest = 0x0020;

struct AlControl {
  AlState state = AlState::init;
  bool acknowledge_error = false;
  bool request_id = false;

  std::uint16_t encode() const noexcept;
  // Rejects a state code that names no state.
  static Result<AlControl> decode(std::uint16_t raw);
  // Needs 2 bytes (a write to 0x0120 may carry only 1: that is accepted too).
  static Result<AlControl> decode(Bytes bytes);

  bool operator==(const AlControl&) const = default;
};

// The AL control word for requesting `state`, optionally acknowledging a pending error.
constexpr std::uint16_t encode_al_control(AlState state, bool acknowledge_error = false) noexcept {
  return static_cast<std::uint16_t>(static_cast<std::uint16_t>(state) |
                                    (acknowledge_error ? kAlControlErrorAcknowledge : 0));
}

// AL status (0x0130): current state in bits 3..0, error indicator in bit 4, device identification
// loaded in bit 5.
constexpr std::uint16_t kAlStatusError = 0x0010;
constexpr std::uint16_t kAlStatusIdLoaded = 0x0020;

struct AlStatus {
  AlState state = AlState::init;
  bool error = false;      // the slave refused a transition or hit an error: read 0x0134
  bool id_loaded = false;  // device identification value loaded into 0x0134

  std::uint16_t encode() const noexcept;
  // Rejects a state code that names no state ("AL status 0x0015: state code 5 is not a state").
  static Result<AlStatus> decode(std::uint16_t raw);
  // Accepts 1 or 2 bytes (the state byte alone is enough) or 6 bytes (0x0130..0x0135: status,
  // reserved, status code; the code is ignored here, see decode_al_status_block).
  static Result<AlStatus> decode(Bytes bytes);

  bool operator==(const AlStatus&) const = default;
};

// AL status and AL status code read together (6 bytes from 0x0130).
struct AlStatusBlock {
  AlStatus status;
  std::uint16_t code = 0;

  bool operator==(const AlStatusBlock&) const = default;
};
Result<AlStatusBlock> decode_al_status_block(Bytes bytes);

// AL status codes (register 0x0134). Codes 0x8000..0xFFFF are vendor specific.
namespace al_status {
constexpr std::uint16_t kNoError = 0x0000;
constexpr std::uint16_t kUnspecifiedError = 0x0001;
constexpr std::uint16_t kNoMemory = 0x0002;
constexpr std::uint16_t kInvalidDeviceSetup = 0x0003;
constexpr std::uint16_t kInvalidRevision = 0x0004;
constexpr std::uint16_t kSiiFirmwareMismatch = 0x0006;
constexpr std::uint16_t kFirmwareUpdateFailed = 0x0007;
constexpr std::uint16_t kLicenseError = 0x000E;
constexpr std::uint16_t kInvalidRequestedStateChange = 0x0011;
constexpr std::uint16_t kUnknownRequestedState = 0x0012;
constexpr std::uint16_t kBootstrapNotSupported = 0x0013;
constexpr std::uint16_t kNoValidFirmware = 0x0014;
constexpr std::uint16_t kInvalidMailboxConfigurationBootstrap = 0x0015;
constexpr std::uint16_t kInvalidMailboxConfigurationPreop = 0x0016;
constexpr std::uint16_t kInvalidSyncManagerConfiguration = 0x0017;
constexpr std::uint16_t kNoValidInputs = 0x0018;
constexpr std::uint16_t kNoValidOutputs = 0x0019;
constexpr std::uint16_t kSynchronizationError = 0x001A;
constexpr std::uint16_t kSyncManagerWatchdog = 0x001B;
constexpr std::uint16_t kInvalidSyncManagerTypes = 0x001C;
constexpr std::uint16_t kInvalidOutputConfiguration = 0x001D;
constexpr std::uint16_t kInvalidInputConfiguration = 0x001E;
constexpr std::uint16_t kInvalidWatchdogConfiguration = 0x001F;
constexpr std::uint16_t kSlaveNeedsColdStart = 0x0020;
constexpr std::uint16_t kSlaveNeedsInit = 0x0021;
constexpr std::uint16_t kSlaveNeedsPreop = 0x0022;
constexpr std::uint16_t kSlaveNeedsSafeop = 0x0023;
constexpr std::uint16_t kInvalidInputMapping = 0x0024;
constexpr std::uint16_t kInvalidOutputMapping = 0x0025;
constexpr std::uint16_t kInconsistentSettings = 0x0026;
constexpr std::uint16_t kFreeRunNotSupported = 0x0027;
constexpr std::uint16_t kSyncModeNotSupported = 0x0028;
constexpr std::uint16_t kFreeRunNeeds3BufferMode = 0x0029;
constexpr std::uint16_t kBackgroundWatchdog = 0x002A;
constexpr std::uint16_t kNoValidInputsAndOutputs = 0x002B;
constexpr std::uint16_t kFatalSyncError = 0x002C;
constexpr std::uint16_t kNoSyncError = 0x002D;
constexpr std::uint16_t kCycleTimeTooSmall = 0x002E;
constexpr std::uint16_t kInvalidDcSyncConfiguration = 0x0030;
constexpr std::uint16_t kInvalidDcLatchConfiguration = 0x0031;
constexpr std::uint16_t kPllError = 0x0032;
constexpr std::uint16_t kDcSyncIoError = 0x0033;
constexpr std::uint16_t kDcSyncTimeoutError = 0x0034;
constexpr std::uint16_t kDcInvalidSyncCycleTime = 0x0035;
constexpr std::uint16_t kDcSync0CycleTime = 0x0036;
constexpr std::uint16_t kDcSync1CycleTime = 0x0037;
constexpr std::uint16_t kMailboxAoe = 0x0041;
constexpr std::uint16_t kMailboxEoe = 0x0042;
constexpr std::uint16_t kMailboxCoe = 0x0043;
constexpr std::uint16_t kMailboxFoe = 0x0044;
constexpr std::uint16_t kMailboxSoe = 0x0045;
constexpr std::uint16_t kMailboxVoe = 0x004F;
constexpr std::uint16_t kEepromNoAccess = 0x0050;
constexpr std::uint16_t kEepromError = 0x0051;
constexpr std::uint16_t kExternalHardwareNotReady = 0x0052;
constexpr std::uint16_t kSlaveRestartedLocally = 0x0060;
constexpr std::uint16_t kDeviceIdentificationUpdated = 0x0061;
constexpr std::uint16_t kModuleIdentListMismatch = 0x0070;
constexpr std::uint16_t kSupplyVoltageTooLow = 0x0080;
constexpr std::uint16_t kSupplyVoltageTooHigh = 0x0081;
constexpr std::uint16_t kTemperatureTooLow = 0x0082;
constexpr std::uint16_t kTemperatureTooHigh = 0x0083;
constexpr std::uint16_t kApplicationControllerAvailable = 0x00F0;
constexpr std::uint16_t kFirstVendorSpecific = 0x8000;
}  // namespace al_status

struct AlStatusCodeInfo {
  std::uint16_t code;
  std::string_view text;
};

// Every AL status code the ETG documents define, in ascending order.
std::span<const AlStatusCodeInfo> al_status_codes() noexcept;

// The ETG text of a defined code, or nullopt.
std::optional<std::string_view> al_status_code_name(std::uint16_t code) noexcept;

// The ETG text of a defined code; "vendor-specific AL status code 0x8001" for 0x8000..0xFFFF;
// "unknown AL status code 0x0099" for any other value.
std::string al_status_code_text(std::uint16_t code);

}  // namespace ecat::wire
