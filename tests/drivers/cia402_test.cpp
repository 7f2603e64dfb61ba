// The CiA 402 driver: statusword decoding, controlword commands, and a command sequence run
// against the simulator's drive model.
#include "sim/devices/cia402.hpp"

#include <gtest/gtest.h>

#include <ecat/drivers/drivers.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::drivers {
namespace {

using master::DeviceState;
using master::OutputWrite;
using master::Signal;
using master::SignalValues;
using master::Value;

TEST(Cia402State, EveryStatuswordMatchesTheStateTable) {
  struct Row {
    std::uint16_t mask;
    std::uint16_t pattern;
    Cia402State state;
  };
  const Row table[] = {{0x4F, 0x00, Cia402State::not_ready_to_switch_on},
                       {0x4F, 0x40, Cia402State::switch_on_disabled},
                       {0x6F, 0x21, Cia402State::ready_to_switch_on},
                       {0x6F, 0x23, Cia402State::switched_on},
                       {0x6F, 0x27, Cia402State::operation_enabled},
                       {0x6F, 0x07, Cia402State::quick_stop_active},
                       {0x4F, 0x0F, Cia402State::fault_reaction_active},
                       {0x4F, 0x08, Cia402State::fault}};
  std::map<Cia402State, int> counts;
  for (std::uint32_t sw = 0; sw <= 0xFFFF; ++sw) {
    Cia402State expected = Cia402State::unknown;
    for (const auto& row : table) {
      if ((sw & row.mask) == row.pattern) expected = row.state;
    }
    ASSERT_EQ(cia402_state(static_cast<std::uint16_t>(sw)), expected) << std::hex << sw;
    ++counts[expected];
  }
  // Each 0x4F row leaves 11 bits free, each 0x6F row 10.
  EXPECT_EQ(counts[Cia402State::fault], 2048);
  EXPECT_EQ(counts[Cia402State::operation_enabled], 1024);
  EXPECT_GT(counts[Cia402State::unknown], 0);
}

TEST(Cia402State, AgreesWithTheSimulatedDrive) {
  using sim::devices::Ds402State;
  const std::pair<Ds402State, Cia402State> pairs[] = {
      {Ds402State::not_ready_to_switch_on, Cia402State::not_ready_to_switch_on},
      {Ds402State::switch_on_disabled, Cia402State::switch_on_disabled},
      {Ds402State::ready_to_switch_on, Cia402State::ready_to_switch_on},
      {Ds402State::switched_on, Cia402State::switched_on},
      {Ds402State::operation_enabled, Cia402State::operation_enabled},
      {Ds402State::quick_stop_active, Cia402State::quick_stop_active},
      {Ds402State::fault_reaction_active, Cia402State::fault_reaction_active},
      {Ds402State::fault, Cia402State::fault}};
  for (const auto& [sim_state, state] : pairs) {
    const std::uint16_t sw = sim::devices::ds402_statusword(sim_state);
    EXPECT_EQ(cia402_state(sw), state) << to_string(state);
    EXPECT_EQ(cia402_state(static_cast<std::uint16_t>(sw | 0x3C80)), state) << to_string(state);
  }
}

TEST(Cia402Controlword, CommandsKeepModeBitsAndEdgeTheFaultReset) {
  EXPECT_EQ(cia402_controlword(Cia402Command::shutdown, 0x0000), 0x0006);
  EXPECT_EQ(cia402_controlword(Cia402Command::switch_on, 0x0006), 0x0007);
  EXPECT_EQ(cia402_controlword(Cia402Command::enable_operation, 0x0007), 0x000F);
  EXPECT_EQ(cia402_controlword(Cia402Command::disable_operation, 0x000F), 0x0007);
  EXPECT_EQ(cia402_controlword(Cia402Command::disable_voltage, 0x000F), 0x0000);
  EXPECT_EQ(cia402_controlword(Cia402Command::quick_stop, 0x000F), 0x0002);
  EXPECT_EQ(cia402_controlword(Cia402Command::fault_reset, 0x0006), 0x0080);
  EXPECT_EQ(cia402_controlword(Cia402Command::shutdown, 0x0080), 0x0006);
  // Halt (bit 8), PP bits 4..6 and vendor bits survive.
  EXPECT_EQ(cia402_controlword(Cia402Command::enable_operation, 0x8176), 0x817F);
  EXPECT_EQ(cia402_command_from_string("quick_stop"), Cia402Command::quick_stop);
  EXPECT_FALSE(cia402_command_from_string("warp").has_value());
  EXPECT_EQ(cia402_mode_name(8), "csp");
  EXPECT_EQ(cia402_mode_name(0), "none");
  EXPECT_EQ(cia402_mode_name(-3), "mode_-3");
  EXPECT_EQ(cia402_mode_from_string("cst"), 10);
  EXPECT_EQ(cia402_mode_from_string("mode_-3"), -3);
  EXPECT_EQ(cia402_mode_from_string("9"), 9);
  EXPECT_FALSE(cia402_mode_from_string("fast").has_value());
}

class Cia402DriverTest : public ::testing::Test {
 protected:
  void SetUp() override {
    sim::DeviceConfig config;
    config.profile = "servo";
    auto esc = sim::make_device(config);
    ASSERT_TRUE(esc.ok());
    auto decoded = wire::decode_sii((*esc)->eeprom());
    ASSERT_TRUE(decoded.ok());
    auto layout = master::pdo_layout_from_sii(decoded->image);
    ASSERT_TRUE(layout.ok());
    layout_ = *layout;
    auto signals = driver_->signal_model(layout_, {});
    ASSERT_TRUE(signals.ok()) << signals.error().describe();
    signals_ = *signals;
    values_.assign(signals_.size(), Value(std::int64_t{0}));
    for (std::size_t i = 0; i < signals_.size(); ++i) {
      if (master::is_unsigned(signals_[i].type)) values_[i] = Value(std::uint64_t{0});
    }
  }

  void set(std::string_view name, Value v) {
    for (std::size_t i = 0; i < signals_.size(); ++i) {
      if (signals_[i].name == name) {
        values_[i] = std::move(v);
        return;
      }
    }
    ADD_FAILURE() << "no signal " << name;
  }

  Result<std::vector<OutputWrite>> run(std::string_view command, master::CommandArgs args = {}) {
    auto writes =
        driver_->command(command, args, SignalValues(signals_, values_), DeviceState{}, nullptr);
    if (writes.ok()) {
      for (const auto& w : *writes)
        set(w.signal, w.value);
    }
    return writes;
  }

  std::uint64_t controlword() {
    return *master::as_uint64(*SignalValues(signals_, values_).find("controlword"));
  }

  std::shared_ptr<const master::Driver> driver_ = cia402_driver();
  master::PdoLayout layout_;
  std::vector<Signal> signals_;
  std::vector<Value> values_;
};

TEST_F(Cia402DriverTest, SignalModelNamesTheObjects) {
  std::vector<std::string> names;
  for (const auto& s : signals_)
    names.push_back(s.name);
  EXPECT_EQ(names, (std::vector<std::string>{"controlword", "target_position", "target_velocity",
                                             "target_torque", "modes_of_operation", "statusword",
                                             "position_actual", "velocity_actual", "torque_actual",
                                             "modes_of_operation_display", "error_code"}));
  EXPECT_EQ(signals_[4].bit_offset, 96u);
  EXPECT_EQ(signals_[4].type, master::SignalType::int8);
  EXPECT_EQ(signals_[10].bit_offset, 104u);
  EXPECT_EQ(signals_[6].unit, "counts");

  // Without a controlword there is no drive to drive.
  master::Pdo tx = *layout_.find_pdo(0x1A00);
  auto only_inputs = master::make_pdo_layout({tx});
  ASSERT_TRUE(only_inputs.ok());
  auto e = driver_->signal_model(*only_inputs, {});
  ASSERT_FALSE(e.ok());
  EXPECT_EQ(e.error().message(),
            "cia402 driver: the controlword (0x6040) is not mapped in any assigned PDO");
}

TEST_F(Cia402DriverTest, CommandSequenceEnablesTheSimulatedDrive) {
  // The simulator's drive model, fed with the controlword our commands produce.
  sim::ObjectDictionary od;
  sim::devices::add_cia402_objects(od);
  sim::devices::Cia402Drive drive(od, [](std::uint16_t, std::uint8_t) {});
  drive.reset(0);
  std::int64_t now = 0;
  auto step = [&]() {
    od.set<std::uint16_t>(0x6040, 0, static_cast<std::uint16_t>(controlword()));
    od.set<std::int8_t>(0x6060, 0,
                        static_cast<std::int8_t>(*master::as_int64(
                            *SignalValues(signals_, values_).find("modes_of_operation"))));
    now += 1'000'000;
    drive.command(now);
    drive.advance(now);
    const auto sw = od.get<std::uint16_t>(0x6041, 0).value_or(0);
    set("statusword", Value(std::uint64_t{sw}));
    return cia402_state(sw);
  };
  // Let the drive finish its power-up.
  for (int i = 0; i < 3; ++i)
    step();
  EXPECT_EQ(step(), Cia402State::switch_on_disabled);
  ASSERT_TRUE(run("set_mode", {{"mode", Value(std::string("csp"))}}).ok());
  ASSERT_TRUE(run("shutdown").ok());
  EXPECT_EQ(controlword(), 0x0006u);
  EXPECT_EQ(step(), Cia402State::ready_to_switch_on);
  ASSERT_TRUE(run("switch_on").ok());
  EXPECT_EQ(step(), Cia402State::switched_on);
  ASSERT_TRUE(run("enable_operation").ok());
  EXPECT_EQ(controlword(), 0x000Fu);
  EXPECT_EQ(step(), Cia402State::operation_enabled);

  auto state = driver_->project_state(SignalValues(signals_, values_), nullptr, nullptr);
  ASSERT_TRUE(state.ok());
  EXPECT_EQ(*state->find("state"), Value(std::string("operation_enabled")));
  EXPECT_EQ(*state->find("voltage_enabled"), Value(true));
  EXPECT_EQ(*state->find("remote"), Value(true));
  EXPECT_TRUE(state->faults.empty());

  ASSERT_TRUE(run("quick_stop").ok());
  EXPECT_EQ(controlword(), 0x0002u);
  const Cia402State after_quick_stop = step();
  EXPECT_TRUE(after_quick_stop == Cia402State::quick_stop_active ||
              after_quick_stop == Cia402State::switch_on_disabled)
      << to_string(after_quick_stop);
  ASSERT_TRUE(run("disable_voltage").ok());
  EXPECT_EQ(step(), Cia402State::switch_on_disabled);

  // A fault, reset with an edge of bit 7.
  drive.raise_fault(0x8611, now);
  EXPECT_EQ(step(), Cia402State::fault);
  ASSERT_TRUE(run("fault_reset").ok());
  EXPECT_EQ(controlword(), 0x0080u);
  EXPECT_EQ(step(), Cia402State::switch_on_disabled);
  auto again = run("fault_reset");
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().code(), Errc::wrong_state);
}

TEST_F(Cia402DriverTest, ProjectedStateFaultsAndNotices) {
  set("statusword", Value(std::uint64_t{0x0233}));
  set("modes_of_operation_display", Value(std::int64_t{9}));
  auto first = driver_->project_state(SignalValues(signals_, values_), nullptr, nullptr);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(*first->find("state"), Value(std::string("switched_on")));
  EXPECT_EQ(*first->find("mode"), Value(std::string("csv")));
  EXPECT_EQ(*first->find("target_reached"), Value(false));
  EXPECT_EQ(*first->find("position_actual"), Value(std::int64_t{0}));
  EXPECT_TRUE(first->notices.empty());

  set("statusword", Value(std::uint64_t{0x2608}));
  set("error_code", Value(std::uint64_t{0x8611}));
  auto second = driver_->project_state(SignalValues(signals_, values_), &*first, nullptr);
  ASSERT_TRUE(second.ok());
  EXPECT_EQ(*second->find("state"), Value(std::string("fault")));
  EXPECT_EQ(*second->find("following_error"), Value(true));
  EXPECT_EQ(*second->find("target_reached"), Value(true));
  EXPECT_EQ(second->faults, std::vector<std::string>{"drive fault (error code 0x8611)"});
  EXPECT_EQ(second->notices, std::vector<std::string>{"state switched_on -> fault"});
}

TEST_F(Cia402DriverTest, SetpointCommands) {
  auto targets = run("set_target", {{"position", Value(std::int64_t{1000})},
                                    {"velocity", Value(std::int64_t{-5})}});
  ASSERT_TRUE(targets.ok());
  EXPECT_EQ(*targets, (std::vector<OutputWrite>{{"target_position", Value(std::int64_t{1000})},
                                                {"target_velocity", Value(std::int64_t{-5})}}));
  EXPECT_FALSE(run("set_target").ok());
  auto mode = run("set_mode", {{"mode", Value(std::int64_t{1})}});
  ASSERT_TRUE(mode.ok());
  EXPECT_EQ((*mode)[0].value, Value(std::int64_t{1}));
  EXPECT_FALSE(run("set_mode", {{"mode", Value(std::string("warp"))}}).ok());

  ASSERT_TRUE(run("enable_operation").ok());
  auto move = run("move_to", {{"position", Value(std::int64_t{500})}, {"relative", Value(true)}});
  ASSERT_TRUE(move.ok());
  EXPECT_EQ(controlword(), 0x007Fu);
  auto busy = run("move_to", {{"position", Value(std::int64_t{600})}});
  ASSERT_FALSE(busy.ok());
  EXPECT_EQ(busy.error().code(), Errc::wrong_state);
  ASSERT_TRUE(run("release_setpoint").ok());
  EXPECT_EQ(controlword(), 0x006Fu);
  ASSERT_TRUE(
      run("move_to", {{"position", Value(std::int64_t{600})}, {"immediate", Value(false)}}).ok());
  EXPECT_EQ(controlword(), 0x001Fu);
  EXPECT_EQ(run("warp").error().code(), Errc::not_found);

  const auto d = driver_->describe(signals_);
  EXPECT_EQ(d.device_type, "cia402_drive");
  EXPECT_EQ(d.commands.size(), 12u);
}

}  // namespace
}  // namespace ecat::drivers
