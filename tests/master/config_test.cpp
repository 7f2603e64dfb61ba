// The master's sections of a ring file: every key read, and bad input named by file:line.
#include <string>

#include <gtest/gtest.h>

#include <ecat/master/config.hpp>

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

TEST(MasterConfigFile, ReadsEverySection) {
  auto config = parse_master_config(R"(version: 1
simulator:
  slaves: [{name: a, profile: EK1100}]
master:
  backend: udp:127.0.0.1:34980
  cycle_priority: 80
  cycle_cpu: 1
  cycle_dma_latency_us: 0
  cycle_lock_memory: true
  base_station: 0x2000
  frame_timeout_us: 800
  scan_poll_ms: 5
  scan_stable_ms: 50
  scan_link_check: false
  awaiting_preop_timeout_ms: 7000
  retry_interval_ms: 250
domains:
  - {id: fast, period_us: 250, miss_threshold: 10, recovery_threshold: 2}
  - {id: slow, period_us: 4000}
slaves:
  - name: coupler
  - name: io
    position: 2
    vendor_id: 2
    product_code: 0x07113052
    process_data: fast
    target: safeop
    health_poll_ms: 0
  - name: drive
    driver: cia402
    driver_options: {mode: csp}
    process_data:
      - {signal: statusword, domain: fast}
      - {signal: controlword, domain: slow}
    startup_sdos:
      - {index: 0x6060, subindex: 0, type: i8, value: 8}
      - {index: 0x1C12, type: bytes, value: "01 00 00 16", complete_access: true}
    pdo_source: coe
    esi: devices/drive.xml
    sync: {mode: sync0, pulse_ns: 1000, shift_ns: -2000, assign_activate: 0x0300,
           latches: [{name: probe, unit: 1, edge: falling}]}
dc: {cycle_us: 500, await_lock: true, lock_policy: recovering, lock_threshold_ns: 50,
     follow_reference: false, frame_lead_us: 100}
)");
  ASSERT_TRUE(config) << config.error().describe();
  EXPECT_EQ(config->base_station, 0x2000);
  EXPECT_EQ(config->backend, "udp:127.0.0.1:34980");
  EXPECT_EQ(config->cycle_thread.fifo_priority, 80);
  EXPECT_EQ(config->cycle_thread.cpu, 1);
  EXPECT_EQ(config->cycle_thread.cpu_dma_latency_us, 0);
  EXPECT_TRUE(config->cycle_thread.lock_memory);
  EXPECT_EQ(config->frame_timeout, std::chrono::nanoseconds(800us));
  EXPECT_EQ(config->scan.poll, std::chrono::nanoseconds(5ms));
  EXPECT_FALSE(config->scan.link_check);
  EXPECT_EQ(config->awaiting_preop_timeout, std::chrono::nanoseconds(7s));
  ASSERT_EQ(config->domains.size(), 2u);
  EXPECT_EQ(config->domains[0].period, std::chrono::nanoseconds(250us));
  EXPECT_EQ(config->domains[0].miss_threshold, 10u);
  ASSERT_EQ(config->slaves.size(), 3u);
  const auto& io = config->slaves[1];
  EXPECT_EQ(io.position, 2);
  EXPECT_EQ(io.product_code, 0x07113052u);
  EXPECT_EQ(io.process_data.kind, ProcessDataRequest::Kind::all);
  EXPECT_EQ(io.process_data.domain, "fast");
  EXPECT_EQ(io.target, TargetState::safeop);
  EXPECT_FALSE(io.health_poll.has_value());
  const auto& drive = config->slaves[2];
  EXPECT_EQ(drive.driver, "cia402");
  EXPECT_EQ(drive.driver_config.options.at("mode"), "csp");
  ASSERT_EQ(drive.process_data.routes.size(), 2u);
  EXPECT_EQ(drive.process_data.routes[1].domain, "slow");
  ASSERT_EQ(drive.startup_sdos.size(), 2u);
  EXPECT_EQ(drive.startup_sdos[0].data, (std::vector<std::uint8_t>{8}));
  EXPECT_EQ(drive.startup_sdos[1].data, (std::vector<std::uint8_t>{1, 0, 0, 0x16}));
  EXPECT_TRUE(drive.startup_sdos[1].complete_access);
  EXPECT_EQ(drive.pdo_source, SlaveConfig::PdoSource::coe);
  ASSERT_TRUE(drive.sync.has_value());
  EXPECT_EQ(drive.sync->mode, SyncMode::sync0);
  EXPECT_EQ(drive.sync->sync0_shift, std::chrono::nanoseconds(-2000));
  EXPECT_EQ(drive.sync->assign_activate, 0x0300);
  ASSERT_EQ(drive.sync->latches.size(), 1u);
  EXPECT_EQ(drive.sync->latches[0].name, "probe");
  EXPECT_EQ(drive.sync->latches[0].unit, 1);
  EXPECT_EQ(drive.sync->latches[0].edge, LatchEdge::falling);
  ASSERT_TRUE(config->dc.has_value());
  EXPECT_EQ(config->dc->cycle, std::chrono::nanoseconds(500us));
  EXPECT_EQ(config->dc->lock_policy, LockPolicy::recovering);
  EXPECT_FALSE(config->dc->follow_reference);
  EXPECT_EQ(config->dc->frame_lead, std::chrono::nanoseconds(100us));
  // Relative to the ring file's directory (the source here has none: as written).
  EXPECT_EQ(drive.esi_file, "devices/drive.xml");
}

TEST(MasterConfigFile, EsiPathsAreRelativeToTheRingFile) {
  auto config = parse_master_config("slaves: [{name: d, esi: esi/d.xml}]\n", "/etc/ecat/ring.yaml");
  ASSERT_TRUE(config) << config.error().describe();
  EXPECT_EQ(config->slaves[0].esi_file, "/etc/ecat/esi/d.xml");
  auto absolute = parse_master_config("slaves: [{name: d, esi: /opt/d.xml}]\n", "/etc/r.yaml");
  ASSERT_TRUE(absolute) << absolute.error().describe();
  EXPECT_EQ(absolute->slaves[0].esi_file, "/opt/d.xml");
}

TEST(MasterConfigFile, FrameLeadMustLieWithinHalfTheCycle) {
  auto config = parse_master_config("dc: {cycle_us: 1000, frame_lead_us: 600}\n");
  ASSERT_FALSE(config);
  EXPECT_NE(config.error().describe().find("dc.frame_lead 600000 ns must lie in 0 .. half"),
            std::string::npos)
      << config.error().describe();
  MasterConfig direct;
  direct.dc->frame_lead = std::chrono::microseconds(-1);
  EXPECT_FALSE(validate(direct));
  direct.dc->frame_lead = std::chrono::microseconds(499);
  EXPECT_TRUE(validate(direct));
}

TEST(MasterConfigFile, DcFalseDisablesAndDefaultsHold) {
  auto config = parse_master_config("dc: false\n");
  ASSERT_TRUE(config) << config.error().describe();
  EXPECT_FALSE(config->dc.has_value());
  EXPECT_EQ(config->base_station, 0x1000);
  EXPECT_TRUE(config->slaves.empty());
}

TEST(MasterConfigFile, MailboxStatusOnByDefaultOffByKey) {
  auto defaults = parse_master_config("slaves: [{name: a}]\n");
  ASSERT_TRUE(defaults) << defaults.error().describe();
  EXPECT_TRUE(defaults->mailbox_status);
  EXPECT_FALSE(defaults->slaves.at(0).mailbox_status.has_value());
  auto off = parse_master_config(
      "master: {mailbox_status: false}\nslaves: [{name: a, mailbox_status: true}]\n");
  ASSERT_TRUE(off) << off.error().describe();
  EXPECT_FALSE(off->mailbox_status);
  EXPECT_EQ(off->slaves.at(0).mailbox_status, true);
}

TEST(MasterConfigFile, WatchdogIsTheEscsUnlessSetZeroIsOff) {
  auto config = parse_master_config(
      "slaves: [{name: a}, {name: b, watchdog_us: 0}, {name: c, watchdog_us: 250000}]\n");
  ASSERT_TRUE(config) << config.error().describe();
  EXPECT_FALSE(config->slaves.at(0).watchdog.has_value());
  EXPECT_EQ(config->slaves.at(1).watchdog, std::chrono::nanoseconds(0));
  EXPECT_EQ(config->slaves.at(2).watchdog, std::chrono::nanoseconds(250ms));
}

TEST(MasterConfig, WatchdogBeyondTheEscsRegistersIsRefused) {
  MasterConfig config;
  SlaveConfig slave;
  slave.name = "io";
  slave.watchdog = std::chrono::seconds(200);
  config.slaves.push_back(slave);
  auto checked = validate(config);
  ASSERT_FALSE(checked);
  EXPECT_NE(checked.error().message().find("slave io: watchdog"), std::string::npos)
      << checked.error().describe();
  config.slaves[0].watchdog = std::chrono::nanoseconds(-1);
  EXPECT_FALSE(validate(config));
  config.slaves[0].watchdog = std::chrono::seconds(171);
  EXPECT_TRUE(validate(config)) << validate(config).error().describe();
}

struct BadCase {
  const char* yaml;
  const char* expect;  // in the message
};

class MasterConfigBad : public ::testing::TestWithParam<BadCase> {};

TEST_P(MasterConfigBad, NamesWhatIsWrong) {
  auto config = parse_master_config(GetParam().yaml, "ring.yaml");
  ASSERT_FALSE(config) << GetParam().yaml;
  EXPECT_NE(config.error().describe().find(GetParam().expect), std::string::npos)
      << config.error().describe();
}

INSTANTIATE_TEST_SUITE_P(
    Cases, MasterConfigBad,
    ::testing::Values(
        BadCase{"master: {base_station: 0}\n", "master.base_station"},
        BadCase{"master: {bogus: 1}\n", "bogus"},
        BadCase{"slaves: [{name: x, alias: 0}]\n", "slaves[0].alias"},
        BadCase{"master: {backend: eth0}\n", "\"eth0\" is not a backend"},
        BadCase{"master: {cycle_priority: 100}\n", "master.cycle_priority"},
        BadCase{"master: {cycle_cpu: -1}\n", "master.cycle_cpu"},
        BadCase{"master: {cycle_dma_latency_us: -1}\n", "master.cycle_dma_latency_us"},
        BadCase{"master: {cycle_lock_memory: maybe}\n", "master.cycle_lock_memory"},
        BadCase{"master: {mailbox_status: often}\n", "master.mailbox_status"},
        BadCase{"slaves: [{name: x, mailbox_status: 2}]\n", "slaves[0].mailbox_status"},
        BadCase{"slaves: [{name: x, watchdog_us: -5}]\n", "slaves[0].watchdog_us"},
        BadCase{"slaves: [{name: x, watchdog_us: 200000000}]\n", "slaves[0].watchdog_us"},
        BadCase{"slaves: [{name: x, watchdog_us: often}]\n", "slaves[0].watchdog_us"},
        BadCase{"domains: [{period_us: 1000}]\n", "needs an id"},
        BadCase{"domains: [{id: a, period_us: 10}]\n", "ring.yaml:1"},
        BadCase{"domains: [{id: a}, {id: a}]\n", "used twice"},
        BadCase{"slaves: [{name: x, process_data: nowhere}]\n", "unknown domain \"nowhere\""},
        BadCase{"slaves: [{name: x, target: run}]\n", "unknown target"},
        BadCase{"slaves: [{name: x}, {name: x}]\n", "used twice"},
        BadCase{"slaves: [{name: x, startup_sdos: [{index: 0x1000, type: u8, value: 300}]}]\n",
                "value"},
        BadCase{"slaves: [{name: x, startup_sdos: [{index: 0x1000, type: bytes, value: zz}]}]\n",
                "not a hex byte"},
        BadCase{"slaves: [{name: x, sync: {mode: sync7}}]\n", "unknown mode"},
        BadCase{"slaves: [{name: x, sync: {latches: [{name: p, edge: up}]}}]\n",
                "unknown edge \"up\""},
        BadCase{"slaves: [{name: x, sync: {latches: [{name: p, unit: 2}]}}]\n",
                "slaves[0].sync.latches[0].unit"},
        BadCase{"slaves: [{name: x, sync: {latches: [{unit: 1}]}}]\n", "a latch needs a name"},
        BadCase{"dc: {lock_policy: maybe}\n", "unknown lock_policy"},
        BadCase{"dc: {follow_reference: perhaps}\n", "dc.follow_reference"},
        BadCase{"slaves: [{name: x, esi: \"\"}]\n", "must name an ESI file"},
        BadCase{"slaves: {name: x}\n", "must be a list"},
        BadCase{"slaves: [ {name: x\n", "YAML syntax error"}));

TEST(MasterConfigFile, MissingFileIsNamed) {
  auto config = load_master_config("/nonexistent/ring.yaml");
  ASSERT_FALSE(config);
  EXPECT_EQ(config.error().code(), Errc::not_found);
  EXPECT_NE(config.error().message().find("/nonexistent/ring.yaml"), std::string::npos);
}

}  // namespace
}  // namespace ecat::master
