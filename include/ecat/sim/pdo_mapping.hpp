// PDO assignment (0x1C10 + SyncManager) and PDO mapping (0x1600.. RxPDO, 0x1A00.. TxPDO) objects
// of a simulated slave, with the CiA 301 / ETG.1000.6 rules a master meets when it changes them:
//  - writable in PREOP only (0x08000022 in SAFEOP/OP);
//  - entries may only change while subindex 0 is 0 (0x08000022 otherwise, as CANopen devices
//    answer);
//  - a mapping entry must name an existing entry that is PDO-mappable in the PDO's direction,
//    with its bit length (0x06040041), or a gap (index 0 or a data type index 0x0001..0x0007);
//  - subindex 0 may not exceed the capacity (0x06090030), and a mapping may not exceed its
//    maximum length (0x06040042);
//  - an assignment may only name PDOs of its direction that exist (0x06090030), and the assigned
//    PDOs may not exceed the SyncManager's maximum length (0x06040042).
// The process-data layout of a SyncManager follows from these objects (process_data_layout), and
// pack_inputs / unpack_outputs move values between the dictionary and the process image.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::sim {

// rx: outputs (master -> slave, 0x1600..0x17FF, usually SM2 / 0x1C12);
// tx: inputs (slave -> master, 0x1A00..0x1BFF, usually SM3 / 0x1C13).
enum class PdoDirection : std::uint8_t { rx, tx };

// The direction of a PDO mapping object by its index, or nullopt outside both ranges.
std::optional<PdoDirection> pdo_direction_of(std::uint16_t pdo_index) noexcept;

// One entry of a PDO mapping object, as stored: index << 16 | subindex << 8 | bit length.
struct PdoEntryRef {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint8_t bit_length = 0;

  constexpr std::uint32_t encode() const noexcept {
    return (std::uint32_t{index} << 16) | (std::uint32_t{subindex} << 8) | bit_length;
  }
  static constexpr PdoEntryRef decode(std::uint32_t raw) noexcept {
    return {static_cast<std::uint16_t>(raw >> 16), static_cast<std::uint8_t>(raw >> 8),
            static_cast<std::uint8_t>(raw)};
  }
  // A gap in the process data: index 0, or a CiA 301 dummy entry (data type index 1..7).
  constexpr bool is_gap() const noexcept { return index <= 0x0007; }
  friend constexpr bool operator==(const PdoEntryRef&, const PdoEntryRef&) = default;
};

struct PdoMappingOptions {
  std::uint8_t capacity = 8;   // entries the object has (subindex 1..capacity)
  bool writable = true;        // false: a fixed mapping (read-only in every state)
  std::uint32_t max_bits = 0;  // maximum total length of the PDO; 0 = no limit
};

// Adds a PDO mapping object (a RECORD of UNSIGNED32 entries, data type PDO_MAPPING) holding
// `entries`; the direction follows from the index (0x16xx rx, 0x1Axx tx).
void add_pdo_mapping(ObjectDictionary& od, std::uint16_t pdo_index, std::string name,
                     const std::vector<PdoEntryRef>& entries, PdoMappingOptions options = {});

struct PdoAssignmentOptions {
  std::uint8_t capacity = 4;    // PDOs the object can hold
  bool writable = true;         // false: a fixed assignment
  std::uint32_t max_bytes = 0;  // maximum process data of the SyncManager; 0 = no limit
};

// Adds the PDO assignment object 0x1C10 + sm (an ARRAY of UNSIGNED16) holding `pdos`.
void add_pdo_assignment(ObjectDictionary& od, std::uint8_t sync_manager, PdoDirection direction,
                        const std::vector<std::uint16_t>& pdos, PdoAssignmentOptions options = {});

// Whether `entry` may be mapped into a PDO of `direction` (the checks a mapping entry write
// makes); an ok status or the abort code.
SdoStatus check_pdo_entry(const ObjectDictionary& od, PdoDirection direction, PdoEntryRef entry);

// One mapped entry in a SyncManager's process data.
struct MappedEntry {
  std::uint16_t pdo_index = 0;
  std::uint16_t index = 0;  // 0 for a gap
  std::uint8_t subindex = 0;
  std::uint32_t bit_offset = 0;  // from the start of the SyncManager's process data
  std::uint16_t bit_length = 0;
  bool gap = false;

  friend bool operator==(const MappedEntry&, const MappedEntry&) = default;
};

struct SyncManagerLayout {
  std::uint8_t sync_manager = 0;
  std::vector<std::uint16_t> pdos;   // assigned PDOs in order
  std::vector<MappedEntry> entries;  // every mapped entry in order, gaps included
  std::uint32_t bit_length = 0;
  std::uint32_t byte_length = 0;  // (bit_length + 7) / 8: the SyncManager's length
};

// The process data of SyncManager `sm` as its assignment object (0x1C10 + sm) and the assigned
// PDOs' mapping objects say. A SyncManager without an assignment object has an empty layout.
// Fails (not_found / malformed) when an assigned PDO or a mapped object is missing.
Result<SyncManagerLayout> process_data_layout(const ObjectDictionary& od, std::uint8_t sm);

// Copies the mapped entries' values into `image` (the SyncManager's process data), bit-exact;
// gaps and bits beyond the image are left alone. With run_read_hooks, each entry's read hook
// refreshes its value first (state OP).
void pack_inputs(ObjectDictionary& od, const SyncManagerLayout& layout,
                 std::span<std::uint8_t> image, bool run_read_hooks = true);
// Stores the mapped entries' values from `image` into the dictionary (device access: no hooks).
// Returns the entries whose value changed.
std::vector<std::pair<std::uint16_t, std::uint8_t>> unpack_outputs(ObjectDictionary& od,
                                                                   const SyncManagerLayout& layout,
                                                                   wire::Bytes image);

// The dictionary entries `layout` maps, in its order (nullptr for gaps and missing entries):
// resolved once, valid while od.generation() is unchanged. The overloads below take them instead
// of looking every entry up per call (the simulator's cyclic path).
std::vector<ObjectEntry*> resolve_entries(ObjectDictionary& od, const SyncManagerLayout& layout);
void pack_inputs(ObjectDictionary& od, const SyncManagerLayout& layout,
                 std::span<ObjectEntry* const> entries, std::span<std::uint8_t> image,
                 bool run_read_hooks = true);
std::vector<std::pair<std::uint16_t, std::uint8_t>> unpack_outputs(
    const SyncManagerLayout& layout, std::span<ObjectEntry* const> entries, wire::Bytes image);

}  // namespace ecat::sim
