// "soe_drive": a servo drive on the SERCOS drive profile (SoE), of the simulator's own make
// (vendor 0x00000ACE, product 0x00005E00), shaped like Beckhoff's AX5000 series as SOEM's
// slaveinfo shows an AX5206 (SOEM issue #127): a 128-byte mailbox at 0x1000 / 0x1080 whose SII
// declares SoE and not CoE (AX5000 drives declare SoE + FoE: mailbox protocols 0x18), the SoE
// channel count in the GENERAL category, process data as plain SII PDOs.
//
// SoE only, no CoE, on purpose: it is what SERCOS drives declare, and it proves the master needs
// no CoE for a mailbox slave (the PDO layout comes from the SII). (The simulator's mailbox engine
// is the CoeServer, which still answers a CoE request from the PDO objects; a real SoE-only drive
// would answer with mailbox error 0x02. The master sends it none.)
//
// IDNs (each drive number 0..drives-1 has its own; option drives=1..8, default 1):
//   S-0-0001 NC cycle time (us, 125..65000)         write protected in SAFEOP and OP
//   S-0-0002 Communication cycle time (us)          write protected in SAFEOP and OP
//   S-0-0011 Class 1 diagnostic                     read only (S-0-0099 clears it)
//   S-0-0015 Telegram type, S-0-0016 AT list, S-0-0024 MDT list   write protected in SAFEOP/OP
//   S-0-0017 IDN-list of all operation data         read only; 126 bytes: two read fragments
//   S-0-0030 Manufacturer version (text)            read only
//   S-0-0032 Primary operation mode (2 velocity, 3 position)   write protected in OP
//   S-0-0036 Velocity command value (rpm, +-6000), S-0-0040 velocity feedback value 1 (read only)
//   S-0-0047 Position command value (Incr), S-0-0051 position feedback value 1 (read only)
//   S-0-0091 Bipolar velocity limit value (rpm)
//   S-0-0095 Diagnostic message (text)
//   S-0-0099 Reset class 1 diagnostic, S-0-0127 CP3 transition check, S-0-0128 CP4 transition
//            check: procedure commands; writing 3 (set + enable) runs them and the drive sends a
//            notification (opcode 5, data state element) with 0x0003 when done. S-0-0127 refuses
//            (0x7013) a cycle time S-0-0001 that is not a multiple of 125 us; S-0-0128 runs only
//            in SAFEOP (else 0x7012).
//   S-0-0134 Master control word, S-0-0135 Drive status word
//   P-0-0010 Error history: 64 x u32 (260 bytes: three read fragments)
//   P-0-0101..P-0-0140 Manufacturer parameter 1..40 (u32, write protected in SAFEOP and OP)
// Process data (SII PDOs; the model copies it into the IDNs and back):
//   RxPDO 0x1600 "MDT" (SM2 0x1100, 10 bytes): master control word u16, position command i32,
//                                              velocity command i32
//   TxPDO 0x1A00 "AT"  (SM3 0x1180, 10 bytes): drive status word u16, position feedback i32,
//                                              velocity feedback i32
// The motor: with control word bits 15 (drive on), 14 (enable) and 13 (start) set, in velocity
// mode the velocity feedback follows the command and the position integrates it (2^20 increments
// per revolution); in position mode the position feedback follows the command. The status word
// shows bits 15..14 = 11 (ready, drive on with torque) while enabled, else 01.
#include <algorithm>
#include <cstdint>
#include <limits>

#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

namespace attr = soe_attribute;

constexpr std::uint16_t s(unsigned n) {
  return static_cast<std::uint16_t>(n);
}
constexpr std::uint16_t p(unsigned n) {
  return static_cast<std::uint16_t>(0x8000 | n);
}

constexpr std::uint16_t kCycleTime = s(1);
constexpr std::uint16_t kDiagnostic = s(11);
constexpr std::uint16_t kIdnList = s(17);
constexpr std::uint16_t kOperationMode = s(32);
constexpr std::uint16_t kVelocityCommand = s(36);
constexpr std::uint16_t kVelocityFeedback = s(40);
constexpr std::uint16_t kPositionCommand = s(47);
constexpr std::uint16_t kPositionFeedback = s(51);
constexpr std::uint16_t kResetDiagnostic = s(99);
constexpr std::uint16_t kCp3Check = s(127);
constexpr std::uint16_t kCp4Check = s(128);
constexpr std::uint16_t kControlWord = s(134);
constexpr std::uint16_t kStatusWord = s(135);

constexpr double kIncrementsPerRevolution = 1 << 20;
constexpr std::uint16_t kCommandDone = 0x0003;  // data state: set, enabled, executed

std::vector<std::uint8_t> le(std::int64_t v, std::size_t n) {
  std::vector<std::uint8_t> out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>(static_cast<std::uint64_t>(v) >> (8 * i));
  return out;
}

std::size_t size_of(std::uint32_t attribute) {
  return std::size_t{1} << ((attribute >> 16) & 0x03);
}

SoeIdn number(std::uint16_t idn, std::string name, std::uint32_t attribute,
              std::optional<std::string> unit, std::int64_t value,
              std::optional<std::int64_t> min = std::nullopt,
              std::optional<std::int64_t> max = std::nullopt) {
  SoeIdn e;
  e.idn = idn;
  e.name = std::move(name);
  e.attribute = attribute;
  e.unit = std::move(unit);
  const std::size_t n = size_of(attribute);
  e.value = le(value, n);
  e.default_value = e.value;
  if (min) e.minimum = le(*min, n);
  if (max) e.maximum = le(*max, n);
  return e;
}

SoeIdn list(std::uint16_t idn, std::string name, std::uint32_t attribute,
            std::vector<std::uint8_t> value, std::uint16_t max_length) {
  SoeIdn e;
  e.idn = idn;
  e.name = std::move(name);
  e.attribute = attribute | attr::kList;
  e.value = std::move(value);
  e.default_value = e.value;
  e.max_length = max_length;
  return e;
}

SoeIdn text(std::uint16_t idn, std::string name, std::string_view value, std::uint16_t max,
            std::uint32_t protection) {
  return list(idn, std::move(name), attr::kLength1 | attr::kText | protection,
              std::vector<std::uint8_t>(value.begin(), value.end()), max);
}

std::vector<std::uint8_t> idns_bytes(const std::vector<std::uint16_t>& idns) {
  std::vector<std::uint8_t> out;
  for (auto idn : idns) {
    out.push_back(static_cast<std::uint8_t>(idn));
    out.push_back(static_cast<std::uint8_t>(idn >> 8));
  }
  return out;
}

std::vector<SoeIdn> drive_idns() {
  constexpr std::uint32_t kPhase2 = attr::kWriteProtectedSafeop | attr::kWriteProtectedOp;
  constexpr std::uint32_t kCommand = attr::kLength2 | attr::kCommand | attr::kBinary;
  constexpr std::int32_t kVelocityLimit = 6000;
  std::vector<SoeIdn> idns = {
      number(kCycleTime, "NC cycle time (TNcyc)", attr::kLength2 | attr::kUnsigned | kPhase2, "us",
             1000, 125, 65000),
      number(s(2), "Communication cycle time (tScyc)", attr::kLength2 | attr::kUnsigned | kPhase2,
             "us", 1000, 125, 65000),
      number(kDiagnostic, "Class 1 diagnostic", attr::kLength2 | attr::kHex | attr::kReadOnly,
             std::nullopt, 0),
      number(s(15), "Telegram type parameter", attr::kLength2 | attr::kUnsigned | kPhase2,
             std::nullopt, 7, 0, 7),
      list(s(16), "Configuration list of AT", attr::kLength2 | attr::kIdn | kPhase2,
           idns_bytes({kPositionFeedback, kVelocityFeedback}), 32),
      list(s(24), "Configuration list of MDT", attr::kLength2 | attr::kIdn | kPhase2,
           idns_bytes({kPositionCommand, kVelocityCommand}), 32),
      text(s(30), "Manufacturer version", "ecat sim SoE drive 1.0", 64, attr::kReadOnly),
      number(kOperationMode, "Primary operation mode",
             attr::kLength2 | attr::kHex | attr::kWriteProtectedOp, std::nullopt, 3, 1, 3),
      number(kVelocityCommand, "Velocity command value", attr::kLength4 | attr::kSigned, "rpm", 0,
             -kVelocityLimit, kVelocityLimit),
      number(kVelocityFeedback, "Velocity feedback value 1",
             attr::kLength4 | attr::kSigned | attr::kReadOnly, "rpm", 0, -kVelocityLimit,
             kVelocityLimit),
      number(kPositionCommand, "Position command value", attr::kLength4 | attr::kSigned, "Incr", 0,
             std::numeric_limits<std::int32_t>::min(), std::numeric_limits<std::int32_t>::max()),
      number(kPositionFeedback, "Position feedback value 1",
             attr::kLength4 | attr::kSigned | attr::kReadOnly, "Incr", 0,
             std::numeric_limits<std::int32_t>::min(), std::numeric_limits<std::int32_t>::max()),
      number(s(91), "Bipolar velocity limit value",
             attr::kLength4 | attr::kUnsigned | attr::kWriteProtectedOp, "rpm", kVelocityLimit, 0,
             kVelocityLimit),
      text(s(95), "Diagnostic message", "A0010 Drive ready", 64, attr::kReadOnly),
      number(kResetDiagnostic, "Reset class 1 diagnostic", kCommand, std::nullopt, 0),
      number(kCp3Check, "CP3 transition check", kCommand, std::nullopt, 0),
      number(kCp4Check, "CP4 transition check", kCommand, std::nullopt, 0),
      number(kControlWord, "Master control word", attr::kLength2 | attr::kHex, std::nullopt, 0),
      number(kStatusWord, "Drive status word", attr::kLength2 | attr::kHex | attr::kReadOnly,
             std::nullopt, 0x4000),
  };
  std::vector<std::uint8_t> history;
  for (std::uint32_t i = 0; i < 64; ++i) {
    auto entry = le(0xF000 + i, 4);
    history.insert(history.end(), entry.begin(), entry.end());
  }
  idns.push_back(list(p(10), "Error history", attr::kLength4 | attr::kHex | attr::kReadOnly,
                      std::move(history), 256));
  for (unsigned i = 1; i <= 40; ++i) {
    idns.push_back(number(p(100 + i), fmt::format("Manufacturer parameter {}", i),
                          attr::kLength4 | attr::kUnsigned | kPhase2, std::nullopt, i, 0, 0xFFFF));
  }
  std::vector<std::uint16_t> all = {kIdnList};
  for (const auto& e : idns)
    all.push_back(e.idn);
  std::sort(all.begin(), all.end());
  idns.push_back(list(kIdnList, "IDN-list of all operation data",
                      attr::kLength2 | attr::kIdn | attr::kReadOnly, idns_bytes(all),
                      static_cast<std::uint16_t>(all.size() * 2)));
  return idns;
}

class SoeDrive : public StandardApplication {
 public:
  explicit SoeDrive(StandardConfig config) : StandardApplication(std::move(config)) {
    add_entry_signal({"control_word", SignalDirection::output, "u16", ""}, 0x7000, 1);
    add_entry_signal({"position_command", SignalDirection::output, "i32", "Incr"}, 0x7000, 2);
    add_entry_signal({"velocity_command", SignalDirection::output, "i32", "rpm"}, 0x7000, 3);
    add_entry_signal({"status_word", SignalDirection::input, "u16", ""}, 0x6000, 1);
    add_entry_signal({"position_feedback", SignalDirection::input, "i32", "Incr"}, 0x6000, 2);
    add_entry_signal({"velocity_feedback", SignalDirection::input, "i32", "rpm"}, 0x6000, 3);
    if (auto* soe = soe_server()) {
      soe->set_write_hook([this](Esc& esc, std::uint8_t drive, std::uint16_t idn,
                                 const std::vector<std::uint8_t>& value) {
        return on_write(esc, drive, idn, value);
      });
    }
  }

 protected:
  void outputs_changed(
      const std::vector<std::pair<std::uint16_t, std::uint8_t>>& changed) override {
    (void)changed;
    auto* soe = soe_server();
    if (soe == nullptr) return;
    // The MDT carries drive 0's commands.
    soe->set_number(0, kControlWord, dictionary().get<std::uint16_t>(0x7000, 1).value_or(0));
    soe->set_number(0, kPositionCommand, dictionary().get<std::int32_t>(0x7000, 2).value_or(0));
    soe->set_number(0, kVelocityCommand, dictionary().get<std::int32_t>(0x7000, 3).value_or(0));
  }

  void apply_safe_outputs() override {
    StandardApplication::apply_safe_outputs();
    if (auto* soe = soe_server()) soe->set_number(0, kControlWord, 0);
  }

  void update_inputs(std::int64_t now_ns) override {
    auto* soe = soe_server();
    if (soe == nullptr) return;
    const double dt = last_ns_ != 0 ? static_cast<double>(now_ns - last_ns_) * 1e-9 : 0.0;
    last_ns_ = now_ns;
    for (std::uint8_t d = 0; d < soe->config().drives; ++d)
      step(*soe, d, dt);
    dictionary().set<std::uint16_t>(
        0x6000, 1, static_cast<std::uint16_t>(soe->number(0, kStatusWord).value_or(0)));
    dictionary().set<std::int32_t>(
        0x6000, 2, static_cast<std::int32_t>(soe->number(0, kPositionFeedback).value_or(0)));
    dictionary().set<std::int32_t>(
        0x6000, 3, static_cast<std::int32_t>(soe->number(0, kVelocityFeedback).value_or(0)));
  }

  void reset_model() override {
    last_ns_ = 0;
    position_.fill(0.0);
  }

 private:
  void step(SoeServer& soe, std::uint8_t drive, double dt) {
    const auto control = soe.number(drive, kControlWord).value_or(0);
    const bool enabled = (control & 0xE000) == 0xE000;
    soe.set_number(drive, kStatusWord, enabled ? 0xC000 : 0x4000);
    double& position = position_[drive];
    if (!enabled) {
      soe.set_number(drive, kVelocityFeedback, 0);
      return;
    }
    if ((soe.number(drive, kOperationMode).value_or(0) & 0x07) == 2) {
      const auto velocity = soe.number(drive, kVelocityCommand).value_or(0);
      soe.set_number(drive, kVelocityFeedback, velocity);
      position += static_cast<double>(velocity) / 60.0 * kIncrementsPerRevolution * dt;
      position = std::clamp(position, -2147483648.0, 2147483647.0);
    } else {
      position = static_cast<double>(soe.number(drive, kPositionCommand).value_or(0));
      soe.set_number(drive, kVelocityFeedback, 0);
    }
    soe.set_number(drive, kPositionFeedback, static_cast<std::int64_t>(position));
  }

  // Procedure commands: 3 (set + enable) runs them, 0 cancels; anything else is refused.
  std::uint16_t on_write(Esc& esc, std::uint8_t drive, std::uint16_t idn,
                         const std::vector<std::uint8_t>& value) {
    if (idn != kResetDiagnostic && idn != kCp3Check && idn != kCp4Check) return 0;
    auto* soe = soe_server();
    const unsigned command = value.size() >= 1 ? value[0] & 0x03u : 0u;
    if (command == 0) return 0;
    if (command != 3) return 0x7013;  // not executable (wrong parameters)
    if (idn == kCp3Check) {
      const auto cycle = soe->number(drive, kCycleTime).value_or(0);
      if (cycle % 125 != 0) return 0x7013;
    }
    if (idn == kCp4Check && esc.al_state() != wire::AlState::safeop) return 0x7012;
    if (idn == kResetDiagnostic) soe->set_number(drive, kDiagnostic, 0);
    soe->notify(esc, drive, idn, wire::kSoeElementDataState, le(kCommandDone, 2));
    return 0;
  }

  std::int64_t last_ns_ = 0;
  std::array<double, 8> position_{};
};

}  // namespace

Result<std::unique_ptr<Esc>> make_soe_drive(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"drives", "serial", "require_valid_outputs", "check_fmmus"});
      !ok) {
    return ok.error();
  }
  auto drives = option_u32(config, "drives", 1);
  if (!drives) return drives.error();
  if (*drives < 1 || *drives > 8) {
    return Error(Errc::invalid_argument,
                 fmt::format("soe_drive: drives={} is outside 1..8", *drives));
  }

  wire::SiiImage sii;
  sii.pdi_control = 0x0C08;
  sii.identity = {kSimVendorId, 0x00005E00, 0x00010000, 0x3001};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  sii.mailbox_protocols = wire::mailbox_protocol::kSoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("ECAT-SOE-DRIVE");
  general.group_index = strings.add("Drives");
  general.name_index = strings.add("ecat sim SoE servo drive");
  general.soe_channels = static_cast<std::uint8_t>(*drives);
  general.physical_port = 0x0011;
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kInputs,
               wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 128, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1080, 128, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn},
                       {0x1100, 10, 0x64, 0, 0x01, wire::sii_sm_type::kOutputs},
                       {0x1180, 10, 0x20, 0, 0x01, wire::sii_sm_type::kInputs}};
  const auto entry = [&](std::uint16_t index, std::uint8_t sub, std::string_view name,
                         DataType type, std::uint8_t bits) {
    return wire::SiiPdoEntry{index, sub, strings.add(name), static_cast<std::uint8_t>(type),
                             bits,  0};
  };
  wire::SiiPdo rx;
  rx.index = 0x1600;
  rx.sync_manager = 2;
  rx.name_index = strings.add("MDT");
  rx.entries = {entry(0x7000, 1, "Master control word", DataType::unsigned16, 16),
                entry(0x7000, 2, "Position command value", DataType::integer32, 32),
                entry(0x7000, 3, "Velocity command value", DataType::integer32, 32)};
  wire::SiiPdo tx;
  tx.index = 0x1A00;
  tx.sync_manager = 3;
  tx.name_index = strings.add("AT");
  tx.entries = {entry(0x6000, 1, "Drive status word", DataType::unsigned16, 16),
                entry(0x6000, 2, "Position feedback value 1", DataType::integer32, 32),
                entry(0x6000, 3, "Velocity feedback value 1", DataType::integer32, 32)};
  sii.rxpdos = {rx};
  sii.txpdos = {tx};

  StandardConfig cfg;
  add_sii_process_data(cfg.dictionary, sii);
  cfg.soe.drives = static_cast<std::uint8_t>(*drives);
  cfg.soe.idns = drive_idns();
  cfg.sii = sii;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  EscHardware hw;
  hw.ports =
      wire::PortDescriptor{{wire::PortType::mii, wire::PortType::mii,
                            wire::PortType::not_implemented, wire::PortType::not_implemented}};
  return build_device(config, hw, image, std::make_unique<SoeDrive>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
