// The Beckhoff terminal drivers against the simulator's profiles.
#include <gtest/gtest.h>

#include <ecat/drivers/drivers.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::drivers {
namespace {

using master::DeviceState;
using master::DriverConfig;
using master::OutputWrite;
using master::PdoDirection;
using master::PdoLayout;
using master::Signal;
using master::SignalType;
using master::SignalValues;
using master::Value;

PdoLayout profile_layout(const std::string& profile) {
  sim::DeviceConfig config;
  config.profile = profile;
  auto esc = sim::make_device(config);
  EXPECT_TRUE(esc.ok());
  auto decoded = wire::decode_sii((*esc)->eeprom());
  EXPECT_TRUE(decoded.ok());
  auto layout = master::pdo_layout_from_sii(decoded->image);
  EXPECT_TRUE(layout.ok());
  return *layout;
}

const Signal& named(const std::vector<Signal>& signals, std::string_view name) {
  for (const auto& s : signals) {
    if (s.name == name) return s;
  }
  ADD_FAILURE() << "no signal " << name;
  static const Signal none;
  return none;
}

// The values of every signal, decoded (engineering units) from per-SM images.
std::vector<Value> decode_all(const std::vector<Signal>& signals,
                              const std::map<std::uint8_t, std::vector<std::uint8_t>>& images) {
  std::vector<Value> out;
  for (const auto& s : signals) {
    auto v = master::decode_scaled(s, images.at(s.sync_manager));
    EXPECT_TRUE(v.ok()) << s.name;
    out.push_back(v.ok() ? *v : Value(false));
  }
  return out;
}

TEST(El1809Driver, SixteenBooleanInputsOnSm0) {
  const auto driver = el1809_driver();
  auto signals = driver->signal_model(profile_layout("EL1809"), {});
  ASSERT_TRUE(signals.ok()) << signals.error().describe();
  ASSERT_EQ(signals->size(), 16u);
  for (int ch = 1; ch <= 16; ++ch) {
    const Signal& s = (*signals)[ch - 1];
    EXPECT_EQ(s.name, "channel_" + std::to_string(ch));
    EXPECT_EQ(s.type, SignalType::boolean);
    EXPECT_EQ(s.direction, PdoDirection::input);
    EXPECT_EQ(s.sync_manager, 0);
    EXPECT_EQ(s.bit_offset, static_cast<std::uint32_t>(ch - 1));
  }
  const std::vector<std::uint8_t> image{0x01, 0x80};
  const auto values = decode_all(*signals, {{0, image}});
  EXPECT_EQ(values[0], Value(true));
  EXPECT_EQ(values[1], Value(false));
  EXPECT_EQ(values[15], Value(true));
  auto state = driver->project_state(SignalValues(*signals, values), nullptr, nullptr);
  ASSERT_TRUE(state.ok());
  EXPECT_EQ(*state->find("channel_16"), Value(true));
  EXPECT_EQ(driver->describe(*signals).device_type, "digital_input");
  // An EL2809 layout does not fit the EL1809 driver.
  EXPECT_FALSE(driver->signal_model(profile_layout("EL2809"), {}).ok());
}

TEST(El2809Driver, OutputsOnTwoSyncManagersAndSetChannels) {
  const auto driver = el2809_driver();
  auto signals = driver->signal_model(profile_layout("EL2809"), {});
  ASSERT_TRUE(signals.ok());
  const Signal& ch9 = named(*signals, "channel_9");
  EXPECT_EQ(ch9.sync_manager, 1);
  EXPECT_EQ(ch9.bit_offset, 0u);
  EXPECT_EQ(ch9.direction, PdoDirection::output);
  std::vector<Value> values(16, Value(false));
  const SignalValues current(*signals, values);
  auto writes = driver->command("set_channels", {{"mask", Value(std::uint64_t{0x8101})}}, current,
                                DeviceState{}, nullptr);
  ASSERT_TRUE(writes.ok());
  ASSERT_EQ(writes->size(), 16u);
  std::map<std::uint8_t, std::vector<std::uint8_t>> images{{0, {0}}, {1, {0}}};
  for (const auto& w : *writes) {
    const Signal& s = named(*signals, w.signal);
    ASSERT_TRUE(master::encode_scaled(s, w.value, images[s.sync_manager]).ok());
  }
  EXPECT_EQ(images[0], std::vector<std::uint8_t>{0x01});
  EXPECT_EQ(images[1], std::vector<std::uint8_t>{0x81});
  EXPECT_FALSE(driver
                   ->command("set_channels", {{"mask", Value(std::uint64_t{0x10000})}}, current,
                             DeviceState{}, nullptr)
                   .ok());
  auto single = driver->command(
      "set_output", {{"signal", Value(std::string("channel_2"))}, {"value", Value(true)}}, current,
      DeviceState{}, nullptr);
  ASSERT_TRUE(single.ok());
  EXPECT_EQ(*single, (std::vector<OutputWrite>{{"channel_2", Value(true)}}));
}

TEST(El3202Driver, TemperatureStatusAndFaults) {
  const auto driver = el3202_driver();
  auto signals = driver->signal_model(profile_layout("EL3202"), {});
  ASSERT_TRUE(signals.ok()) << signals.error().describe();
  ASSERT_EQ(signals->size(), 16u);
  const Signal& t1 = named(*signals, "channel_1.temperature");
  EXPECT_EQ(t1.bit_offset, 16u);
  EXPECT_EQ(t1.unit, "°C");
  const Signal& t2 = named(*signals, "channel_2.temperature");
  EXPECT_EQ(t2.bit_offset, 48u);
  EXPECT_EQ(named(*signals, "channel_2.error").bit_offset, 38u);
  EXPECT_EQ(named(*signals, "channel_1.limit_2").type, SignalType::uint8);

  // Channel 1: 21.5 °C; channel 2: overrange + error, value clamped at 850.0 °C.
  std::vector<std::uint8_t> image(8, 0);
  ASSERT_TRUE(master::encode(t1, Value(std::int64_t{215}), image).ok());
  ASSERT_TRUE(master::encode(t2, Value(std::int64_t{8500}), image).ok());
  ASSERT_TRUE(master::encode(named(*signals, "channel_2.overrange"), Value(true), image).ok());
  ASSERT_TRUE(master::encode(named(*signals, "channel_2.error"), Value(true), image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0x00, 0x00, 0xD7, 0x00, 0x42, 0x00, 0x34, 0x21}));
  const auto values = decode_all(*signals, {{3, image}});
  auto state = driver->project_state(SignalValues(*signals, values), nullptr, nullptr);
  ASSERT_TRUE(state.ok());
  EXPECT_EQ(*state->find("channel_1.temperature"), Value(21.5));
  EXPECT_EQ(*state->find("channel_2.temperature"), Value(850.0));
  EXPECT_EQ(*state->find("channel_2.overrange"), Value(true));
  EXPECT_EQ(*state->find("channel_1.error"), Value(false));
  EXPECT_EQ(state->faults, std::vector<std::string>{"channel 2: overrange"});
  EXPECT_TRUE(state->notices.empty());

  // The error clears: a notice.
  std::vector<std::uint8_t> fine(8, 0);
  auto next = driver->project_state(SignalValues(*signals, decode_all(*signals, {{3, fine}})),
                                    &*state, nullptr);
  ASSERT_TRUE(next.ok());
  EXPECT_TRUE(next->faults.empty());
  EXPECT_EQ(next->notices, std::vector<std::string>{"channel 2: error cleared"});
}

TEST(El3202Driver, StartupSdosFromOptions) {
  const auto driver = el3202_driver();
  DriverConfig config;
  config.options = {{"element", "pt1000"},
                    {"channel_2.element", "ni100"},
                    {"connection", "3_wire"},
                    {"presentation", "high_resolution"}};
  auto writes = driver->startup_sdos(config, master::StartupPhase::preop, {});
  ASSERT_TRUE(writes.ok()) << writes.error().describe();
  std::vector<std::string> text;
  for (const auto& w : *writes)
    text.push_back(master::to_string(w));
  EXPECT_EQ(text,
            (std::vector<std::string>{"0x8000:02 = 02", "0x8000:19 = 02 00", "0x8000:1a = 01 00",
                                      "0x8010:02 = 02", "0x8010:19 = 01 00", "0x8010:1a = 01 00"}));
  auto signals = driver->signal_model(profile_layout("EL3202"), config);
  ASSERT_TRUE(signals.ok());
  EXPECT_EQ(named(*signals, "channel_1.temperature").scale->factor, 0.01);

  DriverConfig bad;
  bad.options = {{"element", "pt9999"}};
  auto e = driver->startup_sdos(bad, master::StartupPhase::preop, {});
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.error().message(),
            "EL3202 option element: \"pt9999\" is not one of pt100, ni100, pt1000, pt500, pt200, "
            "ni1000, ni1000_tk1500, ni120");
  DriverConfig unknown;
  unknown.options = {{"channel_3.element", "pt100"}};
  EXPECT_FALSE(driver->signal_model(profile_layout("EL3202"), unknown).ok());
  EXPECT_TRUE(driver->startup_sdos({}, master::StartupPhase::preop, {})->empty());
}

TEST(El4102Driver, VoltsToRawAndRangeChecks) {
  const auto driver = el4102_driver();
  auto signals = driver->signal_model(profile_layout("EL4102"), {});
  ASSERT_TRUE(signals.ok());
  ASSERT_EQ(signals->size(), 2u);
  const Signal& out2 = named(*signals, "channel_2.output");
  EXPECT_EQ(out2.sync_manager, 2);
  EXPECT_EQ(out2.bit_offset, 16u);
  EXPECT_EQ(out2.unit, "V");

  std::vector<Value> values(2, Value(0.0));
  const SignalValues current(*signals, values);
  auto writes =
      driver->command("set_voltage", {{"channel", Value(std::int64_t{2})}, {"volts", Value(2.5)}},
                      current, DeviceState{}, nullptr);
  ASSERT_TRUE(writes.ok());
  ASSERT_EQ(writes->size(), 1u);
  std::vector<std::uint8_t> image(4, 0);
  ASSERT_TRUE(master::encode_scaled(out2, (*writes)[0].value, image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0, 0, 0x00, 0x20}));  // 8191.75 -> 8192
  ASSERT_TRUE(master::encode_scaled(out2, Value(10.0), image).ok());
  EXPECT_EQ(image, (std::vector<std::uint8_t>{0, 0, 0xFF, 0x7F}));
  EXPECT_FALSE(master::encode_scaled(out2, Value(-0.1), image).ok());
  auto high =
      driver->command("set_voltage", {{"channel", Value(std::int64_t{1})}, {"volts", Value(11.0)}},
                      current, DeviceState{}, nullptr);
  ASSERT_FALSE(high.ok());
  EXPECT_EQ(high.error().message(), "EL4102 set_voltage: 11 V out of range 0..10 V");
  EXPECT_FALSE(driver
                   ->command("set_voltage",
                             {{"channel", Value(std::int64_t{3})}, {"volts", Value(1.0)}}, current,
                             DeviceState{}, nullptr)
                   .ok());

  DriverConfig config;
  config.options = {{"watchdog", "last_value"}, {"default_output", "5"}};
  auto sdos = driver->startup_sdos(config, master::StartupPhase::preop, {});
  ASSERT_TRUE(sdos.ok());
  std::vector<std::string> text;
  for (const auto& w : *sdos)
    text.push_back(master::to_string(w));
  EXPECT_EQ(text, (std::vector<std::string>{"0x8000:05 = 02", "0x8000:13 = 00 40", "0x8010:05 = 02",
                                            "0x8010:13 = 00 40"}));
  config.options = {{"default_output", "12"}};
  EXPECT_FALSE(driver->startup_sdos(config, master::StartupPhase::preop, {}).ok());
  EXPECT_EQ(driver->describe(*signals).device_type, "analog_output");
}

}  // namespace
}  // namespace ecat::drivers
