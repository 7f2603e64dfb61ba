// A SignalHandle's read() and write() from the per-cycle callback allocate nothing: the
// allocations made on the cycle thread while the callback uses its handles are counted.
#include <atomic>
#include <chrono>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/ecat.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

struct Loop {
  SignalHandle input;
  SignalHandle output;
  std::atomic<bool> armed{false};
  std::atomic<std::uint64_t> reads{0};
  std::atomic<std::uint64_t> writes{0};
  std::atomic<std::uint64_t> failures{0};
  bool level = false;

  void on_cycle(const CycleOutcome& outcome) {
    if (!outcome.valid || !armed.load(std::memory_order_acquire)) return;
    allocs::count_this_thread = true;
    auto value = input.read();
    if (value) {
      reads.fetch_add(1, std::memory_order_relaxed);
      level = !as_bool(*value).value_or(false);
    }
    auto written = output.write(Value(level));
    allocs::count_this_thread = false;
    if (written) {
      writes.fetch_add(1, std::memory_order_relaxed);
    }
    if (!value || !written) failures.fetch_add(1, std::memory_order_relaxed);
  }
};

TEST(SignalHandleAllocations, ReadAndWriteFromTheCycleCallbackAllocateNothing) {
  Loop loop;
  auto master = open_master(std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml",
                            {.configure = [&loop](MasterConfig& config) {
                              for (auto& d : config.domains) {
                                if (d.id != "main") continue;
                                d.stale_after = 10s;  // a stale read would be an error (text)
                                d.on_cycle = [&loop](Domain&, const CycleOutcome& outcome) {
                                  loop.on_cycle(outcome);
                                };
                              }
                            }});
  ASSERT_TRUE(master) << master.error().describe();
  ASSERT_TRUE((*master)->await_operational(20s));
  auto input = (*master)->signal_handle("inputs", "channel_1");
  auto output = (*master)->signal_handle("outputs", "channel_1");
  ASSERT_TRUE(input && output);
  loop.input = std::move(*input);
  loop.output = std::move(*output);
  const auto counted_before = allocs::counted.load();
  loop.armed.store(true, std::memory_order_release);
  auto domain = (*master)->domain("main");
  ASSERT_TRUE(domain);
  for (int i = 0; i < 200; ++i)
    ASSERT_TRUE((*domain)->await_next_cycle(2s));
  loop.armed.store(false, std::memory_order_release);
  ASSERT_TRUE((*domain)->await_next_cycle(2s));  // the callback has seen armed == false

  EXPECT_GE(loop.reads.load(), 100u);
  EXPECT_GE(loop.writes.load(), 100u);
  EXPECT_EQ(loop.failures.load(), 0u);
  EXPECT_EQ(allocs::counted.load() - counted_before, 0u);
  ASSERT_TRUE((*master)->stop());
}

}  // namespace
}  // namespace ecat::master
