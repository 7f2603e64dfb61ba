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

namespace {

thread_local bool t_count_allocations = false;
thread_local bool t_is_bus_thread = false;
std::atomic<bool> g_count_bus_thread{false};
std::atomic<std::size_t> g_app_thread_allocations{0};
std::atomic<std::size_t> g_bus_thread_allocations{0};

void note_allocation() noexcept {
  if (t_count_allocations) g_app_thread_allocations.fetch_add(1, std::memory_order_relaxed);
  if (t_is_bus_thread && g_count_bus_thread.load(std::memory_order_relaxed)) {
    g_bus_thread_allocations.fetch_add(1, std::memory_order_relaxed);
  }
}

void* allocate(std::size_t size) {
  note_allocation();
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}

void* allocate_aligned(std::size_t size, std::align_val_t alignment) {
  note_allocation();
  const auto align = static_cast<std::size_t>(alignment);
  const std::size_t rounded = (size + align - 1) / align * align;
  if (void* p = std::aligned_alloc(align, rounded == 0 ? align : rounded)) return p;
  throw std::bad_alloc();
}

}  // namespace

void* operator new(std::size_t size) {
  return allocate(size);
}
void* operator new[](std::size_t size) {
  return allocate(size);
}
void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  note_allocation();
  return std::malloc(size == 0 ? 1 : size);
}
void* operator new[](std::size_t size, const std::nothrow_t&) noexcept {
  note_allocation();
  return std::malloc(size == 0 ? 1 : size);
}
void* operator new(std::size_t size, std::align_val_t alignment) {
  return allocate_aligned(size, alignment);
}
void* operator new[](std::size_t size, std::align_val_t alignment) {
  return allocate_aligned(size, alignment);
}
void operator delete(void* p) noexcept {
  std::free(p);
}
void operator delete[](void* p) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::size_t) noexcept {
  std::free(p);
}
void operator delete(void* p, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete(void* p, std::size_t, std::align_val_t) noexcept {
  std::free(p);
}
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept {
  std::free(p);
}

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
  options.on_thread_start = [] { t_is_bus_thread = true; };
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

  g_app_thread_allocations.store(0);
  g_bus_thread_allocations.store(0);
  const auto cycles_before = domain.stats().cycle_count;
  const auto changed_before = observer.changed.load();

  // Counted phase: the bus thread and this thread.
  g_count_bus_thread.store(true);
  t_count_allocations = true;
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
  t_count_allocations = false;
  g_count_bus_thread.store(false);

  const auto stats = domain.stats();
  const auto cycles = stats.cycle_count - cycles_before;
  EXPECT_EQ(g_app_thread_allocations.load(), 0u);
  EXPECT_EQ(g_bus_thread_allocations.load(), 0u);
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
  t_count_allocations = true;
  EXPECT_FALSE(domain.read(PdoKey{0x7777, 0}, buffer).ok());
  t_count_allocations = false;
  EXPECT_GT(g_app_thread_allocations.load(), 0u);
  ASSERT_TRUE(cycler.stop().ok());
}

}  // namespace
}  // namespace ecat::master::test
