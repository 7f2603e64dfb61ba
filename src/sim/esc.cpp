#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <utility>

#include <ecat/sim/application.hpp>
#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim {

namespace reg = wire::reg;
using wire::Command;

namespace {

constexpr std::uint32_t kRegisterAreaEnd = 0x1000;
// SyncManagers may cover the digital I/O and user RAM registers too (0x0F00..0x0FFF): Beckhoff
// digital output terminals (EL2004, EL2809 ...) place their output SyncManager at 0x0F00.
constexpr std::uint32_t kSyncManagerAreaStart = 0x0F00;
constexpr std::size_t kMaxDatagram = wire::kMaxDatagramLength + 1;
// EEPROMs up to 16 kbit (2 KiB) take one address byte, larger ones two (SII control bit 7).
constexpr std::size_t kOneAddressByteEepromBytes = 2048;
constexpr std::uint8_t kEscConfigDeviceEmulation = 0x01;
constexpr std::uint8_t kEscConfigDcUnits = 0x0C;  // SYNC out unit (bit 2), latch in unit (bit 3)
constexpr std::uint16_t kDcBase = 0x0900;
constexpr std::uint16_t kDcReceiveTimesEnd = 0x0910;  // port receive times 0x0900..0x090F
constexpr std::uint16_t kDcSize = 0x0100;

bool in_range(std::uint32_t address, std::uint32_t first, std::uint32_t size) noexcept {
  return address >= first && address < first + size;
}

// Does [first, last] (inclusive) overlap [start, start + size)?
bool overlaps(std::uint32_t first, std::uint32_t last, std::uint32_t start,
              std::uint32_t size) noexcept {
  return first < start + size && last >= start;
}

// A process-data window is a few bytes: a loop beats a call into the C library's memcpy.
void copy_bytes(std::uint8_t* to, const std::uint8_t* from, std::size_t n) noexcept {
  if (n > 16) {
    std::memcpy(to, from, n);
    return;
  }
  for (std::size_t k = 0; k < n; ++k)
    to[k] = from[k];
}

std::uint8_t masked(std::uint8_t old_value, std::uint8_t new_value, const std::uint8_t* mask,
                    std::size_t i) noexcept {
  if (mask == nullptr) return new_value;
  return static_cast<std::uint8_t>((old_value & ~mask[i]) | (new_value & mask[i]));
}

}  // namespace

// Reset values per ESC type, for what neither a capture nor an EEPROM shows. Sources: the
// Beckhoff "EtherCAT Slave Controller" datasheet, section II (register 0x0000 type codes;
// 0x0100..0x0103 DL control: forwarding rule bit 0 reset 1, RX FIFO size bits 16..18 reset 7,
// everything else 0; 0x0502 bit 6 "supported number of EEPROM read bytes": 8 for ET1100,
// ET1200 and the IP core, 4 for the ESC10/ESC20 FPGAs) and the Microchip LAN9252 datasheet (its
// ESC core reports type 0xC0 and the ET1100 register defaults). The shared captures agree where
// they show a value: every ET1100/ET1200 there reads 0x0502 bit 6 = 1. The search tool's stored
// material did not hold these datasheet pages, so the table was not re-checked against them in
// this session.
EscTypeDefaults esc_type_defaults(std::uint8_t type) noexcept {
  constexpr std::uint32_t kDlControlReset = 0x0007'0001;
  switch (type) {
    case 0x01:
      return {"ESC10", false, kDlControlReset};
    case 0x02:
      return {"ESC20", false, kDlControlReset};
    case 0x04:
      return {"IP core", true, kDlControlReset};
    case 0x11:
      return {"ET1100", true, kDlControlReset};
    case 0x12:
      return {"ET1200", true, kDlControlReset};
    case 0xC0:
      return {"LAN9252", true, kDlControlReset};
    default:
      return {"unknown", true, kDlControlReset};
  }
}

bool ecat_may_write_register(std::uint16_t address) noexcept {
  struct Range {
    std::uint16_t first;
    std::uint16_t last;
  };
  // The registers a master may write (ESC datasheet, section II); all others are read-only for
  // ECAT. SyncManager bytes are special-cased in register_write.
  static constexpr Range kWritable[] = {
      {0x0010, 0x0011},  // configured station address
      {0x0020, 0x0021},  // write register enable / protection
      {0x0030, 0x0031},  // ESC write enable / protection
      {0x0040, 0x0040},  // ESC reset ECAT
      {0x0100, 0x0103},  // DL control (incl. port loop control, alias enable)
      {0x0108, 0x0109},  // physical read/write offset
      {0x0120, 0x0121},  // AL control
      {0x0138, 0x0139},  // LED overrides
      {0x0200, 0x0201},  // ECAT event mask
      {0x0300, 0x0313},  // error counters (a write clears them)
      {0x0400, 0x0401},  // watchdog divider
      {0x0410, 0x0411},  // watchdog time PDI
      {0x0420, 0x0421},  // watchdog time process data
      {0x0442, 0x0443},  // watchdog counters (a write clears them)
      {0x0500, 0x0500},  // SII configuration (ECAT/PDI ownership)
      {0x0502, 0x050F},  // SII control, address, data
      {0x0510, 0x0517},  // MII management
      {0x0600, 0x06FF},  // FMMUs
      {0x0800, 0x087F},  // SyncManagers (bytes refined below)
      {0x0900, 0x0903},  // DC receive time port 0: a write latches all ports
      {0x0910, 0x0917},  // DC system time: a write feeds the drift filter
      {0x0920, 0x092B},  // DC system time offset and delay
      {0x0930, 0x0931},  // DC speed counter start
      {0x0934, 0x0936},  // DC filter depths, receive time latch mode
      {0x0980, 0x0981},  // DC cyclic unit control, activation
      {0x0990, 0x0997},  // DC start time
      {0x09A0, 0x09A7},  // DC SYNC0/SYNC1 cycle times
      {0x09A8, 0x09A9},  // DC latch control
      {0x0F00, 0x0F03},  // digital I/O output data
      {0x0F10, 0x0F17},  // general purpose outputs
      {0x0F80, 0x0FFF},  // user RAM
  };
  // Asked for every byte a datagram writes (a broadcast reset block writes ~100 bytes into every
  // slave): one bit per register, built once from the ranges above.
  static const std::array<bool, 0x1000> kTable = [] {
    std::array<bool, 0x1000> table{};
    for (const auto& r : kWritable) {
      for (std::uint32_t a = r.first; a <= r.last; ++a)
        table[a] = true;
    }
    return table;
  }();
  return address < kTable.size() && kTable[address];
}

Esc::Esc(EscHardware hardware, std::vector<std::uint8_t> eeprom,
         std::unique_ptr<Application> application)
    : fmmu_count_(
          static_cast<std::uint8_t>(std::min<std::size_t>(hardware.fmmu_count, reg::kMaxFmmus))),
      application_(application ? std::move(application) : std::make_unique<BasicApplication>()),
      hardware_(hardware),
      memory_(kRegisterAreaEnd + static_cast<std::size_t>(hardware.ram_size_kib) * 1024u, 0),
      eeprom_(std::move(eeprom)),
      sms_(std::min<std::size_t>(hardware.sync_manager_count, reg::kMaxSyncManagers)) {
  ram_ = memory_.data();
  memory_size_ = static_cast<std::uint32_t>(memory_.size());
  if (hardware_.dc_supported) dc_ = std::make_unique<DcUnit>(*this);
  restore_hardware_refusals();
  reset_registers();
  application_->start(*this);
}

Esc::~Esc() = default;

void Esc::reset_registers() {
  std::fill(memory_.begin(), memory_.end(), std::uint8_t{0});
  wire::EscInformation info;
  info.type = hardware_.type;
  info.revision = hardware_.revision;
  info.build = hardware_.build;
  info.fmmu_count = fmmu_count_;
  info.sync_manager_count = static_cast<std::uint8_t>(sms_.size());
  info.ram_size_kib = hardware_.ram_size_kib;
  info.ports = hardware_.ports;
  info.features = hardware_.features;
  info.features.dc_supported = hardware_.dc_supported;
  info.features.dc_64bit = hardware_.dc_supported;
  const auto encoded = info.encode();
  std::memcpy(memory_.data(), encoded.data(), encoded.size());

  // Values the ESC loads from the SII EEPROM's configuration area at power-up.
  sii_busy_until_ns_ = 0;
  sii_pending_.reset();
  sii_running_ = false;
  const bool eeprom_ok = sii_load_configuration(true);
  std::uint16_t sii_status = sii_fixed_bits();
  if (!eeprom_ok) sii_status |= wire::sii_control::kChecksumError;
  // No configuration area at all: nothing answers on the I2C bus, the device information could
  // not be loaded (0x0502 bit 12). A checksum error alone leaves bit 12 clear so that the
  // EEPROM can still be read and repaired through the interface.
  if (eeprom_.size() < wire::kSiiChecksummedBytes + 2) {
    sii_status |= wire::sii_control::kDeviceInfoError;
  }
  sii_store_status(sii_status);

  // The DC system time unit is powered down when the ESC configuration enables neither the SYNC
  // out nor the latch in unit; only the port receive times remain. EL1004 in
  // soem-sdinfo-ek1100-el1004.pcapng has 0x0141 = 0x01 and answers FPRD 0x0918 with WKC 0, the
  // EK1100 (0x0D) with WKC 1. Without a loadable EEPROM the hardware default (on) stays.
  dc_system_time_ = hardware_.dc_supported &&
                    (!eeprom_ok || (memory_[reg::kEscConfiguration] & kEscConfigDcUnits) != 0);

  wire::DlStatus dl;
  dl.pdi_operational = eeprom_ok;
  // SII word 0 bit 9 (ESC configuration 0x0141 bit 1, enhanced link detection for all ports) is
  // also mapped to DL status bit 2 (ESC datasheet section I, "ESC Configuration Area"). None of
  // the shared EEPROMs and captures sets it (0x0141 = 0x0D / 0x01, DL status 0x5A31 / 0x5613).
  // A profile's `enhanced_link_detection` (what a capture's DL status or 0x0141 showed) replaces
  // the SII's bit; 0x0141 then shows it too.
  if (hardware_.enhanced_link_detection) {
    memory_[reg::kEscConfiguration] =
        static_cast<std::uint8_t>((memory_[reg::kEscConfiguration] & ~0x02) |
                                  (*hardware_.enhanced_link_detection ? 0x02 : 0));
  }
  dl.enhanced_link_detection = hardware_.enhanced_link_detection.value_or(
      eeprom_ok && (memory_[reg::kEscConfiguration] & 0x02) != 0);
  // Nothing reloads the PDI watchdog of an ESC without a PDI (PDI control 0): the EK1100
  // (0x0140 = 0x00) reports DL status 0x5A31 in the replay captures, terminals with a PDI 0x..33.
  dl.pdi_watchdog_ok = !eeprom_ok || memory_[reg::kPdiControl] != 0;
  wire::store_le16(&memory_[reg::kDlStatus], dl.encode());
  // DL control keeps its reset value until the master writes it (ESC datasheet section II,
  // 0x0100..0x0103; esc_type_defaults()).
  wire::store_le32(&memory_[reg::kDlControl], hardware_.dl_control);

  wire::store_le16(&memory_[reg::kAlStatus], static_cast<std::uint16_t>(wire::AlState::init));
  // 100 us ticks, 100 ms for both watchdogs.
  wire::store_le16(&memory_[reg::kWatchdogDivider], wire::ProcessDataWatchdog::kDefaultDivider);
  wire::store_le16(&memory_[reg::kWatchdogTimePdi], wire::ProcessDataWatchdog::kDefaultTicks);
  wire::store_le16(&memory_[reg::kWatchdogTimeProcessData],
                   wire::ProcessDataWatchdog::kDefaultTicks);
  wire::store_le16(&memory_[reg::kWatchdogStatus], 0x0001);

  for (auto& sm : sms_)
    sm = SyncManagerState{};
  for (std::size_t i = 0; i < sms_.size(); ++i)
    update_sm_status(i);
  for (auto& f : fmmus_)
    f = wire::FmmuConfig{};
  active_fmmus_ = 0;
  rebuild_sm_areas();
  last_mailbox_reply_.clear();
  if (dc_) dc_->reset();
  if (layout_observer_ != nullptr) layout_observer_->esc_layout_changed(layout_tag_);
}

void Esc::layout_written(std::uint32_t first, std::uint32_t last) {
  if (layout_observer_ == nullptr) return;
  if (overlaps(first, last, reg::kStationAddress, 4) || overlaps(first, last, reg::kDlControl, 4) ||
      overlaps(first, last, reg::kFmmuBase, reg::kFmmuSize * reg::kMaxFmmus)) {
    layout_observer_->esc_layout_changed(layout_tag_);
  }
  if (overlaps(first, last, reg::kDlPortControl, 1)) {
    layout_observer_->esc_port_control_written(layout_tag_);
  }
}

void Esc::power_cycle(std::int64_t now_ns) {
  now_ns_ = now_ns;
  restore_hardware_refusals();
  reset_registers();
  application_->start(*this);
}

void Esc::set_al_refusal(wire::AlState state, std::optional<std::uint16_t> status_code) {
  auto& slot = al_refusals_[static_cast<std::size_t>(state) & 0x0F];
  slot = status_code;
  if (status_code) return;
  // Lifting an injected refusal leaves the device's own (EscHardware::al_refusals).
  for (const auto& [refused, code] : hardware_.al_refusals) {
    if (refused == state) slot = code;
  }
}

void Esc::restore_hardware_refusals() {
  al_refusals_.fill(std::nullopt);
  for (const auto& [state, code] : hardware_.al_refusals) {
    al_refusals_[static_cast<std::size_t>(state) & 0x0F] = code;
  }
}

std::optional<std::uint16_t> Esc::al_refusal(wire::AlState state) const noexcept {
  return al_refusals_[static_cast<std::size_t>(state) & 0x0F];
}

void Esc::advance(std::int64_t now_ns) {
  if (now_ns > now_ns_) now_ns_ = now_ns;
  sii_finish_if_due();
  // The segment advances every ESC before each frame: the SII write enable (0x0502 bit 0) is
  // self-clearing at the start of the next frame (ESC datasheet section II, 0x0502).
  // (Stored only when the register or the bit differ: the segment advances every ESC per frame.)
  // (sii_register_stale_ instead of comparing the register: its cache line stays untouched.)
  const auto sii_status =
      static_cast<std::uint16_t>(sii_status_ & ~wire::sii_control::kWriteEnable);
  if (sii_status != sii_status_ || sii_register_stale_) sii_store_status(sii_status);
  // Process-data watchdog: an output SyncManager with the watchdog trigger enabled that sees no
  // complete write for the watchdog time expires (status bit 0 -> 0, counter + 1).
  std::optional<std::int64_t> timeout_ns;  // read when an SM needs it
  for (std::uint32_t bits = watchdog_sms_; bits != 0; bits &= bits - 1) {
    const auto& sm = sms_[static_cast<std::size_t>(std::countr_zero(bits))];
    if (!timeout_ns) {
      const auto watchdog = process_data_watchdog();
      if (watchdog.off()) break;
      timeout_ns = watchdog.time().count();
    }
    if ((read_u16(reg::kWatchdogStatus) & 1) != 0 && now_ns_ - sm.last_write_ns > *timeout_ns) {
      wire::store_le16(&memory_[reg::kWatchdogStatus], 0);
      memory_[reg::kWatchdogCounterProcessData] =
          static_cast<std::uint8_t>(std::min(255, memory_[reg::kWatchdogCounterProcessData] + 1));
    }
  }
  if (dc_) dc_->advance(now_ns_);
  application_->advance(*this, now_ns_);
}

bool Esc::advance_due(std::int64_t now_ns) const noexcept {
  if (sii_running_ || (sii_status_ & wire::sii_control::kWriteEnable) != 0 || sii_register_stale_) {
    return true;
  }
  // A running process-data watchdog (status bit 0 set) that expires by now_ns (as advance()).
  const std::int64_t now = std::max(now_ns, now_ns_);
  for (std::uint32_t bits = watchdog_sms_; bits != 0; bits &= bits - 1) {
    const auto& sm = sms_[static_cast<std::size_t>(std::countr_zero(bits))];
    if ((read_u16(reg::kWatchdogStatus) & 1) == 0) break;
    const auto watchdog = process_data_watchdog();
    if (watchdog.off()) break;
    if (now - sm.last_write_ns > watchdog.time().count()) return true;
  }
  if (dc_ && (dc_->sync_state() == SyncUnitState::waiting ||
              dc_->sync_state() == SyncUnitState::running)) {
    return true;
  }
  return application_->wants_advance(*this, now);
}

// ---------------------------------------------------------------------------------------------
// Datagram processing

bool Esc::matches_station(std::uint16_t adp) const noexcept {
  if (adp == station_address()) return true;
  const bool alias_enabled = (memory_[reg::kDlAliasControl] & 0x01) != 0;
  return alias_enabled && adp == station_alias();
}

void Esc::pass_by(const PassContext& pass) {
  if (pass.epu_time_ns > now_ns_) now_ns_ = pass.epu_time_ns;
  sii_finish_if_due();
  if (dc_) dc_->on_datagram(pass);
}

DatagramEffect Esc::process(DatagramInFlight& d, const PassContext& pass) {
  pass_by(pass);
  DatagramEffect effect;
  auto count = [&](AccessResult r, bool read_write) {
    std::uint16_t add = 0;
    if (read_write) {
      add = static_cast<std::uint16_t>((r.read ? 1 : 0) + (r.written ? 2 : 0));
    } else {
      add = (r.read || r.written) ? 1 : 0;
    }
    d.wkc = static_cast<std::uint16_t>(d.wkc + add);
    effect.wkc_added = add;
  };
  const std::uint16_t adp = d.adp();
  switch (d.command) {
    case Command::nop:
      break;
    case Command::aprd:
    case Command::apwr:
    case Command::aprw: {
      d.set_adp(static_cast<std::uint16_t>(adp + 1));
      if (adp != 0) break;
      effect.addressed = true;
      const bool rd = d.command != Command::apwr;
      const bool wr = d.command != Command::aprd;
      count(access(d.ado(), d.data, rd, wr, false, pass), rd && wr);
      break;
    }
    case Command::fprd:
    case Command::fpwr:
    case Command::fprw: {
      if (!matches_station(adp)) break;
      effect.addressed = true;
      const bool rd = d.command != Command::fpwr;
      const bool wr = d.command != Command::fprd;
      count(access(d.ado(), d.data, rd, wr, false, pass), rd && wr);
      break;
    }
    case Command::brd:
    case Command::bwr:
    case Command::brw: {
      d.set_adp(static_cast<std::uint16_t>(adp + 1));
      effect.addressed = true;
      const bool rd = d.command != Command::bwr;
      const bool wr = d.command != Command::brd;
      count(access(d.ado(), d.data, rd, wr, true, pass), rd && wr);
      break;
    }
    case Command::armw: {
      d.set_adp(static_cast<std::uint16_t>(adp + 1));
      effect.addressed = true;
      const bool rd = adp == 0;
      count(access(d.ado(), d.data, rd, !rd, false, pass), false);
      break;
    }
    case Command::frmw: {
      effect.addressed = true;
      const bool rd = matches_station(adp);
      count(access(d.ado(), d.data, rd, !rd, false, pass), false);
      break;
    }
    case Command::lrd:
    case Command::lwr:
    case Command::lrw: {
      const bool rd = d.command != Command::lwr;
      const bool wr = d.command != Command::lrd;
      const AccessResult r = logical(d, rd, wr, pass);
      effect.addressed = r.read || r.written;
      count(r, d.command == Command::lrw);
      break;
    }
  }
  return effect;
}

Esc::AccessResult Esc::access(std::uint32_t address, std::span<std::uint8_t> data, bool do_read,
                              bool do_write, bool or_into_data, const PassContext& pass) {
  AccessResult result;
  if (data.empty()) return result;
  // Read-write commands read the old contents and write what the master sent, so keep a copy of
  // the incoming data before the read overwrites it (only its first n bytes are ever used: not
  // zeroed, as a datagram of a few bytes would otherwise clear a frame's worth per slave).
  std::array<std::uint8_t, kMaxDatagram> incoming;
  const std::size_t n = std::min(data.size(), incoming.size());
  if (do_write && do_read) std::memcpy(incoming.data(), data.data(), n);
  if (do_read) result.read = physical_read(address, data.first(n), nullptr, or_into_data).read;
  if (do_write) {
    std::span<const std::uint8_t> in =
        do_read ? std::span<const std::uint8_t>(incoming.data(), n) : data.first(n);
    result.written = physical_write(address, in, nullptr, pass).written;
  }
  return result;
}

Esc::AccessResult Esc::logical(DatagramInFlight& d, bool do_read, bool do_write,
                               const PassContext& pass) {
  // The result is built from two locals at the end: kept in a struct on the stack, its two
  // bytes were stored one at a time and loaded as one word, a load that cannot be forwarded from
  // the store buffer and so waited for every store before it (the RAM window's, a cache miss)
  // to reach the cache, which serialised the slaves' RAM misses.
  bool any_read = false;
  bool any_written = false;
  const std::uint64_t first_bit = static_cast<std::uint64_t>(d.address) * 8;
  const std::uint64_t end_bit = first_bit + d.data.size() * 8;  // exclusive
  for (std::uint32_t bits = active_fmmus_; bits != 0; bits &= bits - 1) {
    const wire::FmmuConfig& f = fmmus_[static_cast<std::size_t>(std::countr_zero(bits))];
    const bool f_reads = f.type == wire::FmmuType::read || f.type == wire::FmmuType::read_write;
    const bool f_writes = f.type == wire::FmmuType::write || f.type == wire::FmmuType::read_write;
    const bool reading = do_read && f_reads;
    const bool writing = do_write && f_writes;
    if (!reading && !writing) continue;
    const std::uint64_t f_first =
        static_cast<std::uint64_t>(f.logical_start) * 8 + f.logical_start_bit;
    const std::uint64_t f_end =
        (static_cast<std::uint64_t>(f.logical_start) + f.length - 1) * 8 + f.logical_stop_bit + 1;
    if (f_end <= f_first) continue;
    const std::uint64_t lo = std::max(first_bit, f_first);
    const std::uint64_t hi = std::min(end_bit, f_end);
    if (lo >= hi) continue;
    // Physical bit of logical bit b: phys_first + (b - f_first).
    const std::uint64_t phys_first =
        static_cast<std::uint64_t>(f.physical_start) * 8 + f.physical_start_bit;
    const std::uint64_t p_lo = phys_first + (lo - f_first);
    const std::uint64_t p_hi = phys_first + (hi - f_first);  // exclusive
    const auto p_byte = static_cast<std::uint32_t>(p_lo / 8);
    const std::size_t p_bytes = static_cast<std::size_t>((p_hi + 7) / 8 - p_lo / 8);
    if (p_bytes > kMaxDatagram) continue;

    const bool aligned = (lo % 8 == 0) && (hi % 8 == 0) && (p_lo % 8 == 0);
    const std::size_t d_offset = static_cast<std::size_t>((lo - first_bit) / 8);
    if (aligned) {
      auto window = d.data.subspan(d_offset, p_bytes);
      if (p_byte >= kRegisterAreaEnd && p_byte + p_bytes <= memory_size_ &&
          !sm_overlaps(p_byte, p_byte + static_cast<std::uint32_t>(p_bytes))) {
        // Process RAM outside every SyncManager (physical_read's and physical_write's fast
        // path, taken here without the copy of the incoming bytes): a read-write swaps.
        std::uint8_t* ram = ram_ + p_byte;
        if (reading && writing) {
          for (std::size_t k = 0; k < p_bytes; ++k)
            std::swap(ram[k], window[k]);
        } else if (reading) {
          copy_bytes(window.data(), ram, p_bytes);
        } else {
          copy_bytes(ram, window.data(), p_bytes);
        }
        any_read |= reading;
        any_written |= writing;
        continue;
      }
      if (reading && writing) {
        // Only the window's p_bytes are copied and used.
        std::array<std::uint8_t, kMaxDatagram> incoming;
        copy_bytes(incoming.data(), window.data(), p_bytes);
        any_read |= physical_read(p_byte, window, nullptr, false).read;
        any_written |=
            physical_write(p_byte, std::span<const std::uint8_t>(incoming.data(), p_bytes), nullptr,
                           pass)
                .written;
      } else if (reading) {
        any_read |= physical_read(p_byte, window, nullptr, false).read;
      } else {
        any_written |= physical_write(p_byte, window, nullptr, pass).written;
      }
      continue;
    }

    // Bit-granular mapping: gather the physical bytes, move single bits, scatter back. Only the
    // p_bytes physical bytes and the datagram bytes holding logical bits lo..hi are touched, so
    // only those are cleared or copied (a slave's share, not the whole datagram).
    std::array<std::uint8_t, kMaxDatagram> phys;
    std::array<std::uint8_t, kMaxDatagram> mask;
    std::array<std::uint8_t, kMaxDatagram> incoming;
    std::memset(phys.data(), 0, p_bytes);
    std::memset(mask.data(), 0, p_bytes);
    {
      const auto d_first = static_cast<std::size_t>((lo - first_bit) / 8);
      const auto d_end = static_cast<std::size_t>((hi - first_bit + 7) / 8);
      std::memcpy(incoming.data() + d_first, d.data.data() + d_first, d_end - d_first);
    }
    auto bit_of = [](const std::uint8_t* bytes, std::uint64_t bit) {
      return (bytes[bit / 8] >> (bit % 8)) & 1;
    };
    if (reading) {
      const AccessResult r =
          physical_read(p_byte, std::span<std::uint8_t>(phys.data(), p_bytes), nullptr, false);
      if (r.read) {
        any_read = true;
        for (std::uint64_t b = lo; b < hi; ++b) {
          const std::uint64_t pb = p_lo + (b - lo) - static_cast<std::uint64_t>(p_byte) * 8;
          const std::uint64_t db = b - first_bit;
          const auto bit = static_cast<std::uint8_t>(1u << (db % 8));
          if (bit_of(phys.data(), pb) != 0) {
            d.data[db / 8] = static_cast<std::uint8_t>(d.data[db / 8] | bit);
          } else {
            d.data[db / 8] = static_cast<std::uint8_t>(d.data[db / 8] & ~bit);
          }
        }
      }
    }
    if (writing) {
      std::fill(phys.begin(), phys.begin() + static_cast<std::ptrdiff_t>(p_bytes), 0);
      for (std::uint64_t b = lo; b < hi; ++b) {
        const std::uint64_t pb = p_lo + (b - lo) - static_cast<std::uint64_t>(p_byte) * 8;
        const std::uint64_t db = b - first_bit;
        const auto bit = static_cast<std::uint8_t>(1u << (pb % 8));
        mask[pb / 8] = static_cast<std::uint8_t>(mask[pb / 8] | bit);
        if (bit_of(incoming.data(), db) != 0) {
          phys[pb / 8] = static_cast<std::uint8_t>(phys[pb / 8] | bit);
        }
      }
      any_written |= physical_write(p_byte, std::span<const std::uint8_t>(phys.data(), p_bytes),
                                    mask.data(), pass)
                         .written;
    }
  }
  AccessResult result;
  result.read = any_read;
  result.written = any_written;
  return result;
}

int Esc::sm_index_for(std::uint32_t address) const noexcept {
  for (std::size_t i = 0; i < sm_area_count_; ++i) {
    const SmArea& area = sm_areas_[i];
    if (address >= area.start && address < area.end) return static_cast<int>(area.index);
  }
  return -1;
}

bool Esc::sm_overlaps(std::uint32_t first, std::uint32_t end) const noexcept {
  for (std::size_t i = 0; i < sm_area_count_; ++i) {
    if (sm_areas_[i].start < end && sm_areas_[i].end > first) return true;
  }
  return false;
}

void Esc::rebuild_sm_areas() noexcept {
  sm_area_count_ = 0;
  watchdog_sms_ = 0;
  for (std::size_t i = 0; i < sms_.size() && i < sm_areas_.size(); ++i) {
    const auto& sm = sms_[i];
    if (!sm.enabled) continue;
    if (sm.config.length > 0) {
      sm_areas_[sm_area_count_++] =
          SmArea{sm.config.physical_start,
                 static_cast<std::uint32_t>(sm.config.physical_start) + sm.config.length,
                 static_cast<std::uint32_t>(i)};
    }
    if (sm.config.control.watchdog && sm.config.control.direction == wire::SmDirection::write) {
      watchdog_sms_ |= 1u << i;
    }
  }
}

Esc::AccessResult Esc::physical_read(std::uint32_t address, std::span<std::uint8_t> out,
                                     const std::uint8_t* mask, bool or_into_data) {
  AccessResult result;
  const std::uint32_t end = address + static_cast<std::uint32_t>(out.size());
  if (address >= kRegisterAreaEnd && end <= memory_size_ && !sm_overlaps(address, end)) {
    // Process RAM outside every SyncManager (a plain FMMU window): no register semantics, no
    // buffer handshake, nothing else to look at.
    if (out.empty()) return result;
    const std::uint8_t* from = ram_ + address;
    if (or_into_data) {
      for (std::size_t k = 0; k < out.size(); ++k)
        out[k] = static_cast<std::uint8_t>(out[k] | from[k]);
    } else if (mask == nullptr) {
      copy_bytes(out.data(), from, out.size());
    } else {
      for (std::size_t k = 0; k < out.size(); ++k)
        out[k] = masked(out[k], from[k], mask, k);
    }
    result.read = true;
    return result;
  }
  if (address < kRegisterAreaEnd) refresh_registers_for_read(address, out.size());
  std::uint32_t pos = address;
  while (pos < end) {
    const std::size_t i = pos - address;
    if (pos >= memory_.size()) break;  // beyond the implemented RAM: not accessible
    const int sm_index = pos >= kSyncManagerAreaStart ? sm_index_for(pos) : -1;
    std::uint32_t run_end =
        std::min<std::uint32_t>(end, static_cast<std::uint32_t>(memory_.size()));
    if (sm_index < 0) {
      // Up to the next SyncManager area that starts inside the range.
      for (std::size_t s = 0; s < sm_area_count_; ++s) {
        if (sm_areas_[s].start > pos && sm_areas_[s].start < run_end) run_end = sm_areas_[s].start;
      }
      for (std::uint32_t a = pos; a < run_end; ++a) {
        // Bytes the ESC does not have leave the datagram alone and do not count.
        if (a < kRegisterAreaEnd && !register_implemented(a)) continue;
        const std::uint8_t v = memory_[a];
        const std::size_t k = a - address;
        out[k] = or_into_data ? static_cast<std::uint8_t>(out[k] | v) : masked(out[k], v, mask, k);
        result.read = true;
      }
      pos = run_end;
      continue;
    }
    auto& sm = sms_[static_cast<std::size_t>(sm_index)];
    const std::uint32_t sm_start = sm.config.physical_start;
    const std::uint32_t sm_end = sm_start + sm.config.length;
    run_end = std::min(run_end, sm_end);
    const bool covers_first = pos == sm_start;
    const bool covers_last = run_end == sm_end;
    const bool deactivated = sm.config.pdi_control.deactivate;
    const bool mailbox = sm.config.control.mode == wire::SmMode::mailbox;
    const bool ecat_reads = sm.config.control.direction == wire::SmDirection::read;
    bool allowed = !deactivated;
    if (mailbox) allowed = allowed && ecat_reads && sm.mailbox_full;
    if (allowed && !mailbox && ecat_reads && covers_first) {
      application_->before_buffer_read(*this, static_cast<std::size_t>(sm_index));
    }
    if (allowed) {
      for (std::uint32_t a = pos; a < run_end; ++a) {
        const std::uint8_t v = memory_[a];
        const std::size_t k = a - address;
        out[k] = or_into_data ? static_cast<std::uint8_t>(out[k] | v) : masked(out[k], v, mask, k);
      }
      result.read = true;
      if (ecat_reads) {
        if (covers_first) sm.read_open = true;
        if (covers_last && sm.read_open) {
          sm.read_open = false;
          ++sm.buffers_read;
          if (mailbox) sm.mailbox_full = false;
          sm.config.status.interrupt_read = true;
          sm.config.status.interrupt_write = false;
          update_sm_status(static_cast<std::size_t>(sm_index));
          application_->on_buffer_read(*this, static_cast<std::size_t>(sm_index));
        } else {
          update_sm_status(static_cast<std::size_t>(sm_index));
        }
      }
    }
    (void)i;
    pos = run_end;
  }
  const std::uint32_t dc_end = dc_system_time_ ? kDcBase + kDcSize : kDcReceiveTimesEnd;
  if (dc_ && address < kRegisterAreaEnd && overlaps(address, end - 1, kDcBase, dc_end - kDcBase)) {
    dc_->after_read(static_cast<std::uint16_t>(std::max<std::uint32_t>(address, kDcBase)),
                    static_cast<std::uint16_t>(std::min<std::uint32_t>(end - 1, dc_end - 1)));
  }
  return result;
}

Esc::AccessResult Esc::physical_write(std::uint32_t address, std::span<const std::uint8_t> in,
                                      const std::uint8_t* mask, const PassContext& pass) {
  AccessResult result;
  const std::uint32_t end = address + static_cast<std::uint32_t>(in.size());
  if (address >= kRegisterAreaEnd && end <= memory_size_ && !sm_overlaps(address, end)) {
    // Process RAM outside every SyncManager: written as it comes (physical_read's fast path).
    if (in.empty()) return result;
    std::uint8_t* to = ram_ + address;
    if (mask == nullptr) {
      copy_bytes(to, in.data(), in.size());
    } else {
      for (std::size_t k = 0; k < in.size(); ++k)
        to[k] = masked(to[k], in[k], mask, k);
    }
    result.written = true;
    return result;
  }
  std::uint32_t pos = address;
  while (pos < end) {
    if (pos >= memory_.size()) break;
    const int sm_index = pos >= kSyncManagerAreaStart ? sm_index_for(pos) : -1;
    std::uint32_t run_end =
        std::min<std::uint32_t>(end, static_cast<std::uint32_t>(memory_.size()));
    if (sm_index < 0) {
      for (std::size_t s = 0; s < sm_area_count_; ++s) {
        if (sm_areas_[s].start > pos && sm_areas_[s].start < run_end) run_end = sm_areas_[s].start;
      }
      if (pos < kRegisterAreaEnd) {
        // Registers outside any SyncManager keep their ECAT write permissions.
        run_end = std::min(run_end, kRegisterAreaEnd);
        const std::size_t k = pos - address;
        if (register_write(pos, in.subspan(k, run_end - pos), mask != nullptr ? mask + k : nullptr,
                           pass)) {
          result.written = true;
        }
      } else {
        for (std::uint32_t a = pos; a < run_end; ++a) {
          memory_[a] = masked(memory_[a], in[a - address], mask, a - address);
        }
        result.written = true;
      }
      pos = run_end;
      continue;
    }
    const auto index = static_cast<std::size_t>(sm_index);
    auto& sm = sms_[index];
    const std::uint32_t sm_start = sm.config.physical_start;
    const std::uint32_t sm_end = sm_start + sm.config.length;
    run_end = std::min(run_end, sm_end);
    const bool covers_first = pos == sm_start;
    const bool covers_last = run_end == sm_end;
    const bool mailbox = sm.config.control.mode == wire::SmMode::mailbox;
    const bool ecat_writes = sm.config.control.direction == wire::SmDirection::write;
    bool allowed = ecat_writes && !sm.config.pdi_control.deactivate;
    if (mailbox) allowed = allowed && !sm.mailbox_full;
    if (allowed) {
      if (covers_first) {
        sm.write_open = true;
        if (!mailbox) {
          // The producer's buffer starts as the last complete one, so partial (bit-masked)
          // writes keep the bits they do not touch.
          sm.shadow.assign(memory_.begin() + sm_start, memory_.begin() + sm_end);
        }
      }
      for (std::uint32_t a = pos; a < run_end; ++a) {
        const std::size_t k = a - address;
        if (mailbox) {
          memory_[a] = masked(memory_[a], in[k], mask, k);
        } else if (sm.shadow.size() == sm.config.length) {
          auto& byte = sm.shadow[a - sm_start];
          byte = masked(byte, in[k], mask, k);
        }
      }
      result.written = true;
      if (covers_last && sm.write_open) {
        sm.write_open = false;
        if (!mailbox && sm.shadow.size() == sm.config.length) {
          std::copy(sm.shadow.begin(), sm.shadow.end(), memory_.begin() + sm_start);
          sm.config.status.buffer_state = static_cast<std::uint8_t>((sm.buffers_written + 1) % 3);
        }
        if (mailbox) sm.mailbox_full = true;
        ++sm.buffers_written;
        sm.last_write_ns = pass.epu_time_ns;
        sm.config.status.interrupt_write = true;
        sm.config.status.interrupt_read = false;
        if (sm.config.control.watchdog) {
          wire::store_le16(&memory_[reg::kWatchdogStatus], 0x0001);  // retriggered
        }
        update_sm_status(index);
        application_->on_buffer_written(*this, index);
      } else {
        update_sm_status(index);
      }
    }
    pos = run_end;
  }
  return result;
}

bool Esc::register_write(std::uint32_t address, std::span<const std::uint8_t> in,
                         const std::uint8_t* mask, const PassContext& pass) {
  const std::uint32_t first = address;
  const std::uint32_t last = address + static_cast<std::uint32_t>(in.size()) - 1;
  std::array<std::uint8_t, 8> unused{};
  bool any_writable = false;
  for (std::uint32_t a = first; a <= last; ++a) {
    const auto r = static_cast<std::uint16_t>(a);
    if (!ecat_may_write_register(r) || !register_implemented(a)) continue;
    any_writable = true;
    if (in_range(a, reg::kSyncManagerBase, reg::kSyncManagerSize * reg::kMaxSyncManagers)) {
      const std::size_t sm = (a - reg::kSyncManagerBase) / reg::kSyncManagerSize;
      const std::size_t byte = (a - reg::kSyncManagerBase) % reg::kSyncManagerSize;
      if (sm >= sms_.size()) continue;
      if (byte == reg::kSyncManagerStatusOffset || byte == reg::kSyncManagerPdiControlOffset) {
        continue;  // written by the ESC / the PDI only
      }
      // Start, length and control can only change while the SyncManager is disabled.
      if (byte < reg::kSyncManagerStatusOffset && sms_[sm].enabled) continue;
    }
    memory_[a] = masked(memory_[a], in[a - first], mask, a - first);
  }
  if (any_writable) after_register_write(first, last, pass, unused);
  return any_writable;
}

bool Esc::register_implemented(std::uint32_t address) const noexcept {
  if (in_range(address, reg::kFmmuBase, reg::kFmmuSize * reg::kMaxFmmus)) {
    return (address - reg::kFmmuBase) / reg::kFmmuSize < fmmu_count_;
  }
  if (in_range(address, reg::kSyncManagerBase, 0x100)) {  // 0x0880..0x08FF: reserved
    return (address - reg::kSyncManagerBase) / reg::kSyncManagerSize < sms_.size();
  }
  if (in_range(address, kDcBase, kDcSize)) {
    return hardware_.dc_supported && (address < kDcReceiveTimesEnd || dc_system_time_);
  }
  return true;
}

void Esc::after_register_write(std::uint32_t first, std::uint32_t last, const PassContext& pass,
                               const std::array<std::uint8_t, 8>& /*sm_activate_before*/) {
  if (overlaps(first, last, reg::kRxErrorCounter, 0x0C)) {
    // A write to any RX error counter clears all of them.
    std::fill(memory_.begin() + reg::kRxErrorCounter, memory_.begin() + reg::kRxErrorCounter + 0x0C,
              std::uint8_t{0});
  }
  for (std::uint16_t r = reg::kProcessingUnitError; r < reg::kLostLink + 4; ++r) {
    if (overlaps(first, last, r, 1)) memory_[r] = 0;
  }
  for (std::uint16_t r : {reg::kWatchdogCounterProcessData, reg::kWatchdogCounterPdi}) {
    if (overlaps(first, last, r, 1)) memory_[r] = 0;
  }
  for (std::size_t i = 0; i < fmmu_count_; ++i) {
    if (!overlaps(first, last, reg::fmmu(i), reg::kFmmuSize)) continue;
    auto decoded = wire::FmmuConfig::decode(wire::Bytes(&memory_[reg::fmmu(i)], reg::kFmmuSize));
    // A configuration the FMMU cannot represent (bit numbers > 7) leaves it inactive.
    fmmus_[i] = decoded ? *decoded : wire::FmmuConfig{};
    const std::uint32_t bit = 1u << i;
    active_fmmus_ =
        fmmus_[i].active && fmmus_[i].length != 0 ? active_fmmus_ | bit : active_fmmus_ & ~bit;
  }
  layout_written(first, last);
  for (std::size_t i = 0; i < sms_.size(); ++i) {
    if (!overlaps(first, last, reg::sync_manager(i), reg::kSyncManagerSize)) continue;
    sync_manager_written(i, sms_[i].enabled);
  }
  if (overlaps(first, last, reg::kSiiAccess, 1)) sii_access_written();
  if (overlaps(first, last, reg::kSiiControl, 2)) sii_control_written(first, last);
  const std::uint32_t dc_end = dc_system_time_ ? kDcBase + kDcSize : kDcReceiveTimesEnd;
  if (dc_ && overlaps(first, last, kDcBase, dc_end - kDcBase)) {
    dc_->on_write(static_cast<std::uint16_t>(std::max<std::uint32_t>(first, kDcBase)),
                  static_cast<std::uint16_t>(std::min<std::uint32_t>(last, dc_end - 1)), pass);
  }
  if (overlaps(first, last, reg::kAlControl, 2)) {
    const std::uint16_t control = read_u16(reg::kAlControl);
    const auto requested = wire::al_state_from_code(static_cast<std::uint8_t>(control & 0x0F));
    if (requested && *requested != al_state()) {
      if (const auto code = al_refusal(*requested)) {
        // The firmware refuses the state (refuse_state): it stays where it is, error flagged.
        pdi_set_al_status(al_state(), true, *code);
        return;
      }
    }
    if ((memory_[reg::kEscConfiguration] & kEscConfigDeviceEmulation) != 0) {
      // Device emulation: the ESC itself copies AL control into AL status, error acknowledge bit
      // included (BWR 0x0120 = 0x0011 reads back as AL status 0x0011 from EK1100, EL2828 and
      // EL2889 in replay-ek1100-el2828-el2889.pcapng). Firmware on the PDI may still overwrite it.
      memory_[reg::kAlStatus] = memory_[reg::kAlControl];
      memory_[reg::kAlStatus + 1] = memory_[reg::kAlControl + 1];
    }
    application_->on_al_control(*this, read_u16(reg::kAlControl));
    apply_id_request(read_u16(reg::kAlControl));
  }
}

void Esc::apply_id_request(std::uint16_t control) noexcept {
  if (!hardware_.device_id) return;
  constexpr std::uint8_t kIdLoaded = 0x20;  // AL status bit 5
  if ((control & wire::kAlControlIdRequest) != 0 && !al_error()) {
    memory_[reg::kAlStatus] = static_cast<std::uint8_t>(memory_[reg::kAlStatus] | kIdLoaded);
    wire::store_le16(&memory_[reg::kAlStatusCode], *hardware_.device_id);
  } else if ((control & wire::kAlControlIdRequest) == 0 &&
             (memory_[reg::kAlStatus] & kIdLoaded) != 0) {
    memory_[reg::kAlStatus] = static_cast<std::uint8_t>(memory_[reg::kAlStatus] & ~kIdLoaded);
    if (!al_error()) wire::store_le16(&memory_[reg::kAlStatusCode], 0);
  }
}

void Esc::sync_manager_written(std::size_t index, bool was_enabled) {
  auto& sm = sms_[index];
  const std::uint16_t base = reg::sync_manager(index);
  const bool old_repeat = sm.config.activate.repeat_request;
  const auto old_config = sm.config;
  sm.config.physical_start = read_u16(base);
  sm.config.length = read_u16(base + 2);
  auto control = wire::SmControl::decode(memory_[base + 4]);
  sm.config.control = control ? *control : wire::SmControl{};
  sm.config.activate = wire::SmActivate::decode(memory_[base + reg::kSyncManagerActivateOffset]);
  const bool enable =
      sm.config.activate.enable && sm.config.length > 0 && control.ok() &&
      sm.config.physical_start >= kSyncManagerAreaStart &&
      static_cast<std::size_t>(sm.config.physical_start) + sm.config.length <= memory_.size();
  if (enable && !was_enabled) {
    sm.enabled = true;
    sm.mailbox_full = false;
    sm.write_open = false;
    sm.read_open = false;
    sm.shadow.clear();
    sm.last_write_ns = now_ns_;
    sm.config.status = wire::SmStatus{};
  } else if (!enable && was_enabled) {
    sm.enabled = false;
    sm.mailbox_full = false;
    sm.write_open = false;
    sm.read_open = false;
    sm.config.status = wire::SmStatus{};
  }
  rebuild_sm_areas();
  update_sm_status(index);
  if (sm.enabled && sm.config.activate.repeat_request != old_repeat &&
      sm.config.control.mode == wire::SmMode::mailbox) {
    application_->on_mailbox_repeat(*this, index);
  }
  if (sm.enabled != was_enabled ||
      !(old_config.physical_start == sm.config.physical_start &&
        old_config.length == sm.config.length && old_config.control == sm.config.control)) {
    application_->on_sync_manager_changed(*this, index);
  }
}

void Esc::update_sm_status(std::size_t index) {
  auto& sm = sms_[index];
  sm.config.status.mailbox_full =
      sm.config.control.mode == wire::SmMode::mailbox && sm.mailbox_full;
  sm.config.status.write_buffer_open = sm.write_open;
  sm.config.status.read_buffer_open = sm.read_open;
  const std::uint16_t base = reg::sync_manager(index);
  memory_[base + reg::kSyncManagerStatusOffset] = sm.config.status.encode();
  memory_[base + reg::kSyncManagerPdiControlOffset] = sm.config.pdi_control.encode();
}

void Esc::refresh_registers_for_read(std::uint32_t address, std::size_t length) {
  const std::uint32_t first = address;
  const std::uint32_t last = address + static_cast<std::uint32_t>(length) - 1;
  const std::uint32_t dc_end = dc_system_time_ ? kDcBase + kDcSize : kDcReceiveTimesEnd;
  if (dc_ && overlaps(first, last, kDcBase, dc_end - kDcBase)) {
    dc_->refresh(static_cast<std::uint16_t>(std::max<std::uint32_t>(first, kDcBase)),
                 static_cast<std::uint16_t>(std::min<std::uint32_t>(last, dc_end - 1)), now_ns_);
  }
}

// ---------------------------------------------------------------------------------------------
// SII EEPROM interface

// The interface as the ESC datasheets (section II, registers 0x0500..0x050F) describe it:
//   - 0x0502 bit 0 (write enable) is latched from the master's write and self-clearing: at the
//     start of the next frame (Esc::advance) and when a command consumed it;
//   - bits 8..10 (command) and 15 (busy) read back while a command runs and clear when it ends
//     (0x8140 then 0x0040 after FPWR 0x0502 = 0x0100 from the EK1100 in
//     replay-ek1100-el2828-el2889.pcapng);
//   - a write while busy is ignored, and so is a command while the acknowledge/command error
//     (bit 13) is pending; the NOP command clears bits 13 and 14;
//   - bit 14 (write enable error): a write command without write enable; it does not start;
//   - bit 13: the EEPROM did not acknowledge (an address beyond the EEPROM, an injected NACK) or
//     the command is invalid (anything but 0, 1, 2, 4 in bits 8..10);
//   - bit 11 (checksum error) and bit 12 (device information not loaded) report the last load of
//     the configuration area (power-up or reload command); bits 6 and 7 are hardware facts.
// The EEPROM itself is non-volatile: a write lands in eeprom_ when its write cycle ends and
// survives power_cycle; the registers loaded from it change at the next power-up (or reload).

std::uint16_t Esc::sii_fixed_bits() const noexcept {
  namespace sc = wire::sii_control;
  const bool two_bytes =
      hardware_.sii_two_address_bytes.value_or(eeprom_.size() > kOneAddressByteEepromBytes);
  return static_cast<std::uint16_t>((hardware_.sii_emulation ? sc::kEmulation : 0) |
                                    (hardware_.sii_reads_8_bytes ? sc::kReadSize8 : 0) |
                                    (two_bytes ? sc::kTwoAddressBytes : 0));
}

bool Esc::sii_load_configuration(bool power_up) {
  if (eeprom_.size() < wire::kSiiChecksummedBytes + 2 ||
      wire::sii_crc8(wire::Bytes(eeprom_).first(wire::kSiiChecksummedBytes)) !=
          eeprom_[wire::kSiiChecksummedBytes]) {
    return false;
  }
  auto eeprom_word = [&](std::size_t word) -> std::uint16_t {
    return wire::load_le16(&eeprom_[word * 2]);
  };
  const std::uint16_t word0 = eeprom_word(wire::sii_word::kPdiControl);
  if (power_up) {
    wire::store_le16(&memory_[reg::kPdiControl], word0);  // PDI control + ESC configuration
    wire::store_le16(&memory_[reg::kStationAlias], eeprom_word(wire::sii_word::kStationAlias));
  } else {
    // A reload transfers neither the station alias nor the enhanced-link-detection bits of the
    // ESC configuration (0x0141 bits 1, 4..7): they are taken at power-up or reset only (ESC
    // datasheet section I, "SII EEPROM content").
    constexpr std::uint8_t kPowerUpOnly = 0xF2;
    memory_[reg::kPdiControl] = static_cast<std::uint8_t>(word0);
    memory_[reg::kEscConfiguration] = static_cast<std::uint8_t>(
        (memory_[reg::kEscConfiguration] & kPowerUpOnly) | ((word0 >> 8) & ~kPowerUpOnly));
  }
  wire::store_le16(&memory_[reg::kPdiConfiguration],
                   eeprom_word(wire::sii_word::kPdiConfiguration));
  wire::store_le16(&memory_[reg::kDcPulseLength], eeprom_word(wire::sii_word::kSyncImpulseLength));
  wire::store_le16(&memory_[reg::kExtendedPdiConfiguration],
                   eeprom_word(wire::sii_word::kPdiConfiguration2));
  return true;
}

void Esc::pdi_take_eeprom(bool take) {
  const bool offered = (memory_[reg::kSiiAccess] & wire::sii_access::kPdiOwns) != 0;
  memory_[reg::kSiiPdiAccess] = (take && offered) ? 0x01 : 0x00;
}

void Esc::sii_access_written() {
  // Bit 1 forces ECAT access: the PDI loses the EEPROM at once (0x0501 bit 0 reset), and the
  // bit itself does not stay set. Taking the offer back (bit 0 = 0) does not take the EEPROM
  // from a PDI that holds it: the PDI has to give it back.
  if ((memory_[reg::kSiiAccess] & wire::sii_access::kForceEcatAccess) != 0) {
    memory_[reg::kSiiPdiAccess] = 0;
    memory_[reg::kSiiAccess] =
        static_cast<std::uint8_t>(memory_[reg::kSiiAccess] & ~wire::sii_access::kForceEcatAccess);
  }
}

void Esc::sii_control_written(std::uint32_t first, std::uint32_t last) {
  namespace sc = wire::sii_control;
  // memory_ holds what the master wrote over the ESC's status; the status before the write is
  // rebuilt from it and the ESC's own state: only bit 0 and bits 8..10 are writable.
  const std::uint16_t written = read_u16(reg::kSiiControl);
  const bool low = overlaps(first, last, reg::kSiiControl, 1);
  const bool high = overlaps(first, last, reg::kSiiControl + 1, 1);
  std::uint16_t status = sii_status_;
  auto store = [&] { sii_store_status(status); };
  const bool busy = sii_pending_.has_value() && sii_busy_until_ns_ > now_ns_;
  const bool pdi_holds = (memory_[reg::kSiiAccess] & wire::sii_access::kPdiOwns) != 0 &&
                         (memory_[reg::kSiiPdiAccess] & 0x01) != 0;
  if (busy || pdi_holds) {
    store();  // ignored: the interface is busy, or the PDI holds the EEPROM
    return;
  }
  if (low) {
    status =
        static_cast<std::uint16_t>((status & ~sc::kWriteEnable) | (written & sc::kWriteEnable));
  }
  const std::uint16_t command = high ? written & sc::kCommandMask : 0;
  if (!high) {
    store();
    return;
  }
  if (command == sc::kCommandNop) {
    status = static_cast<std::uint16_t>(status & ~(sc::kAcknowledgeError | sc::kWriteEnableError));
    store();
    return;
  }
  if ((status & sc::kAcknowledgeError) != 0) {
    store();  // ignored until a NOP acknowledges the error
    return;
  }
  status = static_cast<std::uint16_t>(status & ~sc::kWriteEnableError);
  const bool write_enabled = (status & sc::kWriteEnable) != 0;
  status = static_cast<std::uint16_t>(status & ~sc::kWriteEnable);  // consumed by the command
  SiiPending pending;
  pending.command = command;
  std::int64_t busy_ns = hardware_.sii_busy_ns;
  const std::uint32_t word = read_u32(reg::kSiiAddress);
  const bool nack = sii_nacks_ > 0 && (!sii_nack_writes_only_ || command == sc::kCommandWrite);
  switch (command) {
    case sc::kCommandRead: {
      // The data register is filled at once (the captures' data reads all follow the end of
      // busy, so nothing shows when the real ESC fills it).
      const std::size_t n = hardware_.sii_reads_8_bytes ? 8 : 4;
      for (std::size_t i = 0; i < n; ++i) {
        const std::size_t byte = static_cast<std::size_t>(word) * 2 + i;
        memory_[reg::kSiiData + i] = byte < eeprom_.size() && !nack ? eeprom_[byte] : 0xFF;
      }
      if (nack || static_cast<std::size_t>(word) * 2 >= eeprom_.size()) {
        pending.errors = sc::kAcknowledgeError;
      }
      break;
    }
    case sc::kCommandWrite: {
      if (!write_enabled) {
        // Refused before anything reaches the EEPROM: no busy time.
        status |= sc::kWriteEnableError;
        store();
        return;
      }
      const std::size_t byte = static_cast<std::size_t>(word) * 2;
      if (nack || byte + 1 >= eeprom_.size()) {
        pending.errors = sc::kAcknowledgeError;
      } else {
        pending.write_byte = byte;
        pending.write_data = {memory_[reg::kSiiData], memory_[reg::kSiiData + 1]};
      }
      busy_ns = hardware_.sii_write_busy_ns;
      break;
    }
    case sc::kCommandReload:
      if (nack) pending.errors = sc::kAcknowledgeError;
      break;
    default:
      status |= sc::kAcknowledgeError;  // invalid command: refused at once
      store();
      return;
  }
  if (nack) --sii_nacks_;
  sii_pending_ = pending;
  sii_running_ = true;
  if (busy_ns > 0) {
    sii_busy_until_ns_ = now_ns_ + busy_ns;
    status = static_cast<std::uint16_t>(status | sc::kBusy | command);
    store();
  } else {
    sii_busy_until_ns_ = now_ns_;
    store();
    sii_finish_if_due();
  }
}

void Esc::sii_finish_if_due_slow() {
  namespace sc = wire::sii_control;
  if (!sii_pending_ || now_ns_ < sii_busy_until_ns_) return;
  const SiiPending done = *sii_pending_;
  sii_pending_.reset();
  sii_running_ = false;
  sii_busy_until_ns_ = 0;
  std::uint16_t status = static_cast<std::uint16_t>(sii_status_ & ~(sc::kBusy | sc::kCommandMask));
  status |= done.errors;
  if (done.write_byte) {
    eeprom_[*done.write_byte] = done.write_data[0];
    eeprom_[*done.write_byte + 1] = done.write_data[1];
  }
  if (done.command == sc::kCommandReload && done.errors == 0) {
    const bool loaded = sii_load_configuration(false);
    status = static_cast<std::uint16_t>((status & ~sc::kChecksumError) |
                                        (loaded ? 0 : sc::kChecksumError));
  }
  sii_store_status(status);
}

void Esc::sii_store_status(std::uint16_t status) noexcept {
  sii_status_ = status;
  sii_register_stale_ = false;
  wire::store_le16(&memory_[reg::kSiiControl], status);
}

// ---------------------------------------------------------------------------------------------
// Observation

std::uint16_t Esc::station_address() const noexcept {
  return read_u16(reg::kStationAddress);
}
std::uint16_t Esc::station_alias() const noexcept {
  return read_u16(reg::kStationAlias);
}
wire::AlState Esc::al_state() const noexcept {
  return wire::al_state_from_code(memory_[reg::kAlStatus] & 0x0F).value_or(wire::AlState::init);
}
bool Esc::al_error() const noexcept {
  return (memory_[reg::kAlStatus] & 0x10) != 0;
}
std::uint16_t Esc::al_status_code() const noexcept {
  return read_u16(reg::kAlStatusCode);
}

std::uint8_t Esc::read_u8(std::uint16_t address) const noexcept {
  return address < memory_.size() ? memory_[address] : 0;
}
std::uint16_t Esc::read_u16(std::uint16_t address) const noexcept {
  return address + 2u <= memory_.size() ? wire::load_le16(&memory_[address]) : 0;
}
std::uint32_t Esc::read_u32(std::uint16_t address) const noexcept {
  return address + 4u <= memory_.size() ? wire::load_le32(&memory_[address]) : 0;
}
std::uint64_t Esc::read_u64(std::uint16_t address) const noexcept {
  return address + 8u <= memory_.size() ? wire::load_le64(&memory_[address]) : 0;
}

// ---------------------------------------------------------------------------------------------
// PDI side

void Esc::pdi_set_al_status(wire::AlState state, bool error, std::uint16_t status_code) {
  const auto status = static_cast<std::uint16_t>(static_cast<std::uint16_t>(state) |
                                                 (error ? wire::kAlStatusError : 0));
  wire::store_le16(&memory_[reg::kAlStatus], status);
  wire::store_le16(&memory_[reg::kAlStatusCode], status_code);
}

bool Esc::pdi_mailbox_send(std::size_t index, wire::Bytes message) {
  if (index >= sms_.size()) return false;
  auto& sm = sms_[index];
  if (!sm.enabled || sm.config.control.mode != wire::SmMode::mailbox ||
      sm.config.control.direction != wire::SmDirection::read || sm.mailbox_full ||
      message.size() > sm.config.length) {
    return false;
  }
  auto* area = &memory_[sm.config.physical_start];
  // Only the message is written: the rest of the buffer keeps what earlier replies left there,
  // as in real ESC RAM (the EL3004's mailbox reads in replay-ek1914-el3004-mailbox.pcapng show
  // the tails of earlier, longer replies after a short one).
  std::memcpy(area, message.data(), message.size());
  last_mailbox_reply_.assign(area, area + sm.config.length);
  sm.mailbox_full = true;
  sm.config.status.interrupt_write = true;
  update_sm_status(index);
  return true;
}

std::optional<wire::Bytes> Esc::pdi_mailbox_received(std::size_t index) const {
  if (index >= sms_.size()) return std::nullopt;
  const auto& sm = sms_[index];
  if (!sm.enabled || sm.config.control.mode != wire::SmMode::mailbox ||
      sm.config.control.direction != wire::SmDirection::write || !sm.mailbox_full) {
    return std::nullopt;
  }
  return wire::Bytes(&memory_[sm.config.physical_start], sm.config.length);
}

void Esc::pdi_mailbox_release(std::size_t index) {
  if (index >= sms_.size()) return;
  auto& sm = sms_[index];
  if (!sm.mailbox_full) return;
  sm.mailbox_full = false;
  sm.config.status.interrupt_write = false;
  // The firmware read the request completely: the read event shows until the master writes the
  // next one (SM0 status 0x02 after the EL3004 took a request in
  // replay-ek1914-el3004-mailbox.pcapng).
  sm.config.status.interrupt_read = true;
  update_sm_status(index);
}

void Esc::pdi_mailbox_repeat(std::size_t index) {
  if (index >= sms_.size()) return;
  auto& sm = sms_[index];
  if (sm.enabled && !last_mailbox_reply_.empty() &&
      last_mailbox_reply_.size() == sm.config.length) {
    std::memcpy(&memory_[sm.config.physical_start], last_mailbox_reply_.data(),
                last_mailbox_reply_.size());
    sm.mailbox_full = true;
  }
  sm.config.pdi_control.repeat_ack = sm.config.activate.repeat_request;
  update_sm_status(index);
}

void Esc::pdi_write_buffer(std::size_t index, wire::Bytes data) {
  if (index >= sms_.size()) return;
  auto& sm = sms_[index];
  const std::size_t n = std::min<std::size_t>(data.size(), sm.config.length);
  if (n == 0 || static_cast<std::size_t>(sm.config.physical_start) + n > memory_.size()) return;
  std::memcpy(&memory_[sm.config.physical_start], data.data(), n);
}

wire::Bytes Esc::pdi_read_buffer(std::size_t index) const {
  if (index >= sms_.size()) return {};
  const auto& sm = sms_[index];
  if (static_cast<std::size_t>(sm.config.physical_start) + sm.config.length > memory_.size()) {
    return {};
  }
  return wire::Bytes(&memory_[sm.config.physical_start], sm.config.length);
}

void Esc::pdi_set_sm_deactivated(std::size_t index, bool deactivated) {
  if (index >= sms_.size()) return;
  sms_[index].config.pdi_control.deactivate = deactivated;
  update_sm_status(index);
}

void Esc::pdi_write(std::uint16_t address, wire::Bytes data) {
  if (static_cast<std::size_t>(address) + data.size() > memory_.size()) return;
  std::memcpy(&memory_[address], data.data(), data.size());
  if (data.empty()) return;
  const std::uint32_t last = address + static_cast<std::uint32_t>(data.size()) - 1;
  if (overlaps(address, last, reg::kSiiControl, 2)) sii_register_stale_ = true;
  layout_written(address, last);
}

void Esc::pdi_write_u16(std::uint16_t address, std::uint16_t value) {
  if (static_cast<std::size_t>(address) + 2 > memory_.size()) return;
  wire::store_le16(&memory_[address], value);
  if (overlaps(address, static_cast<std::uint32_t>(address) + 1, reg::kSiiControl, 2)) {
    sii_register_stale_ = true;
  }
  layout_written(address, static_cast<std::uint32_t>(address) + 1);
}

}  // namespace ecat::sim
