// Beckhoff EL4102: 2-channel analog output 0..10 V. RxPDO 0x1600 + n maps 0x70n0:11 (INT16,
// 0x7FFF = 10 V, negative values give 0 V). Settings 0x80n0: :05 watchdog (0 default value,
// 1 ramp to it, 2 keep the last value), :13 default output.
#include <cmath>

#include <fmt/format.h>

#include <ecat/drivers/drivers.hpp>

namespace ecat::drivers {

namespace {

using master::CommandArgs;
using master::Description;
using master::DeviceState;
using master::DriverConfig;
using master::DriverIdentity;
using master::OutputWrite;
using master::PdoLayout;
using master::SdoWrite;
using master::Signal;
using master::SignalValues;
using master::Value;

constexpr int kChannels = 2;
constexpr double kFullScaleVolts = 10.0;
constexpr double kFullScaleRaw = 32767.0;

master::LinearScale volts_scale() {
  return {kFullScaleVolts / kFullScaleRaw, 0.0, 0.0, kFullScaleVolts};
}

class El4102 final : public master::Driver {
 public:
  std::string_view name() const noexcept override { return "EL4102"; }
  std::vector<DriverIdentity> identities() const override {
    return {{0x00000002, 0x10063052, std::nullopt}};
  }

  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig& config) const override {
    if (auto known = config.check_known({"watchdog", "default_output"}); !known) {
      return known.error();
    }
    std::vector<Signal> out;
    for (int ch = 1; ch <= kChannels; ++ch) {
      const auto object = static_cast<std::uint16_t>(0x7000 + 0x10 * (ch - 1));
      auto s = master::signal_for_entry(layout, object, 0x11, fmt::format("channel_{}.output", ch));
      if (!s) return s.error().context("EL4102 driver");
      s->type = master::SignalType::int16;
      s->unit = "V";
      s->scale = volts_scale();
      out.push_back(std::move(*s));
    }
    return out;
  }

  Result<std::vector<SdoWrite>> startup_sdos(const DriverConfig& config, master::StartupPhase phase,
                                             const master::SyncSettings& sync) const override {
    if (auto known = config.check_known({"watchdog", "default_output"}); !known) {
      return known.error();
    }
    if (phase == master::StartupPhase::sync_update) {
      return Driver::startup_sdos(config, phase, sync);
    }
    std::vector<SdoWrite> out;
    std::optional<std::uint8_t> watchdog;
    if (const auto text = config.text("watchdog")) {
      if (*text == "default_value") {
        watchdog = 0;
      } else if (*text == "ramp") {
        watchdog = 1;
      } else if (*text == "last_value") {
        watchdog = 2;
      } else {
        return Error(Errc::invalid_argument,
                     fmt::format("EL4102 option watchdog: \"{}\" is not one of default_value, "
                                 "ramp, last_value",
                                 *text));
      }
    }
    auto volts = config.number("default_output");
    if (!volts) return volts.error();
    std::optional<std::int16_t> default_raw;
    if (*volts) {
      const double v = volts->value_or(0.0);
      if (!(v >= 0.0 && v <= kFullScaleVolts)) {
        return Error(Errc::out_of_range,
                     fmt::format("EL4102 option default_output: {} V out of range 0..10 V", v));
      }
      default_raw = static_cast<std::int16_t>(std::lround(v / kFullScaleVolts * kFullScaleRaw));
    }
    for (int ch = 1; ch <= kChannels; ++ch) {
      const auto settings = static_cast<std::uint16_t>(0x8000 + 0x10 * (ch - 1));
      if (watchdog) out.push_back({settings, 0x05, {*watchdog}, false});
      if (default_raw) {
        const auto raw = static_cast<std::uint16_t>(*default_raw);
        out.push_back({settings,
                       0x13,
                       {static_cast<std::uint8_t>(raw), static_cast<std::uint8_t>(raw >> 8)},
                       false});
      }
    }
    return out;
  }

  Result<std::vector<OutputWrite>> command(std::string_view command, const CommandArgs& args,
                                           const SignalValues& current, const DeviceState& state,
                                           master::DriverState* driver_state) const override {
    // set_voltage {channel: 1|2, volts: 0..10}
    if (command == "set_voltage") {
      const Value* channel = master::find_arg(args, "channel");
      const Value* volts = master::find_arg(args, "volts");
      // Plain values, not optionals: GCC's -O1 flow analysis misreads an optional's engaged check.
      std::int64_t ch = 0;  // 0: missing or not an integer
      if (channel != nullptr) ch = master::as_int64(*channel).value_or(0);
      const auto v = volts != nullptr ? master::as_double(*volts) : std::nullopt;
      if (ch < 1 || ch > kChannels || !v) {
        return Error(Errc::invalid_argument,
                     "EL4102 set_voltage needs channel (1 or 2) and volts (a number)");
      }
      const double value = v.value_or(0.0);
      if (!(value >= 0.0 && value <= kFullScaleVolts)) {
        return Error(Errc::out_of_range,
                     fmt::format("EL4102 set_voltage: {} V out of range 0..10 V", value));
      }
      return std::vector<OutputWrite>{{fmt::format("channel_{}.output", ch), Value(value)}};
    }
    return Driver::command(command, args, current, state, driver_state);
  }

  Description describe(std::span<const Signal> model) const override {
    Description d = Driver::describe(model);
    d.device_type = "analog_output";
    for (auto& e : d.endpoints) {
      e.label = fmt::format("Channel {} output voltage", e.signal.substr(8, 1));
      e.description = "0..10 V";
    }
    d.commands.push_back({"set_voltage", "set one channel's output voltage", {"channel", "volts"}});
    return d;
  }
};

}  // namespace

std::shared_ptr<const master::Driver> el4102_driver() {
  static const auto driver = std::make_shared<El4102>();
  return driver;
}

}  // namespace ecat::drivers
