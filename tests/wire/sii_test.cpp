#include <algorithm>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

#include "support/shared_data.hpp"

namespace {

using namespace ecat::wire;
using nlohmann::json;
using ::testing::HasSubstr;

// ---------------------------------------------------------------------------------------------
// Helpers

// Ground truth numbers come as integers or as "0x..." strings.
std::uint64_t num(const json& j) {
  if (j.is_string()) return std::stoull(j.get<std::string>(), nullptr, 16);
  return j.get<std::uint64_t>();
}

std::string hex_of(const std::vector<std::uint8_t>& bytes) {
  static const char* digits = "0123456789abcdef";
  std::string s;
  for (auto b : bytes) {
    s += digits[b >> 4];
    s += digits[b & 0xF];
  }
  return s;
}

std::string hex_of(std::string_view bytes) {
  return hex_of(std::vector<std::uint8_t>(bytes.begin(), bytes.end()));
}

// The string a ground-truth name field should equal: null means no string (index 0).
std::string name_of(const json& j) {
  return j.is_null() ? std::string() : j.get<std::string>();
}

bool any_warning_contains(const SiiDecoded& d, const std::string& needle) {
  return std::any_of(d.warnings.begin(), d.warnings.end(),
                     [&](const std::string& w) { return w.find(needle) != std::string::npos; });
}

// An image exercising every category the codec knows, built in code.
SiiImage full_image() {
  SiiImage img;
  img.pdi_control = 0x0C80;
  img.pdi_configuration = 0x6E;
  img.sync_impulse_length = 100;
  img.pdi_configuration2 = 0x0044;
  img.station_alias = 0x1234;
  img.identity = {0x0000ABCD, 0x12345678, 0x00020001, 0xDEADBEEF};
  img.execution_delay = 5;
  img.port0_delay = 6;
  img.port1_delay = 7;
  img.bootstrap_mailbox = {0x1000, 0x0200, 0x1200, 0x0200};
  img.standard_mailbox = {0x1000, 0x0080, 0x1080, 0x0080};
  img.mailbox_protocols = mailbox_protocol::kCoe | mailbox_protocol::kFoe | mailbox_protocol::kEoe;
  img.eeprom_size = 31;  // 4 KiB
  img.version = 1;
  img.reserved_words[0x20] = 0xA5A5;
  img.reserved_words[0x13] = 0x0102;
  img.strings = {"Drive",  "Servo",   "Drive 1 \xB5s", "Inputs",
                 "Status", "Outputs", "Control",       "DcSync"};
  img.data_types = std::vector<std::uint8_t>{1, 2, 3, 4};
  SiiGeneral g;
  g.group_index = 2;
  g.order_index = 1;
  g.name_index = 3;
  g.coe_details =
      sii_coe_detail::kSdo | sii_coe_detail::kSdoInfo | sii_coe_detail::kSdoCompleteAccess;
  g.foe_details = 1;
  g.eoe_details = 1;
  g.ds402_channels = 1;
  g.flags = sii_general_flag::kEnableSafeOp;
  g.current_on_ebus_ma = -500;
  g.group_index_2 = 2;
  g.physical_port = 0x0011;
  g.physical_memory_address = 0x0100;
  img.general = g;
  img.fmmus = {sii_fmmu_usage::kOutputs, sii_fmmu_usage::kInputs, sii_fmmu_usage::kMailboxState,
               sii_fmmu_usage::kNone};
  img.sync_managers = {{0x1000, 0x80, 0x26, 0, 0x01, sii_sm_type::kMailboxOut},
                       {0x1080, 0x80, 0x22, 0, 0x01, sii_sm_type::kMailboxIn},
                       {0x1100, 4, 0x64, 0, 0x01, sii_sm_type::kOutputs},
                       {0x1400, 6, 0x20, 0, 0x01, sii_sm_type::kInputs}};
  img.fmmu_ex = std::vector<std::uint8_t>{0xFE, 0xFF, 0x00, 0x00};
  img.sync_unit = std::vector<std::uint8_t>{0xF0, 0xFF};
  SiiPdo tx;
  tx.index = 0x1A00;
  tx.sync_manager = 3;
  tx.name_index = 4;
  tx.flags = sii_pdo_flag::kMandatory;
  tx.entries = {{0x6041, 0, 5, 0x06, 16, 0}, {0x6064, 0, 0, 0x04, 32, 0}};
  SiiPdo rx;
  rx.index = 0x1600;
  rx.sync_manager = 2;
  rx.name_index = 6;
  rx.entries = {{0x6040, 0, 7, 0x06, 16, 0}, {0, 0, 0, 0, 16, 0}};
  img.txpdos = {tx};
  img.rxpdos = {rx};
  SiiDcSync dc;
  dc.cycle_time_0 = 1000000;
  dc.shift_time_0 = 250000;
  dc.sync0_cycle_factor = 1;
  dc.sync1_cycle_factor = -1;
  dc.assign_activate = 0x0300;
  dc.name_index = 8;
  img.dc = {dc};
  img.other_categories = {{0x0001, {0xAA, 0xBB}}, {0x0800, {0x01, 0x02, 0x03, 0x04}}};
  return img;
}

std::vector<std::uint8_t> encode_or_die(const SiiImage& img, SiiEncodeOptions options = {}) {
  auto bytes = encode_sii(img, options);
  EXPECT_TRUE(bytes.ok()) << (bytes.ok() ? "" : bytes.error().describe());
  return bytes.ok() ? *bytes : std::vector<std::uint8_t>{};
}

// ---------------------------------------------------------------------------------------------
// CRC

TEST(SiiCrc, KnownAnswers) {
  const std::string check = "123456789";
  EXPECT_EQ(sii_crc8(Bytes{reinterpret_cast<const std::uint8_t*>(check.data()), check.size()}),
            0xFB);
  const std::uint8_t zeros[14] = {};
  EXPECT_EQ(sii_crc8(zeros), 0x30);
  const std::uint8_t header[14] = {0x80, 0x0c, 0x68, 0x00, 0x64, 0x00, 0x00,
                                   0x00, 0x34, 0x12, 0x00, 0x00, 0x00, 0x00};
  EXPECT_EQ(sii_crc8(header), 0x6C);
  EXPECT_EQ(sii_crc8(Bytes{}), 0xFF);
}

TEST(SiiCrc, EncoderWritesTheChecksumIntoWordSeven) {
  const auto bytes = encode_or_die(full_image());
  ASSERT_GE(bytes.size(), kSiiHeaderBytes);
  EXPECT_EQ(bytes[14], sii_crc8(Bytes{bytes.data(), 14}));
  EXPECT_EQ(bytes[15], 0x00);
}

// ---------------------------------------------------------------------------------------------
// Names

TEST(SiiNames, CategoriesProtocolsAndUsages) {
  EXPECT_EQ(sii_category_name(10), "STRINGS");
  EXPECT_EQ(sii_category_name(20), "DATATYPES");
  EXPECT_EQ(sii_category_name(30), "GENERAL");
  EXPECT_EQ(sii_category_name(40), "FMMU");
  EXPECT_EQ(sii_category_name(41), "SYNCM");
  EXPECT_EQ(sii_category_name(42), "FMMU_EX");
  EXPECT_EQ(sii_category_name(43), "SYNCUNIT");
  EXPECT_EQ(sii_category_name(50), "TXPDO");
  EXPECT_EQ(sii_category_name(51), "RXPDO");
  EXPECT_EQ(sii_category_name(60), "DC");
  EXPECT_EQ(sii_category_name(0xFFFF), "END");
  EXPECT_EQ(sii_category_name(1), "vendor/unknown");
  EXPECT_EQ(mailbox_protocol_names(0x003F),
            (std::vector<std::string_view>{"AoE", "EoE", "CoE", "FoE", "SoE", "VoE"}));
  EXPECT_EQ(mailbox_protocol_names(0x0C04), (std::vector<std::string_view>{"CoE"}));
  EXPECT_TRUE(mailbox_protocol_names(0).empty());
  EXPECT_EQ(sii_fmmu_usage_name(0), "unused");
  EXPECT_EQ(sii_fmmu_usage_name(1), "outputs");
  EXPECT_EQ(sii_fmmu_usage_name(2), "inputs");
  EXPECT_EQ(sii_fmmu_usage_name(3), "mailbox_state");
  EXPECT_EQ(sii_fmmu_usage_name(0xFF), "unused");
  EXPECT_EQ(sii_fmmu_usage_name(7), "unknown");
  EXPECT_EQ(sii_sync_manager_type_name(1), "mailbox_out");
  EXPECT_EQ(sii_sync_manager_type_name(2), "mailbox_in");
  EXPECT_EQ(sii_sync_manager_type_name(3), "outputs");
  EXPECT_EQ(sii_sync_manager_type_name(4), "inputs");
  EXPECT_EQ(sii_sync_manager_type_name(9), "unknown");
  EXPECT_EQ(sii_port_name(1), "MII");
  EXPECT_EQ(sii_port_name(3), "EBUS");
  EXPECT_EQ(sii_port_name(0), "unused");
}

TEST(SiiStrings, Latin1ToUtf8) {
  EXPECT_EQ(sii_string_to_utf8("1\xB5s"), "1\xC2\xB5s");
  EXPECT_EQ(sii_string_to_utf8("\xFF"), "\xC3\xBF");
  EXPECT_EQ(sii_string_to_utf8("plain"), "plain");
}

// ---------------------------------------------------------------------------------------------
// Real images against the ground truth

class SiiGroundTruth : public ::testing::TestWithParam<std::string> {};

TEST_P(SiiGroundTruth, DecodesEveryField) {
  const std::string name = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/" + name + ".bin");
  ECAT_SHARED_DATA_OR_SKIP(truth_path, "ground_truth/" + name + ".json");
  const auto bytes = ecat::test::read_file(image_path);
  std::ifstream truth_file(truth_path);
  const json gt = json::parse(truth_file);

  auto result = decode_sii(bytes);
  ASSERT_TRUE(result.ok()) << result.error().describe();
  const SiiDecoded& d = *result;
  const SiiImage& img = d.image;
  EXPECT_TRUE(d.warnings.empty()) << d.warnings.front();

  // Header
  const auto& h = gt["header"];
  EXPECT_EQ(img.pdi_control, num(h["pdi_control"]));
  EXPECT_EQ(img.pdi_configuration, num(h["pdi_configuration"]));
  EXPECT_EQ(img.sync_impulse_length, num(h["sync_impulse_len_10ns"]));
  EXPECT_EQ(img.pdi_configuration2, num(h["pdi_configuration2"]));
  EXPECT_EQ(img.station_alias, num(h["configured_station_alias"]));
  EXPECT_EQ(d.checksum_word, num(h["checksum_word"]));
  EXPECT_EQ(d.checksum_computed, num(h["checksum_crc8_computed"]));
  EXPECT_EQ(d.checksum_ok, h["checksum_ok"].get<bool>());

  // Identity, delays, mailboxes, protocols, size, version
  const auto& id = gt["identity"];
  EXPECT_EQ(img.identity.vendor_id, num(id["vendor_id_int"]));
  EXPECT_EQ(img.identity.product_code, num(id["product_code_int"]));
  EXPECT_EQ(img.identity.revision, num(id["revision_int"]));
  EXPECT_EQ(img.identity.serial, num(id["serial_int"]));
  EXPECT_EQ(img.execution_delay, num(gt["delays"]["execution_delay"]));
  EXPECT_EQ(img.port0_delay, num(gt["delays"]["port0_delay"]));
  EXPECT_EQ(img.port1_delay, num(gt["delays"]["port1_delay"]));
  for (const auto& [key, mbx] : {std::pair{"bootstrap_mailbox", img.bootstrap_mailbox},
                                 std::pair{"standard_mailbox", img.standard_mailbox}}) {
    const auto& m = gt[key];
    EXPECT_EQ(mbx.recv_offset, num(m["receive_offset(master->slave)"])) << key;
    EXPECT_EQ(mbx.recv_size, num(m["receive_size"])) << key;
    EXPECT_EQ(mbx.send_offset, num(m["send_offset(slave->master)"])) << key;
    EXPECT_EQ(mbx.send_size, num(m["send_size"])) << key;
  }
  EXPECT_EQ(img.mailbox_protocols, num(gt["mailbox_protocols"]["raw"]));
  std::vector<std::string> protocols;
  for (auto p : mailbox_protocol_names(img.mailbox_protocols))
    protocols.emplace_back(p);
  EXPECT_EQ(protocols, gt["mailbox_protocols"]["protocols"].get<std::vector<std::string>>());
  EXPECT_EQ(img.eeprom_size, num(gt["eeprom_size_word(0x3E)"]));
  EXPECT_EQ(img.eeprom_size_bytes(), num(gt["eeprom_size_bytes_declared"]));
  EXPECT_EQ(img.version, num(gt["sii_version(0x3F)"]));

  // Category layout
  const auto& cats = gt["categories"];
  ASSERT_EQ(d.categories.size(), cats.size());
  for (std::size_t i = 0; i < cats.size(); ++i) {
    SCOPED_TRACE("category " + std::to_string(i));
    EXPECT_EQ(d.categories[i].type, num(cats[i]["type"]));
    EXPECT_EQ(d.categories[i].word_address, num(cats[i]["word_address"]));
    EXPECT_EQ(d.categories[i].size_words, cats[i].value("size_words", 0u));
    EXPECT_EQ(sii_category_name(d.categories[i].type), cats[i]["type_name"].get<std::string>());
    EXPECT_FALSE(d.categories[i].truncated);
  }

  // Strings
  const auto& strings = gt["strings"];
  ASSERT_EQ(img.strings.size(), strings.size());
  for (std::size_t i = 0; i < strings.size(); ++i) {
    EXPECT_EQ(num(strings[i]["index"]), i + 1);
    EXPECT_EQ(img.strings[i].size(), num(strings[i]["length"]));
    EXPECT_EQ(hex_of(img.strings[i]), strings[i]["raw_hex"].get<std::string>());
    EXPECT_EQ(sii_string_to_utf8(img.strings[i]), strings[i]["text_latin1"].get<std::string>());
  }

  // General
  const auto& g = gt["general"];
  ASSERT_TRUE(img.general.has_value());
  const SiiGeneral& gen = *img.general;
  EXPECT_EQ(gen.group_index, num(g["group_idx"]));
  EXPECT_EQ(gen.image_index, num(g["image_idx"]));
  EXPECT_EQ(gen.order_index, num(g["order_idx"]));
  EXPECT_EQ(gen.name_index, num(g["name_idx"]));
  EXPECT_EQ(gen.coe_details, num(g["coe_details_raw"]));
  EXPECT_EQ(gen.foe_details, num(g["foe_details_raw"]));
  EXPECT_EQ(gen.eoe_details, num(g["eoe_details_raw"]));
  EXPECT_EQ(gen.soe_channels, num(g["soe_channels"]));
  EXPECT_EQ(gen.ds402_channels, num(g["ds402_channels"]));
  EXPECT_EQ(gen.sysman_class, num(g["sysman_class"]));
  EXPECT_EQ(gen.flags, num(g["flags_raw"]));
  EXPECT_EQ(gen.current_on_ebus_ma, g["current_on_ebus_mA"].get<int>());
  EXPECT_EQ(gen.physical_port, num(g["physical_port_raw"]));
  EXPECT_EQ(gen.physical_memory_address, num(g["physical_memory_address"]));
  for (std::size_t p = 0; p < 4; ++p) {
    EXPECT_EQ(sii_port_name(gen.port(p)), g["ports"][p].get<std::string>()) << "port " << p;
  }
  EXPECT_EQ(sii_string_to_utf8(img.string(gen.group_index)), name_of(g["group"]));
  EXPECT_EQ(sii_string_to_utf8(img.string(gen.image_index)), name_of(g["image"]));
  EXPECT_EQ(sii_string_to_utf8(img.string(gen.order_index)), name_of(g["order"]));
  EXPECT_EQ(sii_string_to_utf8(img.string(gen.name_index)), name_of(g["name"]));
  EXPECT_EQ(sii_string_to_utf8(img.device_name()), gt["device_name"].get<std::string>());

  // FMMU
  const auto& fmmu = gt["fmmu"];
  ASSERT_EQ(img.fmmus.size(), fmmu.size());
  for (std::size_t i = 0; i < fmmu.size(); ++i) {
    EXPECT_EQ(img.fmmus[i], num(fmmu[i]["usage_raw"])) << "FMMU " << i;
    EXPECT_EQ(sii_fmmu_usage_name(img.fmmus[i]), fmmu[i]["usage"].get<std::string>());
  }

  // SyncManagers, with the control and enable bytes decoded
  const auto& sms = gt["sync_managers"];
  ASSERT_EQ(img.sync_managers.size(), sms.size());
  for (std::size_t i = 0; i < sms.size(); ++i) {
    SCOPED_TRACE("SM" + std::to_string(i));
    const auto& sm = img.sync_managers[i];
    const auto& t = sms[i];
    EXPECT_EQ(sm.start, num(t["start"]));
    EXPECT_EQ(sm.length, num(t["length"]));
    EXPECT_EQ(sm.control, num(t["control"]));
    EXPECT_EQ(sm.status, num(t["status"]));
    EXPECT_EQ(sm.enable, num(t["enable"]));
    EXPECT_EQ(sm.type, num(t["type"]));
    auto control = SmControl::decode(sm.control);
    ASSERT_TRUE(control.ok());
    const auto& cd = t["control_decoded"];
    EXPECT_EQ(control->mode == SmMode::buffered,
              cd["mode"].get<std::string>().rfind("buffered", 0) == 0);
    EXPECT_EQ(control->direction == SmDirection::write,
              cd["direction"].get<std::string>().rfind("write", 0) == 0);
    EXPECT_EQ(control->ecat_event, cd["ecat_event"].get<bool>());
    EXPECT_EQ(control->pdi_event, cd["pdi_event"].get<bool>());
    EXPECT_EQ(control->watchdog, cd["watchdog"].get<bool>());
    const auto& ed = t["enable_decoded"];
    EXPECT_EQ(sm.enabled(), ed["enable"].get<bool>());
    EXPECT_EQ(sm.fixed_content(), ed["fixed_content"].get<bool>());
    EXPECT_EQ(sm.virtual_sm(), ed["virtual"].get<bool>());
    EXPECT_EQ(sm.op_only(), ed["op_only"].get<bool>());
  }

  // Raw categories
  const auto raw_matches = [](const std::optional<std::vector<std::uint8_t>>& field,
                              const json& expected) {
    if (expected.is_null()) return !field.has_value();
    return field.has_value() && hex_of(*field) == expected.get<std::string>();
  };
  EXPECT_TRUE(raw_matches(img.fmmu_ex, gt["fmmu_ex_raw_hex"]));
  EXPECT_TRUE(raw_matches(img.sync_unit, gt["syncunit_raw_hex"]));
  EXPECT_TRUE(raw_matches(img.data_types, gt["datatypes_raw_hex"]));

  // PDOs, every entry
  for (const auto& [key, pdos] :
       {std::pair{"txpdo", &img.txpdos}, std::pair{"rxpdo", &img.rxpdos}}) {
    const auto& list = gt[key];
    ASSERT_EQ(pdos->size(), list.size()) << key;
    for (std::size_t i = 0; i < list.size(); ++i) {
      SCOPED_TRACE(std::string(key) + " " + std::to_string(i));
      const SiiPdo& pdo = (*pdos)[i];
      const auto& t = list[i];
      EXPECT_EQ(pdo.index, num(t["index"]));
      EXPECT_EQ(pdo.entries.size(), num(t["n_entries"]));
      EXPECT_EQ(pdo.sync_manager, num(t["sm"]));
      EXPECT_EQ(pdo.dc_sync, num(t["dc_sync"]));
      EXPECT_EQ(pdo.name_index, num(t["name_idx"]));
      EXPECT_EQ(sii_string_to_utf8(img.string(pdo.name_index)), name_of(t["name"]));
      EXPECT_EQ(pdo.flags, num(t["flags"]));
      EXPECT_EQ(pdo.bit_length(), num(t["bit_len_total"]));
      ASSERT_EQ(pdo.entries.size(), t["entries"].size());
      for (std::size_t e = 0; e < pdo.entries.size(); ++e) {
        const auto& entry = pdo.entries[e];
        const auto& te = t["entries"][e];
        EXPECT_EQ(entry.index, num(te["index"]));
        EXPECT_EQ(entry.subindex, num(te["subindex"]));
        EXPECT_EQ(entry.name_index, num(te["name_idx"]));
        EXPECT_EQ(sii_string_to_utf8(img.string(entry.name_index)), name_of(te["name"]));
        EXPECT_EQ(entry.data_type, num(te["data_type"]));
        EXPECT_EQ(entry.bit_length, num(te["bit_len"]));
        EXPECT_EQ(entry.flags, num(te["flags"]));
        EXPECT_EQ(entry.padding(), num(te["index"]) == 0);
      }
    }
  }

  // DC
  const auto& dcs = gt["dc"];
  ASSERT_EQ(img.dc.size(), dcs.size());
  for (std::size_t i = 0; i < dcs.size(); ++i) {
    SCOPED_TRACE("DC " + std::to_string(i));
    const auto& dc = img.dc[i];
    const auto& t = dcs[i];
    EXPECT_EQ(dc.cycle_time_0, num(t["cycle_time0"]));
    EXPECT_EQ(dc.shift_time_0, num(t["shift_time0"]));
    EXPECT_EQ(dc.shift_time_1, num(t["shift_time1"]));
    EXPECT_EQ(dc.sync1_cycle_factor, t["sync1_cycle_factor"].get<int>());
    EXPECT_EQ(dc.assign_activate, num(t["assign_activate"]));
    EXPECT_EQ(dc.sync0_cycle_factor, t["sync0_cycle_factor"].get<int>());
    EXPECT_EQ(dc.name_index, num(t["name_idx"]));
    EXPECT_EQ(sii_string_to_utf8(img.string(dc.name_index)), name_of(t["name"]));
    EXPECT_EQ(dc.description_index, num(t["desc_idx"]));
  }

  // Vendor/unknown categories are kept with their data
  std::size_t unknown = 0;
  for (const auto& c : cats)
    unknown += c["type_name"] == "vendor/unknown" ? 1 : 0;
  EXPECT_EQ(img.other_categories.size(), unknown);
}

TEST_P(SiiGroundTruth, ReencodesByteForByte) {
  const std::string name = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/" + name + ".bin");
  const auto bytes = ecat::test::read_file(image_path);
  auto decoded = decode_sii(bytes);
  ASSERT_TRUE(decoded.ok());
  auto encoded = encode_sii(decoded->image);
  ASSERT_TRUE(encoded.ok()) << encoded.error().describe();
  ASSERT_EQ(encoded->size(), bytes.size());
  const auto mismatch = std::mismatch(bytes.begin(), bytes.end(), encoded->begin());
  EXPECT_TRUE(mismatch.first == bytes.end())
      << "first difference at byte 0x" << std::hex << (mismatch.first - bytes.begin());
}

TEST_P(SiiGroundTruth, EveryTruncationDecodesOrFailsCleanly) {
  const std::string name = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/" + name + ".bin");
  const auto bytes = ecat::test::read_file(image_path);
  auto full = decode_sii(bytes);
  ASSERT_TRUE(full.ok());
  // Where the END marker sits: cuts past it lose nothing.
  const std::size_t end_byte = 2 * full->categories.back().word_address + 2;
  for (std::size_t n = 0; n <= bytes.size(); ++n) {
    SCOPED_TRACE("length " + std::to_string(n));
    auto cut = decode_sii(Bytes{bytes.data(), n});
    if (n < kSiiHeaderBytes) {
      ASSERT_FALSE(cut.ok());
      EXPECT_EQ(cut.error().code(), ecat::Errc::truncated);
      continue;
    }
    ASSERT_TRUE(cut.ok()) << cut.error().describe();
    if (n >= end_byte) {
      EXPECT_EQ(cut->image, full->image);
    } else {
      EXPECT_FALSE(cut->warnings.empty());
    }
  }
}

INSTANTIATE_TEST_SUITE_P(RealImages, SiiGroundTruth,
                         ::testing::Values("ek1100", "el2004", "el2262", "el2828"));

TEST(SiiRealImage, PartialRxPdoCategoryNamesTheCategoryAndAddress) {
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/el2262.bin");
  auto bytes = ecat::test::read_file(image_path);
  // RXPDO sits at word 0x00f7 with 160 words; cut the image in the middle of it.
  bytes.resize(2 * (0x00f7 + 2) + 104);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(any_warning_contains(*d, "category RXPDO (type 51) at word 0x00f7"));
  EXPECT_TRUE(any_warning_contains(*d, "declares 160 words"));
  // 104 bytes hold six whole PDOs of 16 bytes; the seventh header fits without its entry.
  EXPECT_EQ(d->image.rxpdos.size(), 7u);
  EXPECT_TRUE(d->image.rxpdos.back().entries.empty());
  EXPECT_TRUE(d->categories.back().truncated);
  EXPECT_TRUE(d->image.dc.empty());
}

// ---------------------------------------------------------------------------------------------
// Synthetic images

TEST(SiiCodec, FullImageRoundTrips) {
  const SiiImage img = full_image();
  const auto bytes = encode_or_die(img);
  EXPECT_EQ(bytes.size(), 4096u);  // padded to the declared 4 KiB
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok()) << d.error().describe();
  EXPECT_TRUE(d->warnings.empty()) << d->warnings.front();
  EXPECT_TRUE(d->checksum_ok);
  EXPECT_EQ(d->image, img);
  EXPECT_EQ(sii_string_to_utf8(d->image.device_name()), "Drive 1 \xC2\xB5s");
  EXPECT_EQ(d->image.txpdos[0].bit_length(), 48u);
}

TEST(SiiCodec, HeaderWordsLandAtTheirAddresses) {
  const auto bytes = encode_or_die(full_image());
  const auto word = [&](std::size_t w) { return load_le16(&bytes[2 * w]); };
  EXPECT_EQ(word(0x00), 0x0C80);
  EXPECT_EQ(word(0x04), 0x1234);
  EXPECT_EQ(word(0x08), 0xABCD);
  EXPECT_EQ(word(0x09), 0x0000);
  EXPECT_EQ(load_le32(&bytes[2 * 0x0A]), 0x12345678u);
  EXPECT_EQ(load_le32(&bytes[2 * 0x0C]), 0x00020001u);
  EXPECT_EQ(load_le32(&bytes[2 * 0x0E]), 0xDEADBEEFu);
  EXPECT_EQ(word(0x10), 5);
  EXPECT_EQ(word(0x13), 0x0102);
  EXPECT_EQ(word(0x14), 0x1000);
  EXPECT_EQ(word(0x15), 0x0200);
  EXPECT_EQ(word(0x18), 0x1000);
  EXPECT_EQ(word(0x19), 0x0080);
  EXPECT_EQ(word(0x1A), 0x1080);
  EXPECT_EQ(word(0x1B), 0x0080);
  EXPECT_EQ(word(0x1C), 0x000E);
  EXPECT_EQ(word(0x20), 0xA5A5);
  EXPECT_EQ(word(0x3E), 31);
  EXPECT_EQ(word(0x3F), 1);
  // First category: the vendor type 1 (ascending type order), then STRINGS.
  EXPECT_EQ(word(0x40), 1);
  EXPECT_EQ(word(0x41), 1);
  EXPECT_EQ(word(0x42), 0xBBAA);
  EXPECT_EQ(word(0x43), sii_category::kStrings);
}

TEST(SiiCodec, CategoryOrderIsAscendingType) {
  auto d = decode_sii(encode_or_die(full_image()));
  ASSERT_TRUE(d.ok());
  std::vector<std::uint16_t> types;
  for (const auto& c : d->categories)
    types.push_back(c.type);
  EXPECT_EQ(types, (std::vector<std::uint16_t>{1, 10, 20, 30, 40, 41, 42, 43, 50, 51, 60, 0x0800,
                                               0xFFFF}));
}

TEST(SiiCodec, MinimalImageHasOnlyTheEndMarker) {
  SiiImage img;
  const auto bytes = encode_or_die(img, {.pad_to_eeprom_size = false});
  ASSERT_EQ(bytes.size(), kSiiHeaderBytes + 2);
  EXPECT_EQ(load_le16(&bytes[kSiiHeaderBytes]), 0xFFFF);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->image, img);
  ASSERT_EQ(d->categories.size(), 1u);
  EXPECT_EQ(d->categories[0].type, sii_category::kEnd);
  EXPECT_EQ(d->categories[0].word_address, 0x40u);
  EXPECT_FALSE(d->image.general.has_value());
  EXPECT_EQ(d->image.device_name(), "");
}

TEST(SiiCodec, OddFmmuCountIsPaddedWithUnused) {
  SiiImage img;
  img.fmmus = {1, 2, 3};
  auto d = decode_sii(encode_or_die(img));
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->image.fmmus, (std::vector<std::uint8_t>{1, 2, 3, 0xFF}));
}

TEST(SiiCodec, StringIndexResolution) {
  SiiImage img;
  img.strings = {"a", "b"};
  EXPECT_EQ(img.string(0), "");
  EXPECT_EQ(img.string(1), "a");
  EXPECT_EQ(img.string(2), "b");
  EXPECT_EQ(img.string(3), "");
  EXPECT_EQ(img.device_name(), "a");
}

TEST(SiiCodec, UnrepresentableImagesAreErrors) {
  {
    SiiImage img;
    img.strings.assign(256, "x");
    auto r = encode_sii(img);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code(), ecat::Errc::out_of_range);
    EXPECT_THAT(r.error().message(), HasSubstr("256"));
  }
  {
    SiiImage img;
    img.strings = {"ok", std::string(256, 'y')};
    auto r = encode_sii(img);
    ASSERT_FALSE(r.ok());
    EXPECT_THAT(r.error().message(), HasSubstr("string 2 is 256 bytes"));
  }
  {
    SiiImage img;
    SiiPdo pdo;
    pdo.index = 0x1A07;
    pdo.entries.resize(256);
    img.txpdos = {pdo};
    auto r = encode_sii(img);
    ASSERT_FALSE(r.ok());
    EXPECT_THAT(r.error().message(), HasSubstr("TxPDO 0x1a07 has 256 entries"));
  }
  for (std::uint16_t type :
       {std::uint16_t{0}, std::uint16_t{10}, std::uint16_t{51}, std::uint16_t{0xFFFF}}) {
    SiiImage img;
    img.other_categories = {{type, {1, 2}}};
    auto r = encode_sii(img);
    ASSERT_FALSE(r.ok()) << type;
    EXPECT_EQ(r.error().code(), ecat::Errc::invalid_argument);
  }
  {
    SiiImage img;
    img.other_categories = {{0x0800, std::vector<std::uint8_t>(2 * 0x10000, 0)}};
    auto r = encode_sii(img);
    ASSERT_FALSE(r.ok());
    EXPECT_THAT(r.error().message(), HasSubstr("65536 words"));
  }
}

// ---------------------------------------------------------------------------------------------
// Corrupt, truncated, blank and oversized images

TEST(SiiDecode, TooShortForTheHeaderIsAnError) {
  for (std::size_t n : {0u, 1u, 14u, 127u}) {
    std::vector<std::uint8_t> bytes(n, 0x11);
    auto d = decode_sii(bytes);
    ASSERT_FALSE(d.ok()) << n;
    EXPECT_EQ(d.error().code(), ecat::Errc::truncated);
    EXPECT_THAT(d.error().message(), HasSubstr(std::to_string(n) + " bytes"));
    EXPECT_THAT(d.error().message(), HasSubstr("128"));
  }
}

TEST(SiiDecode, BlankImagesAreErrors) {
  for (std::uint8_t fill : {std::uint8_t{0xFF}, std::uint8_t{0x00}}) {
    std::vector<std::uint8_t> bytes(2048, fill);
    auto d = decode_sii(bytes);
    ASSERT_FALSE(d.ok());
    EXPECT_EQ(d.error().code(), ecat::Errc::malformed);
    EXPECT_THAT(d.error().message(), HasSubstr("blank"));
    EXPECT_THAT(d.error().message(), HasSubstr(fill == 0xFF ? "0xff" : "0x00"));
  }
}

TEST(SiiDecode, BadChecksumIsAWarningAndFlagged) {
  auto bytes = encode_or_die(full_image());
  bytes[0] ^= 0x01;  // PDI control low byte
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_FALSE(d->checksum_ok);
  EXPECT_EQ(d->checksum_computed, sii_crc8(Bytes{bytes.data(), 14}));
  EXPECT_NE(d->checksum_word & 0xFF, d->checksum_computed);
  ASSERT_EQ(d->warnings.size(), 1u);
  EXPECT_THAT(d->warnings[0], HasSubstr("checksum mismatch"));
  EXPECT_EQ(d->image.pdi_control, 0x0C81);
  EXPECT_EQ(d->image.identity, full_image().identity);  // the rest still decodes
}

TEST(SiiDecode, OversizedImagesAreFine) {
  auto bytes = encode_or_die(full_image());
  bytes.resize(bytes.size() + 65536, 0xFF);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(d->warnings.empty());
  EXPECT_EQ(d->image, full_image());
}

TEST(SiiDecode, OddLengthIsAWarning) {
  auto bytes = encode_or_die(full_image());
  bytes.push_back(0x00);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(any_warning_contains(*d, "odd length"));
  EXPECT_EQ(d->image, full_image());
}

TEST(SiiDecode, MissingEndMarkerIsAWarning) {
  auto bytes = encode_or_die(full_image(), {.pad_to_eeprom_size = false});
  bytes.resize(bytes.size() - 2);  // drop the END marker
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(any_warning_contains(*d, "without an END marker"));
  EXPECT_EQ(d->image, full_image());
  EXPECT_NE(d->categories.back().type, sii_category::kEnd);
}

TEST(SiiDecode, CategoryPastTheEndIsDecodedPartially) {
  SiiImage img;
  img.sync_managers = {{0x1000, 1, 0x64, 0, 1, 3}, {0x1100, 2, 0x20, 0, 1, 4}};
  auto bytes = encode_or_die(img, {.pad_to_eeprom_size = false});
  // Keep the category header and one and a half entries.
  bytes.resize(kSiiHeaderBytes + 4 + 12);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->image.sync_managers.size(), 1u);
  EXPECT_EQ(d->image.sync_managers[0], img.sync_managers[0]);
  EXPECT_TRUE(any_warning_contains(*d,
                                   "category SYNCM (type 41) at word 0x0040: declares 8 "
                                   "words but the image ends after 6"));
  EXPECT_TRUE(any_warning_contains(*d, "4 trailing bytes"));
  ASSERT_EQ(d->categories.size(), 1u);
  EXPECT_TRUE(d->categories[0].truncated);
  EXPECT_EQ(d->categories[0].size_words, 8u);
}

TEST(SiiDecode, PdoEntriesPastTheirCategoryAreDecodedPartially) {
  SiiImage img;
  SiiPdo pdo;
  pdo.index = 0x1A00;
  pdo.entries = {{0x6000, 1, 0, 1, 1, 0}, {0x6000, 2, 0, 1, 1, 0}};
  img.txpdos = {pdo};
  auto bytes = encode_or_die(img, {.pad_to_eeprom_size = false});
  // The PDO header's entry count is byte 2 of the category data.
  bytes[kSiiHeaderBytes + 4 + 2] = 5;
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->image.txpdos.size(), 1u);
  EXPECT_EQ(d->image.txpdos[0].entries, pdo.entries);
  EXPECT_TRUE(any_warning_contains(
      *d,
      "category TXPDO (type 50) at word 0x0040: PDO 0x1a00 (byte offset 0) declares 5 "
      "entries but the category ends after 2"));
  EXPECT_EQ(d->categories.back().type, sii_category::kEnd);  // the walk went on
}

TEST(SiiDecode, StringsPastTheirCategoryAreDecodedPartially) {
  SiiImage img;
  img.strings = {"abc", "defgh"};
  auto bytes = encode_or_die(img, {.pad_to_eeprom_size = false});
  bytes[kSiiHeaderBytes + 4] = 4;  // claim four strings
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->image.strings, img.strings);
  EXPECT_TRUE(any_warning_contains(*d, "declares 4 strings but string 3"));
}

TEST(SiiDecode, DanglingStringIndicesAreWarnings) {
  SiiImage img;
  img.strings = {"only"};
  SiiGeneral g;
  g.name_index = 9;
  img.general = g;
  SiiPdo pdo;
  pdo.index = 0x1600;
  pdo.name_index = 2;
  img.rxpdos = {pdo};
  auto d = decode_sii(encode_or_die(img));
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(any_warning_contains(*d, "GENERAL name refers to string 9, but the image has 1"));
  EXPECT_TRUE(any_warning_contains(*d, "RxPDO 0x1600 name refers to string 2"));
  EXPECT_EQ(d->image.device_name(), "only");
}

TEST(SiiDecode, ShortGeneralReadsMissingFieldsAsZero) {
  SiiImage img;
  SiiGeneral g;
  g.group_index = 1;
  g.current_on_ebus_ma = 100;
  g.physical_port = 0x33;
  img.general = g;
  auto bytes = encode_or_die(img, {.pad_to_eeprom_size = false});
  // Shrink the category to 7 words: physical port (bytes 16..17) is lost.
  bytes[kSiiHeaderBytes + 2] = 7;
  bytes.erase(bytes.begin() + kSiiHeaderBytes + 4 + 14, bytes.end() - 2);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  ASSERT_TRUE(d->image.general.has_value());
  EXPECT_EQ(d->image.general->group_index, 1);
  EXPECT_EQ(d->image.general->current_on_ebus_ma, 100);
  EXPECT_EQ(d->image.general->physical_port, 0);
  EXPECT_TRUE(any_warning_contains(*d, "14 bytes, expected 32"));
}

TEST(SiiDecode, DuplicateCategoriesAreMerged) {
  SiiImage a;
  a.sync_managers = {{0x1000, 1, 0x64, 0, 1, 3}};
  a.other_categories = {{0x0800, {9, 9}}};
  auto bytes = encode_or_die(a, {.pad_to_eeprom_size = false});
  // Append a second SYNCM category in place of the END marker.
  bytes.resize(bytes.size() - 2);
  const std::uint8_t second[] = {41, 0, 4, 0, 0x00, 0x11, 2, 0, 0x20, 0, 1, 4, 0xFF, 0xFF};
  bytes.insert(bytes.end(), std::begin(second), std::end(second));
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  ASSERT_EQ(d->image.sync_managers.size(), 2u);
  EXPECT_EQ(d->image.sync_managers[1].start, 0x1100);
  EXPECT_EQ(d->image.sync_managers[1].type, sii_sm_type::kInputs);
}

TEST(SiiDecode, EndlessZeroSizeCategoriesTerminate) {
  // Every category header says "type 0x0800, 0 words": the walk must still end at the image end.
  std::vector<std::uint8_t> bytes = encode_or_die(SiiImage{}, {.pad_to_eeprom_size = false});
  bytes.resize(kSiiHeaderBytes);
  for (int i = 0; i < 1000; ++i) {
    for (std::uint8_t b : {0x00, 0x08, 0x00, 0x00})
      bytes.push_back(b);
  }
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->image.other_categories.size(), 1000u);
  EXPECT_TRUE(any_warning_contains(*d, "without an END marker"));
}

TEST(SiiDecode, NopCategoriesAreSkipped) {
  std::vector<std::uint8_t> bytes = encode_or_die(SiiImage{}, {.pad_to_eeprom_size = false});
  bytes.resize(kSiiHeaderBytes);
  const std::uint8_t tail[] = {0, 0, 1, 0, 0xAB, 0xCD, 0xFF, 0xFF};
  bytes.insert(bytes.end(), std::begin(tail), std::end(tail));
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(d->image.other_categories.empty());
  EXPECT_TRUE(any_warning_contains(*d, "1 NOP categories skipped"));
  ASSERT_EQ(d->categories.size(), 1u);
  EXPECT_EQ(d->categories[0].word_address, 0x43u);
}

TEST(SiiDecode, SizeWordCutOffIsAWarning) {
  auto bytes = encode_or_die(SiiImage{}, {.pad_to_eeprom_size = false});
  bytes.resize(kSiiHeaderBytes);
  bytes.push_back(41);
  bytes.push_back(0);
  auto d = decode_sii(bytes);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(any_warning_contains(*d, "ends before the category's size word"));
}

// Random corruption: decoding never fails on a header-sized image that is not blank, and what
// decodes re-encodes to an image that decodes to the same content.
TEST(SiiDecode, RandomCorruptionIsStable) {
  const auto base = encode_or_die(full_image(), {.pad_to_eeprom_size = false});
  std::mt19937 rng(12345);
  for (int round = 0; round < 3000; ++round) {
    auto bytes = base;
    const int flips = 1 + static_cast<int>(rng() % 8);
    for (int i = 0; i < flips; ++i)
      bytes[rng() % bytes.size()] = static_cast<std::uint8_t>(rng());
    if (rng() % 4 == 0) bytes.resize(kSiiHeaderBytes + rng() % (bytes.size() - kSiiHeaderBytes));
    auto first = decode_sii(bytes);
    ASSERT_TRUE(first.ok()) << first.error().describe();
    auto again = encode_sii(first->image, {.pad_to_eeprom_size = false});
    if (!again.ok()) continue;
    auto second = decode_sii(*again);
    ASSERT_TRUE(second.ok()) << second.error().describe();
    ASSERT_EQ(second->image, first->image) << "round " << round;
    EXPECT_TRUE(second->checksum_ok);
  }
}

}  // namespace
