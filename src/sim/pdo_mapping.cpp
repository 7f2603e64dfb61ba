#include <algorithm>
#include <array>
#include <cstdio>
#include <cstring>
#include <string>

#include <fmt/format.h>

#include <ecat/sim/pdo_mapping.hpp>

namespace ecat::sim {
namespace {

using wire::SdoAbortCode;

constexpr std::uint16_t kAssignmentBase = 0x1C10;

void copy_bits(wire::Bytes src, std::size_t src_bit, std::span<std::uint8_t> dst,
               std::size_t dst_bit, std::size_t bits) {
  // Never beyond either end.
  bits = std::min({bits, src.size() * 8 - std::min(src.size() * 8, src_bit),
                   dst.size() * 8 - std::min(dst.size() * 8, dst_bit)});
  if (src_bit % 8 == 0 && dst_bit % 8 == 0 && bits >= 8) {
    // Whole bytes at once (most mapped entries are byte-aligned); a few bytes by a loop, which
    // beats a call into the C library per entry per cycle.
    const std::size_t bytes = bits / 8;
    if (bytes <= 8) {
      for (std::size_t k = 0; k < bytes; ++k)
        dst[dst_bit / 8 + k] = src[src_bit / 8 + k];
    } else {
      std::memcpy(dst.data() + dst_bit / 8, src.data() + src_bit / 8, bytes);
    }
    src_bit += bytes * 8;
    dst_bit += bytes * 8;
    bits -= bytes * 8;
  }
  for (std::size_t i = 0; i < bits; ++i) {
    const std::size_t s = src_bit + i;
    const std::size_t d = dst_bit + i;
    const bool bit = ((src[s / 8] >> (s % 8)) & 1u) != 0;
    auto& byte = dst[d / 8];
    byte = static_cast<std::uint8_t>(bit ? (byte | (1u << (d % 8))) : (byte & ~(1u << (d % 8))));
  }
}

std::uint32_t entry_u32(const ObjectEntry& e) {
  return from_le_bytes<std::uint32_t>(e.value).value_or(0);
}
std::uint16_t entry_u16(const ObjectEntry& e) {
  return from_le_bytes<std::uint16_t>(e.value).value_or(0);
}

// Entries of an ARRAY/RECORD other than subindex 0 may only change while subindex 0 is 0.
SdoStatus require_sub0_zero(const AccessContext& context) {
  if (context.dictionary == nullptr) return {};
  const OdObject* object = context.dictionary->find(context.index);
  if (object != nullptr && object->entries_in_use() != 0) {
    return SdoAbortCode::cannot_store_device_state;
  }
  return {};
}

// The total bit length of a mapping object's first `count` entries, or an abort code when one of
// them is not a valid entry for `direction`.
SdoStatus mapping_bits(const ObjectDictionary& od, const OdObject& mapping, PdoDirection direction,
                       std::uint8_t count, std::uint32_t& bits) {
  bits = 0;
  for (std::uint8_t s = 1; s <= count && s != 0; ++s) {
    const ObjectEntry* e = mapping.entry(s);
    if (e == nullptr) return SdoAbortCode::object_not_mappable;
    const PdoEntryRef ref = PdoEntryRef::decode(entry_u32(*e));
    if (auto st = check_pdo_entry(od, direction, ref); !st.ok()) return st;
    bits += ref.bit_length;
  }
  return {};
}

}  // namespace

std::optional<PdoDirection> pdo_direction_of(std::uint16_t pdo_index) noexcept {
  if (pdo_index >= 0x1600 && pdo_index <= 0x17FF) return PdoDirection::rx;
  if (pdo_index >= 0x1A00 && pdo_index <= 0x1BFF) return PdoDirection::tx;
  return std::nullopt;
}

SdoStatus check_pdo_entry(const ObjectDictionary& od, PdoDirection direction, PdoEntryRef entry) {
  if (entry.index == 0) return {};
  if (entry.is_gap()) {
    // A CiA 301 dummy entry: the data type's own length.
    const auto natural = natural_bit_length(static_cast<DataType>(entry.index));
    if (natural != entry.bit_length) return SdoAbortCode::object_not_mappable;
    return {};
  }
  const ObjectEntry* target = od.find(entry.index, entry.subindex);
  if (target == nullptr) return SdoAbortCode::object_not_mappable;
  const bool mappable =
      direction == PdoDirection::rx ? target->rx_mappable() : target->tx_mappable();
  if (!mappable || target->bit_length != entry.bit_length) return SdoAbortCode::object_not_mappable;
  return {};
}

void add_pdo_mapping(ObjectDictionary& od, std::uint16_t pdo_index, std::string name,
                     const std::vector<PdoEntryRef>& entries, PdoMappingOptions options) {
  const PdoDirection direction = pdo_direction_of(pdo_index).value_or(PdoDirection::rx);
  const std::uint16_t access = options.writable ? kAccessReadWritePreop : kAccessRead;
  const std::uint8_t capacity = std::max<std::uint8_t>(
      options.capacity, static_cast<std::uint8_t>(std::min<std::size_t>(entries.size(), 255)));
  std::vector<std::vector<std::uint8_t>> values;
  for (const auto& e : entries)
    values.push_back(to_le_bytes(e.encode()));
  OdObject object =
      make_array(pdo_index, std::move(name), DataType::unsigned32, capacity, access,
                 std::move(values), static_cast<std::uint8_t>(entries.size()), access);
  object.code = ObjectCode::record;
  object.data_type = static_cast<std::uint16_t>(DataType::pdo_mapping);
  for (auto& e : object.entries) {
    if (e.subindex == 0) {
      e.maximum = {capacity};
      e.on_write = [direction, max_bits = options.max_bits](
                       const ObjectEntry&, wire::Bytes value,
                       const AccessContext& context) -> SdoStatus {
        if (value.empty() || value[0] == 0 || context.dictionary == nullptr) return {};
        const OdObject* self = context.dictionary->find(context.index);
        if (self == nullptr) return {};
        std::uint32_t bits = 0;
        if (auto st = mapping_bits(*context.dictionary, *self, direction, value[0], bits);
            !st.ok()) {
          return st;
        }
        if (max_bits != 0 && bits > max_bits) return SdoAbortCode::pdo_length_exceeded;
        return {};
      };
    } else {
      e.on_write = [direction](const ObjectEntry&, wire::Bytes value,
                               const AccessContext& context) -> SdoStatus {
        if (auto st = require_sub0_zero(context); !st.ok()) return st;
        if (context.dictionary == nullptr) return {};
        const auto raw = from_le_bytes<std::uint32_t>(value).value_or(0);
        return check_pdo_entry(*context.dictionary, direction, PdoEntryRef::decode(raw));
      };
    }
  }
  od.add(std::move(object));
}

void add_pdo_assignment(ObjectDictionary& od, std::uint8_t sync_manager, PdoDirection direction,
                        const std::vector<std::uint16_t>& pdos, PdoAssignmentOptions options) {
  const std::uint16_t access = options.writable ? kAccessReadWritePreop : kAccessRead;
  const std::uint8_t capacity = std::max<std::uint8_t>(
      options.capacity, static_cast<std::uint8_t>(std::min<std::size_t>(pdos.size(), 255)));
  std::vector<std::vector<std::uint8_t>> values;
  for (auto p : pdos)
    values.push_back(to_le_bytes(p));
  const auto index = static_cast<std::uint16_t>(kAssignmentBase + sync_manager);
  OdObject object = make_array(
      index, direction == PdoDirection::rx ? "RxPDO assign" : "TxPDO assign", DataType::unsigned16,
      capacity, access, std::move(values), static_cast<std::uint8_t>(pdos.size()), access);
  // Whether `pdo` may be assigned here: it exists and carries this direction's data.
  const auto valid_pdo = [direction](const ObjectDictionary& dict, std::uint16_t pdo) {
    return pdo_direction_of(pdo) == direction && dict.find(pdo) != nullptr;
  };
  for (auto& e : object.entries) {
    if (e.subindex == 0) {
      e.maximum = {capacity};
      e.on_write = [valid_pdo, direction, max_bytes = options.max_bytes](
                       const ObjectEntry&, wire::Bytes value,
                       const AccessContext& context) -> SdoStatus {
        if (value.empty() || value[0] == 0 || context.dictionary == nullptr) return {};
        const ObjectDictionary& dict = *context.dictionary;
        const OdObject* self = dict.find(context.index);
        if (self == nullptr) return {};
        std::uint32_t bits = 0;
        for (std::uint8_t s = 1; s <= value[0] && s != 0; ++s) {
          const ObjectEntry* entry = self->entry(s);
          if (entry == nullptr) return SdoAbortCode::value_range_exceeded;
          const std::uint16_t pdo = entry_u16(*entry);
          if (!valid_pdo(dict, pdo)) return SdoAbortCode::value_range_exceeded;
          const OdObject* mapping = dict.find(pdo);
          std::uint32_t pdo_bits = 0;
          if (auto st =
                  mapping_bits(dict, *mapping, direction, mapping->entries_in_use(), pdo_bits);
              !st.ok()) {
            return st;
          }
          bits += pdo_bits;
        }
        if (max_bytes != 0 && (bits + 7) / 8 > max_bytes) return SdoAbortCode::pdo_length_exceeded;
        return {};
      };
    } else {
      e.on_write = [valid_pdo](const ObjectEntry&, wire::Bytes value,
                               const AccessContext& context) -> SdoStatus {
        if (auto st = require_sub0_zero(context); !st.ok()) return st;
        if (context.dictionary == nullptr) return {};
        const auto pdo = from_le_bytes<std::uint16_t>(value).value_or(0);
        if (pdo != 0 && !valid_pdo(*context.dictionary, pdo)) {
          return SdoAbortCode::value_range_exceeded;
        }
        return {};
      };
    }
  }
  od.add(std::move(object));
}

Result<SyncManagerLayout> process_data_layout(const ObjectDictionary& od, std::uint8_t sm) {
  SyncManagerLayout layout;
  layout.sync_manager = sm;
  const auto assign_index = static_cast<std::uint16_t>(kAssignmentBase + sm);
  const OdObject* assignment = od.find(assign_index);
  if (assignment == nullptr) return layout;
  std::uint32_t bit = 0;
  for (std::uint8_t s = 1; s <= assignment->entries_in_use() && s != 0; ++s) {
    const ObjectEntry* slot = assignment->entry(s);
    if (slot == nullptr) {
      return Error(Errc::malformed, fmt::format("SM{} PDO assignment 0x{:04X} has no subindex {}",
                                                sm, assign_index, s));
    }
    const std::uint16_t pdo = entry_u16(*slot);
    if (pdo == 0) continue;
    const OdObject* mapping = od.find(pdo);
    if (mapping == nullptr) {
      return Error(Errc::not_found,
                   fmt::format("PDO 0x{:04X} assigned to SM{} (0x{:04X}:{:02X}) does not exist",
                               pdo, sm, assign_index, s));
    }
    layout.pdos.push_back(pdo);
    for (std::uint8_t m = 1; m <= mapping->entries_in_use() && m != 0; ++m) {
      const ObjectEntry* me = mapping->entry(m);
      if (me == nullptr) {
        return Error(Errc::malformed,
                     fmt::format("PDO mapping 0x{:04X} has no subindex {}", pdo, m));
      }
      const PdoEntryRef ref = PdoEntryRef::decode(entry_u32(*me));
      MappedEntry out;
      out.pdo_index = pdo;
      out.bit_offset = bit;
      out.bit_length = ref.bit_length;
      out.gap = ref.is_gap();
      if (!out.gap) {
        out.index = ref.index;
        out.subindex = ref.subindex;
        if (od.find(ref.index, ref.subindex) == nullptr) {
          return Error(Errc::not_found,
                       fmt::format("PDO 0x{:04X}:{:02X} maps 0x{:04X}:{:02X}, which does not exist",
                                   pdo, m, ref.index, ref.subindex));
        }
      }
      layout.entries.push_back(out);
      bit += ref.bit_length;
    }
  }
  layout.bit_length = bit;
  layout.byte_length = (bit + 7) / 8;
  return layout;
}

std::vector<ObjectEntry*> resolve_entries(ObjectDictionary& od, const SyncManagerLayout& layout) {
  std::vector<ObjectEntry*> entries;
  entries.reserve(layout.entries.size());
  for (const auto& m : layout.entries)
    entries.push_back(m.gap ? nullptr : od.find(m.index, m.subindex));
  return entries;
}

void pack_inputs(ObjectDictionary& od, const SyncManagerLayout& layout,
                 std::span<ObjectEntry* const> entries, std::span<std::uint8_t> image,
                 bool run_read_hooks) {
  const std::size_t n = std::min(layout.entries.size(), entries.size());
  for (std::size_t i = 0; i < n; ++i) {
    const MappedEntry& m = layout.entries[i];
    ObjectEntry* e = entries[i];
    if (e == nullptr) continue;
    if (run_read_hooks && e->on_read) {
      AccessContext context;
      context.state = wire::AlState::op;
      context.index = m.index;
      context.dictionary = &od;
      (void)e->on_read(*e, context);
    }
    // The entry's bits (at most its length), zero beyond a value shorter than the entry.
    const std::size_t bits = std::min<std::size_t>(e->byte_length() * 8, m.bit_length);
    const std::size_t have = std::min<std::size_t>(e->value.size() * 8, bits);
    copy_bits(e->value, 0, image, m.bit_offset, have);
    static constexpr std::uint8_t kZeros[8] = {};
    for (std::size_t at = have; at < bits; at += 64) {
      copy_bits(kZeros, 0, image, m.bit_offset + at, std::min<std::size_t>(64, bits - at));
    }
  }
}

void pack_inputs(ObjectDictionary& od, const SyncManagerLayout& layout,
                 std::span<std::uint8_t> image, bool run_read_hooks) {
  const auto entries = resolve_entries(od, layout);
  pack_inputs(od, layout, entries, image, run_read_hooks);
}

std::vector<std::pair<std::uint16_t, std::uint8_t>> unpack_outputs(
    const SyncManagerLayout& layout, std::span<ObjectEntry* const> entries, wire::Bytes image) {
  std::vector<std::pair<std::uint16_t, std::uint8_t>> changed;
  const std::size_t n = std::min(layout.entries.size(), entries.size());
  for (std::size_t i = 0; i < n; ++i) {
    const MappedEntry& m = layout.entries[i];
    ObjectEntry* e = entries[i];
    if (e == nullptr) continue;
    // Compared in place first: an unchanged output costs no copy.
    std::array<std::uint8_t, 8> small{};
    std::vector<std::uint8_t> large;
    std::span<std::uint8_t> v;
    if (e->byte_length() <= small.size()) {
      v = std::span<std::uint8_t>(small.data(), e->byte_length());
    } else {
      large.resize(e->byte_length());
      v = large;
    }
    // Element loops, not std::copy_n / std::equal: for the few bytes of an entry these become
    // a memmove and a memcmp call per entry per cycle (a tenth of the simulator's time at 1,024
    // terminals).
    const std::size_t have = std::min(e->value.size(), v.size());
    for (std::size_t k = 0; k < have; ++k)
      v[k] = e->value[k];
    copy_bits(image, m.bit_offset, v, 0, m.bit_length);
    bool same = e->value.size() == v.size();
    for (std::size_t k = 0; same && k < v.size(); ++k)
      same = v[k] == e->value[k];
    if (!same) {
      e->value.assign(v.begin(), v.end());
      changed.emplace_back(m.index, m.subindex);
    }
  }
  return changed;
}

std::vector<std::pair<std::uint16_t, std::uint8_t>> unpack_outputs(ObjectDictionary& od,
                                                                   const SyncManagerLayout& layout,
                                                                   wire::Bytes image) {
  const auto entries = resolve_entries(od, layout);
  return unpack_outputs(layout, entries, image);
}

}  // namespace ecat::sim
