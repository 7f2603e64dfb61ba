// One emulated EtherCAT slave controller (ESC): the register file and process RAM, and the
// semantics a real ESC applies to every datagram that passes it — addressing, working counter,
// register write permissions, FMMU logical mapping down to single bits, SyncManager mailbox and
// 3-buffer handshakes, the SII EEPROM interface, and hand-off of AL control requests to the
// device's application (the firmware on the PDI side).
//
// Nothing here knows about a particular device. A device is an Esc plus an Application
// (include/ecat/sim/application.hpp) that reacts like that device's firmware.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <ecat/sim/application.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::sim {

class DcUnit;

// Told when an ESC register that decides where frames go or which datagrams address the ESC may
// have changed: the station address or alias (0x0010..0x0013), DL control and alias control
// (0x0100..0x0103), an FMMU (0x0600..0x06FF), or everything (power cycle). The segment keeps its
// dispatch indexes with it (include/ecat/sim/segment.hpp).
class EscLayoutObserver {
 public:
  virtual ~EscLayoutObserver() = default;
  virtual void esc_layout_changed(std::size_t tag) = 0;
  // The loop control byte 0x0101 was written by a datagram or the PDI (also with the value it
  // held: writing "auto close" again opens a port that auto close shut). Not for a power cycle.
  virtual void esc_port_control_written(std::size_t tag) { (void)tag; }
};

// The hardware of one ESC: what its information registers report and how large it is.
struct EscHardware {
  std::uint8_t type = 0x11;  // ET1100-class, as Beckhoff terminals report
  std::uint8_t revision = 0x00;
  std::uint16_t build = 0x0000;
  std::uint8_t fmmu_count = 8;
  std::uint8_t sync_manager_count = 8;
  std::uint8_t ram_size_kib = 8;  // process RAM from 0x1000
  wire::PortDescriptor ports{{wire::PortType::ebus, wire::PortType::ebus,
                              wire::PortType::not_implemented, wire::PortType::not_implemented}};
  wire::EscFeatures features{};
  bool sii_reads_8_bytes = true;  // SII data register holds 8 bytes (else 4)
  bool dc_supported = true;
  // How long the SII interface stays busy after a read or reload command, in nanoseconds of
  // segment time.
  std::int64_t sii_busy_ns = 0;
  // How long a write command keeps it busy: the EEPROM's internal write cycle. I2C EEPROMs of the
  // 24Cxx class specify at most 5 ms per write (tWR); IgH waits 5 ms before it even looks at the
  // busy bit after a write (fsm_sii.c SII_INHIBIT). Tests set it lower to stay fast.
  std::int64_t sii_write_busy_ns = 5'000'000;
  // 0x0502 bit 7 (EEPROM algorithm: two address bytes, EEPROMs above 16 kbit). Unset: from the
  // size of the EEPROM image, as an ESC whose EEPROM size pin matches its EEPROM.
  std::optional<bool> sii_two_address_bytes{};
  // 0x0502 bit 5: the PDI emulates the EEPROM (the firmware serves SII commands; the simulator
  // serves them from the image as before, the bit only reads back).
  bool sii_emulation = false;
  // DL control 0x0100..0x0103 at power-up: forwarding rule (bit 0) = 1, RX FIFO size (bits
  // 16..18) = 7, loop control auto, station alias off (esc_type_defaults()).
  std::uint32_t dl_control = 0x0007'0001;
  // DL status bit 2 (enhanced link detection) and ESC configuration 0x0141 bit 1 at power-up.
  // Unset: from SII word 0 bit 9, as a real ESC loads it.
  std::optional<bool> enhanced_link_detection{};
  // AL states the device refuses whatever the master does (a firmware that rejects its
  // configuration): AL control requesting one leaves the state as it is, with the AL error
  // indicator and the status code. Part of the device, so power cycles keep it (set_al_refusal
  // adds to it; lifting a refusal restores these).
  std::vector<std::pair<wire::AlState, std::uint16_t>> al_refusals{};
  // Explicit device identification (an ID selector switch on the device; ring file `device_id`):
  // AL control 0x0120 bit 5 (ID request) makes the firmware put it into the AL status code
  // register 0x0134 and set AL status 0x0130 bit 5 (ID loaded) while the request stays set and no
  // AL error is pending; clearing the request clears both. Unset: the request is ignored.
  std::optional<std::uint16_t> device_id{};
};

// What the ESC datasheets give for an ESC type (register 0x0000) where neither a capture nor
// an EEPROM shows a value (esc_type_defaults()).
struct EscTypeDefaults {
  std::string_view name;          // "ET1100", "ET1200", "ESC20", "IP core", "LAN9252", "unknown"
  bool sii_reads_8_bytes = true;  // 0x0502 bit 6
  std::uint32_t dl_control = 0;   // 0x0100..0x0103 reset value
};
EscTypeDefaults esc_type_defaults(std::uint8_t type) noexcept;

// Per-frame facts the segment hands to each ESC: when the frame reached this ESC's ports and its
// processing unit, for DC receive-time latching. Times are in segment nanoseconds.
struct PassContext {
  std::int64_t epu_time_ns = 0;                // when the ESC processed the frame
  std::array<std::int64_t, 4> port_time_ns{};  // when the frame arrived at each port (0 = none)
  std::array<bool, 4> port_seen{};             // which ports the frame arrived at
};

// A datagram in flight, modified in place as it passes the ESC.
struct DatagramInFlight {
  wire::Command command = wire::Command::nop;
  std::uint32_t address = 0;  // ADP | ADO << 16, or logical
  std::span<std::uint8_t> data;
  std::uint16_t wkc = 0;

  std::uint16_t adp() const noexcept { return static_cast<std::uint16_t>(address); }
  std::uint16_t ado() const noexcept { return static_cast<std::uint16_t>(address >> 16); }
  void set_adp(std::uint16_t adp) noexcept { address = (address & 0xFFFF0000u) | adp; }
};

// What one datagram did at one ESC, for fault injection and observation.
struct DatagramEffect {
  bool addressed = false;  // the ESC matched the address (or had an FMMU overlap)
  std::uint16_t wkc_added = 0;
};

// Runtime state of one SyncManager as the ESC tracks it.
struct SyncManagerState {
  wire::SyncManagerConfig config;  // as last written (status byte maintained by the ESC)
  bool enabled = false;
  bool mailbox_full = false;  // mailbox mode: buffer holds unread data
  bool write_open = false;    // first byte written, last byte not yet
  bool read_open = false;
  std::vector<std::uint8_t> shadow;   // 3-buffer write side: committed when the last byte lands
  std::uint64_t buffers_written = 0;  // completed ECAT writes (outputs, mailbox out)
  std::uint64_t buffers_read = 0;     // completed ECAT reads (inputs, mailbox in)
  std::int64_t last_write_ns = 0;     // segment time of the last completed ECAT write
};

class Esc {
 public:
  Esc(EscHardware hardware, std::vector<std::uint8_t> eeprom,
      std::unique_ptr<Application> application);
  ~Esc();
  Esc(const Esc&) = delete;
  Esc& operator=(const Esc&) = delete;

  // Processes one datagram as the frame passes this ESC; updates data, ADP and WKC in place.
  DatagramEffect process(DatagramInFlight& datagram, const PassContext& pass);
  // What process() does for a datagram that does not concern this ESC, apart from the address
  // field: the frame passing (time, DC frame start, a finished SII command). Idempotent for one
  // pass; process() begins with it.
  void pass_by(const PassContext& pass);
  // Whether a configured-address datagram with this ADP addresses the ESC (station or alias).
  bool matches_station(std::uint16_t adp) const noexcept;
  std::size_t fmmu_count() const noexcept { return fmmu_count_; }
  // Reports layout changes (see EscLayoutObserver) as `tag`; nullptr stops.
  void set_layout_observer(EscLayoutObserver* observer, std::size_t tag) noexcept {
    layout_observer_ = observer;
    layout_tag_ = tag;
  }

  // The process-data watchdog as the registers hold it now (0x0400 divider, 0x0420 time).
  wire::ProcessDataWatchdog process_data_watchdog() const noexcept {
    return {read_u16(wire::reg::kWatchdogDivider), read_u16(wire::reg::kWatchdogTimeProcessData)};
  }
  // Lets time-driven behaviour (watchdogs, DC SYNC, device dynamics) advance to `now_ns`.
  void advance(std::int64_t now_ns);
  // Whether advance(now_ns) has something to do that cannot wait until a datagram next addresses
  // this ESC (the segment advances an ESC before its first datagram of a frame): an SII
  // operation running or its write enable to clear, a process-data watchdog running out by
  // now_ns, a DC sync unit generating pulses, or an application that asks for it
  // (Application::wants_advance). The segment advances only these ESCs on every frame.
  bool advance_due(std::int64_t now_ns) const noexcept;

  // Power cycle: registers back to reset values, station 0, INIT, SMs and FMMUs off; the
  // application restarts.
  void power_cycle(std::int64_t now_ns);

  // ---- Observation (tests, the control channel, `ecat sim status`) -------------------------
  std::uint16_t station_address() const noexcept;
  std::uint16_t station_alias() const noexcept;
  wire::AlState al_state() const noexcept;
  bool al_error() const noexcept;
  std::uint16_t al_status_code() const noexcept;
  const EscHardware& hardware() const noexcept { return hardware_; }
  // EscHardware::device_id (the device's ID switch: kept across power cycles).
  void set_device_id(std::optional<std::uint16_t> id) noexcept { hardware_.device_id = id; }
  wire::Bytes memory() const noexcept { return memory_; }
  std::uint8_t read_u8(std::uint16_t address) const noexcept;
  std::uint16_t read_u16(std::uint16_t address) const noexcept;
  std::uint32_t read_u32(std::uint16_t address) const noexcept;
  std::uint64_t read_u64(std::uint16_t address) const noexcept;
  const SyncManagerState& sync_manager(std::size_t index) const { return sms_.at(index); }
  const wire::FmmuConfig& fmmu(std::size_t index) const {
    if (index >= fmmu_count_) throw std::out_of_range("Esc::fmmu: no such FMMU");
    return fmmus_[index];
  }
  std::span<const std::uint8_t> eeprom() const noexcept { return eeprom_; }
  Application& application() noexcept { return *application_; }
  DcUnit* dc() noexcept { return dc_.get(); }
  std::int64_t now_ns() const noexcept { return now_ns_; }
  // Whether the DC system time unit (0x0910..0x09FF) answers: the hardware has DC and the SII's
  // ESC configuration (0x0141 bits 2, 3) enables the SYNC or latch units (see reset_registers).
  bool dc_system_time() const noexcept { return dc_system_time_; }
  // Whether a register byte exists in this ESC (FMMUs and SyncManagers beyond its count, DC
  // registers without DC do not: accesses to them leave the working counter alone).
  bool register_implemented(std::uint32_t address) const noexcept;

  // A firmware that refuses `state` (fault injection, refuse_state): AL control requesting it
  // (from any other state) leaves the AL state as it is and sets the error indicator with
  // `status_code`; the application never sees the request. nullopt lifts the refusal. A power
  // cycle lifts every refusal (the firmware restarts).
  void set_al_refusal(wire::AlState state, std::optional<std::uint16_t> status_code);
  std::optional<std::uint16_t> al_refusal(wire::AlState state) const noexcept;

  // ---- The PDI side: what the device's firmware (Application) uses --------------------------
  void pdi_set_al_status(wire::AlState state, bool error, std::uint16_t status_code);
  // Copies a reply into a mailbox SM that the master reads (direction read). Fails when the SM is
  // not enabled, not a read mailbox, too small, or still full.
  bool pdi_mailbox_send(std::size_t sm, wire::Bytes message);
  // The bytes the master wrote into a write-direction mailbox SM, while it is full.
  std::optional<wire::Bytes> pdi_mailbox_received(std::size_t sm) const;
  // Marks the write-direction mailbox read by the firmware (the master may write again).
  void pdi_mailbox_release(std::size_t sm);
  // Re-sends the last mailbox reply after a repeat request; sets the repeat acknowledge.
  void pdi_mailbox_repeat(std::size_t sm);
  // Writes the process-data inputs of a read-direction buffered SM (the firmware's new buffer).
  void pdi_write_buffer(std::size_t sm, wire::Bytes data);
  // The last complete buffer the master wrote into a write-direction buffered SM.
  wire::Bytes pdi_read_buffer(std::size_t sm) const;
  void pdi_set_sm_deactivated(std::size_t sm, bool deactivated);
  // Direct register/RAM access from the PDI (bypasses ECAT write permissions).
  void pdi_write(std::uint16_t address, wire::Bytes data);
  void pdi_write_u16(std::uint16_t address, std::uint16_t value);
  // SII words the PDI may change (EEPROM emulation).
  std::vector<std::uint8_t>& pdi_eeprom() noexcept { return eeprom_; }
  // The PDI takes the EEPROM (0x0501 bit 0) when the master offered it (0x0500 bit 0), or
  // gives it back. While the PDI holds it, EEPROM commands from ECAT are ignored.
  void pdi_take_eeprom(bool take);

  // ---- SII fault injection (tests) ------------------------------------------------------------
  // The next `count` EEPROM commands (read, write, reload) end with the acknowledge error (0x0502
  // bit 13) and change nothing: an I2C EEPROM that does not acknowledge, as it does while its
  // internal write cycle still runs. `writes_only`: only write commands count and fail.
  void inject_sii_acknowledge_errors(unsigned count, bool writes_only = false) noexcept {
    sii_nacks_ = count;
    sii_nack_writes_only_ = writes_only;
  }

 private:
  friend class DcUnit;
  struct AccessResult {
    bool read = false;
    bool written = false;
  };

  void reset_registers();
  // al_refusals_ as the device has them (EscHardware::al_refusals), nothing injected.
  void restore_hardware_refusals();
  // Tells the observer when [first, last] touches a register of the layout.
  void layout_written(std::uint32_t first, std::uint32_t last);
  AccessResult access(std::uint32_t address, std::span<std::uint8_t> data, bool do_read,
                      bool do_write, bool or_into_data, const PassContext& pass);
  AccessResult logical(DatagramInFlight& datagram, bool do_read, bool do_write,
                       const PassContext& pass);
  // Byte-range access through SyncManager protection; `mask` (nullable) selects bits.
  AccessResult physical_read(std::uint32_t address, std::span<std::uint8_t> out,
                             const std::uint8_t* mask, bool or_into_data);
  AccessResult physical_write(std::uint32_t address, std::span<const std::uint8_t> in,
                              const std::uint8_t* mask, const PassContext& pass);
  // Returns whether any byte was writable (only then does the write count in the WKC).
  bool register_write(std::uint32_t address, std::span<const std::uint8_t> in,
                      const std::uint8_t* mask, const PassContext& pass);
  void refresh_registers_for_read(std::uint32_t address, std::size_t length);
  void after_register_write(std::uint32_t first, std::uint32_t last, const PassContext& pass,
                            const std::array<std::uint8_t, 8>& sm_activate_before);
  void sync_manager_written(std::size_t index, bool was_enabled);
  void update_sm_status(std::size_t index);
  // The master wrote bytes [first, last] that overlap 0x0502..0x0503 (control/status).
  void sii_control_written(std::uint32_t first, std::uint32_t last);
  // The master wrote 0x0500 (EEPROM configuration: offer to the PDI, force ECAT access).
  void sii_access_written();
  void sii_finish_if_due() {
    if (sii_running_) sii_finish_if_due_slow();
  }
  // Loads the ESC configuration area (words 0..7) into the registers: at power-up everything,
  // on a reload command all but the station alias and 0x0141 bits 1, 4..7. Returns whether the
  // checksum matched (nothing is loaded when it did not).
  bool sii_load_configuration(bool power_up);
  std::uint16_t sii_fixed_bits() const noexcept;
  // 0x0502 as the ESC keeps it (the register bytes are overwritten by a master's write before
  // sii_control_written sees it).
  void sii_store_status(std::uint16_t status) noexcept;
  int sm_index_for(std::uint32_t address) const noexcept;
  // Whether an enabled SyncManager covers any byte of [first, end).
  bool sm_overlaps(std::uint32_t first, std::uint32_t end) const noexcept;
  // Rebuilds sm_areas_ and watchdog_sms_ from sms_ (after an SM is enabled, disabled, moved).
  void rebuild_sm_areas() noexcept;
  void sii_finish_if_due_slow();

  // What every datagram of a frame looks at first, kept together in the object's first cache
  // line and apart from the bulky state below: the frame path of a 256-slave ring is bound by
  // the cache lines it touches per ESC (docs/SIMULATOR.md, "Inside an addressed ESC"). `ram_` is
  // memory_'s storage (its size never changes after construction); `sii_running_` mirrors
  // sii_pending_.has_value(); `sii_register_stale_` says the PDI wrote over 0x0502..0x0503 since
  // the ESC last stored its SII status there (only the PDI can: an ECAT write goes through
  // sii_control_written), so advance() need not load the register's line to compare it.
  alignas(64) std::uint8_t* ram_ = nullptr;
  std::uint32_t memory_size_ = 0;
  std::uint32_t active_fmmus_ = 0;  // bit per FMMU: active with a non-zero length
  std::uint32_t watchdog_sms_ = 0;  // bit per SyncManager: output with its watchdog running
  std::uint16_t sii_status_ = 0;
  std::uint8_t sm_area_count_ = 0;
  std::uint8_t fmmu_count_ = 0;
  bool sii_running_ = false;
  bool sii_register_stale_ = false;
  std::int64_t now_ns_ = 0;
  std::unique_ptr<Application> application_;
  std::unique_ptr<DcUnit> dc_;
  // The FMMUs (as decoded from their registers) right after that line, so that an LRW reads the
  // first four from the next one; the enabled SyncManagers' areas in SM index order ([start,
  // end), index), so that a physical access searches these instead of every SyncManager's state
  // (sm_index_for keeps the lowest index first, as before), rebuilt by rebuild_sm_areas whenever
  // one is enabled, disabled or moved.
  std::array<wire::FmmuConfig, wire::reg::kMaxFmmus> fmmus_{};
  struct SmArea {
    std::uint32_t start = 0;
    std::uint32_t end = 0;
    std::uint32_t index = 0;
  };
  std::array<SmArea, wire::reg::kMaxSyncManagers> sm_areas_{};

  void apply_id_request(std::uint16_t control) noexcept;
  EscHardware hardware_;
  std::vector<std::uint8_t> memory_;
  std::vector<std::uint8_t> eeprom_;
  std::vector<SyncManagerState> sms_;
  std::int64_t sii_busy_until_ns_ = 0;
  // What the running EEPROM command does when the busy time ends.
  struct SiiPending {
    std::uint16_t command = 0;
    std::uint16_t errors = 0;               // error bits it ends with
    std::optional<std::size_t> write_byte;  // write: the EEPROM byte offset and the word
    std::array<std::uint8_t, 2> write_data{};
  };
  std::optional<SiiPending> sii_pending_;
  unsigned sii_nacks_ = 0;
  bool sii_nack_writes_only_ = false;
  bool dc_system_time_ = false;
  std::vector<std::uint8_t> last_mailbox_reply_;
  std::array<std::optional<std::uint16_t>, 16> al_refusals_{};  // by AL state code (4 bits)
  EscLayoutObserver* layout_observer_ = nullptr;
  std::size_t layout_tag_ = 0;
};

// Byte ranges of the register area (0x0000..0x0FFF) the master may write; everything else is
// read-only from ECAT. A write that reaches no writable byte is ignored and does not count in the
// working counter, as on real ESCs (BWR 0x092C, system time difference, comes back with WKC 0 from
// DC-capable EK1100 and EL2889 in replay-ek1100-el2828-el2889.pcapng).
bool ecat_may_write_register(std::uint16_t address) noexcept;

}  // namespace ecat::sim
