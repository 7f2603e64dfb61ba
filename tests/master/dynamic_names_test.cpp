// A dynamic session (no slaves configured) names its slaves by what their SII says they are: a
// coupler `coupler` (`coupler_2`, ...), every other slave `slave_<position>`. The decision is
// checked on its own (real EEPROM images, hand-made shapes), through the EEPROM reads against
// the simulator, and end to end through the master.
#include "master/dynamic_names.hpp"

#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/wire/sii.hpp>

#include "master/master_test_support.hpp"
#include "support/shared_data.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

MasterConfig dynamic_config() {
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 5s};
  config.awaiting_preop_timeout = 10s;
  config.retry_interval = 50ms;
  config.dc.reset();
  return config;  // no slaves, no domains: the dynamic, PREOP-first session
}

std::vector<std::string> names_of_dynamic_session(std::string_view ring) {
  auto server = test::make_sim_server(ring);
  if (!server) return {};
  auto link = server->serve_memory();
  EXPECT_TRUE(link) << link.error().describe();
  if (!link) return {};
  Master master(dynamic_config());
  EXPECT_TRUE(master.start(std::move(*link)));
  auto running = master.await_running(15s);
  EXPECT_TRUE(running) << running.error().describe();
  EXPECT_EQ(master.state(), MasterState::preop_ready);
  std::vector<std::string> names;
  for (const auto& s : master.slaves()) {
    names.push_back(s.name);
    EXPECT_EQ(s.state, SlaveState::preop) << s.name;
  }
  EXPECT_EQ(master.status().illegal_transitions, 0u);
  EXPECT_TRUE(master.stop());
  return names;
}

TEST(DynamicNames, NamesCouplersInOrderAndTheRestByPosition) {
  const std::vector<std::optional<bool>> coupler = {true, false, std::nullopt, true, false, true};
  const auto names = dynamic_slave_names(coupler);
  EXPECT_EQ(names, (std::vector<std::string>{"coupler", "slave_1", "slave_2", "coupler_2",
                                             "slave_4", "coupler_3"}));
  EXPECT_TRUE(dynamic_slave_names(std::vector<std::optional<bool>>{}).empty());
}

TEST(DynamicNames, ShapeDecidesCoupler) {
  namespace c = wire::sii_category;
  SiiShape coupler;
  coupler.category_types = {c::kStrings, c::kGeneral, c::kEnd};
  EXPECT_TRUE(sii_shape_is_coupler(coupler));
  // A mailbox, process-data categories or DC rule it out, whichever it is.
  auto with_mailbox = coupler;
  with_mailbox.standard_mailbox = {0x1000, 128, 0x1080, 128};
  EXPECT_FALSE(sii_shape_is_coupler(with_mailbox));
  auto with_protocols = coupler;
  with_protocols.mailbox_protocols = wire::mailbox_protocol::kCoe;
  EXPECT_FALSE(sii_shape_is_coupler(with_protocols));
  for (const auto type :
       {c::kFmmu, c::kSyncManager, c::kFmmuEx, c::kSyncUnit, c::kTxPdo, c::kRxPdo, c::kDc}) {
    auto terminal = coupler;
    terminal.category_types = {c::kStrings, c::kGeneral, type, c::kEnd};
    EXPECT_FALSE(sii_shape_is_coupler(terminal)) << wire::sii_category_name(type);
  }
  // Nothing that looks like a real SII: no GENERAL, or no END within the walk.
  SiiShape blank;
  blank.category_types = {c::kEnd};
  EXPECT_FALSE(sii_shape_is_coupler(blank));
  SiiShape unended;
  unended.category_types = {c::kStrings, c::kGeneral};
  EXPECT_FALSE(sii_shape_is_coupler(unended));
}

// The real Beckhoff images: only the EK1100 is a coupler (the EL2004 has no mailbox either, but
// it has its SyncManager and PDO categories).
TEST(DynamicNames, RealEepromImagesDecide) {
  ECAT_SHARED_DATA_OR_SKIP(dir, "eeprom");
  for (const auto& [file, is_coupler] :
       std::vector<std::pair<std::string, bool>>{{"ek1100.bin", true},
                                                 {"el2004.bin", false},
                                                 {"el2828.bin", false},
                                                 {"el2262.bin", false}}) {
    const auto path = dir / file;
    if (!std::filesystem::exists(path)) continue;
    const auto bytes = ::ecat::test::read_file(path);
    auto decoded = wire::decode_sii(bytes);
    ASSERT_TRUE(decoded) << file << ": " << decoded.error().describe();
    EXPECT_EQ(sii_shape_is_coupler(sii_shape_of(*decoded)), is_coupler) << file;
  }
}

// The EEPROM reads against the simulator's profiles: header words, then category headers.
TEST(DynamicNames, ProbeReadsTheSimulatedSii) {
  auto bench = test::SimBench::make(R"(version: 1
simulator:
  slaves:
    - {name: a, profile: EK1100}
    - {name: b, profile: EL1809}
    - {name: c, profile: EL2809}
    - {name: d, profile: EL3202}
    - {name: e, profile: servo}
)");
  ASSERT_TRUE(bench);
  ASSERT_TRUE(bench->run(test::assign_stations(bench->loop, *bench->bus, 5)));
  std::vector<std::optional<bool>> seen;
  for (std::size_t pos = 0; pos < 5; ++pos)
    seen.push_back(bench->run(probe_coupler(bench->loop, *bench->bus, test::station_at(pos))));
  EXPECT_EQ(seen, (std::vector<std::optional<bool>>{true, false, false, false, false}));
  // A station nobody has: the SII cannot be read, the name stays positional.
  EXPECT_EQ(bench->run(probe_coupler(bench->loop, *bench->bus, 0x7777)), std::nullopt);
}

TEST(DynamicNames, SessionNamesTheCoupler) {
  EXPECT_EQ(names_of_dynamic_session(R"(version: 1
simulator:
  slaves:
    - {name: x, profile: EK1100}
    - {name: y, profile: EL1809}
    - {name: z, profile: EL2809}
)"),
            (std::vector<std::string>{"coupler", "slave_1", "slave_2"}));
}

TEST(DynamicNames, RingWithoutCouplerKeepsPositionalNames) {
  EXPECT_EQ(names_of_dynamic_session(R"(version: 1
simulator:
  slaves:
    - {name: x, profile: EL1809}
    - {name: y, profile: EL2809}
    - {name: z, profile: servo}
)"),
            (std::vector<std::string>{"slave_0", "slave_1", "slave_2"}));
}

TEST(DynamicNames, SessionOfRealImagesNamesTheEk1100) {
  ECAT_SHARED_DATA_OR_SKIP(ek1100, "eeprom/ek1100.bin");
  ECAT_SHARED_DATA_OR_SKIP(el2004, "eeprom/el2004.bin");
  ECAT_SHARED_DATA_OR_SKIP(el2828, "eeprom/el2828.bin");
  EXPECT_EQ(names_of_dynamic_session(fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: a, profile: eeprom, file: "{}"}}
    - {{name: b, profile: eeprom, file: "{}"}}
    - {{name: c, profile: eeprom, file: "{}"}}
    - {{name: d, profile: eeprom, file: "{}"}}
)",
                                                 el2004.string(), ek1100.string(), el2828.string(),
                                                 ek1100.string())),
            (std::vector<std::string>{"slave_0", "coupler", "slave_2", "coupler_2"}));
}

}  // namespace
}  // namespace ecat::master
