// Distributed clocks through the Master: initialised at startup, the runtime started with the
// activation, SYNC0 written on the way to SAFEOP from the slave's sync configuration, the lock
// reported by dc_status / await_dc_locked / reference_clock, and a lost lock handled by the
// configured policy (recovering: the session heals when the clocks lock again).
#include <chrono>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/server.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

// An EK1100 (DC-capable), two digital terminals and two drives whose clocks drift and start
// at random-looking offsets.
constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: generic, clock: {drift_ppm: 12.5, offset_ns: 7000000000}}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: axis_1, profile: servo, clock: {drift_ppm: -80, offset_ns: 1500000}}
    - {name: axis_2, profile: servo, clock: {drift_ppm: 95, offset_ns: 900000000}}
)";

MasterConfig dc_config(LockPolicy policy = LockPolicy::advisory) {
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.retry_interval = 50ms;
  DcConfig dc;
  dc.cycle = 1ms;
  dc.lock_policy = policy;
  config.dc = dc;
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  config.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs", "axis_1", "axis_2"}) {
    SlaveConfig s;
    s.name = name;
    if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
    if (std::string(name).starts_with("axis")) {
      SyncConfig sync;
      sync.mode = SyncMode::sync0;
      s.sync = sync;
    }
    config.slaves.push_back(s);
  }
  return config;
}

bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds limit = 15s) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(5ms);
  }
  return condition();
}

class MasterDcTest : public ::testing::Test {
 protected:
  void start(MasterConfig config) {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
    auto link = server_->serve_memory();
    ASSERT_TRUE(link);
    master_ = std::make_unique<Master>(std::move(config));
    ASSERT_TRUE(master_->start(std::move(*link)));
    auto op = master_->await_operational(20s);
    ASSERT_TRUE(op) << op.error().describe();
  }
  void TearDown() override {
    if (master_) (void)master_->stop();
  }
  std::unique_ptr<sim::SimServer> server_;
  std::unique_ptr<Master> master_;
};

TEST_F(MasterDcTest, LocksReportsAndSynchronisesTheDrives) {
  ASSERT_NO_FATAL_FAILURE(start(dc_config()));
  auto locked = master_->await_dc_locked(20s);
  ASSERT_TRUE(locked) << locked.error().describe();
  auto status = master_->dc_status();
  ASSERT_TRUE(status) << status.error().describe();
  EXPECT_TRUE(status->locked);
  EXPECT_EQ(status->reference_station, 0x1000);
  ASSERT_GE(status->slaves.size(), 3u);  // the coupler and both drives at least
  for (const auto& s : status->slaves) {
    EXPECT_LT(std::llabs(s.difference_ns), 100) << "station " << s.station;
  }
  EXPECT_GT(status->frmw_sent, 0u);
  EXPECT_FALSE(status->history.empty());
  auto reference = master_->reference_clock();
  ASSERT_TRUE(reference) << reference.error().describe();
  EXPECT_EQ(reference->slave, "coupler");
  EXPECT_EQ(reference->station, 0x1000);
  EXPECT_EQ(reference->position, 0);

  // SYNC0 was written on the way to SAFEOP: a cycle of 1 ms, an AssignActivate, a start time in
  // the reference's time base, and the simulated ESCs generate pulses.
  auto axis = master_->slave("axis_1");
  ASSERT_TRUE(axis);
  const auto info = (*axis)->info();
  ASSERT_TRUE(info.dc_sync);
  EXPECT_EQ(info.dc_sync->sync0_cycle_ns, 1'000'000u);
  EXPECT_NE(info.dc_sync->assign_activate, 0);
  EXPECT_GT(info.dc_sync->start_time, 0u);
  EXPECT_FALSE((*master_->slave("inputs"))->info().dc_sync.has_value());
  // The drive's application was told to run on SYNC0 (0x1C32:01 = 2).
  auto mode = (*axis)->upload_sdo(0x1C32, 1);
  ASSERT_TRUE(mode) << mode.error().describe();
  EXPECT_EQ(*mode, (std::vector<std::uint8_t>{0x02, 0x00}));
  EXPECT_TRUE(eventually([&] {
    return server_->with_segment([](sim::Segment& segment, sim::FaultInjector&) {
      return segment.esc(3).dc()->sync_state() == sim::SyncUnitState::running &&
             segment.esc(4).dc()->sync_state() == sim::SyncUnitState::running;
    });
  }));
}

TEST_F(MasterDcTest, LatchEdgesReachSubscribers) {
  auto config = dc_config();
  for (auto& s : config.slaves) {
    if (s.name != "axis_1") continue;
    s.sync->latches = {{"probe_on", 0, LatchEdge::rising}, {"probe_off", 0, LatchEdge::falling}};
  }
  ASSERT_NO_FATAL_FAILURE(start(config));
  auto axis = master_->slave("axis_1");
  ASSERT_TRUE(axis);
  std::mutex mutex;
  std::vector<SignalEvent> seen;
  auto record = [&](const SignalEvent& e) {
    std::lock_guard lock(mutex);
    seen.push_back(e);
  };
  ASSERT_TRUE((*axis)->subscribe("probe_on", record));
  ASSERT_TRUE((*axis)->subscribe("probe_off", record));
  auto unknown = (*axis)->subscribe("probe_sideways", record);
  ASSERT_FALSE(unknown);
  EXPECT_NE(unknown.error().message().find("no signal or latch \"probe_sideways\""),
            std::string::npos);
  const auto t = server_->now_ns();
  const auto expected = server_->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto* dc = segment.esc(3).dc();
    dc->latch_input(0, true, t);
    dc->latch_input(0, false, t + 2000);
    return std::make_pair(dc->system_time(t), dc->system_time(t + 2000));
  });
  ASSERT_TRUE(eventually([&] {
    std::lock_guard lock(mutex);
    return seen.size() >= 2;
  }));
  std::lock_guard lock(mutex);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].signal, "probe_on");
  EXPECT_EQ(seen[0].value, Value(std::uint64_t{expected.first}));
  EXPECT_EQ(seen[1].signal, "probe_off");
  EXPECT_EQ(seen[1].value, Value(std::uint64_t{expected.second}));
  EXPECT_EQ(seen[0].slave, "axis_1");
}

TEST_F(MasterDcTest, ClockJumpLosesTheLockAndRecoveringHealsIt) {
  ASSERT_NO_FATAL_FAILURE(start(dc_config(LockPolicy::recovering)));
  ASSERT_TRUE(master_->await_dc_locked(20s));
  const auto locks_before = master_->dc_status()->lock_count;
  // The second drive's clock jumps by 50 us: its difference leaves the threshold.
  server_->with_segment(
      [](sim::Segment& segment, sim::FaultInjector&) { segment.esc(4).dc()->jump(50'000); });
  ASSERT_TRUE(eventually([&] { return master_->state() == MasterState::recovering; }))
      << to_string(master_->state());
  const auto faults = master_->status().runtime_faults;
  ASSERT_FALSE(faults.empty());
  EXPECT_NE(faults.front().find("distributed clocks lost lock"), std::string::npos)
      << faults.front();
  // The ESC's time loop slews the jump away; the lock comes back and so does the session.
  ASSERT_TRUE(eventually([&] { return master_->state() == MasterState::operational; }, 30s))
      << to_string(master_->state());
  auto status = master_->dc_status();
  ASSERT_TRUE(status);
  EXPECT_GE(status->unlock_count, 1u);
  EXPECT_GT(status->lock_count, locks_before);
  EXPECT_EQ(master_->status().illegal_transitions, 0u);
}

TEST(MasterDc, IdleOrDisabledSaysWhy) {
  auto server = test::make_sim_server(R"(version: 1
simulator:
  slaves:
    - {name: inputs, profile: EL1809}
)");
  ASSERT_TRUE(server);
  auto config = dc_config();
  config.slaves.clear();
  config.domains.clear();
  Master idle(config);
  auto none = idle.dc_status();
  ASSERT_FALSE(none);
  EXPECT_EQ(none.error().code(), Errc::unsupported);

  config.dc.reset();
  Master disabled(config);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  ASSERT_TRUE(disabled.start(std::move(*link)));
  ASSERT_TRUE(disabled.await_running(10s));
  auto off = disabled.dc_status();
  ASSERT_FALSE(off);
  EXPECT_EQ(off.error().code(), Errc::unsupported);
  EXPECT_NE(off.error().message().find("disabled in the configuration"), std::string::npos);
  auto wait = disabled.await_dc_locked(100ms);
  ASSERT_FALSE(wait);
  EXPECT_EQ(wait.error().code(), Errc::unsupported);
  ASSERT_TRUE(disabled.stop());
}

}  // namespace
}  // namespace ecat::master
