#include "tsc_clock.hpp"

#include <fstream>
#include <string>

namespace ecat::master::detail {

bool tsc_usable() noexcept {
#if defined(__x86_64__)
  static const bool usable = [] {
    try {
      std::ifstream in("/sys/devices/system/clocksource/clocksource0/current_clocksource");
      std::string source;
      return static_cast<bool>(in >> source) && source == "tsc";
    } catch (...) {
      return false;
    }
  }();
  return usable;
#else
  return false;
#endif
}

void TscCalibration::sample(std::uint64_t before, std::int64_t ns, std::uint64_t after) noexcept {
  if (!usable_ || broken_) return;
  if (after < before || after - before > kMaxPairTicks) return;  // preempted between the reads
  if (!anchored_) {
    anchored_ = true;
    anchor_after_ = after;
    anchor_ns_ = ns;
    return;
  }
  if (before <= anchor_after_ || ns <= anchor_ns_) {
    // The counter or the clock went backwards: not a counter to rely on.
    broken_ = true;
    ticks_per_ns_ = 0;
    return;
  }
  if (rate_ == 0) {
    if (ns - anchor_ns_ < kFirstWindowNs) return;
    // From the anchor's later read to this triple's earlier one: at most the ticks between the
    // two clock reads, so the rate is a lower bound.
    rate_ = static_cast<double>(before - anchor_after_) / static_cast<double>(ns - anchor_ns_);
    ticks_per_ns_ = rate_ * (1 - kMargin);
    check_after_ = after;
    check_ns_ = ns;
    return;
  }
  if (ns - check_ns_ < kCheckWindowNs) return;
  if (before <= check_after_) {
    broken_ = true;
    ticks_per_ns_ = 0;
    return;
  }
  const double window =
      static_cast<double>(before - check_after_) / static_cast<double>(ns - check_ns_);
  // Only a slower counter matters: a faster one makes the stamps cover less time than asked.
  if (window < rate_ * (1 - kMaxDrift)) {
    broken_ = true;
    ticks_per_ns_ = 0;
    return;
  }
  check_after_ = after;
  check_ns_ = ns;
}

std::uint64_t TscCalibration::ticks_within(std::chrono::nanoseconds window) const noexcept {
  if (ticks_per_ns_ <= 0 || window.count() <= 0) return 0;
  return static_cast<std::uint64_t>(static_cast<double>(window.count()) * ticks_per_ns_);
}

}  // namespace ecat::master::detail
