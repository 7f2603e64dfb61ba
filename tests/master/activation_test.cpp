// Activation as the reference does it: the bus quiesces first (settle, quiet window, settle); an
// activation error rolls back the runtime it started; an incomplete activation (a slave refuses)
// leaves the runtime running while it is retried; deactivate(safeop) keeps the exchange running
// and deactivate(preop) stops it (ecat's documented difference: docs/ARCHITECTURE.md).
#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/quiesce.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/al.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds limit = 15s) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (condition()) return true;
    std::this_thread::sleep_for(2ms);
  }
  return condition();
}

constexpr const char* kRing = test::kTerminalRing;

// DC-capable: a drive with a drifting clock behind the terminals.
constexpr const char* kDcRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: axis, profile: servo, clock: {drift_ppm: 40, offset_ns: 1500000}}
)";

// The quick test configuration (1 ms domain) with `names` as the slaves, all but the coupler
// with process data.
MasterConfig config_for(std::initializer_list<const char*> names) {
  MasterConfig config = test::quick_config(1ms);
  config.slaves.clear();
  for (const char* name : names)
    config.slaves.push_back(test::quick_slave(name, std::string_view(name) != "coupler"));
  return config;
}

struct Running {
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;
  Running(std::string_view ring, MasterConfig config,
          std::initializer_list<sim::Fault> before_start = {}) {
    server = test::make_sim_server(ring);
    if (!server) return;
    for (const auto& f : before_start) {
      auto injected = server->inject(f);
      EXPECT_TRUE(injected) << injected.error().describe();
    }
    auto link = server->serve_memory();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return;
    }
    master = std::make_unique<Master>(std::move(config));
    auto started = master->start(std::move(*link));
    EXPECT_TRUE(started) << started.error().describe();
  }
  ~Running() {
    if (master) {
      EXPECT_EQ(master->status().illegal_transitions, 0u);
      (void)master->stop();
    }
  }
  DomainSummary domain() const { return master->domains().at(0); }
  // The domain exchanges: its cycle count grows by `n`.
  bool cycles_grow(std::uint64_t n = 5) const {
    const auto start = domain().cycles;
    return eventually([&] { return domain().cycles >= start + n; }, 5000ms);
  }
};

// The reference's activation error (DC lock not reached in time): the domains and the DC runtime
// that activation started are stopped again, no slave left PREOP. ecat then retries every
// retry_interval from activation_blocked (2 s here: no retry within the test).
TEST(Activation, LockFailureRollsBackWhatActivationStarted) {
  auto config = config_for({"coupler", "inputs", "outputs", "axis"});
  DcConfig dc;
  dc.cycle = 1ms;
  dc.await_lock = true;
  dc.lock_timeout = 1ns;  // no DC runtime is locked before it sent a single FRMW
  config.dc = dc;
  config.retry_interval = 2s;
  Running run(kDcRing, config);
  ASSERT_TRUE(run.master);
  auto running = run.master->await_running(15s);
  ASSERT_FALSE(running);
  EXPECT_NE(running.error().describe().find("did not lock"), std::string::npos)
      << running.error().describe();
  EXPECT_EQ(run.master->state(), MasterState::activation_blocked);
  EXPECT_EQ(run.domain().state, "stopped");
  for (const auto& s : run.master->slaves())
    EXPECT_EQ(s.state, SlaveState::preop) << s.name;
  // The DC runtime is out of the cycle: no reference-time exchange goes out any more.
  auto before = run.master->dc_status();
  ASSERT_TRUE(before) << before.error().describe();
  const auto cycles = run.domain().cycles;
  std::this_thread::sleep_for(100ms);
  auto after = run.master->dc_status();
  ASSERT_TRUE(after);
  EXPECT_EQ(after->frmw_sent, before->frmw_sent);
  EXPECT_EQ(run.domain().cycles, cycles);
}

// An incomplete activation (a slave refuses OP) is activation_blocked with the runtime running,
// as the reference leaves it: the domain keeps exchanging while activation is retried, and the
// session goes operational once the refusal is lifted.
TEST(Activation, IncompleteActivationKeepsTheDomainsCycling) {
  Running run(kRing, config_for({"coupler", "inputs", "outputs"}),
              {sim::fault::refuse_state("outputs", wire::AlState::op, 0x001D)});
  ASSERT_TRUE(run.master);
  auto running = run.master->await_running(15s);
  ASSERT_FALSE(running);
  EXPECT_EQ(run.master->state(), MasterState::activation_blocked);
  EXPECT_EQ(run.domain().state, "cycling");
  EXPECT_TRUE(run.cycles_grow());
  run.server->clear_faults();
  auto op = run.master->await_operational(15s);
  ASSERT_TRUE(op) << op.error().describe();
  EXPECT_EQ(run.domain().state, "cycling");
}

// ecat keeps the exchange running in SAFEOP (inputs are valid there) and stops it in PREOP; the
// reference stops it for both (docs/ARCHITECTURE.md says why ecat differs).
TEST(Activation, DeactivateToSafeopKeepsCyclingToPreopStops) {
  Running run(kRing, config_for({"coupler", "inputs", "outputs"}));
  ASSERT_TRUE(run.master);
  auto op = run.master->await_operational(15s);
  ASSERT_TRUE(op) << op.error().describe();
  auto safeop = run.master->deactivate(TargetState::safeop);
  ASSERT_TRUE(safeop) << safeop.error().describe();
  EXPECT_EQ(run.master->state(), MasterState::deactivated);
  EXPECT_EQ(run.domain().state, "cycling");
  EXPECT_TRUE(run.cycles_grow());
  EXPECT_TRUE(run.domain().healthy);
  auto preop = run.master->deactivate(TargetState::preop);
  ASSERT_TRUE(preop) << preop.error().describe();
  EXPECT_EQ(run.master->state(), MasterState::preop_ready);
  EXPECT_EQ(run.domain().state, "stopped");
  auto again = run.master->activate();
  ASSERT_TRUE(again) << again.error().describe();
  EXPECT_EQ(run.master->state(), MasterState::operational);
  EXPECT_EQ(run.domain().state, "cycling");
}

// settle waits for reliable work in flight; quiesce = settle + quiet window + settle.
TEST(Activation, SettleWaitsForReliableWorkInFlight) {
  auto [near, far] = link::make_memory_link_pair();  // `far` never answers: frames stay in flight
  bus::BusOptions options;
  options.frame_timeout = 300ms;
  bus::Bus bus(std::move(near), options);
  ASSERT_TRUE(bus.start());
  exec::EventLoop loop;
  auto run = [&loop](auto task) {
    std::optional<Result<void>> result;
    exec::spawn(loop, std::move(task), [&](Result<void>&& r) {
      result.emplace(std::move(r));
      loop.stop();
    });
    loop.run();
    loop.reset();
    return std::move(*result);
  };
  // Idle bus: settles at once.
  EXPECT_TRUE(run(exec::quiesce(loop, bus, 1ms)));
  ASSERT_TRUE(exec::reliable_idle(bus.info()));

  bus::Transaction tx;
  tx.brd(0x0000, 1);
  ASSERT_TRUE(bus.submit(std::move(tx), [](Result<bus::TransactionResult>) {},
                         {.timeout = 500ms, .retries = 0}));
  const auto begin = std::chrono::steady_clock::now();
  auto short_wait = run(exec::settle(loop, bus, {.timeout = 50ms}));
  ASSERT_FALSE(short_wait);
  EXPECT_EQ(short_wait.error().code(), Errc::timeout);
  EXPECT_NE(short_wait.error().describe().find("1 reliable transaction(s) pending"),
            std::string::npos)
      << short_wait.error().describe();
  // The frame times out (300 ms): only then is the bus idle again.
  auto long_wait = run(exec::quiesce(loop, bus, 2ms, {.timeout = 5s}));
  ASSERT_TRUE(long_wait) << long_wait.error().describe();
  EXPECT_GE(std::chrono::steady_clock::now() - begin, 250ms);
  EXPECT_TRUE(exec::reliable_idle(bus.info()));
  bus.stop();
  // A stopped bus cannot settle: said as such.
  auto stopped = run(exec::settle(loop, bus));
  ASSERT_FALSE(stopped);
  EXPECT_EQ(stopped.error().code(), Errc::closed);
  (void)far;
}

}  // namespace
}  // namespace ecat::master
