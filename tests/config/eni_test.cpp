// The ENI reader (config/eni.hpp): the example ENI of examples/default.yaml's ring parsed element
// by element, and hostile files refused with file:line and the element.
#include <string>

#include <gtest/gtest.h>

#include <ecat/config/eni.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::config {
namespace {

const std::string kExample = std::string(ECAT_SOURCE_DIR) + "/examples/default-eni.xml";

std::string wrap_config(const std::string& body) {
  return "<?xml version=\"1.0\"?>\n<EtherCATConfig "
         "Version=\"1.3\">\n<Config>\n<Master><Info><Name>m"
         "</Name></Info></Master>\n" +
         body + "</Config>\n</EtherCATConfig>\n";
}

std::string wrap_slave(const std::string& body) {
  return wrap_config(
      "<Slave>\n<Info><Name>s</Name><VendorId>2</VendorId><ProductCode>#x10</"
      "ProductCode></Info>\n" +
      body + "</Slave>\n");
}

void expect_error(const std::string& xml, const std::string& fragment) {
  auto eni = parse_eni(xml, "bad.xml");
  ASSERT_FALSE(eni) << "expected an error containing: " << fragment;
  EXPECT_NE(eni.error().describe().find(fragment), std::string::npos) << eni.error().describe();
}

TEST(Eni, TheExampleIsReadInRingOrderWithIdentities) {
  auto eni = load_eni(kExample);
  ASSERT_TRUE(eni) << eni.error().describe();
  EXPECT_EQ(eni->version, "1.3");
  EXPECT_EQ(eni->master.name, "ecat example master");
  EXPECT_EQ(eni->master.init_cmds.size(), 1u);
  EXPECT_TRUE(eni->master.has_mailbox_states);
  ASSERT_EQ(eni->slaves.size(), 5u);
  const auto& coupler = eni->slaves[0].info;
  EXPECT_EQ(coupler.name, "Term 1 (EK1100)");
  EXPECT_EQ(coupler.phys_addr, 4096);
  EXPECT_EQ(coupler.auto_inc_addr, 0);
  EXPECT_EQ(coupler.vendor_id, 2u);
  EXPECT_EQ(coupler.product_code, 0x044C2C52u);
  EXPECT_EQ(coupler.revision_no, 0x00120000u);
  EXPECT_EQ(coupler.serial_no, 0u);
  EXPECT_FALSE(eni->slaves[0].process_data);
  EXPECT_FALSE(eni->slaves[0].mailbox);
  ASSERT_TRUE(eni->slaves[0].dc);
  EXPECT_TRUE(eni->slaves[0].dc->reference_clock);
  EXPECT_EQ(eni->slaves[0].dc->cycle_time0, 0);
  EXPECT_EQ(eni->slaves[2].info.auto_inc_addr, 0xFFFE);
  EXPECT_EQ(eni->slaves[4].info.vendor_id, 0xACEu);
  EXPECT_EQ(eni->slaves[4].info.product_code, 0x2402u);
  EXPECT_TRUE(eni->slaves[0].unrecognised.empty());
  EXPECT_TRUE(eni->unrecognised.empty());
}

TEST(Eni, ProcessDataSyncManagersAndPdos) {
  auto eni = load_eni(kExample);
  ASSERT_TRUE(eni) << eni.error().describe();
  const auto& inputs = *eni->slaves[1].process_data;
  ASSERT_TRUE(inputs.recv);
  EXPECT_EQ(inputs.recv->bit_start, 208u);
  EXPECT_EQ(inputs.recv->bit_length, 16u);
  EXPECT_FALSE(inputs.send);
  ASSERT_EQ(inputs.sync_managers.size(), 1u);
  EXPECT_EQ(inputs.sync_managers[0].index, 0);
  EXPECT_EQ(inputs.sync_managers[0].type, "Inputs");
  EXPECT_EQ(inputs.sync_managers[0].start_address, 0x1000);
  EXPECT_EQ(inputs.sync_managers[0].default_size, 2);
  EXPECT_TRUE(inputs.sync_managers[0].enable);
  ASSERT_EQ(inputs.sync_managers[0].pdos.size(), 16u);
  EXPECT_EQ(inputs.sync_managers[0].pdos[15], 0x1A0F);
  ASSERT_EQ(inputs.tx_pdos.size(), 16u);
  EXPECT_TRUE(inputs.tx_pdos[0].fixed);
  EXPECT_TRUE(inputs.tx_pdos[0].mandatory);
  EXPECT_EQ(inputs.tx_pdos[0].sync_manager, 0);
  ASSERT_EQ(inputs.tx_pdos[3].entries.size(), 1u);
  EXPECT_EQ(inputs.tx_pdos[3].entries[0].index, 0x6030);
  EXPECT_EQ(inputs.tx_pdos[3].entries[0].subindex, 1);
  EXPECT_EQ(inputs.tx_pdos[3].entries[0].bit_length, 1);
  EXPECT_EQ(inputs.tx_pdos[3].entries[0].data_type, "BOOL");
  EXPECT_EQ(inputs.tx_pdos[3].entries[0].name, "Input");

  const auto& outputs = *eni->slaves[2].process_data;
  ASSERT_EQ(outputs.sync_managers.size(), 2u);
  EXPECT_EQ(outputs.sync_managers[1].index, 1);
  EXPECT_EQ(outputs.sync_managers[1].control_byte, 0x44);
  EXPECT_EQ(outputs.rx_pdos.size(), 16u);

  const auto& rtd = *eni->slaves[3].process_data;
  ASSERT_EQ(rtd.tx_pdos.size(), 2u);
  const auto& gap = rtd.tx_pdos[0].entries[5];
  EXPECT_EQ(gap.index, 0);  // a padding entry without Index
  EXPECT_EQ(gap.bit_length, 7);
  EXPECT_EQ(rtd.tx_pdos[1].entries[8].data_type, "INT");

  const auto& drive = *eni->slaves[4].process_data;
  ASSERT_EQ(drive.rx_pdos.size(), 1u);
  EXPECT_FALSE(drive.rx_pdos[0].fixed);
  EXPECT_EQ(drive.rx_pdos[0].entries.size(), 5u);
  EXPECT_EQ(drive.rx_pdos[0].entries[1].index, 0x607A);
  EXPECT_EQ(drive.rx_pdos[0].entries[1].bit_length, 32);
}

TEST(Eni, MailboxCoeInitCmdsDcAndEscCommands) {
  auto eni = load_eni(kExample);
  ASSERT_TRUE(eni) << eni.error().describe();
  const auto& drive = eni->slaves[4];
  ASSERT_TRUE(drive.mailbox);
  EXPECT_EQ(drive.mailbox->send_start, 0x1000);
  EXPECT_EQ(drive.mailbox->recv_length, 128);
  EXPECT_EQ(drive.mailbox->protocols, (std::vector<std::string>{"CoE", "FoE"}));
  ASSERT_EQ(drive.mailbox->coe_init_cmds.size(), 8u);
  const auto& mode = drive.mailbox->coe_init_cmds[0];
  EXPECT_EQ(mode.transitions, (std::vector<std::string>{"IP"}));
  EXPECT_EQ(mode.index, 0x6060);
  EXPECT_EQ(mode.subindex, 0);
  EXPECT_EQ(mode.data, (std::vector<std::uint8_t>{0x08}));
  EXPECT_EQ(mode.comment, "modes of operation: cyclic synchronous position");
  EXPECT_TRUE(mode.fixed);
  EXPECT_FALSE(mode.complete_access);
  EXPECT_EQ(drive.mailbox->coe_init_cmds[2].data, (std::vector<std::uint8_t>{0x00, 0x16}));
  EXPECT_EQ(drive.mailbox->coe_init_cmds[7].transitions, (std::vector<std::string>{"SO"}));
  EXPECT_GT(mode.line, 0);

  ASSERT_TRUE(drive.dc);
  EXPECT_EQ(drive.dc->cycle_time0, 1'000'000);
  EXPECT_EQ(drive.dc->shift_time, 0);
  EXPECT_EQ(drive.dc->cycle_time1, 0);

  ASSERT_EQ(drive.init_cmds.size(), 4u);
  EXPECT_EQ(drive.init_cmds[0].transitions, (std::vector<std::string>{"PI", "SI", "OI"}));
  EXPECT_EQ(drive.init_cmds[3].ado, 0x0980);
  EXPECT_EQ(drive.init_cmds[3].data, (std::vector<std::uint8_t>{0x00, 0x03}));
  EXPECT_EQ(drive.init_cmds[3].cmd, 5);
  EXPECT_EQ(drive.init_cmds[3].adp, 4100);

  const auto& rtd = eni->slaves[3].mailbox->coe_init_cmds;
  ASSERT_EQ(rtd.size(), 2u);
  EXPECT_EQ(rtd[0].subindex, 0x15);
  EXPECT_EQ(rtd[1].ccs, 2);
  EXPECT_TRUE(rtd[1].data.empty());
}

TEST(Eni, CyclicFramesAndProcessImage) {
  auto eni = load_eni(kExample);
  ASSERT_TRUE(eni) << eni.error().describe();
  ASSERT_EQ(eni->cyclic.size(), 1u);
  EXPECT_EQ(eni->cyclic[0].cycle_time_us, 1000u);
  ASSERT_EQ(eni->cyclic[0].frames.size(), 1u);
  ASSERT_EQ(eni->cyclic[0].frames[0].size(), 1u);
  const auto& lrw = eni->cyclic[0].frames[0][0];
  EXPECT_EQ(lrw.cmd, 12);
  EXPECT_EQ(lrw.addr, 0x00010000u);
  EXPECT_EQ(lrw.data_length, 51u);
  EXPECT_EQ(lrw.cnt, 9);
  EXPECT_TRUE(eni->has_process_image);
}

TEST(Eni, SoeInitCmdsAndUnknownElementsAreKept) {
  auto eni = parse_eni(wrap_slave("<Mailbox><Protocol>SoE</Protocol><SoE><InitCmds><InitCmd>"
                                  "<Transition>PS</Transition><OpCode>3</OpCode><DriveNo>1</"
                                  "DriveNo><IDN>15</IDN><Data>0700</Data></InitCmd></InitCmds></"
                                  "SoE><EoE/></Mailbox>\n<Wobble/>\n"),
                       "soe.xml");
  ASSERT_TRUE(eni) << eni.error().describe();
  const auto& mb = *eni->slaves[0].mailbox;
  ASSERT_EQ(mb.soe_init_cmds.size(), 1u);
  EXPECT_EQ(mb.soe_init_cmds[0].idn, 15);
  EXPECT_EQ(mb.soe_init_cmds[0].drive_no, 1);
  EXPECT_EQ(mb.soe_init_cmds[0].data, (std::vector<std::uint8_t>{0x07, 0x00}));
  EXPECT_TRUE(mb.has_eoe);
  ASSERT_EQ(eni->slaves[0].unrecognised.size(), 1u);
  EXPECT_EQ(eni->slaves[0].unrecognised[0], "<Wobble> (line 8)");
}

TEST(Eni, HotConnectGroupNameMemberCountAndIdentifyCmds) {
  auto eni = parse_eni(wrap_slave("<HotConnect><GroupName>tool</GroupName><GroupMemberCnt>3</"
                                  "GroupMemberCnt><IdentifyCmd><Cmd>1</Cmd><Adp>0</Adp><Ado>#x12"
                                  "</Ado><DataLength>2</DataLength><Validate><Data>4200</Data>"
                                  "<DataMask>ffff</DataMask><Timeout>100</Timeout></Validate></"
                                  "IdentifyCmd>\n<IdentifyCmd><Cmd>1</Cmd><Ado>308</Ado></"
                                  "IdentifyCmd></HotConnect>\n"),
                       "hc.xml");
  ASSERT_TRUE(eni) << eni.error().describe();
  const auto& s = eni->slaves[0];
  EXPECT_TRUE(s.unrecognised.empty());
  ASSERT_TRUE(s.hot_connect);
  EXPECT_EQ(s.hot_connect->group_name, "tool");
  EXPECT_EQ(s.hot_connect->member_count, 3u);
  EXPECT_EQ(s.hot_connect->line, 7);
  ASSERT_EQ(s.hot_connect->identify.size(), 2u);
  const auto& alias = s.hot_connect->identify[0];
  EXPECT_EQ(alias.cmd, 1);
  EXPECT_EQ(alias.ado, 0x0012);
  EXPECT_EQ(alias.data_length, 2u);
  EXPECT_EQ(alias.expected, (std::vector<std::uint8_t>{0x42, 0x00}));
  EXPECT_EQ(alias.mask, (std::vector<std::uint8_t>{0xFF, 0xFF}));
  EXPECT_EQ(s.hot_connect->identify[1].ado, 0x0134);
  EXPECT_TRUE(s.hot_connect->identify[1].expected.empty());
  EXPECT_EQ(s.hot_connect->identify[1].line, 8);
  // Without a count the reader keeps what it has (the importer decides).
  auto bare =
      parse_eni(wrap_slave("<HotConnect><GroupName><Name>t</Name></GroupName>"
                           "</HotConnect>\n"));
  ASSERT_TRUE(bare) << bare.error().describe();
  EXPECT_EQ(bare->slaves[0].hot_connect->group_name, "t");
  EXPECT_FALSE(bare->slaves[0].hot_connect->member_count);
  expect_error(wrap_slave("<HotConnect><GroupMemberCnt>-1</GroupMemberCnt></HotConnect>\n"),
               "bad.xml:7: <GroupMemberCnt>: -1 is out of range");
  expect_error(wrap_slave("<HotConnect><IdentifyCmd><Ado>18</Ado></IdentifyCmd></HotConnect>\n"),
               "bad.xml:7: <IdentifyCmd>: <Cmd> is missing");
  expect_error(wrap_slave("<HotConnect><IdentifyCmd><Cmd>1</Cmd><Ado>18</Ado><Validate><Data>"
                          "4200</Data><DataMask>ff</DataMask></Validate></IdentifyCmd>"
                          "</HotConnect>\n"),
               "<Validate>: <DataMask> has 1 bytes, <Data> 2");
  expect_error(wrap_slave("<HotConnect/><HotConnect/>\n"), "a second <HotConnect>");
}

TEST(Eni, SignedAndHexadecimalForms) {
  auto eni =
      parse_eni(wrap_config("<Slave><Info><Name>s</Name><AutoIncAddr>-1</AutoIncAddr>"
                            "<VendorId>0x2</VendorId><ProductCode>-1</ProductCode>"
                            "<Identification><Ado>#x12</Ado><Value>7</Value></"
                            "Identification></Info><DC><ShiftTime>-250000</ShiftTime></"
                            "DC></Slave>\n"));
  ASSERT_TRUE(eni) << eni.error().describe();
  const auto& s = eni->slaves[0];
  EXPECT_EQ(s.info.auto_inc_addr, 0xFFFF);
  EXPECT_EQ(s.info.vendor_id, 2u);
  EXPECT_EQ(s.info.product_code, 0xFFFFFFFFu);
  EXPECT_EQ(s.info.identification_ado, 0x12);
  EXPECT_EQ(s.info.identification_value, 7);
  EXPECT_EQ(s.dc->shift_time, -250'000);
}

TEST(Eni, LooksLikeEniByContent) {
  EXPECT_TRUE(looks_like_eni("<EtherCATConfig/>"));
  EXPECT_TRUE(
      looks_like_eni("\xEF\xBB\xBF<?xml version=\"1.0\"?>\n<!-- c -->\n<EtherCATConfig "
                     "Version=\"1.3\">"));
  EXPECT_FALSE(looks_like_eni("version: 1\nsimulator: {}\n"));
  EXPECT_FALSE(looks_like_eni("<EtherCATInfo/>"));
  EXPECT_FALSE(looks_like_eni("<EtherCATConfigX/>"));
  EXPECT_FALSE(looks_like_eni("<?xml version=\"1.0\""));
  EXPECT_FALSE(looks_like_eni(""));
}

TEST(Eni, MalformedXmlNamesTheLine) {
  expect_error("<?xml version=\"1.0\"?>\n<EtherCATConfig>\n<Config>\n<Slave>\n</Config>",
               "bad.xml:5: not well-formed XML");
  expect_error("<EtherCATInfo/>", "not <EtherCATConfig>");
  expect_error("<EtherCATConfig/>", "<EtherCATConfig>: has no <Config>");
}

TEST(Eni, MissingIdentitiesAreErrors) {
  expect_error(wrap_config("<Slave>\n<ProcessData/>\n</Slave>\n"),
               "bad.xml:5: <Slave>: has no <Info>");
  expect_error(wrap_config("<Slave>\n<Info><Name>x</Name><ProductCode>1</ProductCode></Info>\n"
                           "</Slave>\n"),
               "bad.xml:6: <Info>: <VendorId> is missing");
  expect_error(wrap_config("<Slave>\n<Info><Name>x</Name><VendorId>1</VendorId></Info>\n"
                           "</Slave>\n"),
               "<ProductCode> is missing");
}

TEST(Eni, WrongTypesAreErrors) {
  expect_error(wrap_config("<Slave>\n<Info><VendorId>two</VendorId><ProductCode>1</ProductCode>"
                           "</Info></Slave>\n"),
               "bad.xml:6: <VendorId>: \"two\" is not a number");
  expect_error(wrap_slave("<Mailbox><CoE><InitCmds><InitCmd>\n<Transition>XY</Transition>"
                          "<Index>1</Index><Data>00</Data></InitCmd></InitCmds></CoE></Mailbox>"),
               "<Transition>: unknown transition \"XY\"");
  expect_error(wrap_slave("<Mailbox><CoE><InitCmds><InitCmd><Transition>PS</Transition>"
                          "<Index>#x6060</Index><Data>0</Data></InitCmd></InitCmds></CoE>"
                          "</Mailbox>"),
               "odd number of digits");
  expect_error(wrap_slave("<Mailbox><CoE><InitCmds><InitCmd><Transition>PS</Transition>"
                          "<Index>#x6060</Index><Data>zz</Data></InitCmd></InitCmds></CoE>"
                          "</Mailbox>"),
               "\"zz\" is not hex data");
  expect_error(wrap_slave("<Mailbox><CoE><InitCmds><InitCmd><Transition>PS</Transition>"
                          "<Index>#x6060</Index></InitCmd></InitCmds></CoE></Mailbox>"),
               "the download to 0x6060:00 has no <Data>");
  expect_error(wrap_slave("<ProcessData><RxPdo Fixed=\"maybe\"><Index>#x1600</Index></RxPdo>"
                          "</ProcessData>"),
               "not a boolean");
  expect_error(wrap_slave("<ProcessData><TxPdo><Index>#x1a00</Index><Entry><Index>#x6000</Index>"
                          "<BitLen>0</BitLen></Entry></TxPdo></ProcessData>"),
               "a PDO entry needs at least one bit");
}

TEST(Eni, OversizedValuesAreErrors) {
  expect_error(wrap_slave("<ProcessData><TxPdo><Index>#x1a00</Index><Entry><Index>#x6000</Index>"
                          "<BitLen>256</BitLen></Entry></TxPdo></ProcessData>"),
               "256 is out of range [0, 255]");
  expect_error(wrap_slave("<ProcessData><Sm2><StartAddress>#x10000</StartAddress></Sm2>"
                          "</ProcessData>"),
               "<StartAddress>: #x10000 is out of range");
  expect_error(wrap_slave("<ProcessData><Sm16/></ProcessData>"), "SyncManagers 0..15");
  expect_error(wrap_slave("<DC><CycleTime0>-1</CycleTime0></DC>"), "<CycleTime0>: -1 is out of");
  expect_error(wrap_slave("<InitCmds><InitCmd><Cmd>2</Cmd><DataLength>70000</DataLength>"
                          "</InitCmd></InitCmds>"),
               "more than a datagram carries");
  expect_error(wrap_config("<Slave><Info><VendorId>99999999999999999999999</VendorId></Info>"
                           "</Slave>\n"),
               "is not a number");
  std::string data(2 * (kMaxEniDataBytes + 1), 'a');
  expect_error(wrap_slave("<Mailbox><CoE><InitCmds><InitCmd><Transition>PS</Transition><Index>1"
                          "</Index><Data>" +
                          data + "</Data></InitCmd></InitCmds></CoE></Mailbox>"),
               "bytes of data");
}

TEST(Eni, AFileThatIsNotThereIsNamed) {
  auto eni = load_eni("/nonexistent/network.xml");
  ASSERT_FALSE(eni);
  EXPECT_NE(eni.error().describe().find("/nonexistent/network.xml"), std::string::npos);
}

}  // namespace
}  // namespace ecat::config
