// The CoE object dictionary of a simulated slave (CiA 301 / ETG.1000.6): objects (VAR, ARRAY,
// RECORD) with typed entries, ETG object access per AL state, PDO-mappable flags, values with
// default/minimum/maximum, and per-entry hooks through which the device's firmware computes values
// on read and validates or reacts to writes.
//
// Two kinds of access:
//  - SDO access (sdo_read / sdo_write / complete-access variants) is what the CoE server uses: it
//    applies the access rights for the AL state, length and range checks and the hooks, and
//    answers with an SDO abort code when it refuses.
//  - Device access (value / set_value / get<T> / set<T>) is what device code uses: plain reads
//    and writes of the stored bytes, no access rights, no hooks.
//
// Values are stored little-endian, as they travel on the wire. Entries shorter than a byte
// (BOOLEAN, BIT1..BIT8) store one byte.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/sdo_abort.hpp>
#include <ecat/wire/sdo_info.hpp>

namespace ecat::sim {

// CoE data types (ETG.1000.6 Table 64, ETG.1020): the index of the type's definition object.
enum class DataType : std::uint16_t {
  boolean = 0x0001,
  integer8 = 0x0002,
  integer16 = 0x0003,
  integer32 = 0x0004,
  unsigned8 = 0x0005,
  unsigned16 = 0x0006,
  unsigned32 = 0x0007,
  real32 = 0x0008,
  visible_string = 0x0009,
  octet_string = 0x000A,
  unicode_string = 0x000B,
  time_of_day = 0x000C,
  time_difference = 0x000D,
  domain = 0x000F,
  integer24 = 0x0010,
  real64 = 0x0011,
  integer40 = 0x0012,
  integer48 = 0x0013,
  integer56 = 0x0014,
  integer64 = 0x0015,
  unsigned24 = 0x0016,
  unsigned40 = 0x0018,
  unsigned48 = 0x0019,
  unsigned56 = 0x001A,
  unsigned64 = 0x001B,
  guid = 0x001D,
  byte = 0x001E,
  word = 0x001F,
  dword = 0x0020,
  pdo_mapping = 0x0021,  // RECORD type of the PDO mapping objects
  identity = 0x0023,     // RECORD type of 0x1018
  bitarr8 = 0x002D,
  bitarr16 = 0x002E,
  bitarr32 = 0x002F,
  bit1 = 0x0030,
  bit2 = 0x0031,
  bit3 = 0x0032,
  bit4 = 0x0033,
  bit5 = 0x0034,
  bit6 = 0x0035,
  bit7 = 0x0036,
  bit8 = 0x0037,
};

// "BOOLEAN", "UNSIGNED16", "VISIBLE_STRING", ...; "DT0x0nnn" for others.
std::string to_string(DataType type);
// The bit length of a fixed-size type (1 for BOOLEAN and BIT1, 24 for UNSIGNED24 ...); 0 for the
// variable-length types (strings, DOMAIN) and the structure types.
std::uint16_t natural_bit_length(DataType type) noexcept;
// Whether values are compared as signed integers, unsigned integers or floats for range checks.
bool is_signed_integer(DataType type) noexcept;
bool is_unsigned_integer(DataType type) noexcept;  // BOOLEAN, BITn, BYTE/WORD/DWORD included
bool is_real(DataType type) noexcept;
// VISIBLE_STRING, OCTET_STRING, UNICODE_STRING, DOMAIN: a value may be shorter than the entry.
bool is_variable_length(DataType type) noexcept;

using wire::ObjectCode;

// Object access words (the ETG entry description's bits, wire::kAccess*), combined for the usual
// cases.
constexpr std::uint16_t kAccessRead =
    wire::kAccessReadPreop | wire::kAccessReadSafeop | wire::kAccessReadOp;  // "ro"
constexpr std::uint16_t kAccessWrite =
    wire::kAccessWritePreop | wire::kAccessWriteSafeop | wire::kAccessWriteOp;  // "wo"
constexpr std::uint16_t kAccessReadWrite = kAccessRead | kAccessWrite;          // "rw"
// Readable always, writable only in PREOP (PDO assignment and mapping, most settings).
constexpr std::uint16_t kAccessReadWritePreop = kAccessRead | wire::kAccessWritePreop;
constexpr std::uint16_t kAccessRxPdo = wire::kAccessRxPdoMappable;
constexpr std::uint16_t kAccessTxPdo = wire::kAccessTxPdoMappable;
constexpr std::uint16_t kAccessBackup = wire::kAccessBackup;
constexpr std::uint16_t kAccessSettings = wire::kAccessSettings;

// The outcome of an SDO-side access: success, or the SDO abort code the server answers with.
// Hooks return it: `return {};` accepts, `return wire::SdoAbortCode::value_too_high;` refuses.
class SdoStatus {
 public:
  constexpr SdoStatus() = default;
  constexpr SdoStatus(wire::SdoAbortCode code)  // NOLINT(google-explicit-constructor)
      : code_(static_cast<std::uint32_t>(code)) {}
  // Any code, including ones the table does not know (a fault rule may send those).
  static constexpr SdoStatus abort(std::uint32_t code) {
    SdoStatus s;
    s.code_ = code;
    return s;
  }
  constexpr bool ok() const noexcept { return code_ == 0; }
  constexpr std::uint32_t code() const noexcept { return code_; }
  friend constexpr bool operator==(SdoStatus, SdoStatus) = default;

 private:
  std::uint32_t code_ = 0;
};

class ObjectDictionary;

// Who accesses an entry and in which AL state; hooks see it. The dictionary fills in index and
// dictionary, so a hook can look at other entries (a mapping entry checks its subindex 0).
struct AccessContext {
  wire::AlState state = wire::AlState::preop;
  bool complete_access = false;  // part of a complete-access transfer
  std::uint16_t index = 0;
  ObjectDictionary* dictionary = nullptr;
};

struct ObjectEntry;

// Called before an SDO read of the entry: may refresh entry.value (an actual position, a
// measured temperature) or refuse.
using ReadHook = std::function<SdoStatus(ObjectEntry& entry, const AccessContext& context)>;
// Called before an SDO write is stored, with the new value (already checked against length,
// access and range): may refuse it.
using WriteHook = std::function<SdoStatus(const ObjectEntry& entry, wire::Bytes value,
                                          const AccessContext& context)>;
// Called after an SDO write was stored: the device reacts (a controlword, a new mapping).
using WrittenHook = std::function<void(ObjectEntry& entry, const AccessContext& context)>;

struct ObjectEntry {
  std::uint8_t subindex = 0;
  std::string name;
  DataType data_type = DataType::unsigned8;
  // Bits on the wire and in PDOs; for variable-length types the capacity (8 * max bytes).
  std::uint16_t bit_length = 8;
  std::uint16_t access = kAccessRead;  // kAccess* / wire::kAccess* bits
  std::vector<std::uint8_t> value;     // (bit_length + 7) / 8 bytes; strings: the current length
  std::vector<std::uint8_t> default_value;  // empty: none
  std::vector<std::uint8_t> minimum;        // empty: no lower limit (range checks on write)
  std::vector<std::uint8_t> maximum;        // empty: no upper limit
  std::uint32_t unit = 0;                   // CiA 303-2 / ETG.1004 unit code, 0 = none
  ReadHook on_read;
  WriteHook on_write;
  WrittenHook on_written;

  std::size_t byte_length() const noexcept { return (bit_length + 7u) / 8u; }
  bool readable_in(wire::AlState state) const noexcept;
  bool writable_in(wire::AlState state) const noexcept;
  bool rx_mappable() const noexcept { return (access & kAccessRxPdo) != 0; }
  bool tx_mappable() const noexcept { return (access & kAccessTxPdo) != 0; }
};

struct OdObject {
  std::uint16_t index = 0;
  std::string name;
  ObjectCode code = ObjectCode::var;
  // VAR: the entry's type; ARRAY: the element type; RECORD: the structure type (e.g.
  // DataType::identity for 0x1018, DataType::pdo_mapping for 0x16xx/0x1Axx) or any index.
  std::uint16_t data_type = 0;
  // Sorted by subindex. VAR: exactly subindex 0. ARRAY/RECORD: subindex 0 (UNSIGNED8, the number
  // of entries in use) then the entries; a RECORD may leave gaps.
  std::vector<ObjectEntry> entries;

  ObjectEntry* entry(std::uint8_t subindex) noexcept;
  const ObjectEntry* entry(std::uint8_t subindex) const noexcept;
  // The highest subindex the object has (object description "max subindex").
  std::uint8_t max_subindex() const noexcept;
  // ARRAY/RECORD: subindex 0's value (entries in use); VAR: 0.
  std::uint8_t entries_in_use() const noexcept;
};

// ---- Builders for entries and objects ------------------------------------------------------

// An entry of a fixed-size type, value zero (or `value` when given: little-endian bytes).
ObjectEntry make_entry(std::uint8_t subindex, std::string name, DataType type,
                       std::uint16_t access = kAccessRead, std::vector<std::uint8_t> value = {});
// Typed convenience: make_entry_of<std::int32_t>(1, "Target", DataType::integer32, rw, 0).
template <class T>
ObjectEntry make_entry_of(std::uint8_t subindex, std::string name, DataType type,
                          std::uint16_t access, T value);
// A VISIBLE_STRING entry whose capacity is max(capacity, text size) bytes.
ObjectEntry make_string_entry(std::uint8_t subindex, std::string name, std::string_view text,
                              std::uint16_t access = kAccessRead, std::size_t capacity = 0);
// An OCTET_STRING (or DOMAIN) entry holding `bytes`; capacity max(capacity, bytes size).
ObjectEntry make_octet_entry(std::uint8_t subindex, std::string name,
                             std::vector<std::uint8_t> bytes, std::uint16_t access = kAccessRead,
                             std::size_t capacity = 0, DataType type = DataType::octet_string);

// A VAR object holding one entry (its subindex is forced to 0, its name defaults to the
// object's).
OdObject make_var(std::uint16_t index, std::string name, ObjectEntry entry);
// An ARRAY of `capacity` elements of one type: subindex 0 (UNSIGNED8, value `in_use`, or capacity
// when in_use is nullopt; access `sub0_access`) then elements 1..capacity named "SubIndex 001"...
// with `values` (little-endian, one per element given, the rest zero).
OdObject make_array(std::uint16_t index, std::string name, DataType element_type,
                    std::uint8_t capacity, std::uint16_t element_access,
                    std::vector<std::vector<std::uint8_t>> values = {},
                    std::optional<std::uint8_t> in_use = std::nullopt,
                    std::uint16_t sub0_access = kAccessRead);
// A RECORD: subindex 0 (UNSIGNED8 read-only, value = highest subindex of `entries`) then
// `entries` (sorted by subindex here).
OdObject make_record(std::uint16_t index, std::string name, std::vector<ObjectEntry> entries,
                     std::uint16_t data_type = 0);

// ---- Standard communication objects (CiA 301 / ETG.1000.6) --------------------------------

struct Identity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::uint32_t serial_number = 0;
};

OdObject make_device_type(std::uint32_t device_type);      // 0x1000
OdObject make_error_register();                            // 0x1001
OdObject make_device_name(std::string_view name);          // 0x1008
OdObject make_hardware_version(std::string_view version);  // 0x1009
OdObject make_software_version(std::string_view version);  // 0x100A
OdObject make_identity(const Identity& identity);          // 0x1018
// 0x10F1 error settings: 1 local error reaction (u32), 2 sync error counter limit (u16).
OdObject make_error_settings(std::uint32_t local_error_reaction = 0,
                             std::uint16_t sync_error_counter_limit = 4);
// 0x1C00 SyncManager communication types: one UNSIGNED8 per SM (1 mailbox out, 2 mailbox in,
// 3 process data outputs, 4 process data inputs, 0 unused).
OdObject make_sync_manager_types(const std::vector<std::uint8_t>& types);

// ---- The dictionary ----------------------------------------------------------------------------

class ObjectDictionary {
 public:
  // Called after every successful SDO write (entry or complete access), with the object index and
  // the subindex written (0 for complete access). Devices use it to notice mapping changes.
  using ChangeListener = std::function<void(std::uint16_t index, std::uint8_t subindex)>;

  ObjectDictionary() = default;
  // Copies and moves give both dictionaries new generations (see generation()).
  ObjectDictionary(const ObjectDictionary& other);
  ObjectDictionary(ObjectDictionary&& other) noexcept;
  ObjectDictionary& operator=(const ObjectDictionary& other);
  ObjectDictionary& operator=(ObjectDictionary&& other) noexcept;
  ~ObjectDictionary() = default;

  // Adds or replaces an object (entries are sorted by subindex).
  void add(OdObject object);
  bool remove(std::uint16_t index);
  void clear() noexcept;
  // A value unique in the process, renewed whenever add(), remove(), clear(), a copy or a move
  // may have moved or dropped entries: an ObjectEntry* taken from find() stays valid while the
  // generation is unchanged (values change in place). The process-data path resolves its mapped
  // entries once per layout and generation.
  std::uint64_t generation() const noexcept { return generation_; }

  OdObject* find(std::uint16_t index) noexcept;
  const OdObject* find(std::uint16_t index) const noexcept;
  ObjectEntry* find(std::uint16_t index, std::uint8_t subindex) noexcept;
  const ObjectEntry* find(std::uint16_t index, std::uint8_t subindex) const noexcept;
  // Object indices in ascending order.
  std::vector<std::uint16_t> indices() const;
  const std::map<std::uint16_t, OdObject>& objects() const noexcept { return objects_; }
  std::size_t size() const noexcept { return objects_.size(); }

  // The indices of an SDO information OD list: all objects, objects with an RxPDO/TxPDO-mappable
  // entry, with a backup / settings entry. For number_of_objects: the five list lengths.
  std::vector<std::uint16_t> od_list(wire::OdListType type) const;

  // ---- SDO access (the CoE server) ----------------------------------------------------------
  // Reads one entry: object/subindex exist (0x06020000 / 0x06090011), readable in the state
  // (0x06010001 never readable, 0x08000022 not in this state), then the read hook.
  SdoStatus sdo_read(std::uint16_t index, std::uint8_t subindex, const AccessContext& context,
                     std::vector<std::uint8_t>& out);
  // Writes one entry: existence, writable (0x06010002 / 0x08000022), length (0x06070012 too
  // long, 0x06070013 too short; `expedited_unsized` accepts up to 4 bytes for entries of <= 4
  // bytes and uses the entry's length), range (0x06090031 / 0x06090032, 0x06090030 for a BOOLEAN
  // above 1), the write hook, then stores the value and calls the written hook.
  SdoStatus sdo_write(std::uint16_t index, std::uint8_t subindex, wire::Bytes value,
                      const AccessContext& context, bool expedited_unsized = false);
  // The checks sdo_write makes before it sees the value, for a normal transfer announcing `size`
  // bytes: existence, access and length. Servers run it on an initiate download request so that
  // a doomed segmented transfer aborts at once.
  SdoStatus sdo_check_write(std::uint16_t index, std::uint8_t subindex, std::size_t size,
                            const AccessContext& context);
  // Complete access (ARRAY/RECORD only, else 0x06010004) from subindex 0 or 1 (else 0x06010004).
  // From 0 the value starts with subindex 0 padded to 16 bits; the entries follow bit-packed in
  // subindex order, up to subindex 0's value (entries absent in a RECORD are skipped).
  SdoStatus sdo_read_complete(std::uint16_t index, std::uint8_t subindex,
                              const AccessContext& context, std::vector<std::uint8_t>& out);
  // Writes the entries the value holds (for a writable subindex 0: the count it carries; a
  // read-only entry must carry its present value), then subindex 0. Length mismatches abort with
  // 0x06070012 / 0x06070013; subindex 0 is set to 0 before the entries are written so that
  // mapping objects accept the new entries.
  SdoStatus sdo_write_complete(std::uint16_t index, std::uint8_t subindex, wire::Bytes value,
                               const AccessContext& context);

  void set_change_listener(ChangeListener listener) { listener_ = std::move(listener); }

  // ---- Device access (no access rights, no hooks) ------------------------------------------
  // The stored bytes, or nullopt when the entry does not exist.
  std::optional<wire::Bytes> value(std::uint16_t index, std::uint8_t subindex) const;
  // Replaces the stored bytes (for fixed-size types the size must equal byte_length(), for
  // variable-length types be at most that). False when the entry is missing or the size wrong.
  bool set_value(std::uint16_t index, std::uint8_t subindex, wire::Bytes bytes);
  // Typed access for arithmetic T (bool, integers, float, double): little-endian, the entry's
  // byte length must be sizeof(T) (or 1 for bool; 3/5/6/7 bytes for UNSIGNED24 ... read into a
  // wider T and written from it).
  template <class T>
  std::optional<T> get(std::uint16_t index, std::uint8_t subindex) const;
  template <class T>
  bool set(std::uint16_t index, std::uint8_t subindex, T value);
  std::optional<std::string> get_string(std::uint16_t index, std::uint8_t subindex) const;
  bool set_string(std::uint16_t index, std::uint8_t subindex, std::string_view text);

  // Every entry back to its default value (entries without one keep their value).
  void reset_to_defaults();

 private:
  SdoStatus check_write_value(const ObjectEntry& entry, wire::Bytes value) const;
  void notify(std::uint16_t index, std::uint8_t subindex) const;

  std::map<std::uint16_t, OdObject> objects_;
  ChangeListener listener_;
  std::uint64_t generation_ = next_generation();

  static std::uint64_t next_generation() noexcept;
};

// ---- Little-endian value helpers (header-only so templates work for any arithmetic T) -------

namespace detail {
template <class T, class = void>
struct UnsignedOfImpl {
  using type = std::make_unsigned_t<T>;
};
template <>
struct UnsignedOfImpl<bool> {
  using type = std::uint8_t;
};
template <>
struct UnsignedOfImpl<float> {
  using type = std::uint32_t;
};
template <>
struct UnsignedOfImpl<double> {
  using type = std::uint64_t;
};
template <class T>
using UnsignedOf = typename UnsignedOfImpl<T>::type;
}  // namespace detail

// The `size` little-endian bytes of value (size <= 8; integers truncated, floats bit-exact).
template <class T>
std::vector<std::uint8_t> to_le_bytes(T value, std::size_t size = sizeof(T)) {
  static_assert(std::is_arithmetic_v<T>);
  std::uint64_t raw = 0;
  if constexpr (std::is_same_v<T, bool>) {
    raw = value ? 1 : 0;
  } else if constexpr (std::is_floating_point_v<T>) {
    raw = std::bit_cast<detail::UnsignedOf<T>>(value);
  } else {
    raw = static_cast<std::uint64_t>(static_cast<detail::UnsignedOf<T>>(value));
  }
  std::vector<std::uint8_t> out(size);
  for (std::size_t i = 0; i < size && i < 8; ++i)
    out[i] = static_cast<std::uint8_t>(raw >> (8 * i));
  return out;
}

// Reads T from 1..8 little-endian bytes; signed T sign-extends from the top bit of the last byte.
template <class T>
std::optional<T> from_le_bytes(wire::Bytes bytes) {
  static_assert(std::is_arithmetic_v<T>);
  if (bytes.empty() || bytes.size() > 8) return std::nullopt;
  std::uint64_t raw = 0;
  for (std::size_t i = 0; i < bytes.size(); ++i)
    raw |= std::uint64_t{bytes[i]} << (8 * i);
  if constexpr (std::is_same_v<T, bool>) {
    return raw != 0;
  } else if constexpr (std::is_floating_point_v<T>) {
    if (bytes.size() != sizeof(T)) return std::nullopt;
    return std::bit_cast<T>(static_cast<detail::UnsignedOf<T>>(raw));
  } else {
    if (bytes.size() > sizeof(T)) return std::nullopt;
    if constexpr (std::is_signed_v<T>) {
      const unsigned bits = static_cast<unsigned>(bytes.size() * 8);
      if (bits < 64 && (raw >> (bits - 1)) != 0) raw |= ~std::uint64_t{0} << bits;
    }
    return static_cast<T>(static_cast<detail::UnsignedOf<T>>(raw));
  }
}

template <class T>
ObjectEntry make_entry_of(std::uint8_t subindex, std::string name, DataType type,
                          std::uint16_t access, T value) {
  ObjectEntry entry = make_entry(subindex, std::move(name), type, access);
  entry.value = to_le_bytes(value, entry.byte_length());
  return entry;
}

template <class T>
std::optional<T> ObjectDictionary::get(std::uint16_t index, std::uint8_t subindex) const {
  const ObjectEntry* entry = find(index, subindex);
  if (entry == nullptr) return std::nullopt;
  if constexpr (std::is_floating_point_v<T>) {
    if (entry->value.size() != sizeof(T)) return std::nullopt;
  }
  return from_le_bytes<T>(entry->value);
}

template <class T>
bool ObjectDictionary::set(std::uint16_t index, std::uint8_t subindex, T value) {
  const ObjectEntry* entry = find(index, subindex);
  if (entry == nullptr || entry->byte_length() > 8) return false;
  if constexpr (std::is_floating_point_v<T>) {
    if (entry->byte_length() != sizeof(T)) return false;
  }
  const auto bytes = to_le_bytes(value, entry->byte_length());
  return set_value(index, subindex, bytes);
}

}  // namespace ecat::sim
