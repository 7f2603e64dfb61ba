// What a master session is told to do: the C++ form of the reference design's start options,
// Slave.Config, Domain.Config and DC.Config (upstream-inventory §2.14-2.18), without its limits
// (any cycle period, several sessions per process). Loaded from the master's sections of a ring
// file (docs/MASTER-CONFIG.md) or built in code.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/master/driver.hpp>
#include <ecat/master/pdo.hpp>
#include <ecat/master/states.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::link {
class FrameRecorder;
}

namespace ecat::config {
struct EniFile;  // <ecat/config/eni.hpp>
}  // namespace ecat::config

namespace ecat::master {

// ---- options of the session's steps (al_control.hpp, startup.hpp) ---------------------------

struct AlOptions {
  // Limit for one step (write + the slave reaching the state). ETG.1000.6 lets a slave take up
  // to 10 s for PREOP -> SAFEOP; real devices answer in a few ms, the simulator at once.
  std::chrono::nanoseconds step_timeout = std::chrono::seconds(5);
  // Pause between two AL status reads while waiting.
  std::chrono::nanoseconds poll_interval = std::chrono::milliseconds(1);
  // Each AL status read: its time limit and how often it is sent again after a lost frame.
  std::chrono::nanoseconds read_timeout = std::chrono::milliseconds(200);
  unsigned read_retries = 2;
};

struct ScanOptions {
  std::chrono::nanoseconds poll = std::chrono::milliseconds(100);
  // The count must stay the same for this long (and over at least two reads).
  std::chrono::nanoseconds stable = std::chrono::seconds(1);
  // Ends the wait earlier: the count the same at two consecutive polls and, both times, the same
  // complete link picture (every slave's DL status read by position; each port 1-3 with a link
  // carries frames, and the links add up to exactly the counted slaves). A ring where they do not
  // add up (a device still coming up, a port held closed, a redundant ring's return cable) waits
  // out `stable` as without it. docs/ARCHITECTURE.md, "Startup".
  bool link_check = true;
  // Give up (Errc::timeout) when no stable non-zero count was seen for this long.
  std::chrono::nanoseconds timeout = std::chrono::seconds(10);
};

struct InitOptions {
  unsigned attempts = 100;
  std::chrono::nanoseconds interval = std::chrono::milliseconds(10);
};

// ---- how an SDO transfer is made (Slave::upload_sdo and friends, coe_client.hpp) -------------

struct SdoOptions {
  // Transfer the whole object (subindex 0 or 1 only). Starting at subindex 0 the value begins with
  // subindex 0 padded to 16 bits (see wire::split_complete_access).
  bool complete_access = false;
  // For each mailbox exchange of the transfer (a segmented transfer has several).
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // Uploads announcing more than this fail before their segments are fetched.
  std::size_t max_upload_size = 16 * 1024 * 1024;
};

// ---- domains: configuration and what they report (domain.hpp holds the Domain) -------------

// The clock domain times are on (the bus's: bus::Clock).
using Clock = std::chrono::steady_clock;

enum class DomainState : std::uint8_t { open, cycling, stopped };
std::string_view to_string(DomainState state) noexcept;

// The domain's state diagram (../shared/seeds/domain.md), the only changes a Domain makes: each
// edge with what causes it. stop_cycling and the miss threshold are two rows of cycling ->
// stopped. Anything else asked for is refused and counted (DomainStats::refused_transitions).
enum class DomainTrigger : std::uint8_t { start_cycling, stop_cycling, miss_threshold };
std::string_view to_string(DomainTrigger trigger) noexcept;
struct DomainTransition {
  DomainState from;
  DomainState to;
  DomainTrigger trigger;
  std::string_view label;  // the diagram's label
};
std::span<const DomainTransition> domain_transitions() noexcept;

// What a registration maps: a SyncManager's image (process data), or the SyncManager's one-byte
// status register (0x0805 + 8 n) read through an FMMU of its own — the read mailbox's status
// ("mailbox full", bit 3), so a mailbox reply is seen in the cyclic frame.
// reserved: room kept for a hot-connect group (Domain::reserve; key.slave 0, key.sync_manager the
// reservation's index); the group's own registrations are made inside it when it appears.
enum class RegistrationKind : std::uint8_t { process_data, sm_status, reserved };
std::string_view to_string(RegistrationKind kind) noexcept;

struct PdoKey {
  std::uint16_t slave = 0;        // configured station address
  std::uint8_t sync_manager = 0;  // SyncManager index
  RegistrationKind kind = RegistrationKind::process_data;
  auto operator<=>(const PdoKey&) const = default;
};
// "station 0x1002 SM2", "station 0x1002 SM1 status"
std::string to_string(const PdoKey& key);

// Position of a registration in its domain: O(1) hot-path access without a key lookup.
struct PdoHandle {
  std::uint32_t index = 0;
  auto operator<=>(const PdoHandle&) const = default;
};

class Domain;
struct CycleOutcome;

// The per-cycle callback (DomainConfig::on_cycle).
using CycleCallback = std::function<void(Domain& domain, const CycleOutcome& outcome)>;

// The largest image a domain sizes itself to (DomainConfig::max_image_size 0), and so the
// logical address span the master reserves for such a domain.
inline constexpr std::size_t kAutoImageLimit = std::size_t{1} << 20;
// The most registrations a domain holds (DomainConfig::max_registrations 0).
inline constexpr std::size_t kMaxRegistrations = 65535;

struct DomainConfig {
  std::string id{};  // names the domain in every message
  // Any value >= kMinPeriod (not limited to whole milliseconds).
  std::chrono::nanoseconds period = std::chrono::milliseconds(1);
  std::uint32_t logical_base = 0;
  // Consecutive transport misses (timeouts, expired or unsendable exchanges) that stop the domain.
  std::uint32_t miss_threshold = 1000;
  // Consecutive invalid cycles (misses or WKC mismatches) that report the domain degraded.
  std::uint32_t recovery_threshold = 3;
  // Inputs older than this are stale. 0: 3 x period (follows update_period()).
  std::chrono::nanoseconds stale_after{0};
  // How long an exchange may wait for the link before the bus drops it (Bus::submit_realtime).
  // 0: max(period x 9/10, 200 us) (follows update_period()).
  std::chrono::nanoseconds realtime_budget{0};
  // Largest image (bytes). Registrations beyond it fail with image_too_large. 0 (the default):
  // as large as the registrations make it, up to kAutoImageLimit; the image grows while slaves
  // register and is fixed when the domain first cycles. Images larger than one datagram are split
  // over several datagrams and frames. (The reference fixes 2035 bytes, its one-datagram limit.)
  std::size_t max_image_size = 0;
  // Largest LRW datagram (data bytes). 0: as large as one frame of the bus carries (1486 bytes on
  // a standard 1500-byte Ethernet payload).
  std::size_t max_datagram_size = 0;
  // Registrations the domain may hold. 0 (the default): as many as the slaves register, up to
  // 65535. Storage grows in fixed blocks that never move, so readers never race a reallocation.
  std::size_t max_registrations = 0;
  // Exchanges that may be in flight at once: a lost frame keeps its exchange until the bus's frame
  // timeout, and the following cycles use the others. When all are still in flight, the cycle is
  // a miss (counted as an overrun).
  std::size_t exchanges_in_flight = 4;
  // Input change records buffered for drain_changes() (rounded up to a power of two).
  std::size_t change_queue_capacity = 1024;
  // Called on the bus (cycle) thread once per cycle, right after the cycle's reply was classified
  // and, when valid, its inputs published: read() sees this cycle's inputs and write() is staged
  // for the next cycle. For control loops that compute outputs from the latest inputs. It must
  // not block, allocate, log or throw (it delays the cycle); an exception ends the process.
  CycleCallback on_cycle{};
};

// Why a cycle was not valid.
enum class InvalidReason : std::uint8_t {
  wkc_mismatch,  // a reply came back, but a working counter differs from the expectation
  timeout,     // transport miss: no reply in time, dropped as stale (expired), or no free exchange
  link_error,  // transport miss: the link failed to send
  closed,      // transport miss: the bus is stopped
};
std::string_view to_string(InvalidReason reason) noexcept;

struct CycleInvalid {
  InvalidReason reason = InvalidReason::timeout;
  std::uint32_t expected_wkc = 0;  // sum over the datagrams (wkc_mismatch)
  std::uint32_t actual_wkc = 0;
  std::uint16_t datagram = 0;  // first datagram that differed (wkc_mismatch)
  bool operator==(const CycleInvalid&) const = default;
};

// What the per-cycle callback is told.
struct CycleOutcome {
  std::uint64_t cycle = 0;              // the cycle's number (as in the domain's stats)
  bool valid = false;                   // inputs published this cycle
  std::optional<CycleInvalid> invalid;  // why not, when not valid
};

struct CycleHealth {
  bool healthy = true;                  // the latest cycle was valid (true before any cycle)
  std::optional<CycleInvalid> invalid;  // when not healthy
};

struct DomainStats {
  DomainState state = DomainState::open;
  CycleHealth health;
  std::uint64_t cycle_count = 0;         // cycles started (ticks while cycling)
  std::uint64_t valid_count = 0;         // valid cycles
  std::uint64_t miss_count = 0;          // consecutive transport misses (now)
  std::uint64_t total_miss_count = 0;    // transport misses, all time
  std::uint64_t invalid_streak = 0;      // consecutive invalid cycles (now)
  std::uint64_t wkc_mismatch_count = 0;  // all time
  std::uint64_t timeout_count = 0;       // no reply within the bus's frame timeout
  std::uint64_t expired_count = 0;       // dropped by the bus: not sendable within the budget
  std::uint64_t overrun_count = 0;       // every exchange still in flight at the tick
  std::uint64_t link_error_count = 0;    // link failures and a stopped bus
  std::uint64_t late_results = 0;        // results of older cycles that arrived after newer ones
  std::uint64_t output_stage_skips = 0;  // cycles sent with the previous outputs (writer held lock)
  std::uint64_t changes_dropped = 0;     // change records lost to a full queue
  // Changes the state diagram does not draw that were asked for and refused (start while
  // cycling, stop while not cycling).
  std::uint64_t refused_transitions = 0;
  // The same for the hot-connect reservations' diagram (Domain::reservation_transitions).
  std::uint64_t refused_reservation_transitions = 0;
  std::uint32_t last_wkc = 0;  // sum of the working counters of the latest reply
  std::optional<Clock::time_point> last_valid_at;
  std::optional<Clock::time_point> last_invalid_at;
  std::optional<CycleInvalid> last_invalid;
  // Submission to completion of exchanges that got a reply.
  std::chrono::nanoseconds last_latency{0};
  std::chrono::nanoseconds min_latency{0};
  std::chrono::nanoseconds max_latency{0};
  std::chrono::nanoseconds mean_latency{0};
};

struct PdoRegistration {
  PdoKey key;
  PdoHandle handle;
  std::uint32_t offset = 0;   // in the image
  std::uint32_t logical = 0;  // logical_base + offset
  std::uint16_t size = 0;
  PdoDirection direction = PdoDirection::input;
  bool contributes_wkc = true;
};

// One LRW datagram of the cycle.
struct DomainDatagram {
  std::uint32_t offset = 0;  // in the image
  std::uint32_t logical = 0;
  std::uint16_t length = 0;
  std::uint16_t expected_wkc = 0;
};

struct DomainInfo {
  std::string id;
  DomainState state = DomainState::open;
  std::chrono::nanoseconds period{0};
  std::chrono::nanoseconds stale_after{0};
  std::chrono::nanoseconds realtime_budget{0};
  std::uint32_t logical_base = 0;
  std::uint32_t image_size = 0;
  std::uint32_t expected_wkc = 0;  // sum over the datagrams
  std::vector<DomainDatagram> datagrams;
  std::vector<PdoRegistration> registrations;
  DomainStats stats;
};

enum class Freshness : std::uint8_t { not_ready, fresh, stale };
std::string_view to_string(Freshness freshness) noexcept;

struct FreshnessInfo {
  Freshness state = Freshness::not_ready;
  std::optional<Clock::time_point> refreshed_at;  // last valid cycle
  std::optional<std::chrono::nanoseconds> age;    // now - refreshed_at
  std::chrono::nanoseconds stale_after{0};
};

struct SampleInfo {
  std::size_t size = 0;  // bytes copied
  // inputs: the last valid cycle; outputs: the last write (while the domain cycles, the start of
  // the cycle tick in which it was written: the write does not read the clock)
  std::optional<Clock::time_point> updated_at;
  std::optional<Clock::time_point> changed_at;  // last time the bytes changed
  std::optional<FreshnessInfo> freshness;       // inputs only
};

struct Sample {
  std::vector<std::uint8_t> value;
  SampleInfo info;
};

// One input registration whose bytes changed in a valid cycle.
struct InputChange {
  PdoHandle handle;
  PdoKey key;
  std::uint64_t cycle = 0;       // the domain's cycle number
  Clock::time_point at;          // when the reply was published
  std::uint16_t first_byte = 0;  // first and last changed byte within the registration
  std::uint16_t last_byte = 0;
};

struct DrainResult {
  std::size_t delivered = 0;
  std::uint64_t dropped = 0;  // records lost to a full queue since the previous drain
};

// ---- distributed clocks: what they report (dc.hpp holds the machinery) -----------------------

struct DcSlaveStatus {
  std::uint16_t station = 0;
  std::int64_t difference_ns = 0;          // last 0x092C
  std::int64_t max_abs_difference_ns = 0;  // since start
  std::uint64_t reinitialised = 0;         // re-initialisations after a reconnect
  // Outside the lock: the redundant ring is broken between it and the reference clock, so no
  // reference time reaches it and it runs on its last drift correction; and after the ring
  // healed and its offset was stepped again, until its difference is back below the threshold.
  // Also while a hot-connect group comes or goes on a junction port in front of it, until its
  // new propagation delay is written and its difference is back below the threshold (and a
  // joining group's slave until it is). Its difference (0x092C, not updated without reference
  // times) counts for neither the lock nor max_difference_ns meanwhile.
  bool free_running = false;
  std::uint64_t free_runs = 0;  // times the ring broke between it and the reference
};

struct DcStatus {
  std::uint16_t reference_station = 0;
  bool locked = false;
  std::int64_t max_difference_ns = 0;  // max |difference| of the last sample (slaves in the lock)
  std::vector<DcSlaveStatus> slaves;
  std::size_t free_running = 0;       // slaves outside the lock (DcSlaveStatus::free_running)
  std::vector<std::int64_t> history;  // max |difference| per sample, oldest first
  std::uint64_t samples = 0;
  std::uint64_t lock_count = 0;    // unlocked -> locked
  std::uint64_t unlock_count = 0;  // locked -> unlocked
  std::chrono::steady_clock::time_point last_lock_change{};
  // Phase of the last FRMW at the reference clock against the SYNC0 grid, in (-cycle/2, cycle/2]:
  // positive = the frame passed the reference after the grid point.
  std::int64_t phase_ns = 0;
  std::int64_t phase_target_ns = 0;  // DcRuntimeOptions::phase_target
  // phase_ns - phase_target_ns, wrapped into (-cycle/2, cycle/2]: what steering holds near 0.
  std::int64_t phase_error_ns = 0;
  // Largest |phase_error_ns| since the steering settled (without steering: since start).
  std::int64_t max_abs_phase_error_ns = 0;
  std::vector<std::int64_t> phase_history;  // phase_error_ns per sample (as `history`)
  // Steering (DcRuntimeOptions::follow_reference).
  bool follows_reference = false;
  bool phase_settled = false;        // the error stayed within cycle/20 for 20 samples
  double cycle_rate_ppm = 0.0;       // the rate applied to the cycle (Bus::set_cycle_rate)
  std::int64_t cycle_offset_ns = 0;  // where the steered deadlines stand against the host grid
  std::uint64_t phase_steps = 0;     // coarse re-alignments (start, lost phase)
  std::uint64_t reference_time = 0;  // system time from the last FRMW
  // The reference clock's rate against the host's steady clock, in ppm (positive: the reference
  // runs fast), smoothed. A cycle that follows the reference runs its period shortened by it.
  double reference_drift_ppm = 0.0;
  std::uint64_t frmw_sent = 0;
  std::uint64_t frmw_failed = 0;  // not ok (timeout, expired, wkc)
  std::uint32_t consecutive_failures = 0;
  bool failed = false;                 // consecutive_failures reached the failure threshold
  std::uint64_t runtime_failures = 0;  // healthy -> failed
  std::uint64_t overruns = 0;          // ticks skipped because the last exchange was pending
};

enum class AssignActivateSource : std::uint8_t { config, esi, sii, mode_default, none };
std::string_view to_string(AssignActivateSource source) noexcept;

struct DcSyncResult {
  std::uint16_t assign_activate = 0;
  AssignActivateSource source = AssignActivateSource::none;
  std::uint64_t start_time = 0;  // first SYNC0 (system time); 0 in free run
  std::uint32_t sync0_cycle_ns = 0;
  std::uint32_t sync1_cycle_ns = 0;
  std::uint8_t latch_control[2]{};
};

// Which of a slave's signals go to which domain.
struct ProcessDataRequest {
  enum class Kind : std::uint8_t { none, all, signals };
  Kind kind = Kind::none;
  std::string domain{};  // Kind::all
  struct Route {
    std::string signal{};
    std::string domain{};
  };
  std::vector<Route> routes{};  // Kind::signals

  static ProcessDataRequest none() { return {}; }
  static ProcessDataRequest all(std::string domain_id) {
    return {Kind::all, std::move(domain_id), {}};
  }
};

// free_run: the application runs on its own; sm_synchronous: on the SyncManager event (no DC);
// sync0 / sync1: on the DC SYNC signals. Written to 0x1C32:01 / 0x1C33:01 when the slave has them.
enum class SyncMode : std::uint8_t { free_run, sync0, sync1, sm_synchronous };
std::string_view to_string(SyncMode mode) noexcept;

enum class LatchEdge : std::uint8_t { rising, falling };

struct LatchConfig {
  std::string name{};
  std::uint8_t unit = 0;  // LATCH0 / LATCH1
  LatchEdge edge = LatchEdge::rising;
};

// DC synchronisation of one slave (applied on the way to SAFEOP when the session has DC).
struct SyncConfig {
  SyncMode mode = SyncMode::free_run;
  std::chrono::nanoseconds sync0_pulse{0};  // 0 = from the ESI/SII or the ESC default
  std::chrono::nanoseconds sync0_shift{0};
  std::chrono::nanoseconds sync1_offset{0};
  // AssignActivate (0x0980/0x0981); empty = from the SII DC category, else mode defaults.
  std::optional<std::uint16_t> assign_activate{};
  std::vector<LatchConfig> latches{};
};

struct SlaveConfig {
  std::string name{};
  // Ring position this entry describes; empty = the one after the previous entry's (0 first).
  std::optional<std::uint16_t> position{};
  // Configured station alias (SII word 4, register 0x0012) of the slave this entry describes:
  // found wherever it sits in the ring; a position given too must agree.
  std::optional<std::uint16_t> alias{};
  // When set, the slave's identity must match (checked after the SII is read).
  std::optional<std::uint32_t> vendor_id{};
  std::optional<std::uint32_t> product_code{};
  std::optional<std::uint32_t> revision{};
  std::string driver{};  // driver name; empty = chosen by identity, else the generic driver
  DriverConfig driver_config{};
  ProcessDataRequest process_data{};
  TargetState target = TargetState::op;
  std::optional<SyncConfig> sync{};
  // An ESI (EtherCAT Slave Information) file describing the device. The master takes the sync
  // mode's AssignActivate from its DC OpModes (before the SII's DC category); the device is the
  // file's entry with the slave's product code. Read when SYNC is first configured.
  std::string esi_file{};
  // Map the read mailbox's status (SM1's status byte, "mailbox full") into the cycling domain
  // the slave's process data is in, so waiting for a mailbox reply costs no frames of its own
  // (MasterConfig::mailbox_status). Empty: the master's setting.
  std::optional<bool> mailbox_status{};
  // AL status poll period while the slave is in PREOP or above; empty disables it.
  std::optional<std::chrono::nanoseconds> health_poll = std::chrono::milliseconds(250);
  // The process-data watchdog (ESC registers 0x0400 divider and 0x0420 time, written in PREOP):
  // an output SyncManager with the watchdog trigger that is not written for this long takes the
  // slave to SAFEOP (AL status 0x001B). Empty: the ESC's own (100 ms from power-up), raised to
  // three periods of the slowest domain writing the slave's outputs when that is longer. Zero:
  // off (the outputs are not watched). Else this time, rounded up to the ESC's tick (100 us, or
  // coarser beyond 6.5 s; at most 171 s); it must be longer than the period of every domain
  // writing the slave's outputs (checked in PREOP, where the domains are known).
  std::optional<std::chrono::nanoseconds> watchdog{};
  // SDO downloads run in PREOP before process data is set up (after the driver's own).
  std::vector<SdoWrite> startup_sdos{};
  // Where the PDO layout comes from: the SII (the device's default), the device's CoE objects
  // (0x1C12/0x1C13 and the mapping objects, read in PREOP), or a mapping given here, written to
  // the device in PREOP and then used.
  enum class PdoSource : std::uint8_t { sii, coe, configured };
  PdoSource pdo_source = PdoSource::sii;
  std::optional<CoePdoConfiguration> pdo_mapping{};  // PdoSource::configured
};

enum class LockPolicy : std::uint8_t { advisory, recovering, fatal };
std::string_view to_string(LockPolicy policy) noexcept;

struct DcConfig {
  std::chrono::nanoseconds cycle = std::chrono::milliseconds(1);
  bool await_lock = false;
  LockPolicy lock_policy = LockPolicy::advisory;
  std::chrono::nanoseconds lock_threshold = std::chrono::nanoseconds(100);
  std::chrono::nanoseconds lock_timeout = std::chrono::seconds(5);
  // DC cycles (drift-compensation FRMWs) the maintainer runs at the first activation before any
  // slave goes on to SAFEOP.
  std::uint32_t warmup_cycles = 0;
  // The master's cycle follows the reference clock: its wake-ups are steered so that the frame
  // passes the reference `frame_lead` before each point of the SYNC0 grid (SYNC0 itself fires at
  // the grid point plus the slave's sync0_shift). Empty frame_lead: a quarter of the cycle.
  bool follow_reference = true;
  std::optional<std::chrono::nanoseconds> frame_lead{};
};

// How the master's cycle (bus) thread runs. All are requests: when the system refuses them
// (no CAP_SYS_NICE, a CPU that does not exist, no CAP_IPC_LOCK or RLIMIT_MEMLOCK too small, no
// access to /dev/cpu_dma_latency) the session runs on and MasterStatus::cycle_thread says what was
// granted, what was refused and why. Nothing is done unless asked.
struct CycleThreadOptions {
  std::optional<int> fifo_priority{};  // SCHED_FIFO with this priority (1..99)
  std::optional<int> cpu{};            // pinned to this CPU
  // Held while the session runs, as cyclictest does: /dev/cpu_dma_latency open with this value
  // (microseconds; 0 keeps the CPUs out of deep idle states, whose exit latency is the wake-up's).
  std::optional<std::int32_t> cpu_dma_latency_us{};
  // mlockall(MCL_CURRENT | MCL_FUTURE) while the session runs (process-wide: released when the
  // last session that asked stops), and the cycle thread's stack pre-faulted at its start.
  bool lock_memory = false;
};

// The built-in device drivers (drivers::builtin_registry(), <ecat/drivers/builtin.hpp>): what
// MasterConfig::drivers starts with.
DriverRegistry builtin_drivers();

// A master's control endpoint (master/control_endpoint.hpp): a local Unix socket through which
// another process (`ecat ... --attach`, scripts, dashboards) looks at the running master and,
// when writes are allowed, changes what it does. Off unless `name` is set.
struct ControlEndpointConfig {
  // A name ("line1": $XDG_RUNTIME_DIR/ecat-master-line1.sock, or /tmp/... without
  // XDG_RUNTIME_DIR) or a path (anything with a '/'). Empty: no endpoint.
  std::string name{};
  // Permissions of the socket file: who may connect (owner only by default).
  std::uint32_t mode = 0600;
  // Requests that change what the master does (stage outputs, request states, SDO downloads,
  // register and EEPROM writes) are refused unless this is set.
  bool allow_writes = false;
  // The frames of the recent past (link/recording_link.hpp: the link the master was started on
  // records into it): the endpoint's "capture.frames" request reads it. Empty: that request
  // answers not_found. Only declared here: the recorder is the application's business.
  std::shared_ptr<const link::FrameRecorder> flight_recorder{};
};

// The mailbox gateway (ETG.8200, master/mailbox_gateway.hpp): a UDP port through which a
// configuration tool outside the segment exchanges mailbox messages (CoE, FoE, SoE, ...) with the
// slaves through the running master. Off unless `enabled`. Enabling it is the user's consent to
// what the tools send: SDO downloads and FoE writes go to the slaves as the tool wrote them.
struct MailboxGatewayConfig {
  bool enabled = false;
  // The local address to listen on: empty means loopback (127.0.0.1), "*" every IPv4 address.
  std::string address{};
  // 0x88A4 (34980), the port ETG.8200 names; 0 picks a free one (MailboxGatewayStatus::port). An
  // `ecat sim --udp` on the same host listens on 34980 too: give one of them another port.
  std::uint16_t port = 0x88A4;
  // How long one request may take in the slave's mailbox (each of its waits: a full SM0, the
  // reply, the repeat request); a request that runs out gets no reply (counted).
  std::chrono::nanoseconds request_timeout = std::chrono::seconds(1);
  // Requests waiting for their slave (one request is in flight per slave); beyond this a request
  // is answered with mailbox error 0x0007 (no more memory).
  std::size_t max_queued = 64;
  // Threads that carry requests to their slaves: so many slaves are served at once.
  std::size_t workers = 4;
};

// A hot-connect group (docs/MASTER-CONFIG.md "Hot connect"): slaves that may be absent when the
// session starts, appear later behind the end of the line (a tool changer, an optional module) and
// go again. The group is recognised by its first slave: the configured station alias (SII word 4,
// register 0x0012) when `alias` is given, else the identity (vendor and product code of the first
// slave's SII, `vendor_id`/`product_code` here or the first slave's own). Its slaves are
// configured as any other (driver, process data, targets, startup SDOs) and get fixed station
// addresses after the fixed slaves' (base_station + the count of MasterConfig::slaves + their
// index among all groups' slaves); their ring positions are where the group is found.
// Every domain a group's slaves map process data into reserves `reserve_bytes` of its image for
// the group at start, so nothing moves when it appears; its expected working counter counts the
// group only while it is present.
inline constexpr std::size_t kMaxHotConnectGroups = 16;

struct HotConnectGroup {
  std::string name{};
  std::optional<std::uint16_t> alias{};
  std::optional<std::uint32_t> vendor_id{};
  std::optional<std::uint32_t> product_code{};
  // Explicit device ID (ring file `identify: {device_id: N}`; an ENI IdentifyCmd reading 0x0134):
  // the first slave's answer to an AL ID request (0x0120 bit 5 -> 0x0134) must be this, and
  // its alias / identity too where given.
  std::optional<std::uint16_t> device_id{};
  // Image bytes reserved per domain the group's slaves use; 0: 64 bytes per slave of the group.
  std::size_t reserve_bytes = 0;
  // No `position` (found where the group sits); `alias` is not used on them.
  std::vector<SlaveConfig> slaves{};
};

struct MasterConfig {
  // What the master talks to when the caller does not say (ring files: `master: backend:`):
  // raw:IFACE, udp:HOST:PORT or sim:RING.yaml. Master::start takes a link; tools open this one.
  std::string backend{};
  ControlEndpointConfig control{};
  MailboxGatewayConfig mailbox_gateway{};
  CycleThreadOptions cycle_thread{};
  std::uint16_t base_station = 0x1000;
  // Empty: every slave found is managed, held in PREOP with no process data: the dynamic,
  // PREOP-first session. A slave whose SII shows a coupler (no mailbox, no SyncManager, FMMU, PDO
  // or DC category, as the EK1100's) is named "coupler" ("coupler_2", ...), every other one
  // "slave_<position>" (also when its SII cannot be read).
  std::vector<SlaveConfig> slaves{};
  // Optional groups of slaves after the fixed ones (HotConnectGroup); needs `slaves`. The ring
  // is polled for them (a broadcast read of the slave count) every `hot_connect_poll`.
  std::vector<HotConnectGroup> hot_connect{};
  std::chrono::nanoseconds hot_connect_poll = std::chrono::milliseconds(50);
  // Domain configurations (domain.hpp); logical_base is assigned by the master (index x 0x800)
  // unless set.
  std::vector<DomainConfig> domains{};
  std::optional<DcConfig> dc = DcConfig{};                  // empty disables DC
  std::optional<std::chrono::nanoseconds> frame_timeout{};  // empty: tuned to the slave count
  ScanOptions scan{};
  std::chrono::nanoseconds awaiting_preop_timeout = std::chrono::seconds(30);
  std::chrono::nanoseconds retry_interval = std::chrono::seconds(1);
  std::chrono::nanoseconds slave_retry_interval = std::chrono::milliseconds(200);
  // A link that fails (an interface down, a cable pulled from the NIC) is reopened by the bus
  // with a bounded backoff; the session heals on its own once it is back. If it is not back
  // within this window (or cannot be reopened at all, or the bus stops), the master ends the
  // session: idle, with last_failure "link_lost" (or "bus_stopped").
  std::chrono::nanoseconds link_recovery_window = std::chrono::seconds(30);
  // Mailbox status in the cyclic frame (as SOEM and KickCAT do): a slave with a mailbox, process
  // data in a domain and a spare FMMU gets one more FMMU mapping its SM1 status byte (0x080D)
  // into that domain's image; its mailbox then waits for "mailbox full" there instead of polling
  // SM1 with frames of its own, and polls only while the status cannot be trusted (the domain not
  // cycling or stale, its period above MailboxOptions::status_max_period). SlaveConfig can say
  // otherwise per slave. Ring file: `master: mailbox_status:` and `slaves[]: mailbox_status:`.
  bool mailbox_status = true;
  AlOptions al{};
  InitOptions init{};
  // The device drivers slaves are matched with (by identity, or by SlaveConfig::driver's name):
  // the built-in ones to begin with; an application adds its own the same way
  // (`config.drivers.add(std::make_shared<MyDriver>())`, later additions win).
  DriverRegistry drivers = builtin_drivers();
};

// Checks a configuration: unique slave names and domain ids, known domains in process-data
// requests, positive periods and thresholds, a base station that fits. Errors name the entry.
Result<void> validate(const MasterConfig& config);

// Reads the master's sections (master:, domains:, slaves:, dc:) of a ring file; the simulator's
// section is ignored. Errors carry file:line.
Result<MasterConfig> parse_master_config(std::string_view yaml, std::string source = "ring.yaml");
Result<MasterConfig> load_master_config(const std::string& path);

// ENI files (ETG.2100 EtherCAT Network Information, what TwinCAT and other configurators
// export; docs/MASTER-CONFIG.md "ENI files") mapped onto a MasterConfig, with a report: one line
// for each thing the file holds that ecat does not use, naming the element and the slave.
struct EniImport {
  MasterConfig config{};
  std::vector<std::string> report{};
};
Result<EniImport> import_eni(std::string_view xml, std::string source = "network.xml");
Result<EniImport> import_eni(const config::EniFile& eni, std::string source = "network.xml");

// What load_master_config found in the file.
struct ConfigFileInfo {
  bool eni = false;                       // an ENI (root element <EtherCATConfig>)
  std::vector<std::string> eni_report{};  // EniImport::report
};
// Reads a ring file or an ENI, told apart by content (not by extension). An ENI has no
// simulator section: the backend comes from the caller. `info`, when given, says which it was.
Result<MasterConfig> load_master_config(const std::string& path, ConfigFileInfo* info);

}  // namespace ecat::master
