// ESI device descriptions: the parser (config/esi.hpp) on a small description of our own and on
// the real Ingenia EVS-NET-01 ESI from the shared data, the SII generated from them, and the
// simulator's "esi" profile bringing such devices to OP (the Ingenia drive with its CiA 402
// model).
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include <ecat/config/esi.hpp>
#include <ecat/sim/standard_application.hpp>

#include "sim/sim_master.hpp"
#include "support/shared_data.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;
using test::SimMaster;
using wire::AlState;

// A small description written for these tests: two channels of 16-bit inputs on SM3, one
// 16-bit output on SM2, a remappable assignment, records, arrays and strings.
constexpr const char* kEsi = R"(<?xml version="1.0" encoding="utf-8"?>
<EtherCATInfo Version="1.6">
  <Vendor><Id>#x00000ACE</Id><Name>ecat tests</Name></Vendor>
  <Descriptions>
    <Devices>
      <Device Physics="KK">
        <Type ProductCode="#x00001234" RevisionNo="2">TEST-IO</Type>
        <Name LcId="1033">Test IO module</Name>
        <Info><EtherCATController><DpramSize>8192</DpramSize><SmCount>4</SmCount><FmmuCount>3</FmmuCount></EtherCATController></Info>
        <GroupType>TestGroup</GroupType>
        <Profile>
          <ProfileNo>5001</ProfileNo>
          <Dictionary>
            <DataTypes>
              <DataType><Name>UINT</Name><BitSize>16</BitSize></DataType>
              <DataType><Name>DT1C13ARR</Name><BaseType>UINT</BaseType><BitSize>32</BitSize><ArrayInfo><LBound>1</LBound><Elements>2</Elements></ArrayInfo></DataType>
              <DataType><Name>DT1C13</Name><BitSize>48</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access WriteRestrictions="PreOP">rw</Access></Flags></SubItem>
                <SubItem><Name>Elements</Name><Type>DT1C13ARR</Type><BitSize>32</BitSize><BitOffs>16</BitOffs><Flags><Access WriteRestrictions="PreOP">rw</Access></Flags></SubItem>
              </DataType>
              <DataType><Name>DT1A00</Name><BitSize>80</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>1</SubIdx><Name>Entry 1</Name><Type>UDINT</Type><BitSize>32</BitSize><BitOffs>16</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>2</SubIdx><Name>Entry 2</Name><Type>UDINT</Type><BitSize>32</BitSize><BitOffs>48</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
              </DataType>
              <DataType><Name>DT6000</Name><BitSize>48</BitSize>
                <SubItem><SubIdx>0</SubIdx><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize><BitOffs>0</BitOffs><Flags><Access>ro</Access></Flags></SubItem>
                <SubItem><SubIdx>1</SubIdx><Name>Value 1</Name><Type>INT</Type><BitSize>16</BitSize><BitOffs>16</BitOffs><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></SubItem>
                <SubItem><SubIdx>2</SubIdx><Name>Value 2</Name><Type>INT</Type><BitSize>16</BitSize><BitOffs>32</BitOffs><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></SubItem>
              </DataType>
            </DataTypes>
            <Objects>
              <Object><Index>#x1000</Index><Name>Device type</Name><Type>UDINT</Type><BitSize>32</BitSize><Info><DefaultData>89130000</DefaultData></Info><Flags><Access>ro</Access></Flags></Object>
              <Object><Index>#x1008</Index><Name>Device name</Name><Type>STRING(7)</Type><BitSize>56</BitSize><Info><DefaultString>TEST-IO</DefaultString></Info><Flags><Access>ro</Access></Flags></Object>
              <Object><Index>#x1A00</Index><Name>Inputs mapping</Name><Type>DT1A00</Type><BitSize>80</BitSize>
                <Info>
                  <SubItem><Name>SubIndex 000</Name><Info><DefaultData>02</DefaultData></Info></SubItem>
                  <SubItem><Name>Entry 1</Name><Info><DefaultData>10010060</DefaultData></Info></SubItem>
                  <SubItem><Name>Entry 2</Name><Info><DefaultData>10020060</DefaultData></Info></SubItem>
                </Info>
              </Object>
              <Object><Index>#x1C13</Index><Name>TxPDO assign</Name><Type>DT1C13</Type><BitSize>48</BitSize>
                <Info>
                  <SubItem><Name>SubIndex 000</Name><Info><DefaultData>00</DefaultData></Info></SubItem>
                  <SubItem><Name>Element 1</Name><Info><DefaultData>0000</DefaultData></Info></SubItem>
                  <SubItem><Name>Element 2</Name><Info><DefaultData>0000</DefaultData></Info></SubItem>
                </Info>
              </Object>
              <Object><Index>#x6000</Index><Name>Inputs</Name><Type>DT6000</Type><BitSize>48</BitSize>
                <Info>
                  <SubItem><Name>SubIndex 000</Name><Info><DefaultData>02</DefaultData></Info></SubItem>
                  <SubItem><Name>Value 1</Name><Info><DefaultData>3412</DefaultData></Info></SubItem>
                  <SubItem><Name>Value 2</Name><Info><DefaultData>ffff</DefaultData></Info></SubItem>
                </Info>
              </Object>
              <Object><Index>#x7000</Index><Name>Output</Name><Type>UINT</Type><BitSize>16</BitSize>
                <Info><DefaultData>0000</DefaultData><MinValue>0</MinValue><MaxValue>1000</MaxValue></Info>
                <Flags><Access>rw</Access><PdoMapping>R</PdoMapping></Flags></Object>
              <Object><Index>#x8000</Index><Name>Setting</Name><Type>UINT</Type><BitSize>16</BitSize>
                <Info><DefaultData>0500</DefaultData></Info>
                <Flags><Access WriteRestrictions="PreOP">rw</Access><Backup>1</Backup></Flags></Object>
            </Objects>
          </Dictionary>
        </Profile>
        <Fmmu>Outputs</Fmmu><Fmmu>Inputs</Fmmu><Fmmu>MBoxState</Fmmu>
        <Sm MinSize="34" MaxSize="128" DefaultSize="64" StartAddress="#x1000" ControlByte="#x26" Enable="1">MBoxOut</Sm>
        <Sm MinSize="34" MaxSize="128" DefaultSize="64" StartAddress="#x1080" ControlByte="#x22" Enable="1">MBoxIn</Sm>
        <Sm DefaultSize="2" StartAddress="#x1100" ControlByte="#x64" Enable="1">Outputs</Sm>
        <Sm DefaultSize="4" StartAddress="#x1180" ControlByte="#x20" Enable="1">Inputs</Sm>
        <RxPdo Fixed="1" Sm="2" Mandatory="1"><Index>#x1600</Index><Name>Output mapping</Name>
          <Entry><Index>#x7000</Index><SubIndex>0</SubIndex><BitLen>16</BitLen><Name>Output</Name><DataType>UINT</DataType></Entry>
        </RxPdo>
        <TxPdo Sm="3"><Index>#x1A00</Index><Name>Inputs mapping</Name>
          <Entry><Index>#x6000</Index><SubIndex>1</SubIndex><BitLen>16</BitLen><Name>Value 1</Name><DataType>INT</DataType></Entry>
          <Entry><Index>#x6000</Index><SubIndex>2</SubIndex><BitLen>16</BitLen><Name>Value 2</Name><DataType>INT</DataType></Entry>
        </TxPdo>
        <Mailbox DataLinkLayer="true"><CoE SdoInfo="true" CompleteAccess="false" PdoAssign="true" PdoConfig="false"/><FoE/></Mailbox>
        <Dc><OpMode><Name>DcSync</Name><Desc>DC synchronous</Desc><AssignActivate>#x300</AssignActivate><CycleTimeSync0 Factor="1">0</CycleTimeSync0><ShiftTimeSync0>0</ShiftTimeSync0></OpMode></Dc>
        <Eeprom><ByteSize>2048</ByteSize><ConfigData>050E03440A000000000000000000</ConfigData><BootStrap>0010000100140001</BootStrap></Eeprom>
      </Device>
    </Devices>
  </Descriptions>
</EtherCATInfo>
)";

std::filesystem::path write_temp(const std::string& name, const std::string& text) {
  const auto path = std::filesystem::temp_directory_path() / name;
  std::ofstream(path) << text;
  return path;
}

TEST(EsiParser, ReadsEveryPartOfADescription) {
  auto file = config::parse_esi(kEsi);
  ASSERT_TRUE(file.ok()) << file.error().describe();
  EXPECT_EQ(file->vendor_id, 0x00000ACEu);
  EXPECT_EQ(file->vendor_name, "ecat tests");
  ASSERT_EQ(file->devices.size(), 1u);
  const auto& d = file->devices[0];
  EXPECT_EQ(d.product_code, 0x1234u);
  EXPECT_EQ(d.revision, 2u);
  EXPECT_EQ(d.type, "TEST-IO");
  EXPECT_EQ(d.name, "Test IO module");
  EXPECT_EQ(d.group_type, "TestGroup");
  EXPECT_EQ(d.physics, "KK");
  EXPECT_EQ(d.profile_no, 5001u);
  EXPECT_EQ(d.sync_manager_count, 4);
  EXPECT_EQ(d.fmmu_count, 3);
  EXPECT_EQ(d.dpram_size, 8192u);
  EXPECT_EQ(d.fmmus, (std::vector<std::string>{"Outputs", "Inputs", "MBoxState"}));
  ASSERT_EQ(d.sync_managers.size(), 4u);
  EXPECT_EQ(d.sync_managers[2].type, "Outputs");
  EXPECT_EQ(d.sync_managers[2].start, 0x1100);
  EXPECT_EQ(d.sync_managers[2].control_byte, 0x64);
  EXPECT_EQ(d.sync_managers[0].max_size, 128);
  ASSERT_EQ(d.rxpdos.size(), 1u);
  EXPECT_TRUE(d.rxpdos[0].fixed);
  EXPECT_TRUE(d.rxpdos[0].mandatory);
  EXPECT_EQ(d.rxpdos[0].sync_manager, 2);
  ASSERT_EQ(d.txpdos[0].entries.size(), 2u);
  EXPECT_EQ(d.txpdos[0].entries[1].subindex, 2);
  EXPECT_EQ(d.txpdos[0].entries[1].data_type, "INT");
  ASSERT_TRUE(d.mailbox);
  EXPECT_TRUE(d.mailbox->coe);
  EXPECT_TRUE(d.mailbox->foe);
  EXPECT_FALSE(d.mailbox->eoe);
  EXPECT_TRUE(d.mailbox->sdo_info);
  EXPECT_FALSE(d.mailbox->complete_access);
  EXPECT_TRUE(d.mailbox->pdo_assign);
  EXPECT_TRUE(d.mailbox->data_link_layer);
  ASSERT_EQ(d.dc_op_modes.size(), 1u);
  EXPECT_EQ(d.dc_op_modes[0].assign_activate, 0x0300);
  EXPECT_EQ(d.dc_op_modes[0].cycle_time_sync0_factor, 1);
  EXPECT_EQ(d.eeprom_byte_size, 2048u);
  ASSERT_TRUE(d.bootstrap);
  EXPECT_EQ(*d.bootstrap, (std::array<std::uint16_t, 4>{0x1000, 0x0100, 0x1400, 0x0100}));
  // Objects: a VAR, a string, records, an array expanded from its element type.
  ASSERT_EQ(d.objects.size(), 7u);
  const auto* type = d.object(0x1000);
  ASSERT_NE(type, nullptr);
  EXPECT_EQ(type->code, config::EsiObjectCode::var);
  EXPECT_EQ(type->entries[0].default_data, (Bytes{0x89, 0x13, 0x00, 0x00}));
  const auto* name = d.object(0x1008);
  EXPECT_EQ(name->entries[0].default_data, (Bytes{'T', 'E', 'S', 'T', '-', 'I', 'O'}));
  const auto* assign = d.object(0x1C13);
  ASSERT_NE(assign, nullptr);
  EXPECT_EQ(assign->code, config::EsiObjectCode::array);
  ASSERT_EQ(assign->entries.size(), 3u);
  EXPECT_EQ(assign->entries[2].subindex, 2);
  EXPECT_EQ(assign->entries[2].type, "UINT");
  EXPECT_EQ(assign->entries[2].bit_size, 16u);
  EXPECT_EQ(assign->entries[2].write_restrictions, "PreOP");
  EXPECT_EQ(assign->entries[2].name, "Element 2");
  const auto* inputs = d.object(0x6000);
  EXPECT_EQ(inputs->code, config::EsiObjectCode::record);
  EXPECT_EQ(inputs->entries[1].pdo_mapping, "T");
  EXPECT_EQ(inputs->entries[1].default_data, (Bytes{0x34, 0x12}));
  const auto* output = d.object(0x7000);
  EXPECT_EQ(output->entries[0].access, "rw");
  EXPECT_EQ(output->entries[0].maximum, 1000);
  EXPECT_TRUE(d.object(0x8000)->entries[0].backup);
  EXPECT_EQ(config::esi_basic_type("UDINT"), 0x0007);
  EXPECT_EQ(config::esi_basic_type("STRING(10)"), 0x0009);
  EXPECT_EQ(config::esi_basic_type("DT1018"), 0);
}

TEST(EsiParser, ErrorsNameWhatIsWrong) {
  auto broken = config::parse_esi("<EtherCATInfo><Vendor>");
  ASSERT_FALSE(broken.ok());
  EXPECT_NE(broken.error().message().find("XML error"), std::string::npos);
  auto other = config::parse_esi("<Root/>");
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().message().find("EtherCATInfo"), std::string::npos);
  std::string bad_product = kEsi;
  bad_product.replace(bad_product.find("#x00001234"), 10, "#xZZ");
  auto product = config::parse_esi(bad_product);
  ASSERT_FALSE(product.ok());
  EXPECT_NE(product.error().message().find("ProductCode"), std::string::npos);
  EXPECT_NE(product.error().message().find("TEST-IO"), std::string::npos);
  std::string bad_index = kEsi;
  bad_index.replace(bad_index.find("<Index>#x8000</Index>"), 21, "<Index>#xQQ</Index>");
  auto index = config::parse_esi(bad_index);
  ASSERT_FALSE(index.ok());
  EXPECT_NE(index.error().message().find("Index"), std::string::npos);
  auto none = config::parse_esi(
      "<EtherCATInfo><Vendor><Id>1</Id></Vendor><Descriptions><Devices/></Descriptions>"
      "</EtherCATInfo>");
  ASSERT_FALSE(none.ok());
  auto file = config::parse_esi(kEsi);
  ASSERT_TRUE(file.ok());
  auto missing = config::find_esi_device(*file, 0x9999);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message().find("0x00001234 (TEST-IO)"), std::string::npos);
  auto only = config::find_esi_device(*file, std::nullopt);
  ASSERT_TRUE(only.ok());
  EXPECT_EQ((*only)->product_code, 0x1234u);
  EXPECT_FALSE(config::load_esi("/nonexistent/device.xml").ok());
}

TEST(EsiToSii, EncodesTheDescription) {
  auto file = config::parse_esi(kEsi);
  ASSERT_TRUE(file.ok());
  auto sii = config::esi_to_sii(*file, file->devices[0]);
  ASSERT_TRUE(sii.ok()) << sii.error().describe();
  auto bytes = wire::encode_sii(*sii);
  ASSERT_TRUE(bytes.ok());
  auto decoded = wire::decode_sii(*bytes);
  ASSERT_TRUE(decoded.ok());
  EXPECT_TRUE(decoded->checksum_ok);
  const auto& s = decoded->image;
  EXPECT_EQ(s.identity, (wire::SiiIdentity{0x0ACE, 0x1234, 2, 0}));
  EXPECT_EQ(s.pdi_control, 0x0E05);
  EXPECT_EQ(s.pdi_configuration, 0x4403);
  EXPECT_EQ(s.sync_impulse_length, 0x000A);
  EXPECT_EQ(s.standard_mailbox, (wire::SiiMailbox{0x1000, 64, 0x1080, 64}));
  EXPECT_EQ(s.bootstrap_mailbox, (wire::SiiMailbox{0x1000, 0x100, 0x1400, 0x100}));
  EXPECT_EQ(s.mailbox_protocols, wire::mailbox_protocol::kCoe | wire::mailbox_protocol::kFoe);
  EXPECT_EQ(s.eeprom_size, 15);
  ASSERT_TRUE(s.general);
  EXPECT_EQ(s.string(s.general->order_index), "TEST-IO");
  EXPECT_EQ(s.string(s.general->name_index), "Test IO module");
  EXPECT_EQ(s.string(s.general->group_index), "TestGroup");
  EXPECT_EQ(s.general->coe_details, wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo |
                                        wire::sii_coe_detail::kPdoAssign);
  EXPECT_EQ(s.general->foe_details, 1);
  EXPECT_EQ(s.general->port(0), wire::sii_port::kEbus);
  EXPECT_EQ(s.general->port(1), wire::sii_port::kEbus);
  EXPECT_EQ(s.general->flags & wire::sii_general_flag::kMailboxDataLinkLayer,
            wire::sii_general_flag::kMailboxDataLinkLayer);
  ASSERT_EQ(s.sync_managers.size(), 4u);
  EXPECT_EQ(s.sync_managers[3],
            (wire::SiiSyncManager{0x1180, 4, 0x20, 0, 0x01, wire::sii_sm_type::kInputs}));
  EXPECT_EQ(s.fmmus.size(), 4u);  // 3, padded to whole words
  EXPECT_EQ(s.fmmus[2], wire::sii_fmmu_usage::kMailboxState);
  ASSERT_EQ(s.txpdos.size(), 1u);
  EXPECT_EQ(s.txpdos[0].sync_manager, 3);
  EXPECT_EQ(s.txpdos[0].entries[1].data_type, 0x03);
  EXPECT_EQ(s.string(s.txpdos[0].entries[1].name_index), "Value 2");
  EXPECT_EQ(s.rxpdos[0].flags & wire::sii_pdo_flag::kFixedContent,
            wire::sii_pdo_flag::kFixedContent);
  ASSERT_EQ(s.dc.size(), 1u);
  EXPECT_EQ(s.dc[0].assign_activate, 0x0300);
  EXPECT_EQ(s.string(s.dc[0].name_index), "DcSync");
}

TEST(EsiProfile, ADeviceFromOurDescriptionReachesOp) {
  const auto path = write_temp("ecat_test_io.xml", kEsi);
  DeviceConfig c = test::profile("esi");
  c.file = path.string();
  Segment segment;
  test::add_device(segment, "io", c);
  SimMaster m(segment);
  m.assign_stations();
  m.bring_to_preop(0);
  // The dictionary: ESI defaults, the identity of the Type element, the default assignment from
  // the PDOs' Sm attributes, access rights from the flags.
  auto identity = m.upload(0, 0x1018, 2);
  ASSERT_TRUE(identity.value);
  EXPECT_EQ(*identity.value, test::le32(0x1234));
  auto assign = m.upload(0, 0x1C13, 1);
  ASSERT_TRUE(assign.value);
  EXPECT_EQ(*assign.value, test::le16(0x1A00));
  auto name = m.upload(0, 0x1008, 0);
  ASSERT_TRUE(name.value);
  EXPECT_EQ(std::string(name.value->begin(), name.value->end()), "TEST-IO");
  EXPECT_EQ(m.download(0, 0x7000, 0, test::le16(1001)).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::value_too_high));
  EXPECT_EQ(m.download(0, 0x1000, 0, test::le32(1)).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::write_of_read_only));
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  // The setting is writable in PREOP only.
  EXPECT_EQ(m.download(0, 0x8000, 0, test::le16(7)).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::cannot_store_device_state));
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  auto& dev = *device_application(segment.esc(0));
  const auto signals = dev.signals();
  ASSERT_EQ(signals.size(), 3u);
  EXPECT_EQ(signals[0].name, "output_mapping");
  EXPECT_EQ(signals[1].name, "inputs_value_1");
  EXPECT_EQ(signals[2].name, "inputs_value_2");
  EXPECT_EQ(signals[2].type, "i16");
  wire::store_le16(&m.image()[m.slot(0, 2).offset], 500);
  EXPECT_TRUE(dev.set_input("inputs_value_2", -5));
  EXPECT_EQ(m.lrw(), 3);
  EXPECT_EQ(dev.signal("output_mapping"), 500.0);
  EXPECT_EQ(wire::load_le16(&m.image()[m.slot(0, 3).offset]), 0x1234);
  EXPECT_EQ(static_cast<std::int16_t>(wire::load_le16(&m.image()[m.slot(0, 3).offset + 2])), -5);
  std::filesystem::remove(path);
}

TEST(EsiProfile, OptionsAndErrors) {
  DeviceConfig c = test::profile("esi");
  EXPECT_FALSE(make_device(c).ok());
  const auto path = write_temp("ecat_test_io2.xml", kEsi);
  c.file = path.string();
  c.options["product"] = "0x4321";
  auto wrong = make_device(c);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.error().describe().find("0x00004321"), std::string::npos);
  c.options["product"] = "0x1234";
  EXPECT_TRUE(make_device(c).ok());
  std::filesystem::remove(path);
}

// ---- the Ingenia EVS-NET-01 ESI
// ------------------------------------------------------------------

TEST(IngeniaEsi, ParsesTheVendorFile) {
  ECAT_SHARED_DATA_OR_SKIP(path, "esi/ingenia-evs-net-01.xml");
  auto file = config::load_esi(path.string());
  ASSERT_TRUE(file.ok()) << file.error().describe();
  EXPECT_EQ(file->vendor_id, 0x0000029Cu);
  EXPECT_EQ(file->vendor_name, "Ingenia");
  ASSERT_EQ(file->devices.size(), 1u);
  const auto& d = file->devices[0];
  EXPECT_EQ(d.product_code, 61935618u);
  EXPECT_EQ(d.revision, 327685u);
  EXPECT_EQ(d.type, "EVS-NET-01");
  EXPECT_EQ(d.profile_no, 402u);
  EXPECT_EQ(d.objects.size(), 583u);
  EXPECT_EQ(d.rxpdos.size(), 3u);
  EXPECT_EQ(d.txpdos.size(), 3u);
  EXPECT_EQ(d.rxpdos[0].excludes, (std::vector<std::uint16_t>{0x1601, 0x1602}));
  ASSERT_EQ(d.dc_op_modes.size(), 2u);
  EXPECT_EQ(d.dc_op_modes[1].assign_activate, 0x0300);
  EXPECT_EQ(d.dc_op_modes[1].shift_time_sync0, -3);
  ASSERT_TRUE(d.bootstrap);
  EXPECT_EQ(*d.bootstrap, (std::array<std::uint16_t, 4>{0x1000, 0x0080, 0x1400, 0x0080}));
  const auto* mapping = d.object(0x1600);
  ASSERT_NE(mapping, nullptr);
  EXPECT_EQ(mapping->entries.size(), 16u);  // subindex 0 and 15 elements (496 bits)
  EXPECT_EQ(mapping->entries[1].default_data, (Bytes{0x10, 0x00, 0x40, 0x60}));
  const auto* control = d.object(0x6040);
  ASSERT_NE(control, nullptr);
  EXPECT_EQ(control->entries[0].pdo_mapping, "R");
  auto sii = config::esi_to_sii(*file, d);
  ASSERT_TRUE(sii.ok());
  EXPECT_EQ(sii->eeprom_size, 127);  // 16 KiB
  auto bytes = wire::encode_sii(*sii);
  ASSERT_TRUE(bytes.ok()) << bytes.error().describe();
  EXPECT_EQ(bytes->size(), 16384u);
}

TEST(IngeniaEsi, TheDriveReachesOpAndRunsCia402) {
  ECAT_SHARED_DATA_OR_SKIP(path, "esi/ingenia-evs-net-01.xml");
  DeviceConfig c = test::profile("esi");
  c.file = path.string();
  Segment segment;
  test::add_device(segment, "drive", c);
  SimMaster m(segment);
  m.assign_stations();
  const auto image = m.sii(0);
  EXPECT_EQ(image.identity.vendor_id, 0x0000029Cu);
  EXPECT_EQ(image.identity.product_code, 61935618u);
  EXPECT_EQ(image.bootstrap_mailbox.recv_size, 0x80);
  m.bring_to_preop(0);
  auto product = m.upload(0, 0x1018, 2);
  ASSERT_TRUE(product.value);
  EXPECT_EQ(*product.value, test::le32(61935618));
  auto version = m.upload(0, 0x5EE4, 0);
  ASSERT_TRUE(version.value);
  EXPECT_EQ(std::string(version.value->begin(), version.value->end()), "000.0.0.1");
  auto assign = m.upload(0, 0x1C12, 1);
  ASSERT_TRUE(assign.value);
  EXPECT_EQ(*assign.value, test::le16(0x1600));
  // The SII lengths (DefaultSize 11) match the default mapping: 16 + 32 + 32 + 8 bits.
  m.configure_process_data(0);
  EXPECT_EQ(m.slot(0, 2).length, 11);
  EXPECT_EQ(m.slot(0, 3).length, 11);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  // RxPDO: controlword(0) position set-point(2) velocity set-point(6) mode(10).
  // TxPDO: statusword(0) actual position(2) actual velocity(6) mode display(10).
  std::uint8_t* out = &m.image()[m.slot(0, 2).offset];
  const std::uint8_t* in = &m.image()[m.slot(0, 3).offset];
  auto cycle = [&](std::uint16_t controlword) {
    wire::store_le16(out, controlword);
    out[10] = 8;  // CSP
    m.wait(1'000'000);
    EXPECT_EQ(m.lrw(), 3);
    m.wait(1'000'000);
    m.lrw();
    return wire::load_le16(in);
  };
  EXPECT_EQ(cycle(0x0000), 0x0240);
  EXPECT_EQ(cycle(0x0006), 0x0231);
  EXPECT_EQ(cycle(0x0007), 0x0233);
  EXPECT_EQ(cycle(0x000F) & 0x006F, 0x0027);
  EXPECT_EQ(static_cast<std::int8_t>(in[10]), 8);
  wire::store_le32(out + 2, 40);
  for (int i = 0; i < 20; ++i)
    cycle(0x000F);
  EXPECT_EQ(static_cast<std::int32_t>(wire::load_le32(in + 2)), 40);
  auto& dev = *device_application(segment.esc(0));
  EXPECT_EQ(dev.signal("position_actual"), 40.0);
  EXPECT_EQ(dev.signal("mode"), 8.0);
}

}  // namespace
}  // namespace ecat::sim
