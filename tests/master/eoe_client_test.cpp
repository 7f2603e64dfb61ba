// The EoE client against scripted bytes: the simulator's "mailbox" device (a 64-byte mailbox: 58
// data bytes, so 54 bytes of frame after the EoE header and 32 in every fragment but the last)
// with an EoE handler that records each request and answers with byte strings written here, so
// the client is checked against the wire layout itself, not against our own EoE server. The
// layout is ETG.1000.6 §5.7's as SOEM's ethercateoe.h spells it out: word 0 frame type bits 0..3,
// port 4..7, last fragment bit 8, time appended 9, time request 10; word 1 fragment number bits
// 0..5, offset / size in 32-byte blocks bits 6..11, frame number bits 12..15; the Set IP
// Parameter request's "included" flags (MAC 0x01, IP 0x02, subnet 0x04, gateway 0x08, DNS server
// 0x10, DNS name 0x20) followed by the present fields, IPv4 addresses little-endian.
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/eoe.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/eoe.hpp>

#include "master/master_test_support.hpp"
#include "master/scripted_mailbox.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

Bytes frame_of(std::size_t size, std::uint8_t first = 0) {
  Bytes frame(size);
  for (std::size_t i = 0; i < size; ++i)
    frame[i] = static_cast<std::uint8_t>(first + i);
  return frame;
}

Bytes cat(Bytes head, const Bytes& tail) {
  head.insert(head.end(), tail.begin(), tail.end());
  return head;
}

Bytes slice(const Bytes& b, std::size_t from, std::size_t to) {
  return Bytes(b.begin() + static_cast<std::ptrdiff_t>(from),
               b.begin() + static_cast<std::ptrdiff_t>(to));
}

TEST(EoeFragments, ALargeFrameAsTheSpecLaysItOut) {
  const Bytes frame = frame_of(100);
  auto parts = eoe_fragments(frame, 58, 5);
  ASSERT_TRUE(parts.ok()) << parts.error().describe();
  ASSERT_EQ(parts->size(), 3u);
  // Fragment 0: type 0, not last; fragment 0, size (100 + 31) / 32 = 4 blocks, frame 5:
  // word 1 = 0 | 4 << 6 | 5 << 12 = 0x5100.
  EXPECT_EQ((*parts)[0], cat({0x00, 0x00, 0x00, 0x51}, slice(frame, 0, 32)));
  // Fragment 1 at offset 32 bytes = block 1: 1 | 1 << 6 | 5 << 12 = 0x5041.
  EXPECT_EQ((*parts)[1], cat({0x00, 0x00, 0x41, 0x50}, slice(frame, 32, 64)));
  // The last (bit 8 of word 0) at block 2 with the 36 bytes left (up to 54 fit).
  EXPECT_EQ((*parts)[2], cat({0x00, 0x01, 0x82, 0x50}, slice(frame, 64, 100)));
  // A frame that fits whole is one fragment: last, size in blocks, port in bits 4..7.
  auto one = eoe_fragments(frame_of(54), 58, 15, 3);
  ASSERT_TRUE(one.ok());
  ASSERT_EQ(one->size(), 1u);
  EXPECT_EQ(slice((*one)[0], 0, 4), (Bytes{0x30, 0x01, 0x80, 0xF0}));
  // Every encoded fragment decodes back to its fields.
  auto decoded = wire::decode_eoe((*parts)[1]);
  ASSERT_TRUE(decoded.ok());
  const auto& f = std::get<wire::EoeFragment>(*decoded);
  EXPECT_EQ(f.header.fragment_number, 1);
  EXPECT_EQ(f.header.offset_blocks, 1);
  EXPECT_EQ(f.header.frame_number, 5);
  EXPECT_EQ(f.data, slice(frame, 32, 64));
}

TEST(EoeFragments, FramesOutsideEthernetSizesAndTinyMailboxesAreRefused) {
  auto small = eoe_fragments(frame_of(13), 58, 0);
  ASSERT_FALSE(small.ok());
  EXPECT_EQ(small.error().code(), Errc::invalid_argument);
  auto big = eoe_fragments(frame_of(kEoeMaxFrameSize + 1), 58, 0);
  ASSERT_FALSE(big.ok());
  EXPECT_EQ(big.error().code(), Errc::invalid_argument);
  EXPECT_NE(big.error().message().find("1519 bytes"), std::string::npos);
  auto tiny = eoe_fragments(frame_of(60), 35, 0);
  ASSERT_FALSE(tiny.ok());
  EXPECT_EQ(tiny.error().code(), Errc::unsupported);
  // The largest frame in a 64-byte mailbox: 48 blocks announced, 46 fragments of 32 bytes and
  // the last one of 46.
  auto largest = eoe_fragments(frame_of(kEoeMaxFrameSize), 58, 0);
  ASSERT_TRUE(largest.ok());
  ASSERT_EQ(largest->size(), 47u);
  EXPECT_EQ(largest->back().size(), 4u + 46u);
  EXPECT_EQ((*largest)[0][2] | ((*largest)[0][3] << 8), 48 << 6);
}

TEST(EoeReassembly, FragmentsMakeTheFrameAndALostOneDropsIt) {
  const Bytes frame = frame_of(100, 7);
  auto parts = eoe_fragments(frame, 58, 2);
  ASSERT_TRUE(parts.ok());
  ASSERT_EQ(parts->size(), 3u);
  EoeClient client;
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[0])));
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[1])));
  auto done = client.accept(wire::Bytes((*parts)[2]));
  ASSERT_TRUE(done.has_value());
  EXPECT_EQ(*done, frame);
  EXPECT_EQ(client.stats().frames_received, 1u);
  // Fragment 1 lost: fragment 2 does not follow fragment 0, the frame is dropped.
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[0])));
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[2])));
  EXPECT_EQ(client.stats().frames_dropped, 1u);
  // Out of order: 0, 2, 1 -- dropped at 2; 1 then belongs to no open frame.
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[0])));
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[2])));
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[1])));
  EXPECT_EQ(client.stats().frames_dropped, 2u);
  EXPECT_EQ(client.stats().fragments_dropped, 3u);
  // A new frame 0 while one is open drops the open one; the new one completes.
  auto other = eoe_fragments(frame_of(70), 58, 3);
  ASSERT_TRUE(other.ok());
  EXPECT_FALSE(client.accept(wire::Bytes((*parts)[0])));
  for (const auto& p : *other)
    done = client.accept(wire::Bytes(p));
  ASSERT_TRUE(done.has_value());
  EXPECT_EQ(*done, frame_of(70));
  EXPECT_EQ(client.stats().frames_dropped, 3u);
}

TEST(EoeReassembly, OversizeAndShortFramesAreDropped) {
  EoeClient client;
  // Fragment 0 announces 1 block (32 bytes) but the frame grows to 64.
  wire::EoeFragment f;
  f.header.offset_blocks = 1;
  f.data = frame_of(32);
  EXPECT_FALSE(client.accept(f));
  f.header.fragment_number = 1;
  f.header.offset_blocks = 1;
  f.header.last_fragment = true;
  EXPECT_FALSE(client.accept(f));
  EXPECT_EQ(client.stats().frames_dropped, 1u);
  // Announced 63 blocks (2016 bytes): still bounded by kEoeMaxFrameSize.
  EoeClient big;
  f = {};
  f.header.offset_blocks = 63;
  f.data = frame_of(32 * 47);
  EXPECT_FALSE(big.accept(f));
  f.header.fragment_number = 1;
  f.header.offset_blocks = 47;
  f.header.last_fragment = true;
  f.data = frame_of(64);  // 1504 + 64 > 1518
  EXPECT_FALSE(big.accept(f));
  EXPECT_EQ(big.stats().frames_dropped, 1u);
  // A "frame" of 10 bytes is no Ethernet frame.
  f = {};
  f.header.offset_blocks = 1;
  f.header.last_fragment = true;
  f.data = frame_of(10);
  EXPECT_FALSE(client.accept(f));
  EXPECT_EQ(client.stats().frames_dropped, 2u);
  // Garbage and other frame types are counted, not taken.
  EXPECT_FALSE(client.accept(wire::Bytes(Bytes{0x00, 0x01})));
  EXPECT_EQ(client.stats().fragments_dropped, 1u);
  EXPECT_FALSE(client.accept(wire::Bytes(Bytes{0x03, 0x01, 0x00, 0x00})));
  EXPECT_EQ(client.stats().other_dropped, 1u);
}

class EoeClientTest : public test::ScriptedMailboxTest<wire::MailboxType::eoe> {};

TEST_F(EoeClientTest, AFrameGoesOutInFragmentsAndTheAnswerIsReassembled) {
  const Bytes frame = frame_of(100);
  const Bytes reply = frame_of(80, 0x40);
  auto reply_parts = eoe_fragments(reply, 58, 9);
  ASSERT_TRUE(reply_parts.ok());
  answer({});            // fragment 0
  answer({});            // fragment 1
  answer(*reply_parts);  // after the last: the answer frame in three fragments
  EoeClient client;
  auto sent = run(client.send(*mailbox_, frame));
  ASSERT_TRUE(sent.ok()) << sent.error().describe();
  auto expected = eoe_fragments(frame, 58, 0);
  ASSERT_TRUE(expected.ok());
  EXPECT_EQ(requests(), *expected);
  EXPECT_EQ(client.stats().fragments_sent, 3u);
  auto frames = run(client.receive(*mailbox_, 2s));
  ASSERT_TRUE(frames.ok()) << frames.error().describe();
  ASSERT_EQ(frames->size(), 1u);
  EXPECT_EQ(frames->front(), reply);
  // The next frame has the next frame number.
  answer({});
  ASSERT_TRUE(run(client.send(*mailbox_, frame_of(20))).ok());
  EXPECT_EQ(requests().back()[3] >> 4, 1);
  // Nothing more comes: an empty answer in time, not an error.
  auto none = run(client.receive(*mailbox_, 30ms));
  ASSERT_TRUE(none.ok()) << none.error().describe();
  EXPECT_TRUE(none->empty());
}

TEST_F(EoeClientTest, ALostReplyFragmentDropsThatFrameAndTheNextOneArrives) {
  const Bytes reply = frame_of(100, 0x10);
  auto parts = eoe_fragments(reply, 58, 4);
  auto next = eoe_fragments(frame_of(60, 0x80), 58, 5);
  ASSERT_TRUE(parts.ok() && next.ok());
  ASSERT_EQ(parts->size(), 3u);
  // The middle fragment of frame 4 never comes; frame 5 follows whole.
  std::vector<Bytes> answers = {(*parts)[0], (*parts)[2]};
  answers.insert(answers.end(), next->begin(), next->end());
  answer(answers);
  EoeClient client;
  ASSERT_TRUE(run(client.send(*mailbox_, frame_of(20))).ok());
  std::vector<Bytes> got;
  for (int i = 0; i < 20 && got.empty(); ++i) {
    auto frames = run(client.receive(*mailbox_, 100ms));
    ASSERT_TRUE(frames.ok()) << frames.error().describe();
    got = *frames;
  }
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got.front(), frame_of(60, 0x80));
  EXPECT_EQ(client.stats().frames_dropped, 1u);
  EXPECT_EQ(client.stats().frames_received, 1u);
}

TEST_F(EoeClientTest, SetIpParameterAndItsResult) {
  answer({{0x03, 0x01, 0x00, 0x00}});  // set IP parameter response, last fragment, success
  EoeClient client;
  wire::EoeIpParameters p;
  p.ip = 0xC0A80102;
  p.subnet_mask = 0xFFFFFF00;
  auto done = run(client.set_ip(*mailbox_, p, 1s));
  ASSERT_TRUE(done.ok()) << done.error().describe();
  // Type 2 with "last fragment", flags IP | subnet, then both addresses little-endian.
  EXPECT_EQ(requests().at(0), (Bytes{0x02, 0x01, 0x00, 0x00, 0x06, 0x00, 0x00, 0x00, 0x02, 0x01,
                                     0xA8, 0xC0, 0x00, 0xFF, 0xFF, 0xFF}));
  // Refused: the result code 0x0201 (no IP support) in word 1.
  answer({{0x03, 0x01, 0x01, 0x02}});
  auto refused = run(client.set_ip(*mailbox_, p, 1s));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::mailbox_error);
  EXPECT_EQ(eoe_result_code(refused.error()), 0x0201);
  EXPECT_NE(refused.error().message().find("no IP support"), std::string::npos);
  EXPECT_FALSE(eoe_result_code(Error(Errc::mailbox_error, "x").with_value(2)).has_value());
  // No response: a timeout.
  auto silent = run(client.set_ip(*mailbox_, p, 50ms));
  ASSERT_FALSE(silent.ok());
  EXPECT_EQ(silent.error().code(), Errc::timeout);
}

}  // namespace
}  // namespace ecat::master
