// Writing a slave's station alias through a running session (Slave::write_alias): refused in
// OP, written in PREOP; the alias register 0x0012 changes only when the simulated ESC is power
// cycled (fault `power_cycle`, sim/faults.hpp), and a new session then finds the slave by it.
#include <chrono>
#include <memory>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/master/sii_writer.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/wire/sii.hpp>

#include "scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using namespace std::chrono_literals;

constexpr std::uint16_t kAlias = 0x0ABC;

std::uint16_t register_u16(sim::SimServer& server, const char* slave, std::uint16_t address) {
  auto bytes = server.read_memory(slave, address, 2);
  EXPECT_TRUE(bytes);
  return bytes ? static_cast<std::uint16_t>((*bytes)[0] | ((*bytes)[1] << 8)) : 0xFFFF;
}

TEST(SiiWriteScenario, AliasWrittenInPreopSurvivesAPowerCycleAndFindsTheSlave) {
  RingSpec spec;
  spec.targets["outputs"] = TargetState::preop;
  spec.adjust = [](master::MasterConfig& config) {
    for (auto& s : config.slaves) {
      if (s.name == "outputs") s.process_data = master::ProcessDataRequest::none();
    }
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  master::SiiWriteOptions options;
  options.busy_timeout = 200ms;

  // In OP the EEPROM stays alone.
  auto refused = ring->slave("inputs").write_alias(kAlias, options);
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::wrong_state) << refused.error().describe();

  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::preop; }))
      << ring->describe();
  // The register write is asked for too: the ESC does not take it (read-only from EtherCAT).
  options.write_alias_register = true;
  auto written = ring->slave("outputs").write_alias(kAlias, options);
  ASSERT_FALSE(written);
  EXPECT_EQ(written.error().code(), Errc::unsupported) << written.error().describe();
  EXPECT_NE(written.error().describe().find("0x0012"), std::string::npos);
  // ... but word 4 and its checksum are in the EEPROM, and the session's SII copy has them.
  EXPECT_EQ(ring->slave("outputs").info().identity.has_value(), true);
  EXPECT_EQ(register_u16(*ring->server, "outputs", wire::reg::kStationAlias), 0)
      << "0x0012 changes at the next power-up only";

  ASSERT_TRUE(ring->master->stop());
  ring->master.reset();
  ASSERT_TRUE(ring->server->power_cycle("outputs"));
  EXPECT_EQ(register_u16(*ring->server, "outputs", wire::reg::kStationAlias), kAlias);
  auto status = register_u16(*ring->server, "outputs", wire::reg::kSiiControl);
  EXPECT_EQ(status & wire::sii_control::kChecksumError, 0) << "the checksum was fixed";

  // A new session whose `outputs` entry names only the alias finds it at position 2.
  auto config = ring_config(RingSpec{});
  for (auto& s : config.slaves) {
    if (s.name == "outputs") s.alias = kAlias;
  }
  // The first session's link goes; the simulated devices (and their EEPROMs) stay.
  ring->server->stop();
  auto link = ring->server->serve_memory();
  ASSERT_TRUE(link) << link.error().describe();
  master::Master second(config);
  ASSERT_TRUE(second.start(std::move(*link)));
  auto op = second.await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe();
  auto outputs = second.slave("outputs");
  ASSERT_TRUE(outputs);
  EXPECT_EQ((*outputs)->position(), 2);
  EXPECT_TRUE(second.stop());
}

}  // namespace
}  // namespace ecat::scenarios
