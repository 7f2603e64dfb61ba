// The simulator's object dictionary and PDO mapping objects, accessed directly (no mailbox):
// builders, typed access, SDO access rules per AL state, complete access, hooks, the PDO
// assignment/mapping rules and the process-data layout that follows from them.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/object_dictionary.hpp>
#include <ecat/sim/pdo_mapping.hpp>
#include <ecat/wire/sdo_abort.hpp>

namespace ecat::sim {
namespace {

using wire::AlState;
using wire::SdoAbortCode;
using Bytes = std::vector<std::uint8_t>;

constexpr std::uint32_t code(SdoAbortCode c) {
  return static_cast<std::uint32_t>(c);
}

Bytes stored(const ObjectDictionary& od, std::uint16_t index, std::uint8_t subindex) {
  auto v = od.value(index, subindex);
  return v ? Bytes(v->begin(), v->end()) : Bytes{};
}

AccessContext in(AlState state) {
  AccessContext c;
  c.state = state;
  return c;
}

std::uint32_t write(ObjectDictionary& od, std::uint16_t index, std::uint8_t sub, const Bytes& v,
                    AlState state = AlState::preop) {
  return od.sdo_write(index, sub, v, in(state)).code();
}

std::uint32_t read(ObjectDictionary& od, std::uint16_t index, std::uint8_t sub, Bytes& out,
                   AlState state = AlState::preop) {
  return od.sdo_read(index, sub, in(state), out).code();
}

TEST(DataTypes, NamesAndNaturalLengths) {
  EXPECT_EQ(to_string(DataType::unsigned24), "UNSIGNED24");
  EXPECT_EQ(to_string(DataType::visible_string), "VISIBLE_STRING");
  EXPECT_EQ(to_string(static_cast<DataType>(0x0800)), "DT0x0800");
  EXPECT_EQ(natural_bit_length(DataType::boolean), 1);
  EXPECT_EQ(natural_bit_length(DataType::bit3), 3);
  EXPECT_EQ(natural_bit_length(DataType::unsigned24), 24);
  EXPECT_EQ(natural_bit_length(DataType::integer64), 64);
  EXPECT_EQ(natural_bit_length(DataType::real32), 32);
  EXPECT_EQ(natural_bit_length(DataType::visible_string), 0);
  EXPECT_TRUE(is_signed_integer(DataType::integer24));
  EXPECT_FALSE(is_signed_integer(DataType::unsigned8));
  EXPECT_TRUE(is_unsigned_integer(DataType::bit8));
  EXPECT_TRUE(is_real(DataType::real64));
  EXPECT_TRUE(is_variable_length(DataType::octet_string));
}

TEST(Builders, ShapesOfVarArrayRecordAndStandardObjects) {
  const OdObject var =
      make_var(0x6000, "Temperature",
               make_entry_of(0, "", DataType::integer16, kAccessRead, std::int16_t{-250}));
  EXPECT_EQ(var.code, ObjectCode::var);
  EXPECT_EQ(var.data_type, 0x0003);
  EXPECT_EQ(var.entries.size(), 1u);
  EXPECT_EQ(var.entries[0].name, "Temperature");
  EXPECT_EQ(var.entries[0].value, (Bytes{0x06, 0xFF}));
  EXPECT_EQ(var.max_subindex(), 0);
  EXPECT_EQ(var.entries_in_use(), 0);

  const OdObject array = make_array(0x2100, "Gains", DataType::unsigned16, 3, kAccessReadWrite,
                                    {{0x01, 0x00}, {0x02, 0x00}});
  EXPECT_EQ(array.code, ObjectCode::array);
  EXPECT_EQ(array.max_subindex(), 3);
  EXPECT_EQ(array.entries_in_use(), 3);
  EXPECT_EQ(array.entry(2)->value, (Bytes{0x02, 0x00}));
  EXPECT_EQ(array.entry(3)->value, (Bytes{0x00, 0x00}));
  EXPECT_EQ(array.entry(1)->name, "SubIndex 001");

  const OdObject identity = make_identity({0x2, 0x0C823052, 0x00110000, 12345});
  EXPECT_EQ(identity.index, 0x1018);
  EXPECT_EQ(identity.code, ObjectCode::record);
  EXPECT_EQ(identity.data_type, 0x0023);
  EXPECT_EQ(identity.entries_in_use(), 4);
  EXPECT_EQ(identity.entry(2)->value, (Bytes{0x52, 0x30, 0x82, 0x0C}));

  ObjectDictionary od;
  od.add(make_device_type(0x00001389));
  od.add(make_device_name("EL3202-0010"));
  od.add(make_hardware_version("07"));
  od.add(make_software_version("12"));
  od.add(identity);
  od.add(make_sync_manager_types({1, 2, 3, 4}));
  od.add(make_error_settings());
  EXPECT_EQ(od.get<std::uint32_t>(0x1000, 0), 0x1389u);
  EXPECT_EQ(od.get_string(0x1008, 0), "EL3202-0010");
  EXPECT_EQ(od.find(0x1008, 0)->bit_length, 8 * 11);
  EXPECT_EQ(od.get<std::uint8_t>(0x1C00, 0), 4);
  EXPECT_EQ(od.get<std::uint8_t>(0x1C00, 4), 4);
  EXPECT_EQ(od.get<std::uint16_t>(0x10F1, 2), 4);
  EXPECT_EQ(od.indices(),
            (std::vector<std::uint16_t>{0x1000, 0x1008, 0x1009, 0x100A, 0x1018, 0x10F1, 0x1C00}));
}

TEST(TypedAccess, RoundTripsEveryWidth) {
  ObjectDictionary od;
  od.add(make_record(0x2000, "Values",
                     {make_entry(1, "i32", DataType::integer32, kAccessReadWrite),
                      make_entry(2, "u24", DataType::unsigned24, kAccessReadWrite),
                      make_entry(3, "i24", DataType::integer24, kAccessReadWrite),
                      make_entry(4, "f32", DataType::real32, kAccessReadWrite),
                      make_entry(5, "f64", DataType::real64, kAccessReadWrite),
                      make_entry(6, "flag", DataType::boolean, kAccessReadWrite),
                      make_string_entry(7, "text", "abc", kAccessReadWrite, 8)}));
  EXPECT_TRUE(od.set<std::int32_t>(0x2000, 1, -123456));
  EXPECT_EQ(od.get<std::int32_t>(0x2000, 1), -123456);
  EXPECT_EQ(stored(od, 0x2000, 1), (Bytes{0xC0, 0x1D, 0xFE, 0xFF}));
  EXPECT_TRUE(od.set<std::uint32_t>(0x2000, 2, 0x00ABCDEF));
  EXPECT_EQ(stored(od, 0x2000, 2), (Bytes{0xEF, 0xCD, 0xAB}));
  EXPECT_EQ(od.get<std::uint32_t>(0x2000, 2), 0x00ABCDEFu);
  EXPECT_TRUE(od.set<std::int32_t>(0x2000, 3, -2));
  EXPECT_EQ(stored(od, 0x2000, 3), (Bytes{0xFE, 0xFF, 0xFF}));
  EXPECT_EQ(od.get<std::int32_t>(0x2000, 3), -2) << "24-bit values sign-extend";
  EXPECT_TRUE(od.set<float>(0x2000, 4, 1.5F));
  EXPECT_EQ(stored(od, 0x2000, 4), (Bytes{0x00, 0x00, 0xC0, 0x3F}));
  EXPECT_EQ(od.get<float>(0x2000, 4), 1.5F);
  EXPECT_FALSE(od.set<double>(0x2000, 4, 1.5)) << "a REAL32 entry is not a double";
  EXPECT_TRUE(od.set<double>(0x2000, 5, -0.25));
  EXPECT_EQ(od.get<double>(0x2000, 5), -0.25);
  EXPECT_TRUE(od.set<bool>(0x2000, 6, true));
  EXPECT_EQ(stored(od, 0x2000, 6), (Bytes{0x01}));
  EXPECT_EQ(od.get<bool>(0x2000, 6), true);
  EXPECT_TRUE(od.set_string(0x2000, 7, "hello"));
  EXPECT_EQ(od.get_string(0x2000, 7), "hello");
  EXPECT_FALSE(od.set_string(0x2000, 7, "too long!"));
  EXPECT_FALSE(od.set<std::uint8_t>(0x2000, 9, 1)) << "no such subindex";
  EXPECT_EQ(od.get<std::uint8_t>(0x2001, 0), std::nullopt);
}

ObjectDictionary access_dictionary() {
  ObjectDictionary od;
  od.add(make_var(0x2000, "ro",
                  make_entry_of(0, "", DataType::unsigned16, kAccessRead, std::uint16_t{0x1234})));
  od.add(make_var(0x2001, "wo",
                  make_entry_of(0, "", DataType::unsigned32, kAccessWrite, std::uint32_t{7})));
  od.add(
      make_var(0x2002, "rw preop",
               make_entry_of(0, "", DataType::integer16, kAccessReadWritePreop, std::int16_t{5})));
  od.add(make_var(0x2003, "read in op only",
                  make_entry_of(0, "", DataType::unsigned8, wire::kAccessReadOp, std::uint8_t{9})));
  auto limited = make_entry_of(0, "", DataType::integer16, kAccessReadWrite, std::int16_t{0});
  limited.minimum = to_le_bytes(std::int16_t{-100});
  limited.maximum = to_le_bytes(std::int16_t{100});
  od.add(make_var(0x2004, "limited", limited));
  od.add(make_record(0x2005, "record with gap",
                     {make_entry(1, "a", DataType::unsigned8, kAccessReadWrite, {1}),
                      make_entry(3, "c", DataType::unsigned8, kAccessReadWrite, {3})}));
  od.add(make_var(0x2006, "flag", make_entry(0, "", DataType::boolean, kAccessReadWrite)));
  od.add(make_var(0x2007, "two bits", make_entry(0, "", DataType::bit2, kAccessReadWrite)));
  od.add(make_var(0x2008, "name", make_string_entry(0, "", "ab", kAccessReadWrite, 6)));
  return od;
}

TEST(SdoAccess, ReadsFollowExistenceAndAccessRights) {
  ObjectDictionary od = access_dictionary();
  Bytes out;
  EXPECT_EQ(read(od, 0x2000, 0, out), 0u);
  EXPECT_EQ(out, (Bytes{0x34, 0x12}));
  EXPECT_EQ(read(od, 0x3000, 0, out), code(SdoAbortCode::object_does_not_exist));
  EXPECT_EQ(read(od, 0x2000, 1, out), code(SdoAbortCode::subindex_does_not_exist));
  EXPECT_EQ(read(od, 0x2005, 4, out), code(SdoAbortCode::subindex_does_not_exist));
  EXPECT_EQ(read(od, 0x2005, 2, out), code(SdoAbortCode::cannot_store))
      << "a gap inside a record is answered like Beckhoff slaves do";
  EXPECT_EQ(read(od, 0x2001, 0, out), code(SdoAbortCode::read_of_write_only));
  EXPECT_EQ(read(od, 0x2003, 0, out, AlState::preop),
            code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(read(od, 0x2003, 0, out, AlState::op), 0u);
  EXPECT_EQ(out, Bytes{9});
  EXPECT_EQ(read(od, 0x2008, 0, out), 0u);
  EXPECT_EQ(out, (Bytes{'a', 'b'})) << "strings upload their present length";
}

TEST(SdoAccess, WritesCheckAccessLengthAndRange) {
  ObjectDictionary od = access_dictionary();
  EXPECT_EQ(write(od, 0x2000, 0, {1, 2}), code(SdoAbortCode::write_of_read_only));
  EXPECT_EQ(write(od, 0x2001, 0, {1, 0, 0, 0}), 0u);
  EXPECT_EQ(od.get<std::uint32_t>(0x2001, 0), 1u);
  EXPECT_EQ(write(od, 0x2002, 0, {7, 0}, AlState::safeop),
            code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(write(od, 0x2002, 0, {7, 0}, AlState::op),
            code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(write(od, 0x2002, 0, {7, 0}, AlState::preop), 0u);
  EXPECT_EQ(od.get<std::int16_t>(0x2002, 0), 7);
  EXPECT_EQ(write(od, 0x2002, 0, {7, 0, 0}), code(SdoAbortCode::length_too_high));
  EXPECT_EQ(write(od, 0x2002, 0, {7}), code(SdoAbortCode::length_too_low));
  EXPECT_EQ(od.sdo_write(0x2002, 0, Bytes{8, 0, 0xAA, 0xBB}, in(AlState::preop), true).code(), 0u)
      << "an expedited download without size indication carries 4 bytes";
  EXPECT_EQ(od.get<std::int16_t>(0x2002, 0), 8);
  EXPECT_EQ(write(od, 0x2004, 0, to_le_bytes(std::int16_t{101})),
            code(SdoAbortCode::value_too_high));
  EXPECT_EQ(write(od, 0x2004, 0, to_le_bytes(std::int16_t{-101})),
            code(SdoAbortCode::value_too_low));
  EXPECT_EQ(write(od, 0x2004, 0, to_le_bytes(std::int16_t{-100})), 0u);
  EXPECT_EQ(write(od, 0x2006, 0, {2}), code(SdoAbortCode::value_range_exceeded));
  EXPECT_EQ(write(od, 0x2006, 0, {1}), 0u);
  EXPECT_EQ(write(od, 0x2007, 0, {4}), code(SdoAbortCode::value_range_exceeded));
  EXPECT_EQ(write(od, 0x2007, 0, {3}), 0u);
  EXPECT_EQ(write(od, 0x2008, 0, {'a', 'b', 'c', 'd', 'e', 'f', 'g'}),
            code(SdoAbortCode::length_too_high));
  EXPECT_EQ(write(od, 0x2008, 0, {'x', 'y', 'z'}), 0u);
  EXPECT_EQ(od.get_string(0x2008, 0), "xyz");
}

TEST(SdoAccess, CheckWriteSeesOnlyTheAnnouncedSize) {
  ObjectDictionary od = access_dictionary();
  EXPECT_EQ(od.sdo_check_write(0x2002, 0, 2, in(AlState::preop)).code(), 0u);
  EXPECT_EQ(od.sdo_check_write(0x2002, 0, 3, in(AlState::preop)).code(),
            code(SdoAbortCode::length_too_high));
  EXPECT_EQ(od.sdo_check_write(0x2002, 0, 1, in(AlState::preop)).code(),
            code(SdoAbortCode::length_too_low));
  EXPECT_EQ(od.sdo_check_write(0x2008, 0, 1, in(AlState::preop)).code(), 0u);
  EXPECT_EQ(od.sdo_check_write(0x2000, 0, 2, in(AlState::preop)).code(),
            code(SdoAbortCode::write_of_read_only));
}

TEST(Hooks, ReadHookComputesWriteHookRefusesWrittenHookReacts) {
  ObjectDictionary od = access_dictionary();
  int reads = 0;
  od.find(0x2000, 0)->on_read = [&](ObjectEntry& entry, const AccessContext& context) {
    ++reads;
    EXPECT_EQ(context.index, 0x2000);
    EXPECT_NE(context.dictionary, nullptr);
    entry.value = to_le_bytes(static_cast<std::uint16_t>(0x1000 + reads));
    return SdoStatus{};
  };
  Bytes out;
  EXPECT_EQ(read(od, 0x2000, 0, out), 0u);
  EXPECT_EQ(out, (Bytes{0x01, 0x10}));
  EXPECT_EQ(read(od, 0x2000, 0, out), 0u);
  EXPECT_EQ(out, (Bytes{0x02, 0x10}));

  std::vector<std::int16_t> written;
  std::vector<std::pair<std::uint16_t, std::uint8_t>> changes;
  od.set_change_listener([&](std::uint16_t i, std::uint8_t s) { changes.emplace_back(i, s); });
  auto* entry = od.find(0x2002, 0);
  entry->on_write = [](const ObjectEntry&, wire::Bytes value, const AccessContext&) -> SdoStatus {
    if (*from_le_bytes<std::int16_t>(value) == 13) return SdoStatus::abort(0x06090030);
    return {};
  };
  entry->on_written = [&](ObjectEntry& e, const AccessContext&) {
    written.push_back(*from_le_bytes<std::int16_t>(e.value));
  };
  EXPECT_EQ(write(od, 0x2002, 0, to_le_bytes(std::int16_t{13})), 0x06090030u);
  EXPECT_EQ(od.get<std::int16_t>(0x2002, 0), 5) << "a refused value is not stored";
  EXPECT_EQ(write(od, 0x2002, 0, to_le_bytes(std::int16_t{12})), 0u);
  EXPECT_EQ(written, (std::vector<std::int16_t>{12}));
  ASSERT_EQ(changes.size(), 1u);
  EXPECT_EQ(changes[0], (std::pair<std::uint16_t, std::uint8_t>{0x2002, 0}));
}

TEST(CompleteAccess, UploadsPadSubindexZeroAndPackEntries) {
  ObjectDictionary od;
  add_pdo_mapping(od, 0x1601, "RxPDO 2", {});
  add_pdo_assignment(od, 2, PdoDirection::rx, {0x1601});
  od.add(make_identity({0x2, 0x0C823052, 0x00110000, 0}));
  od.add(make_record(0x2000, "bits",
                     {make_entry(1, "b1", DataType::boolean, kAccessRead, {1}),
                      make_entry(2, "b2", DataType::bit2, kAccessRead, {2}),
                      make_entry(3, "pad", DataType::bit5, kAccessRead, {0}),
                      make_entry(4, "word", DataType::unsigned16, kAccessRead, {0x34, 0x12})}));
  Bytes out;
  ASSERT_EQ(od.sdo_read_complete(0x1C12, 0, in(AlState::preop), out).code(), 0u);
  EXPECT_EQ(out, (Bytes{0x01, 0x00, 0x01, 0x16}));
  ASSERT_EQ(od.sdo_read_complete(0x1C12, 1, in(AlState::preop), out).code(), 0u);
  EXPECT_EQ(out, (Bytes{0x01, 0x16}));
  ASSERT_EQ(od.sdo_read_complete(0x1018, 0, in(AlState::op), out).code(), 0u);
  EXPECT_EQ(out, (Bytes{0x04, 0x00, 0x02, 0x00, 0x00, 0x00, 0x52, 0x30, 0x82, 0x0C, 0x00, 0x00,
                        0x11, 0x00, 0x00, 0x00, 0x00, 0x00}));
  ASSERT_EQ(od.sdo_read_complete(0x2000, 0, in(AlState::preop), out).code(), 0u);
  EXPECT_EQ(out, (Bytes{0x04, 0x00, 0b0000'0101, 0x34, 0x12}));
  od.add(make_var(0x2001, "v", make_entry(0, "", DataType::unsigned8, kAccessRead)));
  EXPECT_EQ(od.sdo_read_complete(0x2001, 0, in(AlState::preop), out).code(),
            code(SdoAbortCode::complete_access_not_supported));
  EXPECT_EQ(od.sdo_read_complete(0x1018, 2, in(AlState::preop), out).code(),
            code(SdoAbortCode::complete_access_not_supported));
  EXPECT_EQ(od.sdo_read_complete(0x1019, 0, in(AlState::preop), out).code(),
            code(SdoAbortCode::object_does_not_exist));
}

ObjectDictionary mapping_dictionary() {
  ObjectDictionary od;
  od.add(make_var(0x7000, "Output",
                  make_entry(0, "", DataType::unsigned16, kAccessReadWrite | kAccessRxPdo)));
  od.add(make_var(0x7001, "Output bit",
                  make_entry(0, "", DataType::boolean, kAccessReadWrite | kAccessRxPdo)));
  od.add(make_record(0x6000, "Inputs",
                     {make_entry(1, "Status", DataType::unsigned8, kAccessRead | kAccessTxPdo),
                      make_entry(2, "Value", DataType::integer32, kAccessRead | kAccessTxPdo),
                      make_entry(3, "Not mappable", DataType::unsigned8, kAccessRead)}));
  add_pdo_mapping(od, 0x1600, "RxPDO 1", {{0x7000, 0, 16}}, {4, true, 64});
  add_pdo_mapping(od, 0x1601, "RxPDO 2", {{0x7001, 0, 1}, {0, 0, 7}});
  add_pdo_mapping(od, 0x1A00, "TxPDO 1", {{0x6000, 1, 8}, {0x6000, 2, 32}});
  add_pdo_mapping(od, 0x1A01, "TxPDO fixed", {{0x6000, 1, 8}}, {1, false, 0});
  add_pdo_assignment(od, 2, PdoDirection::rx, {0x1600}, {2, true, 3});
  add_pdo_assignment(od, 3, PdoDirection::tx, {0x1A00});
  return od;
}

TEST(CompleteAccess, DownloadsRewriteTheEntriesBehindSubindexZero) {
  ObjectDictionary od = mapping_dictionary();
  std::vector<std::pair<std::uint16_t, std::uint8_t>> changes;
  od.set_change_listener([&](std::uint16_t i, std::uint8_t s) { changes.emplace_back(i, s); });
  EXPECT_EQ(od.sdo_write_complete(0x1C12, 0, Bytes{0x02, 0x00, 0x00, 0x16, 0x01, 0x16},
                                  in(AlState::preop))
                .code(),
            0u);
  EXPECT_EQ(od.get<std::uint8_t>(0x1C12, 0), 2);
  EXPECT_EQ(od.get<std::uint16_t>(0x1C12, 2), 0x1601);
  ASSERT_EQ(changes.size(), 1u);
  EXPECT_EQ(changes[0], (std::pair<std::uint16_t, std::uint8_t>{0x1C12, 0}));

  EXPECT_EQ(od.sdo_write_complete(0x1C12, 0, Bytes{0x01, 0x00, 0x00}, in(AlState::preop)).code(),
            code(SdoAbortCode::length_too_low));
  EXPECT_EQ(
      od.sdo_write_complete(0x1C12, 0, Bytes{0x01, 0x00, 0x00, 0x16, 0x00}, in(AlState::preop))
          .code(),
      code(SdoAbortCode::length_too_high));
  EXPECT_EQ(
      od.sdo_write_complete(0x1C12, 0, Bytes{0x03, 0x00, 0, 0, 0, 0, 0, 0}, in(AlState::preop))
          .code(),
      code(SdoAbortCode::value_range_exceeded))
      << "more entries than the object has";
  EXPECT_EQ(
      od.sdo_write_complete(0x1C12, 0, Bytes{0x01, 0x00, 0x00, 0x1A}, in(AlState::preop)).code(),
      code(SdoAbortCode::value_range_exceeded))
      << "a TxPDO in the RxPDO assignment";
  EXPECT_EQ(od.get<std::uint8_t>(0x1C12, 0), 2) << "a refused write leaves the object alone";
  EXPECT_EQ(od.get<std::uint16_t>(0x1C12, 1), 0x1600);
  EXPECT_EQ(
      od.sdo_write_complete(0x1C12, 0, Bytes{0x01, 0x00, 0x00, 0x16}, in(AlState::safeop)).code(),
      code(SdoAbortCode::cannot_store_device_state));
  // A read-only record takes a complete write that leaves it unchanged, not one that changes it.
  EXPECT_EQ(od.sdo_write_complete(0x1A01, 0, Bytes{0x01, 0x00, 0x08, 0x01, 0x00, 0x60},
                                  in(AlState::preop))
                .code(),
            0u);
  EXPECT_EQ(od.sdo_write_complete(0x1A01, 0, Bytes{0x01, 0x00, 0x08, 0x02, 0x00, 0x60},
                                  in(AlState::preop))
                .code(),
            code(SdoAbortCode::write_of_read_only));
  // From subindex 1: entries only, subindex 0 untouched.
  EXPECT_EQ(od.sdo_write_complete(0x1C13, 1, Bytes{0x01, 0x1A}, in(AlState::preop)).code(),
            code(SdoAbortCode::cannot_store_device_state))
      << "entries only change while subindex 0 is 0";
}

TEST(PdoMapping, EntriesChangeOnlyWhileSubindexZeroIsZero) {
  ObjectDictionary od = mapping_dictionary();
  const auto u32 = [](std::uint32_t v) { return to_le_bytes(v); };
  EXPECT_EQ(write(od, 0x1600, 1, u32(0x70010001)), code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(write(od, 0x1600, 0, {0}, AlState::safeop),
            code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(write(od, 0x1600, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1600, 1, u32(0x70010001)), 0u);
  EXPECT_EQ(write(od, 0x1600, 2, u32(0x70000010)), 0u);
  EXPECT_EQ(write(od, 0x1600, 3, u32(0x70000008)), code(SdoAbortCode::object_not_mappable))
      << "bit length differs from the object's";
  EXPECT_EQ(write(od, 0x1600, 3, u32(0x60000108)), code(SdoAbortCode::object_not_mappable))
      << "a TxPDO-mappable object in an RxPDO";
  EXPECT_EQ(write(od, 0x1600, 3, u32(0x71000010)), code(SdoAbortCode::object_not_mappable))
      << "no such object";
  EXPECT_EQ(write(od, 0x1600, 3, u32(0x00050008)), 0u) << "UNSIGNED8 dummy entry";
  EXPECT_EQ(write(od, 0x1600, 4, u32(0x00000007)), 0u) << "index 0 gap";
  EXPECT_EQ(write(od, 0x1600, 0, {5}), code(SdoAbortCode::value_too_high)) << "capacity 4";
  EXPECT_EQ(write(od, 0x1600, 0, {4}), 0u);
  EXPECT_EQ(od.get<std::uint8_t>(0x1600, 0), 4);
  // 1 + 16 + 8 + 7 = 32 bits; a fifth 32-bit entry would exceed max_bits 64 only via sub0.
  EXPECT_EQ(write(od, 0x1600, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1600, 1, u32(0x00000040)), 0u);
  EXPECT_EQ(write(od, 0x1600, 0, {2}), code(SdoAbortCode::pdo_length_exceeded))
      << "64 + 16 bits exceed the PDO's 64";
  EXPECT_EQ(write(od, 0x1A01, 0, {0}), code(SdoAbortCode::write_of_read_only));
  // Mapping entries of a tx PDO.
  EXPECT_EQ(write(od, 0x1A00, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1A00, 1, u32(0x60000308)), code(SdoAbortCode::object_not_mappable));
  EXPECT_EQ(write(od, 0x1A00, 1, u32(0x70000010)), code(SdoAbortCode::object_not_mappable));
}

TEST(PdoMapping, AssignmentNamesExistingPdosOfItsDirection) {
  ObjectDictionary od = mapping_dictionary();
  const auto u16 = [](std::uint16_t v) { return to_le_bytes(v); };
  EXPECT_EQ(write(od, 0x1C12, 1, u16(0x1601)), code(SdoAbortCode::cannot_store_device_state));
  EXPECT_EQ(write(od, 0x1C12, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1C12, 1, u16(0x1A00)), code(SdoAbortCode::value_range_exceeded));
  EXPECT_EQ(write(od, 0x1C12, 1, u16(0x1605)), code(SdoAbortCode::value_range_exceeded));
  EXPECT_EQ(write(od, 0x1C12, 1, u16(0x1600)), 0u);
  EXPECT_EQ(write(od, 0x1C12, 2, u16(0x1601)), 0u);
  EXPECT_EQ(write(od, 0x1C12, 0, {2}), 0u) << "2 + 1 bytes fit the SM's 3";
  // Grow 0x1600 to 32 bits: 4 + 1 bytes no longer fit.
  EXPECT_EQ(write(od, 0x1C12, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1600, 0, {0}), 0u);
  EXPECT_EQ(write(od, 0x1600, 2, to_le_bytes(std::uint32_t{0x00000010})), 0u);
  EXPECT_EQ(write(od, 0x1600, 0, {2}), 0u);
  EXPECT_EQ(write(od, 0x1C12, 0, {2}), code(SdoAbortCode::pdo_length_exceeded));
  EXPECT_EQ(write(od, 0x1C12, 0, {3}), code(SdoAbortCode::value_too_high));
}

TEST(PdoMapping, LayoutFollowsAssignmentAndMapping) {
  ObjectDictionary od = mapping_dictionary();
  auto outputs = process_data_layout(od, 2);
  ASSERT_TRUE(outputs.ok()) << outputs.error().describe();
  EXPECT_EQ(outputs->pdos, (std::vector<std::uint16_t>{0x1600}));
  ASSERT_EQ(outputs->entries.size(), 1u);
  EXPECT_EQ(outputs->entries[0], (MappedEntry{0x1600, 0x7000, 0, 0, 16, false}));
  EXPECT_EQ(outputs->byte_length, 2u);

  auto inputs = process_data_layout(od, 3);
  ASSERT_TRUE(inputs.ok());
  ASSERT_EQ(inputs->entries.size(), 2u);
  EXPECT_EQ(inputs->entries[1], (MappedEntry{0x1A00, 0x6000, 2, 8, 32, false}));
  EXPECT_EQ(inputs->bit_length, 40u);
  EXPECT_EQ(inputs->byte_length, 5u);

  // Reassign SM2 to 0x1601 then 0x1600: a bit, a 7-bit gap, then the word.
  ASSERT_EQ(write(od, 0x1C12, 0, {0}), 0u);
  ASSERT_EQ(write(od, 0x1C12, 1, to_le_bytes(std::uint16_t{0x1601})), 0u);
  ASSERT_EQ(write(od, 0x1C12, 2, to_le_bytes(std::uint16_t{0x1600})), 0u);
  ASSERT_EQ(write(od, 0x1C12, 0, {2}), 0u);
  outputs = process_data_layout(od, 2);
  ASSERT_TRUE(outputs.ok());
  EXPECT_EQ(outputs->pdos, (std::vector<std::uint16_t>{0x1601, 0x1600}));
  ASSERT_EQ(outputs->entries.size(), 3u);
  EXPECT_EQ(outputs->entries[0], (MappedEntry{0x1601, 0x7001, 0, 0, 1, false}));
  EXPECT_EQ(outputs->entries[1], (MappedEntry{0x1601, 0, 0, 1, 7, true}));
  EXPECT_EQ(outputs->entries[2], (MappedEntry{0x1600, 0x7000, 0, 8, 16, false}));
  EXPECT_EQ(outputs->byte_length, 3u);

  // Values travel between the image and the dictionary bit-exactly.
  const Bytes image{0x81, 0xCD, 0xAB};
  const auto changed = unpack_outputs(od, *outputs, image);
  EXPECT_EQ(changed.size(), 2u);
  EXPECT_EQ(od.get<bool>(0x7001, 0), true);
  EXPECT_EQ(od.get<std::uint16_t>(0x7000, 0), 0xABCD);
  EXPECT_TRUE(unpack_outputs(od, *outputs, image).empty()) << "nothing changed the second time";

  od.set<std::uint8_t>(0x6000, 1, 0x5A);
  od.find(0x6000, 2)->on_read = [](ObjectEntry& e, const AccessContext& c) {
    EXPECT_EQ(c.state, AlState::op);
    e.value = to_le_bytes(std::int32_t{-2});
    return SdoStatus{};
  };
  std::vector<std::uint8_t> in_image(5, 0);
  pack_inputs(od, *inputs, in_image);
  EXPECT_EQ(in_image, (Bytes{0x5A, 0xFE, 0xFF, 0xFF, 0xFF}));

  // A missing assigned PDO is an error naming it.
  od.remove(0x1A00);
  auto broken = process_data_layout(od, 3);
  ASSERT_FALSE(broken.ok());
  EXPECT_NE(broken.error().message().find("0x1A00"), std::string::npos) << broken.error().message();
  auto none = process_data_layout(od, 4);
  ASSERT_TRUE(none.ok());
  EXPECT_EQ(none->byte_length, 0u);
}

TEST(OdLists, SelectObjectsByEntryFlags) {
  ObjectDictionary od = mapping_dictionary();
  od.find(0x7000, 0)->access |= kAccessBackup;
  od.find(0x6000, 3)->access |= kAccessSettings;
  EXPECT_EQ(od.od_list(wire::OdListType::all).size(), od.size());
  EXPECT_EQ(od.od_list(wire::OdListType::rx_pdo_mappable),
            (std::vector<std::uint16_t>{0x7000, 0x7001}));
  EXPECT_EQ(od.od_list(wire::OdListType::tx_pdo_mappable), (std::vector<std::uint16_t>{0x6000}));
  EXPECT_EQ(od.od_list(wire::OdListType::backup), (std::vector<std::uint16_t>{0x7000}));
  EXPECT_EQ(od.od_list(wire::OdListType::settings), (std::vector<std::uint16_t>{0x6000}));
  EXPECT_EQ(od.od_list(wire::OdListType::number_of_objects),
            (std::vector<std::uint16_t>{static_cast<std::uint16_t>(od.size()), 2, 1, 1, 1}));
}

TEST(Defaults, ResetRestoresEntriesThatHaveOne) {
  ObjectDictionary od = access_dictionary();
  od.find(0x2002, 0)->default_value = to_le_bytes(std::int16_t{42});
  ASSERT_EQ(write(od, 0x2002, 0, to_le_bytes(std::int16_t{1})), 0u);
  ASSERT_EQ(write(od, 0x2004, 0, to_le_bytes(std::int16_t{3})), 0u);
  od.reset_to_defaults();
  EXPECT_EQ(od.get<std::int16_t>(0x2002, 0), 42);
  EXPECT_EQ(od.get<std::int16_t>(0x2004, 0), 3);
}

}  // namespace
}  // namespace ecat::sim
