// ENI files mapped onto a MasterConfig (import_eni, load_master_config): the configuration the
// example ENI of examples/default.yaml's ring maps to, the report of what ecat does not use, and
// the simulated ring brought to OP by a master configured from it.
#include <algorithm>
#include <fstream>
#include <functional>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/master/config.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

const std::string kExample = std::string(ECAT_SOURCE_DIR) + "/examples/default-eni.xml";
const std::string kDefaultRing = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

bool reported(const std::vector<std::string>& report, const std::string& fragment) {
  return std::any_of(report.begin(), report.end(), [&](const std::string& line) {
    return line.find(fragment) != std::string::npos;
  });
}

bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds limit = 10s) {
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < deadline) {
    if (condition()) return true;
    std::this_thread::sleep_for(5ms);
  }
  return condition();
}

std::string joined(const std::vector<std::string>& report) {
  std::string out;
  for (const auto& l : report)
    out += l + "\n";
  return out;
}

TEST(ConfigEni, TheExampleMapsToSlavesDomainsAndStartupSdos) {
  auto imported = import_eni(read_text(kExample), kExample);
  ASSERT_TRUE(imported) << imported.error().describe();
  const MasterConfig& c = imported->config;
  ASSERT_EQ(c.domains.size(), 1u);
  EXPECT_EQ(c.domains[0].id, "main");
  EXPECT_EQ(c.domains[0].period, 1ms);
  EXPECT_EQ(c.base_station, 0x1000);  // the ENI's PhysAddr 4096 + position
  ASSERT_EQ(c.slaves.size(), 5u);
  EXPECT_EQ(c.slaves[0].name, "Term_1_EK1100");
  EXPECT_EQ(c.slaves[4].name, "Drive_1_ECAT-SERVO");
  for (std::size_t i = 0; i < c.slaves.size(); ++i) {
    EXPECT_EQ(c.slaves[i].position, i) << c.slaves[i].name;
    EXPECT_FALSE(c.slaves[i].alias);
  }
  EXPECT_EQ(c.slaves[0].vendor_id, 2u);
  EXPECT_EQ(c.slaves[0].product_code, 0x044C2C52u);
  EXPECT_EQ(c.slaves[4].vendor_id, 0xACEu);
  EXPECT_EQ(c.slaves[4].product_code, 0x2402u);

  EXPECT_EQ(c.slaves[0].process_data.kind, ProcessDataRequest::Kind::none);
  for (std::size_t i = 1; i < 5; ++i) {
    EXPECT_EQ(c.slaves[i].process_data.kind, ProcessDataRequest::Kind::all);
    EXPECT_EQ(c.slaves[i].process_data.domain, "main");
  }
  // No CoE: the terminals keep their SII layout.
  EXPECT_EQ(c.slaves[1].pdo_source, SlaveConfig::PdoSource::sii);
  EXPECT_EQ(c.slaves[2].pdo_source, SlaveConfig::PdoSource::sii);
  // The EL3202: CoE, no assignment in its InitCmds: written from the ENI's lists.
  const auto& rtd = c.slaves[3];
  EXPECT_EQ(rtd.pdo_source, SlaveConfig::PdoSource::configured);
  ASSERT_TRUE(rtd.pdo_mapping);
  ASSERT_EQ(rtd.pdo_mapping->assignments.size(), 1u);
  EXPECT_EQ(rtd.pdo_mapping->assignments[0].sync_manager, 3);
  EXPECT_EQ(rtd.pdo_mapping->assignments[0].pdo_indices,
            (std::vector<std::uint16_t>{0x1A00, 0x1A01}));
  EXPECT_EQ(rtd.pdo_mapping->assignments[0].direction, PdoDirection::input);
  ASSERT_EQ(rtd.pdo_mapping->mappings.size(), 2u);
  EXPECT_EQ(rtd.pdo_mapping->mappings[0].entries.size(), 9u);
  EXPECT_EQ(rtd.pdo_mapping->mappings[0].entries[8], coe_mapping_entry(0x6000, 0x11, 16));
  EXPECT_EQ(rtd.pdo_mapping->mappings[0].entries[5], coe_mapping_entry(0, 0, 7));
  const auto value =
      std::find_if(rtd.pdo_mapping->entry_info.begin(), rtd.pdo_mapping->entry_info.end(),
                   [](const CoeEntryInfo& e) { return e.index == 0x6000 && e.subindex == 0x11; });
  ASSERT_NE(value, rtd.pdo_mapping->entry_info.end());
  EXPECT_EQ(value->data_type, coe_type::kInteger16);
  EXPECT_EQ(value->name, "Value");
  // Its PS download runs; its upload does not.
  ASSERT_EQ(rtd.startup_sdos.size(), 1u);
  EXPECT_EQ(rtd.startup_sdos[0].index, 0x8000);
  EXPECT_EQ(rtd.startup_sdos[0].subindex, 0x15);

  // The drive: its InitCmds write the assignment, so they carry it and the layout is read back.
  const auto& drive = c.slaves[4];
  EXPECT_EQ(drive.pdo_source, SlaveConfig::PdoSource::coe);
  ASSERT_EQ(drive.startup_sdos.size(), 7u);  // IP + PS, in order; not the SO one
  EXPECT_EQ(drive.startup_sdos[0],
            (SdoWrite{.index = 0x6060, .subindex = 0, .data = {0x08}, .complete_access = false}));
  EXPECT_EQ(drive.startup_sdos[2],
            (SdoWrite{.index = 0x1C12, .subindex = 1, .data = {0x00, 0x16}}));
  EXPECT_EQ(drive.startup_sdos[6], (SdoWrite{.index = 0x1C13, .subindex = 0, .data = {0x01}}));
  ASSERT_TRUE(drive.sync);
  EXPECT_EQ(drive.sync->mode, SyncMode::sync0);
  EXPECT_EQ(drive.sync->assign_activate, 0x0300);
  EXPECT_EQ(drive.sync->sync0_shift, 0ns);
  EXPECT_FALSE(c.slaves[0].sync);
  ASSERT_TRUE(c.dc);
  EXPECT_EQ(c.dc->cycle, 1ms);
}

TEST(ConfigEni, TheReportNamesWhatIsNotUsedWithElementAndSlave) {
  auto imported = import_eni(read_text(kExample), kExample);
  ASSERT_TRUE(imported) << imported.error().describe();
  const auto& r = imported->report;
  const auto all = joined(r);
  EXPECT_TRUE(reported(r, "Cyclic (line")) << all;
  EXPECT_TRUE(reported(r, "LRW 0x00010000+51")) << all;
  EXPECT_TRUE(reported(r, "ProcessImage")) << all;
  EXPECT_TRUE(reported(r, "Master/InitCmds: 1 command(s) not replayed")) << all;
  EXPECT_TRUE(reported(r, "Master/MailboxStates")) << all;
  EXPECT_TRUE(reported(r, "slave \"Term 2 (EL1809)\" (line")) << all;
  EXPECT_TRUE(reported(r, "InitCmds: 3 ESC register command(s) not replayed")) << all;
  EXPECT_TRUE(reported(r, "(the DC activation 0x0981 is taken from them)")) << all;
  EXPECT_TRUE(reported(r, "slave \"Term 3 (EL2809)\"")) << all;
  EXPECT_TRUE(reported(r, "no CoE mailbox, so its PDO assignment cannot be written")) << all;
  EXPECT_TRUE(reported(r, "0x2000:01 \"enable the brake release\" at SO: not run")) << all;
  EXPECT_TRUE(reported(r, "1 CoE InitCmd upload(s) (Ccs 2): not run")) << all;
  EXPECT_TRUE(reported(r, "RevisionNo (and SerialNo): not checked for 5 slave(s)")) << all;
}

TEST(ConfigEni, SoeEoeAliasesAndUnknownElementsAreReported) {
  const std::string xml = R"(<?xml version="1.0"?>
<EtherCATConfig>
  <Config>
    <Slave>
      <Info><Name>Axis 1</Name><Identification><Ado>#x0012</Ado><Value>7</Value></Identification>
        <VendorId>2</VendorId><ProductCode>#x13882</ProductCode></Info>
      <Mailbox>
        <Protocol>SoE</Protocol><Protocol>EoE</Protocol>
        <SoE><InitCmds><InitCmd><Transition>PS</Transition><OpCode>3</OpCode><IDN>15</IDN>
          <Data>0700</Data></InitCmd></InitCmds></SoE>
      </Mailbox>
      <Frobnicate/>
    </Slave>
    <Slave>
      <Info><Name>Axis 1</Name><VendorId>2</VendorId><ProductCode>#x13882</ProductCode></Info>
    </Slave>
    <Cyclic><CycleTime>500</CycleTime></Cyclic>
    <Cyclic><CycleTime>2000</CycleTime></Cyclic>
    <Extras/>
  </Config>
</EtherCATConfig>
)";
  auto imported = import_eni(xml, "axes.xml");
  ASSERT_TRUE(imported) << imported.error().describe();
  const auto& c = imported->config;
  ASSERT_EQ(c.slaves.size(), 2u);
  EXPECT_EQ(c.slaves[0].name, "Axis_1");
  EXPECT_EQ(c.slaves[1].name, "Axis_1_2");
  EXPECT_EQ(c.slaves[0].alias, 7);
  EXPECT_FALSE(c.slaves[0].position);
  EXPECT_EQ(c.slaves[1].position, 1);
  EXPECT_EQ(c.domains[0].period, 500us);
  const auto& r = imported->report;
  const auto all = joined(r);
  EXPECT_TRUE(reported(r, "slave \"Axis 1\" (line 4): Mailbox/SoE: 1 InitCmd(s) (S-0-0015)"))
      << all;
  EXPECT_TRUE(reported(r, "slave \"Axis 1\" (line 4): Mailbox/EoE settings not used")) << all;
  EXPECT_TRUE(reported(r, "slave \"Axis 1\" (line 4): <Frobnicate> (line 12) not recognised"))
      << all;
  EXPECT_TRUE(reported(r, "<Extras> (line 19) not recognised")) << all;
  EXPECT_TRUE(reported(r, "2 different cycle times")) << all;
}

TEST(ConfigEni, ErrorsNameTheFile) {
  auto empty = import_eni("<EtherCATConfig><Config/></EtherCATConfig>", "empty.xml");
  ASSERT_FALSE(empty);
  EXPECT_NE(empty.error().describe().find("empty.xml: the ENI describes no <Slave>"),
            std::string::npos)
      << empty.error().describe();
  auto bad = import_eni("<EtherCATConfig><Config>\n<Slave/></Config></EtherCATConfig>", "b.xml");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().describe().find("b.xml:2: <Slave>"), std::string::npos)
      << bad.error().describe();
}

TEST(ConfigEni, LoadMasterConfigTellsEniFromRingFileByContent) {
  // An ENI under a name without .xml is still an ENI.
  const auto path = std::filesystem::temp_directory_path() /
                    fmt::format("ecat-eni-{}.ring", static_cast<long>(::getpid()));
  std::filesystem::copy_file(kExample, path, std::filesystem::copy_options::overwrite_existing);
  ConfigFileInfo info;
  auto config = load_master_config(path.string(), &info);
  std::filesystem::remove(path);
  ASSERT_TRUE(config) << config.error().describe();
  EXPECT_TRUE(info.eni);
  EXPECT_FALSE(info.eni_report.empty());
  EXPECT_EQ(config->slaves.size(), 5u);

  ConfigFileInfo ring_info;
  auto ring = load_master_config(kDefaultRing, &ring_info);
  ASSERT_TRUE(ring) << ring.error().describe();
  EXPECT_FALSE(ring_info.eni);
  EXPECT_TRUE(ring_info.eni_report.empty());
  auto plain = load_master_config(kExample);  // the one-argument form takes ENIs too
  ASSERT_TRUE(plain) << plain.error().describe();
}

// ---- hot-connect groups (Slave/HotConnect) ------------------------------------------------

// A ring with a group (tool_out, tool_in) on a junction port in the middle, identified by an
// explicit device ID (IdentifyCmd reading 0x0134, 7 expected). Also an ENI seed of the fuzz
// corpus.
const std::string kHotConnectEni = std::string(ECAT_SOURCE_DIR) + "/fuzz/seeds/eni/hot-connect.xml";

// The same ring for the simulator, the group unplugged.
constexpr const char* kHotConnectRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: junction, profile: EK1122}
    - {name: tool_out, profile: EL2809, parent: junction, port: 1, device_id: 7, hot_connect: {group: tool, plugged: false}}
    - {name: tool_in, profile: EL1809}
    - {name: far_coupler, profile: EK1100, parent: junction, port: 2}
    - {name: far_in, profile: EL1809}
    - {name: far_out, profile: EL2809}
  wiring:
    - {from: tool_out.channel_1, to: tool_in.channel_1}
)";

TEST(ConfigEni, HotConnectGroupsBecomeMasterGroupsAndLeaveTheFixedSlaves) {
  auto imported = import_eni(read_text(kHotConnectEni), kHotConnectEni);
  ASSERT_TRUE(imported) << imported.error().describe();
  const MasterConfig& c = imported->config;
  ASSERT_EQ(c.slaves.size(), 7u);
  std::vector<std::string> fixed;
  for (const auto& s : c.slaves)
    fixed.push_back(s.name);
  EXPECT_EQ(fixed, (std::vector<std::string>{"coupler", "inputs", "outputs", "junction",
                                             "far_coupler", "far_in", "far_out"}));
  // The fixed slaves' positions are counted without the group (absent when the master starts).
  EXPECT_EQ(c.slaves[3].position, 3);
  EXPECT_EQ(c.slaves[4].position, 4);
  EXPECT_EQ(c.slaves[6].position, 6);
  ASSERT_EQ(c.hot_connect.size(), 1u);
  const auto& g = c.hot_connect[0];
  EXPECT_EQ(g.name, "tool");
  EXPECT_FALSE(g.alias);
  EXPECT_EQ(g.device_id, 7);
  ASSERT_EQ(g.slaves.size(), 2u);
  EXPECT_EQ(g.slaves[0].name, "tool_out");
  EXPECT_EQ(g.slaves[1].name, "tool_in");
  EXPECT_EQ(g.slaves[0].vendor_id, 2u);
  EXPECT_EQ(g.slaves[0].product_code, 0x0AF93052u);
  EXPECT_EQ(g.slaves[1].product_code, 0x07113052u);
  for (const auto& s : g.slaves) {
    EXPECT_FALSE(s.position) << s.name;
    EXPECT_EQ(s.process_data.kind, ProcessDataRequest::Kind::all) << s.name;
  }
  const auto& r = imported->report;
  EXPECT_FALSE(reported(r, "IdentifyCmd (line 17)")) << joined(r);
  EXPECT_TRUE(reported(r,
                       "HotConnect: 1 group(s) may be absent and come and go: tool (2 "
                       "slave(s), by device ID 7)"))
      << joined(r);
}

std::string with_hot_connect(std::string_view head_extra, std::string_view hot_connect) {
  // coupler, then a, b, c: `hot_connect` goes into a's <Slave>, `head_extra` into a's <Info>.
  std::string out = R"(<EtherCATConfig><Config>
<Slave><Info><Name>coupler</Name><VendorId>2</VendorId><ProductCode>1</ProductCode></Info></Slave>
<Slave><Info><Name>a</Name><VendorId>2</VendorId><ProductCode>2</ProductCode>)";
  out += head_extra;
  out += "</Info>\n";
  out += hot_connect;
  out += R"(</Slave>
<Slave><Info><Name>b</Name><VendorId>2</VendorId><ProductCode>3</ProductCode></Info></Slave>
<Slave><Info><Name>c</Name><VendorId>2</VendorId><ProductCode>4</ProductCode></Info></Slave>
</Config></EtherCATConfig>)";
  return out;
}

TEST(ConfigEni, HotConnectByAliasAndMalformedGroupsAreNamed) {
  // Identified by the station alias: IdentifyCmd at 0x0012 with the value expected.
  auto alias = import_eni(
      with_hot_connect("",
                       "<HotConnect><GroupName>Tool 1</GroupName><GroupMemberCnt>3"
                       "</GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd><Ado>#x12</Ado><Validate>"
                       "<Data>4200</Data></Validate></IdentifyCmd></HotConnect>"),
      "alias.xml");
  ASSERT_TRUE(alias) << alias.error().describe();
  ASSERT_EQ(alias->config.hot_connect.size(), 1u);
  EXPECT_EQ(alias->config.hot_connect[0].name, "Tool_1");
  EXPECT_EQ(alias->config.hot_connect[0].alias, 0x0042);
  EXPECT_EQ(alias->config.hot_connect[0].slaves.size(), 3u);
  EXPECT_EQ(alias->config.slaves.size(), 1u);
  // Or by Info/Identification's alias; no GroupName: named after its head.
  auto info = import_eni(
      with_hot_connect("<Identification><Ado>#x0012</Ado><Value>9</Value></Identification>",
                       "<HotConnect><GroupMemberCnt>1</GroupMemberCnt></HotConnect>"),
      "info.xml");
  ASSERT_TRUE(info) << info.error().describe();
  ASSERT_EQ(info->config.hot_connect.size(), 1u);
  EXPECT_EQ(info->config.hot_connect[0].name, "a");
  EXPECT_EQ(info->config.hot_connect[0].alias, 9);
  EXPECT_FALSE(info->config.hot_connect[0].slaves[0].alias);
  EXPECT_EQ(info->config.slaves.size(), 3u);
  EXPECT_EQ(info->config.slaves[1].name, "b");
  EXPECT_EQ(info->config.slaves[1].position, 1);  // 2 in the file, the group in front of it

  auto error_of = [](const std::string& xml) {
    auto r = import_eni(xml, "g.xml");
    return r ? std::string("accepted") : r.error().describe();
  };
  const auto missing = error_of(with_hot_connect("",
                                                 "<HotConnect><GroupName>t</GroupName>"
                                                 "</HotConnect>"));
  EXPECT_NE(missing.find("g.xml: slave \"a\" (line 3): HotConnect (line 4): GroupMemberCnt (how "
                         "many slaves the group has) is missing"),
            std::string::npos)
      << missing;
  const auto past = error_of(with_hot_connect("",
                                              "<HotConnect><GroupName>t</GroupName>"
                                              "<GroupMemberCnt>4</GroupMemberCnt>"
                                              "</HotConnect>"));
  EXPECT_NE(past.find("GroupMemberCnt 4: the group must hold 1..3 slaves"), std::string::npos)
      << past;
  const auto zero = error_of(with_hot_connect("",
                                              "<HotConnect><GroupName>t</GroupName>"
                                              "<GroupMemberCnt>0</GroupMemberCnt>"
                                              "</HotConnect>"));
  EXPECT_NE(zero.find("GroupMemberCnt 0"), std::string::npos) << zero;
  const auto not_number = error_of(with_hot_connect("",
                                                    "<HotConnect><GroupMemberCnt>two"
                                                    "</GroupMemberCnt></HotConnect>"));
  EXPECT_NE(not_number.find("<GroupMemberCnt>: \"two\" is not a number"), std::string::npos)
      << not_number;
  const auto no_value = error_of(with_hot_connect("",
                                                  "<HotConnect><GroupMemberCnt>1"
                                                  "</GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd>"
                                                  "<Ado>18</Ado><Validate/></IdentifyCmd>"
                                                  "</HotConnect>"));
  EXPECT_NE(no_value.find("<Validate>: <Data> (the value expected) is missing"), std::string::npos)
      << no_value;
  const auto alias_zero = error_of(with_hot_connect(
      "",
      "<HotConnect><GroupMemberCnt>1</GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd><Ado>18</Ado>"
      "<Validate><Data>0000</Data></Validate></IdentifyCmd></HotConnect>"));
  EXPECT_NE(alias_zero.find("IdentifyCmd (line 4): alias 0"), std::string::npos) << alias_zero;
  const auto id_zero = error_of(with_hot_connect(
      "",
      "<HotConnect><GroupMemberCnt>1</GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd><Ado>#x134</Ado>"
      "<Validate><Data>0000</Data></Validate></IdentifyCmd></HotConnect>"));
  EXPECT_NE(id_zero.find("IdentifyCmd (line 4): device ID 0"), std::string::npos) << id_zero;
  // An explicit device ID, the ID request itself (AL control 0x0120) passed over.
  auto by_id = import_eni(
      with_hot_connect("",
                       "<HotConnect><GroupMemberCnt>1</GroupMemberCnt><IdentifyCmd><Cmd>2</Cmd>"
                       "<Ado>#x120</Ado></IdentifyCmd><IdentifyCmd><Cmd>1</Cmd><Ado>#x134</Ado>"
                       "<Validate><Data>2a00</Data></Validate></IdentifyCmd></HotConnect>"),
      "by-id.xml");
  ASSERT_TRUE(by_id) << by_id.error().describe();
  ASSERT_EQ(by_id->config.hot_connect.size(), 1u);
  EXPECT_EQ(by_id->config.hot_connect[0].device_id, 42);
  EXPECT_FALSE(reported(by_id->report, "IdentifyCmd")) << joined(by_id->report);
  // A group whose GroupMemberCnt reaches another group's head.
  std::string nested = with_hot_connect(
      "", "<HotConnect><GroupName>t</GroupName><GroupMemberCnt>2</GroupMemberCnt></HotConnect>");
  const std::string b = "<Name>b</Name><VendorId>2</VendorId><ProductCode>3</ProductCode></Info>";
  nested.replace(nested.find(b), b.size(),
                 b + "<HotConnect><GroupName>u</GroupName><GroupMemberCnt>1</GroupMemberCnt>"
                     "</HotConnect>");
  const auto inside = error_of(nested);
  EXPECT_NE(inside.find("slave \"b\" (line 5): HotConnect (line 5): starts a group inside group "
                        "\"t\""),
            std::string::npos)
      << inside;
  // Two groups of one name.
  std::string twice = with_hot_connect(
      "", "<HotConnect><GroupName>t</GroupName><GroupMemberCnt>1</GroupMemberCnt></HotConnect>");
  twice.replace(twice.find(b), b.size(),
                b + "<HotConnect><GroupName>t</GroupName><GroupMemberCnt>1</GroupMemberCnt>"
                    "</HotConnect>");
  const auto same = error_of(twice);
  EXPECT_NE(same.find("GroupName \"t\" is used by another group"), std::string::npos) << same;
  const auto second = error_of(with_hot_connect(
      "", "<HotConnect><GroupMemberCnt>1</GroupMemberCnt></HotConnect><HotConnect/>"));
  EXPECT_NE(second.find("a second <HotConnect>"), std::string::npos) << second;
}

// The hot-connect ENI's master, started on kHotConnectRing (the group plugged from the start when
// `plugged`) and operational; its group's state once `state` (or the wait gave up).
struct HotConnectEniRing {
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<Master> master;

  explicit HotConnectEniRing(bool plugged) {
    auto imported = import_eni(read_text(kHotConnectEni), kHotConnectEni);
    EXPECT_TRUE(imported) << imported.error().describe();
    if (!imported) return;
    if (plugged) {
      // Its fixed slaves all have positions (from AutoIncAddr, counted without the group).
      for (const auto& s : imported->config.slaves)
        EXPECT_TRUE(s.position) << s.name;
    }
    imported->config.hot_connect_poll = 10ms;
    std::string yaml = kHotConnectRing;
    if (plugged) yaml.replace(yaml.find("plugged: false"), 14, "plugged: true");
    server = test::make_sim_server(yaml);
    EXPECT_TRUE(server);
    if (!server) return;
    auto link = server->serve_memory();
    EXPECT_TRUE(link);
    if (!link) return;
    master = std::make_unique<Master>(std::move(imported->config));
    EXPECT_TRUE(master->start(std::move(*link)));
    auto op = master->await_operational(20s);
    EXPECT_TRUE(op) << op.error().describe();
    if (!op) master.reset();
  }
  ~HotConnectEniRing() {
    if (master) (void)master->stop();
  }
  HotConnectEniRing(const HotConnectEniRing&) = delete;
  HotConnectEniRing& operator=(const HotConnectEniRing&) = delete;

  bool group_present() {
    return eventually([&] {
      const auto st = master->status();
      return !st.hot_connect.empty() && st.hot_connect[0].state == HotConnectState::present;
    });
  }
  std::string group_detail() const {
    const auto st = master->status();
    return st.hot_connect.empty() ? "" : st.hot_connect[0].detail;
  }
};

// The ENI's group, on a junction port in the middle of a simulated ring: absent at start, then
// plugged and brought to OP by a master configured from the ENI only.
TEST(ConfigEni, AnEniHotConnectGroupJoinsOnTheSimulatedRing) {
  HotConnectEniRing ring(false);
  ASSERT_TRUE(ring.master);
  auto& master = *ring.master;
  ASSERT_TRUE(ring.server->plug("tool", true));
  EXPECT_TRUE(ring.group_present()) << ring.group_detail();
  EXPECT_NE(ring.group_detail().find("device ID 7"), std::string::npos) << ring.group_detail();
  auto in = master.slave("tool_in");
  ASSERT_TRUE(in);
  EXPECT_EQ((*in)->state(), SlaveState::op);
  EXPECT_EQ(master.state(), MasterState::operational);
}

// The ENI's group already plugged when the master starts: its fixed slaves all have positions
// (from AutoIncAddr, counted without the group), and the group on the junction is still found
// in front of the far slaves, which are placed behind it.
TEST(ConfigEni, AnEniHotConnectGroupPluggedAtStartIsFoundOnTheJunction) {
  HotConnectEniRing ring(true);
  ASSERT_TRUE(ring.master);
  auto& master = *ring.master;
  EXPECT_TRUE(ring.group_present()) << ring.group_detail();
  auto far = master.slave("far_out");
  ASSERT_TRUE(far);
  EXPECT_EQ((*far)->info().position, 8);
  EXPECT_EQ(master.status().hot_connect[0].position, 4);
  auto in = master.slave("tool_in");
  ASSERT_TRUE(in);
  EXPECT_EQ((*in)->state(), SlaveState::op);
  EXPECT_EQ(master.state(), MasterState::operational);
}

// The simulated ring of examples/default.yaml, driven by a master configured from the ENI only.
TEST(ConfigEni, TheDefaultRingReachesOpFromItsEni) {
  auto imported = import_eni(read_text(kExample), kExample);
  ASSERT_TRUE(imported) << imported.error().describe();
  auto server = test::make_sim_server(read_text(kDefaultRing));
  ASSERT_TRUE(server);
  auto link = server->serve_memory();
  ASSERT_TRUE(link);
  Master master(std::move(imported->config));
  ASSERT_TRUE(master.start(std::move(*link)));
  auto op = master.await_operational(20s);
  ASSERT_TRUE(op) << op.error().describe();

  auto drive = master.slave("Drive_1_ECAT-SERVO");
  ASSERT_TRUE(drive) << drive.error().describe();
  const auto info = (*drive)->info();
  EXPECT_EQ(info.state, SlaveState::op);
  EXPECT_EQ(info.layout.bit_length(PdoDirection::output), 104u);
  EXPECT_EQ(info.layout.bit_length(PdoDirection::input), 120u);
  ASSERT_TRUE(info.dc_sync);
  EXPECT_EQ(info.dc_sync->assign_activate, 0x0300);
  EXPECT_EQ(info.dc_sync->source, AssignActivateSource::config);

  auto rtd = master.slave("Term_4_EL3202");
  ASSERT_TRUE(rtd) << rtd.error().describe();
  EXPECT_EQ((*rtd)->info().layout.bit_length(PdoDirection::input), 64u);

  auto domain = master.domain("main");
  ASSERT_TRUE(domain) << domain.error().describe();
  EXPECT_TRUE(eventually([&] { return (*domain)->info().stats.valid_count > 10; }));
  (void)master.stop();
}

}  // namespace
}  // namespace ecat::master
