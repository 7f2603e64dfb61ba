// Beckhoff EL3202: 2-channel RTD input. TxPDO 0x1A00 + n maps 0x60n0 :01 underrange, :02
// overrange, :03 limit 1 (2 bits), :05 limit 2 (2 bits), :07 error, :0F TxPDO state, :10 TxPDO
// toggle, :11 value (INT16, 0.1 °C; 0.01 °C in high-resolution presentation). Settings 0x80n0:
// :02 presentation, :19 RTD element, :1A connection technology.
#include <array>

#include <fmt/format.h>

#include <ecat/drivers/drivers.hpp>

namespace ecat::drivers {

namespace {

using master::CommandArgs;
using master::Description;
using master::DeviceState;
using master::DriverConfig;
using master::DriverIdentity;
using master::PdoLayout;
using master::SdoWrite;
using master::Signal;
using master::SignalValues;
using master::Value;

constexpr int kChannels = 2;

struct Choice {
  std::string_view name;
  std::uint16_t code;
};
constexpr std::array<Choice, 8> kElements{{{"pt100", 0},
                                           {"ni100", 1},
                                           {"pt1000", 2},
                                           {"pt500", 3},
                                           {"pt200", 4},
                                           {"ni1000", 5},
                                           {"ni1000_tk1500", 6},
                                           {"ni120", 7}}};
constexpr std::array<Choice, 4> kConnections{
    {{"2_wire", 0}, {"3_wire", 1}, {"4_wire", 2}, {"not_connected", 3}}};
constexpr std::array<Choice, 2> kPresentations{{{"signed", 0}, {"high_resolution", 2}}};

struct StatusEntry {
  std::uint8_t subindex;
  std::string_view name;
};
constexpr std::array<StatusEntry, 7> kStatus{{{0x01, "underrange"},
                                              {0x02, "overrange"},
                                              {0x03, "limit_1"},
                                              {0x05, "limit_2"},
                                              {0x07, "error"},
                                              {0x0F, "txpdo_state"},
                                              {0x10, "txpdo_toggle"}}};

template <std::size_t N>
Result<std::optional<std::uint16_t>> channel_choice(const DriverConfig& config, int ch,
                                                    std::string_view option,
                                                    const std::array<Choice, N>& choices) {
  const std::string per_channel = fmt::format("channel_{}.{}", ch, option);
  auto text = config.text(per_channel);
  std::string_view key = per_channel;
  if (!text) {
    text = config.text(option);
    key = option;
  }
  if (!text) return std::optional<std::uint16_t>();
  for (const auto& c : choices) {
    if (c.name == *text) return std::optional<std::uint16_t>(c.code);
  }
  std::string list;
  for (const auto& c : choices) {
    if (!list.empty()) list += ", ";
    list += c.name;
  }
  return Error(Errc::invalid_argument,
               fmt::format("EL3202 option {}: \"{}\" is not one of {}", key, *text, list));
}

Result<void> check_options(const DriverConfig& config) {
  for (const auto& [key, value] : config.options) {
    std::string_view option = key;
    if (option.starts_with("channel_1.") || option.starts_with("channel_2.")) {
      option.remove_prefix(10);
    }
    if (option != "element" && option != "connection" && option != "presentation") {
      return Error(Errc::invalid_argument,
                   fmt::format("unknown EL3202 option \"{}\" (known: element, connection, "
                               "presentation, channel_N.<option>)",
                               key));
    }
  }
  return ok();
}

class El3202 final : public master::Driver {
 public:
  std::string_view name() const noexcept override { return "EL3202"; }
  std::vector<DriverIdentity> identities() const override {
    return {{0x00000002, 0x0C823052, std::nullopt}};
  }

  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig& config) const override {
    if (auto valid = check_options(config); !valid) return valid.error();
    std::vector<Signal> out;
    for (int ch = 1; ch <= kChannels; ++ch) {
      const auto object = static_cast<std::uint16_t>(0x6000 + 0x10 * (ch - 1));
      auto presentation = channel_choice(config, ch, "presentation", kPresentations);
      if (!presentation) return presentation.error();
      auto value =
          master::signal_for_entry(layout, object, 0x11, fmt::format("channel_{}.temperature", ch));
      if (!value) return value.error().context("EL3202 driver");
      value->type = master::SignalType::int16;
      value->unit = "°C";
      value->scale = master::LinearScale{presentation->value_or(0) == 2 ? 0.01 : 0.1, 0.0,
                                         std::nullopt, std::nullopt};
      for (const auto& st : kStatus) {
        auto s = master::signal_for_entry(layout, object, st.subindex,
                                          fmt::format("channel_{}.{}", ch, st.name));
        if (!s) continue;  // compact PDOs map the value alone
        if (s->bit_length == 1) s->type = master::SignalType::boolean;
        out.push_back(std::move(*s));
      }
      out.push_back(std::move(*value));
    }
    return out;
  }

  Result<std::vector<SdoWrite>> startup_sdos(const DriverConfig& config, master::StartupPhase phase,
                                             const master::SyncSettings& sync) const override {
    if (auto valid = check_options(config); !valid) return valid.error();
    if (phase == master::StartupPhase::sync_update) {
      return Driver::startup_sdos(config, phase, sync);
    }
    std::vector<SdoWrite> out;
    for (int ch = 1; ch <= kChannels; ++ch) {
      const auto settings = static_cast<std::uint16_t>(0x8000 + 0x10 * (ch - 1));
      auto element = channel_choice(config, ch, "element", kElements);
      if (!element) return element.error();
      auto connection = channel_choice(config, ch, "connection", kConnections);
      if (!connection) return connection.error();
      auto presentation = channel_choice(config, ch, "presentation", kPresentations);
      if (!presentation) return presentation.error();
      if (*presentation) {
        out.push_back({settings, 0x02, {static_cast<std::uint8_t>(**presentation)}, false});
      }
      if (*element) {
        out.push_back({settings, 0x19, {static_cast<std::uint8_t>(**element), 0}, false});
      }
      if (*connection) {
        out.push_back({settings, 0x1A, {static_cast<std::uint8_t>(**connection), 0}, false});
      }
    }
    return out;
  }

  Result<DeviceState> project_state(const SignalValues& current, const DeviceState* previous,
                                    master::DriverState* state) const override {
    (void)state;
    DeviceState out;
    for (int ch = 1; ch <= kChannels; ++ch) {
      const std::string prefix = fmt::format("channel_{}.", ch);
      if (const Value* t = current.find(prefix + "temperature"))
        out.set(prefix + "temperature", *t);
      auto flag = [&](std::string_view name) -> bool {
        const std::string key = prefix + std::string(name);
        const Value* v = current.find(key);
        if (v == nullptr) return false;
        const bool set = master::as_bool(*v).value_or(false);
        out.set(key, Value(set));
        return set;
      };
      const bool under = flag("underrange");
      const bool over = flag("overrange");
      const bool error = flag("error");
      if (under) out.faults.push_back(fmt::format("channel {}: underrange", ch));
      if (over) out.faults.push_back(fmt::format("channel {}: overrange", ch));
      if (error && !under && !over) out.faults.push_back(fmt::format("channel {}: error", ch));
      const std::string error_name = prefix + "error";
      const Value* now = out.find(error_name);
      const Value* before = previous != nullptr ? previous->find(error_name) : nullptr;
      if (now != nullptr && before != nullptr && *now != *before) {
        out.notices.push_back(
            fmt::format("channel {}: error {}", ch, std::get<bool>(*now) ? "raised" : "cleared"));
      }
    }
    return out;
  }

  Description describe(std::span<const Signal> model) const override {
    Description d = Driver::describe(model);
    d.device_type = "temperature_input";
    for (auto& e : d.endpoints) {
      if (e.signal.ends_with(".temperature")) {
        e.label = fmt::format("Channel {} temperature", e.signal[8]);
        e.description = "RTD temperature";
      }
    }
    return d;
  }
};

}  // namespace

std::shared_ptr<const master::Driver> el3202_driver() {
  static const auto driver = std::make_shared<El3202>();
  return driver;
}

}  // namespace ecat::drivers
