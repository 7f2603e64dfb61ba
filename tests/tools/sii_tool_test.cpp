// `ecat sii`: runs the built tool (env ECAT_TOOL) on images the test encodes, on corrupt images it
// writes, and on the shared real EEPROM images (compared with their ground truth).
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/wire/sii.hpp>

#include "support/shared_data.hpp"
#include "support/tool_runner.hpp"

namespace {

namespace fs = std::filesystem;
using ecat::wire::SiiImage;
using nlohmann::json;
using ::testing::HasSubstr;

// Inside the category list of every shared image (before its END marker).
constexpr std::size_t kTruncatedLength = 224;

std::uint64_t num(const json& j) {
  if (j.is_string()) return std::stoull(j.get<std::string>(), nullptr, 16);
  return j.get<std::uint64_t>();
}

SiiImage drive_image() {
  SiiImage img;
  img.identity = {0x0000ABCD, 0x12345678, 0x00020001, 42};
  img.standard_mailbox = {0x1000, 128, 0x1080, 128};
  img.bootstrap_mailbox = {0x1000, 512, 0x1200, 512};
  img.mailbox_protocols = ecat::wire::mailbox_protocol::kCoe | ecat::wire::mailbox_protocol::kFoe;
  img.strings = {"Drive",   "Servo 1\xB5m", "Status", "Statusword",
                 "Control", "Controlword",  "DcSync"};
  ecat::wire::SiiGeneral g;
  g.group_index = 1;
  g.order_index = 1;
  g.name_index = 2;
  g.coe_details = 0x23;
  g.current_on_ebus_ma = -300;
  g.physical_port = 0x0011;
  img.general = g;
  img.fmmus = {1, 2, 3, 0xFF};
  img.sync_managers = {{0x1000, 128, 0x26, 0, 1, 1},
                       {0x1080, 128, 0x22, 0, 1, 2},
                       {0x1100, 2, 0x64, 0, 1, 3},
                       {0x1180, 2, 0x20, 0, 1, 4}};
  ecat::wire::SiiPdo tx;
  tx.index = 0x1A00;
  tx.sync_manager = 3;
  tx.name_index = 3;
  tx.entries = {{0x6041, 0, 4, 0x06, 16, 0}};
  ecat::wire::SiiPdo rx;
  rx.index = 0x1600;
  rx.sync_manager = 2;
  rx.name_index = 5;
  rx.entries = {{0x6040, 0, 6, 0x06, 16, 0}};
  img.txpdos = {tx};
  img.rxpdos = {rx};
  ecat::wire::SiiDcSync dc;
  dc.assign_activate = 0x0300;
  dc.cycle_time_0 = 1000000;
  dc.shift_time_0 = 5000;
  dc.sync0_cycle_factor = 1;
  dc.sync1_cycle_factor = -2;
  dc.name_index = 7;
  img.dc = {dc};
  return img;
}

class SiiTool : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(ecat::test::tool_path()))
        << "ecat tool not found at " << ecat::test::tool_path() << " (set ECAT_TOOL)";
    tool_ = std::make_unique<ecat::test::ToolRunner>("sii-test");
    dir_ = tool_->dir();
  }
  ecat::test::ToolRun run_tool(const std::string& arguments) const {
    return tool_->run("sii " + arguments);
  }

  json run_json(const fs::path& file, int expected_status = 0) const {
    const auto r = run_tool("'" + file.string() + "' --json");
    EXPECT_EQ(r.status, expected_status) << r.err;
    EXPECT_TRUE(json::accept(r.out)) << r.out;
    return json::accept(r.out) ? json::parse(r.out) : json();
  }

  fs::path write(const std::string& name, const std::vector<std::uint8_t>& bytes) const {
    const auto path = dir_ / name;
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char*>(bytes.data()),
               static_cast<std::streamsize>(bytes.size()));
    return path;
  }

  std::unique_ptr<ecat::test::ToolRunner> tool_;
  fs::path dir_;
};

TEST_F(SiiTool, JsonOfAnEncodedImage) {
  auto bytes = ecat::wire::encode_sii(drive_image());
  ASSERT_TRUE(bytes.ok());
  const json j = run_json(write("drive.bin", *bytes));
  ASSERT_TRUE(j.is_object());
  EXPECT_EQ(j["identity"]["vendor_id"], 0xABCD);
  EXPECT_EQ(j["identity"]["product_code"], 0x12345678);
  EXPECT_EQ(j["identity"]["revision"], 0x00020001);
  EXPECT_EQ(j["identity"]["serial"], 42);
  EXPECT_EQ(j["standard_mailbox"], json({{"recv_offset", 0x1000},
                                         {"recv_size", 128},
                                         {"send_offset", 0x1080},
                                         {"send_size", 128}}));
  EXPECT_EQ(j["bootstrap_mailbox"]["recv_size"], 512);
  EXPECT_EQ(j["bootstrap_mailbox"]["send_offset"], 0x1200);
  EXPECT_EQ(j["mailbox_protocols"], json({"CoE", "FoE"}));
  EXPECT_EQ(j["strings"].size(), 7u);
  EXPECT_EQ(j["strings"][1], "Servo 1\xC2\xB5m");  // Latin-1 becomes UTF-8
  EXPECT_EQ(j["device_name"], "Servo 1\xC2\xB5m");
  EXPECT_EQ(j["general"]["current_on_ebus_ma"], -300);
  EXPECT_EQ(j["general"]["coe_details"], 0x23);
  EXPECT_EQ(j["general"]["ports"], json({"MII", "MII", "unused", "unused"}));
  EXPECT_EQ(j["general"]["name"], "Servo 1\xC2\xB5m");
  EXPECT_EQ(j["fmmus"], json({"outputs", "inputs", "mailbox_state", "unused"}));
  ASSERT_EQ(j["sync_managers"].size(), 4u);
  EXPECT_EQ(j["sync_managers"][0]["start"], 0x1000);
  EXPECT_EQ(j["sync_managers"][0]["length"], 128);
  EXPECT_EQ(j["sync_managers"][0]["control"], 0x26);
  EXPECT_EQ(j["sync_managers"][0]["enable"], 1);
  EXPECT_EQ(j["sync_managers"][0]["type"], 1);
  EXPECT_EQ(j["sync_managers"][2]["control"], 0x64);
  EXPECT_EQ(j["sync_managers"][3]["type_name"], "inputs");
  ASSERT_EQ(j["txpdos"].size(), 1u);
  EXPECT_EQ(j["txpdos"][0]["index"], 0x1A00);
  EXPECT_EQ(j["txpdos"][0]["sm"], 3);
  EXPECT_EQ(j["txpdos"][0]["name"], "Status");
  ASSERT_EQ(j["txpdos"][0]["entries"].size(), 1u);
  EXPECT_EQ(j["txpdos"][0]["entries"][0]["index"], 0x6041);
  EXPECT_EQ(j["txpdos"][0]["entries"][0]["subindex"], 0);
  EXPECT_EQ(j["txpdos"][0]["entries"][0]["bit_length"], 16);
  EXPECT_EQ(j["txpdos"][0]["entries"][0]["name"], "Statusword");
  EXPECT_EQ(j["txpdos"][0]["entries"][0]["data_type"], 6);
  EXPECT_EQ(j["rxpdos"][0]["entries"][0]["name"], "Controlword");
  ASSERT_EQ(j["dc"].size(), 1u);
  EXPECT_EQ(j["dc"][0]["name"], "DcSync");
  EXPECT_EQ(j["dc"][0]["assign_activate"], 0x0300);
  EXPECT_EQ(j["dc"][0]["cycle_time_0"], 1000000);
  EXPECT_EQ(j["dc"][0]["shift_time_0"], 5000);
  EXPECT_EQ(j["dc"][0]["shift_time_1"], 0);
  EXPECT_EQ(j["dc"][0]["sync0_cycle_factor"], 1);
  EXPECT_EQ(j["dc"][0]["sync1_cycle_factor"], -2);
  EXPECT_EQ(j["checksum_ok"], true);
  EXPECT_EQ(j["warnings"], json::array());
}

TEST_F(SiiTool, TextDump) {
  auto bytes = ecat::wire::encode_sii(drive_image());
  ASSERT_TRUE(bytes.ok());
  const auto r = run_tool("'" + write("drive.bin", *bytes).string() + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("device: Servo 1\xC2\xB5m"));
  EXPECT_THAT(r.out, HasSubstr("vendor 0x0000abcd, product 0x12345678"));
  EXPECT_THAT(r.out, HasSubstr("standard mailbox: receive 0x1000 (128 bytes), send 0x1080"));
  EXPECT_THAT(r.out, HasSubstr("mailbox protocols: CoE FoE"));
  EXPECT_THAT(r.out, HasSubstr("SM2 start 0x1100 length 2 control 0x64"));
  EXPECT_THAT(r.out, HasSubstr("0x6041:00 16 bits UNSIGNED16"));
  EXPECT_THAT(r.out, HasSubstr("checksum 0x"));
  EXPECT_THAT(r.out, HasSubstr("(ok)"));
}

TEST_F(SiiTool, BadChecksumAndTruncationAreWarnings) {
  auto bytes = ecat::wire::encode_sii(drive_image());
  ASSERT_TRUE(bytes.ok());
  auto corrupt = *bytes;
  corrupt[2] ^= 0xFF;
  json j = run_json(write("checksum.bin", corrupt));
  EXPECT_EQ(j["checksum_ok"], false);
  ASSERT_EQ(j["warnings"].size(), 1u);
  EXPECT_THAT(j["warnings"][0].get<std::string>(), HasSubstr("checksum mismatch"));

  auto truncated = *bytes;
  truncated.resize(200);
  j = run_json(write("truncated.bin", truncated));
  EXPECT_FALSE(j["warnings"].empty());
  EXPECT_EQ(j["identity"]["product_code"], 0x12345678);  // the header still decodes
  const auto text = run_tool("'" + (dir_ / "truncated.bin").string() + "'");
  EXPECT_EQ(text.status, 0);
  EXPECT_THAT(text.out, HasSubstr("warnings:"));
}

TEST_F(SiiTool, UndecodableImagesExitOne) {
  const auto blank = write("blank.bin", std::vector<std::uint8_t>(2048, 0xFF));
  auto r = run_tool("'" + blank.string() + "' --json");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("blank"));
  EXPECT_TRUE(r.out.empty());

  const auto tiny = write("tiny.bin", std::vector<std::uint8_t>(10, 0x12));
  r = run_tool("'" + tiny.string() + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("10 bytes"));

  const auto empty = write("empty.bin", {});
  r = run_tool("'" + empty.string() + "'");
  EXPECT_EQ(r.status, 1);
}

TEST_F(SiiTool, UnreadableFileExitsTwo) {
  auto r = run_tool("'" + (dir_ / "does-not-exist.bin").string() + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("does-not-exist.bin"));
  r = run_tool("'" + dir_.string() + "'");  // a directory
  EXPECT_EQ(r.status, 2);
  EXPECT_FALSE(r.err.empty());
}

class SiiToolRealImages : public SiiTool, public ::testing::WithParamInterface<std::string> {};

TEST_P(SiiToolRealImages, MatchesGroundTruth) {
  const std::string name = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/" + name + ".bin");
  ECAT_SHARED_DATA_OR_SKIP(truth_path, "ground_truth/" + name + ".json");
  std::ifstream truth_file(truth_path);
  const json gt = json::parse(truth_file);
  const json j = run_json(image_path);
  ASSERT_TRUE(j.is_object());

  EXPECT_EQ(j["identity"]["vendor_id"], num(gt["identity"]["vendor_id_int"]));
  EXPECT_EQ(j["identity"]["product_code"], num(gt["identity"]["product_code_int"]));
  EXPECT_EQ(j["identity"]["revision"], num(gt["identity"]["revision_int"]));
  EXPECT_EQ(j["identity"]["serial"], num(gt["identity"]["serial_int"]));
  EXPECT_EQ(j["standard_mailbox"]["recv_size"], num(gt["standard_mailbox"]["receive_size"]));
  EXPECT_EQ(j["standard_mailbox"]["send_size"], num(gt["standard_mailbox"]["send_size"]));
  EXPECT_EQ(j["checksum_ok"], gt["header"]["checksum_ok"]);
  EXPECT_EQ(j["warnings"], json::array());
  EXPECT_EQ(j["device_name"], gt["device_name"]);

  ASSERT_EQ(j["strings"].size(), gt["strings"].size());
  for (std::size_t i = 0; i < gt["strings"].size(); ++i) {
    EXPECT_EQ(j["strings"][i], gt["strings"][i]["text_latin1"]);
  }
  EXPECT_EQ(j["general"]["current_on_ebus_ma"], gt["general"]["current_on_ebus_mA"]);
  EXPECT_EQ(j["general"]["ports"], gt["general"]["ports"]);

  ASSERT_EQ(j["fmmus"].size(), gt["fmmu"].size());
  for (std::size_t i = 0; i < gt["fmmu"].size(); ++i) {
    EXPECT_EQ(j["fmmus"][i], gt["fmmu"][i]["usage"]);
  }
  ASSERT_EQ(j["sync_managers"].size(), gt["sync_managers"].size());
  for (std::size_t i = 0; i < gt["sync_managers"].size(); ++i) {
    const auto& t = gt["sync_managers"][i];
    EXPECT_EQ(j["sync_managers"][i]["start"], num(t["start"]));
    EXPECT_EQ(j["sync_managers"][i]["length"], num(t["length"]));
    EXPECT_EQ(j["sync_managers"][i]["control"], num(t["control"]));
    EXPECT_EQ(j["sync_managers"][i]["enable"], num(t["enable"]));
    EXPECT_EQ(j["sync_managers"][i]["type"], num(t["type"]));
  }
  for (const auto& [ours, theirs] : {std::pair{"txpdos", "txpdo"}, std::pair{"rxpdos", "rxpdo"}}) {
    ASSERT_EQ(j[ours].size(), gt[theirs].size()) << ours;
    for (std::size_t p = 0; p < gt[theirs].size(); ++p) {
      const auto& pdo = j[ours][p];
      const auto& t = gt[theirs][p];
      EXPECT_EQ(pdo["index"], num(t["index"]));
      EXPECT_EQ(pdo["sm"], num(t["sm"]));
      EXPECT_EQ(pdo["name"], t["name"].is_null() ? json("") : t["name"]);
      ASSERT_EQ(pdo["entries"].size(), t["entries"].size());
      for (std::size_t e = 0; e < t["entries"].size(); ++e) {
        const auto& te = t["entries"][e];
        EXPECT_EQ(pdo["entries"][e]["index"], num(te["index"]));
        EXPECT_EQ(pdo["entries"][e]["subindex"], num(te["subindex"]));
        EXPECT_EQ(pdo["entries"][e]["bit_length"], num(te["bit_len"]));
        EXPECT_EQ(pdo["entries"][e]["data_type"], num(te["data_type"]));
        EXPECT_EQ(pdo["entries"][e]["name"], te["name"].is_null() ? json("") : te["name"]);
      }
    }
  }
  ASSERT_EQ(j["dc"].size(), gt["dc"].size());
  for (std::size_t i = 0; i < gt["dc"].size(); ++i) {
    const auto& t = gt["dc"][i];
    EXPECT_EQ(j["dc"][i]["name"], t["name"]);
    EXPECT_EQ(j["dc"][i]["assign_activate"], num(t["assign_activate"]));
    EXPECT_EQ(j["dc"][i]["cycle_time_0"], num(t["cycle_time0"]));
    EXPECT_EQ(j["dc"][i]["shift_time_0"], num(t["shift_time0"]));
    EXPECT_EQ(j["dc"][i]["shift_time_1"], num(t["shift_time1"]));
    EXPECT_EQ(j["dc"][i]["sync0_cycle_factor"], t["sync0_cycle_factor"]);
    EXPECT_EQ(j["dc"][i]["sync1_cycle_factor"], t["sync1_cycle_factor"]);
  }
}

TEST_P(SiiToolRealImages, TruncatedCopyGivesWarningsNotACrash) {
  const std::string name = GetParam();
  ECAT_SHARED_DATA_OR_SKIP(image_path, "eeprom/" + name + ".bin");
  auto bytes = ecat::test::read_file(image_path);
  bytes.resize(kTruncatedLength);
  const json j = run_json(write(name + "-cut.bin", bytes));
  EXPECT_FALSE(j["warnings"].empty());
  EXPECT_EQ(j["checksum_ok"], true);
}

INSTANTIATE_TEST_SUITE_P(RealImages, SiiToolRealImages,
                         ::testing::Values("ek1100", "el2004", "el2262", "el2828"));

}  // namespace
