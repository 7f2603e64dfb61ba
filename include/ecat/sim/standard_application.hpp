// The firmware every simulated device shares: the AL state machine with the checks real slaves
// make before they change state, the mailbox (a CoE server), process data moved between the
// SyncManagers and the object dictionary through the PDO layout, the process-data watchdog, the
// SYNC0 input latch of DC-synchronous devices, emergencies, and the named signals tests and
// wiring use. A device profile (an EL3202, a CiA 402 drive) derives from StandardApplication and
// adds its physics through the protected hooks.
//
// What a device is comes from a StandardConfig: its SII image (mailboxes, process-data
// SyncManagers, DC capability) and its object dictionary, which always holds the PDO assignment
// (0x1C10 + SyncManager) and mapping objects (0x16xx / 0x1Axx) — built from the SII's PDOs for
// devices without CoE (add_sii_process_data), or the device's own, master-writable objects for
// CoE devices. The SyncManager lengths the device expects follow those objects, so a master that
// remaps PDOs in PREOP must configure the SyncManagers to match.
//
// Decisions where real devices differ:
//  - FMMUs are not checked by default (SOES-based and most Beckhoff devices do not look at them);
//    StandardConfig::check_fmmus makes SAFEOP refuse a process-data SyncManager without an FMMU
//    of the right direction mapping its start (0x001D / 0x001E).
//  - OP does not need outputs first by default; with require_valid_outputs, SAFEOP -> OP is
//    refused with 0x001B when the process-data watchdog has expired and 0x0019 when no complete
//    output buffer arrived since SAFEOP was entered.
//  - In OP, the process-data watchdog (ESC register 0x0440 bit 0 falling) drops the device to
//    SAFEOP with 0x001B once it has been in OP for one watchdog time; the outputs go to their safe
//    state.
//  - An unacknowledged error lets the device step down (the error stays); requests for the same or
//    a higher state are ignored until the master acknowledges (AL control bit 4).
//  - Devices whose SII sets ESC configuration bit 0 ("device emulation": simple terminals without
//    a microcontroller, such as the EK1100, EL1809, EL2809, EL2004) have no firmware deciding
//    the AL state: the ESC mirrors AL control into AL status, nothing is refused, and a process
//    data watchdog expiry only puts the outputs into their safe state. The firmware here then
//    just follows the state for its process data.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/eoe_server.hpp>
#include <ecat/sim/foe_server.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/sim/pdo_mapping.hpp>
#include <ecat/sim/soe_server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim {

// A process-data SyncManager as the device's firmware expects the master to configure it.
struct ProcessDataSyncManager {
  std::uint8_t index = 2;
  PdoDirection direction = PdoDirection::rx;  // rx: outputs (master writes), tx: inputs
  std::uint16_t start = 0x1100;

  friend bool operator==(const ProcessDataSyncManager&, const ProcessDataSyncManager&) = default;
};

// The process-data SyncManagers an SII image declares: SYNCM entries of type outputs (3) or
// inputs (4) with the enable bit set (virtual SyncManagers are left out), in SyncManager order.
std::vector<ProcessDataSyncManager> process_data_sync_managers(const wire::SiiImage& sii);

// Distributed-clock synchronisation the device supports and demands at PREOP -> SAFEOP. Only the
// activation (0x0981) and the SYNC0 cycle time (0x09A0) are checked; 0x0980 (which side drives
// the SYNC unit) is not.
struct DcSyncRequirement {
  bool supported = false;  // can run SYNC0-synchronous; activating SYNC0 on others is 0x0030
  bool required = false;   // SAFEOP needs SYNC0 active (0x0981 bits 0 and 1), else 0x0030
  // The SYNC0 cycle time (0x09A0) must lie within these limits when SYNC0 is active, else 0x0035.
  std::uint32_t min_cycle_ns = 0;  // 0: no lower limit (a cycle time of 0 is always refused)
  std::uint32_t max_cycle_ns = 0;  // 0: no upper limit
};

struct StandardConfig {
  wire::SiiImage sii{};
  ObjectDictionary dictionary{};
  CoeServerConfig coe{};  // used when the SII declares a standard mailbox
  SoeServerConfig soe{};  // used when the SII's mailbox protocols also declare SoE
  FoeServerConfig foe{};  // used when it also declares FoE (mailbox protocols)
  EoeServerConfig eoe{};  // used when it also declares EoE (mailbox protocols)
  bool check_fmmus = false;
  bool require_valid_outputs = false;
  // Also a DC requirement: 0x1C32:01 (SM output parameter, synchronisation type) written to 2
  // (DC SYNC0) or 3 (DC SYNC1) by the master makes SYNC0 required.
  DcSyncRequirement dc{};
};

class StandardApplication : public DeviceApplication {
 public:
  explicit StandardApplication(StandardConfig config);

  // ---- Application hooks (the ESC calls these) -----------------------------------------------
  void start(Esc& esc) override;
  void on_al_control(Esc& esc, std::uint16_t control) override;
  void on_buffer_written(Esc& esc, std::size_t sm) override;
  void on_buffer_read(Esc& esc, std::size_t sm) override;
  void before_buffer_read(Esc& esc, std::size_t sm) override;
  void on_mailbox_repeat(Esc& esc, std::size_t sm) override;
  void on_sync_manager_changed(Esc& esc, std::size_t sm) override;
  void advance(Esc& esc, std::int64_t now_ns) override;
  // True while advance() has something to do without being addressed: an AL state set through
  // the PDI to catch up with, or an expired process-data watchdog in OP. A device whose update()
  // models time overrides this (Cia402Application returns true).
  bool wants_advance(const Esc& esc, std::int64_t now_ns) const override;

  // ---- Signals (DeviceApplication) -------------------------------------------------------------
  std::vector<SignalInfo> signals() const override;
  std::optional<double> signal(std::string_view name) const override;
  bool set_input(std::string_view name, double value) override;
  void clear_input(std::string_view name) override;

  // ---- Observation ------------------------------------------------------------------------------
  ObjectDictionary& dictionary() noexcept { return od_; }
  const ObjectDictionary& dictionary() const noexcept { return od_; }
  // The CoE server, or nullptr for devices without a mailbox.
  CoeServer* coe_server() noexcept { return coe_.get(); }
  // The SoE server (plugged into the CoE server for mailbox type 5), or nullptr when the SII
  // does not declare SoE.
  SoeServer* soe_server() noexcept { return soe_.get(); }
  // The FoE server, or nullptr unless the SII declares FoE (and a standard mailbox).
  FoeServer* foe_server() noexcept { return foe_.get(); }
  // The EoE server, or nullptr unless the SII declares EoE (and a standard mailbox).
  EoeServer* eoe_server() noexcept { return eoe_.get(); }
  const wire::SiiImage& sii() const noexcept { return config_.sii; }
  const std::vector<ProcessDataSyncManager>& process_data() const noexcept { return pd_sms_; }
  // The process data of SyncManager `sm` as the dictionary says now.
  Result<SyncManagerLayout> layout(std::uint8_t sm) const { return process_data_layout(od_, sm); }
  // Complete output buffers received since SAFEOP was entered.
  std::uint64_t outputs_received() const noexcept { return outputs_received_; }

  // ---- The firmware's own actions (profiles, fault injection) ---------------------------------
  // A device error: the device drops to `state` (when lower than the present one) and shows the
  // error indicator with `code` (a vendor code 0x8000.. or any ETG code).
  void raise_al_error(Esc& esc, std::uint16_t code, wire::AlState state);
  // Sends a CoE emergency and sets the error register 0x1001 (no mailbox: only 0x1001).
  void emergency(Esc& esc, std::uint16_t error_code, std::uint8_t error_register,
                 std::array<std::uint8_t, 5> data = {});

 protected:
  // ---- Hooks for device models ----------------------------------------------------------------
  // A transition passed every standard check: 0 allows it, an AL status code refuses it.
  virtual std::uint16_t check_transition(wire::AlState from, wire::AlState to) {
    (void)from;
    (void)to;
    return 0;
  }
  virtual void on_state_changed(wire::AlState from, wire::AlState to) {
    (void)from;
    (void)to;
  }
  // Inputs are about to be published (a read of an input SyncManager, or SYNC0): bring the input
  // objects up to date. Forced entry-bound inputs are applied after this hook.
  virtual void update_inputs(std::int64_t now_ns) { (void)now_ns; }
  // New outputs were taken in OP; `changed` lists the entries whose value changed.
  virtual void outputs_changed(const std::vector<std::pair<std::uint16_t, std::uint8_t>>& changed) {
    (void)changed;
  }
  // The outputs go to their safe state (leaving OP, watchdog). Default: every entry mapped into
  // an output SyncManager back to its default value (zero when it has none).
  virtual void apply_safe_outputs();
  // An SDO download changed (index, subindex) (subindex 0 for complete access).
  virtual void object_written(std::uint16_t index, std::uint8_t subindex) {
    (void)index;
    (void)subindex;
  }
  // Time passes (after the watchdog check). Runs when the ESC is advanced: before every frame only
  // when wants_advance() says so, so a device that models time here overrides wants_advance too.
  virtual void update(std::int64_t now_ns) { (void)now_ns; }
  // Power-up: the dictionary is back at its initial content; reset the model too.
  virtual void reset_model() {}

  // ---- Signal bindings
  // ---------------------------------------------------------------------------- A signal that is
  // an object entry: value = raw * scale + offset. Inputs forced with set_input are written back
  // into the entry (raw = (value - offset) / scale, rounded and clamped).
  void add_entry_signal(SignalInfo info, std::uint16_t index, std::uint8_t subindex,
                        double scale = 1.0, double offset = 0.0);
  // A signal the model computes; a forced input is only remembered (see forced()).
  void add_model_signal(SignalInfo info, std::function<double()> read);
  // The value an input is forced to, if it is.
  std::optional<double> forced(std::string_view name) const;

  // The ESC this firmware runs on (valid from start() on).
  Esc& esc() const noexcept { return *esc_; }
  wire::AlState al_state() const noexcept;
  const StandardConfig& config() const noexcept { return config_; }

 private:
  struct AlOutcome {
    wire::AlState state = wire::AlState::init;
    bool error = false;
    std::uint16_t code = 0;
  };
  struct Binding {
    SignalInfo info;
    bool entry = false;
    std::uint16_t index = 0;
    std::uint8_t subindex = 0;
    double scale = 1.0;
    double offset = 0.0;
    std::function<double()> read;
  };

  // The AL state machine: what a write of AL control leads to.
  AlOutcome al_transition(Esc& esc, std::uint16_t control);
  void enter(Esc& esc, wire::AlState to);
  void catch_up(Esc& esc);
  bool device_emulation(const Esc& esc) const noexcept;
  std::uint16_t check_mailbox(const Esc& esc, const wire::SiiMailbox& mailbox,
                              std::uint16_t code) const;
  std::uint16_t check_process_data(const Esc& esc) const;
  std::uint16_t check_dc(const Esc& esc) const;
  std::uint16_t check_valid_outputs(const Esc& esc) const;
  bool watchdog_expired(const Esc& esc) const;
  void publish_inputs(Esc& esc, std::size_t sm);
  void take_outputs(Esc& esc, std::size_t sm);
  void on_sync(Esc& esc, const SyncPulse& pulse);
  const ProcessDataSyncManager* find_pd(std::size_t sm) const noexcept;
  const Binding* find_binding(std::string_view name) const noexcept;
  void restore_dictionary();

  StandardConfig config_;
  ObjectDictionary od_;
  std::unique_ptr<CoeServer> coe_;
  std::unique_ptr<SoeServer> soe_;
  std::unique_ptr<FoeServer> foe_;
  std::unique_ptr<EoeServer> eoe_;
  std::vector<ProcessDataSyncManager> pd_sms_;
  std::map<std::uint8_t, SyncManagerLayout> layouts_;  // frozen at PREOP -> SAFEOP
  // Each layout's mapped entries, resolved once per layout and dictionary generation.
  struct ResolvedEntries {
    std::uint64_t generation = 0;
    std::vector<ObjectEntry*> entries;
  };
  std::map<std::uint8_t, ResolvedEntries> resolved_;
  std::span<ObjectEntry* const> resolved(std::uint8_t sm, const SyncManagerLayout& layout);
  std::vector<Binding> bindings_;
  std::map<std::string, double, std::less<>> forced_;
  std::vector<std::uint8_t> image_;  // scratch for packing inputs
  Esc* esc_ = nullptr;
  wire::AlState state_ = wire::AlState::init;  // the state the firmware last entered
  bool watchdog_handled_ = false;
  std::int64_t op_entered_ns_ = 0;
  std::uint64_t outputs_received_ = 0;
  std::map<std::uint8_t, bool> valid_outputs_;
};

// ---- Dictionaries from SII images ---------------------------------------------------------------

struct SiiDictionaryOptions {
  bool writable = false;      // mapping and assignment objects may be changed in PREOP
  bool entry_objects = true;  // add the mapped entries as objects (existing objects are kept)
  bool assignments = true;    // add the assignment objects 0x1C10 + sm
};

// Adds the process-data objects an SII image describes: every PDO's mapping object (0x16xx /
// 0x1Axx) with its entries; the mapped entries as objects (VAR for subindex 0, RECORD otherwise;
// typed from the SII data type, else by bit length; PDO-mappable in the PDO's direction); and one
// assignment object 0x1C10 + sm per SyncManager listing its PDOs in image order (PDOs whose
// SyncManager is 0xFF or beyond the SYNCM category stay unassigned). PDOs flagged "fixed
// content" keep a read-only mapping.
void add_sii_process_data(ObjectDictionary& od, const wire::SiiImage& sii,
                          SiiDictionaryOptions options = {});

// The communication objects every CoE device has, from the SII: 0x1000 device type, 0x1001,
// 0x1008 device name, 0x1009/0x100A versions, 0x1018 identity, 0x1C00 SyncManager types.
void add_sii_identity(ObjectDictionary& od, const wire::SiiImage& sii,
                      std::uint32_t device_type = 0, std::string_view hardware_version = "",
                      std::string_view software_version = "");

// A dictionary entry's value as a number (integers, BOOLEAN, BITn, REAL32/64), or nullopt for
// strings and missing entries.
std::optional<double> entry_number(const ObjectDictionary& od, std::uint16_t index,
                                   std::uint8_t subindex);
// Stores a number into an entry, rounded and clamped to the entry's type and bit length.
bool set_entry_number(ObjectDictionary& od, std::uint16_t index, std::uint8_t subindex,
                      double value);

}  // namespace ecat::sim
