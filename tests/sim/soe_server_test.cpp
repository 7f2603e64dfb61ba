// The SoE server of the "soe_drive" profile through real datagrams (SimMaster writes SM0 and reads
// SM1 byte by byte, no master-side SoE code): the SII declares SoE and not CoE; every element of
// an IDN in bit order; fragmented reads of S-0-0017 and P-0-0010 with the fragments-left count;
// fragmented writes; write protection by AL state; the error codes; procedure commands with
// their notification; several drive numbers; the fault hooks.
#include <cstdint>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/soe_server.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/soe.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;

class SoeServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    test::add_device(segment, "drive", test::profile("soe_drive", {{"drives", "2"}}));
    m.assign_stations();
    m.bring_to_preop(0);
  }

  SoeServer& server() { return *soe_server_of(segment.esc(0)); }

  // Sends one SoE request; the SoE messages the drive answers with (until SM1 stays empty).
  std::vector<wire::SoeMessage> request(const wire::SoeMessage& message) {
    auto data = wire::encode_soe(message);
    EXPECT_TRUE(data.ok());
    EXPECT_TRUE(m.write_mailbox(0, wire::MailboxType::soe, *data));
    std::vector<wire::SoeMessage> out;
    while (auto reply = m.read_mailbox(0)) {
      EXPECT_EQ(reply->first.type, wire::MailboxType::soe);
      auto soe = wire::decode_soe(reply->second);
      EXPECT_TRUE(soe.ok());
      if (soe) out.push_back(*soe);
    }
    return out;
  }
  std::vector<wire::SoeMessage> read(std::uint16_t idn, std::uint8_t elements,
                                     std::uint8_t drive = 0) {
    return request({{wire::SoeOpcode::read_request, false, false, drive, elements, idn}, {}, {}});
  }
  std::vector<wire::SoeMessage> write(std::uint16_t idn, Bytes data, std::uint8_t drive = 0) {
    return request(
        {{wire::SoeOpcode::write_request, false, false, drive, wire::kSoeElementValue, idn},
         {},
         std::move(data)});
  }
  // The error code of a single error response.
  std::uint16_t error_of(const std::vector<wire::SoeMessage>& replies) {
    EXPECT_EQ(replies.size(), 1u);
    if (replies.size() != 1 || !replies[0].header.error) return 0;
    return replies[0].error_code.value_or(0);
  }

  Segment segment;
  test::SimMaster m{segment};
};

TEST_F(SoeServerTest, TheSiiDeclaresSoeAndNotCoe) {
  const auto sii = m.sii(0);
  EXPECT_EQ(sii.mailbox_protocols, wire::mailbox_protocol::kSoe);
  EXPECT_EQ(sii.general->soe_channels, 2);
  EXPECT_EQ(sii.standard_mailbox.send_size, 128);
}

TEST_F(SoeServerTest, AllSevenElementsInBitOrder) {
  auto replies = read(0x0001, 0xFE);  // everything but the data state
  ASSERT_EQ(replies.size(), 1u);
  const auto& r = replies[0];
  EXPECT_EQ(r.header.opcode, wire::SoeOpcode::read_response);
  EXPECT_FALSE(r.header.incomplete);
  EXPECT_EQ(r.header.idn, 0x0001);
  EXPECT_EQ(r.header.elements, 0xFE);
  const std::string name = "NC cycle time (TNcyc)";
  Bytes expected = {static_cast<std::uint8_t>(name.size()), 0,
                    static_cast<std::uint8_t>(name.size()), 0};
  expected.insert(expected.end(), name.begin(), name.end());
  // Attribute: 2-byte unsigned, conversion factor 0, write protected in SAFEOP and OP.
  const std::uint32_t attribute = soe_attribute::kLength2 | soe_attribute::kUnsigned |
                                  soe_attribute::kWriteProtectedSafeop |
                                  soe_attribute::kWriteProtectedOp;
  for (int i = 0; i < 4; ++i)
    expected.push_back(static_cast<std::uint8_t>(attribute >> (8 * i)));
  Bytes unit = {2, 0, 2, 0, 'u', 's'};
  expected.insert(expected.end(), unit.begin(), unit.end());
  for (std::uint16_t v : {125, 65000, 1000, 1000}) {  // minimum, maximum, value, default
    expected.push_back(static_cast<std::uint8_t>(v));
    expected.push_back(static_cast<std::uint8_t>(v >> 8));
  }
  EXPECT_EQ(r.data, expected);
}

TEST_F(SoeServerTest, TheIdnListComesInTwoFragments) {
  auto replies = read(0x0011, wire::kSoeElementValue);
  ASSERT_EQ(replies.size(), 2u);
  // 128-byte mailbox: 118 bytes of SoE data per message.
  EXPECT_TRUE(replies[0].header.incomplete);
  EXPECT_EQ(replies[0].header.idn, 1);  // one fragment left
  EXPECT_EQ(replies[0].data.size(), 118u);
  EXPECT_FALSE(replies[1].header.incomplete);
  EXPECT_EQ(replies[1].header.idn, 0x0011);
  Bytes all = replies[0].data;
  all.insert(all.end(), replies[1].data.begin(), replies[1].data.end());
  const std::size_t actual = all[0] | (all[1] << 8);
  ASSERT_EQ(all.size(), 4 + actual);
  EXPECT_EQ(actual, 61u * 2);
  std::vector<std::uint16_t> idns;
  for (std::size_t i = 4; i < all.size(); i += 2)
    idns.push_back(static_cast<std::uint16_t>(all[i] | (all[i + 1] << 8)));
  for (std::uint16_t idn : {1, 17, 32, 36, 40, 47, 51, 99, 127, 128})
    EXPECT_NE(std::find(idns.begin(), idns.end(), idn), idns.end()) << idn;
  EXPECT_TRUE(std::is_sorted(idns.begin(), idns.end()));
  EXPECT_EQ(server().stats().fragments_sent, 1u);
}

TEST_F(SoeServerTest, ThreeFragmentsCountDown) {
  auto replies = read(0x800A, wire::kSoeElementValue);  // P-0-0010 error history, 260 bytes
  ASSERT_EQ(replies.size(), 3u);
  EXPECT_EQ(replies[0].header.idn, 2);
  EXPECT_EQ(replies[1].header.idn, 1);
  EXPECT_EQ(replies[2].header.idn, 0x800A);
  EXPECT_EQ(replies[0].data.size() + replies[1].data.size() + replies[2].data.size(), 260u);
}

TEST_F(SoeServerTest, WritesAreCheckedAndStored) {
  auto ok = write(0x0001, {0xF4, 0x01});  // 500 us
  ASSERT_EQ(ok.size(), 1u);
  EXPECT_EQ(ok[0].header.opcode, wire::SoeOpcode::write_response);
  EXPECT_FALSE(ok[0].header.error);
  EXPECT_EQ(ok[0].header.idn, 0x0001);
  EXPECT_EQ(server().number(0, 0x0001), 500);
  EXPECT_EQ(server().number(1, 0x0001), 1000);                  // drive 1 has its own copy
  EXPECT_EQ(error_of(write(0x0001, {0x64, 0x00})), 0x7006);     // 100 < 125
  EXPECT_EQ(error_of(write(0x0001, {0xFF, 0xFF})), 0x7007);     // 65535 > 65000
  EXPECT_EQ(error_of(write(0x0001, {0x01})), 0x7002);           // too short
  EXPECT_EQ(error_of(write(0x0001, {1, 2, 3})), 0x7003);        // too long
  EXPECT_EQ(error_of(write(0x0033, {0, 0, 0, 0})), 0x7004);     // S-0-0051 read only
  EXPECT_EQ(error_of(write(0x0123, {0, 0})), 0x1001);           // S-0-0291 not present
  EXPECT_EQ(error_of(write(0x0001, {0xF4, 0x01}, 5)), 0x800A);  // drive 5 of 2
  // Signed limits: the velocity command is +-6000 rpm.
  EXPECT_EQ(error_of(write(0x0024, {0x90, 0xE8, 0xFF, 0xFF})), 0);  // -6000
  EXPECT_EQ(error_of(write(0x0024, {0x8F, 0xE8, 0xFF, 0xFF})), 0x7006);
  // Other elements than the value are read only, each with its own code.
  auto name =
      request({{wire::SoeOpcode::write_request, false, false, 0, wire::kSoeElementName, 0x0001},
               {},
               {0, 0, 0, 0}});
  EXPECT_EQ(error_of(name), 0x2004);
  // A list: actual length, maximum length, data.
  EXPECT_EQ(error_of(write(0x0010, {2, 0, 32, 0, 0x33, 0x00})), 0);
  EXPECT_EQ(server().find(0, 0x0010)->value, (Bytes{0x33, 0x00}));
  EXPECT_EQ(error_of(write(0x0010, {4, 0, 32, 0, 0x33, 0x00})), 0x7002);
}

TEST_F(SoeServerTest, WriteProtectionFollowsTheAlState) {
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, wire::AlState::safeop).state, wire::AlState::safeop);
  EXPECT_EQ(error_of(write(0x0001, {0xF4, 0x01})), 0x7005);  // S-0-0001: not in SAFEOP
  EXPECT_EQ(error_of(write(0x0020, {0x02, 0x00})), 0);       // S-0-0032: until OP
  ASSERT_EQ(m.request(0, wire::AlState::op).state, wire::AlState::op);
  EXPECT_EQ(error_of(write(0x0020, {0x03, 0x00})), 0x7005);
  EXPECT_EQ(error_of(write(0x002F, {1, 0, 0, 0})), 0);  // commands stay writable
}

TEST_F(SoeServerTest, FragmentedWritesAreReassembled) {
  // P-0-0010 is read only, so a fragmented write goes to S-0-0016 (max 32 bytes) ... too small:
  // the drive's own limits say 0x7003 after reassembly.
  std::vector<wire::SoeMessage> replies;
  Bytes list = {36, 0, 32, 0};
  for (int i = 0; i < 36; ++i)
    list.push_back(static_cast<std::uint8_t>(i));
  const std::size_t per = 118;
  (void)per;
  // Two fragments of 20 bytes each: left 1, then the last with the IDN.
  Bytes first(list.begin(), list.begin() + 20);
  Bytes last(list.begin() + 20, list.end());
  EXPECT_TRUE(request({{wire::SoeOpcode::write_request, true, false, 0, 0x40, 1}, {}, first})
                  .empty());  // not answered
  EXPECT_EQ(error_of(request(
                {{wire::SoeOpcode::write_request, false, false, 0, 0x40, 0x0010}, {}, last})),
            0x7003);  // 36 > 32
  Bytes fits = {4, 0, 32, 0, 0x33, 0x00, 0x28, 0x00};
  EXPECT_TRUE(request({{wire::SoeOpcode::write_request, true, false, 0, 0x40, 1},
                       {},
                       Bytes(fits.begin(), fits.begin() + 5)})
                  .empty());
  EXPECT_EQ(error_of(request({{wire::SoeOpcode::write_request, false, false, 0, 0x40, 0x0010},
                              {},
                              Bytes(fits.begin() + 5, fits.end())})),
            0);
  EXPECT_EQ(server().find(0, 0x0010)->value, (Bytes{0x33, 0x00, 0x28, 0x00}));
  EXPECT_EQ(server().stats().fragments_received, 2u);
  // A lost fragment (left goes 2 -> final) is refused with 0x800B.
  (void)request({{wire::SoeOpcode::write_request, true, false, 0, 0x40, 2}, {}, {4, 0}});
  EXPECT_EQ(error_of(request({{wire::SoeOpcode::write_request, false, false, 0, 0x40, 0x0010},
                              {},
                              {32, 0, 1, 0, 2, 0}})),
            0x800B);
}

TEST_F(SoeServerTest, ReadErrors) {
  EXPECT_EQ(error_of(read(0x0123, 0x40)), 0x1001);
  EXPECT_EQ(error_of(read(0x000B, 0x08)), 0x4001);  // S-0-0011 has no unit
  EXPECT_EQ(error_of(read(0x0001, 0x01)), 0x7014);  // no data state
  EXPECT_EQ(error_of(read(0x0001, 0x00)), 0x800C);
  EXPECT_EQ(error_of(read(0x0001, 0x40, 2)), 0x800A);
  auto r = read(0x0123, 0x40);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].header.opcode, wire::SoeOpcode::read_response);
  EXPECT_TRUE(r[0].header.error);
  EXPECT_EQ(r[0].header.idn, 0x0123);
}

TEST_F(SoeServerTest, ProcedureCommandsNotifyWhenDone) {
  ASSERT_TRUE(server().set_number(0, 0x000B, 0x0001));  // a class 1 diagnostic
  auto replies = write(0x0063, {0x03, 0x00});           // S-0-0099, set + enable
  ASSERT_EQ(replies.size(), 2u);
  EXPECT_EQ(replies[0].header.opcode, wire::SoeOpcode::write_response);
  EXPECT_EQ(replies[1].header.opcode, wire::SoeOpcode::notification);
  EXPECT_EQ(replies[1].header.idn, 0x0063);
  EXPECT_EQ(replies[1].header.elements, wire::kSoeElementDataState);
  EXPECT_EQ(replies[1].data, (Bytes{0x03, 0x00}));
  EXPECT_EQ(server().number(0, 0x000B), 0);
  // CP4 check only in SAFEOP; CP3 refuses a cycle time off the 125 us grid.
  EXPECT_EQ(error_of(write(0x0080, {0x03, 0x00})), 0x7012);
  ASSERT_EQ(error_of(write(0x0001, {0xE8, 0x03})), 0);
  ASSERT_TRUE(server().set_number(0, 0x0001, 1001));
  EXPECT_EQ(error_of(write(0x007F, {0x03, 0x00})), 0x7013);
}

TEST_F(SoeServerTest, FaultHooks) {
  server().add_fault({0, 0x0011, false, SoeFaultKind::drop_fragment, 1, true});
  auto r = read(0x0011, 0x40);
  ASSERT_EQ(r.size(), 1u);  // only the last fragment
  EXPECT_FALSE(r[0].header.incomplete);
  server().add_fault({0, 0x0001, true, SoeFaultKind::error_response, 0x700C, false});
  EXPECT_EQ(error_of(write(0x0001, {0xE8, 0x03})), 0x700C);
  EXPECT_EQ(error_of(write(0x0001, {0xE8, 0x03})), 0x700C);  // sticky
  server().clear_faults();
  EXPECT_EQ(error_of(write(0x0001, {0xE8, 0x03})), 0);
  server().add_fault({0, 0x0001, false, SoeFaultKind::drop_response, 0, true});
  EXPECT_TRUE(read(0x0001, 0x40).empty());
  EXPECT_EQ(read(0x0001, 0x40).size(), 1u);
  EXPECT_EQ(server().stats().faults_applied, 4u);
}

TEST_F(SoeServerTest, PowerUpRestoresTheValues) {
  ASSERT_EQ(error_of(write(0x0001, {0xF4, 0x01})), 0);
  server().power_up();
  EXPECT_EQ(server().number(0, 0x0001), 1000);
}

TEST(VoeEcho, TheMailboxProfileEchoesWithVendorTypePlusOne) {
  Segment segment;
  test::add_device(segment, "mbx", test::profile("mailbox"));
  test::SimMaster m{segment};
  m.assign_stations();
  m.bring_to_preop(0);
  EXPECT_NE(m.sii(0).mailbox_protocols & wire::mailbox_protocol::kVoe, 0);
  auto data = wire::encode_voe({{0x00000ACE, 0x0010}, {1, 2, 3}});
  ASSERT_TRUE(data.ok());
  ASSERT_TRUE(m.write_mailbox(0, wire::MailboxType::voe, *data));
  auto reply = m.read_mailbox(0);
  ASSERT_TRUE(reply.has_value());
  EXPECT_EQ(reply->first.type, wire::MailboxType::voe);
  EXPECT_EQ(reply->second, (Bytes{0xCE, 0x0A, 0, 0, 0x11, 0x00, 1, 2, 3}));
  // Too short for the VoE header: mailbox error 0x06.
  ASSERT_TRUE(m.write_mailbox(0, wire::MailboxType::voe, {1, 2}));
  auto error = m.read_mailbox(0);
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ(error->first.type, wire::MailboxType::error);
  EXPECT_EQ(error->second, (Bytes{0x01, 0x00, 0x06, 0x00}));
}

}  // namespace
}  // namespace ecat::sim
