#include <cstdint>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/mailbox_gateway.hpp>

namespace ecat::wire {
namespace {

using Vec = std::vector<std::uint8_t>;

// A request as the etherlab-dev "ethercat_mbg" capture shows a configuration tool sending it: an
// SDO upload of 0x80f9:02 from station 0x03e9 (EtherCAT header 0x5010: 16 bytes, type 5).
const Vec kToolRequest = {0x10, 0x50, 0x0a, 0x00, 0xe9, 0x03, 0x00, 0x23, 0x00,
                          0x20, 0x41, 0x80, 0xf9, 0x02, 0x00, 0x00, 0x00, 0x00};

TEST(MailboxGateway, DecodesARequestAsAToolSendsIt) {
  auto message = decode_gateway_message(kToolRequest);
  ASSERT_TRUE(message) << message.error().message();
  EXPECT_EQ(message->header.length, 10);
  EXPECT_EQ(message->header.address, 0x03e9);
  EXPECT_EQ(message->header.type, MailboxType::coe);
  EXPECT_EQ(message->header.counter, 2);
  EXPECT_EQ(message->mailbox.size(), 16u);
  EXPECT_EQ(message->data.size(), 10u);
  EXPECT_EQ(message->data[0], 0x00);
  EXPECT_EQ(message->data[1], 0x20);  // CoE service 2: SDO request
}

TEST(MailboxGateway, EncodesWhatItDecodes) {
  auto message = decode_gateway_message(kToolRequest);
  ASSERT_TRUE(message);
  auto again = encode_gateway_message(message->header, message->data);
  ASSERT_TRUE(again) << again.error().message();
  EXPECT_EQ(*again, kToolRequest);
}

TEST(MailboxGateway, RoundTripsEveryField) {
  MailboxHeader header;
  header.address = 0x1001;
  header.channel = 5;
  header.priority = 2;
  header.type = MailboxType::foe;
  header.counter = 7;
  const Vec data(300, 0xA5);
  auto bytes = encode_gateway_message(header, data);
  ASSERT_TRUE(bytes);
  ASSERT_EQ(bytes->size(), 2u + 6u + 300u);
  EXPECT_EQ((*bytes)[0] | ((*bytes)[1] << 8), 306 | (5 << 12));
  auto decoded = decode_gateway_message(*bytes);
  ASSERT_TRUE(decoded);
  header.length = 300;
  EXPECT_EQ(decoded->header, header);
  EXPECT_EQ(Vec(decoded->data.begin(), decoded->data.end()), data);
}

TEST(MailboxGateway, IgnoresPaddingAfterTheMailbox) {
  Vec padded = kToolRequest;
  padded[0] = 0x14;  // EtherCAT length 20: the mailbox (16) plus 4 bytes of padding
  padded.insert(padded.end(), {0, 0, 0, 0, 0xEE});
  auto message = decode_gateway_message(padded);
  ASSERT_TRUE(message) << message.error().message();
  EXPECT_EQ(message->mailbox.size(), 16u);
}

TEST(MailboxGateway, RefusesWhatIsNotAGatewayMessage) {
  EXPECT_EQ(decode_gateway_message(Vec{}).error().code(), Errc::truncated);
  EXPECT_EQ(decode_gateway_message(Vec{0x10}).error().code(), Errc::truncated);

  Vec datagrams = kToolRequest;
  datagrams[1] = 0x10;  // type 1: an EtherCAT frame of datagrams, not a mailbox
  auto wrong_type = decode_gateway_message(datagrams);
  ASSERT_FALSE(wrong_type);
  EXPECT_EQ(wrong_type.error().code(), Errc::unsupported);
  EXPECT_NE(wrong_type.error().message().find("type is 1"), std::string::npos);

  Vec short_body = kToolRequest;
  short_body.pop_back();  // the EtherCAT length (16) runs past the 15 bytes present
  auto truncated = decode_gateway_message(short_body);
  ASSERT_FALSE(truncated);
  EXPECT_EQ(truncated.error().code(), Errc::truncated);
  EXPECT_NE(truncated.error().message().find("length is 16, only 15"), std::string::npos);

  Vec tiny = {0x04, 0x50, 0, 0, 0, 0};  // EtherCAT length 4: no room for a mailbox header
  EXPECT_EQ(decode_gateway_message(tiny).error().code(), Errc::malformed);

  Vec long_mailbox = kToolRequest;
  long_mailbox[2] = 0x0b;  // the mailbox claims 11 bytes of data, the EtherCAT length has 10
  auto inconsistent = decode_gateway_message(long_mailbox);
  ASSERT_FALSE(inconsistent);
  EXPECT_EQ(inconsistent.error().code(), Errc::malformed);
}

TEST(MailboxGateway, EncoderRefusesWhatTheHeaderCannotCarry) {
  MailboxHeader header;
  auto too_long = encode_gateway_message(header, Vec(kMaxGatewayMailboxSize - 5, 0));
  ASSERT_FALSE(too_long);
  EXPECT_EQ(too_long.error().code(), Errc::invalid_argument);
  EXPECT_TRUE(encode_gateway_message(header, Vec(kMaxGatewayMailboxSize - 6, 0)));

  header.counter = 8;
  EXPECT_EQ(encode_gateway_message(header, Vec{}).error().code(), Errc::invalid_argument);

  Vec small(7);
  EXPECT_EQ(encode_gateway_message(MailboxHeader{}, Vec{}, MutableBytes{small}).error().code(),
            Errc::out_of_range);
}

}  // namespace
}  // namespace ecat::wire
