#include <algorithm>
#include <atomic>
#include <cstdio>

#include <ecat/sim/object_dictionary.hpp>

namespace ecat::sim {
namespace {

using wire::SdoAbortCode;

// The access bits of one AL state. INIT and BOOT never see CoE on a real slave; they are treated
// as PREOP so a test can reach the dictionary before the state machine ran.
struct StateBits {
  std::uint16_t read;
  std::uint16_t write;
};

StateBits bits_for(wire::AlState state) noexcept {
  switch (state) {
    case wire::AlState::safeop:
      return {wire::kAccessReadSafeop, wire::kAccessWriteSafeop};
    case wire::AlState::op:
      return {wire::kAccessReadOp, wire::kAccessWriteOp};
    default:
      return {wire::kAccessReadPreop, wire::kAccessWritePreop};
  }
}

// A value decoded for comparison: signed, unsigned or floating point, by data type.
struct Number {
  enum class Kind : std::uint8_t { none, signed_int, unsigned_int, real } kind = Kind::none;
  std::int64_t s = 0;
  std::uint64_t u = 0;
  double d = 0;
};

Number decode_number(DataType type, wire::Bytes bytes) {
  Number n;
  if (bytes.empty() || bytes.size() > 8) return n;
  if (is_real(type)) {
    if (bytes.size() == 4) {
      n.kind = Number::Kind::real;
      n.d = *from_le_bytes<float>(bytes);
    } else if (bytes.size() == 8) {
      n.kind = Number::Kind::real;
      n.d = *from_le_bytes<double>(bytes);
    }
  } else if (is_signed_integer(type)) {
    n.kind = Number::Kind::signed_int;
    n.s = *from_le_bytes<std::int64_t>(bytes);
  } else if (is_unsigned_integer(type)) {
    n.kind = Number::Kind::unsigned_int;
    n.u = *from_le_bytes<std::uint64_t>(bytes);
  }
  return n;
}

// <0, 0, >0 like strcmp; 0 when the values cannot be compared.
int compare(const Number& a, const Number& b) {
  if (a.kind != b.kind) return 0;
  switch (a.kind) {
    case Number::Kind::signed_int:
      return a.s < b.s ? -1 : (a.s > b.s ? 1 : 0);
    case Number::Kind::unsigned_int:
      return a.u < b.u ? -1 : (a.u > b.u ? 1 : 0);
    case Number::Kind::real:
      return a.d < b.d ? -1 : (a.d > b.d ? 1 : 0);
    case Number::Kind::none:
      break;
  }
  return 0;
}

// Bit-granular copy of `bits` bits from src (starting at bit src_bit) to dst (at dst_bit).
void copy_bits(wire::Bytes src, std::size_t src_bit, std::span<std::uint8_t> dst,
               std::size_t dst_bit, std::size_t bits) {
  for (std::size_t i = 0; i < bits; ++i) {
    const std::size_t s = src_bit + i;
    const std::size_t d = dst_bit + i;
    if (s / 8 >= src.size() || d / 8 >= dst.size()) return;
    const bool bit = ((src[s / 8] >> (s % 8)) & 1u) != 0;
    auto& byte = dst[d / 8];
    byte = static_cast<std::uint8_t>(bit ? (byte | (1u << (d % 8))) : (byte & ~(1u << (d % 8))));
  }
}

// The bits an entry occupies in a complete-access value: its value, zero-padded to its length.
std::vector<std::uint8_t> padded_value(const ObjectEntry& entry) {
  std::vector<std::uint8_t> v = entry.value;
  v.resize(entry.byte_length(), 0);
  return v;
}

// The entries a complete access covers, in order: subindex 1..count that exist.
std::vector<const ObjectEntry*> ca_entries(const OdObject& object, std::uint8_t count) {
  std::vector<const ObjectEntry*> out;
  for (const auto& e : object.entries) {
    if (e.subindex >= 1 && e.subindex <= count) out.push_back(&e);
  }
  return out;
}

}  // namespace

// ---- data types ---------------------------------------------------------------------------------

std::string to_string(DataType type) {
  switch (type) {
    case DataType::boolean:
      return "BOOLEAN";
    case DataType::integer8:
      return "INTEGER8";
    case DataType::integer16:
      return "INTEGER16";
    case DataType::integer32:
      return "INTEGER32";
    case DataType::unsigned8:
      return "UNSIGNED8";
    case DataType::unsigned16:
      return "UNSIGNED16";
    case DataType::unsigned32:
      return "UNSIGNED32";
    case DataType::real32:
      return "REAL32";
    case DataType::visible_string:
      return "VISIBLE_STRING";
    case DataType::octet_string:
      return "OCTET_STRING";
    case DataType::unicode_string:
      return "UNICODE_STRING";
    case DataType::time_of_day:
      return "TIME_OF_DAY";
    case DataType::time_difference:
      return "TIME_DIFFERENCE";
    case DataType::domain:
      return "DOMAIN";
    case DataType::integer24:
      return "INTEGER24";
    case DataType::real64:
      return "REAL64";
    case DataType::integer40:
      return "INTEGER40";
    case DataType::integer48:
      return "INTEGER48";
    case DataType::integer56:
      return "INTEGER56";
    case DataType::integer64:
      return "INTEGER64";
    case DataType::unsigned24:
      return "UNSIGNED24";
    case DataType::unsigned40:
      return "UNSIGNED40";
    case DataType::unsigned48:
      return "UNSIGNED48";
    case DataType::unsigned56:
      return "UNSIGNED56";
    case DataType::unsigned64:
      return "UNSIGNED64";
    case DataType::guid:
      return "GUID";
    case DataType::byte:
      return "BYTE";
    case DataType::word:
      return "WORD";
    case DataType::dword:
      return "DWORD";
    case DataType::pdo_mapping:
      return "PDO_MAPPING";
    case DataType::identity:
      return "IDENTITY";
    case DataType::bitarr8:
      return "BITARR8";
    case DataType::bitarr16:
      return "BITARR16";
    case DataType::bitarr32:
      return "BITARR32";
    case DataType::bit1:
      return "BIT1";
    case DataType::bit2:
      return "BIT2";
    case DataType::bit3:
      return "BIT3";
    case DataType::bit4:
      return "BIT4";
    case DataType::bit5:
      return "BIT5";
    case DataType::bit6:
      return "BIT6";
    case DataType::bit7:
      return "BIT7";
    case DataType::bit8:
      return "BIT8";
  }
  char text[16];
  std::snprintf(text, sizeof text, "DT0x%04X", static_cast<unsigned>(type));
  return text;
}

std::uint16_t natural_bit_length(DataType type) noexcept {
  switch (type) {
    case DataType::boolean:
      return 1;
    case DataType::integer8:
    case DataType::unsigned8:
    case DataType::byte:
    case DataType::bitarr8:
      return 8;
    case DataType::integer16:
    case DataType::unsigned16:
    case DataType::word:
    case DataType::bitarr16:
      return 16;
    case DataType::integer24:
    case DataType::unsigned24:
      return 24;
    case DataType::integer32:
    case DataType::unsigned32:
    case DataType::real32:
    case DataType::dword:
    case DataType::bitarr32:
      return 32;
    case DataType::integer40:
    case DataType::unsigned40:
      return 40;
    case DataType::time_of_day:
    case DataType::time_difference:
    case DataType::integer48:
    case DataType::unsigned48:
      return 48;
    case DataType::integer56:
    case DataType::unsigned56:
      return 56;
    case DataType::integer64:
    case DataType::unsigned64:
    case DataType::real64:
      return 64;
    case DataType::guid:
      return 128;
    case DataType::bit1:
      return 1;
    case DataType::bit2:
      return 2;
    case DataType::bit3:
      return 3;
    case DataType::bit4:
      return 4;
    case DataType::bit5:
      return 5;
    case DataType::bit6:
      return 6;
    case DataType::bit7:
      return 7;
    case DataType::bit8:
      return 8;
    default:
      return 0;
  }
}

bool is_signed_integer(DataType type) noexcept {
  switch (type) {
    case DataType::integer8:
    case DataType::integer16:
    case DataType::integer24:
    case DataType::integer32:
    case DataType::integer40:
    case DataType::integer48:
    case DataType::integer56:
    case DataType::integer64:
      return true;
    default:
      return false;
  }
}

bool is_unsigned_integer(DataType type) noexcept {
  switch (type) {
    case DataType::boolean:
    case DataType::unsigned8:
    case DataType::unsigned16:
    case DataType::unsigned24:
    case DataType::unsigned32:
    case DataType::unsigned40:
    case DataType::unsigned48:
    case DataType::unsigned56:
    case DataType::unsigned64:
    case DataType::byte:
    case DataType::word:
    case DataType::dword:
    case DataType::bitarr8:
    case DataType::bitarr16:
    case DataType::bitarr32:
    case DataType::bit1:
    case DataType::bit2:
    case DataType::bit3:
    case DataType::bit4:
    case DataType::bit5:
    case DataType::bit6:
    case DataType::bit7:
    case DataType::bit8:
      return true;
    default:
      return false;
  }
}

bool is_real(DataType type) noexcept {
  return type == DataType::real32 || type == DataType::real64;
}

bool is_variable_length(DataType type) noexcept {
  return type == DataType::visible_string || type == DataType::octet_string ||
         type == DataType::unicode_string || type == DataType::domain;
}

// ---- entries and objects ------------------------------------------------------------------------

bool ObjectEntry::readable_in(wire::AlState state) const noexcept {
  return (access & bits_for(state).read) != 0;
}

bool ObjectEntry::writable_in(wire::AlState state) const noexcept {
  return (access & bits_for(state).write) != 0;
}

ObjectEntry* OdObject::entry(std::uint8_t subindex) noexcept {
  for (auto& e : entries) {
    if (e.subindex == subindex) return &e;
  }
  return nullptr;
}

const ObjectEntry* OdObject::entry(std::uint8_t subindex) const noexcept {
  for (const auto& e : entries) {
    if (e.subindex == subindex) return &e;
  }
  return nullptr;
}

std::uint8_t OdObject::max_subindex() const noexcept {
  return entries.empty() ? 0 : entries.back().subindex;
}

std::uint8_t OdObject::entries_in_use() const noexcept {
  if (code == ObjectCode::var) return 0;
  const ObjectEntry* sub0 = entry(0);
  return sub0 != nullptr && !sub0->value.empty() ? sub0->value[0] : 0;
}

ObjectEntry make_entry(std::uint8_t subindex, std::string name, DataType type, std::uint16_t access,
                       std::vector<std::uint8_t> value) {
  ObjectEntry entry;
  entry.subindex = subindex;
  entry.name = std::move(name);
  entry.data_type = type;
  entry.bit_length = natural_bit_length(type);
  if (entry.bit_length == 0) entry.bit_length = static_cast<std::uint16_t>(8 * value.size());
  entry.access = access;
  if (!is_variable_length(type)) value.resize(entry.byte_length(), 0);
  entry.value = std::move(value);
  return entry;
}

ObjectEntry make_string_entry(std::uint8_t subindex, std::string name, std::string_view text,
                              std::uint16_t access, std::size_t capacity) {
  ObjectEntry entry;
  entry.subindex = subindex;
  entry.name = std::move(name);
  entry.data_type = DataType::visible_string;
  entry.bit_length = static_cast<std::uint16_t>(8 * std::max(capacity, text.size()));
  entry.access = access;
  entry.value.assign(text.begin(), text.end());
  return entry;
}

ObjectEntry make_octet_entry(std::uint8_t subindex, std::string name,
                             std::vector<std::uint8_t> bytes, std::uint16_t access,
                             std::size_t capacity, DataType type) {
  ObjectEntry entry;
  entry.subindex = subindex;
  entry.name = std::move(name);
  entry.data_type = type;
  entry.bit_length = static_cast<std::uint16_t>(8 * std::max(capacity, bytes.size()));
  entry.access = access;
  entry.value = std::move(bytes);
  return entry;
}

OdObject make_var(std::uint16_t index, std::string name, ObjectEntry entry) {
  OdObject object;
  object.index = index;
  object.code = ObjectCode::var;
  object.data_type = static_cast<std::uint16_t>(entry.data_type);
  entry.subindex = 0;
  if (entry.name.empty()) entry.name = name;
  object.name = std::move(name);
  object.entries.push_back(std::move(entry));
  return object;
}

OdObject make_array(std::uint16_t index, std::string name, DataType element_type,
                    std::uint8_t capacity, std::uint16_t element_access,
                    std::vector<std::vector<std::uint8_t>> values,
                    std::optional<std::uint8_t> in_use, std::uint16_t sub0_access) {
  OdObject object;
  object.index = index;
  object.name = std::move(name);
  object.code = ObjectCode::array;
  object.data_type = static_cast<std::uint16_t>(element_type);
  object.entries.push_back(
      make_entry(0, "SubIndex 000", DataType::unsigned8, sub0_access, {in_use.value_or(capacity)}));
  for (std::uint8_t i = 1; i <= capacity && i != 0; ++i) {
    char label[16];
    std::snprintf(label, sizeof label, "SubIndex %03u", static_cast<unsigned>(i));
    std::vector<std::uint8_t> v = i <= values.size() ? values[i - 1] : std::vector<std::uint8_t>{};
    object.entries.push_back(make_entry(i, label, element_type, element_access, std::move(v)));
    if (i == 255) break;
  }
  return object;
}

OdObject make_record(std::uint16_t index, std::string name, std::vector<ObjectEntry> entries,
                     std::uint16_t data_type) {
  std::sort(entries.begin(), entries.end(),
            [](const ObjectEntry& a, const ObjectEntry& b) { return a.subindex < b.subindex; });
  entries.erase(std::remove_if(entries.begin(), entries.end(),
                               [](const ObjectEntry& e) { return e.subindex == 0; }),
                entries.end());
  OdObject object;
  object.index = index;
  object.name = std::move(name);
  object.code = ObjectCode::record;
  object.data_type = data_type;
  const std::uint8_t highest = entries.empty() ? 0 : entries.back().subindex;
  object.entries.push_back(
      make_entry(0, "SubIndex 000", DataType::unsigned8, kAccessRead, {highest}));
  for (auto& e : entries)
    object.entries.push_back(std::move(e));
  return object;
}

OdObject make_device_type(std::uint32_t device_type) {
  return make_var(0x1000, "Device type",
                  make_entry_of(0, "", DataType::unsigned32, kAccessRead, device_type));
}

OdObject make_error_register() {
  return make_var(0x1001, "Error register",
                  make_entry_of(0, "", DataType::unsigned8, kAccessRead, std::uint8_t{0}));
}

OdObject make_device_name(std::string_view name) {
  return make_var(0x1008, "Device name", make_string_entry(0, "", name));
}

OdObject make_hardware_version(std::string_view version) {
  return make_var(0x1009, "Manufacturer hardware version", make_string_entry(0, "", version));
}

OdObject make_software_version(std::string_view version) {
  return make_var(0x100A, "Manufacturer software version", make_string_entry(0, "", version));
}

OdObject make_identity(const Identity& identity) {
  return make_record(
      0x1018, "Identity",
      {make_entry_of(1, "Vendor ID", DataType::unsigned32, kAccessRead, identity.vendor_id),
       make_entry_of(2, "Product code", DataType::unsigned32, kAccessRead, identity.product_code),
       make_entry_of(3, "Revision", DataType::unsigned32, kAccessRead, identity.revision),
       make_entry_of(4, "Serial number", DataType::unsigned32, kAccessRead,
                     identity.serial_number)},
      static_cast<std::uint16_t>(DataType::identity));
}

OdObject make_error_settings(std::uint32_t local_error_reaction,
                             std::uint16_t sync_error_counter_limit) {
  return make_record(0x10F1, "Error Settings",
                     {make_entry_of(1, "Local Error Reaction", DataType::unsigned32,
                                    kAccessReadWrite, local_error_reaction),
                      make_entry_of(2, "Sync Error Counter Limit", DataType::unsigned16,
                                    kAccessReadWrite, sync_error_counter_limit)});
}

OdObject make_sync_manager_types(const std::vector<std::uint8_t>& types) {
  std::vector<std::vector<std::uint8_t>> values;
  for (auto t : types)
    values.push_back({t});
  return make_array(0x1C00, "Sync manager type", DataType::unsigned8,
                    static_cast<std::uint8_t>(std::min<std::size_t>(types.size(), 255)),
                    kAccessRead, std::move(values));
}

// ---- the dictionary -----------------------------------------------------------------------------

std::uint64_t ObjectDictionary::next_generation() noexcept {
  static std::atomic<std::uint64_t> counter{0};
  return counter.fetch_add(1, std::memory_order_relaxed) + 1;
}

ObjectDictionary::ObjectDictionary(const ObjectDictionary& other)
    : objects_(other.objects_), listener_(other.listener_) {}

ObjectDictionary::ObjectDictionary(ObjectDictionary&& other) noexcept
    : objects_(std::move(other.objects_)), listener_(std::move(other.listener_)) {
  other.generation_ = next_generation();
}

ObjectDictionary& ObjectDictionary::operator=(const ObjectDictionary& other) {
  if (this != &other) {
    objects_ = other.objects_;
    listener_ = other.listener_;
    generation_ = next_generation();
  }
  return *this;
}

ObjectDictionary& ObjectDictionary::operator=(ObjectDictionary&& other) noexcept {
  if (this != &other) {
    objects_ = std::move(other.objects_);
    listener_ = std::move(other.listener_);
    generation_ = next_generation();
    other.generation_ = next_generation();
  }
  return *this;
}

void ObjectDictionary::clear() noexcept {
  objects_.clear();
  generation_ = next_generation();
}

void ObjectDictionary::add(OdObject object) {
  std::stable_sort(
      object.entries.begin(), object.entries.end(),
      [](const ObjectEntry& a, const ObjectEntry& b) { return a.subindex < b.subindex; });
  const auto index = object.index;
  objects_.insert_or_assign(index, std::move(object));
  generation_ = next_generation();
}

bool ObjectDictionary::remove(std::uint16_t index) {
  generation_ = next_generation();
  return objects_.erase(index) != 0;
}

OdObject* ObjectDictionary::find(std::uint16_t index) noexcept {
  auto it = objects_.find(index);
  return it == objects_.end() ? nullptr : &it->second;
}

const OdObject* ObjectDictionary::find(std::uint16_t index) const noexcept {
  auto it = objects_.find(index);
  return it == objects_.end() ? nullptr : &it->second;
}

ObjectEntry* ObjectDictionary::find(std::uint16_t index, std::uint8_t subindex) noexcept {
  OdObject* object = find(index);
  return object == nullptr ? nullptr : object->entry(subindex);
}

const ObjectEntry* ObjectDictionary::find(std::uint16_t index,
                                          std::uint8_t subindex) const noexcept {
  const OdObject* object = find(index);
  return object == nullptr ? nullptr : object->entry(subindex);
}

std::vector<std::uint16_t> ObjectDictionary::indices() const {
  std::vector<std::uint16_t> out;
  out.reserve(objects_.size());
  for (const auto& [index, object] : objects_)
    out.push_back(index);
  return out;
}

std::vector<std::uint16_t> ObjectDictionary::od_list(wire::OdListType type) const {
  const auto any_entry = [](const OdObject& o, std::uint16_t bits) {
    return std::any_of(o.entries.begin(), o.entries.end(),
                       [bits](const ObjectEntry& e) { return (e.access & bits) != 0; });
  };
  const auto list = [&](std::uint16_t bits) {
    std::vector<std::uint16_t> out;
    for (const auto& [index, object] : objects_) {
      if (bits == 0 || any_entry(object, bits)) out.push_back(index);
    }
    return out;
  };
  switch (type) {
    case wire::OdListType::all:
      return list(0);
    case wire::OdListType::rx_pdo_mappable:
      return list(kAccessRxPdo);
    case wire::OdListType::tx_pdo_mappable:
      return list(kAccessTxPdo);
    case wire::OdListType::backup:
      return list(kAccessBackup);
    case wire::OdListType::settings:
      return list(kAccessSettings);
    case wire::OdListType::number_of_objects: {
      std::vector<std::uint16_t> counts;
      for (std::uint16_t bits :
           {std::uint16_t{0}, kAccessRxPdo, kAccessTxPdo, kAccessBackup, kAccessSettings}) {
        counts.push_back(static_cast<std::uint16_t>(list(bits).size()));
      }
      return counts;
    }
  }
  return {};
}

namespace {

// Existence checks shared by reads and writes: 0x06020000 for a missing object, 0x06090011 above
// the highest subindex, 0x08000020 for a gap inside a RECORD (as Beckhoff slaves answer).
SdoStatus locate(ObjectDictionary& od, std::uint16_t index, std::uint8_t subindex,
                 ObjectEntry*& entry) {
  OdObject* object = od.find(index);
  if (object == nullptr) return SdoAbortCode::object_does_not_exist;
  entry = object->entry(subindex);
  if (entry != nullptr) return {};
  if (subindex > object->max_subindex()) return SdoAbortCode::subindex_does_not_exist;
  return SdoAbortCode::cannot_store;
}

AccessContext with_target(const AccessContext& context, std::uint16_t index, ObjectDictionary& od) {
  AccessContext c = context;
  c.index = index;
  c.dictionary = &od;
  return c;
}

SdoStatus read_access(const ObjectEntry& entry, wire::AlState state) {
  if (entry.readable_in(state)) return {};
  if ((entry.access & kAccessRead) == 0) return SdoAbortCode::read_of_write_only;
  return SdoAbortCode::cannot_store_device_state;
}

SdoStatus write_access(const ObjectEntry& entry, wire::AlState state) {
  if (entry.writable_in(state)) return {};
  if ((entry.access & kAccessWrite) == 0) return SdoAbortCode::write_of_read_only;
  return SdoAbortCode::cannot_store_device_state;
}

}  // namespace

SdoStatus ObjectDictionary::sdo_read(std::uint16_t index, std::uint8_t subindex,
                                     const AccessContext& context, std::vector<std::uint8_t>& out) {
  ObjectEntry* entry = nullptr;
  if (auto s = locate(*this, index, subindex, entry); !s.ok()) return s;
  if (auto s = read_access(*entry, context.state); !s.ok()) return s;
  if (entry->on_read) {
    if (auto s = entry->on_read(*entry, with_target(context, index, *this)); !s.ok()) return s;
  }
  out = entry->value;
  if (!is_variable_length(entry->data_type)) out.resize(entry->byte_length(), 0);
  return {};
}

SdoStatus ObjectDictionary::check_write_value(const ObjectEntry& entry, wire::Bytes value) const {
  const DataType type = entry.data_type;
  if (type == DataType::boolean) {
    if (!value.empty() && value[0] > 1) return SdoAbortCode::value_range_exceeded;
  } else if (entry.bit_length < 8 && !value.empty() && !is_variable_length(type)) {
    if ((value[0] >> entry.bit_length) != 0) return SdoAbortCode::value_range_exceeded;
  }
  if (is_variable_length(type)) return {};
  const Number v = decode_number(type, value);
  if (!entry.minimum.empty() && compare(v, decode_number(type, entry.minimum)) < 0) {
    return SdoAbortCode::value_too_low;
  }
  if (!entry.maximum.empty() && compare(v, decode_number(type, entry.maximum)) > 0) {
    return SdoAbortCode::value_too_high;
  }
  return {};
}

SdoStatus ObjectDictionary::sdo_write(std::uint16_t index, std::uint8_t subindex, wire::Bytes value,
                                      const AccessContext& context, bool expedited_unsized) {
  ObjectEntry* entry = nullptr;
  if (auto s = locate(*this, index, subindex, entry); !s.ok()) return s;
  if (auto s = write_access(*entry, context.state); !s.ok()) return s;
  const std::size_t need = entry->byte_length();
  if (is_variable_length(entry->data_type)) {
    if (value.size() > need) return SdoAbortCode::length_too_high;
  } else {
    if (expedited_unsized && need <= 4 && value.size() == 4) value = value.first(need);
    if (value.size() > need) return SdoAbortCode::length_too_high;
    if (value.size() < need) return SdoAbortCode::length_too_low;
  }
  if (auto s = check_write_value(*entry, value); !s.ok()) return s;
  const AccessContext c = with_target(context, index, *this);
  if (entry->on_write) {
    if (auto s = entry->on_write(*entry, value, c); !s.ok()) return s;
  }
  entry->value.assign(value.begin(), value.end());
  if (entry->on_written) entry->on_written(*entry, c);
  if (!context.complete_access) notify(index, subindex);
  return {};
}

SdoStatus ObjectDictionary::sdo_check_write(std::uint16_t index, std::uint8_t subindex,
                                            std::size_t size, const AccessContext& context) {
  ObjectEntry* entry = nullptr;
  if (auto s = locate(*this, index, subindex, entry); !s.ok()) return s;
  if (auto s = write_access(*entry, context.state); !s.ok()) return s;
  const std::size_t need = entry->byte_length();
  if (size > need) return SdoAbortCode::length_too_high;
  if (size < need && !is_variable_length(entry->data_type)) return SdoAbortCode::length_too_low;
  return {};
}

SdoStatus ObjectDictionary::sdo_read_complete(std::uint16_t index, std::uint8_t subindex,
                                              const AccessContext& context,
                                              std::vector<std::uint8_t>& out) {
  OdObject* object = find(index);
  if (object == nullptr) return SdoAbortCode::object_does_not_exist;
  if (object->code == ObjectCode::var || subindex > 1) {
    return SdoAbortCode::complete_access_not_supported;
  }
  AccessContext c = context;
  c.complete_access = true;
  std::vector<std::uint8_t> sub0;
  if (auto s = sdo_read(index, 0, c, sub0); !s.ok()) return s;
  const std::uint8_t count = sub0.empty() ? 0 : sub0[0];
  // Read every entry first (hooks may refresh values), then pack them bit by bit.
  std::vector<std::pair<std::vector<std::uint8_t>, std::uint16_t>> parts;
  std::size_t bits = 0;
  for (const ObjectEntry* e : ca_entries(*object, count)) {
    std::vector<std::uint8_t> v;
    if (auto s = sdo_read(index, e->subindex, c, v); !s.ok()) return s;
    v.resize(e->byte_length(), 0);
    bits += e->bit_length;
    parts.emplace_back(std::move(v), e->bit_length);
  }
  const std::size_t head = subindex == 0 ? 2 : 0;
  out.assign(head + (bits + 7) / 8, 0);
  if (subindex == 0) out[0] = count;
  std::size_t at = head * 8;
  for (const auto& [v, length] : parts) {
    copy_bits(v, 0, out, at, length);
    at += length;
  }
  return {};
}

SdoStatus ObjectDictionary::sdo_write_complete(std::uint16_t index, std::uint8_t subindex,
                                               wire::Bytes value, const AccessContext& context) {
  OdObject* object = find(index);
  if (object == nullptr) return SdoAbortCode::object_does_not_exist;
  if (object->code == ObjectCode::var || subindex > 1) {
    return SdoAbortCode::complete_access_not_supported;
  }
  ObjectEntry* sub0 = object->entry(0);
  if (sub0 == nullptr) return SdoAbortCode::complete_access_not_supported;
  const std::uint8_t current = object->entries_in_use();
  const bool sub0_writable = sub0->writable_in(context.state);
  std::uint8_t count = current;
  if (subindex == 0) {
    if (value.size() < 2) return SdoAbortCode::length_too_low;
    if (value[0] != current) {
      if (auto s = write_access(*sub0, context.state); !s.ok()) return s;
      if (value[0] > object->max_subindex()) return SdoAbortCode::value_range_exceeded;
      count = value[0];
    }
  }
  const auto entries = ca_entries(*object, count);
  std::size_t bits = 0;
  for (const ObjectEntry* e : entries)
    bits += e->bit_length;
  const std::size_t head = subindex == 0 ? 2 : 0;
  const std::size_t expected = head + (bits + 7) / 8;
  if (value.size() > expected) return SdoAbortCode::length_too_high;
  if (value.size() < expected) return SdoAbortCode::length_too_low;

  // Split the value into the entries' new values; entries that may not be written in this state
  // must keep their value.
  struct Part {
    std::uint8_t subindex;
    std::vector<std::uint8_t> bytes;
    bool changes;
  };
  std::vector<Part> parts;
  std::size_t at = head * 8;
  for (const ObjectEntry* e : entries) {
    std::vector<std::uint8_t> v(e->byte_length(), 0);
    copy_bits(value, at, v, 0, e->bit_length);
    at += e->bit_length;
    if (is_variable_length(e->data_type)) {
      // A string ends at its first NUL inside the fixed-size field.
      if (e->data_type == DataType::visible_string) {
        auto nul = std::find(v.begin(), v.end(), std::uint8_t{0});
        v.erase(nul, v.end());
      }
    }
    const bool changes = v != padded_value(*e) && v != e->value;
    if (changes) {
      if (auto s = write_access(*e, context.state); !s.ok()) return s;
    }
    parts.push_back({e->subindex, std::move(v), changes});
  }

  // Apply: subindex 0 to 0 first (mapping objects only accept new entries then), the entries,
  // then the count. Any refusal restores the object as it was.
  std::vector<std::vector<std::uint8_t>> saved;
  for (const auto& e : object->entries)
    saved.push_back(e.value);
  const auto restore = [&] {
    OdObject* o = find(index);
    if (o == nullptr) return;
    for (std::size_t i = 0; i < o->entries.size() && i < saved.size(); ++i) {
      o->entries[i].value = saved[i];
    }
  };
  AccessContext c = context;
  c.complete_access = true;
  const bool rewrite_count = subindex == 0 && sub0_writable;
  if (rewrite_count) {
    const std::uint8_t zero = 0;
    if (auto s = sdo_write(index, 0, wire::Bytes(&zero, 1), c); !s.ok()) {
      restore();
      return s;
    }
  }
  for (const auto& p : parts) {
    if (!p.changes) continue;
    if (auto s = sdo_write(index, p.subindex, p.bytes, c); !s.ok()) {
      restore();
      return s;
    }
  }
  if (rewrite_count) {
    if (auto s = sdo_write(index, 0, wire::Bytes(&count, 1), c); !s.ok()) {
      restore();
      return s;
    }
  }
  notify(index, subindex);
  return {};
}

void ObjectDictionary::notify(std::uint16_t index, std::uint8_t subindex) const {
  if (listener_) listener_(index, subindex);
}

std::optional<wire::Bytes> ObjectDictionary::value(std::uint16_t index,
                                                   std::uint8_t subindex) const {
  const ObjectEntry* entry = find(index, subindex);
  if (entry == nullptr) return std::nullopt;
  return wire::Bytes(entry->value);
}

bool ObjectDictionary::set_value(std::uint16_t index, std::uint8_t subindex, wire::Bytes bytes) {
  ObjectEntry* entry = find(index, subindex);
  if (entry == nullptr) return false;
  if (is_variable_length(entry->data_type) ? bytes.size() > entry->byte_length()
                                           : bytes.size() != entry->byte_length()) {
    return false;
  }
  entry->value.assign(bytes.begin(), bytes.end());
  return true;
}

std::optional<std::string> ObjectDictionary::get_string(std::uint16_t index,
                                                        std::uint8_t subindex) const {
  const ObjectEntry* entry = find(index, subindex);
  if (entry == nullptr) return std::nullopt;
  std::string text(entry->value.begin(), entry->value.end());
  if (auto nul = text.find('\0'); nul != std::string::npos) text.resize(nul);
  return text;
}

bool ObjectDictionary::set_string(std::uint16_t index, std::uint8_t subindex,
                                  std::string_view text) {
  const auto* p = reinterpret_cast<const std::uint8_t*>(text.data());
  return set_value(index, subindex, wire::Bytes(p, text.size()));
}

void ObjectDictionary::reset_to_defaults() {
  for (auto& [index, object] : objects_) {
    for (auto& e : object.entries) {
      if (!e.default_value.empty()) e.value = e.default_value;
    }
  }
}

}  // namespace ecat::sim
