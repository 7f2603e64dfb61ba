// Proves the domain's cycle and hot path allocate nothing once warmed up: the bus thread's
// on_tick (staging copy, submission), the completion (classification, seqlock publication,
// change records, observer), and an application thread's write / write_bits / read / sample /
// drain_changes.
//
// Global operator new is replaced by a counting one that counts on the bus thread (while the test
// says so) and on threads that asked for it (a thread_local flag). The simulator serves on its own
// thread, which is not counted.

#include <array>
#include <atomic>
#include <cstdlib>
#include <new>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>

#include "master/domain_test_support.hpp"
#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::master::test {
namespace {

// An observer that does what the header asks of one: count, nothing else.
class CountingObserver : public DomainObserver {
 public:
  void on_inputs_changed(Domain&, std::size_t count) override { changed.fetch_add(count); }
  std::atomic<std::size_t> changed{0};
};

TEST(DomainAllocations, CycleAndHotPathAllocateNothing) {
  bus::BusOptions options;
  options.frame_timeout = std::chrono::seconds(1);  // no spurious loss on a loaded machine
  options.on_thread_start = [] { allocs::is_bus_thread = true; };
  auto rig = make_rig(std::move(options));
  ASSERT_TRUE(rig);
  CountingObserver observer;
  DomainConfig config;
  config.id = "alloc";
  config.period = kPeriod / 2;
  config.realtime_budget = 50ms;  // a loaded machine must not turn cycles into expiries
  config.exchanges_in_flight = 16;
  auto created = Domain::create(*rig->bus, config, &observer);
  ASSERT_TRUE(created.ok());
  Domain& domain = **created;
  rig->attach(domain, kOutputs);
  rig->attach(domain, kInputs);
  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycler.add(domain).ok());
  ASSERT_TRUE(cycler.start().ok());
  ASSERT_TRUE(domain.start_cycling().ok());
  rig->all_to(wire::AlState::safeop);
  rig->all_to(wire::AlState::op);

  const auto out0 = domain.find({kOutputs, 0});
  const auto out1 = domain.find({kOutputs, 1});
  const auto in = domain.find({kInputs, 0});
  ASSERT_TRUE(out0.ok() && out1.ok() && in.ok());

  // Warm-up: every path once (first publication, change records, staging, reads).
  std::array<std::uint8_t, 2> buffer{};
  std::array<std::uint8_t, 1> value{1};
  ASSERT_TRUE(domain.write(*out0, value).ok());
  ASSERT_TRUE(eventually([&] { return domain.read(*in, buffer).ok() && buffer[0] == 1; }));
  (void)domain.drain_changes([](const InputChange&) {});

  allocs::counted.store(0);
  allocs::bus_thread.store(0);
  const auto cycles_before = domain.stats().cycle_count;
  const auto changed_before = observer.changed.load();

  // Counted phase: the bus thread and this thread.
  allocs::count_bus_thread.store(true);
  allocs::count_this_thread = true;
  std::size_t reads_ok = 0;
  std::size_t drained = 0;
  for (int i = 0; i < 400; ++i) {
    value[0] = static_cast<std::uint8_t>(i);
    const bool wrote = domain.write(*out0, value).ok() &&
                       domain.write_bits(*out1, static_cast<std::size_t>(i % 8), 1, i & 1).ok();
    if (!wrote) break;
    if (domain.read(*in, buffer).ok()) ++reads_ok;
    auto s = domain.sample(*in, buffer);
    if (!s.ok() || !s->freshness) break;
    drained += domain.drain_changes([](const InputChange&) {}).delivered;
    (void)domain.stats();
    std::this_thread::sleep_for(kPeriod / 2);
  }
  allocs::count_this_thread = false;
  allocs::count_bus_thread.store(false);

  const auto stats = domain.stats();
  const auto cycles = stats.cycle_count - cycles_before;
  EXPECT_EQ(allocs::counted.load(), 0u);
  EXPECT_EQ(allocs::bus_thread.load(), 0u);
  EXPECT_EQ(reads_ok, 400u);
  EXPECT_GT(cycles, 100u);
  EXPECT_GT(drained, 10u);
  EXPECT_GT(observer.changed.load() - changed_before, 10u);
  EXPECT_EQ(stats.wkc_mismatch_count, 0u);
  // Misses are possible on a starved machine (sanitizers, parallel builds) and allocate nothing
  // either: the counters above cover them too.
  std::printf(
      "cycles %llu, valid %llu, misses %llu, change records drained %zu, latency min/mean/max "
      "%lld/%lld/%lld us\n",
      static_cast<unsigned long long>(cycles), static_cast<unsigned long long>(stats.valid_count),
      static_cast<unsigned long long>(stats.total_miss_count), drained,
      static_cast<long long>(stats.min_latency.count() / 1000),
      static_cast<long long>(stats.mean_latency.count() / 1000),
      static_cast<long long>(stats.max_latency.count() / 1000));

  // The counters are live: an error message on a counting thread allocates.
  allocs::count_this_thread = true;
  EXPECT_FALSE(domain.read(PdoKey{0x7777, 0}, buffer).ok());
  allocs::count_this_thread = false;
  EXPECT_GT(allocs::counted.load(), 0u);
  ASSERT_TRUE(cycler.stop().ok());
}

}  // namespace
}  // namespace ecat::master::test
