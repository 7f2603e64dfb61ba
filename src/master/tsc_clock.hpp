// A cheap upper bound on elapsed time for the input hot path's staleness check (issue #17).
// Private to src/master.
//
// A freshness check asks "has less than stale_after passed since the last valid cycle?". Reading
// the clock for it costs a vDSO clock_gettime per call (28..39 ns on a VM). On x86-64, where the
// kernel itself keeps time with the TSC, the bus thread instead stamps each publish with the TSC
// count beyond which the input may be stale (`TscCalibration::ticks_within`, a rate measured
// against the clock and lowered by a margin), and a reader compares one unfenced rdtsc with that
// stamp: below it, less than stale_after has certainly passed; at or above it, the reader reads
// the clock as before. The verdict is therefore the clock's own (stale iff older than
// stale_after); the TSC only proves "fresh" early. Elsewhere, or when the kernel does not use
// the TSC, or when the measured rate drifts, no stamp is made and every check reads the clock.
#pragma once

#include <chrono>
#include <cstdint>

#if defined(__x86_64__)
#include <x86intrin.h>
#endif

namespace ecat::master::detail {

// The time stamp counter (0 where there is none: no stamp is ever made then).
inline std::uint64_t read_tsc() noexcept {
#if defined(__x86_64__)
  return __rdtsc();
#else
  return 0;
#endif
}

// Whether the stamps may be made at all: x86-64, and the kernel's clocksource is the TSC (so it
// runs at a constant rate in step with CLOCK_MONOTONIC). Read once per process.
bool tsc_usable() noexcept;

// The TSC's rate against the clock, measured by the bus thread from (tsc, clock, tsc) triples it
// reads anyway (one per reply). Bus thread only.
class TscCalibration {
 public:
  // Margin taken off the measured rate: a stamp covers at most 7/8 of the window asked for.
  static constexpr double kMargin = 1.0 / 8;
  // Triples whose two TSC reads are further apart than this (a preemption between them) are
  // not used: a clock read takes a few hundred ticks.
  static constexpr std::uint64_t kMaxPairTicks = 20'000;
  // The rate is measured from the later TSC read of a first triple to the earlier read of one at
  // least kFirstWindowNs later: fewer ticks than passed between the two clock reads, so a lower
  // bound whatever the window (a short one only lowers it further, by at most
  // 2 x kMaxPairTicks over the window's ticks, under 1 % at 1 GHz). Then checked again over every
  // kCheckWindowNs.
  static constexpr std::int64_t kFirstWindowNs = 5'000'000;
  static constexpr std::int64_t kCheckWindowNs = 100'000'000;
  // A later window whose rate is lower than the first's by more than this drops the stamps for
  // good (the TSC is not the steady counter it was taken for).
  static constexpr double kMaxDrift = 0.02;

  // `before` and `after` are TSC reads on either side of the clock read `ns`.
  void sample(std::uint64_t before, std::int64_t ns, std::uint64_t after) noexcept;
  // TSC ticks that certainly take less than `window` of the clock; 0 while not calibrated (or
  // after a drift, or without a usable TSC).
  std::uint64_t ticks_within(std::chrono::nanoseconds window) const noexcept;
  bool calibrated() const noexcept { return ticks_per_ns_ > 0; }

 private:
  bool usable_ = tsc_usable();
  bool broken_ = false;
  bool anchored_ = false;
  std::uint64_t anchor_after_ = 0;  // the anchor triple's later TSC read
  std::int64_t anchor_ns_ = 0;
  std::uint64_t check_after_ = 0;  // the triple that started the current check window
  std::int64_t check_ns_ = 0;
  double rate_ = 0;          // measured ticks per ns (lower bound over the first window)
  double ticks_per_ns_ = 0;  // rate_ less the margin: what stamps use
};

}  // namespace ecat::master::detail
