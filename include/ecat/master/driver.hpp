// Device drivers: what a slave's process data means.
//
// A Driver turns a PdoLayout into named signals, lists the SDOs a device needs at startup,
// projects the decoded signal values into a device state (named values, faults, notices) and
// turns commands into output writes. A driver object is shared by every slave it serves and all
// its calls are const: per-slave state lives in the DriverState the slave owns (init()).
//
// Without a driver of its own a device gets the generic driver, whose signals come from the PDO
// and entry names, so any device works without code. DriverRegistry finds the driver for an
// identity; users add their own drivers to it.
//
// Calls happen on the control thread, never on the cycle path: they may allocate.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <initializer_list>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/master/pdo.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {

// A driver's settings, as text (a ring file, the command line, code). Readers parse and check
// them, naming the key when a value is wrong.
struct DriverConfig {
  std::map<std::string, std::string, std::less<>> options{};

  std::optional<std::string_view> text(std::string_view key) const;
  Result<std::optional<double>> number(std::string_view key) const;
  Result<std::optional<std::int64_t>> integer(std::string_view key) const;  // decimal or 0x..
  Result<std::optional<bool>> boolean(std::string_view key) const;
  // Fails naming the first key not in `known`.
  Result<void> check_known(std::initializer_list<std::string_view> known) const;
};

// ---- synchronisation (ETG.1020 0x1C32 / 0x1C33) ---------------------------------------------

// Values of 0x1C32:01 (outputs) / 0x1C33:01 (inputs).
enum class SmSyncMode : std::uint16_t {
  free_run = 0x0000,
  sm_event = 0x0001,  // outputs: SM2 event; inputs: SM3 event
  sync0 = 0x0002,
  sync1 = 0x0003,
  sm2_event = 0x0022,  // inputs only: latched with the SM2 (outputs) event
};
std::string_view to_string(SmSyncMode mode) noexcept;

struct SyncSettings {
  std::optional<SmSyncMode> output{};  // nullopt: leave 0x1C32 alone
  std::optional<SmSyncMode> input{};   // nullopt: leave 0x1C33 alone
  std::uint32_t cycle_ns = 0;          // written to :02 of the objects written, when not 0

  bool operator==(const SyncSettings&) const = default;
};

// The downloads for `sync`: 0x1C32:01 (u16) [0x1C32:02 (u32)], then 0x1C33 the same way. Fails
// for sm2_event on the output side.
Result<std::vector<SdoWrite>> sync_mode_writes(const SyncSettings& sync);

// When startup SDOs run: `preop` right after the slave reaches PREOP (then the PDO mapping is
// written), `sync_update` after it and again whenever only the synchronisation changes.
enum class StartupPhase : std::uint8_t { preop, sync_update };

// ---- values a driver sees and produces -------------------------------------------------------

// The present value of every signal of a slave: inputs as last received, outputs as staged.
// Values are engineering values (decode_scaled). A view: it owns nothing.
class SignalValues {
 public:
  SignalValues() = default;
  // `values[i]` is the value of `signals[i]`; a shorter `values` leaves the rest absent.
  SignalValues(std::span<const Signal> signals, std::span<const Value> values) noexcept
      : signals_(signals), values_(values) {}

  std::size_t size() const noexcept { return std::min(signals_.size(), values_.size()); }
  const Signal& signal(std::size_t i) const { return signals_[i]; }
  const Value& value(std::size_t i) const { return values_[i]; }
  const Value* find(std::string_view name) const noexcept;
  const Signal* find_signal(std::string_view name) const noexcept;

 private:
  std::span<const Signal> signals_;
  std::span<const Value> values_;
};

struct NamedValue {
  std::string name;
  Value value;

  bool operator==(const NamedValue&) const = default;
};

// What a driver makes of a device's signals.
struct DeviceState {
  std::vector<NamedValue> values;    // in a stable order (a driver's describe() order)
  std::vector<std::string> faults;   // conditions present now ("channel 1: overrange")
  std::vector<std::string> notices;  // things that happened since the previous state

  const Value* find(std::string_view name) const noexcept;
  // Replaces the value of `name`, or appends it.
  void set(std::string name, Value value);
  bool operator==(const DeviceState&) const = default;
};

// "Write `value` to output signal `signal`": value in engineering units (encode_scaled).
struct OutputWrite {
  std::string signal{};
  Value value{};

  bool operator==(const OutputWrite&) const = default;
};

using CommandArgs = std::vector<NamedValue>;
const Value* find_arg(const CommandArgs& args, std::string_view name) noexcept;

// ---- description ----------------------------------------------------------------------------

struct Endpoint {
  std::string signal;
  PdoDirection direction = PdoDirection::input;
  SignalType type = SignalType::uint8;
  std::string unit;
  std::string label;  // for people: "Channel 1 temperature"
  std::string description;

  bool operator==(const Endpoint&) const = default;
};

struct CommandInfo {
  std::string name;
  std::string description;
  std::vector<std::string> args;  // argument names; "name?" marks an optional one

  bool operator==(const CommandInfo&) const = default;
};

struct Description {
  std::string device_type;  // "digital_input", "cia402_drive", "generic" ...
  std::vector<Endpoint> endpoints;
  std::vector<CommandInfo> commands;
};

// A vendor / product (and optionally revision) a driver serves.
struct DriverIdentity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::optional<std::uint32_t> revision;  // nullopt: every revision

  bool matches(const wire::SiiIdentity& id) const noexcept {
    return id.vendor_id == vendor_id && id.product_code == product_code &&
           (!revision || *revision == id.revision);
  }
  bool operator==(const DriverIdentity&) const = default;
};

// Per-slave state a driver keeps between calls (edge detection, counters ...).
class DriverState {
 public:
  virtual ~DriverState() = default;
};

class Driver {
 public:
  virtual ~Driver() = default;

  // A short unique name ("generic", "EL1809", "cia402").
  virtual std::string_view name() const noexcept = 0;
  // The devices this driver is made for; empty for drivers chosen only by name.
  virtual std::vector<DriverIdentity> identities() const { return {}; }
  // Whether the driver serves `identity` (default: one of identities() matches).
  virtual bool matches(const wire::SiiIdentity& identity) const;

  // The signals of a device with `layout`. Every signal must lie in an SM of the layout.
  virtual Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                                   const DriverConfig& config) const = 0;

  // The mailbox steps of `phase`. Default: nothing in preop; sync_mode_writes(sync) in
  // sync_update.
  virtual Result<std::vector<SdoWrite>> startup_sdos(const DriverConfig& config, StartupPhase phase,
                                                     const SyncSettings& sync) const;

  // Per-slave state, made once when the slave is configured. Default: none (nullptr).
  virtual Result<std::unique_ptr<DriverState>> init(const DriverConfig& config) const;

  // The device state for the present signal values. `previous` is the last state returned (null
  // the first time). Default: every signal's value under its own name, no faults, no notices.
  virtual Result<DeviceState> project_state(const SignalValues& current,
                                            const DeviceState* previous, DriverState* state) const;

  // The output writes for a command. Every driver understands
  //   set_output {signal: "<name>", value: <engineering value>}
  // and fails with Errc::not_found naming unknown commands. `current` holds the staged outputs
  // (so a command can keep bits it does not change).
  virtual Result<std::vector<OutputWrite>> command(std::string_view name, const CommandArgs& args,
                                                   const SignalValues& current,
                                                   const DeviceState& state,
                                                   DriverState* driver_state) const;

  // Device type, endpoints (default: one per signal of `model`) and commands.
  virtual Description describe(std::span<const Signal> model) const;

 protected:
  // The set_output command, for drivers that override command().
  static Result<std::vector<OutputWrite>> set_output(const CommandArgs& args,
                                                     const SignalValues& current);
  static Error unknown_command(std::string_view driver, std::string_view command);
};

// ---- the generic driver ------------------------------------------------------------------------

// Signals for every non-padding entry of every assigned PDO, named "<pdo>.<entry>" from the PDO
// and entry names in snake case ("Channel 1" / "Output" -> "channel_1.output"). A missing PDO
// name gives "pdo_<index hex>", a missing entry name "<index hex>_<subindex hex>"; the second,
// third ... signal with one name gets "_2", "_3" ... in layout order (SM, PDO, entry).
Result<std::vector<Signal>> generic_signal_model(const PdoLayout& layout);

// The generic driver: generic_signal_model, default everything else.
std::shared_ptr<const Driver> generic_driver();

// ---- registry
// ------------------------------------------------------------------------------------

class DriverRegistry {
 public:
  // Only the generic driver. The built-in ones: drivers::builtin_registry()
  // (<ecat/drivers/builtin.hpp>), what MasterConfig::drivers starts with.
  DriverRegistry() = default;

  // Later additions take precedence over earlier ones (a user's driver over a built-in).
  void add(std::shared_ptr<const Driver> driver);
  // The last added driver that matches, else the generic driver. Never null.
  std::shared_ptr<const Driver> find(const wire::SiiIdentity& identity) const;
  // By name (the last added with that name; "generic" for the generic driver); null if none.
  std::shared_ptr<const Driver> find(std::string_view name) const;
  const std::vector<std::shared_ptr<const Driver>>& drivers() const noexcept { return drivers_; }

 private:
  std::vector<std::shared_ptr<const Driver>> drivers_;
};

}  // namespace ecat::master
