// A running Master in steady OP allocates nothing on its cycle (bus) thread, and the
// application's hot path (Slave::read_input / write_output) allocates nothing once warmed up.
//
// The bus thread is recognised from the domain's per-cycle callback, which runs on it. Health
// polls are off here: a poll is acyclic traffic whose completion hands its reply to the control
// loop (that hand-over allocates and is not part of the cycle); degradation events are rare
// posts, kept out by generous thresholds so a loaded machine cannot produce them. The second
// test turns health polls on.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/faults.hpp>

#include "master/master_test_support.hpp"
#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

TEST(MasterAllocations, SteadyOpCycleAndHotPathAllocateNothing) {
  auto server = test::make_sim_server(test::kDriveRing);
  ASSERT_TRUE(server);
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.dc.reset();
  config.frame_timeout = 1s;  // no spurious loss on a loaded machine
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  main.recovery_threshold = 1'000'000;
  main.miss_threshold = 1'000'000;
  main.realtime_budget = 50ms;
  main.exchanges_in_flight = 16;
  main.stale_after = 10s;  // a stale read is an error value, and errors carry text
  std::atomic<std::uint64_t> cycles{0};
  main.on_cycle = [&cycles](Domain&, const CycleOutcome&) {
    allocs::is_bus_thread = true;
    cycles.fetch_add(1, std::memory_order_relaxed);
  };
  config.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
    SlaveConfig s;
    s.name = name;
    if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
    s.health_poll.reset();
    config.slaves.push_back(s);
  }
  Master master(config);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_operational(20s));
  auto outputs = master.slave("outputs");
  auto inputs = master.slave("inputs");
  auto drive = master.slave("drive");
  ASSERT_TRUE(outputs && inputs && drive);

  // Warm up: the first writes size the scratch buffers.
  for (int i = 0; i < 10; ++i) {
    ASSERT_TRUE((*outputs)->write_output("channel_2", Value(i % 2 == 0)));
    (void)(*inputs)->read_input("channel_2");
    ASSERT_TRUE((*drive)->write_output("target_position", Value(std::int64_t{i})));
    (void)(*drive)->read_input("statusword");
  }
  while (cycles.load() < 20)
    std::this_thread::sleep_for(1ms);

  const auto start_cycles = cycles.load();
  allocs::bus_thread = 0;
  allocs::count_bus_thread = true;
  allocs::counted = 0;
  allocs::count_this_thread = true;
  for (int i = 0; i < 2000; ++i) {
    const bool on = (i / 100) % 2 == 0;
    auto w = (*outputs)->write_output("channel_2", Value(on));
    auto r = (*inputs)->read_input("channel_2");
    // Multi-byte signals too: a 32-bit output, a 16-bit input.
    auto w32 = (*drive)->write_output("target_position", Value(std::int64_t{-100'000 + i}));
    auto r16 = (*drive)->read_input("statusword");
    if (!w || !r || !w32 || !r16) {
      allocs::count_this_thread = false;
      FAIL() << (!w     ? w.error().describe()
                 : !r   ? r.error().describe()
                 : !w32 ? w32.error().describe()
                        : r16.error().describe());
    }
    if (i % 20 == 0) std::this_thread::sleep_for(1ms);
  }
  allocs::count_this_thread = false;
  while (cycles.load() < start_cycles + 200)
    std::this_thread::sleep_for(1ms);
  allocs::count_bus_thread = false;
  EXPECT_EQ(allocs::counted.load(), 0u) << "read_input/write_output allocated";
  EXPECT_EQ(allocs::bus_thread.load(), 0u)
      << "the cycle thread allocated over " << cycles.load() - start_cycles << " cycles";
  if (allocs::bus_thread.load() != 0) allocs::print_first_bus_stack();
  ASSERT_TRUE(master.stop());
}

// The acyclic side too: health polls (AL status reads, completed on the bus thread and handed to
// the control loop) run every 2 ms per slave here, 100x the default rate, so a short window of OP
// sees some 1,500 completions; none of them allocates on the bus thread (exec::transact hands
// the reply over with a node in the awaiting coroutine, EventLoop::post(Work&)). master_bench
// --only alloc prints the same figure over a minute at the default rate.
TEST(MasterAllocations, HealthPollCompletionsAllocateNothingOnTheBusThread) {
  auto server = test::make_sim_server(test::kDriveRing);
  ASSERT_TRUE(server);
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.dc.reset();
  config.frame_timeout = 1s;
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  main.recovery_threshold = 1'000'000;
  main.miss_threshold = 1'000'000;
  main.realtime_budget = 50ms;
  main.exchanges_in_flight = 16;
  main.stale_after = 10s;
  std::atomic<std::uint64_t> cycles{0};
  main.on_cycle = [&cycles](Domain&, const CycleOutcome&) {
    allocs::is_bus_thread = true;
    cycles.fetch_add(1, std::memory_order_relaxed);
  };
  config.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
    SlaveConfig s;
    s.name = name;
    if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
    s.health_poll = 2ms;
    config.slaves.push_back(s);
  }
  Master master(config);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_operational(20s));
  while (cycles.load() < 20)
    std::this_thread::sleep_for(1ms);

  bus::Bus* bus = master.bus();
  ASSERT_NE(bus, nullptr);
  const auto before = bus->stats();
  allocs::bus_thread = 0;
  allocs::count_bus_thread = true;
  std::this_thread::sleep_for(400ms);
  allocs::count_bus_thread = false;
  const auto after = bus->stats();
  const auto completed = after.transactions_completed - before.transactions_completed;
  // The polls did run (4 slaves every 2 ms: ~800 in 400 ms; a loaded machine gets fewer).
  EXPECT_GE(completed, 100u);
  EXPECT_EQ(allocs::bus_thread.load(), 0u)
      << "the bus thread allocated while completing " << completed << " acyclic transactions";
  if (allocs::bus_thread.load() != 0) allocs::print_first_bus_stack();
  EXPECT_EQ(master.state(), MasterState::operational);
  ASSERT_TRUE(master.stop());
}

// A domain's degraded / recovered notices reach the control loop (the session goes recovering and
// back to operational) without the bus thread allocating: the master hands them over with work
// items of its own (EventLoop::post(Work&)), not a std::function. A short WKC fault on the
// outputs' share of the LRW degrades the domain at its first invalid cycle.
TEST(MasterAllocations, DomainDegradedAndRecoveredNoticesAllocateNothingOnTheBusThread) {
  auto server = test::make_sim_server(test::kDriveRing);
  ASSERT_TRUE(server);
  MasterConfig config;
  config.scan = {.poll = 2ms, .stable = 10ms, .timeout = 2s};
  config.dc.reset();
  config.frame_timeout = 1s;
  DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  main.recovery_threshold = 1;
  main.miss_threshold = 1'000'000;
  main.realtime_budget = 50ms;
  main.exchanges_in_flight = 16;
  main.stale_after = 10s;
  std::atomic<std::uint64_t> cycles{0};
  main.on_cycle = [&cycles](Domain&, const CycleOutcome&) {
    allocs::is_bus_thread = true;
    cycles.fetch_add(1, std::memory_order_relaxed);
  };
  config.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs", "drive"}) {
    SlaveConfig s;
    s.name = name;
    if (std::string(name) != "coupler") s.process_data = ProcessDataRequest::all("main");
    s.health_poll.reset();
    config.slaves.push_back(s);
  }
  Master master(config);
  std::mutex m;
  std::vector<MasterState> states;
  master.on_state_change([&](MasterState, MasterState to) {
    std::lock_guard lock(m);
    states.push_back(to);
  });
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  ASSERT_TRUE(master.start(std::move(*link)));
  ASSERT_TRUE(master.await_operational(20s));
  while (cycles.load() < 20)
    std::this_thread::sleep_for(1ms);

  allocs::bus_thread = 0;
  allocs::count_bus_thread = true;
  ASSERT_TRUE(server->inject(sim::fault::next(sim::fault::logical_wkc_offset("outputs", -1), 5)));
  const auto recovering_seen = [&] {
    std::lock_guard lock(m);
    return std::find(states.begin(), states.end(), MasterState::recovering) != states.end();
  };
  const auto until = std::chrono::steady_clock::now() + 10s;
  while (!recovering_seen() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(1ms);
  EXPECT_TRUE(recovering_seen()) << "the degraded notice never reached the loop";
  auto back = master.await_operational(10s);
  EXPECT_TRUE(back) << (back ? "" : back.error().describe());
  const auto settled = cycles.load();
  while (cycles.load() < settled + 20)
    std::this_thread::sleep_for(1ms);
  allocs::count_bus_thread = false;
  EXPECT_EQ(allocs::bus_thread.load(), 0u)
      << "the bus thread allocated while the domain degraded and recovered";
  const auto stats = master.domain("main");
  ASSERT_TRUE(stats);
  EXPECT_TRUE((*stats)->stats().health.healthy);
  ASSERT_TRUE(master.stop());
}

}  // namespace
}  // namespace ecat::master
