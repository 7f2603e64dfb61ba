// The Bus: the single serialization point for every frame on one link.
//
// Callers hand the bus transactions; the bus decides frame boundaries, datagram indices,
// retries and timeouts, matches replies to requests and hands each caller its own results.
//
// Two classes of work:
//  * Reliable (acyclic): transact() blocks, submit() calls back on the bus thread. Datagrams of
//    all queued reliable transactions are packed together into frames of up to
//    link.max_frame_size() bytes; a transaction larger than one frame spans several. Lost frames
//    are retried (TransactOptions::retries), each transaction has an overall timeout.
//  * Realtime (cyclic): RealtimeTransaction + submit_realtime(). Never waits behind reliable
//    backlog: it goes out in the next frame the bus sends, in frames of its own (never mixed with
//    reliable datagrams). Not retried; expires if it cannot be sent before its deadline.
//    Allocation-free end to end.
//
// Ordering and matching
//  * Reliable transactions leave in submission order; a transaction that fits one frame is never
//    split across two. A retry re-sends the whole transaction, so it may overtake later ones.
//  * Every datagram in flight has its own index (0..255, round robin, never one still in flight;
//    realtime_reserved_indices are kept for realtime work). A reply frame is accepted only when
//    it has exactly the datagrams of the frame sent with that first index, each with the same
//    index, command, length and address (ADO only for position and broadcast commands, whose ADP
//    the slaves increment). Anything else is counted (BusStats) and dropped, never delivered:
//    late replies (frame already given up; its indices stay unused for late_reply_quarantine),
//    duplicates, strays and mismatches. The frame then times out and is retried as lost.
//
// Threading model
//  * The bus owns one I/O thread (started by start()). It alone sends and receives on the link,
//    owns the index table, the in-flight frames and the packing queue. Completion callbacks of
//    submit() and RealtimeTransaction run on it and must not block.
//  * transact(), submit(), submit_realtime(), set_frame_timeout(), stats(), info() may be called
//    from any thread, concurrently. Reliable submissions go through a mutex-protected intrusive
//    queue; realtime submissions through a separate one (held for a pointer push: a short,
//    practically uncontended lock, never shared with the reliable side). The bus thread is woken
//    with Link::interrupt() only when it is (about to be) blocked in Link::receive().
//  * transact() from the bus thread (inside a callback) would deadlock and is refused.
//  * Never destroy the Bus from its own thread (a callback); stop() there only requests the stop.
//
// The cycle: set_cycle() runs a function on the bus thread at absolute deadlines
// (period-aligned, steady clock). It is the door for the master's cycle thread: the function
// submits the domains' LRW and the DC FRMW as realtime work; the bus sends them immediately after
// it returns, receives their replies, and serves queued reliable work in the slack until the next
// deadline. Deadlines are met as precisely as Link::receive() honours its timeout. Planned next
// steps, all behind this API: stop starting reliable frames shortly before the next deadline
// (so acyclic traffic on the wire cannot delay the cycle's frame), a short spin before the
// deadline, SCHED_FIFO and CPU pinning (already possible through BusOptions::on_thread_start).
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <ecat/bus/realtime.hpp>
#include <ecat/bus/transaction.hpp>
#include <ecat/link/link.hpp>
#include <ecat/result.hpp>

namespace ecat::bus {

using Clock = std::chrono::steady_clock;

// Called exactly once per accepted submit(), on the bus thread.
using Completion = std::function<void(Result<TransactionResult>)>;

struct BusOptions {
  // Time to wait for the reply to a frame (changeable later with set_frame_timeout()).
  std::chrono::nanoseconds frame_timeout = std::chrono::milliseconds(25);
  // Reliable frames only: a late reply (the reply to a frame already given up as lost) shows the
  // replies take longer than the frame timeout (a simulator behind a memory link on a loaded
  // machine, a ring longer than the timeout was sized for), and doubles the time reliable frames
  // get, up to this ceiling, so they stop being re-sent only to be answered twice. Zero keeps
  // the timeout fixed. set_frame_timeout() starts from its value again; realtime frames always
  // get the frame timeout itself. BusInfo::reliable_frame_timeout tells the current value.
  std::chrono::nanoseconds adaptive_frame_timeout_limit{0};
  // Reliable frames in flight at once. More pipelines better on long rings; fewer packs better.
  std::size_t max_reliable_frames_in_flight = 4;
  // Realtime frames in flight at once (a realtime transaction larger than one frame needs one
  // slot per frame).
  std::size_t max_realtime_frames_in_flight = 8;
  // Datagram indices (of 256) that reliable work never takes, so realtime work always finds one.
  std::size_t realtime_reserved_indices = 32;
  // How long the indices of a frame that got no reply stay unused, so a late reply cannot be
  // mistaken for the reply to a new datagram. Zero means 4 x the frame timeout at that moment.
  std::chrono::nanoseconds late_reply_quarantine{0};
  // The bus thread's name as ps, top and perf show it (at most 15 characters are kept). The
  // master names its bus thread "ecat-cycle" (the cycle thread), beside "ecat-control".
  std::string thread_name = "ecat-bus";
  // Runs first thing on the bus thread (set SCHED_FIFO, pin it to a CPU, ...).
  std::function<void()> on_thread_start{};
  // After the link fails (closed, or repeated send/receive errors) the bus completes everything
  // in flight with the failure, fails new work at once, and tries Link::reopen(): first after
  // reopen_backoff_min, then at doubling intervals up to reopen_backoff_max (the reference
  // design retries every second), until the link comes back, says it cannot be reopened
  // (Errc::unsupported or Errc::closed) or the bus stops. Both must be positive, min <= max.
  std::chrono::nanoseconds reopen_backoff_min = std::chrono::milliseconds(10);
  std::chrono::nanoseconds reopen_backoff_max = std::chrono::seconds(1);
  // Called on the bus thread when the link fails, when it is reopened, and when it turns out it
  // cannot be reopened (info() tells which). Rare; must not block (post the news elsewhere).
  std::function<void()> on_link_change{};
};

struct BusStats {
  std::uint64_t frames_sent = 0;  // reliable + realtime
  std::uint64_t realtime_frames_sent = 0;
  std::uint64_t datagrams_sent = 0;
  std::uint64_t frames_received = 0;         // every frame the link handed over
  std::uint64_t frames_lost = 0;             // no valid reply within the frame timeout
  std::uint64_t transactions_completed = 0;  // reliable, successfully
  std::uint64_t transactions_failed = 0;     // reliable, with an error (any)
  std::uint64_t transaction_timeouts = 0;    // reliable, failed with Errc::timeout
  std::uint64_t retries = 0;                 // reliable transactions re-sent after a loss
  std::uint64_t wkc_mismatches = 0;          // datagrams whose expected WKC did not match
  // Replies dropped, by reason:
  std::uint64_t unmatched_replies = 0;   // first index not in flight, not a known late/duplicate
  std::uint64_t mismatched_replies = 0;  // index in flight, but datagram count, an index,
                                         // command, address or length differs from what was sent
  std::uint64_t late_replies = 0;        // reply to a frame already given up (timeout)
  std::uint64_t duplicate_replies = 0;   // second reply to a frame already answered
  std::uint64_t decode_errors = 0;       // not a valid EtherCAT frame
  std::uint64_t realtime_completed = 0;  // realtime exchanges completed (any status)
  std::uint64_t realtime_expired = 0;
  std::uint64_t realtime_timeouts = 0;
  std::uint64_t send_errors = 0;
  std::uint64_t receive_errors = 0;
  std::uint64_t callback_exceptions = 0;  // completions that threw (swallowed to keep the bus up)
  std::uint64_t cycles = 0;               // cycle function invocations
  std::uint64_t cycle_deadlines_missed = 0;
  // Finished reliable transactions whose memory waits for a submitting thread to free it (the
  // bus thread frees nothing unless more than 1,024 wait: docs/ARCHITECTURE.md, "Bus").
  std::uint64_t finished_awaiting_free = 0;
};

struct BusInfo {
  std::string link_name;
  bool running = false;
  // Set while the link is failed (closed, or repeated send/receive errors): every request fails
  // with this error as its cause until the link is reopened (see BusOptions::reopen_backoff_min).
  std::optional<Error> link_failure;
  std::uint64_t link_failures = 0;  // times the link failed
  std::uint64_t link_reopens = 0;   // times it was reopened after failing
  std::uint64_t reopen_attempts = 0;
  // False once the link said it cannot be reopened (Errc::unsupported, or closed): a failure is
  // then for good.
  bool link_reopenable = true;
  // Why the last reopen attempt failed (until the link is reopened).
  std::optional<Error> last_reopen_error;
  std::chrono::nanoseconds frame_timeout{};
  // What reliable frames get: frame_timeout, or more after late replies
  // (BusOptions::adaptive_frame_timeout_limit).
  std::chrono::nanoseconds reliable_frame_timeout{};
  std::size_t max_frame_size = 0;    // largest frame the bus builds
  std::size_t realtime_queued = 0;   // realtime transactions waiting to be sent
  std::size_t reliable_queued = 0;   // reliable transactions with datagrams not yet sent
  std::size_t reliable_pending = 0;  // reliable transactions accepted and not yet completed
  std::size_t frames_in_flight = 0;
  std::size_t realtime_frames_in_flight = 0;
  std::size_t datagrams_in_flight = 0;
  link::LinkStats link_stats;
  // A redundant link's ports and ring (Link::redundancy); none for a single port.
  std::optional<link::RedundancyStatus> redundancy;
};

struct CycleTick {
  std::uint64_t cycle = 0;     // 0, 1, 2, ... (missed deadlines are skipped, not numbered)
  Clock::time_point deadline;  // the absolute deadline this call belongs to (steered)
  // The unsteered grid point of this deadline: first deadline + k * period. Equal to `deadline`
  // unless the cycle is steered (Bus::set_cycle_rate / shift_cycle); schedule by this one.
  Clock::time_point nominal;
  Clock::time_point woke_at;  // when the bus thread got to it
  std::uint64_t missed = 0;   // deadlines skipped just before this one (the thread ran late)
};

// Where cycle steering stands (Bus::cycle_steering).
struct CycleSteering {
  double rate_ppm = 0.0;                // the period is stretched by this (negative: shortened)
  std::chrono::nanoseconds offset{0};   // the next deadline minus its nominal grid point
  std::chrono::nanoseconds pending{0};  // phase steps requested, not applied yet
  std::uint64_t steps = 0;              // ticks at which a phase step was applied
};
using CycleFunction = std::function<void(const CycleTick&)>;

// One tick of the cycle as the bus thread lived it (Bus::set_cycle_trace): where a late tick's
// time went. Steady-clock nanoseconds since the clock's epoch; 0 where the step did not happen.
struct CycleTraceRecord {
  std::uint64_t cycle = 0;   // CycleTick::cycle
  std::uint64_t missed = 0;  // CycleTick::missed
  // The deadline that was due: CycleTick::deadline minus `missed` periods.
  std::int64_t due_ns = 0;
  // The bus thread's last wait in Link::receive() before this tick (the one the deadline should
  // have ended): when it went in, the time it asked to be woken at (the deadline, or earlier for
  // a frame timeout), when receive() returned, and whether it returned with a frame.
  std::int64_t wait_entered_ns = 0;
  std::int64_t wait_until_ns = 0;
  std::int64_t wait_returned_ns = 0;
  bool wait_got_frame = false;
  std::int64_t woke_ns = 0;          // CycleTick::woke_at: the loop turn that ran the tick began
  std::int64_t participants_ns = 0;  // the cycle function (the participants' on_tick) returned
  std::int64_t sent_ns = 0;          // the realtime work they submitted was handed to the link
  // The first reply to that work was matched; the last of it completed (its completion, e.g. a
  // domain publishing its inputs and running its per-cycle callback, returned). 0: not before
  // the next tick.
  std::int64_t reply_ns = 0;
  std::int64_t completed_ns = 0;
  std::uint32_t turns = 0;  // turns of the bus thread's loop from this tick to the next
};

// Preallocated storage for Bus::set_cycle_trace: records the ticks from the one after it is
// attached on, until it is full. Readable from any thread while the bus writes: records below
// size() are final.
class CycleTrace {
 public:
  explicit CycleTrace(std::size_t capacity) : records_(capacity) {}
  std::size_t capacity() const noexcept { return records_.size(); }
  std::size_t size() const noexcept { return size_.load(std::memory_order_acquire); }
  bool full() const noexcept { return size() >= capacity(); }
  const CycleTraceRecord& operator[](std::size_t i) const noexcept { return records_[i]; }

 private:
  friend class Bus;
  std::vector<CycleTraceRecord> records_;
  std::atomic<std::size_t> size_{0};
};

class Bus {
 public:
  explicit Bus(std::unique_ptr<link::Link> link, BusOptions options = {});
  // Stops the bus (see stop()) and closes the link.
  ~Bus();
  Bus(const Bus&) = delete;
  Bus& operator=(const Bus&) = delete;

  // Starts the bus thread. Fails with Errc::wrong_state when already started or stopped, or
  // Errc::invalid_argument for unusable options.
  Result<void> start();
  // Completes all queued and in-flight work (reliable with Errc::closed, realtime with
  // RealtimeStatus::closed), then joins the bus thread. Idempotent; the bus cannot be restarted.
  // Called on the bus thread (from a callback) it only requests the stop.
  void stop();
  bool running() const noexcept;
  bool on_bus_thread() const noexcept;

  // Reliable, blocking. Returns the results by slot, or an Error naming what failed:
  // Errc::timeout, Errc::wkc_mismatch, Errc::closed, Errc::invalid_argument, or the link's error
  // as cause. Refused (Errc::wrong_state) on the bus thread.
  Result<TransactionResult> transact(Transaction transaction, TransactOptions options = {});
  // Reliable, asynchronous. On success the bus owns the transaction and calls `completion`
  // exactly once, on the bus thread. On error (not running, invalid transaction) `completion` is
  // never called.
  Result<void> submit(Transaction transaction, Completion completion, TransactOptions options = {});

  // Realtime. Sends `rt` in the next frame(s) the bus sends. If it cannot be sent within
  // `stale_after` (> 0) from now it completes with RealtimeStatus::expired. Fails with Errc::busy
  // when `rt` is still pending, Errc::invalid_argument for a layout that does not fit, or
  // Errc::closed. Allocation-free on success.
  Result<void> submit_realtime(RealtimeTransaction& rt, std::chrono::nanoseconds stale_after);

  // Time to wait for each frame's reply; applies to frames sent from now on. Must be positive.
  Result<void> set_frame_timeout(std::chrono::nanoseconds timeout);
  std::chrono::nanoseconds frame_timeout() const noexcept;

  // Runs `function` on the bus thread at first_deadline, first_deadline + period, ... (or, with
  // no first deadline, from the next multiple of `period` on the steady clock). Replaces any
  // previous cycle. From another thread, returns once the new function is installed (the old one
  // is no longer running); from the bus thread, takes effect after the current call returns.
  Result<void> set_cycle(std::chrono::nanoseconds period, CycleFunction function,
                         std::optional<Clock::time_point> first_deadline = std::nullopt);
  // Stops calling the cycle function (same guarantee as set_cycle()); forgets the fastest work
  // period (set_fastest_work_period).
  void clear_cycle();
  // The shortest period of the work the cycle carries: the fastest of several domains (the
  // cycle's own period is their common base tick, which may be shorter: 2 ms and 3 ms tick at
  // 1 ms). While a cycle runs, the link's frame budget (Link::set_frame_budget) is capped at
  // three of it rather than three cycle periods. 0 (the default, and after clear_cycle()): the
  // cycle's period. Any thread; never on the cycle path. Errc::invalid_argument when negative.
  Result<void> set_fastest_work_period(std::chrono::nanoseconds period);

  // Cycle steering, for a cycle that follows another clock (distributed clocks: the reference
  // clock's SYNC0 grid). Each deadline is its nominal grid point plus an offset; after every
  // tick the offset moves by period * rate_ppm / 1e6 and by the phase steps requested since
  // (at most a quarter period per tick; the rest carries over to the next ticks). Both may be
  // called from any thread, the bus thread included: lock-free and allocation-free. Steering
  // survives set_cycle(); reset_cycle_steering() returns to the unsteered grid.
  void set_cycle_rate(double rate_ppm) noexcept;
  void shift_cycle(std::chrono::nanoseconds step) noexcept;
  void reset_cycle_steering() noexcept;
  CycleSteering cycle_steering() const noexcept;

  // Diagnostics: records every tick from the next one on into `trace` (see CycleTraceRecord)
  // until it is full, or until replaced; nullptr stops. Off, it costs the bus thread one atomic
  // load per loop turn. Returns once the bus thread no longer touches the previous trace (which
  // may then be destroyed). Refused on the bus thread (Errc::wrong_state).
  Result<void> set_cycle_trace(CycleTrace* trace);

  BusStats stats() const noexcept;
  BusInfo info() const;
  // A redundant link's per-port frame contents (link::Link::set_port_nop), from any thread: the
  // link reads its selectors without a lock on the bus thread. Errc::unsupported for one port.
  Result<void> set_port_nop(link::Port port, link::NopSlot slot,
                            std::optional<link::DatagramSelector> selector);
  const std::string& link_name() const noexcept { return link_name_; }
  // Largest EtherCAT frame the bus builds: min(link max_frame_size, 2 + 2047).
  std::size_t max_frame_size() const noexcept { return max_frame_size_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string link_name_;
  std::size_t max_frame_size_ = 0;
};

}  // namespace ecat::bus
