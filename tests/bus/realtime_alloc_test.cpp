// Proves the realtime path allocates nothing: submit, send, receive, match, complete and wait.
//
// Global operator new is replaced by a counting one. Allocations are counted only on threads that
// asked for it (a thread_local flag), and on the bus thread while the test says so. Phase A runs
// realtime cycles alone and counts both the realtime thread and the bus thread; phase B runs them
// while another thread keeps reliable transactions flowing and counts the realtime thread.

#include <array>
#include <atomic>
#include <cstdlib>
#include <new>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>

#include "bus/bus_test_support.hpp"
#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::bus::test {
namespace {

struct CycleOutcome {
  int not_ok = 0;
  int wrong_data = 0;
};

// Runs `cycles` realtime LRW exchanges; allocations on this thread are counted while `count`.
CycleOutcome run_cycles(Bus& bus, RealtimeTransaction& rt, int cycles, bool count) {
  CycleOutcome outcome;
  allocs::count_this_thread = count;
  for (int i = 0; i < cycles; ++i) {
    auto out = rt.output(0);
    out[0] = static_cast<std::uint8_t>(i);
    out[1] = static_cast<std::uint8_t>(i >> 8);
    if (!bus.submit_realtime(rt, std::chrono::seconds(1))) {
      ++outcome.not_ok;
      continue;
    }
    rt.wait();
    if (rt.status() != RealtimeStatus::ok) {
      ++outcome.not_ok;
      continue;
    }
    const auto in = rt.input(0);
    if (in[0] != static_cast<std::uint8_t>(i) || in[2] != 0xC1 || rt.wkc(0) != 3) {
      ++outcome.wrong_data;
    }
  }
  allocs::count_this_thread = false;
  return outcome;
}

TEST(RealtimeAllocations, RealtimePathAllocatesNothing) {
  FakeSegment::Options seg;
  seg.record = false;  // the fake's frame log would allocate
  auto segment = make_segment(seg);
  segment->map_logical(0, {0x00010000, 0x1000, 2, false, true});
  segment->map_logical(1, {0x00010002, 0x1100, 2, true, false});
  const std::array<std::uint8_t, 2> inputs{0xC1, 0xC2};
  segment->write(1, 0x1100, inputs);

  BusOptions options;
  options.frame_timeout = std::chrono::seconds(1);  // no spurious loss on a loaded machine
  options.on_thread_start = [] { allocs::is_bus_thread = true; };
  auto bus = start_bus(segment, options);

  Transaction layout;
  const std::array<std::uint8_t, 4> image{};
  layout.lrw(0x00010000, image, 3);
  RealtimeTransaction rt(std::move(layout));

  // Counters are global: measure from here (another test may have counted before).
  allocs::counted.store(0);
  allocs::bus_thread.store(0);

  constexpr int kCycles = 5000;
  CycleOutcome warmup;
  CycleOutcome phase_a;
  CycleOutcome phase_b;

  // Phase A: realtime alone; count the realtime thread and the bus thread.
  std::thread realtime([&] {
    warmup = run_cycles(*bus, rt, 200, false);
    allocs::count_bus_thread.store(true);
    phase_a = run_cycles(*bus, rt, kCycles, true);
    allocs::count_bus_thread.store(false);
  });
  realtime.join();
  EXPECT_EQ(warmup.not_ok + warmup.wrong_data, 0);
  EXPECT_EQ(phase_a.not_ok, 0);
  EXPECT_EQ(phase_a.wrong_data, 0);
  EXPECT_EQ(allocs::counted.load(), 0u);
  EXPECT_EQ(allocs::bus_thread.load(), 0u);

  // The bus-thread counter is live: a failing reliable transaction formats its message there.
  allocs::count_bus_thread.store(true);
  Transaction failing;
  failing.fprd(0x7777, 0x0130, 2, 1);
  EXPECT_FALSE(bus->transact(std::move(failing)));
  allocs::count_bus_thread.store(false);
  EXPECT_GT(allocs::bus_thread.load(), 0u);

  // Phase B: reliable traffic from another thread at the same time; count the realtime thread.
  std::atomic<bool> stop{false};
  std::atomic<int> reliable_done{0};
  std::atomic<int> reliable_failed{0};
  std::thread reliable([&] {
    const std::array<std::uint8_t, 4> value{1, 2, 3, 4};
    while (!stop.load()) {
      Transaction tx;
      tx.fpwr(0x1003, 0x1200, value, 1);
      tx.fprd(0x1003, 0x1200, 4, 1);
      if (bus->transact(std::move(tx))) {
        reliable_done.fetch_add(1);
      } else {
        reliable_failed.fetch_add(1);
      }
    }
  });
  std::thread realtime_b([&] { phase_b = run_cycles(*bus, rt, kCycles, true); });
  realtime_b.join();
  stop.store(true);
  reliable.join();

  EXPECT_EQ(phase_b.not_ok, 0);
  EXPECT_EQ(phase_b.wrong_data, 0);
  EXPECT_EQ(allocs::counted.load(), 0u);
  EXPECT_GT(reliable_done.load(), 0);
  EXPECT_EQ(reliable_failed.load(), 0);
  const auto stats = bus->stats();
  EXPECT_EQ(stats.realtime_completed, static_cast<std::uint64_t>(200 + 2 * kCycles));
  EXPECT_EQ(stats.realtime_expired + stats.realtime_timeouts, 0u);
  std::printf("realtime cycles: %d; reliable transactions alongside: %d; frames sent: %llu\n",
              200 + 2 * kCycles, reliable_done.load(),
              static_cast<unsigned long long>(stats.frames_sent));
}

// The counter itself works: an allocation on a counting thread is seen.
TEST(RealtimeAllocations, CounterSeesAllocations) {
  const auto before = allocs::counted.load();
  allocs::count_this_thread = true;
  void* volatile p = ::operator new(16);
  allocs::count_this_thread = false;
  ::operator delete(p);
  EXPECT_EQ(allocs::counted.load(), before + 1);
}

}  // namespace
}  // namespace ecat::bus::test
