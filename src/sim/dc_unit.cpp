#include <algorithm>
#include <cmath>
#include <limits>

#include <ecat/sim/dc_unit.hpp>

namespace ecat::sim {

namespace reg = wire::reg;

namespace {

// Speed Counter Start (0x0930): reset value and the range the ESC accepts (ESC register
// description, "Speed Counter Start"). The speed counter diff may swing ±(start − 0x7F).
constexpr std::uint16_t kSpeedCounterStartReset = 0x1000;
constexpr std::uint16_t kSpeedCounterStartMin = 0x0080;
constexpr std::uint16_t kSpeedCounterStartMax = 0x3FFF;
constexpr std::uint16_t kSpeedCounterDiffMargin = 0x7F;
// Filter depths after power-up (0x0934 / 0x0935).
constexpr std::uint8_t kTimeDifferenceFilterDepthReset = 0x04;
constexpr std::uint8_t kSpeedCounterFilterDepthReset = 0x0C;
// Samples closer together than this carry no usable frequency information (two writes of 0x0910
// in one frame, say); they only update the phase.
constexpr std::int64_t kMinFrequencyInterval = 1'000;
// Activation register (0x0981) bits beyond the three enables.
constexpr std::uint8_t kAutoActivation = 0x08;
constexpr std::uint8_t kStartTimeExtension = 0x10;
constexpr std::uint8_t kPlausibilityCheck = 0x20;
constexpr std::uint8_t kNearFutureShort = 0x40;
constexpr std::uint8_t kDebugPulse = 0x80;
// Cyclic unit control (0x0980): which units the PDI owns instead of ECAT.
constexpr std::uint8_t kCyclicUnitToPdi = 0x01;
constexpr std::uint8_t kLatch0ToPdi = 0x10;
// Event request bits the DC unit drives.
constexpr std::uint8_t kEcatEventDcLatch = 0x01;  // 0x0210 bit 0
constexpr std::uint8_t kAlEventDcLatch = 0x02;    // 0x0220 bit 1
constexpr std::uint8_t kAlEventSync0 = 0x04;      // 0x0220 bit 2 (SYNC1: bit 3)
// A runaway guard: at most this many pulses are generated one by one per advance; beyond that
// (a 1 µs cycle skipped over by an hour) the counters jump ahead without events.
constexpr std::uint64_t kMaxPulsesPerAdvance = 4096;
// Jitter beyond a second is no longer jitter; the bound keeps the arithmetic in range.
constexpr std::int64_t kMaxJitter = 1'000'000'000;
constexpr std::size_t kEdgeHistory = 16384;

bool touches(std::uint16_t first, std::uint16_t last, std::uint16_t start, std::uint16_t size) {
  return first < start + size && last >= start;
}

// Clock period deviation represented by speed counter diff `d` with speed counter start `s`
// (ESC register description, "Speed Counter Diff": deviation = d / (5 (s + d + 2)(s − d + 2))).
double deviation(double d, double s) {
  return d / (5.0 * (s + d + 2.0) * (s - d + 2.0));
}

// The speed counter diff that represents `rate` (the positive root of the quadratic above).
double speed_counter_for(double rate, double s) {
  if (std::fabs(rate) < 1e-15) return 0.0;
  const double a = s + 2.0;
  return (-1.0 + std::sqrt(1.0 + 100.0 * rate * rate * a * a)) / (10.0 * rate);
}

std::int64_t signed_difference(std::uint64_t a, std::uint64_t b) {
  return static_cast<std::int64_t>(a - b);
}

// double -> int64 without undefined behaviour for values a caller could push out of range.
std::int64_t to_int64(double v) {
  constexpr double kLimit = 9.0e18;
  if (!(v > -kLimit)) return static_cast<std::int64_t>(-kLimit);
  if (!(v < kLimit)) return static_cast<std::int64_t>(kLimit);
  return static_cast<std::int64_t>(v);
}

}  // namespace

DcUnit::DcUnit(Esc& esc) : esc_(esc) {}

// ---------------------------------------------------------------------------------------------
// The clock

void DcUnit::set_clock(const DcClockModel& model) {
  model_ = model;
  osc_base_ = model.start_offset_ns;
  osc_base_time_ = 0;
  jitter_state_ = model.jitter_seed;
}

std::uint64_t DcUnit::oscillator_time(std::int64_t t) const noexcept {
  // Unsigned arithmetic: the local time is a free-running counter that wraps.
  const std::int64_t dt = t - osc_base_time_;
  const std::int64_t gained =
      to_int64(std::floor(static_cast<double>(dt) * model_.drift_ppm * 1e-6));
  return static_cast<std::uint64_t>(osc_base_) + static_cast<std::uint64_t>(dt) +
         static_cast<std::uint64_t>(gained);
}

double DcUnit::slewed_at(std::int64_t t) const noexcept {
  if (slew_amount_ == 0.0 || slew_rate_ <= 0.0 || t <= anchor_time_) return 0.0;
  const double done =
      std::min(static_cast<double>(t - anchor_time_) * slew_rate_, std::fabs(slew_amount_));
  return slew_amount_ > 0.0 ? done : -done;
}

double DcUnit::correction_at(std::int64_t t) const noexcept {
  return anchor_correction_ + frequency_rate_ * static_cast<double>(t - anchor_time_) +
         slewed_at(t);
}

std::uint64_t DcUnit::local_time(std::int64_t t) const noexcept {
  return oscillator_time(t) + static_cast<std::uint64_t>(to_int64(std::floor(correction_at(t))));
}

std::uint64_t DcUnit::system_time(std::int64_t t) const noexcept {
  return local_time(t) + esc_.read_u64(reg::kDcSystemTimeOffset);
}

std::int64_t DcUnit::segment_time_at(std::uint64_t target) const noexcept {
  // system_time() is piecewise linear with a slope within a few hundred ppm of 1, so Newton steps
  // land within a nanosecond; the last loops find the first nanosecond that reaches the target.
  std::int64_t t = std::max(advanced_to_, anchor_time_);
  for (int i = 0; i < 8; ++i) {
    const std::int64_t error = signed_difference(system_time(t), target);
    if (error == 0) break;
    const double slope = 1.0 + model_.drift_ppm * 1e-6 + correction_ppm(t) * 1e-6;
    // A target further than ~30 years away is not reachable in a simulation; stay in range.
    constexpr double kStepLimit = 1.0e18;
    std::int64_t step = to_int64(
        std::clamp(std::round(static_cast<double>(error) / slope), -kStepLimit, kStepLimit));
    if (step == 0) step = error > 0 ? 1 : -1;
    if ((step < 0 && t > std::numeric_limits<std::int64_t>::max() + step) ||
        (step > 0 && t < std::numeric_limits<std::int64_t>::min() + step)) {
      break;
    }
    t -= step;
  }
  for (int i = 0; i < 64 && t < std::numeric_limits<std::int64_t>::max() &&
                  signed_difference(system_time(t), target) < 0;
       ++i) {
    ++t;
  }
  for (int i = 0; i < 64 && t > std::numeric_limits<std::int64_t>::min() &&
                  signed_difference(system_time(t - 1), target) >= 0;
       ++i) {
    --t;
  }
  return t;
}

std::int64_t DcUnit::jitter() {
  if (model_.jitter_ns <= 0) return 0;
  // splitmix64: deterministic per seed, so a failing run can be replayed.
  jitter_state_ += 0x9E3779B97F4A7C15ull;
  std::uint64_t z = jitter_state_;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  const std::int64_t peak = std::min(model_.jitter_ns, kMaxJitter);
  const auto span = static_cast<std::uint64_t>(2 * peak + 1);
  return static_cast<std::int64_t>(z % span) - peak;
}

std::int64_t DcUnit::frame_start(const PassContext& pass) const noexcept {
  // The ESC latches times at the start of frame at the port the frame entered by: the earliest
  // port the frame was seen at.
  std::int64_t start = std::numeric_limits<std::int64_t>::max();
  for (std::size_t p = 0; p < pass.port_seen.size(); ++p) {
    if (pass.port_seen[p]) start = std::min(start, pass.port_time_ns[p]);
  }
  return start == std::numeric_limits<std::int64_t>::max() ? pass.epu_time_ns : start;
}

// ---------------------------------------------------------------------------------------------
// The time control loop

std::uint16_t DcUnit::speed_counter_start() const noexcept {
  const auto value = static_cast<std::uint16_t>(esc_.read_u16(reg::kDcSpeedCounterStart) & 0x7FFF);
  return std::clamp(value, kSpeedCounterStartMin, kSpeedCounterStartMax);
}

double DcUnit::max_rate() const noexcept {
  const double s = speed_counter_start();
  return deviation(s - kSpeedCounterDiffMargin, s);
}

void DcUnit::reanchor(std::int64_t t) noexcept {
  if (t < anchor_time_) t = anchor_time_;
  const double slewed = slewed_at(t);
  anchor_correction_ = correction_at(t);
  slew_amount_ -= slewed;
  anchor_time_ = t;
}

void DcUnit::compare_system_time(std::uint32_t received, std::int64_t t) {
  t = std::max(t, anchor_time_);
  advance(t);
  // Δt = (local time + offset − delay) − received, on the lower 32 bits, with the local copy
  // latched at the start of the frame.
  const auto own =
      static_cast<std::uint32_t>(system_time(t) + static_cast<std::uint64_t>(jitter()));
  const std::uint32_t delay = esc_.read_u32(reg::kDcSystemTimeDelay);
  const std::int64_t difference = static_cast<std::int32_t>(own - delay - received);

  // An alpha-beta tracker: the phase estimate is corrected by a fraction of the surprise (filter
  // depth 0x0934), the rate by a smaller one (filter depth 0x0935, scaled by the speed counter
  // start: a larger start is a smaller bandwidth). β is kept below α/2 so every setting is stable.
  const unsigned phase_depth = esc_.read_u8(reg::kDcSystemTimeFilterDepth) & 0x0F;
  const unsigned rate_depth = esc_.read_u8(reg::kDcSpeedCounterFilterDepth) & 0x0F;
  const double alpha = std::ldexp(1.0, -static_cast<int>(phase_depth));
  const double beta = std::min(std::ldexp(1.0, -static_cast<int>(rate_depth)) *
                                   kSpeedCounterStartReset / speed_counter_start(),
                               alpha / 2.0);
  // 0x092C is the mean of the received differences themselves, averaged with the same depth.
  mean_difference_ =
      have_sample_ ? mean_difference_ + alpha * (static_cast<double>(difference) - mean_difference_)
                   : static_cast<double>(difference);
  // What is left of the error seen last time, if the rate correction were exact.
  const double predicted = -(slew_amount_ - slewed_at(t));
  double estimate = static_cast<double>(difference);
  std::int64_t interval = 0;
  if (have_sample_) {
    const double innovation = static_cast<double>(difference) - predicted;
    estimate = predicted + alpha * innovation;
    interval = t - last_sample_time_;
    if (interval >= kMinFrequencyInterval) {
      // Time gained since the last sample beyond what was slewed: the clock runs fast by
      // innovation / interval; slow it down.
      frequency_rate_ -= beta * innovation / static_cast<double>(interval);
    }
  }
  const double limit = max_rate();
  reanchor(t);
  frequency_rate_ = std::clamp(frequency_rate_, -limit, limit);
  // The phase is slewed over the time the last sample took to come (the loop's own period), with
  // at most what the speed counter has left beside the frequency correction: the speed counter
  // diff (0x0932) then moves with the filtered error, as a real ESC's control value does, instead
  // of swinging to its limit for a few nanoseconds of error (and back) at every sample.
  slew_amount_ = -estimate;
  const double room = std::max(limit - std::fabs(frequency_rate_), 0.0);
  slew_rate_ = interval >= kMinFrequencyInterval
                   ? std::min(room, std::fabs(estimate) / static_cast<double>(interval))
                   : room;
  phase_estimate_ = estimate;
  last_difference_ = difference;
  last_sample_time_ = t;
  have_sample_ = true;
  ++samples_;
  wire::store_le32(
      &esc_.memory_[reg::kDcSystemTimeDifference],
      wire::encode_system_time_difference(static_cast<std::int32_t>(
          std::clamp<std::int64_t>(system_time_difference(), -0x7FFFFFFF, 0x7FFFFFFF))));
}

void DcUnit::reset_loop(std::int64_t t) {
  reanchor(t);
  slew_amount_ = 0.0;
  slew_rate_ = 0.0;
  frequency_rate_ = 0.0;
  phase_estimate_ = 0.0;
  mean_difference_ = 0.0;
  have_sample_ = false;
  wire::store_le32(&esc_.memory_[reg::kDcSystemTimeDifference], 0);
  wire::store_le16(&esc_.memory_[reg::kDcSpeedCounterDiff], 0);
}

std::int64_t DcUnit::system_time_difference() const noexcept {
  return static_cast<std::int64_t>(std::llround(mean_difference_));
}

std::int64_t DcUnit::offset() const noexcept {
  return static_cast<std::int64_t>(esc_.read_u64(reg::kDcSystemTimeOffset));
}

double DcUnit::correction_ns(std::int64_t t) const noexcept {
  return correction_at(t);
}

double DcUnit::correction_ppm(std::int64_t t) const noexcept {
  double rate = frequency_rate_;
  if (slew_rate_ > 0.0 && std::fabs(slew_amount_) > std::fabs(slewed_at(t))) {
    rate += slew_amount_ > 0.0 ? slew_rate_ : -slew_rate_;
  }
  return rate * 1e6;
}

std::int16_t DcUnit::speed_counter_diff(std::int64_t t) const noexcept {
  const double s = speed_counter_start();
  const double range = s - kSpeedCounterDiffMargin;
  const double d =
      std::clamp(std::round(speed_counter_for(correction_ppm(t) * 1e-6, s)), -range, range);
  return static_cast<std::int16_t>(d);
}

void DcUnit::jump(std::int64_t ns) {
  const std::int64_t t = std::max(advanced_to_, anchor_time_);
  advance(t);
  reanchor(t);
  anchor_correction_ += static_cast<double>(ns);
}

// ---------------------------------------------------------------------------------------------
// SYNC0 / SYNC1

void DcUnit::activate(std::int64_t now) {
  const std::uint64_t system_now = system_time(now);
  start_time_ = esc_.read_u64(reg::kDcStartTime);
  cycle0_ = esc_.read_u32(reg::kDcSync0CycleTime);
  cycle1_ = esc_.read_u32(reg::kDcSync1CycleTime);
  plausibility_failed_ = false;
  sync_state_ = SyncUnitState::waiting;
  // "Near future" is half the time range (2^63 ns), or about 2.1 s when 0x0981 bit 6 asks so. A
  // start time outside it is generated at once when the plausibility check is on; otherwise the
  // unit waits until the system time reaches it — for a time in the past, never.
  const std::uint64_t window =
      (activation_ & kNearFutureShort) != 0 ? (std::uint64_t{1} << 31) : (std::uint64_t{1} << 63);
  const std::uint64_t ahead = start_time_ - system_now;
  if (ahead >= window) {
    if ((activation_ & kPlausibilityCheck) != 0) {
      start_time_ = system_now;
      plausibility_failed_ = true;
    } else if (static_cast<std::int64_t>(ahead) < 0) {
      sync_state_ = SyncUnitState::stalled;
    }
  }
  next_[0] = start_time_;
  next_[1] = start_time_ + cycle1_;
  scheduled_[0] = scheduled_[1] = true;
  first_pending_[0] = first_pending_[1] = true;
  if (sync_state_ == SyncUnitState::waiting) advance(now);
  update_sync_registers();
}

void DcUnit::deactivate() {
  sync_state_ = SyncUnitState::idle;
  scheduled_[0] = scheduled_[1] = false;
  first_pending_[0] = first_pending_[1] = false;
  update_sync_registers();
}

void DcUnit::emit(SyncSignal signal, std::uint64_t due) {
  const auto s = static_cast<std::size_t>(signal);
  first_pending_[s] = false;
  const std::uint8_t enable = s == 0 ? wire::dc_activation::kSync0 : wire::dc_activation::kSync1;
  if ((activation_ & enable) == 0) return;
  ++pulse_count_[s];
  last_pulse_system_[s] = due;
  pulsed_[s] = true;
  const std::int64_t when = segment_time_at(due);
  edges_[s].push_back(when);
  if (edges_[s].size() > kEdgeHistory) edges_[s].pop_front();
  if (esc_.read_u16(reg::kDcPulseLength) == 0) acknowledge_pending_[s] = true;
  esc_.memory_[reg::kAlEventRequest] |= static_cast<std::uint8_t>(kAlEventSync0 << s);
  if (sync_handler_) sync_handler_(SyncPulse{signal, due, when, pulse_count_[s]});
}

void DcUnit::advance(std::int64_t now_ns) {
  if (now_ns > advanced_to_) advanced_to_ = now_ns;
  if (sync_state_ != SyncUnitState::waiting && sync_state_ != SyncUnitState::running) return;
  const std::uint64_t system_now = system_time(advanced_to_);
  // SYNC1 follows its SYNC0 by the SYNC1 cycle time and then waits for the next SYNC0 after it:
  // its period is the first multiple of the SYNC0 cycle beyond the SYNC1 cycle time.
  const std::uint64_t period0 = cycle0_;
  const std::uint64_t period1 = cycle0_ == 0 ? 0 : (cycle1_ / cycle0_ + 1) * period0;
  const std::uint64_t periods[2] = {period0, period1};
  std::uint64_t generated = 0;
  while (true) {
    int due = -1;
    for (int s = 0; s < 2; ++s) {
      if (!scheduled_[s] || signed_difference(system_now, next_[s]) < 0) continue;
      if (due < 0 || signed_difference(next_[s], next_[due]) < 0) due = s;
    }
    if (due < 0) break;
    if (++generated > kMaxPulsesPerAdvance) {
      for (int s = 0; s < 2; ++s) {
        if (!scheduled_[s] || periods[s] == 0 || signed_difference(system_now, next_[s]) < 0) {
          continue;
        }
        const std::uint64_t skipped = (system_now - next_[s]) / periods[s] + 1;
        const std::uint8_t enable =
            s == 0 ? wire::dc_activation::kSync0 : wire::dc_activation::kSync1;
        if ((activation_ & enable) != 0) pulse_count_[s] += skipped;
        next_[s] += skipped * periods[s];
      }
      break;
    }
    emit(static_cast<SyncSignal>(due), next_[due]);
    if (periods[due] == 0) {
      scheduled_[due] = false;
    } else {
      next_[due] += periods[due];
    }
    sync_state_ = SyncUnitState::running;
  }
  if (!scheduled_[0] && !scheduled_[1]) sync_state_ = SyncUnitState::finished;
}

bool DcUnit::sync_level(SyncSignal signal, std::int64_t t) const noexcept {
  const auto s = static_cast<std::size_t>(signal);
  if (!pulsed_[s]) return false;
  const std::uint64_t length = std::uint64_t{esc_.read_u16(reg::kDcPulseLength)} * 10;
  if (length == 0) return acknowledge_pending_[s];
  const std::int64_t since = signed_difference(system_time(t), last_pulse_system_[s]);
  return since >= 0 && static_cast<std::uint64_t>(since) < length;
}

std::uint8_t DcUnit::pdi_read_sync_status(SyncSignal signal) {
  const auto s = static_cast<std::size_t>(signal);
  const bool level = sync_level(signal, advanced_to_);
  acknowledge_pending_[s] = false;
  esc_.memory_[reg::kAlEventRequest] &= static_cast<std::uint8_t>(~(kAlEventSync0 << s));
  esc_.memory_[reg::kDcSync0Status + s] = 0;
  return level ? 1 : 0;
}

void DcUnit::update_sync_registers() {
  auto& mem = esc_.memory_;
  const bool waiting =
      sync_state_ == SyncUnitState::waiting || sync_state_ == SyncUnitState::stalled;
  // A first pulse is pending only for the outputs that are enabled.
  std::uint8_t status = 0;
  if (waiting && first_pending_[0] && (activation_ & wire::dc_activation::kSync0) != 0) {
    status |= 0x01;
  }
  if (waiting && first_pending_[1] && (activation_ & wire::dc_activation::kSync1) != 0) {
    status |= 0x02;
  }
  if (plausibility_failed_) status |= 0x04;
  mem[reg::kDcActivationStatus] = status;
  for (std::size_t s = 0; s < 2; ++s) {
    mem[reg::kDcSync0Status + s] = sync_level(static_cast<SyncSignal>(s), advanced_to_) ? 1 : 0;
  }
  if (sync_state_ != SyncUnitState::idle) {
    wire::store_le64(&mem[reg::kDcStartTime], next_[0]);
    wire::store_le64(&mem[reg::kDcNextSync1], next_[1]);
  }
}

std::vector<std::int64_t> DcUnit::sync0_edges_between(std::int64_t t0, std::int64_t t1) const {
  std::vector<std::int64_t> out;
  for (const std::int64_t t : edges_[0]) {
    if (t >= t0 && t < t1) out.push_back(t);
  }
  return out;
}

std::vector<std::int64_t> DcUnit::sync1_edges_between(std::int64_t t0, std::int64_t t1) const {
  std::vector<std::int64_t> out;
  for (const std::int64_t t : edges_[1]) {
    if (t >= t0 && t < t1) out.push_back(t);
  }
  return out;
}

void DcUnit::start_time_written(std::uint16_t first, std::uint16_t last) {
  // A start time written as 32 bits is widened to the 64-bit value in the near future when 0x0981
  // bit 4 asks so; otherwise the upper half keeps whatever the register held.
  const bool low_half = touches(first, last, reg::kDcStartTime, 4);
  const bool high_half = touches(first, last, reg::kDcStartTime + 4, 4);
  if (low_half && !high_half && (activation_ & kStartTimeExtension) != 0) {
    const std::uint64_t now = system_time(current_frame_start_);
    std::uint64_t start = (now & 0xFFFFFFFF00000000ull) | esc_.read_u32(reg::kDcStartTime);
    if (signed_difference(start, now) < 0) start += std::uint64_t{1} << 32;
    wire::store_le64(&esc_.memory_[reg::kDcStartTime], start);
  }
}

// ---------------------------------------------------------------------------------------------
// Latch units

void DcUnit::latch_input(unsigned unit, bool rising, std::int64_t t) {
  if (unit > 1) return;
  auto& mem = esc_.memory_;
  const auto status_reg = static_cast<std::uint16_t>(reg::kDcLatch0Status + unit);
  const std::uint8_t control = mem[reg::kDcLatch0Control + unit];
  const std::uint8_t event =
      rising ? wire::dc_latch::kStatusPositiveEvent : wire::dc_latch::kStatusNegativeEvent;
  const bool single = (control & (rising ? wire::dc_latch::kControlPositiveSingle
                                         : wire::dc_latch::kControlNegativeSingle)) != 0;
  if (rising) {
    mem[status_reg] |= wire::dc_latch::kStatusPinState;
  } else {
    mem[status_reg] &= static_cast<std::uint8_t>(~wire::dc_latch::kStatusPinState);
  }
  // Single event: only the first edge until its timestamp is read. Continuous: every edge, and
  // the status register does not reflect events.
  if (!single || (mem[status_reg] & event) == 0) {
    const std::uint64_t stamp = system_time(t) + static_cast<std::uint64_t>(jitter());
    const auto time_reg =
        static_cast<std::uint16_t>(reg::kDcLatch0PositiveEdge + 16 * unit + (rising ? 0 : 8));
    wire::store_le64(&mem[time_reg], stamp);
    if (single) mem[status_reg] |= event;
    ++latch_counts_[unit][rising ? 0 : 1];
  }
  update_event_registers();
}

std::uint64_t DcUnit::latch_events(unsigned unit, bool rising) const noexcept {
  return unit > 1 ? 0 : latch_counts_[unit][rising ? 0 : 1];
}

std::uint64_t DcUnit::pdi_read_latch_time(unsigned unit, bool rising) {
  if (unit > 1) return 0;
  const auto time_reg =
      static_cast<std::uint16_t>(reg::kDcLatch0PositiveEdge + 16 * unit + (rising ? 0 : 8));
  const std::uint64_t value = esc_.read_u64(time_reg);
  if ((esc_.memory_[reg::kDcCyclicUnitControl] & (kLatch0ToPdi << unit)) != 0) {
    esc_.memory_[reg::kDcLatch0Status + unit] &= static_cast<std::uint8_t>(
        ~(rising ? wire::dc_latch::kStatusPositiveEvent : wire::dc_latch::kStatusNegativeEvent));
    update_event_registers();
  }
  return value;
}

void DcUnit::update_event_registers() {
  auto& mem = esc_.memory_;
  bool ecat_event = false;
  bool pdi_event = false;
  for (unsigned unit = 0; unit < 2; ++unit) {
    const bool event = (mem[reg::kDcLatch0Status + unit] & 0x03) != 0;
    const bool to_pdi = (mem[reg::kDcCyclicUnitControl] & (kLatch0ToPdi << unit)) != 0;
    (to_pdi ? pdi_event : ecat_event) |= event;
  }
  mem[reg::kEcatEventRequest] = static_cast<std::uint8_t>(
      (mem[reg::kEcatEventRequest] & ~kEcatEventDcLatch) | (ecat_event ? kEcatEventDcLatch : 0));
  mem[reg::kAlEventRequest] = static_cast<std::uint8_t>(
      (mem[reg::kAlEventRequest] & ~kAlEventDcLatch) | (pdi_event ? kAlEventDcLatch : 0));
}

// ---------------------------------------------------------------------------------------------
// Esc integration

void DcUnit::on_datagram(const PassContext& pass) {
  current_frame_start_ = frame_start(pass);
  advance(current_frame_start_);
}

void DcUnit::on_write(std::uint16_t first, std::uint16_t last, const PassContext& pass) {
  auto& mem = esc_.memory_;
  const std::int64_t start = frame_start(pass);
  if (touches(first, last, reg::kDcReceiveTimePort0, 4)) {
    // A write to 0x0900 latches, per port, the local time at which this frame began arriving
    // there (ports the frame did not pass keep their old value), and the 64-bit receive time of
    // the processing unit: the time at the port the frame entered by.
    for (std::size_t port = 0; port < 4; ++port) {
      if (!pass.port_seen[port]) continue;
      const std::uint64_t at =
          local_time(pass.port_time_ns[port]) + static_cast<std::uint64_t>(jitter());
      wire::store_le32(&mem[reg::dc_receive_time(port)], static_cast<std::uint32_t>(at));
      if (pass.port_time_ns[port] == start) wire::store_le64(&mem[reg::kDcReceiveTimeEpu], at);
    }
    if (!pass.port_seen[0] && !pass.port_seen[1] && !pass.port_seen[2] && !pass.port_seen[3]) {
      wire::store_le64(&mem[reg::kDcReceiveTimeEpu], local_time(start));
    }
  }
  // The loop compares only when the write included the first byte of the system time; the upper
  // half of a 64-bit write is not used.
  if (first <= reg::kDcSystemTime && last >= reg::kDcSystemTime) {
    compare_system_time(esc_.read_u32(reg::kDcSystemTime), start);
  }
  if (touches(first, last, reg::kDcSpeedCounterStart, 2)) reset_loop(start);

  bool activate_now = false;
  if (touches(first, last, reg::kDcActivation, 1)) {
    if ((mem[reg::kDcCyclicUnitControl] & kCyclicUnitToPdi) != 0) {
      mem[reg::kDcActivation] = activation_;  // the PDI owns the cyclic unit
    } else {
      const std::uint8_t written = mem[reg::kDcActivation];
      const std::uint8_t old = activation_;
      activation_ = static_cast<std::uint8_t>(written & ~kDebugPulse);
      mem[reg::kDcActivation] = activation_;  // the debug bit clears itself
      if ((written & kDebugPulse) != 0) {
        const std::uint64_t now = system_time(start);
        if ((written & wire::dc_activation::kSync0) != 0) emit(SyncSignal::sync0, now);
        if ((written & wire::dc_activation::kSync1) != 0) emit(SyncSignal::sync1, now);
      }
      const bool was_on = (old & wire::dc_activation::kCyclicOperation) != 0;
      const bool is_on = (activation_ & wire::dc_activation::kCyclicOperation) != 0;
      if (!was_on && is_on) activate_now = true;
      if (was_on && !is_on) deactivate();
    }
  }
  if (touches(first, last, reg::kDcStartTime, 8) &&
      (mem[reg::kDcCyclicUnitControl] & kCyclicUnitToPdi) == 0) {
    start_time_written(first, last);
    if ((activation_ & kAutoActivation) != 0) {
      activation_ |= wire::dc_activation::kCyclicOperation;
      mem[reg::kDcActivation] = activation_;
      activate_now = true;
    }
  }
  if (activate_now) activate(start);
}

void DcUnit::refresh(std::uint16_t first, std::uint16_t last, std::int64_t now_ns) {
  advance(now_ns);
  auto& mem = esc_.memory_;
  if (touches(first, last, reg::kDcSystemTime, 8)) {
    // An ECAT read returns the system time at the start of the frame minus the delay: the
    // reference's time when the frame passed it.
    const std::uint64_t value = system_time(current_frame_start_) -
                                esc_.read_u32(reg::kDcSystemTimeDelay) +
                                static_cast<std::uint64_t>(jitter());
    wire::store_le64(&mem[reg::kDcSystemTime], value);
  }
  if (touches(first, last, reg::kDcSpeedCounterDiff, 2)) {
    wire::store_le16(&mem[reg::kDcSpeedCounterDiff],
                     static_cast<std::uint16_t>(speed_counter_diff(now_ns)));
  }
  if (touches(first, last, reg::kDcActivationStatus, 0x20)) update_sync_registers();
}

void DcUnit::after_read(std::uint16_t first, std::uint16_t last) {
  // Reading a latch timestamp from ECAT (its first byte, which latches the rest) acknowledges the
  // event, when ECAT owns the latch unit.
  bool changed = false;
  for (unsigned unit = 0; unit < 2; ++unit) {
    if ((esc_.memory_[reg::kDcCyclicUnitControl] & (kLatch0ToPdi << unit)) != 0) continue;
    for (unsigned edge = 0; edge < 2; ++edge) {
      const auto time_reg =
          static_cast<std::uint16_t>(reg::kDcLatch0PositiveEdge + 16 * unit + 8 * edge);
      if (first <= time_reg && last >= time_reg) {
        esc_.memory_[reg::kDcLatch0Status + unit] &= static_cast<std::uint8_t>(~(1u << edge));
        changed = true;
      }
    }
  }
  if (changed) update_event_registers();
}

void DcUnit::reset() {
  const std::int64_t now = esc_.now_ns();
  // The oscillator counter restarts at 0 at power-up.
  osc_base_ = 0;
  osc_base_time_ = now;
  jitter_state_ = model_.jitter_seed;
  anchor_time_ = now;
  anchor_correction_ = 0.0;
  frequency_rate_ = 0.0;
  slew_amount_ = 0.0;
  slew_rate_ = 0.0;
  phase_estimate_ = 0.0;
  mean_difference_ = 0.0;
  last_difference_ = 0;
  last_sample_time_ = now;
  have_sample_ = false;
  samples_ = 0;
  current_frame_start_ = now;
  advanced_to_ = now;
  sync_state_ = SyncUnitState::idle;
  activation_ = 0;
  start_time_ = 0;
  cycle0_ = cycle1_ = 0;
  for (std::size_t s = 0; s < 2; ++s) {
    next_[s] = 0;
    scheduled_[s] = false;
    first_pending_[s] = false;
    pulse_count_[s] = 0;
    last_pulse_system_[s] = 0;
    pulsed_[s] = false;
    acknowledge_pending_[s] = false;
    edges_[s].clear();
  }
  plausibility_failed_ = false;
  for (auto& unit : latch_counts_)
    unit[0] = unit[1] = 0;
  auto& mem = esc_.memory_;
  wire::store_le16(&mem[reg::kDcSpeedCounterStart], kSpeedCounterStartReset);
  mem[reg::kDcSystemTimeFilterDepth] = kTimeDifferenceFilterDepthReset;
  mem[reg::kDcSpeedCounterFilterDepth] = kSpeedCounterFilterDepthReset;
}

}  // namespace ecat::sim
