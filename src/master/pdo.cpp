#include <algorithm>
#include <map>
#include <set>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/pdo.hpp>

namespace ecat::master {

std::string coe_type_name(std::uint16_t code) {
  switch (code) {
    case coe_type::kNone:
      return "NONE";
    case coe_type::kBoolean:
      return "BOOLEAN";
    case coe_type::kInteger8:
      return "INTEGER8";
    case coe_type::kInteger16:
      return "INTEGER16";
    case coe_type::kInteger32:
      return "INTEGER32";
    case coe_type::kUnsigned8:
      return "UNSIGNED8";
    case coe_type::kUnsigned16:
      return "UNSIGNED16";
    case coe_type::kUnsigned32:
      return "UNSIGNED32";
    case coe_type::kReal32:
      return "REAL32";
    case coe_type::kVisibleString:
      return "VISIBLE_STRING";
    case coe_type::kOctetString:
      return "OCTET_STRING";
    case coe_type::kUnicodeString:
      return "UNICODE_STRING";
    case coe_type::kInteger24:
      return "INTEGER24";
    case coe_type::kReal64:
      return "REAL64";
    case coe_type::kInteger40:
      return "INTEGER40";
    case coe_type::kInteger48:
      return "INTEGER48";
    case coe_type::kInteger56:
      return "INTEGER56";
    case coe_type::kInteger64:
      return "INTEGER64";
    case coe_type::kUnsigned24:
      return "UNSIGNED24";
    case coe_type::kUnsigned40:
      return "UNSIGNED40";
    case coe_type::kUnsigned48:
      return "UNSIGNED48";
    case coe_type::kUnsigned56:
      return "UNSIGNED56";
    case coe_type::kUnsigned64:
      return "UNSIGNED64";
    case coe_type::kByte:
      return "BYTE";
    case coe_type::kWord:
      return "WORD";
    case coe_type::kDword:
      return "DWORD";
    case coe_type::kBitArr8:
      return "BITARR8";
    case coe_type::kBitArr16:
      return "BITARR16";
    case coe_type::kBitArr32:
      return "BITARR32";
    default:
      break;
  }
  if (code >= coe_type::kBit1 && code <= coe_type::kBit8) {
    return fmt::format("BIT{}", code - coe_type::kBit1 + 1);
  }
  return fmt::format("0x{:04x}", code);
}

std::string_view to_string(PdoDirection direction) noexcept {
  return direction == PdoDirection::input ? "input" : "output";
}

std::optional<PdoDirection> pdo_direction_of_index(std::uint16_t pdo_index) noexcept {
  if (pdo_index >= 0x1600 && pdo_index <= 0x17FF) return PdoDirection::output;
  if (pdo_index >= 0x1A00 && pdo_index <= 0x1BFF) return PdoDirection::input;
  return std::nullopt;
}

std::uint32_t Pdo::bit_length() const noexcept {
  std::uint32_t bits = 0;
  for (const auto& e : entries)
    bits += e.bit_length;
  return bits;
}

const SyncManagerPdos* PdoLayout::find_sync_manager(std::uint8_t sync_manager) const noexcept {
  for (const auto& sm : sync_managers) {
    if (sm.sync_manager == sync_manager) return &sm;
  }
  return nullptr;
}

const Pdo* PdoLayout::find_pdo(std::uint16_t pdo_index) const noexcept {
  for (const auto& sm : sync_managers) {
    for (const auto& pdo : sm.pdos) {
      if (pdo.index == pdo_index) return &pdo;
    }
  }
  for (const auto& pdo : unassigned) {
    if (pdo.index == pdo_index) return &pdo;
  }
  return nullptr;
}

std::optional<PdoEntryLocation> PdoLayout::find_entry(std::uint16_t index,
                                                      std::uint8_t subindex) const noexcept {
  for (const auto& sm : sync_managers) {
    for (const auto& pdo : sm.pdos) {
      for (const auto& e : pdo.entries) {
        if (!e.padding() && e.index == index && e.subindex == subindex) {
          return PdoEntryLocation{&sm, &pdo, &e};
        }
      }
    }
  }
  return std::nullopt;
}

std::uint32_t PdoLayout::bit_length(PdoDirection direction) const noexcept {
  std::uint32_t bits = 0;
  for (const auto& sm : sync_managers) {
    if (sm.direction == direction) bits += sm.bit_length;
  }
  return bits;
}

namespace {

std::string pdo_label(const Pdo& pdo) {
  return fmt::format("{} 0x{:04x}{}", pdo.direction == PdoDirection::input ? "TxPDO" : "RxPDO",
                     pdo.index, pdo.name.empty() ? "" : fmt::format(" \"{}\"", pdo.name));
}

constexpr std::uint32_t kMaxImageBits = 0xFFFFu * 8u;

}  // namespace

Result<PdoLayout> make_pdo_layout(
    std::vector<Pdo> pdos,
    const std::vector<std::pair<std::uint8_t, PdoDirection>>& empty_sync_managers) {
  PdoLayout layout;
  std::map<std::uint8_t, SyncManagerPdos> by_sm;
  std::map<std::uint16_t, const Pdo*> assigned_indices;
  for (const auto& [sm, direction] : empty_sync_managers) {
    if (sm >= kMaxSyncManagers) {
      return Error(Errc::out_of_range,
                   fmt::format("SyncManager {} is beyond the 16 an ESC can have", sm));
    }
    auto& group = by_sm[sm];
    group.sync_manager = sm;
    group.direction = direction;
  }
  for (auto& pdo : pdos) {
    if (pdo.sync_manager == kSyncManagerUnassigned) {
      layout.unassigned.push_back(std::move(pdo));
      continue;
    }
    if (pdo.sync_manager >= kMaxSyncManagers) {
      return Error(Errc::out_of_range,
                   fmt::format("{} is assigned to SyncManager {}, beyond the 16 an ESC can have",
                               pdo_label(pdo), pdo.sync_manager));
    }
    auto [it, inserted] = by_sm.try_emplace(pdo.sync_manager);
    SyncManagerPdos& group = it->second;
    if (inserted) {
      group.sync_manager = pdo.sync_manager;
      group.direction = pdo.direction;
    } else if (group.direction != pdo.direction) {
      return Error(Errc::invalid_argument,
                   fmt::format("{} is assigned to SyncManager {}, which carries {}s",
                               pdo_label(pdo), pdo.sync_manager, to_string(group.direction)));
    }
    for (const auto& [sm, other] : by_sm) {
      for (const auto& p : other.pdos) {
        if (p.index == pdo.index) {
          return Error(Errc::invalid_argument,
                       fmt::format("{} is assigned twice (SyncManager {} and {})", pdo_label(pdo),
                                   sm, pdo.sync_manager));
        }
      }
    }
    pdo.bit_offset = group.bit_length;
    std::uint32_t offset = group.bit_length;
    for (auto& e : pdo.entries) {
      e.bit_offset = offset;
      offset += e.bit_length;
    }
    if (offset > kMaxImageBits) {
      return Error(Errc::out_of_range,
                   fmt::format("SyncManager {} would hold {} bits with {}, more than 65535 bytes",
                               pdo.sync_manager, offset, pdo_label(pdo)));
    }
    group.bit_length = offset;
    group.pdos.push_back(std::move(pdo));
  }
  for (auto& [sm, group] : by_sm)
    layout.sync_managers.push_back(std::move(group));
  return layout;
}

namespace {

Pdo pdo_from_sii(const wire::SiiImage& sii, const wire::SiiPdo& in, PdoDirection direction) {
  Pdo pdo;
  pdo.index = in.index;
  pdo.direction = direction;
  pdo.sync_manager = in.sync_manager;
  pdo.name = wire::sii_string_to_utf8(sii.string(in.name_index));
  pdo.mandatory = (in.flags & wire::sii_pdo_flag::kMandatory) != 0;
  pdo.fixed_content = (in.flags & wire::sii_pdo_flag::kFixedContent) != 0;
  for (const auto& e : in.entries) {
    PdoEntry entry;
    entry.index = e.index;
    entry.subindex = e.subindex;
    entry.bit_length = e.bit_length;
    entry.data_type = e.padding() ? coe_type::kNone : e.data_type;
    entry.name = e.padding() ? std::string() : wire::sii_string_to_utf8(sii.string(e.name_index));
    pdo.entries.push_back(std::move(entry));
  }
  return pdo;
}

}  // namespace

Result<PdoLayout> pdo_layout_from_sii(const wire::SiiImage& sii) {
  std::vector<Pdo> pdos;
  pdos.reserve(sii.txpdos.size() + sii.rxpdos.size());
  // Category order decides offsets within an SM; an SM only ever holds one direction, so
  // appending all TxPDOs then all RxPDOs keeps each SM's PDOs in category order.
  for (const auto& p : sii.txpdos)
    pdos.push_back(pdo_from_sii(sii, p, PdoDirection::input));
  for (const auto& p : sii.rxpdos)
    pdos.push_back(pdo_from_sii(sii, p, PdoDirection::output));
  auto layout = make_pdo_layout(std::move(pdos));
  if (!layout) return layout.error().context("SII process data");
  return layout;
}

namespace {

const PdoEntry* find_known_entry(const PdoLayout* known, std::uint16_t index,
                                 std::uint8_t subindex) {
  if (known == nullptr) return nullptr;
  auto search = [&](const std::vector<Pdo>& pdos) -> const PdoEntry* {
    for (const auto& pdo : pdos) {
      for (const auto& e : pdo.entries) {
        if (!e.padding() && e.index == index && e.subindex == subindex) return &e;
      }
    }
    return nullptr;
  };
  for (const auto& sm : known->sync_managers) {
    if (const auto* e = search(sm.pdos)) return e;
  }
  return search(known->unassigned);
}

}  // namespace

Result<PdoLayout> pdo_layout_from_coe(const CoePdoConfiguration& coe, const PdoLayout* known) {
  std::vector<Pdo> pdos;
  std::vector<std::pair<std::uint8_t, PdoDirection>> empty;
  std::set<std::uint8_t> seen_sms;
  for (const auto& assignment : coe.assignments) {
    const std::uint16_t object = pdo_assignment_object(assignment.sync_manager);
    if (assignment.sync_manager >= kMaxSyncManagers) {
      return Error(Errc::out_of_range,
                   fmt::format("PDO assignment for SyncManager {}: an ESC has at most 16",
                               assignment.sync_manager));
    }
    if (!seen_sms.insert(assignment.sync_manager).second) {
      return Error(Errc::invalid_argument,
                   fmt::format("PDO assignment 0x{:04x} given twice", object));
    }
    std::optional<PdoDirection> direction = assignment.direction;
    if (!direction) {
      for (auto index : assignment.pdo_indices) {
        auto d = pdo_direction_of_index(index);
        if (!d) {
          return Error(Errc::invalid_argument,
                       fmt::format("0x{:04x} assigns PDO 0x{:04x}, outside 0x1600..0x17FF "
                                   "(RxPDO) and 0x1A00..0x1BFF (TxPDO): give the direction",
                                   object, index));
        }
        if (direction && *direction != *d) {
          return Error(Errc::invalid_argument,
                       fmt::format("0x{:04x} assigns both RxPDOs and TxPDOs (0x{:04x} is an {})",
                                   object, index, to_string(*d)));
        }
        direction = d;
      }
    }
    if (assignment.pdo_indices.empty()) {
      if (direction) empty.emplace_back(assignment.sync_manager, *direction);
      continue;
    }
    for (auto index : assignment.pdo_indices) {
      Pdo pdo;
      pdo.index = index;
      pdo.direction = *direction;
      pdo.sync_manager = assignment.sync_manager;
      const auto mapping = std::find_if(coe.mappings.begin(), coe.mappings.end(),
                                        [&](const auto& m) { return m.pdo_index == index; });
      const Pdo* known_pdo = known != nullptr ? known->find_pdo(index) : nullptr;
      if (known_pdo != nullptr) {
        pdo.name = known_pdo->name;
        pdo.mandatory = known_pdo->mandatory;
        pdo.fixed_content = known_pdo->fixed_content;
      }
      if (mapping == coe.mappings.end()) {
        if (known_pdo == nullptr) {
          return Error(Errc::not_found,
                       fmt::format("0x{:04x} assigns PDO 0x{:04x} but its mapping is unknown "
                                   "(not uploaded and not in the SII)",
                                   object, index));
        }
        for (auto e : known_pdo->entries)
          pdo.entries.push_back(std::move(e));
      } else {
        if (!mapping->name.empty()) pdo.name = mapping->name;
        for (std::size_t i = 0; i < mapping->entries.size(); ++i) {
          const std::uint32_t raw = mapping->entries[i];
          PdoEntry e;
          e.index = static_cast<std::uint16_t>(raw >> 16);
          e.subindex = static_cast<std::uint8_t>(raw >> 8);
          e.bit_length = static_cast<std::uint8_t>(raw);
          if (e.bit_length == 0) {
            return Error(Errc::malformed,
                         fmt::format("PDO mapping 0x{:04x}:{:02x} = 0x{:08x} maps 0x{:04x}:{:02x} "
                                     "with bit length 0",
                                     index, i + 1, raw, e.index, e.subindex));
          }
          if (!e.padding()) {
            const auto info = std::find_if(
                coe.entry_info.begin(), coe.entry_info.end(),
                [&](const auto& x) { return x.index == e.index && x.subindex == e.subindex; });
            const PdoEntry* k = find_known_entry(known, e.index, e.subindex);
            if (info != coe.entry_info.end()) {
              e.data_type = info->data_type;
              e.name = info->name;
            }
            if (k != nullptr) {
              if (e.data_type == coe_type::kNone) e.data_type = k->data_type;
              if (e.name.empty()) e.name = k->name;
            }
          }
          pdo.entries.push_back(std::move(e));
        }
      }
      pdos.push_back(std::move(pdo));
    }
  }
  if (known != nullptr) {
    for (const auto& pdo : known->unassigned) {
      const bool assigned =
          std::any_of(pdos.begin(), pdos.end(), [&](const Pdo& p) { return p.index == pdo.index; });
      if (!assigned) pdos.push_back(pdo);
    }
    for (const auto& sm : known->sync_managers) {
      for (const auto& pdo : sm.pdos) {
        const bool assigned = std::any_of(pdos.begin(), pdos.end(),
                                          [&](const Pdo& p) { return p.index == pdo.index; });
        if (!assigned) {
          Pdo p = pdo;
          p.sync_manager = kSyncManagerUnassigned;
          pdos.push_back(std::move(p));
        }
      }
    }
  }
  auto layout = make_pdo_layout(std::move(pdos), empty);
  if (!layout) return layout.error().context("CoE process data");
  return layout;
}

std::string to_string(const SdoWrite& write) {
  std::string bytes;
  for (std::size_t i = 0; i < write.data.size(); ++i) {
    if (i != 0) bytes += ' ';
    bytes += fmt::format("{:02x}", write.data[i]);
  }
  return fmt::format("0x{:04x}:{:02x}{} = {}", write.index, write.subindex,
                     write.complete_access ? " (complete access)" : "", bytes);
}

namespace {

SdoWrite write_u8(std::uint16_t index, std::uint8_t sub, std::uint8_t value) {
  return SdoWrite{index, sub, {value}, false};
}
SdoWrite write_u16(std::uint16_t index, std::uint8_t sub, std::uint16_t value) {
  return SdoWrite{
      index, sub, {static_cast<std::uint8_t>(value), static_cast<std::uint8_t>(value >> 8)}, false};
}
SdoWrite write_u32(std::uint16_t index, std::uint8_t sub, std::uint32_t value) {
  return SdoWrite{index,
                  sub,
                  {static_cast<std::uint8_t>(value), static_cast<std::uint8_t>(value >> 8),
                   static_cast<std::uint8_t>(value >> 16), static_cast<std::uint8_t>(value >> 24)},
                  false};
}

constexpr std::size_t kMaxSubentries = 254;  // subindex 0 counts, 0xFF is reserved

}  // namespace

Result<std::vector<SdoWrite>> coe_mapping_writes(const PdoLayout& layout,
                                                 CoeMappingOptions options) {
  std::vector<SdoWrite> writes;
  auto included = [&](const SyncManagerPdos& sm) {
    return !sm.pdos.empty() || options.write_empty_assignments;
  };
  for (const auto& sm : layout.sync_managers) {
    if (sm.pdos.size() > kMaxSubentries) {
      return Error(Errc::out_of_range,
                   fmt::format("SyncManager {} has {} PDOs; an assignment object holds at most {}",
                               sm.sync_manager, sm.pdos.size(), kMaxSubentries));
    }
    if (included(sm)) writes.push_back(write_u8(pdo_assignment_object(sm.sync_manager), 0, 0));
  }
  for (const auto& sm : layout.sync_managers) {
    for (const auto& pdo : sm.pdos) {
      if (pdo.fixed_content && !options.write_fixed_mappings) continue;
      if (pdo.entries.size() > kMaxSubentries) {
        return Error(Errc::out_of_range,
                     fmt::format("{} has {} entries; a mapping object holds at most {}",
                                 pdo_label(pdo), pdo.entries.size(), kMaxSubentries));
      }
      writes.push_back(write_u8(pdo.index, 0, 0));
      for (std::size_t i = 0; i < pdo.entries.size(); ++i) {
        const auto& e = pdo.entries[i];
        writes.push_back(write_u32(pdo.index, static_cast<std::uint8_t>(i + 1),
                                   coe_mapping_entry(e.index, e.subindex, e.bit_length)));
      }
      writes.push_back(write_u8(pdo.index, 0, static_cast<std::uint8_t>(pdo.entries.size())));
    }
  }
  for (const auto& sm : layout.sync_managers) {
    if (!included(sm)) continue;
    const std::uint16_t object = pdo_assignment_object(sm.sync_manager);
    for (std::size_t i = 0; i < sm.pdos.size(); ++i) {
      writes.push_back(write_u16(object, static_cast<std::uint8_t>(i + 1), sm.pdos[i].index));
    }
    writes.push_back(write_u8(object, 0, static_cast<std::uint8_t>(sm.pdos.size())));
  }
  return writes;
}

}  // namespace ecat::master
