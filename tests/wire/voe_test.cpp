// The VoE header (ETG.1000.6 §5.10: vendor id u32, vendor type u16, little-endian): round trips,
// bytes as laid out on the wire, truncated input, the length limit, and the mailbox summary.
#include <cstdint>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/mailbox_summary.hpp>
#include <ecat/wire/voe.hpp>

namespace ecat::wire {
namespace {

using Bytes = std::vector<std::uint8_t>;

TEST(Voe, HeaderBytesAndRoundTrip) {
  const VoeMessage message{{0x00000002, 0x1234}, {0xDE, 0xAD}};
  auto bytes = encode_voe(message);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, (Bytes{0x02, 0x00, 0x00, 0x00, 0x34, 0x12, 0xDE, 0xAD}));
  auto back = decode_voe(*bytes);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, message);
  for (const VoeMessage& m : {VoeMessage{}, VoeMessage{{0xFFFFFFFF, 0xFFFF}, Bytes(1000, 7)}}) {
    auto e = encode_voe(m);
    ASSERT_TRUE(e.ok());
    auto d = decode_voe(*e);
    ASSERT_TRUE(d.ok());
    EXPECT_EQ(*d, m);
  }
  std::uint8_t buf[6];
  ByteWriter w(buf);
  ASSERT_TRUE(encode_voe_header({0x00000ACE, 0x0011}, w).ok());
  auto header = decode_voe_header(Bytes(buf, buf + 6));
  ASSERT_TRUE(header.ok());
  EXPECT_EQ(*header, (VoeHeader{0x00000ACE, 0x0011}));
  std::uint8_t small[5];
  ByteWriter tight(small);
  EXPECT_FALSE(encode_voe_header({}, tight).ok());
}

TEST(Voe, TruncatedHeadersNameTheField) {
  auto short_id = decode_voe(Bytes{1, 2, 3});
  ASSERT_FALSE(short_id.ok());
  EXPECT_EQ(short_id.error().code(), Errc::truncated);
  EXPECT_EQ(short_id.error().message(),
            "VoE header: vendor id at offset 0 needs 4 bytes, 3 remain");
  auto short_type = decode_voe(Bytes{1, 2, 3, 4, 5});
  ASSERT_FALSE(short_type.ok());
  EXPECT_EQ(short_type.error().message(),
            "VoE header: vendor type at offset 4 needs 2 bytes, 1 remains");
}

TEST(Voe, TheMailboxLengthLimit) {
  EXPECT_TRUE(encode_voe({{}, Bytes(65535 - 6, 0)}).ok());
  auto too_long = encode_voe({{}, Bytes(65535 - 5, 0)});
  ASSERT_FALSE(too_long.ok());
  EXPECT_EQ(too_long.error().code(), Errc::invalid_argument);
}

TEST(Voe, Summary) {
  auto data = encode_voe({{0x00000ACE, 0x0011}, {1, 2, 3}});
  ASSERT_TRUE(data.ok());
  MailboxHeader header;
  header.type = MailboxType::voe;
  header.counter = 2;
  auto mailbox = encode_mailbox(header, *data);
  ASSERT_TRUE(mailbox.ok());
  const auto text = summarize_mailbox(*mailbox);
  EXPECT_EQ(text.rfind("mbx VoE cnt=2 vendor=0x00000ace type=0x0011", 0), 0u) << text;
  auto broken = encode_mailbox(header, Bytes{1, 2});
  ASSERT_TRUE(broken.ok());
  EXPECT_NE(summarize_mailbox(*broken).find("VoE header"), std::string::npos)
      << summarize_mailbox(*broken);
}

}  // namespace
}  // namespace ecat::wire
