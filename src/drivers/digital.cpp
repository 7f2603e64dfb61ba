// Beckhoff EL1809 / EL2809: 16 digital channels, one 1-bit PDO each (0x1A00.. mapping 0x6000 +
// 0x10 * n : 01, 0x1600.. mapping 0x7000 + 0x10 * n : 01).
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
using master::PdoDirection;
using master::PdoLayout;
using master::Signal;
using master::SignalValues;

constexpr std::uint32_t kBeckhoff = 0x00000002;

class DigitalTerminal final : public master::Driver {
 public:
  DigitalTerminal(std::string_view name, std::uint32_t product, std::uint16_t object_base,
                  PdoDirection direction)
      : name_(name), product_(product), object_base_(object_base), direction_(direction) {}

  std::string_view name() const noexcept override { return name_; }
  std::vector<DriverIdentity> identities() const override {
    return {{kBeckhoff, product_, std::nullopt}};
  }

  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig& config) const override {
    if (auto known = config.check_known({}); !known) return known.error();
    std::vector<Signal> out;
    for (int ch = 1; ch <= kChannels; ++ch) {
      const auto index = static_cast<std::uint16_t>(object_base_ + 0x10 * (ch - 1));
      auto s = master::signal_for_entry(layout, index, 0x01, fmt::format("channel_{}", ch));
      if (!s) return s.error().context(fmt::format("{} driver", name_));
      if (s->direction != direction_) {
        return Error(
            Errc::invalid_argument,
            fmt::format("{} driver: 0x{:04x}:01 is mapped as {}, expected {}", name_, index,
                        master::to_string(s->direction), master::to_string(direction_)));
      }
      s->type = master::SignalType::boolean;
      out.push_back(std::move(*s));
    }
    return out;
  }

  Result<std::vector<OutputWrite>> command(std::string_view command, const CommandArgs& args,
                                           const SignalValues& current, const DeviceState& state,
                                           master::DriverState* driver_state) const override {
    // set_channels {mask}: all 16 outputs at once, bit n-1 = channel n.
    if (direction_ == PdoDirection::output && command == "set_channels") {
      const master::Value* mask = master::find_arg(args, "mask");
      const auto bits = mask != nullptr ? master::as_uint64(*mask) : std::nullopt;
      if (!bits || *bits > 0xFFFF) {
        return Error(Errc::invalid_argument,
                     fmt::format("{} set_channels: mask must be 0..0xffff", name_));
      }
      std::vector<OutputWrite> writes;
      for (int ch = 1; ch <= kChannels; ++ch) {
        writes.push_back(
            {fmt::format("channel_{}", ch), master::Value(((*bits >> (ch - 1)) & 1u) != 0)});
      }
      return writes;
    }
    return Driver::command(command, args, current, state, driver_state);
  }

  Description describe(std::span<const Signal> model) const override {
    Description d = Driver::describe(model);
    d.device_type = direction_ == PdoDirection::input ? "digital_input" : "digital_output";
    for (auto& e : d.endpoints)
      e.label = fmt::format("{} {}", name_, e.signal);
    if (direction_ == PdoDirection::output) {
      d.commands.push_back(
          {"set_channels", "write all 16 outputs: bit n-1 of mask = channel n", {"mask"}});
    }
    return d;
  }

 private:
  static constexpr int kChannels = 16;
  std::string_view name_;
  std::uint32_t product_;
  std::uint16_t object_base_;
  PdoDirection direction_;
};

}  // namespace

std::shared_ptr<const master::Driver> el1809_driver() {
  static const auto driver =
      std::make_shared<DigitalTerminal>("EL1809", 0x07113052, 0x6000, PdoDirection::input);
  return driver;
}

std::shared_ptr<const master::Driver> el2809_driver() {
  static const auto driver =
      std::make_shared<DigitalTerminal>("EL2809", 0x0AF93052, 0x7000, PdoDirection::output);
  return driver;
}

}  // namespace ecat::drivers
