#include <algorithm>
#include <array>
#include <cctype>
#include <charconv>
#include <map>
#include <set>

#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

Result<std::uint32_t> option_u32(const DeviceConfig& config, const std::string& key,
                                 std::uint32_t fallback) {
  auto it = config.options.find(key);
  if (it == config.options.end()) return fallback;
  std::string_view text = it->second;
  int base = 10;
  if (text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X')) {
    text.remove_prefix(2);
    base = 16;
  }
  std::uint32_t value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value, base);
  if (text.empty() || ec != std::errc{} || end != text.data() + text.size()) {
    return Error(Errc::invalid_argument,
                 fmt::format("device option {}: '{}' is not a 32-bit number", key, it->second));
  }
  return value;
}

Result<double> option_double(const DeviceConfig& config, const std::string& key, double fallback) {
  auto it = config.options.find(key);
  if (it == config.options.end()) return fallback;
  const std::string& text = it->second;
  double value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc{} || end != text.data() + text.size()) {
    return Error(Errc::invalid_argument,
                 fmt::format("device option {}: '{}' is not a number", key, text));
  }
  return value;
}

Result<bool> option_bool(const DeviceConfig& config, const std::string& key, bool fallback) {
  auto it = config.options.find(key);
  if (it == config.options.end()) return fallback;
  const std::string& t = it->second;
  if (t == "1" || t == "true" || t == "yes" || t == "on") return true;
  if (t == "0" || t == "false" || t == "no" || t == "off") return false;
  return Error(
      Errc::invalid_argument,
      fmt::format("device option {}: '{}' is not a yes/no value (1/0, true/false)", key, t));
}

Result<void> check_options(const DeviceConfig& config,
                           std::initializer_list<std::string_view> known) {
  for (const auto& [key, value] : config.options) {
    const bool common = std::find(std::begin(kCommonOptions), std::end(kCommonOptions), key) !=
                        std::end(kCommonOptions);
    if (common || std::find(known.begin(), known.end(), key) != known.end()) continue;
    std::string list;
    for (auto k : kCommonOptions)
      list += (list.empty() ? "" : ", ") + std::string(k);
    for (auto k : known)
      list += ", " + std::string(k);
    return Error(
        Errc::invalid_argument,
        fmt::format("profile '{}' has no option '{}' (options: {})", config.profile, key, list));
  }
  return {};
}

Result<void> apply_common_options(const DeviceConfig& config, StandardConfig& cfg) {
  auto serial = option_u32(config, "serial", cfg.sii.identity.serial);
  if (!serial) return serial.error();
  auto valid_outputs = option_bool(config, "require_valid_outputs", cfg.require_valid_outputs);
  if (!valid_outputs) return valid_outputs.error();
  auto fmmus = option_bool(config, "check_fmmus", cfg.check_fmmus);
  if (!fmmus) return fmmus.error();
  auto reply_us = option_u32(config, "mailbox_reply_us",
                             static_cast<std::uint32_t>(cfg.coe.reply_delay.count() / 1000));
  if (!reply_us) return reply_us.error();
  if (*reply_us > 10'000'000) {
    return Error(
        Errc::invalid_argument,
        fmt::format("device option mailbox_reply_us: {} is above 10000000 (10 s)", *reply_us));
  }
  cfg.coe.reply_delay = std::chrono::microseconds(*reply_us);
  cfg.sii.identity.serial = *serial;
  cfg.require_valid_outputs = *valid_outputs;
  cfg.check_fmmus = *fmmus;
  if (auto* identity = cfg.dictionary.find(0x1018, 4)) {
    identity->value = to_le_bytes(*serial);
  }
  return {};
}

std::uint8_t SiiStrings::add(std::string_view text) {
  auto& strings = image_.strings;
  for (std::size_t i = 0; i < strings.size(); ++i) {
    if (strings[i] == text) return static_cast<std::uint8_t>(i + 1);
  }
  if (strings.size() >= 255) return 0;
  strings.emplace_back(text);
  return static_cast<std::uint8_t>(strings.size());
}

EscHardware terminal_hardware() {
  EscHardware hw;
  hw.type = 0x12;  // ET1200
  hw.fmmu_count = 3;
  hw.sync_manager_count = 4;
  hw.ram_size_kib = 1;
  hw.ports =
      wire::PortDescriptor{{wire::PortType::ebus, wire::PortType::ebus,
                            wire::PortType::not_implemented, wire::PortType::not_implemented}};
  return hw;
}

EscHardware coupler_hardware() {
  EscHardware hw;
  hw.type = 0x11;  // ET1100
  hw.fmmu_count = 8;
  hw.sync_manager_count = 8;
  hw.ram_size_kib = 8;
  hw.ports = wire::PortDescriptor{{wire::PortType::mii, wire::PortType::ebus, wire::PortType::mii,
                                   wire::PortType::not_implemented}};
  return hw;
}

Result<std::unique_ptr<Esc>> build_device(const DeviceConfig& config, EscHardware hardware,
                                          const wire::SiiImage& sii,
                                          std::unique_ptr<Application> application) {
  auto eeprom = wire::encode_sii(sii);
  if (!eeprom) {
    return Error(Errc::invalid_argument,
                 fmt::format("profile '{}': cannot encode its SII image: {}", config.profile,
                             eeprom.error().describe()));
  }
  config.esc.apply(hardware);
  auto esc = std::make_unique<Esc>(hardware, std::move(*eeprom), std::move(application));
  if (auto* dc = esc->dc()) dc->set_clock(config.clock);
  return esc;
}

Result<std::unique_ptr<Esc>> build_device_from_eeprom(const DeviceConfig& config,
                                                      EscHardware hardware,
                                                      std::vector<std::uint8_t> eeprom,
                                                      std::unique_ptr<Application> application) {
  config.esc.apply(hardware);
  auto esc = std::make_unique<Esc>(hardware, std::move(eeprom), std::move(application));
  if (auto* dc = esc->dc()) dc->set_clock(config.clock);
  return esc;
}

EscHardware hardware_for(const wire::SiiImage& sii, std::uint8_t ram_kib) {
  EscHardware hw;
  hw.fmmu_count = static_cast<std::uint8_t>(std::clamp<std::size_t>(sii.fmmus.size(), 3, 8));
  hw.sync_manager_count =
      static_cast<std::uint8_t>(std::clamp<std::size_t>(sii.sync_managers.size(), 4, 8));
  hw.ram_size_kib = ram_kib;
  if (sii.general) {
    for (std::size_t p = 0; p < 4; ++p) {
      switch (sii.general->port(p)) {
        case wire::sii_port::kMii:
          hw.ports.ports[p] = wire::PortType::mii;
          break;
        case wire::sii_port::kEbus:
          hw.ports.ports[p] = wire::PortType::ebus;
          break;
        default:
          hw.ports.ports[p] = wire::PortType::not_implemented;
          break;
      }
    }
  }
  return hw;
}

std::string signal_type_name(const ObjectEntry& entry) {
  switch (entry.data_type) {
    case DataType::boolean:
    case DataType::bit1:
      return "bool";
    case DataType::real32:
      return "f32";
    case DataType::real64:
      return "f64";
    default:
      break;
  }
  if (is_signed_integer(entry.data_type)) return fmt::format("i{}", entry.bit_length);
  return fmt::format("u{}", entry.bit_length);
}

namespace {

// A CoE entry for a preset: typed by its size (strings for the standard string objects),
// writable when the device accepted a download, refusing with the abort code it answered.
ObjectEntry preset_entry(const ObjectPreset& o) {
  const std::uint16_t access = o.writable ? kAccessReadWrite : kAccessRead;
  ObjectEntry e;
  const bool text = o.index == 0x1008 || o.index == 0x1009 || o.index == 0x100A;
  if (text) {
    e = make_string_entry(o.subindex, fmt::format("SubIndex {:03}", o.subindex),
                          std::string(o.value.begin(), o.value.end()), access);
  } else {
    // Unsigned integers of the standard sizes, octet strings otherwise.
    constexpr std::array<std::pair<std::size_t, DataType>, 4> kBySize{{{1, DataType::unsigned8},
                                                                       {2, DataType::unsigned16},
                                                                       {4, DataType::unsigned32},
                                                                       {8, DataType::unsigned64}}};
    const auto sized = std::find_if(kBySize.begin(), kBySize.end(),
                                    [&](const auto& p) { return p.first == o.value.size(); });
    e = sized != kBySize.end() ? make_entry(o.subindex, "", sized->second, access, o.value)
                               : make_octet_entry(o.subindex, "", o.value, access);
    e.name = fmt::format("SubIndex {:03}", o.subindex);
  }
  if (o.abort_code) {
    const std::uint32_t code = *o.abort_code;
    e.on_read = [code](ObjectEntry&, const AccessContext&) { return SdoStatus::abort(code); };
    e.on_write = [code](const ObjectEntry&, wire::Bytes, const AccessContext&) {
      return SdoStatus::abort(code);
    };
  }
  return e;
}

std::string snake_case(std::string_view text) {
  std::string out;
  bool gap = false;
  for (char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (std::isalnum(u) != 0) {
      if (gap && !out.empty()) out += '_';
      out += static_cast<char>(std::tolower(u));
      gap = false;
    } else {
      gap = true;
    }
  }
  return out;
}

}  // namespace

void apply_object_presets(ObjectDictionary& od, const std::vector<ObjectPreset>& presets) {
  std::map<std::uint16_t, std::vector<const ObjectPreset*>> by_index;
  for (const auto& o : presets)
    by_index[o.index].push_back(&o);
  for (const auto& [index, objects] : by_index) {
    OdObject* existing = od.find(index);
    if (existing != nullptr) {
      for (const ObjectPreset* o : objects) {
        if (ObjectEntry* e = existing->entry(o->subindex); e != nullptr && !o->abort_code) {
          e->value = o->value;
          if (o->writable) e->access |= kAccessReadWrite;
        }
      }
      continue;
    }
    const bool var = objects.size() == 1 && objects.front()->subindex == 0;
    if (var) {
      od.add(make_var(index, fmt::format("Object {:04X}", index), preset_entry(*objects.front())));
    } else {
      std::vector<ObjectEntry> entries;
      for (const ObjectPreset* o : objects) {
        if (o->subindex != 0) entries.push_back(preset_entry(*o));
      }
      od.add(make_record(index, fmt::format("Object {:04X}", index), std::move(entries)));
    }
  }
}

std::vector<GeneratedSignal> signals_from_layout(const ObjectDictionary& od,
                                                 const std::vector<ProcessDataSyncManager>& sms) {
  std::vector<GeneratedSignal> out;
  std::set<std::string> used;
  std::set<std::pair<std::uint16_t, std::uint8_t>> seen;
  for (const auto& pd : sms) {
    auto layout = process_data_layout(od, pd.index);
    if (!layout) continue;
    for (const auto& m : layout->entries) {
      if (m.gap || !seen.insert({m.index, m.subindex}).second) continue;
      const ObjectEntry* entry = od.find(m.index, m.subindex);
      const OdObject* object = od.find(m.index);
      const OdObject* pdo = od.find(m.pdo_index);
      if (entry == nullptr || object == nullptr) continue;
      // Only what has a number to read: an entry mapped with no bits, more than 8 bytes, a
      // variable length or a REAL of the wrong size (an image may map any of these) is no signal.
      if (!entry_number(od, m.index, m.subindex)) continue;
      std::size_t mapped_in_pdo = 0;
      for (const auto& other : layout->entries) {
        if (other.pdo_index == m.pdo_index && !other.gap) ++mapped_in_pdo;
      }
      std::string name;
      if (mapped_in_pdo == 1 && pdo != nullptr) {
        name = snake_case(pdo->name);
      } else if (object->code == ObjectCode::var) {
        name = snake_case(object->name);
      } else {
        name = snake_case(object->name + " " + entry->name);
      }
      if (name.empty()) name = fmt::format("x{:04x}_{:02x}", m.index, m.subindex);
      std::string unique = name;
      for (int n = 2; !used.insert(unique).second; ++n)
        unique = fmt::format("{}_{}", name, n);
      GeneratedSignal g;
      g.info.name = unique;
      g.info.direction =
          pd.direction == PdoDirection::rx ? SignalDirection::output : SignalDirection::input;
      g.info.type = signal_type_name(*entry);
      g.index = m.index;
      g.subindex = m.subindex;
      out.push_back(std::move(g));
    }
  }
  return out;
}

}  // namespace ecat::sim::devices

namespace ecat::sim {

bool EscPreset::empty() const noexcept {
  return !type && !revision && !build && !fmmu_count && !sync_manager_count && !ram_size_kib &&
         !ports && !features && !sii_busy_ns && !sii_read_bytes && !sii_address_bytes &&
         !sii_emulation && !dl_control && !enhanced_link_detection && al_refusals.empty();
}

void EscPreset::apply(EscHardware& hw) const {
  if (type) {
    hw.type = *type;
    const EscTypeDefaults defaults = esc_type_defaults(*type);
    hw.sii_reads_8_bytes = defaults.sii_reads_8_bytes;
    hw.dl_control = defaults.dl_control;
  }
  if (revision) hw.revision = *revision;
  if (build) hw.build = *build;
  if (fmmu_count) hw.fmmu_count = *fmmu_count;
  if (sync_manager_count) hw.sync_manager_count = *sync_manager_count;
  if (ram_size_kib) hw.ram_size_kib = *ram_size_kib;
  if (ports) hw.ports = wire::PortDescriptor::decode(*ports);
  if (features) {
    hw.features = wire::EscFeatures::decode(*features);
    hw.dc_supported = hw.features.dc_supported;
  }
  if (sii_busy_ns) hw.sii_busy_ns = *sii_busy_ns;
  if (sii_read_bytes) hw.sii_reads_8_bytes = *sii_read_bytes == 8;
  if (sii_address_bytes) hw.sii_two_address_bytes = *sii_address_bytes == 2;
  if (sii_emulation) hw.sii_emulation = *sii_emulation;
  if (dl_control) hw.dl_control = *dl_control;
  if (enhanced_link_detection) hw.enhanced_link_detection = *enhanced_link_detection;
  if (!al_refusals.empty()) hw.al_refusals = al_refusals;
}

}  // namespace ecat::sim

namespace ecat::sim::devices {

OdObject make_sm_parameter(std::uint16_t index, std::uint16_t sync_type, std::uint16_t supported,
                           std::uint32_t min_cycle_ns) {
  return make_record(
      index, index == 0x1C32 ? "SM output parameter" : "SM input parameter",
      {make_entry_of(0x01, "Sync mode", DataType::unsigned16, kAccessReadWrite, sync_type),
       make_entry_of(0x02, "Cycle time", DataType::unsigned32, kAccessReadWrite, std::uint32_t{0}),
       make_entry_of(0x04, "Sync modes supported", DataType::unsigned16, kAccessRead, supported),
       make_entry_of(0x05, "Minimum cycle time", DataType::unsigned32, kAccessRead, min_cycle_ns),
       make_entry_of(0x06, "Calc and copy time", DataType::unsigned32, kAccessRead,
                     std::uint32_t{0}),
       make_entry_of(0x0C, "Cycle time too small", DataType::unsigned16, kAccessRead,
                     std::uint16_t{0}),
       make_entry_of(0x20, "Sync error", DataType::boolean, kAccessRead, false)});
}

OdObject make_restore_defaults(std::vector<std::uint16_t> objects) {
  constexpr std::uint32_t kLoad = 0x64616F6C;  // "load"
  auto entry =
      make_entry_of(1, "SubIndex 001", DataType::unsigned32, kAccessReadWrite, std::uint32_t{0});
  entry.on_write = [](const ObjectEntry&, wire::Bytes value, const AccessContext&) -> SdoStatus {
    if (from_le_bytes<std::uint32_t>(value).value_or(0) != kLoad) {
      return wire::SdoAbortCode::cannot_store;
    }
    return {};
  };
  entry.on_written = [objects = std::move(objects)](ObjectEntry& self,
                                                    const AccessContext& context) {
    self.value = to_le_bytes(std::uint32_t{0});
    if (context.dictionary == nullptr) return;
    for (auto index : objects) {
      OdObject* object = context.dictionary->find(index);
      if (object == nullptr) continue;
      for (auto& e : object->entries) {
        if (!e.default_value.empty()) e.value = e.default_value;
      }
    }
  };
  return make_record(0x1011, "Restore default parameters", {std::move(entry)});
}

}  // namespace ecat::sim::devices
