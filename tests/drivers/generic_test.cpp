// The generic driver's signal names on the simulator's profiles and on real SII images, and the
// driver registry.
#include <set>

#include <gtest/gtest.h>

#include <ecat/drivers/drivers.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/wire/sii.hpp>

#include "master/master_test_support.hpp"
#include "support/shared_data.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

PdoLayout layout_of(std::span<const std::uint8_t> eeprom) {
  auto decoded = wire::decode_sii(eeprom);
  EXPECT_TRUE(decoded.ok());
  auto layout = pdo_layout_from_sii(decoded->image);
  EXPECT_TRUE(layout.ok());
  return layout.ok() ? *layout : PdoLayout{};
}

PdoLayout profile_layout(const std::string& profile) {
  sim::DeviceConfig config;
  config.profile = profile;
  auto esc = sim::make_device(config);
  EXPECT_TRUE(esc.ok());
  return layout_of((*esc)->eeprom());
}

std::vector<std::string> names(const std::vector<Signal>& signals) {
  std::vector<std::string> out;
  for (const auto& s : signals)
    out.push_back(s.name);
  return out;
}

TEST(GenericDriver, El2809ChannelsAreChannelNOutput) {
  auto signals = generic_signal_model(profile_layout("EL2809"));
  ASSERT_TRUE(signals.ok());
  ASSERT_EQ(signals->size(), 16u);
  for (int ch = 1; ch <= 16; ++ch) {
    const Signal& s = (*signals)[ch - 1];
    EXPECT_EQ(s.name, "channel_" + std::to_string(ch) + ".output");
    EXPECT_EQ(s.direction, PdoDirection::output);
    EXPECT_EQ(s.sync_manager, ch <= 8 ? 0 : 1);
    EXPECT_EQ(s.bit_offset, static_cast<std::uint32_t>((ch - 1) % 8));
    EXPECT_EQ(s.type, SignalType::boolean);
    EXPECT_EQ(s.pdo_index, 0x1600 + ch - 1);
    EXPECT_EQ(s.index, 0x7000 + 0x10 * (ch - 1));
  }
}

TEST(GenericDriver, El3202SkipsTheGapAndNamesEveryEntry) {
  auto signals = generic_signal_model(profile_layout("EL3202"));
  ASSERT_TRUE(signals.ok());
  const std::vector<std::string> ch1{
      "rtd_inputs_channel_1.status_underrange",   "rtd_inputs_channel_1.status_overrange",
      "rtd_inputs_channel_1.status_limit_1",      "rtd_inputs_channel_1.status_limit_2",
      "rtd_inputs_channel_1.status_error",        "rtd_inputs_channel_1.status_txpdo_state",
      "rtd_inputs_channel_1.status_txpdo_toggle", "rtd_inputs_channel_1.value"};
  ASSERT_EQ(signals->size(), 16u);
  const auto all = names(*signals);
  EXPECT_EQ(std::vector<std::string>(all.begin(), all.begin() + 8), ch1);
  EXPECT_EQ((*signals)[2].type, SignalType::uint8);  // BIT2
  EXPECT_EQ((*signals)[2].bit_length, 2);
  EXPECT_EQ((*signals)[7].type, SignalType::int16);
  EXPECT_EQ((*signals)[7].bit_offset, 16u);
  EXPECT_EQ((*signals)[15].name, "rtd_inputs_channel_2.value");
  EXPECT_EQ((*signals)[15].bit_offset, 48u);
}

TEST(GenericDriver, ServoEntriesUnderTheirPdoNames) {
  auto signals = generic_signal_model(profile_layout("servo"));
  ASSERT_TRUE(signals.ok());
  EXPECT_EQ(names(*signals),
            (std::vector<std::string>{
                "rxpdo_1.controlword", "rxpdo_1.target_position", "rxpdo_1.target_velocity",
                "rxpdo_1.target_torque", "rxpdo_1.modes_of_operation", "txpdo_1.statusword",
                "txpdo_1.position_actual_value", "txpdo_1.velocity_actual_value",
                "txpdo_1.torque_actual_value", "txpdo_1.modes_of_operation_display",
                "txpdo_1.error_code"}));
  EXPECT_EQ((*signals)[4].type, SignalType::int8);
  EXPECT_EQ((*signals)[4].bit_offset, 96u);
}

TEST(GenericDriver, DuplicatesAndMissingNamesAreDeterministic) {
  Pdo a{0x1A00, PdoDirection::input, 3, "", {{0x6000, 1, 8, 0, "", 0}, {0, 0, 8, 0, "", 0}}};
  Pdo b{0x1A01, PdoDirection::input, 3, "Same", {{0x6010, 1, 8, 0, "X", 0}}};
  Pdo c{0x1A02, PdoDirection::input, 3, "Same", {{0x6020, 1, 8, 0, "X", 0}}};
  Pdo d{0x1A03, PdoDirection::input, 3, "Same", {{0x6030, 1, 8, 0, "x", 0}}};
  auto layout = make_pdo_layout({a, b, c, d});
  ASSERT_TRUE(layout.ok());
  auto signals = generic_signal_model(*layout);
  ASSERT_TRUE(signals.ok());
  EXPECT_EQ(names(*signals),
            (std::vector<std::string>{"pdo_1a00.6000_01", "same.x", "same.x_2", "same.x_3"}));
  EXPECT_EQ((*signals)[1].bit_offset, 16u);
}

TEST(GenericDriver, RealImagesGiveUniqueValidNames) {
  struct Case {
    const char* file;
    std::size_t count;
    const char* first;
  };
  const Case cases[] = {{"eeprom/ek1100.bin", 0, ""},
                        {"eeprom/el2004.bin", 4, "channel_1.output"},
                        {"eeprom/el2828.bin", 8, "channel_1.output"},
                        {"eeprom/el2262.bin", 7, "cyccount0.cycle_counter0"}};
  for (const auto& c : cases) {
    const auto path = ::ecat::test::shared_data(c.file);
    if (!path) {
      GTEST_SKIP() << "real-device data " << c.file << " not found";
    }
    const auto image = ::ecat::test::read_file(*path);
    const PdoLayout layout = layout_of(image);
    auto signals = generic_signal_model(layout);
    ASSERT_TRUE(signals.ok()) << c.file;
    ASSERT_EQ(signals->size(), c.count) << c.file;
    std::set<std::string> unique;
    for (const auto& s : *signals) {
      EXPECT_TRUE(unique.insert(s.name).second) << s.name;
      EXPECT_TRUE(validate_signal(s, layout.find_sync_manager(s.sync_manager)->byte_length()).ok());
    }
    if (c.count != 0) {
      EXPECT_EQ(signals->front().name, c.first) << c.file;
    }
  }
}

TEST(GenericDriver, El2262DuplicatePdoNamesGetSuffixes) {
  ECAT_SHARED_DATA_OR_SKIP(path, "eeprom/el2262.bin");
  auto signals = generic_signal_model(layout_of(::ecat::test::read_file(path)));
  ASSERT_TRUE(signals.ok());
  EXPECT_EQ(names(*signals), (std::vector<std::string>{
                                 "cyccount0.cycle_counter0", "sample0.output0", "sample0.output0_2",
                                 "cyccount1.cycle_counter1", "sample1.output1", "sample1.output1_2",
                                 "starttimenextoutput.starttimenextoutput"}));
  EXPECT_EQ((*signals)[2].type, SignalType::uint8);
  EXPECT_EQ((*signals)[2].bit_offset, 17u);
  EXPECT_EQ((*signals)[6].direction, PdoDirection::input);
}

TEST(GenericDriver, DefaultProjectionCommandsAndDescription) {
  const auto driver = generic_driver();
  auto signals = driver->signal_model(profile_layout("EL2809"), {});
  ASSERT_TRUE(signals.ok());
  std::vector<Value> values(signals->size(), Value(false));
  values[2] = Value(true);
  const SignalValues current(*signals, values);
  auto state = driver->project_state(current, nullptr, nullptr);
  ASSERT_TRUE(state.ok());
  ASSERT_EQ(state->values.size(), 16u);
  EXPECT_EQ(*state->find("channel_3.output"), Value(true));
  EXPECT_TRUE(state->faults.empty());

  auto writes = driver->command(
      "set_output", {{"signal", Value(std::string("channel_4.output"))}, {"value", Value(true)}},
      current, *state, nullptr);
  ASSERT_TRUE(writes.ok());
  EXPECT_EQ(*writes, (std::vector<OutputWrite>{{"channel_4.output", Value(true)}}));
  EXPECT_EQ(
      driver
          ->command("set_output", {{"signal", Value(std::string("nope"))}, {"value", Value(true)}},
                    current, *state, nullptr)
          .error()
          .code(),
      Errc::not_found);
  auto unknown = driver->command("explode", {}, current, *state, nullptr);
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().message(), "driver generic has no command 'explode'");

  const Description d = driver->describe(*signals);
  EXPECT_EQ(d.device_type, "generic");
  ASSERT_EQ(d.endpoints.size(), 16u);
  EXPECT_EQ(d.endpoints[0].signal, "channel_1.output");
  EXPECT_EQ(d.endpoints[0].direction, PdoDirection::output);
  EXPECT_EQ(d.commands.at(0).name, "set_output");

  DriverConfig config;
  config.options["bogus"] = "1";
  EXPECT_FALSE(driver->signal_model(profile_layout("EL2809"), config).ok());
}

TEST(SyncModeWrites, ObjectsAndValues) {
  auto writes = sync_mode_writes({SmSyncMode::sync0, SmSyncMode::sm2_event, 1'000'000});
  ASSERT_TRUE(writes.ok());
  std::vector<std::string> text;
  for (const auto& w : *writes)
    text.push_back(to_string(w));
  EXPECT_EQ(text, (std::vector<std::string>{"0x1c32:01 = 02 00", "0x1c32:02 = 40 42 0f 00",
                                            "0x1c33:01 = 22 00", "0x1c33:02 = 40 42 0f 00"}));
  EXPECT_FALSE(sync_mode_writes({SmSyncMode::sm2_event, std::nullopt, 0}).ok());
  EXPECT_TRUE(sync_mode_writes({}).value().empty());
  auto generic = generic_driver()->startup_sdos({}, StartupPhase::sync_update,
                                                {SmSyncMode::free_run, std::nullopt, 0});
  ASSERT_TRUE(generic.ok());
  ASSERT_EQ(generic->size(), 1u);
  EXPECT_EQ(to_string((*generic)[0]), "0x1c32:01 = 00 00");
  EXPECT_TRUE(generic_driver()
                  ->startup_sdos({}, StartupPhase::preop, {SmSyncMode::free_run, std::nullopt, 0})
                  ->empty());
}

TEST(DriverConfig, TypedReaders) {
  DriverConfig c;
  c.options = {{"a", "2.5"}, {"b", "0x10"}, {"c", "yes"}, {"d", "x"}};
  EXPECT_EQ(c.number("a").value(), 2.5);
  EXPECT_EQ(c.integer("b").value(), 16);
  EXPECT_EQ(c.boolean("c").value(), true);
  EXPECT_FALSE(c.number("d").ok());
  EXPECT_FALSE(c.integer("a").ok());
  EXPECT_EQ(c.number("missing").value(), std::nullopt);
  auto unknown = c.check_known({"a", "b", "c"});
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().message(), "unknown driver option \"d\" (known: a, b, c)");
}

class UserDriver final : public Driver {
 public:
  std::string_view name() const noexcept override { return "mine"; }
  std::vector<DriverIdentity> identities() const override {
    return {{0x00000002, 0x07113052, 0x00120000}};
  }
  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig&) const override {
    return generic_signal_model(layout);
  }
};

TEST(DriverRegistry, BuiltinsByIdentityGenericFallbackUserOverride) {
  DriverRegistry registry = drivers::builtin_registry();
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x07113052, 0x00120000, 0})->name(), "EL1809");
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x0AF93052, 0x00100000, 0})->name(), "EL2809");
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x0C823052, 0, 0})->name(), "EL3202");
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x10063052, 0, 0})->name(), "EL4102");
  EXPECT_EQ(registry.find(wire::SiiIdentity{0xACE, 0x2402, 0x00010000, 0})->name(), "cia402");
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x07D43052, 0, 0})->name(), "generic");
  EXPECT_EQ(registry.find("cia402")->name(), "cia402");
  EXPECT_EQ(registry.find("generic")->name(), "generic");
  EXPECT_EQ(registry.find("nothing"), nullptr);

  registry.add(std::make_shared<UserDriver>());
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x07113052, 0x00120000, 0})->name(), "mine");
  // The user's driver is only for revision 0x00120000.
  EXPECT_EQ(registry.find(wire::SiiIdentity{2, 0x07113052, 0x00130000, 0})->name(), "EL1809");
  EXPECT_EQ(DriverRegistry().find(wire::SiiIdentity{2, 0x07113052, 0, 0})->name(), "generic");
}

// Every revision of the EL1809, under another name: what an application's own driver looks like.
class ApplicationInputs final : public Driver {
 public:
  std::string_view name() const noexcept override { return "application_inputs"; }
  std::vector<DriverIdentity> identities() const override {
    return {{0x00000002, 0x07113052, std::nullopt}};
  }
  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig&) const override {
    return generic_signal_model(layout);
  }
};

// MasterConfig::drivers: the built-in drivers unless changed; an application's own driver is
// added the same way and wins over the built-in one for the devices it claims.
TEST(DriverRegistry, AMasterUsesTheDriversOfItsConfiguration) {
  constexpr const char* kRing = test::kTerminalRing;
  for (const bool own : {false, true}) {
    SCOPED_TRACE(own ? "with the application's driver" : "built-ins");
    auto server = test::make_sim_server(kRing);
    ASSERT_TRUE(server);
    auto link = server->serve_memory();
    ASSERT_TRUE(link);
    MasterConfig config;
    config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 5s};
    config.dc.reset();
    if (own) config.drivers.add(std::make_shared<ApplicationInputs>());
    Master master(config);
    ASSERT_TRUE(master.start(std::move(*link)));
    ASSERT_TRUE(master.await_running(10s));
    auto inputs = master.slave("slave_1");
    ASSERT_TRUE(inputs) << inputs.error().describe();
    EXPECT_EQ((*inputs)->info().driver, own ? "application_inputs" : "EL1809");
    auto outputs = master.slave("slave_2");
    ASSERT_TRUE(outputs);
    EXPECT_EQ((*outputs)->info().driver, "EL2809");
    EXPECT_TRUE(master.stop());
  }
}

}  // namespace
}  // namespace ecat::master
