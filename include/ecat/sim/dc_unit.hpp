// The distributed-clock unit of one emulated ESC: a free-running local clock with its own drift
// and start offset, receive-time latching, the system time with its offset and delay registers,
// the time control loop fed by writes of the reference time, the SYNC0/SYNC1 generator and the
// two latch units. docs/SIMULATOR-DC.md describes what is modelled and where the constants come
// from.
//
// Time here is "segment time": the simulator's true time in nanoseconds. The ESC's oscillator
// runs at (1 + drift_ppm / 1e6) times segment time. Its local time is the oscillator plus what the
// control loop has corrected so far (the loop speeds the local clock up or slows it down, as the
// ESC's speed counter does); the system time is the local time plus the offset register.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <vector>

#include <ecat/sim/esc.hpp>

namespace ecat::sim {

struct DcClockModel {
  double drift_ppm = 0.0;            // oscillator error against segment time
  std::int64_t start_offset_ns = 0;  // local time at segment time 0
  // Peak timestamp jitter: every latched local time (receive times, the system time a frame
  // samples, latch-input timestamps) is off by a uniform amount in [-jitter_ns, +jitter_ns].
  // 0 (the default) is jitter-free.
  std::int64_t jitter_ns = 0;
  std::uint64_t jitter_seed = 1;
};

enum class SyncSignal : std::uint8_t { sync0 = 0, sync1 = 1 };

// One pulse of the SYNC generator.
struct SyncPulse {
  SyncSignal signal = SyncSignal::sync0;
  std::uint64_t system_time = 0;     // when it was due, in this ESC's system time
  std::int64_t segment_time_ns = 0;  // when it happened
  std::uint64_t count = 0;           // pulses of this signal since power-up, this one included
};

// Where the cyclic (SYNC) unit stands.
enum class SyncUnitState : std::uint8_t {
  idle,      // not activated (0x0981 bit 0 clear)
  waiting,   // activated, the start time lies ahead
  running,   // pulses are being generated
  stalled,   // activated with a start time in the past: waits for the time to wrap (never)
  finished,  // single shot done; re-arm by deactivating and activating again
};

class DcUnit {
 public:
  explicit DcUnit(Esc& esc);

  // ---- The clock -------------------------------------------------------------------------------
  // Sets the oscillator: local time = start_offset_ns + t * (1 + drift_ppm / 1e6) (plus the loop's
  // correction). Meant for set-up before the segment runs; a power cycle restarts the local time
  // at 0.
  void set_clock(const DcClockModel& model);
  const DcClockModel& clock() const noexcept { return model_; }

  // The free-running local time at segment time `t` (no loop correction).
  std::uint64_t oscillator_time(std::int64_t t) const noexcept;
  // The local time (oscillator + control-loop correction) at segment time `t`.
  std::uint64_t local_time(std::int64_t t) const noexcept;
  // The system time (local time + offset 0x0920) at segment time `t`, as the PDI reads it.
  std::uint64_t system_time(std::int64_t t) const noexcept;
  // The segment time at which the system time reaches `system_time` (valid from the last loop
  // update on; earlier times are extrapolated).
  std::int64_t segment_time_at(std::uint64_t system_time) const noexcept;

  // ---- Observation ---------------------------------------------------------------------------
  // The filtered difference (own system time − received reference time) in ns, as in 0x092C.
  std::int64_t system_time_difference() const noexcept;
  // The raw difference of the last received system time.
  std::int64_t last_difference() const noexcept { return last_difference_; }
  // How many system-time writes fed the loop since power-up.
  std::uint64_t difference_samples() const noexcept { return samples_; }
  // The offset register 0x0920.
  std::int64_t offset() const noexcept;
  // Total correction the loop has applied to the local clock so far, in ns (jumps included).
  double correction_ns(std::int64_t t) const noexcept;
  // The loop's current rate correction (frequency part plus phase slew) in ppm; positive means the
  // local clock is sped up.
  double correction_ppm(std::int64_t t) const noexcept;
  // The frequency part alone: the loop's estimate of the drift against the reference, in ppm.
  double frequency_correction_ppm() const noexcept { return frequency_rate_ * 1e6; }
  // The speed counter diff (0x0932) that represents the correction rate at `t`.
  std::int16_t speed_counter_diff(std::int64_t t) const noexcept;

  // ---- Faults --------------------------------------------------------------------------------
  // Steps the local clock by `ns` (a glitch of the oscillator counter). The loop sees it as a
  // difference and slews it away at the rate a speed counter allows.
  void jump(std::int64_t ns);

  // ---- SYNC0 / SYNC1 ---------------------------------------------------------------------------
  SyncUnitState sync_state() const noexcept { return sync_state_; }
  std::uint64_t sync0_count() const noexcept { return pulse_count_[0]; }
  std::uint64_t sync1_count() const noexcept { return pulse_count_[1]; }
  // Segment times of the pulses generated in [t0, t1). Only pulses up to the time the unit has
  // been advanced to (Segment::advance / a frame) exist; the most recent 16384 per signal are kept.
  std::vector<std::int64_t> sync0_edges_between(std::int64_t t0, std::int64_t t1) const;
  std::vector<std::int64_t> sync1_edges_between(std::int64_t t0, std::int64_t t1) const;
  // Called for every pulse as it is generated (the firmware's SYNC interrupt). Survives power
  // cycles; an Application typically installs it in start().
  void set_sync_handler(std::function<void(const SyncPulse&)> handler) {
    sync_handler_ = std::move(handler);
  }
  // The level of the SYNC output at segment time `t` (pulse length, or acknowledge mode).
  bool sync_level(SyncSignal signal, std::int64_t t) const noexcept;
  // The PDI reads the SYNC0/SYNC1 status register (0x098E/0x098F); in acknowledge mode (pulse
  // length 0) this read clears the signal.
  std::uint8_t pdi_read_sync_status(SyncSignal signal);

  // ---- Latch inputs --------------------------------------------------------------------------
  // An edge on LATCH0 (unit 0) or LATCH1 (unit 1) at segment time `t`: timestamped in system time
  // per the latch control register (single event: only the first edge until acknowledged;
  // continuous: every edge). Units other than 0 and 1 are ignored.
  void latch_input(unsigned unit, bool rising, std::int64_t t);
  // Edges recorded into the timestamp registers so far (per unit and edge).
  std::uint64_t latch_events(unsigned unit, bool rising) const noexcept;
  // The PDI reads a latch timestamp; acknowledges the event when the latch unit is assigned to the
  // PDI (0x0980 bit 4/5).
  std::uint64_t pdi_read_latch_time(unsigned unit, bool rising);

  // ---- Esc integration (Esc is the only caller) ------------------------------------------------
  // A datagram starts at this ESC (before any of its reads or writes).
  void on_datagram(const PassContext& pass);
  // Register writes in [first, last] (inclusive, within 0x0900..0x09FF) by `pass`.
  void on_write(std::uint16_t first, std::uint16_t last, const PassContext& pass);
  // Before an ECAT read of [first, last]: brings the registers up to date.
  void refresh(std::uint16_t first, std::uint16_t last, std::int64_t now_ns);
  // After an ECAT read of [first, last]: read side effects (latch event acknowledge).
  void after_read(std::uint16_t first, std::uint16_t last);
  // Generates the SYNC pulses due up to `now_ns`.
  void advance(std::int64_t now_ns);
  // Power-up state (registers already zeroed by the Esc).
  void reset();

 private:
  // ---- control loop ----
  double correction_at(std::int64_t t) const noexcept;
  double slewed_at(std::int64_t t) const noexcept;  // phase slew done since the anchor
  void reanchor(std::int64_t t) noexcept;
  void compare_system_time(std::uint32_t received, std::int64_t t);
  void reset_loop(std::int64_t t);
  std::uint16_t speed_counter_start() const noexcept;
  double max_rate() const noexcept;
  std::int64_t jitter();
  std::int64_t frame_start(const PassContext& pass) const noexcept;

  // ---- SYNC unit ----
  void start_time_written(std::uint16_t first, std::uint16_t last);
  void activate(std::int64_t now);
  void deactivate();
  void emit(SyncSignal signal, std::uint64_t due);
  void update_sync_registers();

  // ---- latch / events ----
  void update_event_registers();

  Esc& esc_;
  DcClockModel model_;
  std::uint64_t jitter_state_ = 1;

  // Oscillator: local time = osc_base_ + (t - osc_base_time_) * (1 + drift).
  std::int64_t osc_base_ = 0;
  std::int64_t osc_base_time_ = 0;

  // Loop correction, piecewise: from anchor_time_ on, the correction grows at frequency_rate_
  // plus a phase slew of slew_rate_ (magnitude) until slew_amount_ (signed) is used up.
  std::int64_t anchor_time_ = 0;
  double anchor_correction_ = 0.0;
  double frequency_rate_ = 0.0;
  double slew_amount_ = 0.0;
  double slew_rate_ = 0.0;
  double phase_estimate_ = 0.0;   // the tracker's estimate of the error at the last sample
  double mean_difference_ = 0.0;  // mean of the received differences (0x092C)
  std::int64_t last_difference_ = 0;
  std::int64_t last_sample_time_ = 0;
  bool have_sample_ = false;
  std::uint64_t samples_ = 0;

  // The datagram being processed: its start-of-frame time at this ESC.
  std::int64_t current_frame_start_ = 0;
  std::int64_t advanced_to_ = 0;

  // SYNC unit.
  SyncUnitState sync_state_ = SyncUnitState::idle;
  std::uint8_t activation_ = 0;  // 0x0981 as last accepted
  std::uint64_t start_time_ = 0;
  std::uint32_t cycle0_ = 0;
  std::uint32_t cycle1_ = 0;
  std::uint64_t next_[2]{};
  bool scheduled_[2]{};
  bool first_pending_[2]{};
  bool plausibility_failed_ = false;
  std::uint64_t pulse_count_[2]{};
  std::uint64_t last_pulse_system_[2]{};
  bool pulsed_[2]{};
  bool acknowledge_pending_[2]{};
  std::deque<std::int64_t> edges_[2];
  std::function<void(const SyncPulse&)> sync_handler_;

  // Latch units.
  std::uint64_t latch_counts_[2][2]{};
};

}  // namespace ecat::sim
