// The Cycler: the one cycle function of a bus, shared by every cyclic participant on it.
//
// A bus has exactly one cycle function (Bus::set_cycle). The Cycler owns it and runs several
// participants with different periods from it: process-data domains (ecat::master::Domain), the
// DC drift compensation (an FRMW every cycle), anything else that must send realtime work at
// absolute deadlines.
//
// Scheduling
//  * The bus ticks at the base period: the greatest common divisor of all participants' periods.
//    Ticks fall on multiples of the base period on the steady clock, and a participant is due on
//    multiples of its own period, so participants whose periods divide each other run in the same
//    tick (a 1 ms and a 2 ms domain: both at every even millisecond, in phase).
//  * In a tick, the due participants run in priority order (higher first), participants of equal
//    priority in the order they were added. Give DC maintenance kPriorityDc so its FRMW leaves in
//    front of the domains' LRWs.
//  * When the bus thread ran late and the bus skipped deadlines, a participant runs once for the
//    latest deadline (CycleTick::missed says how many were skipped), never several times in a row.
//  * A base period below kMinBasePeriod is refused (1 ms and 333 us would need a 1 us tick).
//
// Changes at runtime (add, remove, a participant's new period) are built on the calling thread and
// installed with Bus::set_cycle, whose guarantee carries over: when add()/remove()/refresh()
// return, the previous schedule is no longer running, so a removed participant is never called
// again and may be destroyed. These calls must not be made from the bus thread (a participant's
// on_tick or a completion): they are refused there with Errc::wrong_state.
//
// Threading: add/remove/refresh/start/stop from any thread but the bus thread, serialized by an
// internal mutex that the bus thread never takes. stats() from any thread.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include <ecat/result.hpp>

namespace ecat::bus {
class Bus;
struct CycleTick;
}  // namespace ecat::bus

namespace ecat::master {

class Cycler;

// Something that runs on the bus thread at its own period. on_tick() must be cheap and must not
// block, allocate or throw: it submits realtime work (Bus::submit_realtime) and returns.
class CyclicParticipant {
 public:
  CyclicParticipant() = default;
  virtual ~CyclicParticipant();
  CyclicParticipant(const CyclicParticipant&) = delete;
  CyclicParticipant& operator=(const CyclicParticipant&) = delete;

  // Called on the bus thread when the participant is due.
  virtual void on_tick(const bus::CycleTick& tick) = 0;
  // The participant's period (positive). Read by the Cycler when it (re)builds its schedule.
  virtual std::chrono::nanoseconds cycle_period() const noexcept = 0;

  // The Cycler this participant is added to, or nullptr.
  Cycler* cycler() const noexcept { return cycler_.load(std::memory_order_acquire); }

 protected:
  // Tells the Cycler (if any) that cycle_period() changed; takes effect between two ticks.
  // Fails like Cycler::refresh() (base period too small, called on the bus thread).
  Result<void> notify_period_changed();
  // Derived classes call this first in their destructor (before their members go away), so the
  // bus thread no longer calls on_tick. The base destructor does it too, as a last resort.
  void detach_from_cycler() noexcept;

 private:
  friend class Cycler;
  std::atomic<Cycler*> cycler_{nullptr};
};

struct CyclerStats {
  std::uint64_t ticks = 0;              // cycle function calls
  std::uint64_t participant_runs = 0;   // on_tick calls, all participants
  std::uint64_t deadlines_skipped = 0;  // sum of CycleTick::missed
  std::uint64_t overlong_ticks = 0;     // ticks whose participants took longer than the base period
  std::chrono::nanoseconds last_tick_duration{0};  // time spent in the participants' on_tick
  std::chrono::nanoseconds max_tick_duration{0};
  std::chrono::nanoseconds total_tick_duration{0};  // mean = total / ticks
  std::chrono::nanoseconds base_period{0};          // 0 while there is no participant
  std::size_t participants = 0;
  bool running = false;
};

class Cycler {
 public:
  static constexpr int kPriorityDefault = 0;
  static constexpr int kPriorityDc = 100;
  static constexpr std::chrono::nanoseconds kMinBasePeriod = std::chrono::microseconds(10);

  explicit Cycler(bus::Bus& bus);
  // Stops (clears the bus cycle) and detaches every participant.
  ~Cycler();
  Cycler(const Cycler&) = delete;
  Cycler& operator=(const Cycler&) = delete;

  // Adds a participant (not already in a Cycler). When running, it is due from the next multiple
  // of its period on. Errc::invalid_argument for a non-positive period or a participant already
  // added, Errc::out_of_range when the base period would drop below kMinBasePeriod.
  Result<void> add(CyclicParticipant& participant, int priority = kPriorityDefault);
  // Removes it; when this returns, its on_tick is not running and will not be called again.
  // Errc::not_found when it is not in this Cycler.
  Result<void> remove(CyclicParticipant& participant);
  // Re-reads every participant's cycle_period() and reschedules (participants call it through
  // notify_period_changed()). On error the previous schedule stays.
  Result<void> refresh();

  // Installs the cycle function on the bus (ticks start at the next multiple of the base period).
  // With no participant yet, the bus cycle is installed by the first add().
  Result<void> start();
  // Clears the bus cycle; participants stay added. Idempotent. Refused on the bus thread.
  Result<void> stop();
  bool running() const noexcept { return running_.load(std::memory_order_acquire); }

  std::chrono::nanoseconds base_period() const noexcept {
    return std::chrono::nanoseconds(base_period_ns_.load(std::memory_order_acquire));
  }
  CyclerStats stats() const noexcept;
  bus::Bus& bus() const noexcept { return bus_; }

 private:
  struct Entry;
  struct Schedule;

  Result<void> install_locked(std::unique_ptr<Schedule> next);
  Result<std::unique_ptr<Schedule>> build_locked(std::chrono::nanoseconds* base) const;
  void run(Schedule& schedule, const bus::CycleTick& tick) noexcept;

  bus::Bus& bus_;
  mutable std::mutex mutex_;  // control side only; the bus thread never takes it
  std::vector<std::unique_ptr<Entry>> entries_;
  std::unique_ptr<Schedule> schedule_;  // the one the bus runs (or would run)
  std::uint64_t next_sequence_ = 0;
  std::atomic<bool> running_{false};
  std::atomic<std::int64_t> base_period_ns_{0};
  std::atomic<std::size_t> participant_count_{0};

  std::atomic<std::uint64_t> ticks_{0};
  std::atomic<std::uint64_t> runs_{0};
  std::atomic<std::uint64_t> skipped_{0};
  std::atomic<std::uint64_t> overlong_{0};
  std::atomic<std::int64_t> last_tick_ns_{0};
  std::atomic<std::int64_t> max_tick_ns_{0};
  std::atomic<std::int64_t> total_tick_ns_{0};
};

}  // namespace ecat::master
