// The PREOP configuration of one slave as a plan: facts read from the slave and its configuration
// in, the writes to make and the process-data layout out. Private to src/master.
//
// Everything here is pure (no I/O, no clocks, no domains touched), so each decision can be tested
// on its own (tests/master/preop_plan_test.cpp); Slave::Impl::configure_preop gathers the facts,
// asks for the plan and carries it out. Three steps, because two facts appear only half-way:
//
//   1. plan_layout: the SDOs written before the PDO layout is settled (the driver's PREOP SDOs, the
//      configuration's startup SDOs, a configured PDO assignment/mapping) and the layout itself,
//      unless it is to be read from the slave's CoE objects after those SDOs (which may change
//      them).
//   2. plan_process_data: with the layout known, the driver's sync-update SDOs, the signals, one
//      FMMU per (SyncManager, domain), the registrations the domains must take, and the
//      SyncManagers to configure.
//   3. process_data_writes: once the domains gave each registration its logical address, the
//      SyncManager and FMMU register writes, in the order they are sent.
//
// Errors name the slave (PreopFacts::who) and what did not fit, in the words the master has
// always used for them.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <ecat/master/config.hpp>
#include <ecat/master/driver.hpp>
#include <ecat/master/pdo.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master::detail {

// One of the session's domains as the plan sees it: its id and what this slave already has
// registered in it (a rebuilt slave keeps its registrations: the image cannot change under a
// cycling domain).
struct DomainFacts {
  struct Registered {
    std::uint8_t sync_manager = 0;
    std::uint16_t size = 0;
    PdoDirection direction = PdoDirection::input;
    std::uint32_t logical_address = 0;
    RegistrationKind kind = RegistrationKind::process_data;
  };
  std::string id;
  std::chrono::nanoseconds period{0};
  std::vector<Registered> registered;
};

// What the PREOP configuration depends on, read from the slave and the session before planning.
struct PreopFacts {
  std::string who;  // how errors name the slave: "slave io (station 0x1001)"
  wire::SiiImage sii;
  std::uint8_t fmmu_count = 0;  // from the ESC information; 0 when the ESC does not say (16)
  bool has_mailbox = false;     // the SII describes a standard mailbox and it was set up
  // Map the read mailbox's status into a domain (the configuration's mailbox_status, resolved).
  bool mailbox_status = false;
  std::uint8_t mailbox_in_sync_manager = 1;  // the read mailbox's SyncManager
  std::vector<DomainFacts> domains;
};

// The driver the configuration names, else the one the registry matches to the SII identity.
// Errc::not_found for a name the registry does not know.
Result<std::shared_ptr<const Driver>> choose_driver(const DriverRegistry& drivers,
                                                    const SlaveConfig& config,
                                                    const wire::SiiIdentity& identity,
                                                    const std::string& who);

// ---- 1. up to the PDO layout ------------------------------------------------------------------

struct LayoutPlan {
  PdoLayout sii_layout;  // the layout the SII describes (names and fixed PDOs for CoE)
  // Downloaded first, in this order: the driver's PREOP SDOs, the configuration's startup SDOs,
  // the configured PDO assignment and mapping (pdo_source 'configured').
  std::vector<SdoWrite> sdos;
  // pdo_source 'coe': the layout is what the slave's assignment and mapping objects hold once
  // `sdos` are written; coe_assignments_to_read() says which objects to read.
  bool read_from_coe = false;
  PdoLayout layout;  // the layout, unless read_from_coe
};

Result<LayoutPlan> plan_layout(const PreopFacts& facts, const SlaveConfig& config,
                               const Driver& driver);

// The SyncManagers whose assignment objects (0x1C10 + n) pdo_source 'coe' reads, with the
// direction the SII gives each: every SyncManager the SII describes beyond the two mailbox ones.
std::vector<CoePdoAssignment> coe_assignments_to_read(const wire::SiiImage& sii);

// ---- 2. the process data ----------------------------------------------------------------------

// Registrations one domain must take for this slave: checked for room before any is made, so a
// slave registers all of its SyncManagers or none.
struct DomainRoom {
  std::string domain;
  std::size_t count = 0;
  std::size_t bytes = 0;
};

// A SyncManager the slave gets configured, with its register value.
struct PlannedSyncManager {
  std::uint8_t sync_manager = 0;
  wire::SyncManagerConfig config;
};

// The read mailbox's status byte mapped into a domain by an FMMU of its own (read, 1 byte at the
// SyncManager's status register 0x0805 + 8 n).
struct MailboxStatusMapping {
  std::string domain;
  std::uint8_t sync_manager = 1;
  std::uint16_t physical_address = 0;
  std::uint8_t fmmu = 0;
  std::uint32_t logical_address = 0;  // set when registered before (a rebuild), else by the caller
  bool new_registration = true;
};

struct ProcessDataPlan {
  // The driver's sync-update SDOs, downloaded before anything below is applied.
  std::vector<SdoWrite> sdos;
  PdoLayout layout;
  std::vector<Signal> signals;
  // One per (SyncManager, domain), with its FMMU; logical_address is set for the registrations
  // the slave already has and filled in by the caller for the others (see new_registrations).
  std::vector<SmAttachment> attachments;
  // Indices into `attachments` of those the domains must register, in registration order.
  std::vector<std::size_t> new_registrations;
  std::vector<DomainRoom> room;  // ascending domain id
  // Every SyncManager with process data: first those routed to a domain (in the order of their
  // first attachment), then those routed nowhere, which the slave still checks on its way to
  // SAFEOP (AL status 0x001D / 0x001E otherwise) and which no FMMU maps.
  std::vector<PlannedSyncManager> sync_managers;
  // facts.mailbox_status, a mailbox, process data in a domain and an FMMU to spare: the mailbox
  // status in the domain with the shortest period (the one it already is in, after a rebuild).
  // Its registration comes after the attachments' (room included in `room`).
  std::optional<MailboxStatusMapping> mailbox_status;
  // The process-data watchdog to write (0x0400, 0x0420), when the configuration sets one or the
  // ESC's 100 ms from power-up is shorter than three periods of the slowest domain writing the
  // slave's outputs; empty: left as it is.
  std::optional<wire::ProcessDataWatchdog> watchdog;
};

// `coe` is what was read from the objects coe_assignments_to_read() named, when
// layout.read_from_coe (ignored otherwise).
Result<ProcessDataPlan> plan_process_data(const PreopFacts& facts, const SlaveConfig& config,
                                          const Driver& driver, const LayoutPlan& layout,
                                          const CoePdoConfiguration* coe = nullptr);

// ---- 3. the register writes -------------------------------------------------------------------

// One register write to the slave (FPWR at its station).
struct RegisterWrite {
  std::uint16_t address = 0;
  std::vector<std::uint8_t> data;
  bool operator==(const RegisterWrite&) const = default;
};

// The SyncManager and FMMU writes of `plan` once every attachment has its logical address: the
// process-data watchdog first (when planned), then for each attachment its SyncManager
// (deactivated, then written with its configuration) the first time it appears, then its FMMU; then
// the SyncManagers routed to no domain; then the mailbox status FMMU.
std::vector<RegisterWrite> process_data_writes(const ProcessDataPlan& plan);

}  // namespace ecat::master::detail
