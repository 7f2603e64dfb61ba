// Cycler: several participants with different periods on one bus cycle, in phase and in priority
// order; runtime add/remove/period changes; two real domains at 1 ms and 2 ms.

#include <array>
#include <atomic>

#include <gtest/gtest.h>

#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>

#include "master/domain_test_support.hpp"

namespace ecat::master::test {
namespace {

using Bytes = std::vector<std::uint8_t>;

// Appends (tick number, deadline, id) to a shared preallocated log on every run.
struct Log {
  struct Record {
    std::uint64_t cycle = 0;
    std::int64_t deadline_ns = 0;
    std::uint64_t missed = 0;
    int id = 0;
  };
  static constexpr std::size_t kCapacity = 1 << 16;
  std::vector<Record> records = std::vector<Record>(kCapacity);
  std::atomic<std::size_t> size{0};

  void add(const bus::CycleTick& tick, int id) {
    const std::size_t i = size.fetch_add(1);
    if (i < kCapacity) {
      records[i] = {
          tick.cycle,
          std::chrono::duration_cast<std::chrono::nanoseconds>(tick.deadline.time_since_epoch())
              .count(),
          tick.missed, id};
    }
  }
  std::vector<Record> snapshot() const {
    return {records.begin(),
            records.begin() + static_cast<std::ptrdiff_t>(std::min(size.load(), kCapacity))};
  }
};

class Counter : public CyclicParticipant {
 public:
  Counter(std::chrono::nanoseconds period, int id, Log* log = nullptr)
      : period_(period.count()), id_(id), log_(log) {}
  ~Counter() override { detach_from_cycler(); }
  void on_tick(const bus::CycleTick& tick) override {
    runs.fetch_add(1);
    if (log_) log_->add(tick, id_);
    if (on_tick_hook) on_tick_hook();
  }
  std::chrono::nanoseconds cycle_period() const noexcept override {
    return std::chrono::nanoseconds(period_.load());
  }
  Result<void> set_period(std::chrono::nanoseconds p) {
    period_.store(p.count());
    return notify_period_changed();
  }
  std::atomic<std::uint64_t> runs{0};
  std::function<void()> on_tick_hook;

 private:
  std::atomic<std::int64_t> period_;
  int id_;
  Log* log_;
};

TEST(CyclerTest, PhaseAndPriorityOrder) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  Log log;
  Counter fast(1ms, 1, &log);
  Counter slow(2ms, 2, &log);
  Counter dc(1ms, 3, &log);
  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycler.add(fast).ok());
  ASSERT_TRUE(cycler.add(slow).ok());
  ASSERT_TRUE(cycler.add(dc, Cycler::kPriorityDc).ok());
  EXPECT_EQ(cycler.base_period(), 1ms);
  ASSERT_TRUE(cycler.start().ok());
  std::this_thread::sleep_for(100ms);
  ASSERT_TRUE(cycler.stop().ok());
  const auto records = log.snapshot();
  ASSERT_GT(records.size(), 60u);

  // Group by tick: the DC participant first, then fast, then slow (registration order); slow
  // only on even milliseconds, and always together with fast.
  std::size_t i = 0;
  std::size_t ticks = 0;
  std::size_t slow_ticks = 0;
  std::size_t late_catch_ups = 0;
  while (i < records.size()) {
    std::size_t j = i;
    while (j < records.size() && records[j].cycle == records[i].cycle)
      ++j;
    std::vector<int> ids;
    for (std::size_t k = i; k < j; ++k)
      ids.push_back(records[k].id);
    const bool even = records[i].deadline_ns % 2'000'000 == 0;
    EXPECT_EQ(records[i].deadline_ns % 1'000'000, 0) << "tick deadline on the 1 ms grid";
    if (even) {
      EXPECT_EQ(ids, (std::vector<int>{3, 1, 2})) << "tick " << records[i].cycle;
      ++slow_ticks;
    } else if (records[i].missed > 0 && ids.size() == 3) {
      // The bus thread woke late and skipped the even deadline: the slow participant runs now,
      // once, and is back on its grid next time.
      EXPECT_EQ(ids, (std::vector<int>{3, 1, 2})) << "tick " << records[i].cycle;
      ++slow_ticks;
      ++late_catch_ups;
    } else {
      EXPECT_EQ(ids, (std::vector<int>{3, 1})) << "tick " << records[i].cycle;
    }
    ++ticks;
    i = j;
  }
  const auto skipped = static_cast<double>(cycler.stats().deadlines_skipped);
  EXPECT_NEAR(static_cast<double>(slow_ticks), ticks / 2.0, 1.5 + skipped);
  std::printf("ticks %zu, deadlines skipped %.0f, late catch-ups %zu\n", ticks, skipped,
              late_catch_ups);
  const auto stats = cycler.stats();
  EXPECT_EQ(stats.ticks, ticks);
  EXPECT_EQ(stats.participant_runs, records.size());
  EXPECT_EQ(stats.participants, 3u);
  EXPECT_FALSE(stats.running);
}

TEST(CyclerTest, AddRemoveAndPeriodChangesAtRuntime) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  Cycler cycler(*rig->bus);
  Counter a(1ms, 1);
  ASSERT_TRUE(cycler.start().ok());  // nothing yet: the first add installs the cycle
  ASSERT_TRUE(cycler.add(a).ok());
  ASSERT_TRUE(eventually([&] { return a.runs.load() > 10; }));

  auto dup = cycler.add(a);
  ASSERT_FALSE(dup.ok());
  EXPECT_EQ(dup.error().message(), "cycler: participant already added");

  {
    Counter b(250us, 2);
    ASSERT_TRUE(cycler.add(b).ok());
    EXPECT_EQ(cycler.base_period(), 250us);
    ASSERT_TRUE(eventually([&] { return b.runs.load() > 40; }));
    ASSERT_TRUE(cycler.remove(b).ok());
    const auto after = b.runs.load();
    std::this_thread::sleep_for(10ms);
    EXPECT_EQ(b.runs.load(), after) << "not called after remove() returned";
    EXPECT_EQ(b.cycler(), nullptr);
    EXPECT_EQ(cycler.base_period(), 1ms);
    // Destroyed while not in a cycler.
  }
  {
    Counter c(500us, 3);
    ASSERT_TRUE(cycler.add(c).ok());
    ASSERT_TRUE(eventually([&] { return c.runs.load() > 10; }));
    // Destroyed while added: it removes itself first.
  }
  EXPECT_EQ(cycler.stats().participants, 1u);

  // A period change through the participant reschedules.
  ASSERT_TRUE(a.set_period(3ms).ok());
  EXPECT_EQ(cycler.base_period(), 3ms);
  auto before = a.runs.load();
  std::this_thread::sleep_for(150ms);
  auto runs = a.runs.load() - before;
  EXPECT_GE(runs, 30u);
  EXPECT_LE(runs, 52u);

  // A base tick below the minimum is refused; the old schedule stays.
  Counter odd(333us, 4);
  auto refused = cycler.add(odd);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::out_of_range);
  EXPECT_EQ(refused.error().message(),
            "cycler: the periods 3000000 ns, 333000 ns have a common base tick of 3000 ns, below "
            "the 10000 ns minimum; choose periods that are multiples of a common tick");
  EXPECT_EQ(odd.cycler(), nullptr);
  EXPECT_EQ(cycler.base_period(), 3ms);
  {
    Counter other(1ms, 6);
    ASSERT_TRUE(cycler.add(other).ok());
    EXPECT_EQ(cycler.base_period(), 1ms);
    auto bad_change = a.set_period(1000001ns);
    ASSERT_FALSE(bad_change.ok());
    EXPECT_EQ(bad_change.error().code(), Errc::out_of_range);
    EXPECT_EQ(cycler.base_period(), 1ms);
  }
  EXPECT_EQ(cycler.base_period(), 1000001ns);  // the other one left; a's new period applies

  // Calls from the bus thread are refused rather than deadlocking.
  ASSERT_TRUE(a.set_period(1ms).ok());
  std::atomic<int> refused_on_bus{0};
  Counter prober(1ms, 5);
  prober.on_tick_hook = [&] {
    auto r = cycler.add(odd);
    if (!r.ok() && r.error().code() == Errc::wrong_state) refused_on_bus.fetch_add(1);
    auto s = cycler.stop();
    if (!s.ok() && s.error().code() == Errc::wrong_state) refused_on_bus.fetch_add(1);
  };
  ASSERT_TRUE(cycler.add(prober).ok());
  ASSERT_TRUE(eventually([&] { return refused_on_bus.load() >= 2; }));
  ASSERT_TRUE(cycler.remove(prober).ok());
  ASSERT_TRUE(cycler.stop().ok());
  const auto stopped_at = a.runs.load();
  std::this_thread::sleep_for(10ms);
  EXPECT_EQ(a.runs.load(), stopped_at);
  EXPECT_EQ(cycler.remove(odd).error().code(), Errc::not_found);
}

// A link that records the frame budget the bus tells it (Link::set_frame_budget).
class BudgetLink final : public link::ForwardingLink {
 public:
  explicit BudgetLink(std::unique_ptr<link::Link> inner) : ForwardingLink(std::move(inner)) {}
  void set_frame_budget(std::chrono::nanoseconds budget) override { told.store(budget.count()); }
  std::atomic<std::int64_t> told{-1};
};

// The link's frame budget follows the fastest participant, not the base tick: at 2 ms and 3 ms
// the bus ticks at 1 ms, and three of the fastest period (6 ms) is the cap, within the frame
// timeout; the changes of the schedule carry it along.
TEST(CyclerTest, TheLinksFrameBudgetFollowsTheFastestParticipant) {
  auto pair = link::make_memory_link_pair();
  auto budget_link = std::make_unique<BudgetLink>(std::move(pair.first));
  BudgetLink* link = budget_link.get();
  bus::BusOptions options;
  options.frame_timeout = 50ms;
  bus::Bus bus(std::move(budget_link), options);
  ASSERT_TRUE(bus.start());
  const auto told = [&] { return std::chrono::nanoseconds(link->told.load()); };
  Cycler cycler(bus);
  Counter two(2ms, 1);
  Counter three(3ms, 2);
  ASSERT_TRUE(cycler.add(two).ok());
  ASSERT_TRUE(cycler.add(three).ok());
  ASSERT_TRUE(cycler.start().ok());
  EXPECT_EQ(cycler.base_period(), 1ms);
  EXPECT_EQ(told(), 6ms);
  {
    Counter fast(1ms, 3);
    ASSERT_TRUE(cycler.add(fast).ok());
    EXPECT_EQ(told(), 3ms);
    Counter slow(10ms, 4);
    ASSERT_TRUE(cycler.add(slow).ok());
    EXPECT_EQ(told(), 3ms);
    ASSERT_TRUE(cycler.remove(fast).ok());
    EXPECT_EQ(told(), 6ms);
  }
  ASSERT_TRUE(two.set_period(30ms).ok());
  EXPECT_EQ(told(), 9ms);
  ASSERT_TRUE(cycler.remove(three).ok());
  EXPECT_EQ(told(), 50ms);  // 3 x 30 ms is beyond the frame timeout
  ASSERT_TRUE(cycler.stop().ok());
  EXPECT_EQ(told(), 50ms);
  ASSERT_TRUE(cycler.remove(two).ok());
  bus.stop();
}

TEST(CyclerTest, TwoDomainsAtOneAndTwoMilliseconds) {
  auto rig = make_rig();
  ASSERT_TRUE(rig);
  DomainConfig fast_config;
  fast_config.id = "fast";
  fast_config.period = kPeriod;
  fast_config.logical_base = 0;
  DomainConfig slow_config;
  slow_config.id = "slow";
  slow_config.period = 2 * kPeriod;
  slow_config.logical_base = 0x800;
  auto fast = Domain::create(*rig->bus, fast_config);
  auto slow = Domain::create(*rig->bus, slow_config);
  ASSERT_TRUE(fast.ok() && slow.ok());
  rig->attach(**fast, kOutputs);
  rig->attach(**fast, kInputs);
  rig->attach(**slow, kInputs2);

  Cycler cycler(*rig->bus);
  ASSERT_TRUE(cycler.add(**fast).ok());
  ASSERT_TRUE(cycler.add(**slow).ok());
  EXPECT_EQ(cycler.base_period(), kPeriod);
  ASSERT_TRUE(cycler.start().ok());
  ASSERT_TRUE((*fast)->start_cycling().ok());
  ASSERT_TRUE((*slow)->start_cycling().ok());
  rig->all_to(wire::AlState::safeop);
  rig->all_to(wire::AlState::op);
  ASSERT_TRUE(eventually([&] { return (*slow)->stats().valid_count > 5; }));

  const auto f0 = (*fast)->stats().cycle_count;
  const auto s0 = (*slow)->stats().cycle_count;
  const auto skipped0 = cycler.stats().deadlines_skipped;
  std::this_thread::sleep_for(200ms * kSlow);
  const auto f = (*fast)->stats().cycle_count - f0;
  const auto s = (*slow)->stats().cycle_count - s0;
  const auto skipped = static_cast<double>(cycler.stats().deadlines_skipped - skipped0);
  EXPECT_GT(s, 50u);
  // Both count ticks of the same bus cycle: the ratio is 2 up to the edges of the window, and up
  // to the deadlines a late bus thread skipped (each costs the fast domain a cycle, the slow one
  // only every second time).
  EXPECT_NEAR(static_cast<double>(f), 2.0 * static_cast<double>(s), 3.0 + 2.0 * skipped)
      << f << " vs " << s << ", skipped deadlines " << skipped;

  EXPECT_EQ((*fast)->info().expected_wkc, 3u);
  EXPECT_EQ((*slow)->info().expected_wkc, 1u);
  EXPECT_EQ((*fast)->stats().last_wkc, 3u);
  EXPECT_EQ((*slow)->stats().last_wkc, 1u);
  EXPECT_EQ((*fast)->stats().wkc_mismatch_count, 0u);
  EXPECT_EQ((*slow)->stats().wkc_mismatch_count, 0u);
  ASSERT_TRUE((*fast)->write(PdoKey{kOutputs, 0}, Bytes{0x77}).ok());
  ASSERT_TRUE((*fast)->write(PdoKey{kOutputs, 1}, Bytes{0x66}).ok());
  EXPECT_TRUE(eventually([&] {
    auto v = (*fast)->read(PdoKey{kInputs, 0});
    return v.ok() && *v == Bytes{0x77, 0x66};
  }));
  auto slow_inputs = (*slow)->read(PdoKey{kInputs2, 0});
  ASSERT_TRUE(slow_inputs.ok());
  EXPECT_EQ(*slow_inputs, (Bytes{0, 0}));  // nothing wired to inputs2
  ASSERT_TRUE(cycler.stop().ok());
}

}  // namespace
}  // namespace ecat::master::test
