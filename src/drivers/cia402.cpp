// CiA 402 drive driver: the power state machine seen through the statusword and driven by the
// controlword, modes of operation and set-points.
#include <algorithm>
#include <array>
#include <charconv>

#include <fmt/format.h>

#include <ecat/drivers/drivers.hpp>

namespace ecat::drivers {

std::string_view to_string(Cia402State state) noexcept {
  switch (state) {
    case Cia402State::not_ready_to_switch_on:
      return "not_ready_to_switch_on";
    case Cia402State::switch_on_disabled:
      return "switch_on_disabled";
    case Cia402State::ready_to_switch_on:
      return "ready_to_switch_on";
    case Cia402State::switched_on:
      return "switched_on";
    case Cia402State::operation_enabled:
      return "operation_enabled";
    case Cia402State::quick_stop_active:
      return "quick_stop_active";
    case Cia402State::fault_reaction_active:
      return "fault_reaction_active";
    case Cia402State::fault:
      return "fault";
    case Cia402State::unknown:
      return "unknown";
  }
  return "unknown";
}

Cia402State cia402_state(std::uint16_t sw) noexcept {
  // Bits 0-3 and 6 tell most states apart; bit 5 (quick stop) separates the three powered ones.
  switch (sw & 0x004F) {
    case 0x0000:
      return Cia402State::not_ready_to_switch_on;
    case 0x0040:
      return Cia402State::switch_on_disabled;
    case 0x000F:
      return Cia402State::fault_reaction_active;
    case 0x0008:
      return Cia402State::fault;
    default:
      break;
  }
  switch (sw & 0x006F) {
    case 0x0021:
      return Cia402State::ready_to_switch_on;
    case 0x0023:
      return Cia402State::switched_on;
    case 0x0027:
      return Cia402State::operation_enabled;
    case 0x0007:
      return Cia402State::quick_stop_active;
    default:
      break;
  }
  return Cia402State::unknown;
}

namespace {

struct CommandName {
  Cia402Command command;
  std::string_view name;
};
constexpr std::array<CommandName, 7> kCommands{
    {{Cia402Command::shutdown, "shutdown"},
     {Cia402Command::switch_on, "switch_on"},
     {Cia402Command::enable_operation, "enable_operation"},
     {Cia402Command::disable_operation, "disable_operation"},
     {Cia402Command::disable_voltage, "disable_voltage"},
     {Cia402Command::quick_stop, "quick_stop"},
     {Cia402Command::fault_reset, "fault_reset"}}};

constexpr std::uint16_t kCommandBits = 0x008F;  // bits 0-3 and 7
constexpr std::uint16_t kNewSetpoint = 0x0010;
constexpr std::uint16_t kChangeImmediately = 0x0020;
constexpr std::uint16_t kRelative = 0x0040;
constexpr std::uint16_t kFaultReset = 0x0080;

}  // namespace

std::string_view to_string(Cia402Command command) noexcept {
  for (const auto& c : kCommands) {
    if (c.command == command) return c.name;
  }
  return "unknown";
}

std::optional<Cia402Command> cia402_command_from_string(std::string_view name) noexcept {
  for (const auto& c : kCommands) {
    if (c.name == name) return c.command;
  }
  return std::nullopt;
}

std::uint16_t cia402_controlword(Cia402Command command, std::uint16_t current) noexcept {
  const auto keep = static_cast<std::uint16_t>(current & ~kCommandBits);
  switch (command) {
    case Cia402Command::shutdown:
      return keep | 0x0006;
    case Cia402Command::switch_on:
    case Cia402Command::disable_operation:
      return keep | 0x0007;
    case Cia402Command::enable_operation:
      return keep | 0x000F;
    case Cia402Command::disable_voltage:
      return keep;
    case Cia402Command::quick_stop:
      return keep | 0x0002;
    case Cia402Command::fault_reset:
      return keep | kFaultReset;
  }
  return current;
}

namespace {

struct ModeName {
  std::int8_t mode;
  std::string_view name;
};
constexpr std::array<ModeName, 8> kModes{{{cia402_mode::kProfilePosition, "pp"},
                                          {cia402_mode::kProfileVelocity, "pv"},
                                          {cia402_mode::kProfileTorque, "pt"},
                                          {cia402_mode::kHoming, "hm"},
                                          {cia402_mode::kInterpolatedPosition, "ip"},
                                          {cia402_mode::kCyclicPosition, "csp"},
                                          {cia402_mode::kCyclicVelocity, "csv"},
                                          {cia402_mode::kCyclicTorque, "cst"}}};

}  // namespace

std::string cia402_mode_name(std::int8_t mode) {
  if (mode == 0) return "none";
  for (const auto& m : kModes) {
    if (m.mode == mode) return std::string(m.name);
  }
  return fmt::format("mode_{}", mode);
}

std::optional<std::int8_t> cia402_mode_from_string(std::string_view name) noexcept {
  for (const auto& m : kModes) {
    if (m.name == name) return m.mode;
  }
  if (name == "none") return std::int8_t{0};
  if (name.starts_with("mode_")) name.remove_prefix(5);
  int v = 0;
  const auto [end, ec] = std::from_chars(name.data(), name.data() + name.size(), v);
  if (ec != std::errc() || end != name.data() + name.size() || name.empty() || v < -128 ||
      v > 127) {
    return std::nullopt;
  }
  return static_cast<std::int8_t>(v);
}

namespace {

using master::CommandArgs;
using master::Description;
using master::DeviceState;
using master::DriverConfig;
using master::DriverIdentity;
using master::OutputWrite;
using master::PdoLayout;
using master::Signal;
using master::SignalValues;
using master::Value;

struct KnownObject {
  std::uint16_t index;
  std::string_view name;
  std::string_view unit;
};
constexpr std::array<KnownObject, 21> kObjects{{
    {0x603F, "error_code", ""},
    {0x6040, "controlword", ""},
    {0x6041, "statusword", ""},
    {0x6060, "modes_of_operation", ""},
    {0x6061, "modes_of_operation_display", ""},
    {0x6062, "position_demand", "counts"},
    {0x6064, "position_actual", "counts"},
    {0x606C, "velocity_actual", "counts/s"},
    {0x6071, "target_torque", "‰"},
    {0x6072, "max_torque", "‰"},
    {0x6077, "torque_actual", "‰"},
    {0x607A, "target_position", "counts"},
    {0x6081, "profile_velocity", "counts/s"},
    {0x6083, "profile_acceleration", "counts/s²"},
    {0x6084, "profile_deceleration", "counts/s²"},
    {0x60B0, "position_offset", "counts"},
    {0x60B1, "velocity_offset", "counts/s"},
    {0x60B2, "torque_offset", "‰"},
    {0x60F4, "following_error_actual", "counts"},
    {0x60FD, "digital_inputs", ""},
    {0x60FF, "target_velocity", "counts/s"},
}};

const KnownObject* known_object(std::uint16_t index) {
  for (const auto& o : kObjects) {
    if (o.index == index) return &o;
  }
  return nullptr;
}

struct StatusBit {
  std::uint16_t mask;
  std::string_view name;
};
constexpr std::array<StatusBit, 7> kStatusBits{{{0x0010, "voltage_enabled"},
                                                {0x0080, "warning"},
                                                {0x0200, "remote"},
                                                {0x0400, "target_reached"},
                                                {0x0800, "internal_limit_active"},
                                                {0x1000, "setpoint_acknowledged"},
                                                {0x2000, "following_error"}}};

class Cia402 final : public master::Driver {
 public:
  std::string_view name() const noexcept override { return "cia402"; }
  std::vector<DriverIdentity> identities() const override {
    return {{0x00000ACE, 0x00002402, std::nullopt}};  // the simulator's servo
  }

  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig& config) const override {
    if (auto known = config.check_known({}); !known) return known.error();
    auto generic = master::generic_signal_model(layout);
    if (!generic) return generic.error().context("cia402 driver");
    std::vector<Signal> out = std::move(*generic);
    std::vector<std::string_view> taken;
    for (auto& s : out) {
      const KnownObject* o = s.subindex == 0 ? known_object(s.index) : nullptr;
      if (o == nullptr) continue;
      if (std::find(taken.begin(), taken.end(), o->name) != taken.end()) continue;
      taken.push_back(o->name);
      s.name = std::string(o->name);
      s.unit = std::string(o->unit);
    }
    for (const auto& s : out) {
      if (std::count_if(out.begin(), out.end(), [&](const Signal& x) { return x.name == s.name; }) >
          1) {
        return Error(Errc::invalid_argument,
                     fmt::format("cia402 driver: two signals named '{}'", s.name));
      }
    }
    for (std::string_view required : {"controlword", "statusword"}) {
      if (std::find(taken.begin(), taken.end(), required) == taken.end()) {
        return Error(Errc::not_found,
                     fmt::format("cia402 driver: the {} (0x{:04x}) is not mapped in any assigned "
                                 "PDO",
                                 required, required == "controlword" ? 0x6040 : 0x6041));
      }
    }
    return out;
  }

  Result<DeviceState> project_state(const SignalValues& current, const DeviceState* previous,
                                    master::DriverState* state) const override {
    (void)state;
    DeviceState out;
    const Value* sw_value = current.find("statusword");
    const auto sw = sw_value != nullptr ? master::as_uint64(*sw_value) : std::nullopt;
    if (!sw || *sw > 0xFFFF) {
      return Error(Errc::invalid_argument, "cia402 driver: no usable statusword value");
    }
    const auto statusword = static_cast<std::uint16_t>(*sw);
    const Cia402State st = cia402_state(statusword);
    out.set("state", Value(std::string(to_string(st))));
    const Value* mode = current.find("modes_of_operation_display");
    if (mode == nullptr) mode = current.find("modes_of_operation");
    if (mode != nullptr) {
      const auto m = master::as_int64(*mode).value_or(0);
      out.set("mode", Value(cia402_mode_name(static_cast<std::int8_t>(m))));
    }
    for (const auto& bit : kStatusBits)
      out.set(std::string(bit.name), Value((statusword & bit.mask) != 0));
    for (std::size_t i = 0; i < current.size(); ++i)
      out.set(current.signal(i).name, current.value(i));

    if (st == Cia402State::fault || st == Cia402State::fault_reaction_active) {
      const Value* code = current.find("error_code");
      const auto c = code != nullptr ? master::as_uint64(*code) : std::nullopt;
      out.faults.push_back(c && *c != 0
                               ? fmt::format("drive {} (error code 0x{:04x})", to_string(st), *c)
                               : fmt::format("drive {}", to_string(st)));
    }
    if (previous != nullptr) {
      const Value* before = previous->find("state");
      const auto* was = before != nullptr ? std::get_if<std::string>(before) : nullptr;
      if (was != nullptr && *was != to_string(st)) {
        out.notices.push_back(fmt::format("state {} -> {}", *was, to_string(st)));
      }
    }
    return out;
  }

  Result<std::vector<OutputWrite>> command(std::string_view command, const CommandArgs& args,
                                           const SignalValues& current, const DeviceState& state,
                                           master::DriverState* driver_state) const override {
    auto controlword = [&]() -> Result<std::uint16_t> {
      const Value* v = current.find("controlword");
      const auto cw = v != nullptr ? master::as_uint64(*v) : std::nullopt;
      if (!cw || *cw > 0xFFFF) {
        return Error(Errc::not_found, fmt::format("cia402 {}: no controlword signal", command));
      }
      return static_cast<std::uint16_t>(*cw);
    };
    auto write_cw = [](std::uint16_t cw) {
      return std::vector<OutputWrite>{{"controlword", Value(std::uint64_t{cw})}};
    };
    if (const auto c = cia402_command_from_string(command)) {
      auto cw = controlword();
      if (!cw) return cw.error();
      if (*c == Cia402Command::fault_reset && (*cw & kFaultReset) != 0) {
        return Error(Errc::wrong_state,
                     "cia402 fault_reset: controlword bit 7 is still set from the last reset, so "
                     "writing it again is no rising edge; send disable_voltage or shutdown first");
      }
      return write_cw(cia402_controlword(*c, *cw));
    }
    if (command == "set_mode") {
      const Value* m = master::find_arg(args, "mode");
      std::optional<std::int8_t> mode;
      if (m != nullptr) {
        if (const auto* text = std::get_if<std::string>(m)) {
          mode = cia402_mode_from_string(*text);
        } else if (const auto i = master::as_int64(*m); i && *i >= -128 && *i <= 127) {
          mode = static_cast<std::int8_t>(*i);
        }
      }
      if (!mode) {
        return Error(Errc::invalid_argument,
                     "cia402 set_mode needs mode: pp, pv, pt, hm, ip, csp, csv, cst or a number");
      }
      if (current.find_signal("modes_of_operation") == nullptr) {
        return Error(Errc::not_found,
                     "cia402 set_mode: modes of operation (0x6060) is not mapped; set it by SDO");
      }
      return std::vector<OutputWrite>{{"modes_of_operation", Value(std::int64_t{*mode})}};
    }
    if (command == "set_target") {
      std::vector<OutputWrite> writes;
      for (std::string_view what : {"position", "velocity", "torque"}) {
        const Value* v = master::find_arg(args, what);
        if (v == nullptr) continue;
        const std::string signal = fmt::format("target_{}", what);
        if (current.find_signal(signal) == nullptr) {
          return Error(Errc::not_found, fmt::format("cia402 set_target: {} is not mapped", signal));
        }
        writes.push_back({signal, *v});
      }
      if (writes.empty()) {
        return Error(Errc::invalid_argument,
                     "cia402 set_target needs position, velocity and/or torque");
      }
      return writes;
    }
    if (command == "move_to" || command == "release_setpoint") {
      auto cw = controlword();
      if (!cw) return cw.error();
      if (command == "release_setpoint") {
        return write_cw(static_cast<std::uint16_t>(*cw & ~kNewSetpoint));
      }
      const Value* position = master::find_arg(args, "position");
      if (position == nullptr) {
        return Error(Errc::invalid_argument, "cia402 move_to needs position");
      }
      if ((*cw & kNewSetpoint) != 0) {
        return Error(Errc::wrong_state,
                     "cia402 move_to: the previous set-point (controlword bit 4) is not "
                     "released; send release_setpoint first");
      }
      if (current.find_signal("target_position") == nullptr) {
        return Error(Errc::not_found, "cia402 move_to: target_position is not mapped");
      }
      const Value* immediate = master::find_arg(args, "immediate");
      const Value* relative = master::find_arg(args, "relative");
      std::uint16_t next = *cw | kNewSetpoint;
      next = immediate == nullptr || master::as_bool(*immediate).value_or(true)
                 ? static_cast<std::uint16_t>(next | kChangeImmediately)
                 : static_cast<std::uint16_t>(next & ~kChangeImmediately);
      next = relative != nullptr && master::as_bool(*relative).value_or(false)
                 ? static_cast<std::uint16_t>(next | kRelative)
                 : static_cast<std::uint16_t>(next & ~kRelative);
      return std::vector<OutputWrite>{{"target_position", *position},
                                      {"controlword", Value(std::uint64_t{next})}};
    }
    return Driver::command(command, args, current, state, driver_state);
  }

  Description describe(std::span<const Signal> model) const override {
    Description d = Driver::describe(model);
    d.device_type = "cia402_drive";
    for (const auto& c : kCommands)
      d.commands.push_back({std::string(c.name), "CiA 402 device control command", {}});
    d.commands.push_back({"set_mode", "modes of operation (pp pv pt hm ip csp csv cst)", {"mode"}});
    d.commands.push_back(
        {"set_target", "cyclic set-points", {"position?", "velocity?", "torque?"}});
    d.commands.push_back({"move_to",
                          "profile position: new set-point (controlword bit 4)",
                          {"position", "immediate?", "relative?"}});
    d.commands.push_back(
        {"release_setpoint", "clear controlword bit 4 after the drive acknowledged", {}});
    return d;
  }
};

}  // namespace

std::shared_ptr<const master::Driver> cia402_driver() {
  static const auto driver = std::make_shared<Cia402>();
  return driver;
}

std::vector<std::shared_ptr<const master::Driver>> builtin_drivers() {
  return {el1809_driver(), el2809_driver(), el3202_driver(), el4102_driver(), cia402_driver()};
}

}  // namespace ecat::drivers
