// "esi": a device built from an ESI XML description (file=path; product=0x... picks one device
// of a file that describes several). The SII comes from config::esi_to_sii; the object dictionary
// from the ESI's CoE dictionary (objects, data types, default values, access rights, PDO
// mapping flags), with these adjustments a real device's firmware makes:
//  - 0x1018 reports the identity of the Type element (ESI defaults are often placeholders);
//  - the PDO mapping (0x16xx / 0x1Axx) and assignment (0x1C10..0x1C2F) objects get the CiA 301
//    write rules (pdo_mapping.hpp), writable in PREOP when the ESI says so;
//  - an assignment object whose default is empty takes the PDOs the ESI assigns to that
//    SyncManager (the Sm attribute), as a configuration tool would download them.
// A CiA 402 device (ProfileNo 402, with 0x6040 and 0x6041) runs the Cia402Drive model; others
// get one signal per mapped entry.
#include <algorithm>

#include <fmt/format.h>

#include <ecat/config/esi.hpp>

#include "sim/devices/applications.hpp"
#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

std::uint16_t access_bits(const config::EsiEntry& e) {
  const bool read = e.access == "ro" || e.access == "rw" || e.access.empty();
  const bool write = e.access == "rw" || e.access == "wo";
  auto states = [](const std::string& restriction, std::uint16_t preop, std::uint16_t safeop,
                   std::uint16_t op) -> std::uint16_t {
    if (restriction.empty()) return static_cast<std::uint16_t>(preop | safeop | op);
    std::uint16_t bits = 0;
    if (restriction.find("PreOP") != std::string::npos) bits |= preop;
    if (restriction.find("SafeOP") != std::string::npos) bits |= safeop;
    if (restriction.find("_OP") != std::string::npos || restriction == "OP") bits |= op;
    return bits;
  };
  std::uint16_t bits = 0;
  if (read) {
    bits |= states(e.read_restrictions, wire::kAccessReadPreop, wire::kAccessReadSafeop,
                   wire::kAccessReadOp);
  }
  if (write) {
    bits |= states(e.write_restrictions, wire::kAccessWritePreop, wire::kAccessWriteSafeop,
                   wire::kAccessWriteOp);
  }
  if (e.pdo_mapping.find('R') != std::string::npos) bits |= kAccessRxPdo;
  if (e.pdo_mapping.find('T') != std::string::npos) bits |= kAccessTxPdo;
  if (e.backup) bits |= kAccessBackup;
  if (e.setting) bits |= kAccessSettings;
  return bits;
}

ObjectEntry convert_entry(const config::EsiEntry& e) {
  ObjectEntry out;
  out.subindex = e.subindex;
  out.name = e.name;
  out.access = access_bits(e);
  const std::uint16_t basic = config::esi_basic_type(e.type);
  const std::uint32_t bits = std::min<std::uint32_t>(e.bit_size, 0xFFFF);
  if (basic != 0) {
    out.data_type = static_cast<DataType>(basic);
  } else {
    // Arrays of bytes and other unknown types travel as octet strings of their size.
    out.data_type = DataType::octet_string;
  }
  out.bit_length = static_cast<std::uint16_t>(bits != 0 ? bits : natural_bit_length(out.data_type));
  if (out.bit_length == 0) out.bit_length = 8;
  if (is_variable_length(out.data_type)) {
    out.value = e.default_data;
    if (out.value.size() > out.byte_length()) out.value.resize(out.byte_length());
    if (out.data_type == DataType::octet_string && out.value.empty()) {
      out.value.assign(out.byte_length(), 0);
    }
  } else {
    out.value = e.default_data;
    out.value.resize(out.byte_length(), 0);
  }
  if (!e.default_data.empty()) out.default_value = out.value;
  const std::size_t n = out.byte_length();
  if (!is_variable_length(out.data_type) && n <= 8) {
    if (e.minimum) out.minimum = to_le_bytes(*e.minimum, n);
    if (e.maximum) out.maximum = to_le_bytes(*e.maximum, n);
  }
  return out;
}

OdObject convert_object(const config::EsiObject& o) {
  OdObject object;
  object.index = o.index;
  object.name = o.name;
  switch (o.code) {
    case config::EsiObjectCode::var:
      object.code = ObjectCode::var;
      break;
    case config::EsiObjectCode::array:
      object.code = ObjectCode::array;
      break;
    case config::EsiObjectCode::record:
      object.code = ObjectCode::record;
      break;
  }
  for (const auto& e : o.entries) {
    if (object.code == ObjectCode::var && e.subindex != 0) continue;
    object.entries.push_back(convert_entry(e));
  }
  object.data_type =
      object.entries.empty() ? 0 : static_cast<std::uint16_t>(object.entries.back().data_type);
  return object;
}

std::vector<std::uint8_t> default_of(const config::EsiObject& o, std::uint8_t subindex) {
  for (const auto& e : o.entries) {
    if (e.subindex == subindex) return e.default_data;
  }
  return {};
}

bool writable_in_preop(const config::EsiObject& o) {
  for (const auto& e : o.entries) {
    if (e.subindex != 0 && (access_bits(e) & wire::kAccessWritePreop) != 0) return true;
  }
  return false;
}

// Replaces the ESI's plain PDO objects with ones that apply the CiA 301 write rules; PDOs and
// process-data SyncManagers the dictionary lacks objects for get fixed ones from the PDO list.
void add_pdo_objects(ObjectDictionary& od, const config::EsiDevice& device,
                     const wire::SiiImage& sii) {
  wire::SiiImage missing;
  missing.strings = sii.strings;
  missing.sync_managers = sii.sync_managers;
  for (const auto& p : sii.rxpdos) {
    if (device.object(p.index) == nullptr) missing.rxpdos.push_back(p);
  }
  for (const auto& p : sii.txpdos) {
    if (device.object(p.index) == nullptr) missing.txpdos.push_back(p);
  }
  add_sii_process_data(od, missing, {false, true, false});
  for (std::size_t sm = 0; sm < device.sync_managers.size(); ++sm) {
    const auto& type = device.sync_managers[sm].type;
    const auto index = static_cast<std::uint16_t>(0x1C10 + sm);
    if ((type != "Outputs" && type != "Inputs") || device.object(index) != nullptr) continue;
    std::vector<std::uint16_t> pdos;
    for (const auto* list : {&device.rxpdos, &device.txpdos}) {
      for (const auto& p : *list) {
        if (p.sync_manager && *p.sync_manager == sm) pdos.push_back(p.index);
      }
    }
    if (pdos.empty()) continue;
    PdoAssignmentOptions options;
    options.capacity = static_cast<std::uint8_t>(std::min<std::size_t>(pdos.size(), 255));
    options.writable = false;
    add_pdo_assignment(od, static_cast<std::uint8_t>(sm),
                       type == "Outputs" ? PdoDirection::rx : PdoDirection::tx, pdos, options);
  }
  for (const auto& o : device.objects) {
    if (!pdo_direction_of(o.index) || o.entries.empty()) continue;
    const auto count = default_of(o, 0);
    const std::uint8_t in_use = count.empty() ? 0 : count[0];
    std::vector<PdoEntryRef> refs;
    for (std::uint8_t s = 1; s <= in_use && s != 0; ++s) {
      refs.push_back(
          PdoEntryRef::decode(from_le_bytes<std::uint32_t>(default_of(o, s)).value_or(0)));
    }
    PdoMappingOptions options;
    options.capacity = static_cast<std::uint8_t>(
        std::min<std::size_t>(std::max(o.entries.size() - 1, refs.size()), 255));
    options.writable = writable_in_preop(o);
    add_pdo_mapping(od, o.index, o.name, refs, options);
  }
  for (std::uint16_t index = 0x1C10; index < 0x1C30; ++index) {
    const config::EsiObject* o = device.object(index);
    if (o == nullptr || o->entries.empty()) continue;
    const auto sm = static_cast<std::uint8_t>(index - 0x1C10);
    const auto count = default_of(*o, 0);
    std::vector<std::uint16_t> pdos;
    for (std::uint8_t s = 1; !count.empty() && s <= count[0] && s != 0; ++s) {
      pdos.push_back(from_le_bytes<std::uint16_t>(default_of(*o, s)).value_or(0));
    }
    PdoDirection direction = PdoDirection::rx;
    bool known = false;
    auto from_esi = [&](const std::vector<config::EsiPdo>& list, PdoDirection d) {
      for (const auto& p : list) {
        if (p.sync_manager && *p.sync_manager == sm) {
          direction = d;
          known = true;
          if (count.empty() || count[0] == 0) pdos.push_back(p.index);
        }
      }
    };
    from_esi(device.rxpdos, PdoDirection::rx);
    from_esi(device.txpdos, PdoDirection::tx);
    if (!known) {
      // No PDO names this SyncManager: take the direction from the SyncManager type.
      if (sm < device.sync_managers.size() && device.sync_managers[sm].type == "Inputs") {
        direction = PdoDirection::tx;
      } else if (sm < device.sync_managers.size() && device.sync_managers[sm].type != "Outputs") {
        continue;  // a mailbox SyncManager: keep the ESI's object as it is
      }
    }
    PdoAssignmentOptions options;
    options.capacity =
        // More than 255 assigned PDOs (a hostile ESI) must not make the bounds cross: clamp is UB
        // then.
        static_cast<std::uint8_t>(
            std::min<std::size_t>(std::max(o->entries.size() - 1, pdos.size()), 255));
    options.writable = writable_in_preop(*o);
    add_pdo_assignment(od, sm, direction, pdos, options);
    if (OdObject* added = od.find(index)) added->name = o->name;
  }
}

}  // namespace

Result<std::unique_ptr<Esc>> make_esi_device(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"product"}); !ok) return ok.error();
  if (config.file.empty()) {
    return Error(Errc::invalid_argument, "profile 'esi' needs file=<path of an ESI XML file>");
  }
  std::optional<std::uint32_t> product;
  if (config.options.count("product") != 0) {
    auto p = option_u32(config, "product", 0);
    if (!p) return p.error();
    product = *p;
  }
  auto file = config::load_esi(config.file);
  if (!file) return file.error().context("profile 'esi'");
  auto device = config::find_esi_device(*file, product);
  if (!device) return device.error().context(fmt::format("profile 'esi': {}", config.file));
  const config::EsiDevice& esi = **device;
  auto sii = config::esi_to_sii(*file, esi);
  if (!sii) return sii.error().context(fmt::format("profile 'esi': {}", config.file));

  StandardConfig cfg;
  cfg.sii = *sii;
  ObjectDictionary& od = cfg.dictionary;
  for (const auto& o : esi.objects) {
    if (!o.entries.empty()) od.add(convert_object(o));
  }
  add_pdo_objects(od, esi, cfg.sii);
  if (od.find(0x1018) != nullptr) {
    od.set<std::uint32_t>(0x1018, 1, cfg.sii.identity.vendor_id);
    od.set<std::uint32_t>(0x1018, 2, cfg.sii.identity.product_code);
    od.set<std::uint32_t>(0x1018, 3, cfg.sii.identity.revision);
  } else {
    od.add(make_identity({cfg.sii.identity.vendor_id, cfg.sii.identity.product_code,
                          cfg.sii.identity.revision, cfg.sii.identity.serial}));
  }
  if (od.find(0x1001) == nullptr) od.add(make_error_register());
  cfg.dc.supported = !esi.dc_op_modes.empty();
  if (esi.mailbox) {
    cfg.coe.sdo_info = esi.mailbox->sdo_info;
    cfg.coe.complete_access = esi.mailbox->complete_access;
  }
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();

  EscHardware hw = hardware_for(cfg.sii, 8);
  if (esi.fmmu_count != 0) hw.fmmu_count = esi.fmmu_count;
  if (esi.sync_manager_count != 0) hw.sync_manager_count = esi.sync_manager_count;
  if (esi.dpram_size > 0x1000) {
    hw.ram_size_kib = static_cast<std::uint8_t>(
        std::clamp<std::uint32_t>((esi.dpram_size - 0x1000) / 1024, 1, 60));
  }
  const wire::SiiImage image = cfg.sii;
  const bool drive =
      esi.profile_no == 402 && od.find(0x6040) != nullptr && od.find(0x6041) != nullptr;
  std::unique_ptr<Application> app;
  if (drive) {
    app = std::make_unique<Cia402Application>(std::move(cfg));
  } else {
    app = std::make_unique<PdoSignalDevice>(std::move(cfg));
  }
  return build_device(config, hw, image, std::move(app));
}

}  // namespace ecat::sim::devices
