// The master's first recovery paths (the full scenario suite belongs to the faults issue): a
// slave that is power-cycled in OP is found down, reclaimed at its position, rebuilt to PREOP and
// brought back to OP with the outputs staged before; a slave that retreats to SAFEOP is sent back.
#include <algorithm>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: drive, profile: servo}
  wiring:
    - {from: outputs.channel_3, to: inputs.channel_3}
)";

class RecoveryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = test::make_sim_server(kRing);
    ASSERT_TRUE(server_);
    MasterConfig config;
    config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
    config.retry_interval = 50ms;
    config.dc.reset();
    DomainConfig main;
    main.id = "main";
    main.period = 1ms;
    main.recovery_threshold = 3;
    config.domains.push_back(main);
    for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
      SlaveConfig s;
      s.name = name;
      if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
      s.health_poll = 20ms;
      config.slaves.push_back(s);
    }
    master_ = std::make_unique<Master>(config);
    auto link = server_->serve_memory();
    ASSERT_TRUE(link);
    ASSERT_TRUE(master_->start(std::move(*link)));
    auto op = master_->await_operational(10s);
    ASSERT_TRUE(op) << op.error().describe();
  }
  void TearDown() override {
    if (master_) (void)master_->stop();
  }
  bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds limit = 5s) {
    const auto end = std::chrono::steady_clock::now() + limit;
    while (std::chrono::steady_clock::now() < end) {
      if (condition()) return true;
      std::this_thread::sleep_for(5ms);
    }
    return condition();
  }
  SlaveState state_of(const std::string& name) {
    auto s = master_->slave(name);
    return s ? (*s)->state() : SlaveState::down;
  }
  std::unique_ptr<sim::SimServer> server_;
  std::vector<MasterState> states_;
  std::mutex states_mutex_;
  std::unique_ptr<Master> master_;  // last: destroyed first
};

TEST_F(RecoveryTest, PowerCycledSlaveIsReclaimedAndRestored) {
  auto outputs = master_->slave("outputs");
  auto inputs = master_->slave("inputs");
  ASSERT_TRUE(outputs && inputs);
  ASSERT_TRUE((*outputs)->write_output("channel_3", true));
  ASSERT_TRUE(eventually([&] {
    auto v = (*inputs)->read_input("channel_3");
    return v && as_bool(*v) == true;
  }));
  auto& states = states_;
  auto& m = states_mutex_;
  master_->on_state_change([&](MasterState, MasterState to) {
    std::lock_guard lock(m);
    states.push_back(to);
  });
  ASSERT_TRUE(server_->power_cycle("outputs"));
  // Critical (it carries process data): the session recovers, then is operational again.
  ASSERT_TRUE(eventually([&] {
    std::lock_guard lock(m);
    return std::find(states.begin(), states.end(), MasterState::recovering) != states.end();
  })) << "never recovering";
  auto back = master_->await_operational(10s);
  ASSERT_TRUE(back) << back.error().describe();
  EXPECT_EQ(state_of("outputs"), SlaveState::op);
  // The station was reclaimed and the output staged before the power cycle is applied again.
  EXPECT_TRUE(eventually([&] {
    auto v = (*inputs)->read_input("channel_3");
    return v && as_bool(*v) == true;
  }));
  EXPECT_EQ(master_->status().illegal_transitions, 0u);
  auto station = server_->read_memory("outputs", 0x0010, 2);
  ASSERT_TRUE(station);
  EXPECT_EQ((*station)[0] | ((*station)[1] << 8), 0x1002);
}

TEST_F(RecoveryTest, RetreatedSlaveIsSentBackToOp) {
  ASSERT_TRUE(server_->inject(sim::fault::retreat_to_safeop("drive")));
  // Slave-local: the master stays operational while the drive is brought back.
  EXPECT_TRUE(eventually([&] { return state_of("drive") == SlaveState::safeop; }, 2s) ||
              state_of("drive") == SlaveState::op);
  EXPECT_TRUE(eventually([&] { return state_of("drive") == SlaveState::op; }));
  EXPECT_TRUE(master_->await_operational(5s));
}

}  // namespace
}  // namespace ecat::master
