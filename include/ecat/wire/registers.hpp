// The ESC (EtherCAT slave controller) register map and typed views of the registers a master or
// a simulated ESC works with. Addresses and bit layouts follow ETG.1000.4 and the Beckhoff ESC
// datasheet, section II (register description). Pure definitions: no I/O.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::wire {

namespace reg {

// ESC information
constexpr std::uint16_t kType = 0x0000;              // 1 byte
constexpr std::uint16_t kRevision = 0x0001;          // 1 byte
constexpr std::uint16_t kBuild = 0x0002;             // 2 bytes
constexpr std::uint16_t kFmmuCount = 0x0004;         // 1 byte: FMMUs supported
constexpr std::uint16_t kSyncManagerCount = 0x0005;  // 1 byte: SyncManagers supported
constexpr std::uint16_t kRamSize = 0x0006;           // 1 byte: process RAM in KiB
constexpr std::uint16_t kPortDescriptor = 0x0007;    // 1 byte: 2 bits per port
constexpr std::uint16_t kFeatures = 0x0008;          // 2 bytes: ESC features supported
constexpr std::size_t kEscInformationSize = 10;      // 0x0000..0x0009

// Station address
constexpr std::uint16_t kStationAddress = 0x0010;  // 2 bytes: configured station address
constexpr std::uint16_t kStationAlias = 0x0012;    // 2 bytes: configured station alias

// Write protection
constexpr std::uint16_t kWriteRegisterEnable = 0x0020;
constexpr std::uint16_t kWriteRegisterProtection = 0x0021;
constexpr std::uint16_t kEscWriteEnable = 0x0030;
constexpr std::uint16_t kEscWriteProtection = 0x0031;

// ESC reset
constexpr std::uint16_t kEscResetEcat = 0x0040;
constexpr std::uint16_t kEscResetPdi = 0x0041;

// Data link layer
constexpr std::uint16_t kDlControl = 0x0100;       // 4 bytes
constexpr std::uint16_t kDlPortControl = 0x0101;   // 1 byte: loop control of ports 0..3
constexpr std::uint16_t kDlAliasControl = 0x0103;  // 1 byte: bit 0 enables the station alias
constexpr std::uint16_t kPhysicalReadWriteOffset = 0x0108;  // 2 bytes
constexpr std::uint16_t kDlStatus = 0x0110;                 // 2 bytes

// Application layer
constexpr std::uint16_t kAlControl = 0x0120;     // 2 bytes
constexpr std::uint16_t kAlStatus = 0x0130;      // 2 bytes
constexpr std::uint16_t kAlStatusCode = 0x0134;  // 2 bytes
constexpr std::uint16_t kRunLedOverride = 0x0138;
constexpr std::uint16_t kErrorLedOverride = 0x0139;

// Process data interface
constexpr std::uint16_t kPdiControl = 0x0140;                 // 1 byte
constexpr std::uint16_t kEscConfiguration = 0x0141;           // 1 byte
constexpr std::uint16_t kPdiInformation = 0x014E;             // 2 bytes
constexpr std::uint16_t kPdiConfiguration = 0x0150;           // 1 byte
constexpr std::uint16_t kSyncLatchPdiConfiguration = 0x0151;  // 1 byte
constexpr std::uint16_t kExtendedPdiConfiguration = 0x0152;   // 2 bytes

// Interrupts
constexpr std::uint16_t kEcatEventMask = 0x0200;     // 2 bytes
constexpr std::uint16_t kAlEventMask = 0x0204;       // 4 bytes (PDI AL event mask)
constexpr std::uint16_t kEcatEventRequest = 0x0210;  // 2 bytes
constexpr std::uint16_t kAlEventRequest = 0x0220;    // 4 bytes

// Error counters
constexpr std::uint16_t kRxErrorCounter = 0x0300;    // 8 bytes: per port invalid frame + RX error
constexpr std::uint16_t kForwardedRxError = 0x0308;  // 4 bytes: one byte per port
constexpr std::uint16_t kProcessingUnitError = 0x030C;  // 1 byte
constexpr std::uint16_t kPdiError = 0x030D;             // 1 byte
constexpr std::uint16_t kPdiErrorCode = 0x030E;         // 1 byte
constexpr std::uint16_t kLostLink = 0x0310;             // 4 bytes: one byte per port
constexpr std::size_t kRxErrorCounterSize = 8;

// Watchdogs
constexpr std::uint16_t kWatchdogDivider = 0x0400;             // 2 bytes
constexpr std::uint16_t kWatchdogTimePdi = 0x0410;             // 2 bytes
constexpr std::uint16_t kWatchdogTimeProcessData = 0x0420;     // 2 bytes
constexpr std::uint16_t kWatchdogStatus = 0x0440;              // 2 bytes: bit 0 process data
constexpr std::uint16_t kWatchdogCounterProcessData = 0x0442;  // 1 byte
constexpr std::uint16_t kWatchdogCounterPdi = 0x0443;          // 1 byte

// SII EEPROM interface
constexpr std::uint16_t kSiiAccess = 0x0500;     // 1 byte: EEPROM configuration (ECAT/PDI)
constexpr std::uint16_t kSiiPdiAccess = 0x0501;  // 1 byte: EEPROM PDI access state
constexpr std::uint16_t kSiiControl = 0x0502;    // 2 bytes: control/status
constexpr std::uint16_t kSiiAddress = 0x0504;    // 4 bytes: word address
constexpr std::uint16_t kSiiData = 0x0508;       // 4 or 8 bytes (control bit 6)

// MII management interface
constexpr std::uint16_t kMiiControl = 0x0510;        // 2 bytes: control/status
constexpr std::uint16_t kMiiPhyAddress = 0x0512;     // 1 byte
constexpr std::uint16_t kMiiPhyRegister = 0x0513;    // 1 byte
constexpr std::uint16_t kMiiPhyData = 0x0514;        // 2 bytes
constexpr std::uint16_t kMiiEcatAccess = 0x0516;     // 1 byte
constexpr std::uint16_t kMiiPdiAccess = 0x0517;      // 1 byte
constexpr std::uint16_t kMiiPhyPortStatus = 0x0518;  // 4 bytes: one byte per port

// FMMUs and SyncManagers
constexpr std::uint16_t kFmmuBase = 0x0600;
constexpr std::size_t kFmmuSize = 16;
constexpr std::size_t kMaxFmmus = 16;
constexpr std::uint16_t kSyncManagerBase = 0x0800;
constexpr std::size_t kSyncManagerSize = 8;
constexpr std::size_t kMaxSyncManagers = 16;

// Offsets inside one SyncManager's 8 bytes.
constexpr std::uint16_t kSyncManagerStatusOffset = 5;
constexpr std::uint16_t kSyncManagerActivateOffset = 6;
constexpr std::uint16_t kSyncManagerPdiControlOffset = 7;

// Distributed clocks: receive times and system time
constexpr std::uint16_t kDcReceiveTimePort0 = 0x0900;      // 4 bytes each, ports 0..3 (+4 per port)
constexpr std::uint16_t kDcSystemTime = 0x0910;            // 8 bytes (4 on 32-bit DC)
constexpr std::uint16_t kDcReceiveTimeEpu = 0x0918;        // 8 bytes: receive time of the EPU
constexpr std::uint16_t kDcSystemTimeOffset = 0x0920;      // 8 bytes
constexpr std::uint16_t kDcSystemTimeDelay = 0x0928;       // 4 bytes
constexpr std::uint16_t kDcSystemTimeDifference = 0x092C;  // 4 bytes: bit 31 sign, 30..0 |ns|
constexpr std::uint16_t kDcSpeedCounterStart = 0x0930;     // 2 bytes
constexpr std::uint16_t kDcSpeedCounterDiff = 0x0932;      // 2 bytes
constexpr std::uint16_t kDcSystemTimeFilterDepth = 0x0934;    // 1 byte
constexpr std::uint16_t kDcSpeedCounterFilterDepth = 0x0935;  // 1 byte
constexpr std::uint16_t kDcReceiveTimeLatchMode = 0x0936;     // 1 byte

// Distributed clocks: cyclic unit (SYNC0/SYNC1)
constexpr std::uint16_t kDcCyclicUnitControl = 0x0980;  // 1 byte (AssignActivate low byte)
constexpr std::uint16_t kDcActivation = 0x0981;         // 1 byte
constexpr std::uint16_t kDcPulseLength = 0x0982;        // 2 bytes, in 10 ns units
constexpr std::uint16_t kDcActivationStatus = 0x0984;   // 1 byte
constexpr std::uint16_t kDcSync0Status = 0x098E;        // 1 byte
constexpr std::uint16_t kDcSync1Status = 0x098F;        // 1 byte
constexpr std::uint16_t kDcStartTime = 0x0990;          // 8 bytes: start time / next SYNC0 pulse
constexpr std::uint16_t kDcNextSync1 = 0x0998;          // 8 bytes
constexpr std::uint16_t kDcSync0CycleTime = 0x09A0;     // 4 bytes
constexpr std::uint16_t kDcSync1CycleTime = 0x09A4;     // 4 bytes

// Distributed clocks: latch unit
constexpr std::uint16_t kDcLatch0Control = 0x09A8;       // 1 byte
constexpr std::uint16_t kDcLatch1Control = 0x09A9;       // 1 byte
constexpr std::uint16_t kDcLatch0Status = 0x09AE;        // 1 byte
constexpr std::uint16_t kDcLatch1Status = 0x09AF;        // 1 byte
constexpr std::uint16_t kDcLatch0PositiveEdge = 0x09B0;  // 8 bytes
constexpr std::uint16_t kDcLatch0NegativeEdge = 0x09B8;  // 8 bytes
constexpr std::uint16_t kDcLatch1PositiveEdge = 0x09C0;  // 8 bytes
constexpr std::uint16_t kDcLatch1NegativeEdge = 0x09C8;  // 8 bytes

// Distributed clocks: SyncManager event times
constexpr std::uint16_t kDcEcatBufferChangeEventTime = 0x09F0;  // 4 bytes
constexpr std::uint16_t kDcPdiBufferStartEventTime = 0x09F8;    // 4 bytes
constexpr std::uint16_t kDcPdiBufferChangeEventTime = 0x09FC;   // 4 bytes

// ESC specific
constexpr std::uint16_t kProductId = 0x0E00;  // 8 bytes
constexpr std::uint16_t kVendorId = 0x0E08;   // 8 bytes

// Digital I/O
constexpr std::uint16_t kDigitalIoOutputData = 0x0F00;    // 4 bytes
constexpr std::uint16_t kGeneralPurposeOutputs = 0x0F10;  // 8 bytes
constexpr std::uint16_t kGeneralPurposeInputs = 0x0F18;   // 8 bytes
constexpr std::uint16_t kUserRam = 0x0F80;                // 128 bytes

// Process data RAM
constexpr std::uint16_t kProcessRam = 0x1000;

// Register address of FMMU `index` (0..15), of SyncManager `index` (0..15) and of the receive
// time of `port` (0..3). Indices out of range are a caller bug; they wrap into the block.
constexpr std::uint16_t fmmu(std::size_t index) noexcept {
  return static_cast<std::uint16_t>(kFmmuBase + kFmmuSize * (index % kMaxFmmus));
}
constexpr std::uint16_t sync_manager(std::size_t index) noexcept {
  return static_cast<std::uint16_t>(kSyncManagerBase +
                                    kSyncManagerSize * (index % kMaxSyncManagers));
}
constexpr std::uint16_t dc_receive_time(std::size_t port) noexcept {
  return static_cast<std::uint16_t>(kDcReceiveTimePort0 + 4 * (port % 4));
}

}  // namespace reg

// Bits of AL event request/mask (0x0220 / 0x0204) and ECAT event request/mask (0x0210 / 0x0200).
namespace al_event {
constexpr std::uint32_t kAlControl = 0x0001;
constexpr std::uint32_t kDcLatch = 0x0002;
constexpr std::uint32_t kSync0 = 0x0004;
constexpr std::uint32_t kSync1 = 0x0008;
constexpr std::uint32_t kSyncManagerChanged = 0x0010;
constexpr std::uint32_t kEepromCommandPending = 0x0020;
constexpr std::uint32_t kWatchdogProcessData = 0x0040;
constexpr std::uint32_t kSyncManager0 = 0x0100;  // SyncManager i is bit 8 + i
}  // namespace al_event

namespace ecat_event {
constexpr std::uint16_t kDcLatch = 0x0001;
constexpr std::uint16_t kDlStatusChange = 0x0004;
constexpr std::uint16_t kAlStatusChange = 0x0008;
constexpr std::uint16_t kSyncManager0 = 0x0010;  // SyncManager i is bit 4 + i (0..7)
}  // namespace ecat_event

// DC activation register (0x0981).
namespace dc_activation {
constexpr std::uint8_t kCyclicOperation = 0x01;
constexpr std::uint8_t kSync0 = 0x02;
constexpr std::uint8_t kSync1 = 0x04;
constexpr std::uint8_t kAutoActivation = 0x08;
constexpr std::uint8_t kStartTimeExtension = 0x10;
constexpr std::uint8_t kStartTimePlausibilityCheck = 0x20;
constexpr std::uint8_t kNearFuture = 0x40;
constexpr std::uint8_t kDebugPulse = 0x80;
}  // namespace dc_activation

// DC latch control (0x09A8/0x09A9) and latch status (0x09AE/0x09AF).
namespace dc_latch {
constexpr std::uint8_t kControlPositiveSingle = 0x01;  // 0: continuous, 1: single event
constexpr std::uint8_t kControlNegativeSingle = 0x02;
constexpr std::uint8_t kStatusPositiveEvent = 0x01;
constexpr std::uint8_t kStatusNegativeEvent = 0x02;
constexpr std::uint8_t kStatusPinState = 0x04;
}  // namespace dc_latch

// The signed form of the system time difference register (0x092C): bit 31 is the sign
// (1: local copy smaller than the received time), bits 30..0 the magnitude in ns.
constexpr std::int32_t decode_system_time_difference(std::uint32_t raw) noexcept {
  const auto magnitude = static_cast<std::int32_t>(raw & 0x7FFFFFFFu);
  return (raw & 0x80000000u) != 0 ? -magnitude : magnitude;
}
constexpr std::uint32_t encode_system_time_difference(std::int32_t ns) noexcept {
  // Magnitudes beyond 31 bits saturate; the ESC cannot express them either.
  const std::int64_t wide = ns;
  const std::uint64_t magnitude = static_cast<std::uint64_t>(wide < 0 ? -wide : wide);
  const auto clipped =
      static_cast<std::uint32_t>(magnitude > 0x7FFFFFFFu ? 0x7FFFFFFFu : magnitude);
  return ns < 0 ? (clipped | 0x80000000u) : clipped;
}

// ---------------------------------------------------------------------------------------------
// FMMU (16 bytes at 0x0600 + 16 i)

enum class FmmuType : std::uint8_t {
  unused = 0,
  read = 1,   // ECAT read access: inputs (slave -> master)
  write = 2,  // ECAT write access: outputs (master -> slave)
  read_write = 3,
};

struct FmmuConfig {
  static constexpr std::size_t kSize = reg::kFmmuSize;

  std::uint32_t logical_start = 0;
  std::uint16_t length = 0;  // bytes spanned in the logical address space
  std::uint8_t logical_start_bit = 0;
  std::uint8_t logical_stop_bit = 7;
  std::uint16_t physical_start = 0;
  std::uint8_t physical_start_bit = 0;
  FmmuType type = FmmuType::unused;
  bool active = false;

  std::array<std::uint8_t, kSize> encode() const noexcept;
  // Writes the 16 bytes at the start of `out`; fails when `out` is shorter.
  Result<void> encode(MutableBytes out) const;
  // Needs exactly 16 bytes. Bit numbers above 7 and reserved bits are rejected.
  static Result<FmmuConfig> decode(Bytes bytes);

  bool operator==(const FmmuConfig&) const = default;
};

// ---------------------------------------------------------------------------------------------
// SyncManager (8 bytes at 0x0800 + 8 i)

enum class SmMode : std::uint8_t {
  buffered = 0,  // 3-buffer mode (process data)
  mailbox = 2,   // single-buffer handshake (mailbox)
};

enum class SmDirection : std::uint8_t {
  read = 0,   // ECAT reads, PDI writes (inputs, mailbox in)
  write = 1,  // ECAT writes, PDI reads (outputs, mailbox out)
};

// Control byte (offset 4).
struct SmControl {
  SmMode mode = SmMode::buffered;
  SmDirection direction = SmDirection::read;
  bool ecat_event = false;  // interrupt in the ECAT event request register
  bool pdi_event = false;   // interrupt in the AL event request register
  bool watchdog = false;    // watchdog trigger enable

  std::uint8_t encode() const noexcept;
  // Rejects the reserved operation modes (1, 3) and directions (2, 3).
  static Result<SmControl> decode(std::uint8_t raw);

  bool operator==(const SmControl&) const = default;
};

// Status byte (offset 5); written by the ESC, read-only for the master.
struct SmStatus {
  bool interrupt_write = false;   // buffer completely written
  bool interrupt_read = false;    // buffer completely read
  bool mailbox_full = false;      // mailbox mode: the single buffer holds unread data
  std::uint8_t buffer_state = 0;  // 3-buffer mode: last written buffer 0..2, 3 = none written
  bool read_buffer_open = false;
  bool write_buffer_open = false;

  std::uint8_t encode() const noexcept;
  static SmStatus decode(std::uint8_t raw) noexcept;

  bool operator==(const SmStatus&) const = default;
};

// Activate byte (offset 6).
struct SmActivate {
  bool enable = false;
  bool repeat_request = false;
  bool latch_event_ecat = false;  // DC latch on ECAT buffer change
  bool latch_event_pdi = false;   // DC latch on PDI buffer change

  std::uint8_t encode() const noexcept;
  static SmActivate decode(std::uint8_t raw) noexcept;

  bool operator==(const SmActivate&) const = default;
};

// PDI control byte (offset 7); written by the PDI.
struct SmPdiControl {
  bool deactivate = false;
  bool repeat_ack = false;

  std::uint8_t encode() const noexcept;
  static SmPdiControl decode(std::uint8_t raw) noexcept;

  bool operator==(const SmPdiControl&) const = default;
};

struct SyncManagerConfig {
  static constexpr std::size_t kSize = reg::kSyncManagerSize;

  std::uint16_t physical_start = 0;
  std::uint16_t length = 0;
  SmControl control;
  SmStatus status;
  SmActivate activate;
  SmPdiControl pdi_control;

  std::array<std::uint8_t, kSize> encode() const noexcept;
  Result<void> encode(MutableBytes out) const;
  // Needs exactly 8 bytes; fails on a reserved mode or direction in the control byte.
  static Result<SyncManagerConfig> decode(Bytes bytes);

  bool operator==(const SyncManagerConfig&) const = default;
};

// The control bytes masters conventionally use.
constexpr SmControl kMailboxOutControl{SmMode::mailbox, SmDirection::write, false, true, false};
constexpr SmControl kMailboxInControl{SmMode::mailbox, SmDirection::read, false, true, false};
constexpr SmControl kOutputsControl{SmMode::buffered, SmDirection::write, false, true, true};
constexpr SmControl kInputsControl{SmMode::buffered, SmDirection::read, false, true, false};

// ---------------------------------------------------------------------------------------------
// Process-data watchdog (0x0400 divider, 0x0420 time; ESC datasheet section II): one tick is
// (divider + 2) x 40 ns, the watchdog time is `ticks` ticks, 0 ticks = watchdog off. After
// power-up divider 2498 (100 us ticks) and 1000 ticks (100 ms).

struct ProcessDataWatchdog {
  static constexpr std::uint16_t kDefaultDivider = 2498;
  static constexpr std::uint16_t kDefaultTicks = 1000;
  std::uint16_t divider = kDefaultDivider;
  std::uint16_t ticks = kDefaultTicks;

  std::chrono::nanoseconds time() const noexcept {
    return std::chrono::nanoseconds(std::int64_t{ticks} * (std::int64_t{divider} + 2) * 40);
  }
  bool off() const noexcept { return ticks == 0; }
  // The registers for a watchdog of at least `time` (0 = off): the default 100 us tick while
  // 65535 ticks reach, else the finest coarser tick that does. Errc::out_of_range when negative
  // or beyond what the registers hold (kMaxTime).
  static Result<ProcessDataWatchdog> for_time(std::chrono::nanoseconds time);
  static constexpr std::chrono::nanoseconds kMaxTime{std::int64_t{65535} * (65535 + 2) * 40};

  bool operator==(const ProcessDataWatchdog&) const = default;
};

// ---------------------------------------------------------------------------------------------
// DL status (0x0110, 2 bytes)

struct DlPortStatus {
  bool physical_link = false;  // bit 4 + port
  bool loop_closed = false;    // bit 8 + 2 port
  bool communication = false;  // bit 9 + 2 port: stable communication established

  bool operator==(const DlPortStatus&) const = default;
};

struct DlStatus {
  bool pdi_operational = false;          // bit 0: EEPROM loaded, PDI operational
  bool pdi_watchdog_ok = false;          // bit 1: 1 = reloaded, 0 = expired
  bool enhanced_link_detection = false;  // bit 2
  std::array<DlPortStatus, 4> ports{};

  std::uint16_t encode() const noexcept;
  static DlStatus decode(std::uint16_t raw) noexcept;
  // Needs exactly 2 bytes.
  static Result<DlStatus> decode(Bytes bytes);

  bool operator==(const DlStatus&) const = default;
};

// ---------------------------------------------------------------------------------------------
// ESC features supported (0x0008, 2 bytes)

struct EscFeatures {
  bool fmmu_byte_oriented = false;            // bit 0: 1 = FMMUs cannot map single bits
  bool dc_supported = false;                  // bit 2
  bool dc_64bit = false;                      // bit 3: 64-bit system time (else 32-bit)
  bool low_jitter_ebus = false;               // bit 4
  bool enhanced_link_detection_ebus = false;  // bit 5
  bool enhanced_link_detection_mii = false;   // bit 6
  bool separate_fcs_error_handling = false;   // bit 7
  bool enhanced_dc_sync_activation = false;   // bit 8
  bool lrw_not_supported = false;             // bit 9
  bool read_write_not_supported = false;      // bit 10: BRW, APRW, FPRW not supported
  bool fixed_fmmu_sm_configuration = false;   // bit 11

  std::uint16_t encode() const noexcept;
  static EscFeatures decode(std::uint16_t raw) noexcept;

  bool operator==(const EscFeatures&) const = default;
};

// ---------------------------------------------------------------------------------------------
// Port descriptor (0x0007, 1 byte: 2 bits per port)

enum class PortType : std::uint8_t {
  not_implemented = 0,
  not_configured = 1,  // configured by the SII EEPROM
  ebus = 2,
  mii = 3,  // MII / RMII / RGMII
};

std::string_view to_string(PortType type) noexcept;

struct PortDescriptor {
  std::array<PortType, 4> ports{};

  std::uint8_t encode() const noexcept;
  static PortDescriptor decode(std::uint8_t raw) noexcept;

  bool operator==(const PortDescriptor&) const = default;
};

// ---------------------------------------------------------------------------------------------
// ESC information block (0x0000..0x0009)

struct EscInformation {
  std::uint8_t type = 0;
  std::uint8_t revision = 0;
  std::uint16_t build = 0;
  std::uint8_t fmmu_count = 0;
  std::uint8_t sync_manager_count = 0;
  std::uint8_t ram_size_kib = 0;
  PortDescriptor ports;
  EscFeatures features;

  std::array<std::uint8_t, reg::kEscInformationSize> encode() const noexcept;
  // Needs exactly 10 bytes (a read of 0x0000..0x0009).
  static Result<EscInformation> decode(Bytes bytes);

  bool operator==(const EscInformation&) const = default;
};

// ---------------------------------------------------------------------------------------------
// RX error counters (0x0300, 8 bytes)

struct RxErrorCounters {
  std::array<std::uint8_t, 4> invalid_frame{};  // 0x0300 + 2 port
  std::array<std::uint8_t, 4> rx_error{};       // 0x0301 + 2 port

  std::array<std::uint8_t, reg::kRxErrorCounterSize> encode() const noexcept;
  static Result<RxErrorCounters> decode(Bytes bytes);

  bool operator==(const RxErrorCounters&) const = default;
};

// ---------------------------------------------------------------------------------------------
// SII EEPROM control/status (0x0502, 2 bytes)

namespace sii_control {
constexpr std::uint16_t kWriteEnable = 0x0001;
constexpr std::uint16_t kEmulation = 0x0020;        // status: EEPROM emulated by the PDI
constexpr std::uint16_t kReadSize8 = 0x0040;        // status: data register holds 8 bytes (else 4)
constexpr std::uint16_t kTwoAddressBytes = 0x0080;  // status: EEPROM uses 2 address bytes
constexpr std::uint16_t kCommandMask = 0x0700;
constexpr std::uint16_t kCommandNop = 0x0000;
constexpr std::uint16_t kCommandRead = 0x0100;
constexpr std::uint16_t kCommandWrite = 0x0200;
constexpr std::uint16_t kCommandReload = 0x0400;
constexpr std::uint16_t kChecksumError = 0x0800;     // ESC configuration area checksum
constexpr std::uint16_t kDeviceInfoError = 0x1000;   // EEPROM loading status: not loaded
constexpr std::uint16_t kAcknowledgeError = 0x2000;  // missing acknowledge or invalid command
constexpr std::uint16_t kWriteEnableError = 0x4000;
constexpr std::uint16_t kBusy = 0x8000;
constexpr std::uint16_t kErrorMask = 0x7800;
}  // namespace sii_control

// SII access register (0x0500): bit 0 offers the EEPROM to the PDI, bit 1 forces ECAT access.
namespace sii_access {
constexpr std::uint8_t kPdiOwns = 0x01;
constexpr std::uint8_t kForceEcatAccess = 0x02;
}  // namespace sii_access

enum class SiiCommand : std::uint8_t { nop = 0, read = 1, write = 2, reload = 4 };

struct SiiControlStatus {
  bool write_enable = false;
  bool emulation = false;
  bool read_size_8 = false;
  bool two_address_bytes = false;
  std::uint8_t command = 0;  // bits 10..8 as they are (see SiiCommand)
  bool checksum_error = false;
  bool device_info_error = false;
  bool acknowledge_error = false;
  bool write_enable_error = false;
  bool busy = false;

  bool has_error() const noexcept {
    return checksum_error || device_info_error || acknowledge_error || write_enable_error;
  }
  std::uint16_t encode() const noexcept;
  static SiiControlStatus decode(std::uint16_t raw) noexcept;

  bool operator==(const SiiControlStatus&) const = default;
};

}  // namespace ecat::wire
