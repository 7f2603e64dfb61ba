#include <map>

#include <gtest/gtest.h>

#include <ecat/master/pdo.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/wire/sii.hpp>

#include "support/shared_data.hpp"

namespace ecat::master {
namespace {

wire::SiiImage profile_sii(const std::string& profile) {
  sim::DeviceConfig config;
  config.profile = profile;
  auto esc = sim::make_device(config);
  EXPECT_TRUE(esc.ok()) << (esc.ok() ? "" : esc.error().describe());
  auto decoded = wire::decode_sii((*esc)->eeprom());
  EXPECT_TRUE(decoded.ok());
  return decoded->image;
}

PdoLayout sii_layout(const wire::SiiImage& sii) {
  auto layout = pdo_layout_from_sii(sii);
  EXPECT_TRUE(layout.ok()) << (layout.ok() ? "" : layout.error().describe());
  return layout.ok() ? *layout : PdoLayout{};
}

TEST(PdoLayoutFromSii, El2809HasTwoOutputSyncManagersOfEightOneBitPdos) {
  const PdoLayout layout = sii_layout(profile_sii("EL2809"));
  ASSERT_EQ(layout.sync_managers.size(), 2u);
  for (std::uint8_t sm = 0; sm < 2; ++sm) {
    const auto& group = layout.sync_managers[sm];
    EXPECT_EQ(group.sync_manager, sm);
    EXPECT_EQ(group.direction, PdoDirection::output);
    EXPECT_EQ(group.bit_length, 8u);
    EXPECT_EQ(group.byte_length(), 1u);
    ASSERT_EQ(group.pdos.size(), 8u);
    for (std::size_t i = 0; i < 8; ++i) {
      const Pdo& pdo = group.pdos[i];
      const auto ch = 8 * sm + i;
      EXPECT_EQ(pdo.index, 0x1600 + ch);
      EXPECT_EQ(pdo.name, "Channel " + std::to_string(ch + 1));
      EXPECT_TRUE(pdo.mandatory);
      EXPECT_TRUE(pdo.fixed_content);
      EXPECT_EQ(pdo.bit_offset, i);
      ASSERT_EQ(pdo.entries.size(), 1u);
      EXPECT_EQ(pdo.entries[0].index, 0x7000 + 0x10 * ch);
      EXPECT_EQ(pdo.entries[0].subindex, 1);
      EXPECT_EQ(pdo.entries[0].name, "Output");
      EXPECT_EQ(pdo.entries[0].data_type, coe_type::kBoolean);
      EXPECT_EQ(pdo.entries[0].bit_offset, i);
    }
  }
  EXPECT_TRUE(layout.unassigned.empty());
  EXPECT_EQ(layout.bit_length(PdoDirection::output), 16u);
  EXPECT_EQ(layout.bit_length(PdoDirection::input), 0u);
}

TEST(PdoLayoutFromSii, El3202EntriesHaveOffsetsIncludingTheGap) {
  const PdoLayout layout = sii_layout(profile_sii("EL3202"));
  ASSERT_EQ(layout.sync_managers.size(), 1u);
  const auto& sm3 = layout.sync_managers[0];
  EXPECT_EQ(sm3.sync_manager, 3);
  EXPECT_EQ(sm3.direction, PdoDirection::input);
  EXPECT_EQ(sm3.byte_length(), 8u);
  ASSERT_EQ(sm3.pdos.size(), 2u);
  const Pdo& ch2 = sm3.pdos[1];
  EXPECT_EQ(ch2.index, 0x1A01);
  EXPECT_EQ(ch2.name, "RTD Inputs Channel 2");
  EXPECT_EQ(ch2.bit_offset, 32u);
  const std::vector<std::uint32_t> offsets{32, 33, 34, 36, 38, 39, 46, 47, 48};
  ASSERT_EQ(ch2.entries.size(), offsets.size());
  for (std::size_t i = 0; i < offsets.size(); ++i)
    EXPECT_EQ(ch2.entries[i].bit_offset, offsets[i]) << i;
  EXPECT_TRUE(ch2.entries[5].padding());
  EXPECT_EQ(ch2.entries[5].bit_length, 7);
  EXPECT_EQ(ch2.entries[5].name, "");
  EXPECT_EQ(ch2.entries[8].name, "Value");
  EXPECT_EQ(ch2.entries[8].data_type, coe_type::kInteger16);
  const auto where = layout.find_entry(0x6010, 0x11);
  ASSERT_TRUE(where.has_value());
  EXPECT_EQ(where->pdo->index, 0x1A01);
  EXPECT_EQ(where->entry->bit_offset, 48u);
  EXPECT_FALSE(layout.find_entry(0x6020, 0x11).has_value());
}

TEST(PdoLayoutFromSii, ServoKeepsPdosWithoutSyncManagerUnassigned) {
  const PdoLayout layout = sii_layout(profile_sii("servo"));
  ASSERT_EQ(layout.sync_managers.size(), 2u);
  EXPECT_EQ(layout.sync_managers[0].sync_manager, 2);
  EXPECT_EQ(layout.sync_managers[0].direction, PdoDirection::output);
  EXPECT_EQ(layout.sync_managers[0].byte_length(), 13u);
  EXPECT_EQ(layout.sync_managers[1].sync_manager, 3);
  EXPECT_EQ(layout.sync_managers[1].byte_length(), 15u);
  ASSERT_EQ(layout.unassigned.size(), 2u);
  EXPECT_EQ(layout.unassigned[0].index, 0x1A01);
  EXPECT_EQ(layout.unassigned[1].index, 0x1601);
  ASSERT_NE(layout.find_pdo(0x1601), nullptr);
  EXPECT_EQ(layout.find_pdo(0x1601)->name, "RxPDO 2");
  EXPECT_EQ(layout.find_pdo(0x1234), nullptr);
}

TEST(PdoLayoutFromSii, TruncatedTxPdoCategoryKeepsTheCompleteEntries) {
  const wire::SiiImage sii = profile_sii("EL1809");
  auto bytes = wire::encode_sii(sii, {false});
  ASSERT_TRUE(bytes.ok());
  // Find the TXPDO category and cut the image in the middle of its 6th PDO.
  std::size_t word = wire::sii_word::kFirstCategory;
  std::size_t cut = 0;
  while (2 * word + 4 <= bytes->size()) {
    const auto type = wire::load_le16(bytes->data() + 2 * word);
    const auto size = wire::load_le16(bytes->data() + 2 * word + 2);
    if (type == wire::sii_category::kTxPdo) {
      cut = 2 * word + 4 + 5 * 16 + 12;  // 5 whole PDOs (8 + 8 bytes), half of the 6th entry
      break;
    }
    word += 2 + size;
  }
  ASSERT_NE(cut, 0u);
  bytes->resize(cut);
  auto decoded = wire::decode_sii(*bytes);
  ASSERT_TRUE(decoded.ok());
  const PdoLayout layout = sii_layout(decoded->image);
  ASSERT_EQ(layout.sync_managers.size(), 1u);
  // The 6th PDO's header is complete but its entry is not: it is kept without entries.
  ASSERT_EQ(layout.sync_managers[0].pdos.size(), 6u);
  EXPECT_TRUE(layout.sync_managers[0].pdos[5].entries.empty());
  EXPECT_EQ(layout.sync_managers[0].bit_length, 5u);
}

TEST(PdoLayoutFromSii, RealImagesGiveTheSizesSoemReports) {
  struct Case {
    const char* file;
    std::map<std::uint8_t, std::uint32_t> bits;
  };
  const Case cases[] = {{"eeprom/ek1100.bin", {}},
                        {"eeprom/el2004.bin", {{0, 4}}},
                        {"eeprom/el2828.bin", {{0, 8}}},
                        {"eeprom/el2262.bin", {{0, 53}, {1, 53}, {2, 32}}}};
  for (const auto& c : cases) {
    const auto path = ::ecat::test::shared_data(c.file);
    if (!path) {
      GTEST_SKIP() << "real-device data " << c.file << " not found";
    }
    const auto image = ::ecat::test::read_file(*path);
    auto decoded = wire::decode_sii(image);
    ASSERT_TRUE(decoded.ok()) << c.file;
    const PdoLayout layout = sii_layout(decoded->image);
    std::map<std::uint8_t, std::uint32_t> bits;
    for (const auto& sm : layout.sync_managers)
      bits[sm.sync_manager] = sm.bit_length;
    EXPECT_EQ(bits, c.bits) << c.file;
  }
}

TEST(PdoLayoutFromSii, El2262PaddingPdosKeepOffsetsAndDirections) {
  ECAT_SHARED_DATA_OR_SKIP(path, "eeprom/el2262.bin");
  auto decoded = wire::decode_sii(::ecat::test::read_file(path));
  ASSERT_TRUE(decoded.ok());
  const PdoLayout layout = sii_layout(decoded->image);
  ASSERT_EQ(layout.sync_managers.size(), 3u);
  EXPECT_EQ(layout.sync_managers[2].direction, PdoDirection::input);
  const auto& sm0 = layout.sync_managers[0];
  ASSERT_EQ(sm0.pdos.size(), 10u);
  EXPECT_EQ(sm0.pdos[0].index, 0x1700);  // CycCount0, 16 bits
  EXPECT_EQ(sm0.pdos[1].bit_offset, 16u);
  EXPECT_EQ(sm0.pdos[2].bit_offset, 17u);  // after the 1-bit Sample0
  EXPECT_EQ(sm0.pdos[3].name, "Gap");
  EXPECT_TRUE(sm0.pdos[3].entries[0].padding());
  EXPECT_EQ(sm0.pdos[3].bit_offset, 25u);
  EXPECT_EQ(sm0.byte_length(), 7u);
}

TEST(MakePdoLayout, RejectsMixedDirectionsDuplicatesAndBadSyncManagers) {
  Pdo in{0x1A00, PdoDirection::input, 2, "in", {{0x6000, 1, 8, coe_type::kUnsigned8, "x", 0}}};
  Pdo out{0x1600, PdoDirection::output, 2, "out", {{0x7000, 1, 8, coe_type::kUnsigned8, "y", 0}}};
  auto mixed = make_pdo_layout({in, out});
  ASSERT_FALSE(mixed.ok());
  EXPECT_NE(mixed.error().message().find("RxPDO 0x1600 \"out\" is assigned to SyncManager 2, "
                                         "which carries inputs"),
            std::string::npos)
      << mixed.error().message();

  Pdo again = in;
  again.sync_manager = 3;
  auto twice = make_pdo_layout({in, again});
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.error().message().find("assigned twice"), std::string::npos);

  Pdo far = in;
  far.sync_manager = 16;
  auto bad_sm = make_pdo_layout({far});
  ASSERT_FALSE(bad_sm.ok());
  EXPECT_EQ(bad_sm.error().code(), Errc::out_of_range);

  Pdo huge{0x1A00, PdoDirection::input, 3, "", {}};
  for (int i = 0; i < 2100; ++i)
    huge.entries.push_back({0x6000, 1, 255, coe_type::kNone, "", 0});
  auto too_big = make_pdo_layout({huge});
  ASSERT_FALSE(too_big.ok());
  EXPECT_EQ(too_big.error().code(), Errc::out_of_range);
}

TEST(PdoLayoutFromCoe, TakesMappingsAndNamesFromTheSii) {
  const PdoLayout sii = sii_layout(profile_sii("servo"));
  CoePdoConfiguration coe;
  coe.assignments = {{2, {0x1601}, std::nullopt}, {3, {0x1A01}, PdoDirection::input}};
  coe.mappings = {
      {0x1601, {coe_mapping_entry(0x6040, 0, 16), coe_mapping_entry(0x607A, 0, 32)}, ""},
      {0x1A01,
       {coe_mapping_entry(0x6041, 0, 16), coe_mapping_entry(0, 0, 8),
        coe_mapping_entry(0x6064, 0, 32)},
       "Compact inputs"}};
  coe.entry_info = {{0x6064, 0, coe_type::kInteger32, "Position actual (SDO info)"}};
  auto layout = pdo_layout_from_coe(coe, &sii);
  ASSERT_TRUE(layout.ok()) << layout.error().describe();
  ASSERT_EQ(layout->sync_managers.size(), 2u);
  const auto& out = layout->sync_managers[0];
  EXPECT_EQ(out.direction, PdoDirection::output);
  EXPECT_EQ(out.byte_length(), 6u);
  ASSERT_EQ(out.pdos.size(), 1u);
  EXPECT_EQ(out.pdos[0].name, "RxPDO 2");
  EXPECT_EQ(out.pdos[0].entries[1].name, "Target position");
  EXPECT_EQ(out.pdos[0].entries[1].data_type, coe_type::kInteger32);
  EXPECT_EQ(out.pdos[0].entries[1].bit_offset, 16u);
  const auto& in = layout->sync_managers[1];
  EXPECT_EQ(in.byte_length(), 7u);
  EXPECT_EQ(in.pdos[0].name, "Compact inputs");
  EXPECT_TRUE(in.pdos[0].entries[1].padding());
  EXPECT_EQ(in.pdos[0].entries[2].name, "Position actual (SDO info)");
  EXPECT_EQ(in.pdos[0].entries[2].bit_offset, 24u);
  // The SII's default PDOs are no longer assigned.
  std::vector<std::uint16_t> unassigned;
  for (const auto& p : layout->unassigned)
    unassigned.push_back(p.index);
  EXPECT_EQ(unassigned, (std::vector<std::uint16_t>{0x1600, 0x1A00}));
}

TEST(PdoLayoutFromCoe, FixedPdoWithoutMappingComesFromTheSii) {
  const PdoLayout sii = sii_layout(profile_sii("EL3202"));
  CoePdoConfiguration coe;
  coe.assignments = {{2, {}, PdoDirection::output}, {3, {0x1A01}, std::nullopt}};
  auto layout = pdo_layout_from_coe(coe, &sii);
  ASSERT_TRUE(layout.ok()) << layout.error().describe();
  ASSERT_EQ(layout->sync_managers.size(), 2u);
  EXPECT_TRUE(layout->sync_managers[0].pdos.empty());
  EXPECT_EQ(layout->sync_managers[0].direction, PdoDirection::output);
  EXPECT_EQ(layout->sync_managers[1].byte_length(), 4u);
  EXPECT_EQ(layout->sync_managers[1].pdos[0].entries[8].bit_offset, 16u);
}

TEST(PdoLayoutFromCoe, ErrorsNameTheObject) {
  CoePdoConfiguration missing;
  missing.assignments = {{2, {0x1600}, std::nullopt}};
  auto a = pdo_layout_from_coe(missing);
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.error().message().find("0x1c12 assigns PDO 0x1600 but its mapping is unknown"),
            std::string::npos)
      << a.error().message();

  CoePdoConfiguration zero;
  zero.assignments = {{3, {0x1A00}, std::nullopt}};
  zero.mappings = {{0x1A00, {coe_mapping_entry(0x6000, 1, 0)}, ""}};
  auto b = pdo_layout_from_coe(zero);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.error().message().find("0x1a00:01 = 0x60000100"), std::string::npos)
      << b.error().message();

  CoePdoConfiguration odd;
  odd.assignments = {{2, {0x1800}, std::nullopt}};
  auto c = pdo_layout_from_coe(odd);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message().find("PDO 0x1800"), std::string::npos);

  CoePdoConfiguration mixed;
  mixed.assignments = {{2, {0x1600, 0x1A00}, std::nullopt}};
  EXPECT_FALSE(pdo_layout_from_coe(mixed).ok());
}

TEST(CoeMappingWrites, FollowsTheEtg1020Order) {
  Pdo rx{0x1601, PdoDirection::output, 2, "", {{0x6040, 0, 16, coe_type::kUnsigned16, "", 0}}};
  Pdo tx{0x1A01,
         PdoDirection::input,
         3,
         "",
         {{0x6041, 0, 16, coe_type::kUnsigned16, "", 0},
          {0x6064, 0, 32, coe_type::kInteger32, "", 0}}};
  Pdo fixed{0x1A02, PdoDirection::input, 3, "", {{0x6000, 1, 8, 0, "", 0}}};
  fixed.fixed_content = true;
  auto layout = make_pdo_layout({rx, tx, fixed});
  ASSERT_TRUE(layout.ok());
  auto writes = coe_mapping_writes(*layout);
  ASSERT_TRUE(writes.ok());
  std::vector<std::string> text;
  for (const auto& w : *writes)
    text.push_back(to_string(w));
  const std::vector<std::string> expected{
      "0x1c12:00 = 00",          "0x1c13:00 = 00",          "0x1601:00 = 00",
      "0x1601:01 = 10 00 40 60", "0x1601:00 = 01",          "0x1a01:00 = 00",
      "0x1a01:01 = 10 00 41 60", "0x1a01:02 = 20 00 64 60", "0x1a01:00 = 02",
      "0x1c12:01 = 01 16",       "0x1c12:00 = 01",          "0x1c13:01 = 01 1a",
      "0x1c13:02 = 02 1a",       "0x1c13:00 = 02"};
  EXPECT_EQ(text, expected);

  CoeMappingOptions all;
  all.write_fixed_mappings = true;
  EXPECT_EQ(coe_mapping_writes(*layout, all)->size(), expected.size() + 3);
}

// Applies the writes to a map standing in for the object dictionary, reads the objects back the
// way a master uploads them and checks the same layout comes out.
TEST(CoeMappingWrites, RoundTripThroughPdoLayoutFromCoe) {
  const PdoLayout sii = sii_layout(profile_sii("servo"));
  Pdo rx = *sii.find_pdo(0x1601);
  rx.sync_manager = 2;
  Pdo tx = *sii.find_pdo(0x1A00);
  tx.sync_manager = 3;
  Pdo tx2 = *sii.find_pdo(0x1A01);
  tx2.sync_manager = 3;
  auto wanted = make_pdo_layout({rx, tx, tx2});
  ASSERT_TRUE(wanted.ok());
  auto writes = coe_mapping_writes(*wanted);
  ASSERT_TRUE(writes.ok());

  std::map<std::pair<std::uint16_t, std::uint8_t>, std::uint32_t> od;
  for (const auto& w : *writes) {
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < w.data.size(); ++i)
      v |= std::uint32_t{w.data[i]} << (8 * i);
    od[{w.index, w.subindex}] = v;
  }
  CoePdoConfiguration coe;
  for (std::uint8_t sm : {2, 3}) {
    CoePdoAssignment a{sm, {}, std::nullopt};
    const auto object = pdo_assignment_object(sm);
    for (std::uint32_t i = 1; i <= od[{object, 0}]; ++i) {
      const auto pdo = static_cast<std::uint16_t>(od[{object, static_cast<std::uint8_t>(i)}]);
      a.pdo_indices.push_back(pdo);
      CoePdoMapping m{pdo, {}, ""};
      for (std::uint32_t k = 1; k <= od[{pdo, 0}]; ++k)
        m.entries.push_back(od[{pdo, static_cast<std::uint8_t>(k)}]);
      coe.mappings.push_back(m);
    }
    coe.assignments.push_back(a);
  }
  auto back = pdo_layout_from_coe(coe, &sii);
  ASSERT_TRUE(back.ok()) << back.error().describe();
  EXPECT_EQ(back->sync_managers, wanted->sync_managers);
}

TEST(CoeTypeName, NamesCodes) {
  EXPECT_EQ(coe_type_name(coe_type::kInteger16), "INTEGER16");
  EXPECT_EQ(coe_type_name(0x0032), "BIT3");
  EXPECT_EQ(coe_type_name(0x0777), "0x0777");
  EXPECT_EQ(pdo_direction_of_index(0x17FF), PdoDirection::output);
  EXPECT_EQ(pdo_direction_of_index(0x1A00), PdoDirection::input);
  EXPECT_FALSE(pdo_direction_of_index(0x1800).has_value());
}

}  // namespace
}  // namespace ecat::master
