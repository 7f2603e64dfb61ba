// The master session: one per link, as many as the process wants (the reference design's
// singleton is a limitation ecat does not copy).
//
// A Master owns a Bus (the link's I/O and cycle thread) and a control loop (its own thread) on
// which discovery, the slaves' state machines, SDO traffic and recovery run as coroutines. Every
// public call is thread-safe: control calls are handed to the loop and answered within their
// timeout; the process-data calls of Slave (read_input, write_output) go straight to the
// domains' images and never wait for the loop.
//
// Lifecycle (seeds/master.md, tables in states.hpp):
//   idle --start--> discovering --> awaiting_preop --> preop_ready | operational |
//   activation_blocked; deactivated, recovering; stop() returns to idle from anywhere.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/events.hpp>
#include <ecat/master/signal_handle.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/master/states.hpp>
#include <ecat/result.hpp>

namespace ecat::bus {
class Bus;  // <ecat/bus/bus.hpp>: the session's bus, for diagnostics (Master::bus)
}  // namespace ecat::bus

namespace ecat::master {

class Domain;
struct MailboxGatewayStatus;  // <ecat/master/mailbox_gateway.hpp>

// A terminal failure the session keeps after it ends (upstream-inventory §6.3).
struct Failure {
  // Why the last session ended by itself: "startup_failed" (discovery or configuration),
  // "awaiting_preop_failed" (a slave did not reach PREOP in time), "dc_lock_lost" (under
  // LockPolicy::fatal), "link_lost" (the link did not come back within link_recovery_window, or
  // cannot be reopened), "bus_stopped".
  std::string kind;
  Error error;
  std::chrono::system_clock::time_point at;
};

struct SlaveSummary {
  std::string name;
  std::uint16_t position = 0;
  std::uint16_t station = 0;
  SlaveState state = SlaveState::init;
  TargetState target = TargetState::op;
  std::optional<std::string> fault;  // a tracked slave-local fault, described
  // Why the slave did not reach PREOP at its last attempt (awaiting_preop), described.
  std::optional<std::string> startup_error;
};

// One ring position as the wire shows it now (Master::scan_wire): what a position-addressed read
// of the station address (0x0010) and the AL status (0x0130) returned; empty where the slave did
// not answer (the ring changed under the read).
struct WirePosition {
  std::uint16_t position = 0;
  std::optional<std::uint16_t> station;
  std::optional<std::uint16_t> al_status;
};

struct DomainSummary {
  std::string id;
  std::chrono::nanoseconds period{};
  std::string state;  // open / cycling / stopped
  std::uint32_t logical_base = 0;
  std::size_t image_size = 0;
  std::uint16_t expected_wkc = 0;
  std::uint64_t cycles = 0;
  std::uint64_t total_misses = 0;
  bool healthy = true;
};

// Why activation did not reach its target, per slave.
struct ActivationFailure {
  std::string slave;
  wire::AlState wanted = wire::AlState::op;
  Error error;
  std::optional<std::uint16_t> al_status_code;
};

// The slave whose clock the others follow (the first DC-capable slave in ring order).
struct ReferenceClock {
  std::string slave;
  std::uint16_t station = 0;
  std::uint16_t position = 0;
};

// Counters of a running session, readable at any time (zeros when no session runs). Each is
// cumulative since the session started.
struct MasterCounters {
  // The bus (see bus::BusStats for the full set).
  std::uint64_t frames_sent = 0;
  std::uint64_t frames_received = 0;
  std::uint64_t frames_lost = 0;           // no reply within the frame timeout
  std::uint64_t transaction_timeouts = 0;  // acyclic work that failed with a time-out
  std::uint64_t retries = 0;               // acyclic transactions re-sent after a loss
  std::uint64_t realtime_expired = 0;      // cyclic exchanges dropped as stale before sending
  std::uint64_t cycle_deadlines_missed = 0;
  struct DomainCounters {
    std::string id;
    std::uint64_t cycles = 0;
    std::uint64_t valid = 0;
    std::uint64_t wkc_mismatches = 0;
    std::uint64_t misses = 0;  // transport misses (time-out, expired, link error)
  };
  std::vector<DomainCounters> domains;
  struct SlaveCounters {
    std::string name;
    std::uint64_t wkc_errors = 0;       // health polls answered without this slave's WKC
    std::uint64_t mailbox_retries = 0;  // mailbox requests repeated or recovered (repeat request)
    std::uint64_t sdo_failures = 0;     // SDO transfers that failed (aborts included)
  };
  std::vector<SlaveCounters> slaves;
  // Distributed clocks: the largest |difference| of the last sample, when DC runs.
  std::optional<std::int64_t> dc_max_difference_ns;
  EventStats events;
};

enum class StopOutcome : std::uint8_t { stopped, already_stopped };

// A hot-connect group (MasterConfig::hot_connect) as the session sees it. absent: not in the ring
// (not a failure); joining: recognised, its slaves being configured and brought to the session's
// target; present: all of them there; failed: recognised but could not be brought up (retried
// after retry_interval while it stays plugged). A device that is no group's is reported in
// `refused` of the status, not configured.
enum class HotConnectState : std::uint8_t { absent, joining, present, failed };
std::string_view to_string(HotConnectState state) noexcept;

struct HotConnectStatus {
  std::string group;
  HotConnectState state = HotConnectState::absent;
  std::optional<std::uint16_t> position;  // of its first slave, while in the ring
  std::vector<std::string> slaves;
  std::string detail;  // how it was recognised, why it failed or was lost
  std::uint64_t appearances = 0;
  std::uint64_t losses = 0;
  // From noticing the group to every slave of it at its target, the last time it joined.
  std::optional<std::chrono::nanoseconds> last_join{};
};

struct MasterStatus {
  MasterState state = MasterState::idle;
  TargetState desired_target = TargetState::op;
  std::string link;
  // A redundant link's ports and ring (topology redundant / degraded on one leg / offline; ring
  // whole or broken); none on a single port.
  std::optional<link::RedundancyStatus> redundancy;
  std::uint16_t slave_count = 0;
  std::vector<SlaveSummary> slaves;
  // Hot-connect groups (empty when none are configured), and the last device found behind the
  // fixed slaves that matched no group ("position 3: vendor 0x... product 0x...: no group"), until
  // the ring changes again.
  std::vector<HotConnectStatus> hot_connect;
  std::string hot_connect_refused;
  std::vector<DomainSummary> domains;
  std::vector<ActivationFailure> activation_failures;
  std::vector<std::string> runtime_faults;  // critical faults being healed (described)
  std::optional<Failure> last_failure;
  // State changes the seed's diagram does not draw that were asked for and refused: always 0
  // unless the master has a bug.
  std::uint64_t illegal_transitions = 0;
  // The last of those, "operational -> activation_blocked" (empty when none): what a test or a
  // bug report needs to find it.
  std::string last_illegal_transition;
  // The same for the session's slaves (their lifecycle, slave_fsm) and domains (start while
  // cycling, stop while not cycling): always 0 unless the master has a bug.
  std::uint64_t illegal_slave_transitions = 0;
  std::uint64_t illegal_domain_transitions = 0;
  // ... and for the domains' hot-connect reservations (absent / joining / present).
  std::uint64_t illegal_reservation_transitions = 0;
  // What MasterConfig::cycle_thread came to, one part per request: "SCHED_FIFO 80: applied; CPU
  // 1: pinned; cpu_dma_latency 0 us: held; memory: locked, 256 KiB of stack pre-faulted", or
  // "... refused (reason)" / "memory: not locked (mlockall: reason)"; empty when nothing was asked.
  std::string cycle_thread;
};

class Master {
 public:
  explicit Master(MasterConfig config = {});
  ~Master();  // stops the session
  Master(const Master&) = delete;
  Master& operator=(const Master&) = delete;

  // Opens a session on `link`: idle -> discovering; returns at once (await_running waits).
  // Errc::wrong_state unless idle; Errc::invalid_argument for a configuration validate() refuses.
  Result<void> start(std::unique_ptr<link::Link> link);
  // Same, replacing the configuration first.
  Result<void> start(std::unique_ptr<link::Link> link, MasterConfig config);
  // Tears the session down (domains, slaves back to INIT, bus) and returns to idle. Stopping a
  // master that is already idle is not an error: StopOutcome::already_stopped says so (the seed's
  // :already_stopped). Errc::timeout when the control thread does not answer.
  Result<StopOutcome> stop();

  MasterState state() const noexcept;
  MasterStatus status() const;

  // Waits until the session is usable: preop_ready, deactivated or operational. Returns the
  // activation or startup error when it ends blocked, recovering or idle instead.
  Result<void> await_running(std::chrono::nanoseconds timeout = std::chrono::seconds(10));
  // Waits until operational.
  Result<void> await_operational(std::chrono::nanoseconds timeout = std::chrono::seconds(10));

  // Drives the session towards OP (from preop_ready or deactivated).
  Result<void> activate();
  // Retreats to SAFEOP (-> deactivated) or PREOP (-> preop_ready), keeping the bus alive.
  Result<void> deactivate(TargetState target = TargetState::safeop);
  // Replaces one slave's configuration in preop_ready (PREOP-first dynamic configuration).
  Result<void> configure_slave(std::string_view name, SlaveConfig config);
  // Changes a running domain's period (the stored configuration is unchanged).
  Result<void> update_domain_cycle_time(std::string_view domain, std::chrono::nanoseconds period);

  // Distributed clocks. When DC does not run, the error says why: Errc::unsupported when it
  // cannot (no session, DC disabled in the configuration, no DC-capable slave or its
  // initialisation failed), Errc::not_ready when it will (not initialised or not activated yet).
  Result<DcStatus> dc_status() const;
  Result<ReferenceClock> reference_clock() const;
  // Waits until every DC slave's system-time difference stayed below the lock threshold for the
  // configured number of samples. Errc::timeout names the largest difference seen.
  Result<void> await_dc_locked(std::chrono::nanoseconds timeout = std::chrono::seconds(10));

  // The bus, while a session runs (null otherwise).
  bus::Bus* bus() noexcept;
  // What is on the wire now, read only and without disturbing the session: the slaves a
  // broadcast counts, and at every ring position its station address and AL status (on a broken
  // redundant ring, each position through the port whose frame reaches it). Errc::not_ready
  // without a session; Errc::wkc_mismatch when the ring changed under the read.
  Result<std::vector<WirePosition>> scan_wire();
  std::vector<SlaveSummary> slaves() const;
  std::vector<DomainSummary> domains() const;
  std::optional<Failure> last_failure() const;

  // The mailbox gateway's address, port and counters (master/mailbox_gateway.hpp), while one is
  // open (MasterConfig::mailbox_gateway, from the first start()).
  std::optional<MailboxGatewayStatus> mailbox_gateway() const;

  // A slave of the running session by name (Errc::not_found names it). The reference stays
  // valid until stop().
  Result<Slave*> slave(std::string_view name);
  Result<Domain*> domain(std::string_view id);

  // Called on the control thread after every state change (cheap; do not block).
  void on_state_change(std::function<void(MasterState from, MasterState to)> callback);

  // The event stream (include/ecat/master/events.hpp): state changes of the master, its slaves
  // and domains, faults raised and cleared, recovery steps, activation failures, domain cycle
  // health, DC lock, the link, SDO and mailbox failures, frame losses and time-outs. Callbacks
  // run on the master's dispatcher thread; a queue is pulled by the caller. Both last as long as
  // the master, across sessions.
  EventSubscriptionId subscribe_events(EventCallback callback);
  bool unsubscribe_events(EventSubscriptionId id);
  std::shared_ptr<EventQueue> open_event_queue(std::size_t capacity = 1024);
  EventStats event_stats() const noexcept;
  // Waits until every event raised so far has reached the subscribers (tests, orderly exits).
  bool flush_events(std::chrono::nanoseconds timeout = std::chrono::seconds(1));
  // The running session's counts; once a session ended (stop() or by itself), its final counts
  // (the walk back to INIT included) until the next start.
  MasterCounters counters() const;

  // A signal of a slave of the running session, resolved once for hot-path reads and writes
  // (the per-cycle callback's way to process data; SignalHandle::resolve says what fails).
  Result<SignalHandle> signal_handle(std::string_view slave, std::string_view signal);

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace ecat::master
