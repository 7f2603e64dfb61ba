// The TSC freshness stamps' calibration (src/master/tsc_clock.hpp): a lower bound on the rate,
// nothing before a measured window, nothing once the counter misbehaves.
#include "master/tsc_clock.hpp"

#include <chrono>
#include <cstdint>

#include <gtest/gtest.h>

namespace ecat::master::detail {
namespace {

using namespace std::chrono_literals;

// A counter at `rate` ticks per ns; each triple reads it `skew` ticks either side of the clock.
struct FakeCounter {
  double rate = 3.0;
  std::uint64_t base = 1'000'000;
  std::uint64_t skew = 300;
  void feed(TscCalibration& c, std::int64_t ns) const {
    const auto at = base + static_cast<std::uint64_t>(static_cast<double>(ns) * rate);
    c.sample(at - skew, ns, at + skew);
  }
};

TEST(DomainTscStamp, CalibratesToALowerBoundAfterItsFirstWindow) {
  if (!tsc_usable()) GTEST_SKIP() << "no TSC clocksource here: stamps are never made";
  TscCalibration c;
  FakeCounter counter;
  counter.feed(c, 1'000'000);
  EXPECT_EQ(c.ticks_within(3ms), 0u) << "no stamp before a window was measured";
  counter.feed(c, 1'000'000 + TscCalibration::kFirstWindowNs / 2);
  EXPECT_EQ(c.ticks_within(3ms), 0u);
  counter.feed(c, 1'000'000 + TscCalibration::kFirstWindowNs);
  ASSERT_TRUE(c.calibrated());
  const double true_ticks = 3e6 * counter.rate;
  const auto ticks = static_cast<double>(c.ticks_within(3ms));
  EXPECT_LT(ticks, true_ticks * (1 - TscCalibration::kMargin) + 1) << "never more than 7/8";
  EXPECT_GT(ticks, true_ticks * (1 - TscCalibration::kMargin) * 0.99);
  EXPECT_EQ(c.ticks_within(0ns), 0u);
}

TEST(DomainTscStamp, PreemptedTriplesAreIgnored) {
  if (!tsc_usable()) GTEST_SKIP() << "no TSC clocksource here: stamps are never made";
  TscCalibration c;
  // A triple whose two reads are far apart (preempted between them) anchors nothing.
  c.sample(1'000, 1'000'000, 1'000 + TscCalibration::kMaxPairTicks + 1);
  FakeCounter counter;
  counter.feed(c, 2'000'000 + TscCalibration::kFirstWindowNs);
  EXPECT_FALSE(c.calibrated()) << "the good triple is the anchor, not the end of a window";
}

TEST(DomainTscStamp, ASlowerOrBackwardCounterDropsTheStampsForGood) {
  if (!tsc_usable()) GTEST_SKIP() << "no TSC clocksource here: stamps are never made";
  TscCalibration slowed;
  FakeCounter counter;
  std::int64_t ns = 1'000'000;
  counter.feed(slowed, ns);
  ns += TscCalibration::kFirstWindowNs;
  counter.feed(slowed, ns);
  ASSERT_TRUE(slowed.calibrated());
  // The counter runs 10 % slower over the next check window: its stamps would outlast the time
  // they stand for, so none are made any more, even once it is back at its rate.
  counter.base -= static_cast<std::uint64_t>(0.1 * counter.rate * TscCalibration::kCheckWindowNs);
  ns += TscCalibration::kCheckWindowNs;
  counter.feed(slowed, ns);
  EXPECT_FALSE(slowed.calibrated());
  EXPECT_EQ(slowed.ticks_within(3ms), 0u);
  ns += TscCalibration::kCheckWindowNs;
  counter.feed(slowed, ns);
  EXPECT_FALSE(slowed.calibrated());

  TscCalibration backwards;
  backwards.sample(10'000'000, 1'000'000, 10'000'300);
  backwards.sample(5'000'000, 1'000'000 + TscCalibration::kFirstWindowNs, 5'000'300);
  EXPECT_FALSE(backwards.calibrated());
  backwards.sample(20'000'000'000, 2'000'000'000, 20'000'000'300);
  EXPECT_FALSE(backwards.calibrated()) << "dropped for good";
}

TEST(DomainTscStamp, AFasterCounterKeepsTheStamps) {
  if (!tsc_usable()) GTEST_SKIP() << "no TSC clocksource here: stamps are never made";
  TscCalibration c;
  FakeCounter counter;
  std::int64_t ns = 1'000'000;
  counter.feed(c, ns);
  ns += TscCalibration::kFirstWindowNs;
  counter.feed(c, ns);
  const auto before = c.ticks_within(3ms);
  // More ticks than expected over a window: stamps cover less time than asked, still true.
  counter.base += static_cast<std::uint64_t>(0.1 * counter.rate * TscCalibration::kCheckWindowNs);
  ns += TscCalibration::kCheckWindowNs;
  counter.feed(c, ns);
  EXPECT_TRUE(c.calibrated());
  EXPECT_EQ(c.ticks_within(3ms), before);
}

}  // namespace
}  // namespace ecat::master::detail
