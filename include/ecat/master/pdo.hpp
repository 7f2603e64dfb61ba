// The process-data model of one slave: which PDOs are assigned to which SyncManager, what each PDO
// maps, and where every mapped entry sits in its SyncManager's image.
//
// Two sources build it: the SII (TXPDO/RXPDO categories, the layout a device has by default) and
// CoE (the values of the assignment objects 0x1C10+n and the mapping objects 0x1600../0x1A00..,
// uploaded by the caller). The inverse, coe_mapping_writes(), turns a layout a user chose into the
// SDO downloads that configure it in PREOP.
//
// Everything here is pure: values in, values out, no I/O.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {

// CoE basic data type codes (ETG.1000.6 Table 64, CiA 301 Table 44), as the SII PDO entries and
// the SDO information service carry them.
namespace coe_type {
constexpr std::uint16_t kNone = 0x0000;  // padding entries carry 0
constexpr std::uint16_t kBoolean = 0x0001;
constexpr std::uint16_t kInteger8 = 0x0002;
constexpr std::uint16_t kInteger16 = 0x0003;
constexpr std::uint16_t kInteger32 = 0x0004;
constexpr std::uint16_t kUnsigned8 = 0x0005;
constexpr std::uint16_t kUnsigned16 = 0x0006;
constexpr std::uint16_t kUnsigned32 = 0x0007;
constexpr std::uint16_t kReal32 = 0x0008;
constexpr std::uint16_t kVisibleString = 0x0009;
constexpr std::uint16_t kOctetString = 0x000A;
constexpr std::uint16_t kUnicodeString = 0x000B;
constexpr std::uint16_t kInteger24 = 0x0010;
constexpr std::uint16_t kReal64 = 0x0011;
constexpr std::uint16_t kInteger40 = 0x0012;
constexpr std::uint16_t kInteger48 = 0x0013;
constexpr std::uint16_t kInteger56 = 0x0014;
constexpr std::uint16_t kInteger64 = 0x0015;
constexpr std::uint16_t kUnsigned24 = 0x0016;
constexpr std::uint16_t kUnsigned40 = 0x0018;
constexpr std::uint16_t kUnsigned48 = 0x0019;
constexpr std::uint16_t kUnsigned56 = 0x001A;
constexpr std::uint16_t kUnsigned64 = 0x001B;
constexpr std::uint16_t kByte = 0x001E;
constexpr std::uint16_t kWord = 0x001F;
constexpr std::uint16_t kDword = 0x0020;
constexpr std::uint16_t kBitArr8 = 0x002D;
constexpr std::uint16_t kBitArr16 = 0x002E;
constexpr std::uint16_t kBitArr32 = 0x002F;
constexpr std::uint16_t kBit1 = 0x0030;  // kBit1 + n - 1 is BITn, up to kBit8
constexpr std::uint16_t kBit8 = 0x0037;
}  // namespace coe_type

// "BOOLEAN", "INTEGER16", "BIT2", ...; "0x00xx" for codes without a name here.
std::string coe_type_name(std::uint16_t code);

// Process data as the master sees it: inputs come from the slave (TxPDOs), outputs go to it
// (RxPDOs).
enum class PdoDirection : std::uint8_t { input, output };
std::string_view to_string(PdoDirection direction) noexcept;

// The object-dictionary index ranges of PDO mapping objects (CiA 301): 0x1600..0x17FF RxPDOs,
// 0x1A00..0x1BFF TxPDOs. nullopt for an index outside both.
std::optional<PdoDirection> pdo_direction_of_index(std::uint16_t pdo_index) noexcept;

// The CoE object assigning PDOs to SyncManager `sync_manager` (0x1C10 + n).
constexpr std::uint16_t pdo_assignment_object(std::uint8_t sync_manager) noexcept {
  return static_cast<std::uint16_t>(0x1C10 + sync_manager);
}

constexpr std::uint8_t kSyncManagerUnassigned = 0xFF;
constexpr std::uint8_t kMaxSyncManagers = 16;

struct PdoEntry {
  std::uint16_t index = 0;  // 0: a padding entry (a gap of bit_length bits)
  std::uint8_t subindex = 0;
  std::uint8_t bit_length = 0;
  std::uint16_t data_type = coe_type::kNone;  // see coe_type; kNone when not known
  std::string name;                           // as the SII / object dictionary spells it
  // Where the entry starts in its SyncManager's image; set by make_pdo_layout.
  std::uint32_t bit_offset = 0;

  bool padding() const noexcept { return index == 0; }
  bool operator==(const PdoEntry&) const = default;
};

struct Pdo {
  std::uint16_t index = 0;
  PdoDirection direction = PdoDirection::input;
  std::uint8_t sync_manager = kSyncManagerUnassigned;
  std::string name;
  std::vector<PdoEntry> entries;
  bool mandatory = false;      // the device needs it assigned
  bool fixed_content = false;  // its mapping cannot be changed
  // Where the PDO starts in its SyncManager's image; set by make_pdo_layout.
  std::uint32_t bit_offset = 0;

  std::uint32_t bit_length() const noexcept;
  bool operator==(const Pdo&) const = default;
};

// One SyncManager's process data: the PDOs assigned to it, in order.
struct SyncManagerPdos {
  std::uint8_t sync_manager = 0;
  PdoDirection direction = PdoDirection::input;
  std::vector<Pdo> pdos;
  std::uint32_t bit_length = 0;  // sum of the PDOs' bit lengths

  // The SyncManager's length: ceil(bit_length / 8).
  std::uint16_t byte_length() const noexcept {
    return static_cast<std::uint16_t>((bit_length + 7) / 8);
  }
  bool operator==(const SyncManagerPdos&) const = default;
};

// Where an entry is: its SyncManager, PDO and the entry (offsets inside).
struct PdoEntryLocation {
  const SyncManagerPdos* sync_manager = nullptr;
  const Pdo* pdo = nullptr;
  const PdoEntry* entry = nullptr;
};

struct PdoLayout {
  // Only SyncManagers with a direction: those with assigned PDOs, plus those a CoE assignment
  // listed empty. Ascending SyncManager number.
  std::vector<SyncManagerPdos> sync_managers;
  // PDOs the device describes but that are not assigned (SII PDOs without a SyncManager),
  // kept for names and data types and for remapping.
  std::vector<Pdo> unassigned;

  const SyncManagerPdos* find_sync_manager(std::uint8_t sync_manager) const noexcept;
  // Assigned PDOs first, then unassigned ones.
  const Pdo* find_pdo(std::uint16_t pdo_index) const noexcept;
  // The first assigned, non-padding entry mapping index:subindex; nullopt when none does.
  std::optional<PdoEntryLocation> find_entry(std::uint16_t index,
                                             std::uint8_t subindex) const noexcept;
  std::uint32_t bit_length(PdoDirection direction) const noexcept;
  bool empty() const noexcept { return sync_managers.empty(); }
  bool operator==(const PdoLayout&) const = default;
};

// Builds a layout from assigned PDOs (their sync_manager set, in assignment order per SM) and
// unassigned ones (sync_manager == kSyncManagerUnassigned): groups them per SyncManager,
// computes the bit offsets of every PDO and entry and each SM's length. Fails naming the PDO
// when a SyncManager number is 16 or more, when one SyncManager would carry both inputs and
// outputs, when a PDO index is assigned twice or when an image would exceed 65535 bytes.
// `empty_sync_managers` adds SyncManagers without PDOs (a CoE assignment that lists none).
Result<PdoLayout> make_pdo_layout(
    std::vector<Pdo> pdos,
    const std::vector<std::pair<std::uint8_t, PdoDirection>>& empty_sync_managers = {});

// The default layout the SII describes: every TxPDO (input) and RxPDO (output) whose SyncManager
// byte is set is assigned to that SyncManager in category order (as SOEM and the reference do;
// the SII has no other notion of "assigned"); PDOs with SyncManager 0xFF are unassigned. Names
// come from the STRINGS category. Truncated categories are taken as far as they go (the decoder
// keeps the complete entries). Padding entries (index 0) are kept, so offsets stay right.
Result<PdoLayout> pdo_layout_from_sii(const wire::SiiImage& sii);

// ---- CoE ---------------------------------------------------------------------------------------

// The value of one assignment object 0x1C10+n: the PDO indices of subindices 1..count.
struct CoePdoAssignment {
  std::uint8_t sync_manager = 0;
  std::vector<std::uint16_t> pdo_indices{};
  // The SyncManager's direction, from the SII SyncManager type (3 outputs, 4 inputs) when known;
  // nullopt infers it from the PDO index ranges (0x16xx output, 0x1Axx input).
  std::optional<PdoDirection> direction{};
};

// The value of one mapping object: entries 1..count, each index << 16 | subindex << 8 | bits.
struct CoePdoMapping {
  std::uint16_t pdo_index = 0;
  std::vector<std::uint32_t> entries{};
  std::string name{};  // the object's name (SDO information), if known
};

// Names and data types of mapped objects (from SDO information), keyed by index:subindex.
struct CoeEntryInfo {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::uint16_t data_type = coe_type::kNone;
  std::string name{};
};

struct CoePdoConfiguration {
  std::vector<CoePdoAssignment> assignments{};
  std::vector<CoePdoMapping> mappings{};
  std::vector<CoeEntryInfo> entry_info{};
};

constexpr std::uint32_t coe_mapping_entry(std::uint16_t index, std::uint8_t subindex,
                                          std::uint8_t bit_length) noexcept {
  return (static_cast<std::uint32_t>(index) << 16) | (static_cast<std::uint32_t>(subindex) << 8) |
         bit_length;
}

// The layout CoE describes. Every assigned PDO needs a mapping in `coe.mappings`, except that a
// PDO `known` (usually the SII layout) describes is taken from there (fixed PDOs whose mapping
// object the device does not expose). Entry names and data types come from `coe.entry_info`,
// else from the same index:subindex in `known`, else they stay empty / kNone. PDO names come
// from the mapping, else from `known`. Fails naming the SyncManager or PDO: an assigned PDO with
// no mapping, an entry with bit length 0, a direction that cannot be inferred.
Result<PdoLayout> pdo_layout_from_coe(const CoePdoConfiguration& coe,
                                      const PdoLayout* known = nullptr);

// One SDO download (expedited or segmented; the CoE client picks).
struct SdoWrite {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::vector<std::uint8_t> data{};  // little-endian value
  bool complete_access = false;

  bool operator==(const SdoWrite&) const = default;
};
// "0x1c12:00 = 00" (hex bytes), for logs and errors.
std::string to_string(const SdoWrite& write);

struct CoeMappingOptions {
  // Rewrite the mapping objects of PDOs with fixed content too (devices refuse that).
  bool write_fixed_mappings = false;
  // Write the assignment of SyncManagers without a PDO (clears them).
  bool write_empty_assignments = true;
};

// The downloads that put `layout` into a device in PREOP, in the order ETG.1020 asks for:
//   1. 0x1C1n:00 = 0 for each SyncManager (unassign everything, so mappings become writable)
//   2. for each assigned PDO with a changeable mapping: :00 = 0, :01..:k = entries, :00 = k
//   3. 0x1C1n:01..:m = PDO indices, 0x1C1n:00 = m for each SyncManager
// Fails when a PDO has more than 254 entries or a SyncManager more than 254 PDOs.
Result<std::vector<SdoWrite>> coe_mapping_writes(const PdoLayout& layout,
                                                 CoeMappingOptions options = {});

}  // namespace ecat::master
