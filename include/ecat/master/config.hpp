// What a master session is told to do: the C++ form of the reference design's start options,
// Slave.Config, Domain.Config and DC.Config (upstream-inventory §2.14-2.18), without its limits
// (any cycle period, several sessions per process). Loaded from the master's sections of a ring
// file (docs/MASTER-CONFIG.md) or built in code.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/drivers/builtin.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/master/pdo.hpp>
#include <ecat/master/startup.hpp>
#include <ecat/master/states.hpp>
#include <ecat/result.hpp>

namespace ecat::master {

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
  std::string driver{};  // driver name; empty = chosen by identity, else the generic driver
  DriverConfig driver_config{};
  ProcessDataRequest process_data{};
  TargetState target = TargetState::op;
  std::optional<SyncConfig> sync{};
  // An ESI (EtherCAT Slave Information) file describing the device. The master takes the sync
  // mode's AssignActivate from its DC OpModes (before the SII's DC category); the device is the
  // file's entry with the slave's product code. Read when SYNC is first configured.
  std::string esi_file{};
  // AL status poll period while the slave is in PREOP or above; empty disables it.
  std::optional<std::chrono::nanoseconds> health_poll = std::chrono::milliseconds(250);
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

// How the master's cycle (bus) thread runs. Both are requests: when the system refuses them
// (no CAP_SYS_NICE, a CPU that does not exist) the session runs on and MasterStatus::cycle_thread
// says what was refused and why.
struct CycleThreadOptions {
  std::optional<int> fifo_priority{};  // SCHED_FIFO with this priority (1..99)
  std::optional<int> cpu{};            // pinned to this CPU
};

struct MasterConfig {
  // What the master talks to when the caller does not say (ring files: `master: backend:`):
  // raw:IFACE, udp:HOST:PORT or sim:RING.yaml. Master::start takes a link; tools open this one.
  std::string backend{};
  CycleThreadOptions cycle_thread{};
  std::uint16_t base_station = 0x1000;
  // Empty: every slave found is managed, held in PREOP with no process data: the dynamic,
  // PREOP-first session. A slave whose SII shows a coupler (no mailbox, no SyncManager, FMMU, PDO
  // or DC category, as the EK1100's) is named "coupler" ("coupler_2", ...), every other one
  // "slave_<position>" (also when its SII cannot be read).
  std::vector<SlaveConfig> slaves{};
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
  AlOptions al{};
  InitOptions init{};
  // The device drivers slaves are matched with (by identity, or by SlaveConfig::driver's name):
  // the built-in ones to begin with; an application adds its own the same way
  // (`config.drivers.add(std::make_shared<MyDriver>())`, later additions win).
  DriverRegistry drivers = ecat::drivers::builtin_registry();
};

// Checks a configuration: unique slave names and domain ids, known domains in process-data
// requests, positive periods and thresholds, a base station that fits. Errors name the entry.
Result<void> validate(const MasterConfig& config);

// Reads the master's sections (master:, domains:, slaves:, dc:) of a ring file; the simulator's
// section is ignored. Errors carry file:line.
Result<MasterConfig> parse_master_config(std::string_view yaml, std::string source = "ring.yaml");
Result<MasterConfig> load_master_config(const std::string& path);

}  // namespace ecat::master
