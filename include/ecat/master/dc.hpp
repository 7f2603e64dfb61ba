// Distributed clocks on the master side: topology and delay planning from latched receive times,
// the initialisation sequence (offsets, delays, filters, static drift compensation), the runtime
// maintenance participant (reference time distribution, difference monitoring, lock state, phase
// of the cycle against the reference clock's SYNC0 grid), SYNC0/SYNC1 and latch configuration.
//
// Time base: system time is nanoseconds since 2000-01-01 00:00 (the EtherCAT epoch). The first
// DC-capable slave in frame order is the reference clock; the master never disciplines it, it
// only distributes its time to the others (FRMW of 0x0910) and measures its own phase against it.
//
// Sequence a master runs (see also the functions' comments):
//   1. stations assigned, slaves in INIT or PREOP;
//   2. co_await initialize_dc(loop, bus, stations_in_ring_order, options)  -> DcInitResult;
//   3. DcMaintainer m(bus, result, runtime_options); cycler.add(m, Cycler::kPriorityDc);
//   4. per slave with a SyncConfig, on the way to SAFEOP: co_await configure_sync(...);
//   5. poll m.status() / m.take_lock_lost(), and poll_latches() for slaves with latches.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/bus/realtime.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::config {
// An ESI device description (<ecat/config/esi.hpp>): only pointed to here, so that the master's
// public headers do not carry the ESI reader.
struct EsiDevice;
}  // namespace ecat::config

namespace ecat::master {

// Nanoseconds from 1970-01-01 (Unix epoch) to 2000-01-01 (EtherCAT system time epoch).
constexpr std::int64_t kDcEpochOffsetNs = 946'684'800'000'000'000;

// The master's notion of system time: CLOCK_REALTIME converted to the EtherCAT epoch.
std::int64_t dc_master_time_now() noexcept;

// ---------------------------------------------------------------------------------------------
// Pure planning (no I/O)

// What the master read from one slave after the receive-time latch (BWR 0x0900).
struct DcSlaveSnapshot {
  std::uint16_t station = 0;
  bool dc_supported = false;                 // ESC features 0x0008 bit 2
  bool receive_times_valid = true;           // the 0x0900 read was answered
  std::array<std::uint32_t, 4> port_time{};  // 0x0900 + 4 * port
  std::uint64_t epu_time = 0;                // 0x0918: 64-bit receive time of the frame
  std::uint16_t dl_status = 0;               // 0x0110 raw
  std::uint16_t speed_counter_start = 0;     // 0x0930 as read (0 = not present)
};

// How long an ESC holds a frame internally. Only the parts a master cannot measure matter:
// the time from port 0 to the first downstream port (through the processing unit) and from a
// returning port to the next port. They are assumptions; the defaults are those of the ESC model
// in the simulator (include/ecat/sim/segment.hpp HopTiming), in the range of real EBUS ESCs. An
// error e in them shifts a delay by at most e/2 per hop where it applies.
struct DcTimingModel {
  std::int64_t processing_delay_ns = 100;  // port 0 in -> processing unit -> next port out
  std::int64_t forwarding_delay_ns = 50;   // a returning frame: port in -> next port out
};

struct DcPlanOptions {
  DcTimingModel timing{};
  // A redundant ring (cable redundancy): the last slave in frame order has one port open with no
  // slave behind it, the cable back to the master's second port. Without it that is an error.
  bool ring_returns_to_master = false;
};

// The cabling of a segment as its slaves' DL status (0x0110) shows it: which slave hangs on which
// port of which earlier one. Frame (ring) order is depth first, ports 0 -> 3 -> 1 -> 2, so slave
// k hangs on the next unused downstream port of the deepest earlier slave that still has one.
// DC planning (plan_dc) and the redundant ring's break report (locate_ring_break) share it.
struct RingTree {
  struct Node {
    std::optional<std::size_t> parent;  // ring position of the slave whose port this one hangs on
    std::uint8_t parent_port = 0;       // 1, 2 or 3 (0 for the first slave: the master)
    std::array<std::optional<std::size_t>, 4> children{};  // by port; [0] unused
  };
  std::vector<Node> slaves;  // ring order
  // ring_returns_to_master: the last slave's port cabled back to the master's second port.
  std::optional<std::uint8_t> return_port;
};

// The tree over the slaves' open ports (DL status: communication up and loop open; `dl_status`
// raw, one per slave in ring order; `stations` name them in errors). Errors (Errc::malformed)
// name the slave (position and station): more slaves than open ports, an open port with nothing
// behind it (the last slave's first free one allowed with `ring_returns_to_master`).
Result<RingTree> ring_tree(std::span<const std::uint16_t> dl_status,
                           std::span<const std::uint16_t> stations, bool ring_returns_to_master);

struct DcPlannedSlave {
  std::size_t position = 0;  // ring (frame) order
  std::uint16_t station = 0;
  bool dc = false;                    // takes part (DC supported and receive times present)
  std::optional<std::size_t> parent;  // position of the slave whose port this one hangs on
  std::uint8_t parent_port = 0;       // 1, 2 or 3 (0 for the first slave: the master)
  std::array<bool, 4> open_ports{};   // from DL status: communication and loop open
  // When the frame reaches it, relative to the first slave (fractional: halves accumulate).
  double arrival_ns = 0.0;
  std::uint32_t delay_ns = 0;  // to the reference clock (0x0928), DC slaves only
  std::int64_t offset_ns = 0;  // system time offset (0x0920), DC slaves only
};

struct DcPlan {
  std::size_t reference_position = 0;
  std::uint16_t reference_station = 0;
  std::vector<DcPlannedSlave> slaves;  // ring order
  std::vector<std::size_t> dc_positions() const;
};

// The topology (which slave hangs on which port of which parent; frame order is depth first,
// ports 0 -> 3 -> 1 -> 2), each DC slave's propagation delay from the reference clock and the
// offsets that make every system time equal `master_time_ns` (ns since 2000) at the latch. The
// snapshots are in ring order. Errors name the slave (position and station) and the mismatch:
// more slaves than open ports, an open port with nothing behind it, non-monotonic receive
// times, a slave without receive times that others hang on, no DC-capable slave (Errc::not_found).
Result<DcPlan> plan_dc(std::span<const DcSlaveSnapshot> slaves, std::int64_t master_time_ns,
                       const DcPlanOptions& options = {});

// 0x092C: bit 31 set = own time smaller than the reference (negative), 30..0 magnitude.
constexpr std::int64_t decode_dc_difference(std::uint32_t raw) noexcept {
  const auto magnitude = static_cast<std::int64_t>(raw & 0x7FFF'FFFFu);
  return (raw & 0x8000'0000u) != 0 ? -magnitude : magnitude;
}

// ---------------------------------------------------------------------------------------------
// Initialisation

struct DcInitOptions {
  DcPlanOptions plan{};
  std::uint8_t system_time_filter_depth = 4;     // 0x0934 (ESC power-up value)
  std::uint8_t speed_counter_filter_depth = 12;  // 0x0935 (ESC power-up value)
  // Static drift compensation: FRMWs of the reference time, one per frame, until every
  // |0x092C| is below `threshold` on `settle_checks` consecutive checks (one every `check_every`
  // frames) or `max_frames` were sent or `time_limit` passed. At least `min_frames` are sent:
  // 0x092C is a filtered mean and can look small before the loop has learnt the drift.
  std::uint32_t min_frames = 500;
  std::uint32_t max_frames = 15'000;
  std::uint32_t check_every = 100;
  std::uint32_t settle_checks = 3;
  std::chrono::nanoseconds threshold{100};
  std::chrono::nanoseconds time_limit = std::chrono::seconds(3);
  std::chrono::nanoseconds transaction_timeout = std::chrono::milliseconds(200);
  // The master's time (ns since 2000); empty: dc_master_time_now.
  std::function<std::int64_t()> master_clock{};
};

struct DcInitResult {
  DcPlan plan;
  std::uint16_t reference_station = 0;
  std::uint32_t drift_frames = 0;      // FRMWs sent during static drift compensation
  bool converged = false;              // every |difference| below the threshold at the end
  std::int64_t max_difference_ns = 0;  // at the last check
  std::chrono::nanoseconds duration{0};
};

// BWR 0x0900 (latch), one transaction of reads for all slaves, plan_dc, FPWR offset/delay,
// filter depths and filter reset per DC slave, then static drift compensation. `stations` in ring
// order. A drift compensation that does not converge is not an error (converged = false).
exec::Task<Result<DcInitResult>> initialize_dc(exec::EventLoop& loop, bus::Bus& bus,
                                               std::vector<std::uint16_t> stations,
                                               DcInitOptions options = {});

// Re-initialises one DC slave whose clock settings are gone (a power cycle resets offset, delay
// and filters to their power-up values) without touching any other slave: a BWR of 0x0900 latches
// receive times (it changes nothing else, anywhere), the slave's latched local time is compared
// with that of a DC slave that kept its time (the anchor: the reference clock, or the first other
// DC slave when the slave is the reference itself), and the offset that puts it on the anchor's
// system time, its planned delay, the filter depths and a filter reset are written to it alone.
// The runtime FRMWs then pull its drift in. Errc::not_found when `station` is not a DC slave of
// `plan`; other errors name the step and the station.
struct DcReinitResult {
  std::uint16_t station = 0;
  std::uint16_t anchor_station = 0;  // 0: no other DC slave (the master's time was used)
  std::int64_t offset_ns = 0;        // written to 0x0920
  std::uint32_t delay_ns = 0;        // written to 0x0928
};
exec::Task<Result<DcReinitResult>> reinitialize_dc_slave(exec::EventLoop& loop, bus::Bus& bus,
                                                         const DcPlan& plan, std::uint16_t station,
                                                         DcInitOptions options = {});

// After a redundant ring healed (cable redundancy): the propagation delays measured again for
// the whole ring (a latch and plan_dc, as at startup, on the slaves of `plan`) and the DC slaves
// in `free_ran`, which ran on their own while the ring was broken between them and the reference,
// put back on the reference's time: each gets the offset that makes its system time at the latch
// the reference's plus its delay. Their filters are not reset (their drift correction was right
// before the break and is still). A DC slave whose measured delay differs from `plan`'s gets the
// new one. Errors name the step and the station.
struct DcRestepResult {
  DcPlan plan;  // `plan` with the delays measured now
  struct Step {
    std::uint16_t station = 0;
    std::int64_t step_ns = 0;  // how far its system time was moved (how far it had drifted)
  };
  std::vector<Step> stepped;
  std::vector<std::uint16_t> delays_changed;  // stations given a new delay
};
exec::Task<Result<DcRestepResult>> restep_dc_slaves(exec::EventLoop& loop, bus::Bus& bus,
                                                    DcPlan plan,
                                                    std::vector<std::uint16_t> free_ran,
                                                    DcInitOptions options = {});

// Hot connect: slaves joined the ring (`joining`, a group just placed) or left it (none). The
// propagation delays are measured for the ring as it is now (a latch and plan_dc, as at
// startup, over `stations`: every slave in ring order); each joining DC slave gets the offset
// that puts its system time on the reference's (`reference_station`, which must stay the
// reference: a joining DC slave ahead of it in frame order is Errc::unsupported, named), its
// delay, filter depths and a filter reset. The other DC slaves are not stepped: their clocks are
// right, and only those whose delay changed (a group came or went upstream of them, on a
// junction port) get the new delay. Errors name the step and the station.
struct DcRingChangeResult {
  DcPlan plan;                                // the ring now, with offsets and delays
  std::vector<std::uint16_t> joined;          // joining stations that are DC slaves
  std::vector<std::uint16_t> delays_changed;  // other stations given a new delay
};
exec::Task<Result<DcRingChangeResult>> adapt_dc_to_ring(exec::EventLoop& loop, bus::Bus& bus,
                                                        std::uint16_t reference_station,
                                                        std::vector<std::uint16_t> stations,
                                                        std::vector<std::uint16_t> joining,
                                                        DcInitOptions options = {});

// Hot connect on a junction port (docs/ARCHITECTURE.md "Hot connect"): the master just let a
// group in (opened the port) or the ESC shut the port behind a group that left. The ring as it
// is now, latched and read by position (the new slaves have no station yet), planned (plan_dc);
// each DC slave among `dc_stations` (stations the session owns, held by exactly one slave) whose
// propagation delay changed gets the new one; nothing else is written. Three exchanges: latch,
// reads, writes. Errors name the step (a position that does not answer: the ring changed).
struct DcDelayUpdate {
  struct Changed {
    std::uint16_t station = 0;
    std::uint32_t delay_ns = 0;
  };
  std::vector<Changed> changed;  // stations given a new delay
  std::size_t slaves = 0;        // in the ring as measured
};
exec::Task<Result<DcDelayUpdate>> update_dc_delays(exec::EventLoop& loop, bus::Bus& bus,
                                                   std::uint16_t reference_station,
                                                   std::vector<std::uint16_t> dc_stations,
                                                   DcInitOptions options = {});

// ---------------------------------------------------------------------------------------------
// Runtime

struct DcRuntimeOptions {
  std::chrono::nanoseconds period = std::chrono::milliseconds(1);  // FRMW every period
  std::uint32_t read_every = 10;  // 0x092C of every DC slave read every N-th tick
  std::chrono::nanoseconds threshold{100};
  std::uint32_t lock_samples = 5;  // consecutive samples below the threshold
  std::size_t history = 1024;      // max-difference samples kept
  // The SYNC0 grid the cycle's phase is measured against: start + k * cycle (system time).
  std::uint64_t sync0_start = 0;
  std::chrono::nanoseconds sync0_cycle{0};  // 0: `period`
  std::chrono::nanoseconds stale_after{0};  // 0: `period`
  // Cycle steering: the bus cycle follows the reference clock (Bus::set_cycle_rate and
  // Bus::shift_cycle) so that the frame passes the reference at `phase_target` from the SYNC0
  // grid (negative: ahead of the grid point), whatever the reference's drift against the host.
  // The reference clock itself is never adjusted.
  bool follow_reference = false;
  std::chrono::nanoseconds phase_target{0};
  // Consecutive reference-time exchanges (FRMW 0x0910) without an answer (lost, expired, WKC 0)
  // that make the runtime failed (the reference design escalates at 3); the next answered one
  // makes it healthy again. See DcMaintainer::set_health_callback.
  std::uint32_t failure_threshold = 3;
  // Hot connect: the stations of slaves that may join the ring later (a group's). They are in
  // the runtime from the start, absent (not read into the lock, not in DcStatus::slaves) until
  // DcMaintainer::join_stations, and absent again after leave_stations. An unanswered read of
  // one of them (its group unplugged, before the master noticed) never costs the others' lock.
  // Stations already among the DC slaves are only marked optional.
  std::vector<std::uint16_t> optional_stations{};
  // Hot connect on junction ports: stations whose DL status (0x0110) every FRMW frame reads too;
  // a change of its port bits (link, loop, communication) calls the watch callback, so a group
  // plugged or pulled there is seen within a cycle (DcMaintainer::set_watch_callback).
  std::vector<std::uint16_t> watch_stations{};
};

// Runs on the bus thread through a Cycler (add with Cycler::kPriorityDc). Every tick it sends
// the FRMW of the reference's 0x0910 as realtime work; every read_every-th tick the same frame
// also reads every DC slave's 0x092C (realtime, so the sample belongs to the cycle it was taken
// in and costs no control-thread round trip). Allocation-free per tick.
class DcMaintainer final : public CyclicParticipant {
 public:
  // `dc_stations`: the DC slaves (the reference included). The FRMW expects a WKC equal to the
  // number of DC slaves.
  DcMaintainer(bus::Bus& bus, std::uint16_t reference_station,
               std::vector<std::uint16_t> dc_stations, DcRuntimeOptions options = {});
  DcMaintainer(bus::Bus& bus, const DcInitResult& init, DcRuntimeOptions options = {});
  ~DcMaintainer() override;

  void on_tick(const bus::CycleTick& tick) override;
  std::chrono::nanoseconds cycle_period() const noexcept override { return options_.period; }

  DcStatus status() const;
  bool locked() const noexcept { return locked_.load(std::memory_order_acquire); }
  // True once after each loss of lock (cleared by the call).
  bool take_lock_lost() noexcept { return lock_lost_.exchange(false, std::memory_order_acq_rel); }
  // Called on the bus thread when the lock state changes; must not block or allocate. Set
  // before adding to the Cycler.
  void set_lock_callback(std::function<void(bool locked)> callback) {
    lock_callback_ = std::move(callback);
  }
  // Called on the bus thread when the runtime fails (failure_threshold consecutive FRMWs
  // unanswered: healthy = false) and when an FRMW is answered again (true). Same rules as the
  // lock callback.
  void set_health_callback(std::function<void(bool healthy)> callback) {
    health_callback_ = std::move(callback);
  }
  // Called on the bus thread when the port bits of a watched station's DL status changed
  // (DcRuntimeOptions::watch_stations); same rules as the lock callback.
  void set_watch_callback(std::function<void()> callback) { watch_callback_ = std::move(callback); }
  // Starts counting the lock afresh (e.g. after re-initialising a slave).
  void reset_lock();
  // Counts a re-initialisation of `station` (reinitialize_dc_slave) in its status. Any thread.
  void note_reinitialised(std::uint16_t station);
  // Cable redundancy: the ring is broken between the reference and `stations` (the master no
  // longer sends them reference times), so they free-run on their last drift correction: outside
  // the lock, which the others keep. Any thread, allocation-free.
  void set_free_running(std::span<const std::uint16_t> stations);
  // The ring healed and the free-running slaves' offsets were stepped again (restep_dc_slaves):
  // each rejoins the lock once its difference is below the threshold on lock_samples
  // consecutive samples, or after kRejoinSamples samples whatever it is (then counted as it is).
  // Any thread, allocation-free.
  void rejoin_free_running();
  static constexpr std::uint32_t kRejoinSamples = 200;
  // Hot connect: `stations` (DcRuntimeOptions::optional_stations) joined the ring with their
  // clocks stepped onto the reference (adapt_dc_to_ring): they rejoin the lock as free-running
  // slaves do after a heal. Stations not among the optional ones are ignored. Any thread,
  // allocation-free.
  void join_stations(std::span<const std::uint16_t> stations);
  // They left the ring: absent, out of the status and the lock, which is not lost for it. Any
  // thread, allocation-free.
  void leave_stations(std::span<const std::uint16_t> stations);
  // Hot connect on a junction port: `stations` (any DC slaves here, not absent ones) are about
  // to see their propagation delay change (a group let in or gone in front of them): outside
  // the lock, not counted and not rejoining, until release_stations (their new delay written);
  // then they rejoin as after a heal. Any thread, allocation-free.
  void hold_stations(std::span<const std::uint16_t> stations);
  void release_stations(std::span<const std::uint16_t> stations);
  // True when every one of `stations` that is a DC slave here is in the lock (or absent).
  bool all_in_lock(std::span<const std::uint16_t> stations) const;
  const DcRuntimeOptions& options() const noexcept { return options_; }

 private:
  void on_complete(bus::RealtimeTransaction& rt, bool with_reads);
  // The steering controller, on the bus thread (under mutex_) for every FRMW answered.
  // `lateness_ns`: how late the frame left against its tick's deadline.
  void steer(std::int64_t frame_error_ns, std::int64_t lateness_ns);

  bus::Bus& bus_;
  DcRuntimeOptions options_;
  std::uint16_t reference_station_ = 0;
  std::vector<std::uint16_t> stations_;
  bus::RealtimeTransaction frmw_only_;
  bus::RealtimeTransaction frmw_and_reads_;
  bus::RealtimeTransaction* pending_ = nullptr;  // bus thread only
  std::uint64_t ticks_ = 0;                      // bus thread only
  std::uint32_t below_ = 0;                      // bus thread only
  // Steering state, bus thread only.
  std::int64_t submitted_deadline_ns_ = 0;  // deadline of the tick that sent the pending FRMW
  // The last reference time read and when its reply arrived: the FRMW carries the time predicted
  // from them, which is what the other slaves receive should the reference not answer (down).
  std::uint64_t last_ref_time_ = 0;
  std::int64_t last_ref_host_ns_ = 0;
  double drift_for_prediction_ppm_ = 0.0;
  double feedforward_ppm_ = 0.0;    // -reference drift
  double lateness_usual_ns_ = 0.0;  // a frame's usual send lateness (running median)
  bool lateness_seen_ = false;
  double integral_ppm_ = 0.0;  // the controller's integral, as a rate
  std::uint32_t hold_ = 0;     // samples to skip while a coarse step takes effect
  std::uint32_t settled_samples_ = 0;
  std::uint32_t far_samples_ = 0;                // consecutive medians far off (lost phase)
  std::array<std::int64_t, 5> recent_errors_{};  // the last phase errors (median filter)
  std::size_t recent_count_ = 0;
  bool acquired_ = false;
  std::atomic<bool> locked_{false};
  std::atomic<bool> lock_lost_{false};
  std::atomic<bool> reset_requested_{false};
  // Per DC slave (as stations_): in the lock, free-running, or rejoining. Under mutex_.
  static constexpr std::uint32_t kInLock = 0;
  static constexpr std::uint32_t kFreeRunning = 1;
  static constexpr std::uint32_t kRejoining = 2;
  static constexpr std::uint32_t kAbsent = 3;  // an optional station out of the ring
  static constexpr std::uint32_t kHeld = 4;    // hold_stations: out until released
  // Not counted in the lock (nor as locked): free running, rejoining or held.
  static constexpr bool outside_lock(std::uint32_t m) noexcept {
    return m == kFreeRunning || m == kRejoining || m == kHeld;
  }
  std::vector<std::uint32_t> membership_;
  std::vector<bool> optional_;                 // fixed at construction
  std::vector<std::uint32_t> rejoin_samples_;  // samples since rejoining began
  std::vector<std::uint32_t> rejoin_good_;     // consecutive samples within the threshold
  void update_membership_locked();
  std::function<void(bool)> lock_callback_;
  std::function<void(bool)> health_callback_;
  std::function<void()> watch_callback_;
  // Watched DL status (options_.watch_stations): the last port bits read; bus thread only.
  std::vector<std::uint16_t> watch_last_;
  std::vector<bool> watch_seen_;

  mutable std::mutex mutex_;  // guards status_ (short sections, no allocation under it)
  DcStatus status_;
  std::size_t history_head_ = 0;  // ring buffers status_.history and status_.phase_history
  std::size_t history_size_ = 0;
  // Rate estimate: per window, the sample with the largest (reference - host reception) offset,
  // i.e. the least host latency; the rate is the slope between two windows' best samples.
  std::int64_t window_start_ns_ = 0;
  std::int64_t window_best_offset_ = 0;
  std::int64_t window_best_host_ = 0;
  bool window_open_ = false;
  // The last windows' best samples; the rate is their least-squares slope (a baseline of
  // seconds: a few microseconds of latency floor then move the estimate by a few ppm only).
  static constexpr std::size_t kRateWindows = 16;
  std::array<std::pair<std::int64_t, std::int64_t>, kRateWindows> window_bests_{};  // host, off
  std::size_t window_count_ = 0;  // windows closed (the ring holds the last kRateWindows)
};

// ---------------------------------------------------------------------------------------------
// SYNC0/SYNC1 and latches

struct DcSyncRequest {
  std::uint16_t station = 0;
  std::chrono::nanoseconds cycle = std::chrono::milliseconds(1);  // SYNC0 cycle
  SyncConfig sync{};
  // The slave's SII (for the DC category), when the master has it.
  const wire::SiiImage* sii = nullptr;
  // The slave's ESI device description (its DC OpModes), when the configuration names one.
  const config::EsiDevice* esi = nullptr;
  // How far ahead of the slave's current system time the first pulse is placed.
  std::chrono::nanoseconds start_lead = std::chrono::milliseconds(100);
  std::chrono::nanoseconds timeout = std::chrono::milliseconds(200);
};

// AssignActivate for `sync`: SyncConfig::assign_activate, else the first ESI DC OpMode for the
// mode (SYNC0 without SYNC1 / with SYNC1), else the SII DC category's entry for it, else 0x0300
// (sync0) / 0x0700 (sync1); 0 for free run and SM-synchronous.
std::pair<std::uint16_t, AssignActivateSource> resolve_assign_activate(
    const SyncConfig& sync, const wire::SiiImage* sii,
    const config::EsiDevice* esi = nullptr) noexcept;

// Reads 0x0910, places the first pulse on the next multiple of the cycle at least start_lead
// ahead (plus sync0_shift), then: 0x0981 = 0, SYNC0/SYNC1 cycles, pulse length (when configured),
// start time, latch controls 0x09A8/0x09A9, 0x0980 = AssignActivate low byte, 0x0981 = high byte.
// Free run only deactivates (and configures latches).
exec::Task<Result<DcSyncResult>> configure_sync(exec::EventLoop& loop, bus::Bus& bus,
                                                DcSyncRequest request);

struct LatchEvent {
  std::uint16_t station = 0;
  std::uint8_t unit = 0;  // LATCH0 / LATCH1
  LatchEdge edge = LatchEdge::rising;
  std::uint64_t timestamp_ns = 0;  // system time

  bool operator==(const LatchEvent&) const = default;
};

// Latch control byte for `unit` from the configured latches (bit 0 rising, bit 1 falling).
std::uint8_t latch_control(const std::vector<LatchConfig>& latches, std::uint8_t unit) noexcept;

// Reads 0x09AE/0x09AF; for every edge whose event bit is set, reads its timestamp (which
// acknowledges it) and returns the events (unit 0 before 1, rising before falling).
exec::Task<Result<std::vector<LatchEvent>>> poll_latches(
    exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station,
    std::chrono::nanoseconds timeout = std::chrono::milliseconds(200));

}  // namespace ecat::master
