// The SoE client against scripted bytes: the simulator's "mailbox" device with an SoE handler that
// records each request and answers with byte strings written here, so the client is checked
// against the wire format itself (not against our own SoE server), including bytes as real drives
// send them:
//  - A Beckhoff AX5203's answer to a write of P-0-0092 (IDN 32860 = 0x805C), value 3C 0F 00 00,
//    as libethercat logs it in robert-burger/libethercat issue #34 ("SOE_WRITE: 3C0F0000 ... got
//    response: opcode 4, incomplete 0, error 0, atn 0, elements 64, idn 32860"), over a mailbox
//    of 128 bytes ("mbx_len 118" = 128 - 6 - 4).
//  - Requests laid out as SOEM's ec_SoEt (ethercatsoe.c): byte 0 opCode:3 incomplete:1 error:1
//    driveNo:3, byte 1 elementflags, word idn / fragmentsleft; the error code in the last two
//    bytes of an error response (SOEM reads it at length - 2, right after the 4-byte header).
#include <cstdint>
#include <deque>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/mailbox.hpp>
#include <ecat/master/soe.hpp>
#include <ecat/master/voe.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/soe.hpp>

#include "master/master_test_support.hpp"
#include "master/scripted_mailbox.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

class SoeClientTest : public test::ScriptedMailboxTest<wire::MailboxType::soe> {};

TEST_F(SoeClientTest, AReadRequestAsSoemSendsItAndItsValue) {
  answer({{0x02, 0x40, 0x01, 0x00, 0xE8, 0x03}});
  auto value = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, (Bytes{0xE8, 0x03}));
  ASSERT_EQ(requests().size(), 1u);
  // opcode 1, drive 0, value element, S-0-0001; nothing after the header.
  EXPECT_EQ(requests()[0], (Bytes{0x01, 0x40, 0x01, 0x00}));
  // Drive 2, name + attribute: drive number in bits 5..7 of byte 0.
  answer({{0x42, 0x06, 0x20, 0x00, 0, 0, 0, 0, 0x01, 0x00, 0x21, 0x00}});
  auto both = run(soe_read(*mailbox_, 2, 0x0020, 0x06));
  ASSERT_TRUE(both.ok()) << both.error().describe();
  EXPECT_EQ(requests()[1], (Bytes{0x41, 0x06, 0x20, 0x00}));
  auto split = split_soe_elements(0x06, *both);
  ASSERT_TRUE(split.ok()) << split.error().describe();
  EXPECT_EQ(split->name, "");
  ASSERT_TRUE(split->attribute.has_value());
  EXPECT_EQ(split->attribute->length_code, 1);
  EXPECT_EQ(split->attribute->format, SoeDisplayFormat::signed_decimal);
}

TEST_F(SoeClientTest, AWriteAsTheAx5203AnswersIt) {
  answer({{0x04, 0x40, 0x5C, 0x80}});  // opcode 4, elements 64, idn 32860
  auto done = run(soe_write(*mailbox_, 0, 0x805C, wire::kSoeElementValue, {0x3C, 0x0F, 0, 0}));
  ASSERT_TRUE(done.ok()) << done.error().describe();
  EXPECT_EQ(requests()[0], (Bytes{0x03, 0x40, 0x5C, 0x80, 0x3C, 0x0F, 0x00, 0x00}));
  EXPECT_EQ(wire::format_idn(0x805C), "P-0-0092");
}

TEST_F(SoeClientTest, AFragmentedReadIsReassembled) {
  // S-0-0017 in three fragments: fragments left 2, 1, then the last one with the IDN.
  Bytes list = {12,   0,    12,   0,    0x01, 0x00, 0x11, 0x00,
                0x20, 0x00, 0x24, 0x00, 0x28, 0x00, 0x2F, 0x00};
  answer({{0x0A, 0x40, 0x02, 0x00, list[0], list[1], list[2], list[3], list[4], list[5]},
          {0x0A, 0x40, 0x01, 0x00, list[6], list[7], list[8], list[9], list[10], list[11]},
          {0x02, 0x40, 0x11, 0x00, list[12], list[13], list[14], list[15]}});
  auto value = run(soe_read(*mailbox_, 0, 0x0011));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, list);
  EXPECT_EQ(requests().size(), 1u);  // no request between the fragments
  auto idns = decode_soe_idn_list(*value);
  ASSERT_TRUE(idns.ok());
  EXPECT_EQ(*idns, (std::vector<std::uint16_t>{0x01, 0x11, 0x20, 0x24, 0x28, 0x2F}));
}

TEST_F(SoeClientTest, ALostFragmentIsNamed) {
  answer({{0x0A, 0x40, 0x02, 0x00, 1, 2}, {0x02, 0x40, 0x11, 0x00, 3, 4}});
  auto value = run(soe_read(*mailbox_, 0, 0x0011));
  ASSERT_FALSE(value.ok());
  EXPECT_EQ(value.error().code(), Errc::mailbox_error);
  EXPECT_EQ(value.error().message(),
            "SoE read of S-0-0017 (drive 0) of slave 0x1001: the last fragment came as fragment 2 "
            "while 2 more were announced (a fragment was lost)");
  answer({{0x0A, 0x40, 0x03, 0x00, 1, 2}, {0x0A, 0x40, 0x01, 0x00, 3, 4}});
  auto skipped = run(soe_read(*mailbox_, 0, 0x0011));
  ASSERT_FALSE(skipped.ok());
  EXPECT_NE(skipped.error().message().find("fragment 2 says 1 fragments left, expected 2"),
            std::string::npos)
      << skipped.error().message();
}

TEST_F(SoeClientTest, AReassembledReadIsBounded) {
  answer({{0x0A, 0x40, 0x01, 0x00, 1, 2, 3, 4, 5, 6}, {0x02, 0x40, 0x11, 0x00, 7, 8, 9, 10}});
  auto value = run(soe_read(*mailbox_, 0, 0x0011, 0x40, {1s, 8}));
  ASSERT_FALSE(value.ok());
  EXPECT_EQ(value.error().code(), Errc::out_of_range);
  EXPECT_NE(value.error().message().find("exceeds the limit of 8 bytes"), std::string::npos);
}

TEST_F(SoeClientTest, AnErrorResponseNamesTheCode) {
  // Read response with the error flag (0x10), S-0-0291, error code 0x1001 after the header.
  answer({{0x12, 0x40, 0x23, 0x01, 0x01, 0x10}});
  auto value = run(soe_read(*mailbox_, 0, 0x0123));
  ASSERT_FALSE(value.ok());
  EXPECT_EQ(value.error().code(), Errc::mailbox_error);
  EXPECT_EQ(value.error().message(),
            "SoE read of S-0-0291 (drive 0) of slave 0x1001: the drive answered with SoE error "
            "0x1001 (IDN not present)");
  EXPECT_EQ(soe_error_code(value.error()), 0x1001);
  answer({{0x14, 0x40, 0x01, 0x00, 0x05, 0x70}});
  auto refused = run(soe_write(*mailbox_, 0, 0x0001, 0x40, {0xF4, 0x01}));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(soe_error_code(refused.error()), 0x7005);
  EXPECT_NE(refused.error().message().find("operation data is write protected at this time"),
            std::string::npos);
  EXPECT_EQ(soe_error_code(refused.error().context("outer")), 0x7005);
  EXPECT_FALSE(soe_error_code(Error(Errc::mailbox_error, "x").with_value(2)).has_value());
}

TEST_F(SoeClientTest, AResponseForAnotherIdnOrOpcodeFails) {
  answer({{0x02, 0x40, 0x02, 0x00, 0xE8, 0x03}});
  auto other = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().message().find("the response is for S-0-0002, expected S-0-0001"),
            std::string::npos);
  answer({{0x04, 0x40, 0x01, 0x00}});
  auto opcode = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_FALSE(opcode.ok());
  EXPECT_NE(opcode.error().message().find(
                "the drive answered with opcode 4 (write response), expected read response"),
            std::string::npos);
  answer({{0x22, 0x40, 0x01, 0x00, 0xE8, 0x03}});
  auto drive = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_FALSE(drive.ok());
  EXPECT_NE(drive.error().message().find("for drive 1, expected drive 0"), std::string::npos);
  answer({{0x02, 0x20, 0x01, 0x00, 0xE8, 0x03}});
  auto elements = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_FALSE(elements.ok());
  EXPECT_NE(elements.error().message().find("elements 0x20, asked for 0x40"), std::string::npos);
  answer({{0x02, 0x40}});
  auto shorter = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_FALSE(shorter.ok());
  EXPECT_EQ(shorter.error().code(), Errc::malformed);
}

TEST_F(SoeClientTest, NotificationsAreCollectedNotTakenAsReplies) {
  // A notification (opcode 5) of S-0-0127's data state arrives before the read response.
  answer({{0x05, 0x01, 0x7F, 0x00, 0x03, 0x00}, {0x02, 0x40, 0x01, 0x00, 0xE8, 0x03}});
  auto value = run(soe_read(*mailbox_, 0, 0x0001));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, (Bytes{0xE8, 0x03}));
  const auto notifications = soe_notifications(*mailbox_);
  ASSERT_EQ(notifications.size(), 1u);
  EXPECT_EQ(notifications[0],
            (SoeNotification{wire::SoeOpcode::notification, 0, 0x01, 0x7F, false, {0x03, 0x00}}));
  EXPECT_TRUE(soe_notifications(*mailbox_).empty());
}

TEST_F(SoeClientTest, ALargeWriteGoesOutInFragments) {
  // 64-byte mailbox: 58 bytes of mailbox data, 54 after the SoE header.
  Bytes data(120);
  for (std::size_t i = 0; i < data.size(); ++i)
    data[i] = static_cast<std::uint8_t>(i);
  answer({});  // first fragment: no answer
  answer({});
  answer({{0x04, 0x40, 0x10, 0x00}});
  auto done = run(soe_write(*mailbox_, 0, 0x0010, 0x40, data));
  ASSERT_TRUE(done.ok()) << done.error().describe();
  const auto r = requests();
  ASSERT_EQ(r.size(), 3u);
  EXPECT_EQ(Bytes(r[0].begin(), r[0].begin() + 4), (Bytes{0x0B, 0x40, 0x02, 0x00}));
  EXPECT_EQ(Bytes(r[1].begin(), r[1].begin() + 4), (Bytes{0x0B, 0x40, 0x01, 0x00}));
  EXPECT_EQ(Bytes(r[2].begin(), r[2].begin() + 4), (Bytes{0x03, 0x40, 0x10, 0x00}));
  EXPECT_EQ(r[0].size(), 58u);
  EXPECT_EQ(r[1].size(), 58u);
  EXPECT_EQ(r[2].size(), 4u + 12u);
  Bytes joined;
  for (const auto& q : r)
    joined.insert(joined.end(), q.begin() + 4, q.end());
  EXPECT_EQ(joined, data);
}

TEST_F(SoeClientTest, BadArgumentsAndTimeouts) {
  auto drive = run(soe_read(*mailbox_, 8, 0x0001));
  ASSERT_FALSE(drive.ok());
  EXPECT_EQ(drive.error().code(), Errc::invalid_argument);
  auto none = run(soe_read(*mailbox_, 0, 0x0001, 0));
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code(), Errc::invalid_argument);
  auto silent = run(soe_read(*mailbox_, 0, 0x0001, 0x40, {100ms, 1024}));  // no answer scripted
  ASSERT_FALSE(silent.ok());
  EXPECT_EQ(silent.error().code(), Errc::timeout);
}

TEST(SoeElements, AttributeBitsAsSoemLaysThemOut) {
  // conversion factor 1, length 4 bytes (2), signed decimal (2), 3 decimals, protected in
  // SAFEOP and OP.
  const std::uint32_t raw =
      0x0001u | (2u << 16) | (2u << 20) | (3u << 24) | (1u << 29) | (1u << 30);
  const auto a = decode_soe_attribute(raw);
  EXPECT_EQ(a.conversion_factor, 1);
  EXPECT_EQ(a.item_size(), 4u);
  EXPECT_FALSE(a.list);
  EXPECT_FALSE(a.procedure_command);
  EXPECT_EQ(a.format, SoeDisplayFormat::signed_decimal);
  EXPECT_EQ(a.decimals, 3);
  EXPECT_FALSE(a.write_protected_preop);
  EXPECT_TRUE(a.write_protected_safeop);
  EXPECT_TRUE(a.write_protected_op);
  EXPECT_EQ(encode_soe_attribute(a), raw);
  for (std::uint32_t r : {0u, 0x7F7FFFFFu, 0x12345678u & 0x7F7FFFFFu, 0x100C0000u})
    EXPECT_EQ(encode_soe_attribute(decode_soe_attribute(r)), r) << std::hex << r;
  EXPECT_FALSE(decode_soe_attribute(Bytes{1, 2, 3}).ok());
}

TEST(SoeElements, ListsAndStrings) {
  auto list = encode_soe_list({8, {'A', 'x', 'i', 's'}});
  ASSERT_TRUE(list.ok());
  EXPECT_EQ(*list, (Bytes{4, 0, 8, 0, 'A', 'x', 'i', 's'}));
  auto back = decode_soe_list(*list);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, (SoeList{8, {'A', 'x', 'i', 's'}}));
  EXPECT_EQ(*decode_soe_string(*list), "Axis");
  EXPECT_FALSE(encode_soe_list({2, {1, 2, 3}}).ok());
  auto truncated = decode_soe_list(Bytes{9, 0, 9, 0, 1});
  ASSERT_FALSE(truncated.ok());
  EXPECT_EQ(truncated.error().message(),
            "SoE list: actual length 9 exceeds the 1 bytes after the header");
  EXPECT_FALSE(decode_soe_idn_list(Bytes{3, 0, 4, 0, 1, 2, 3}).ok());
  EXPECT_EQ(*decode_soe_idn_list(encode_soe_idn_list({1, 0x8005}, 4)),
            (std::vector<std::uint16_t>{1, 0x8005}));
}

TEST(SoeElements, SplittingByTheAttribute) {
  // name "Pos", attribute 4-byte signed, unit "Incr", min, max, value, default.
  Bytes data = {3, 0, 3, 0, 'P', 'o', 's'};
  const std::uint32_t raw = (2u << 16) | (2u << 20);
  for (int i = 0; i < 4; ++i)
    data.push_back(static_cast<std::uint8_t>(raw >> (8 * i)));
  for (auto b : Bytes{4, 0, 4, 0, 'I', 'n', 'c', 'r'})
    data.push_back(b);
  for (std::int32_t v : {-100, 100, 42, 0})
    for (int i = 0; i < 4; ++i)
      data.push_back(static_cast<std::uint8_t>(static_cast<std::uint32_t>(v) >> (8 * i)));
  auto split = split_soe_elements(0xFE, data);
  ASSERT_TRUE(split.ok()) << split.error().describe();
  EXPECT_EQ(split->name, "Pos");
  EXPECT_EQ(split->unit, "Incr");
  EXPECT_EQ(split->minimum, (Bytes{0x9C, 0xFF, 0xFF, 0xFF}));
  EXPECT_EQ(split->value, (Bytes{42, 0, 0, 0}));
  EXPECT_EQ(split->default_value, (Bytes{0, 0, 0, 0}));
  // Without the attribute only a last data element can be sized.
  EXPECT_TRUE(split_soe_elements(0x42, Bytes{0, 0, 0, 0, 7, 0}).ok());
  auto ambiguous = split_soe_elements(0xC0, Bytes{1, 0, 2, 0});
  ASSERT_FALSE(ambiguous.ok());
  EXPECT_EQ(ambiguous.error().code(), Errc::invalid_argument);
  EXPECT_FALSE(split_soe_elements(0x04, Bytes{1, 2, 3, 4, 5}).ok());  // left over
}

}  // namespace
}  // namespace ecat::master
