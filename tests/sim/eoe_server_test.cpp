// The simulator's EoE device (sim/eoe_server.hpp) frame by frame: ARP and ICMP echo answered byte
// for byte, both checksums right (RFC 1071, checked against RFC 1071's own example); everything
// else dropped and counted; the reply fragments laid out as ETG.1000.6 §5.7 says (the same bytes
// the master's fragmenter makes); the master's fragments reassembled, a lost one counted.
#include <cstdint>
#include <span>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/eoe.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/eoe_server.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/eoe.hpp>

namespace ecat::sim {
namespace {

using Bytes = std::vector<std::uint8_t>;

// Device 02:00:0a:ce:00:01 at 192.168.7.2, host 02:11:22:33:44:55 at 192.168.7.1.
constexpr std::uint32_t kDeviceIp = 0xC0A80702;

// ICMP echo request, id 0x1234, sequence 1, data "ecat-eoe"; IPv4 id 0xABCD, DF, TTL 64.
const Bytes kEchoRequest = {0x02, 0x00, 0x0A, 0xCE, 0x00, 0x01, 0x02, 0x11, 0x22, 0x33,
                            0x44, 0x55, 0x08, 0x00, 0x45, 0x00, 0x00, 0x24, 0xAB, 0xCD,
                            0x40, 0x00, 0x40, 0x01, 0xFF, 0xB7, 0xC0, 0xA8, 0x07, 0x01,
                            0xC0, 0xA8, 0x07, 0x02, 0x08, 0x00, 0x82, 0x28, 0x12, 0x34,
                            0x00, 0x01, 0x65, 0x63, 0x61, 0x74, 0x2D, 0x65, 0x6F, 0x65};
// The reply: addresses swapped, flags 0, TTL 64, header checksum 0x3FB8, ICMP type 0 with
// checksum 0x8A28 (0x8228 + 0x0800: only the type changed), padded to 60 bytes.
const Bytes kEchoReply = {0x02, 0x11, 0x22, 0x33, 0x44, 0x55, 0x02, 0x00, 0x0A, 0xCE, 0x00, 0x01,
                          0x08, 0x00, 0x45, 0x00, 0x00, 0x24, 0xAB, 0xCD, 0x00, 0x00, 0x40, 0x01,
                          0x3F, 0xB8, 0xC0, 0xA8, 0x07, 0x02, 0xC0, 0xA8, 0x07, 0x01, 0x00, 0x00,
                          0x8A, 0x28, 0x12, 0x34, 0x00, 0x01, 0x65, 0x63, 0x61, 0x74, 0x2D, 0x65,
                          0x6F, 0x65, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00};

Bytes arp_request(std::uint8_t last_octet) {
  return {0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, 0x11, 0x22, 0x33,      0x44, 0x55,  // Ethernet
          0x08, 0x06,                                                                   // ARP
          0x00, 0x01, 0x08, 0x00, 0x06, 0x04, 0x00, 0x01,              // Ethernet/IPv4, request
          0x02, 0x11, 0x22, 0x33, 0x44, 0x55, 0xC0, 0xA8, 0x07, 0x01,  // sender
          0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xC0, 0xA8, 0x07, last_octet};
}

class EoeServerTest : public ::testing::Test {
 protected:
  EoeServerTest() : coe_(od_), server_(coe_, config()) {}
  static EoeServerConfig config() {
    EoeServerConfig c;
    c.ip = kDeviceIp;
    return c;
  }
  ObjectDictionary od_;
  CoeServer coe_;
  EoeServer server_;
};

TEST(InternetChecksum, Rfc1071Example) {
  // RFC 1071 §3: the words 0001 f203 f4f5 f6f7 sum to 0xddf2, the checksum is its complement.
  const Bytes data = {0x00, 0x01, 0xF2, 0x03, 0xF4, 0xF5, 0xF6, 0xF7};
  EXPECT_EQ(internet_checksum(data), 0x220D);
  EXPECT_EQ(internet_checksum(Bytes{0x01}), 0xFEFF);  // an odd byte padded with zero
}

TEST_F(EoeServerTest, AnArpRequestForItsAddressIsAnswered) {
  auto reply = server_.respond(arp_request(0x02));
  ASSERT_TRUE(reply.has_value());
  const Bytes expected = {0x02, 0x11, 0x22, 0x33, 0x44, 0x55, 0x02, 0x00, 0x0A, 0xCE,
                          0x00, 0x01,  // to the asker
                          0x08, 0x06, 0x00, 0x01, 0x08, 0x00, 0x06, 0x04, 0x00, 0x02,  // ARP reply
                          0x02, 0x00, 0x0A, 0xCE, 0x00, 0x01, 0xC0, 0xA8, 0x07, 0x02,  // us
                          0x02, 0x11, 0x22, 0x33, 0x44, 0x55, 0xC0, 0xA8, 0x07, 0x01,  // the asker
                          0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
                          0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00};  // padded to 60 bytes
  EXPECT_EQ(*reply, expected);
  EXPECT_EQ(server_.stats().arp_replies, 1u);
  EXPECT_FALSE(server_.respond(arp_request(0x03)).has_value());  // someone else's address
  EXPECT_EQ(server_.stats().not_for_us, 1u);
}

TEST_F(EoeServerTest, AnEchoRequestIsAnsweredWithRightChecksums) {
  auto reply = server_.respond(kEchoRequest);
  ASSERT_TRUE(reply.has_value());
  EXPECT_EQ(*reply, kEchoReply);
  const std::span<const std::uint8_t> r(*reply);
  EXPECT_EQ(internet_checksum(r.subspan(14, 20)), 0);
  EXPECT_EQ(internet_checksum(r.subspan(34, 16)), 0);
  EXPECT_EQ(server_.stats().icmp_replies, 1u);
  // Ethernet padding after the IP packet is not echoed back.
  Bytes padded = kEchoRequest;
  padded.resize(60, 0xEE);
  auto again = server_.respond(padded);
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(*again, kEchoReply);
}

TEST_F(EoeServerTest, AnythingElseIsDroppedAndCounted) {
  auto with = [](std::size_t at, std::uint8_t value) {
    Bytes b = kEchoRequest;
    b[at] = value;
    return b;
  };
  EXPECT_FALSE(server_.respond(with(25, 0x00)).has_value());  // IP header checksum wrong
  EXPECT_FALSE(server_.respond(with(37, 0x00)).has_value());  // ICMP checksum wrong
  EXPECT_FALSE(server_.respond(with(17, 0xFF)).has_value());  // total length beyond the frame
  EXPECT_FALSE(server_.respond(Bytes(kEchoRequest.begin(), kEchoRequest.begin() + 20)));
  EXPECT_EQ(server_.stats().malformed, 4u);
  EXPECT_FALSE(server_.respond(with(0, 0x04)).has_value());  // another MAC
  EXPECT_EQ(server_.stats().not_for_us, 1u);
  EXPECT_FALSE(server_.respond(with(13, 0xDD)).has_value());  // IPv6
  // UDP instead of ICMP (the header checksum adjusted: protocol 1 -> 17 adds 0x0010).
  Bytes udp = with(23, 17);
  udp[24] = 0xFF;
  udp[25] = 0xA7;
  EXPECT_FALSE(server_.respond(udp).has_value());
  EXPECT_EQ(server_.stats().unsupported, 2u);
  EXPECT_EQ(server_.stats().icmp_replies, 0u);
  // Without an address nothing is answered.
  EoeServer bare(coe_, EoeServerConfig{});
  EXPECT_FALSE(bare.respond(kEchoRequest).has_value());
  EXPECT_FALSE(bare.respond(arp_request(0x02)).has_value());
  EXPECT_EQ(bare.stats().not_for_us, 2u);
}

TEST_F(EoeServerTest, ReplyFragmentsAreTheMastersLayout) {
  // A 64-byte mailbox carries 58 data bytes: 4 of EoE header, 54 of frame, 32 before the last.
  Bytes frame(100);
  for (std::size_t i = 0; i < frame.size(); ++i)
    frame[i] = static_cast<std::uint8_t>(i);
  auto parts = server_.fragments(frame, 58);
  ASSERT_EQ(parts.size(), 3u);
  // fragment 0: size 4 blocks (bits 6..11 of word 1), frame 0; fragment 1 at block 1; the last
  // one (bit 8 of word 0) at block 2.
  EXPECT_EQ(Bytes(parts[0].begin(), parts[0].begin() + 4), (Bytes{0x00, 0x00, 0x00, 0x01}));
  EXPECT_EQ(Bytes(parts[1].begin(), parts[1].begin() + 4), (Bytes{0x00, 0x00, 0x41, 0x00}));
  EXPECT_EQ(Bytes(parts[2].begin(), parts[2].begin() + 4), (Bytes{0x00, 0x01, 0x82, 0x00}));
  EXPECT_EQ(parts[0].size(), 36u);
  EXPECT_EQ(parts[2].size(), 40u);
  auto same = master::eoe_fragments(frame, 58, 0);
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(*same, parts);
  // The next frame has frame number 1 (bits 12..15).
  auto next = server_.fragments(frame, 58);
  ASSERT_EQ(next.size(), 3u);
  EXPECT_EQ(next[0][3], 0x11);
  // The master's reassembly takes them back.
  master::EoeClient client;
  std::optional<Bytes> out;
  for (const auto& p : next)
    out = client.accept(wire::Bytes(p));
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(*out, frame);
}

}  // namespace
}  // namespace ecat::sim
