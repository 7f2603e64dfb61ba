#include <cstring>
#include <string>

#include <fmt/format.h>

#include <ecat/wire/registers.hpp>

namespace ecat::wire {
namespace {

constexpr bool bit(std::uint32_t value, unsigned n) noexcept {
  return ((value >> n) & 1u) != 0;
}

template <class T>
constexpr T flag(bool on, unsigned n) noexcept {
  return static_cast<T>(on ? (1u << n) : 0u);
}

Error wrong_length(const char* what, std::size_t expected, std::size_t actual) {
  return Error(actual < expected ? Errc::truncated : Errc::malformed,
               fmt::format("{} needs {} bytes, got {}", what, expected, actual));
}

Error too_small(const char* what, std::size_t expected, std::size_t actual) {
  return Error(Errc::out_of_range,
               fmt::format("buffer for {} holds {} bytes, needs {}", what, actual, expected));
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// FMMU

std::array<std::uint8_t, FmmuConfig::kSize> FmmuConfig::encode() const noexcept {
  std::array<std::uint8_t, kSize> out{};
  store_le32(&out[0], logical_start);
  store_le16(&out[4], length);
  out[6] = logical_start_bit;
  out[7] = logical_stop_bit;
  store_le16(&out[8], physical_start);
  out[10] = physical_start_bit;
  out[11] = static_cast<std::uint8_t>(type);
  out[12] = active ? 1 : 0;
  return out;
}

Result<void> FmmuConfig::encode(MutableBytes out) const {
  if (out.size() < kSize) return too_small("an FMMU configuration", kSize, out.size());
  const auto bytes = encode();
  std::memcpy(out.data(), bytes.data(), kSize);
  return ok();
}

Result<FmmuConfig> FmmuConfig::decode(Bytes bytes) {
  if (bytes.size() != kSize) return wrong_length("an FMMU configuration", kSize, bytes.size());
  FmmuConfig c;
  c.logical_start = load_le32(&bytes[0]);
  c.length = load_le16(&bytes[4]);
  c.logical_start_bit = bytes[6];
  c.logical_stop_bit = bytes[7];
  c.physical_start = load_le16(&bytes[8]);
  c.physical_start_bit = bytes[10];
  const struct {
    const char* name;
    std::uint8_t value;
    std::size_t offset;
  } bit_fields[] = {{"logical start bit", c.logical_start_bit, 6},
                    {"logical stop bit", c.logical_stop_bit, 7},
                    {"physical start bit", c.physical_start_bit, 10}};
  for (const auto& f : bit_fields) {
    if (f.value > 7) {
      return Error(Errc::malformed,
                   fmt::format("FMMU {} (byte {}) is {}, must be 0..7", f.name, f.offset, f.value));
    }
  }
  if ((bytes[11] & ~0x03u) != 0) {
    return Error(Errc::malformed,
                 fmt::format("FMMU type (byte 11) is 0x{:02x}: only bits 0 (read) and 1 (write) "
                             "are defined",
                             bytes[11]));
  }
  c.type = static_cast<FmmuType>(bytes[11]);
  if ((bytes[12] & ~0x01u) != 0) {
    return Error(
        Errc::malformed,
        fmt::format("FMMU activate (byte 12) is 0x{:02x}: only bit 0 is defined", bytes[12]));
  }
  c.active = bytes[12] != 0;
  return c;
}

// ---------------------------------------------------------------------------------------------
// SyncManager

std::uint8_t SmControl::encode() const noexcept {
  return static_cast<std::uint8_t>(
      static_cast<unsigned>(mode) | (static_cast<unsigned>(direction) << 2) |
      flag<unsigned>(ecat_event, 4) | flag<unsigned>(pdi_event, 5) | flag<unsigned>(watchdog, 6));
}

Result<SmControl> SmControl::decode(std::uint8_t raw) {
  const unsigned mode_bits = raw & 0x03u;
  if (mode_bits != 0 && mode_bits != 2) {
    return Error(Errc::malformed,
                 fmt::format("SyncManager control 0x{:02x} has reserved operation mode {} "
                             "(0 = buffered, 2 = mailbox)",
                             raw, mode_bits));
  }
  const unsigned direction_bits = (raw >> 2) & 0x03u;
  if (direction_bits > 1) {
    return Error(Errc::malformed,
                 fmt::format("SyncManager control 0x{:02x} has reserved direction {} "
                             "(0 = ECAT reads, 1 = ECAT writes)",
                             raw, direction_bits));
  }
  SmControl c;
  c.mode = static_cast<SmMode>(mode_bits);
  c.direction = static_cast<SmDirection>(direction_bits);
  c.ecat_event = bit(raw, 4);
  c.pdi_event = bit(raw, 5);
  c.watchdog = bit(raw, 6);
  return c;
}

std::uint8_t SmStatus::encode() const noexcept {
  return static_cast<std::uint8_t>(
      flag<unsigned>(interrupt_write, 0) | flag<unsigned>(interrupt_read, 1) |
      flag<unsigned>(mailbox_full, 3) | ((buffer_state & 0x03u) << 4) |
      flag<unsigned>(read_buffer_open, 6) | flag<unsigned>(write_buffer_open, 7));
}

SmStatus SmStatus::decode(std::uint8_t raw) noexcept {
  SmStatus s;
  s.interrupt_write = bit(raw, 0);
  s.interrupt_read = bit(raw, 1);
  s.mailbox_full = bit(raw, 3);
  s.buffer_state = static_cast<std::uint8_t>((raw >> 4) & 0x03u);
  s.read_buffer_open = bit(raw, 6);
  s.write_buffer_open = bit(raw, 7);
  return s;
}

std::uint8_t SmActivate::encode() const noexcept {
  return static_cast<std::uint8_t>(flag<unsigned>(enable, 0) | flag<unsigned>(repeat_request, 1) |
                                   flag<unsigned>(latch_event_ecat, 6) |
                                   flag<unsigned>(latch_event_pdi, 7));
}

SmActivate SmActivate::decode(std::uint8_t raw) noexcept {
  SmActivate a;
  a.enable = bit(raw, 0);
  a.repeat_request = bit(raw, 1);
  a.latch_event_ecat = bit(raw, 6);
  a.latch_event_pdi = bit(raw, 7);
  return a;
}

std::uint8_t SmPdiControl::encode() const noexcept {
  return static_cast<std::uint8_t>(flag<unsigned>(deactivate, 0) | flag<unsigned>(repeat_ack, 1));
}

SmPdiControl SmPdiControl::decode(std::uint8_t raw) noexcept {
  SmPdiControl p;
  p.deactivate = bit(raw, 0);
  p.repeat_ack = bit(raw, 1);
  return p;
}

std::array<std::uint8_t, SyncManagerConfig::kSize> SyncManagerConfig::encode() const noexcept {
  std::array<std::uint8_t, kSize> out{};
  store_le16(&out[0], physical_start);
  store_le16(&out[2], length);
  out[4] = control.encode();
  out[5] = status.encode();
  out[6] = activate.encode();
  out[7] = pdi_control.encode();
  return out;
}

Result<void> SyncManagerConfig::encode(MutableBytes out) const {
  if (out.size() < kSize) return too_small("a SyncManager configuration", kSize, out.size());
  const auto bytes = encode();
  std::memcpy(out.data(), bytes.data(), kSize);
  return ok();
}

Result<SyncManagerConfig> SyncManagerConfig::decode(Bytes bytes) {
  if (bytes.size() != kSize)
    return wrong_length("a SyncManager configuration", kSize, bytes.size());
  auto control = SmControl::decode(bytes[4]);
  if (!control) return std::move(control).error();
  SyncManagerConfig c;
  c.physical_start = load_le16(&bytes[0]);
  c.length = load_le16(&bytes[2]);
  c.control = *control;
  c.status = SmStatus::decode(bytes[5]);
  c.activate = SmActivate::decode(bytes[6]);
  c.pdi_control = SmPdiControl::decode(bytes[7]);
  return c;
}

// ---------------------------------------------------------------------------------------------
// DL status

std::uint16_t DlStatus::encode() const noexcept {
  unsigned raw = flag<unsigned>(pdi_operational, 0) | flag<unsigned>(pdi_watchdog_ok, 1) |
                 flag<unsigned>(enhanced_link_detection, 2);
  for (unsigned p = 0; p < 4; ++p) {
    raw |= flag<unsigned>(ports[p].physical_link, 4 + p);
    raw |= flag<unsigned>(ports[p].loop_closed, 8 + 2 * p);
    raw |= flag<unsigned>(ports[p].communication, 9 + 2 * p);
  }
  return static_cast<std::uint16_t>(raw);
}

Result<ProcessDataWatchdog> ProcessDataWatchdog::for_time(std::chrono::nanoseconds time) {
  if (time.count() < 0 || time > kMaxTime) {
    return Error(Errc::out_of_range,
                 fmt::format("a process-data watchdog of {} ns is outside 0 (off) to {} ns",
                             time.count(), kMaxTime.count()));
  }
  ProcessDataWatchdog w;
  if (time.count() == 0) {
    w.ticks = 0;
    return w;
  }
  const std::int64_t ns = time.count();
  std::int64_t tick_ns = (std::int64_t{kDefaultDivider} + 2) * 40;
  if ((ns + tick_ns - 1) / tick_ns > 65535) {
    // The finest tick (a multiple of 40 ns) with which 65535 ticks reach `time`.
    const std::int64_t per_tick = (ns + 65535 - 1) / 65535;
    const std::int64_t units = (per_tick + 40 - 1) / 40;  // divider + 2
    w.divider = static_cast<std::uint16_t>(units - 2);
    tick_ns = units * 40;
  }
  w.ticks = static_cast<std::uint16_t>((ns + tick_ns - 1) / tick_ns);
  return w;
}

DlStatus DlStatus::decode(std::uint16_t raw) noexcept {
  DlStatus s;
  s.pdi_operational = bit(raw, 0);
  s.pdi_watchdog_ok = bit(raw, 1);
  s.enhanced_link_detection = bit(raw, 2);
  for (unsigned p = 0; p < 4; ++p) {
    s.ports[p].physical_link = bit(raw, 4 + p);
    s.ports[p].loop_closed = bit(raw, 8 + 2 * p);
    s.ports[p].communication = bit(raw, 9 + 2 * p);
  }
  return s;
}

Result<DlStatus> DlStatus::decode(Bytes bytes) {
  if (bytes.size() != 2) return wrong_length("DL status (0x0110)", 2, bytes.size());
  return decode(load_le16(bytes.data()));
}

// ---------------------------------------------------------------------------------------------
// ESC features, port descriptor, information block

std::uint16_t EscFeatures::encode() const noexcept {
  return static_cast<std::uint16_t>(
      flag<unsigned>(fmmu_byte_oriented, 0) | flag<unsigned>(dc_supported, 2) |
      flag<unsigned>(dc_64bit, 3) | flag<unsigned>(low_jitter_ebus, 4) |
      flag<unsigned>(enhanced_link_detection_ebus, 5) |
      flag<unsigned>(enhanced_link_detection_mii, 6) |
      flag<unsigned>(separate_fcs_error_handling, 7) |
      flag<unsigned>(enhanced_dc_sync_activation, 8) | flag<unsigned>(lrw_not_supported, 9) |
      flag<unsigned>(read_write_not_supported, 10) |
      flag<unsigned>(fixed_fmmu_sm_configuration, 11));
}

EscFeatures EscFeatures::decode(std::uint16_t raw) noexcept {
  EscFeatures f;
  f.fmmu_byte_oriented = bit(raw, 0);
  f.dc_supported = bit(raw, 2);
  f.dc_64bit = bit(raw, 3);
  f.low_jitter_ebus = bit(raw, 4);
  f.enhanced_link_detection_ebus = bit(raw, 5);
  f.enhanced_link_detection_mii = bit(raw, 6);
  f.separate_fcs_error_handling = bit(raw, 7);
  f.enhanced_dc_sync_activation = bit(raw, 8);
  f.lrw_not_supported = bit(raw, 9);
  f.read_write_not_supported = bit(raw, 10);
  f.fixed_fmmu_sm_configuration = bit(raw, 11);
  return f;
}

std::string_view to_string(PortType type) noexcept {
  switch (type) {
    case PortType::not_implemented:
      return "not implemented";
    case PortType::not_configured:
      return "not configured";
    case PortType::ebus:
      return "EBUS";
    case PortType::mii:
      return "MII";
  }
  return "unknown";
}

std::uint8_t PortDescriptor::encode() const noexcept {
  unsigned raw = 0;
  for (unsigned p = 0; p < 4; ++p)
    raw |= (static_cast<unsigned>(ports[p]) & 0x03u) << (2 * p);
  return static_cast<std::uint8_t>(raw);
}

PortDescriptor PortDescriptor::decode(std::uint8_t raw) noexcept {
  PortDescriptor d;
  for (unsigned p = 0; p < 4; ++p)
    d.ports[p] = static_cast<PortType>((raw >> (2 * p)) & 0x03u);
  return d;
}

std::array<std::uint8_t, reg::kEscInformationSize> EscInformation::encode() const noexcept {
  std::array<std::uint8_t, reg::kEscInformationSize> out{};
  out[0] = type;
  out[1] = revision;
  store_le16(&out[2], build);
  out[4] = fmmu_count;
  out[5] = sync_manager_count;
  out[6] = ram_size_kib;
  out[7] = ports.encode();
  store_le16(&out[8], features.encode());
  return out;
}

Result<EscInformation> EscInformation::decode(Bytes bytes) {
  if (bytes.size() != reg::kEscInformationSize) {
    return wrong_length("ESC information (0x0000..0x0009)", reg::kEscInformationSize, bytes.size());
  }
  EscInformation info;
  info.type = bytes[0];
  info.revision = bytes[1];
  info.build = load_le16(&bytes[2]);
  info.fmmu_count = bytes[4];
  info.sync_manager_count = bytes[5];
  info.ram_size_kib = bytes[6];
  info.ports = PortDescriptor::decode(bytes[7]);
  info.features = EscFeatures::decode(load_le16(&bytes[8]));
  return info;
}

std::array<std::uint8_t, reg::kRxErrorCounterSize> RxErrorCounters::encode() const noexcept {
  std::array<std::uint8_t, reg::kRxErrorCounterSize> out{};
  for (std::size_t p = 0; p < 4; ++p) {
    out[2 * p] = invalid_frame[p];
    out[2 * p + 1] = rx_error[p];
  }
  return out;
}

Result<RxErrorCounters> RxErrorCounters::decode(Bytes bytes) {
  if (bytes.size() != reg::kRxErrorCounterSize) {
    return wrong_length("RX error counters (0x0300)", reg::kRxErrorCounterSize, bytes.size());
  }
  RxErrorCounters c;
  for (std::size_t p = 0; p < 4; ++p) {
    c.invalid_frame[p] = bytes[2 * p];
    c.rx_error[p] = bytes[2 * p + 1];
  }
  return c;
}

// ---------------------------------------------------------------------------------------------
// SII control/status

std::uint16_t SiiControlStatus::encode() const noexcept {
  return static_cast<std::uint16_t>(
      flag<unsigned>(write_enable, 0) | flag<unsigned>(emulation, 5) |
      flag<unsigned>(read_size_8, 6) | flag<unsigned>(two_address_bytes, 7) |
      ((command & 0x07u) << 8) | flag<unsigned>(checksum_error, 11) |
      flag<unsigned>(device_info_error, 12) | flag<unsigned>(acknowledge_error, 13) |
      flag<unsigned>(write_enable_error, 14) | flag<unsigned>(busy, 15));
}

SiiControlStatus SiiControlStatus::decode(std::uint16_t raw) noexcept {
  SiiControlStatus s;
  s.write_enable = bit(raw, 0);
  s.emulation = bit(raw, 5);
  s.read_size_8 = bit(raw, 6);
  s.two_address_bytes = bit(raw, 7);
  s.command = static_cast<std::uint8_t>((raw >> 8) & 0x07u);
  s.checksum_error = bit(raw, 11);
  s.device_info_error = bit(raw, 12);
  s.acknowledge_error = bit(raw, 13);
  s.write_enable_error = bit(raw, 14);
  s.busy = bit(raw, 15);
  return s;
}

}  // namespace ecat::wire
