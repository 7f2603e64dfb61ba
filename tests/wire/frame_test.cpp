#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <new>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/frame.hpp>

#include "support/counting_allocator.hpp"
#include "support/shared_data.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::wire {
namespace {

using ByteVector = std::vector<std::uint8_t>;

constexpr std::array kAllCommands{
    Command::nop,  Command::aprd, Command::apwr, Command::aprw, Command::fprd,
    Command::fpwr, Command::fprw, Command::brd,  Command::bwr,  Command::brw,
    Command::lrd,  Command::lwr,  Command::lrw,  Command::armw, Command::frmw,
};

ByteVector pattern(std::size_t n, std::uint8_t seed) {
  ByteVector v(n);
  for (std::size_t i = 0; i < n; ++i)
    v[i] = static_cast<std::uint8_t>(seed + i * 7);
  return v;
}

std::vector<DatagramView> collect(const FrameView& frame) {
  std::vector<DatagramView> out;
  for (auto datagram : frame)
    out.push_back(datagram);
  return out;
}

// Raw datagram bytes, for frames the builder would refuse to make.
void put_datagram(ByteVector& out, std::uint8_t cmd, std::uint16_t length_field,
                  const ByteVector& data, std::uint16_t wkc = 0) {
  out.push_back(cmd);
  out.push_back(0);
  for (int i = 0; i < 4; ++i)
    out.push_back(0);
  out.push_back(static_cast<std::uint8_t>(length_field));
  out.push_back(static_cast<std::uint8_t>(length_field >> 8));
  out.push_back(0);
  out.push_back(0);
  out.insert(out.end(), data.begin(), data.end());
  out.push_back(static_cast<std::uint8_t>(wkc));
  out.push_back(static_cast<std::uint8_t>(wkc >> 8));
}

ByteVector frame_with_header(std::uint16_t header) {
  return ByteVector{static_cast<std::uint8_t>(header), static_cast<std::uint8_t>(header >> 8)};
}

DecodeError decode_error(const ByteVector& bytes) {
  auto result = decode_frame(bytes);
  EXPECT_FALSE(result) << "frame unexpectedly decoded";
  return result.error;
}

// ---------------------------------------------------------------------------------------------
// Commands

TEST(Command, NamesAndBytes) {
  const char* names[] = {"NOP", "APRD", "APWR", "APRW", "FPRD", "FPWR", "FPRW", "BRD",
                         "BWR", "BRW",  "LRD",  "LWR",  "LRW",  "ARMW", "FRMW"};
  for (std::size_t i = 0; i < kCommandCount; ++i) {
    EXPECT_EQ(to_string(kAllCommands[i]), names[i]);
    auto command = command_from_byte(static_cast<std::uint8_t>(i));
    ASSERT_TRUE(command.has_value());
    EXPECT_EQ(*command, kAllCommands[i]);
  }
  EXPECT_FALSE(command_from_byte(15).has_value());
  EXPECT_FALSE(command_from_byte(0xFF).has_value());
}

TEST(Command, Addressing) {
  EXPECT_EQ(addressing_of(Command::nop), Addressing::none);
  for (auto c : {Command::aprd, Command::apwr, Command::aprw, Command::armw})
    EXPECT_EQ(addressing_of(c), Addressing::position) << to_string(c);
  for (auto c : {Command::fprd, Command::fpwr, Command::fprw, Command::frmw})
    EXPECT_EQ(addressing_of(c), Addressing::station) << to_string(c);
  for (auto c : {Command::brd, Command::bwr, Command::brw})
    EXPECT_EQ(addressing_of(c), Addressing::broadcast) << to_string(c);
  for (auto c : {Command::lrd, Command::lwr, Command::lrw})
    EXPECT_EQ(addressing_of(c), Addressing::logical) << to_string(c);
}

TEST(Command, DataDirection) {
  // {reads, writes} per command, in command order.
  const std::pair<bool, bool> expected[] = {
      {false, false},                               // NOP
      {true, false},  {false, true}, {true, true},  // APRD APWR APRW
      {true, false},  {false, true}, {true, true},  // FPRD FPWR FPRW
      {true, false},  {false, true}, {true, true},  // BRD BWR BRW
      {true, false},  {false, true}, {true, true},  // LRD LWR LRW
      {true, true},   {true, true},                 // ARMW FRMW
  };
  for (std::size_t i = 0; i < kCommandCount; ++i) {
    EXPECT_EQ(command_reads(kAllCommands[i]), expected[i].first) << to_string(kAllCommands[i]);
    EXPECT_EQ(command_writes(kAllCommands[i]), expected[i].second) << to_string(kAllCommands[i]);
  }
}

TEST(Address, Helpers) {
  EXPECT_EQ(physical_address(0x1001, 0x0130), 0x01301001u);
  EXPECT_EQ(position_adp(0), 0x0000);
  EXPECT_EQ(position_adp(1), 0xFFFF);
  EXPECT_EQ(position_adp(3), 0xFFFD);
  DatagramHeader header;
  header.address = 0x01301001;
  EXPECT_EQ(header.adp(), 0x1001);
  EXPECT_EQ(header.ado(), 0x0130);
}

// ---------------------------------------------------------------------------------------------
// Encoding

TEST(FrameBuilder, EncodesExactBytes) {
  std::array<std::uint8_t, 64> buffer{};
  FrameBuilder builder(buffer);
  DatagramHeader header{Command::fprd, 0x12, physical_address(0x1001, 0x0130), 2};
  auto area = builder.add(header, ByteVector{0xAA, 0xBB}, 0x0102);
  ASSERT_TRUE(area.has_value());
  EXPECT_EQ(area->size(), 2u);
  EXPECT_EQ(area->data(), buffer.data() + 12);
  DatagramHeader second{Command::brd, 0x13, 0, 1, /*circulating=*/true, false, 0xBEEF};
  ASSERT_TRUE(builder.add(second).has_value());
  EXPECT_EQ(builder.datagram_count(), 2u);
  EXPECT_EQ(builder.size(), 2u + 14 + 13);
  auto frame = builder.finish();
  const ByteVector expected{
      0x1B, 0x10,                                      // header: length 27, type 1
      0x04, 0x12, 0x01, 0x10, 0x30, 0x01,              // FPRD idx 0x12 adp 0x1001 ado 0x0130
      0x02, 0x80, 0x00, 0x00, 0xAA, 0xBB, 0x02, 0x01,  // len 2 + more-follows, irq 0, data, wkc
      0x07, 0x13, 0x00, 0x00, 0x00, 0x00,              // BRD idx 0x13 address 0
      0x01, 0x40, 0xEF, 0xBE, 0x00, 0x00, 0x00,  // len 1 + circulating, irq 0xBEEF, data 0, wkc 0
  };
  EXPECT_EQ(ByteVector(frame.begin(), frame.end()), expected);
}

TEST(FrameBuilder, RoundTripsEveryCommand) {
  for (std::size_t i = 0; i < kCommandCount; ++i) {
    std::array<std::uint8_t, 128> buffer{};
    FrameBuilder builder(buffer);
    DatagramHeader header{kAllCommands[i], static_cast<std::uint8_t>(0x80 + i),
                          0xA5000000u + static_cast<std::uint32_t>(i),
                          static_cast<std::uint16_t>(i + 1)};
    header.circulating = (i % 2) == 1;
    header.irq = static_cast<std::uint16_t>(0x1000 + i);
    const auto data = pattern(i + 1, static_cast<std::uint8_t>(i));
    ASSERT_TRUE(builder.add(header, data, static_cast<std::uint16_t>(i * 3)));
    auto decoded = decode_frame(builder.finish());
    ASSERT_TRUE(decoded) << decoded.error.describe();
    auto datagrams = collect(*decoded.frame);
    ASSERT_EQ(datagrams.size(), 1u);
    EXPECT_EQ(datagrams[0].header, header) << to_string(kAllCommands[i]);
    EXPECT_EQ(ByteVector(datagrams[0].data.begin(), datagrams[0].data.end()), data);
    EXPECT_EQ(datagrams[0].wkc, i * 3);
  }
}

TEST(FrameBuilder, RoundTripsManyDatagrams) {
  std::array<std::uint8_t, kMaxFrameSize> buffer{};
  FrameBuilder builder(buffer);
  std::vector<DatagramHeader> headers;
  std::vector<ByteVector> payloads;
  for (std::size_t i = 0; i < 60; ++i) {
    DatagramHeader header{kAllCommands[i % kCommandCount], static_cast<std::uint8_t>(i),
                          static_cast<std::uint32_t>(i * 0x01010101u),
                          static_cast<std::uint16_t>(i % 13)};
    header.circulating = (i % 5) == 0;
    header.irq = static_cast<std::uint16_t>(i << 4);
    payloads.push_back(pattern(header.length, static_cast<std::uint8_t>(i)));
    ASSERT_TRUE(builder.add(header, payloads.back(), static_cast<std::uint16_t>(i)));
    headers.push_back(header);
  }
  auto encoded = builder.finish();
  auto decoded = decode_frame(encoded);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_EQ(decoded.frame->header_length(), encoded.size() - 2);
  EXPECT_EQ(decoded.frame->datagram_count(), 60u);
  EXPECT_EQ(decoded.frame->body().size(), encoded.size() - 2);
  auto datagrams = collect(*decoded.frame);
  ASSERT_EQ(datagrams.size(), 60u);
  for (std::size_t i = 0; i < datagrams.size(); ++i) {
    auto expected = headers[i];
    expected.more_follows = i + 1 < datagrams.size();
    EXPECT_EQ(datagrams[i].header, expected) << "datagram " << i;
    EXPECT_EQ(ByteVector(datagrams[i].data.begin(), datagrams[i].data.end()), payloads[i]);
    EXPECT_EQ(datagrams[i].wkc, i);
  }
}

TEST(FrameBuilder, AddZeroFillsWithoutData) {
  std::array<std::uint8_t, 64> buffer;
  buffer.fill(0xEE);
  FrameBuilder builder(buffer);
  auto area = builder.add({Command::lrw, 1, 0x10000, 8});
  ASSERT_TRUE(area.has_value());
  for (auto byte : *area)
    EXPECT_EQ(byte, 0);
  (*area)[3] = 0x42;
  auto decoded = decode_frame(builder.finish());
  ASSERT_TRUE(decoded);
  EXPECT_EQ((*decoded.frame->begin()).data[3], 0x42);
}

TEST(FrameBuilder, RefusesWhatDoesNotFit) {
  std::array<std::uint8_t, 40> buffer{};
  FrameBuilder builder(buffer);
  EXPECT_TRUE(builder.fits(26));  // 2 + 12 + 26 = 40
  EXPECT_FALSE(builder.fits(27));
  EXPECT_FALSE(builder.add({Command::fprd, 0, 0, 27}).has_value());
  EXPECT_EQ(builder.size(), 2u);
  EXPECT_EQ(builder.datagram_count(), 0u);
  ASSERT_TRUE(builder.add({Command::fprd, 0, 0, 10}).has_value());  // 24 bytes used
  EXPECT_TRUE(builder.fits(4));
  EXPECT_FALSE(builder.fits(5));
  EXPECT_FALSE(builder.add({Command::fprd, 1, 0, 5}).has_value());
  EXPECT_EQ(builder.size(), 24u);
  EXPECT_EQ(builder.datagram_count(), 1u);
  // A refused add leaves the frame as it was: the first datagram is still the last one.
  auto decoded = decode_frame(builder.finish());
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_FALSE((*decoded.frame->begin()).header.more_follows);
}

TEST(FrameBuilder, RefusesBadArguments) {
  std::array<std::uint8_t, 4096> buffer{};
  FrameBuilder builder(buffer);
  EXPECT_FALSE(builder.add({Command::fprd, 0, 0, 0x800}).has_value());  // beyond 11 bits
  EXPECT_FALSE(builder.fits(0x800));
  EXPECT_FALSE(builder.add({Command::fprd, 0, 0, 4}, ByteVector{1, 2, 3}).has_value());
  EXPECT_FALSE(builder.add({static_cast<Command>(15), 0, 0, 4}).has_value());
  EXPECT_TRUE(builder.empty());
}

TEST(FrameBuilder, EnforcesElevenBitFrameLength) {
  // Even with room in the buffer, the datagram bytes must fit the 11-bit header length.
  std::array<std::uint8_t, 4096> buffer{};
  FrameBuilder builder(buffer);
  EXPECT_FALSE(builder.fits(kMaxDatagramLength));  // 12 + 2047 > 2047
  EXPECT_FALSE(builder.fits(0x7FF - 11));
  EXPECT_TRUE(builder.fits(0x7FF - 12));
  ASSERT_TRUE(builder.add({Command::lrw, 0, 0, 0x7FF - 12}).has_value());
  EXPECT_FALSE(builder.fits(0));
  auto frame = builder.finish();
  EXPECT_EQ(frame.size(), 2u + 0x7FF);
  EXPECT_EQ(load_le16(frame.data()), 0x17FF);
  auto decoded = decode_frame(frame);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_EQ(decoded.frame->header_length(), 0x7FF);
}

TEST(FrameBuilder, MaxSizeFrameFillsTheMtu) {
  std::array<std::uint8_t, kMaxFrameSize> buffer{};
  FrameBuilder builder(buffer);
  EXPECT_EQ(kMaxSingleDatagramData, 1486u);
  EXPECT_FALSE(builder.fits(kMaxSingleDatagramData + 1));
  const auto data = pattern(kMaxSingleDatagramData, 9);
  ASSERT_TRUE(builder.add({Command::lrw, 7, 0x00010000, kMaxSingleDatagramData}, data, 3));
  EXPECT_FALSE(builder.fits(0));
  auto frame = builder.finish();
  ASSERT_EQ(frame.size(), kMaxFrameSize);

  std::array<std::uint8_t, kEthernetHeaderSize + kMaxFrameSize> wire{};
  auto ethernet =
      encode_ethernet({kBroadcastMac, {2, 0, 0, 0, 0, 1}, {}, kEtherTypeEtherCat}, frame, wire);
  ASSERT_EQ(ethernet.size(), 1514u);
  auto outer = decode_ethernet(ethernet);
  ASSERT_TRUE(outer);
  auto decoded = decode_frame(outer.frame->payload);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  auto datagram = *decoded.frame->begin();
  EXPECT_EQ(ByteVector(datagram.data.begin(), datagram.data.end()), data);
  EXPECT_EQ(datagram.wkc, 3);
}

TEST(FrameBuilder, ResetStartsOver) {
  std::array<std::uint8_t, 66> buffer{};
  FrameBuilder builder(buffer);
  ASSERT_TRUE(builder.add({Command::bwr, 1, 0, 20}));
  ASSERT_TRUE(builder.add({Command::bwr, 2, 0, 20}));
  EXPECT_FALSE(builder.fits(20));
  builder.reset();
  EXPECT_TRUE(builder.empty());
  EXPECT_EQ(builder.size(), 2u);
  ASSERT_TRUE(builder.add({Command::brd, 3, 0, 1}));
  auto decoded = decode_frame(builder.finish());
  ASSERT_TRUE(decoded) << decoded.error.describe();
  auto datagrams = collect(*decoded.frame);
  ASSERT_EQ(datagrams.size(), 1u);
  EXPECT_EQ(datagrams[0].header.index, 3);
  EXPECT_FALSE(datagrams[0].header.more_follows);
}

TEST(FrameBuilder, FinishOnEmptyBuilderGivesAnEmptyFrame) {
  std::array<std::uint8_t, 16> buffer{};
  FrameBuilder builder(buffer);
  auto frame = builder.finish();
  EXPECT_EQ(ByteVector(frame.begin(), frame.end()), (ByteVector{0x00, 0x10}));
  EXPECT_EQ(decode_frame(frame).error.code, DecodeErrc::empty_frame);

  std::array<std::uint8_t, 1> tiny{};
  FrameBuilder no_room(tiny);
  EXPECT_FALSE(no_room.fits(0));
  EXPECT_TRUE(no_room.finish().empty());
}

// ---------------------------------------------------------------------------------------------
// Decoding: accepted variations

TEST(DecodeFrame, IgnoresTrailingPadding) {
  std::array<std::uint8_t, 64> buffer{};
  FrameBuilder builder(buffer);
  ASSERT_TRUE(builder.add({Command::brd, 0, 0, 2}, ByteVector{1, 2}, 5));
  auto frame = builder.finish();
  ByteVector padded(frame.begin(), frame.end());
  padded.resize(46, 0xCC);  // padding need not be zero
  auto decoded = decode_frame(padded);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_EQ(decoded.frame->header_length(), 14);
  EXPECT_EQ(decoded.frame->body().size(), 14u);
  EXPECT_EQ(decoded.frame->body().data(), padded.data() + 2);
  EXPECT_EQ((*decoded.frame->begin()).wkc, 5);
}

TEST(DecodeFrame, AcceptsZeroPaddingCountedInTheHeaderLength) {
  // As sent by a real master: header length 28 for a 13-byte chain followed by zeros.
  ByteVector bytes = frame_with_header(0x1000 | 28);
  put_datagram(bytes, 7, 1, {0x13}, 3);
  bytes.resize(30, 0);
  auto decoded = decode_frame(bytes);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_EQ(decoded.frame->header_length(), 28);
  EXPECT_EQ(decoded.frame->body().size(), 13u);
  EXPECT_EQ(decoded.frame->datagram_count(), 1u);
  auto datagram = *decoded.frame->begin();
  EXPECT_EQ(datagram.header.command, Command::brd);
  EXPECT_EQ(datagram.wkc, 3);
}

TEST(DecodeFrame, IgnoresReservedBits) {
  ByteVector bytes = frame_with_header(0x1000 | 0x0800 | 14);
  put_datagram(bytes, 4, 0x3800 | 2, {9, 8}, 1);
  auto decoded = decode_frame(bytes);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  EXPECT_EQ(decoded.frame->header_length(), 14);
  auto datagram = *decoded.frame->begin();
  EXPECT_EQ(datagram.header.length, 2);
  EXPECT_FALSE(datagram.header.circulating);
  EXPECT_FALSE(datagram.header.more_follows);
  EXPECT_EQ(datagram.wkc, 1);
}

TEST(DecodeFrame, DecodesCirculatingAndIrq) {
  ByteVector bytes = frame_with_header(0x1000 | 12);
  put_datagram(bytes, 8, 0x4000, {}, 0);
  bytes[10] = 0x34;
  bytes[11] = 0x12;
  auto decoded = decode_frame(bytes);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  auto datagram = *decoded.frame->begin();
  EXPECT_TRUE(datagram.header.circulating);
  EXPECT_EQ(datagram.header.irq, 0x1234);
  EXPECT_EQ(datagram.header.length, 0);
  EXPECT_TRUE(datagram.data.empty());
}

TEST(DecodeFrame, IterationAllocatesNothing) {
  std::array<std::uint8_t, kMaxFrameSize> buffer{};
  FrameBuilder builder(buffer);
  for (std::uint8_t i = 0; i < 40; ++i) {
    ASSERT_TRUE(builder.add({Command::fprd, i, physical_address(0x1000 + i, 0x130), 2}));
  }
  auto frame = builder.finish();

  const std::size_t before = allocs::total.load();
  auto decoded = decode_frame(frame);
  std::size_t count = 0;
  std::uint32_t sum = 0;
  if (decoded) {
    for (auto datagram : *decoded.frame) {
      ++count;
      sum += datagram.header.index + datagram.wkc + datagram.data.size();
    }
  }
  auto failed = decode_frame(Bytes(frame.data(), 7));  // the error path allocates nothing either
  const std::size_t after = allocs::total.load();

  EXPECT_EQ(after - before, 0u);
  ASSERT_TRUE(decoded);
  EXPECT_FALSE(failed);
  EXPECT_EQ(count, 40u);
  EXPECT_EQ(sum, 780u + 80u);
  // The counter is live: this test would see an allocation.
  auto* probe = new int(1);
  EXPECT_GT(allocs::total.load(), after);
  delete probe;
}

TEST(DecodeFrame, IteratorsCompareAndAdvance) {
  std::array<std::uint8_t, 64> buffer{};
  FrameBuilder builder(buffer);
  ASSERT_TRUE(builder.add({Command::aprd, 1, 0, 1}));
  ASSERT_TRUE(builder.add({Command::aprd, 2, 0, 2}));
  auto decoded = decode_frame(builder.finish());
  ASSERT_TRUE(decoded);
  auto it = decoded.frame->begin();
  EXPECT_NE(it, decoded.frame->end());
  auto old = it++;
  EXPECT_EQ((*old).header.index, 1);
  EXPECT_EQ((*it).header.index, 2);
  ++it;
  EXPECT_EQ(it, decoded.frame->end());
  ++it;  // advancing past the end stays at the end
  EXPECT_EQ(it, decoded.frame->end());
  EXPECT_EQ((*it).header.length, 0);  // and dereferencing it reads nothing

  FrameView empty;
  EXPECT_EQ(empty.begin(), empty.end());
}

// ---------------------------------------------------------------------------------------------
// Decoding: every rejection, with its numbers

TEST(DecodeFrameError, TruncatedFrameHeader) {
  auto error = decode_error(ByteVector{0x0E});
  EXPECT_EQ(error.code, DecodeErrc::truncated_frame_header);
  EXPECT_EQ(error.offset, 0u);
  EXPECT_EQ(error.expected, 2u);
  EXPECT_EQ(error.actual, 1u);
  EXPECT_EQ(error.describe(), "EtherCAT frame header truncated: 2 bytes needed, 1 present");
  EXPECT_EQ(error.to_error().code(), Errc::truncated);
  EXPECT_EQ(decode_error(ByteVector{}).actual, 0u);
}

TEST(DecodeFrameError, UnsupportedFrameType) {
  ByteVector bytes = frame_with_header(0x4000 | 12);
  put_datagram(bytes, 7, 0, {});
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::unsupported_frame_type);
  EXPECT_EQ(error.expected, 1u);
  EXPECT_EQ(error.actual, 4u);
  EXPECT_EQ(error.describe(),
            "EtherCAT frame header at byte 0: type 4 is not supported (expected 1, datagrams)");
  EXPECT_EQ(error.to_error().code(), Errc::malformed);
}

TEST(DecodeFrameError, EmptyFrame) {
  ByteVector bytes = frame_with_header(0x1000);
  bytes.resize(46, 0);
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::empty_frame);
  EXPECT_EQ(error.actual, 0u);
  EXPECT_EQ(error.expected, 12u);
  EXPECT_EQ(error.to_error().code(), Errc::malformed);
}

TEST(DecodeFrameError, HeaderLengthBeyondBytesPresent) {
  ByteVector bytes = frame_with_header(0x1000 | 40);
  put_datagram(bytes, 7, 8, pattern(8, 1));  // 20 bytes present after the header
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::frame_length_mismatch);
  EXPECT_EQ(error.offset, 0u);
  EXPECT_EQ(error.expected, 20u);
  EXPECT_EQ(error.actual, 40u);
  EXPECT_EQ(error.describe(),
            "EtherCAT frame header length 40 exceeds the 20 bytes present after the header");
  EXPECT_EQ(error.to_error().code(), Errc::malformed);
}

TEST(DecodeFrameError, ChainEndsAfterHeaderLength) {
  ByteVector bytes = frame_with_header(0x1000 | 20);
  put_datagram(bytes, 4, 0x8000 | 2, {1, 2});  // bytes 2..16
  put_datagram(bytes, 4, 4, {1, 2, 3, 4});     // bytes 16..32, header says the frame ends at 22
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::frame_length_mismatch);
  EXPECT_EQ(error.datagram, 1u);
  EXPECT_EQ(error.offset, 16u);
  EXPECT_EQ(error.expected, 20u);
  EXPECT_EQ(error.actual, 30u);
  EXPECT_EQ(error.describe(),
            "datagram 1 at byte 16: the datagram chain runs to 30 bytes, past the frame header "
            "length 20");
}

TEST(DecodeFrameError, ChainEndsBeforeHeaderLength) {
  ByteVector bytes = frame_with_header(0x1000 | 20);
  put_datagram(bytes, 4, 2, {1, 2});  // chain of 14 bytes ends at byte 16
  bytes.resize(22, 0);
  bytes[19] = 0x04;  // looks like a datagram whose more-follows bit went missing
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::frame_length_mismatch);
  EXPECT_EQ(error.datagram, 0u);
  EXPECT_EQ(error.offset, 19u);
  EXPECT_EQ(error.expected, 20u);
  EXPECT_EQ(error.actual, 14u);
  EXPECT_EQ(error.describe(),
            "datagram chain ends after datagram 0 at 14 bytes but the frame header length is 20 "
            "(byte 19 is neither a datagram nor zero padding)");
}

TEST(DecodeFrameError, TruncatedDatagramHeader) {
  ByteVector bytes = frame_with_header(0x1000 | 18);
  put_datagram(bytes, 4, 0x8000 | 2, {1, 2});
  bytes.insert(bytes.end(), {5, 0, 0, 0});  // 4 of the 10 header bytes of datagram 1
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::truncated_datagram_header);
  EXPECT_EQ(error.datagram, 1u);
  EXPECT_EQ(error.offset, 16u);
  EXPECT_EQ(error.expected, 10u);
  EXPECT_EQ(error.actual, 4u);
  EXPECT_EQ(error.describe(),
            "datagram 1 at byte 16: datagram header needs 10 bytes, 4 left in the frame");
  EXPECT_EQ(error.to_error().code(), Errc::truncated);

  ByteVector short_frame = frame_with_header(0x1000 | 5);
  short_frame.insert(short_frame.end(), {4, 0, 0, 0, 0});
  auto first = decode_error(short_frame);
  EXPECT_EQ(first.code, DecodeErrc::truncated_datagram_header);
  EXPECT_EQ(first.datagram, 0u);
  EXPECT_EQ(first.offset, 2u);
  EXPECT_EQ(first.actual, 5u);
}

TEST(DecodeFrameError, TruncatedDatagram) {
  ByteVector bytes = frame_with_header(0x1000 | 58);
  put_datagram(bytes, 4, 0x8000 | 10, pattern(10, 0));  // bytes 2..24
  put_datagram(bytes, 0, 0x8000 | 0, {});               // bytes 24..36
  put_datagram(bytes, 5, 40, pattern(40, 3));           // starts at 36: needs 52 bytes
  bytes.resize(60);                                     // 14 bytes after its header
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::truncated_datagram);
  EXPECT_EQ(error.datagram, 2u);
  EXPECT_EQ(error.offset, 36u);
  EXPECT_EQ(error.expected, 40u);
  EXPECT_EQ(error.actual, 14u);
  EXPECT_EQ(error.describe(),
            "datagram 2 at byte 36: length 40 runs past the end of the frame (14 bytes left for "
            "data and WKC)");
  EXPECT_EQ(error.to_error().code(), Errc::truncated);
  EXPECT_EQ(error.to_error().message(), error.describe());
}

TEST(DecodeFrameError, TruncatedWorkingCounter) {
  ByteVector bytes = frame_with_header(0x1000 | 13);
  put_datagram(bytes, 4, 2, {1, 2});
  bytes.resize(15);  // data complete, one WKC byte missing
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::truncated_datagram);
  EXPECT_EQ(error.offset, 2u);
  EXPECT_EQ(error.expected, 2u);
  EXPECT_EQ(error.actual, 3u);
}

TEST(DecodeFrameError, MoreFollowsOnTheLastDatagram) {
  ByteVector bytes = frame_with_header(0x1000 | 28);
  put_datagram(bytes, 7, 0x8000 | 2, {0, 0});  // bytes 2..16
  put_datagram(bytes, 8, 0x8000 | 2, {0, 0});  // bytes 16..30: ends the frame, says more follows
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::more_follows_past_end);
  EXPECT_EQ(error.datagram, 1u);
  EXPECT_EQ(error.offset, 16u);
  EXPECT_EQ(error.expected, 30u);
  EXPECT_EQ(error.describe(),
            "datagram 1 at byte 16: more-follows is set but the frame ends after this datagram "
            "(at byte 30)");
  EXPECT_EQ(error.to_error().code(), Errc::truncated);

  // Same with Ethernet padding behind it: padding is never read as a datagram.
  bytes.resize(46, 0);
  EXPECT_EQ(decode_error(bytes).code, DecodeErrc::more_follows_past_end);
}

TEST(DecodeFrameError, UnknownCommand) {
  ByteVector bytes = frame_with_header(0x1000 | 28);
  put_datagram(bytes, 7, 0x8000 | 2, {0, 0});
  put_datagram(bytes, 0x1F, 2, {0, 0});
  auto error = decode_error(bytes);
  EXPECT_EQ(error.code, DecodeErrc::unknown_command);
  EXPECT_EQ(error.datagram, 1u);
  EXPECT_EQ(error.offset, 16u);
  EXPECT_EQ(error.expected, 14u);
  EXPECT_EQ(error.actual, 0x1Fu);
  EXPECT_EQ(error.describe(),
            "datagram 1 at byte 16: unknown command 0x1F (commands are 0x00..0x0E)");
  EXPECT_EQ(error.to_error().code(), Errc::malformed);

  bytes[16] = 15;  // the first value past FRMW
  EXPECT_EQ(decode_error(bytes).actual, 15u);
}

TEST(DecodeFrameError, ErrorCodesHaveNames) {
  EXPECT_EQ(to_string(DecodeErrc::truncated_datagram), "truncated_datagram");
  EXPECT_EQ(to_string(DecodeErrc::more_follows_past_end), "more_follows_past_end");
  EXPECT_EQ(to_string(DecodeErrc::not_ethercat), "not_ethercat");
}

// ---------------------------------------------------------------------------------------------
// Ethernet

TEST(Ethernet, MacToString) {
  EXPECT_EQ(to_string(MacAddress{0x12, 0x10, 0xAB, 0x00, 0xCD, 0xFF}), "12:10:ab:00:cd:ff");
  EXPECT_EQ(to_string(kBroadcastMac), "ff:ff:ff:ff:ff:ff");
}

TEST(Ethernet, EncodesAndPadsToMinimum) {
  const ByteVector payload{0x0E, 0x10, 7, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0, 0};
  std::array<std::uint8_t, 128> out;
  out.fill(0xEE);
  const MacAddress source{0x02, 0x11, 0x22, 0x33, 0x44, 0x55};
  auto frame = encode_ethernet({kBroadcastMac, source, {}, kEtherTypeEtherCat}, payload, out);
  ASSERT_EQ(frame.size(), 60u);
  EXPECT_EQ(ByteVector(frame.begin(), frame.begin() + 14),
            (ByteVector{0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, 0x11, 0x22, 0x33, 0x44, 0x55,
                        0x88, 0xA4}));
  EXPECT_EQ(ByteVector(frame.begin() + 14, frame.begin() + 30), payload);
  for (std::size_t i = 30; i < 60; ++i)
    EXPECT_EQ(frame[i], 0) << i;

  auto decoded = decode_ethernet(frame);
  ASSERT_TRUE(decoded);
  EXPECT_EQ(decoded.frame->header.destination, kBroadcastMac);
  EXPECT_EQ(decoded.frame->header.source, source);
  EXPECT_FALSE(decoded.frame->header.vlan_tci.has_value());
  EXPECT_EQ(decoded.frame->payload.size(), 46u);  // padding included
  auto ethercat = decode_frame(decoded.frame->payload);
  ASSERT_TRUE(ethercat) << ethercat.error.describe();
  EXPECT_EQ(ethercat.frame->body().size(), 14u);
}

TEST(Ethernet, EncodeRefusesSmallBuffer) {
  std::array<std::uint8_t, 59> out{};
  EXPECT_TRUE(encode_ethernet({}, ByteVector{1, 2}, out).empty());
  std::array<std::uint8_t, 80> fits{};
  EXPECT_EQ(encode_ethernet({}, pattern(66, 0), fits).size(), 80u);  // no padding needed
  EXPECT_TRUE(encode_ethernet({}, pattern(67, 0), fits).empty());
}

TEST(Ethernet, EncodeAcceptsPayloadAlreadyInPlace) {
  std::array<std::uint8_t, 64> out{};
  for (std::size_t i = 0; i < 20; ++i)
    out[14 + i] = static_cast<std::uint8_t>(i + 1);
  auto frame = encode_ethernet({}, Bytes(out.data() + 14, 20), out);
  ASSERT_EQ(frame.size(), 60u);
  for (std::size_t i = 0; i < 20; ++i)
    EXPECT_EQ(frame[14 + i], i + 1);
}

TEST(Ethernet, VlanTaggedRoundTrip) {
  std::array<std::uint8_t, 128> out{};
  const ByteVector payload = pattern(50, 4);
  EthernetHeader header{kBroadcastMac, {2, 0, 0, 0, 0, 9}, 0x6005, kEtherTypeEtherCat};
  auto frame = encode_ethernet(header, payload, out);
  ASSERT_EQ(frame.size(), 68u);
  EXPECT_EQ(ByteVector(frame.begin() + 12, frame.begin() + 18),
            (ByteVector{0x81, 0x00, 0x60, 0x05, 0x88, 0xA4}));
  auto decoded = decode_ethernet(frame);
  ASSERT_TRUE(decoded) << decoded.error.describe();
  ASSERT_TRUE(decoded.frame->header.vlan_tci.has_value());
  EXPECT_EQ(*decoded.frame->header.vlan_tci, 0x6005);
  EXPECT_EQ(decoded.frame->header.ether_type, kEtherTypeEtherCat);
  EXPECT_EQ(ByteVector(decoded.frame->payload.begin(), decoded.frame->payload.end()), payload);
}

TEST(Ethernet, RejectsOtherEtherTypes) {
  ByteVector ipv4(60, 0);
  ipv4[12] = 0x08;
  auto plain = decode_ethernet(ipv4);
  ASSERT_FALSE(plain);
  EXPECT_EQ(plain.error.code, DecodeErrc::not_ethercat);
  EXPECT_EQ(plain.error.offset, 12u);
  EXPECT_EQ(plain.error.actual, 0x0800u);
  EXPECT_EQ(plain.error.expected, 0x88A4u);
  EXPECT_EQ(plain.error.describe(), "EtherType 0x0800 at byte 12 is not EtherCAT (0x88A4)");
  EXPECT_EQ(plain.error.to_error().code(), Errc::malformed);

  ByteVector tagged(60, 0);
  tagged[12] = 0x81;
  tagged[16] = 0x86;
  tagged[17] = 0xDD;
  auto vlan = decode_ethernet(tagged);
  ASSERT_FALSE(vlan);
  EXPECT_EQ(vlan.error.offset, 16u);
  EXPECT_EQ(vlan.error.actual, 0x86DDu);
}

TEST(Ethernet, RejectsTruncatedHeaders) {
  auto short_frame = decode_ethernet(ByteVector(13, 0));
  ASSERT_FALSE(short_frame);
  EXPECT_EQ(short_frame.error.code, DecodeErrc::truncated_ethernet_header);
  EXPECT_EQ(short_frame.error.expected, 14u);
  EXPECT_EQ(short_frame.error.actual, 13u);
  EXPECT_EQ(short_frame.error.describe(), "Ethernet header truncated: 14 bytes needed, 13 present");
  EXPECT_EQ(short_frame.error.to_error().code(), Errc::truncated);

  ByteVector tagged(16, 0);
  tagged[12] = 0x81;
  auto short_tag = decode_ethernet(tagged);
  ASSERT_FALSE(short_tag);
  EXPECT_EQ(short_tag.error.code, DecodeErrc::truncated_ethernet_header);
  EXPECT_EQ(short_tag.error.expected, 18u);
  EXPECT_EQ(short_tag.error.actual, 16u);
}

TEST(Ethernet, EmptyEtherCatPayloadIsTruncatedFrameHeader) {
  ByteVector bytes(14, 0);
  bytes[12] = 0x88;
  bytes[13] = 0xA4;
  auto decoded = decode_ethernet(bytes);
  ASSERT_TRUE(decoded);
  EXPECT_TRUE(decoded.frame->payload.empty());
  EXPECT_EQ(decode_frame(decoded.frame->payload).error.code, DecodeErrc::truncated_frame_header);
}

// ---------------------------------------------------------------------------------------------
// Real captures: every EtherCAT frame decodes, and re-encodes to the same datagram chain.

// Packets of a pcapng file (Ethernet link type only, which is what the shared captures hold).
// Deliberately independent of the `ecat decode` tool's reader.
std::vector<ByteVector> pcapng_packets(const ByteVector& file) {
  std::vector<ByteVector> packets;
  std::size_t offset = 0;
  while (offset + 12 <= file.size()) {
    const std::uint32_t type = load_le32(file.data() + offset);
    const std::uint32_t length = load_le32(file.data() + offset + 4);
    if (length < 12 || length > file.size() - offset) {
      ADD_FAILURE() << "bad pcapng block at " << offset;
      break;
    }
    if (type == 0x0A0D0D0A) {
      EXPECT_EQ(load_le32(file.data() + offset + 8), 0x1A2B3C4Du) << "big-endian pcapng";
    } else if (type == 1) {
      EXPECT_EQ(load_le16(file.data() + offset + 8), 1) << "link type is not Ethernet";
    } else if (type == 6 && length >= 32) {
      const std::uint32_t captured = load_le32(file.data() + offset + 20);
      if (captured <= length - 32) {
        packets.emplace_back(file.begin() + static_cast<std::ptrdiff_t>(offset + 28),
                             file.begin() + static_cast<std::ptrdiff_t>(offset + 28 + captured));
      }
    }
    offset += length;
  }
  return packets;
}

TEST(SharedCaptures, EveryEtherCatFrameDecodesAndReencodes) {
  ECAT_SHARED_DATA_OR_SKIP(captures, "captures");
  // EtherCAT frame counts per file, counted independently with a script.
  const std::map<std::string, std::size_t> expected_counts{
      {"replay-dc.pcapng", 3604},
      {"replay-ek1100-el2828-el2889.pcapng", 3578},
      {"replay-ek1914-el3004-mailbox.pcapng", 994},
      {"replay-ek1914-segmented-upload.pcapng", 964},
      {"rs-example-sii-el2004.pcapng", 254},
      {"soem-sdinfo-ek1100-el1004.pcapng", 580},
      {"soem-sdinfo-no-slaves.pcapng", 19},
      {"twincat-run-ek1100-el1004.pcapng", 553},
  };
  std::size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(captures)) {
    const auto name = entry.path().filename().string();
    if (entry.path().extension() != ".pcapng" && entry.path().extension() != ".pcap") continue;
    ++files;
    std::size_t ethercat = 0;
    std::size_t datagrams = 0;
    std::size_t packet_number = 0;
    for (const auto& packet : pcapng_packets(test::read_file(entry.path()))) {
      ++packet_number;
      auto ethernet = decode_ethernet(packet);
      if (!ethernet) {
        // Host traffic, some of it cut to 10 bytes by the capture's snap length.
        EXPECT_TRUE(ethernet.error.code == DecodeErrc::not_ethercat ||
                    (ethernet.error.code == DecodeErrc::truncated_ethernet_header &&
                     packet.size() < kEthernetHeaderSize))
            << name << " packet " << packet_number << ": " << ethernet.error.describe();
        continue;
      }
      ++ethercat;
      auto decoded = decode_frame(ethernet.frame->payload);
      ASSERT_TRUE(decoded) << name << " packet " << packet_number << ": "
                           << decoded.error.describe();
      std::array<std::uint8_t, 2 + 0x7FF> buffer{};
      FrameBuilder builder(buffer);
      for (auto datagram : *decoded.frame) {
        ++datagrams;
        ASSERT_TRUE(builder.add(datagram.header, datagram.data, datagram.wkc));
      }
      auto reencoded = builder.finish();
      const auto body = decoded.frame->body();
      ASSERT_EQ(ByteVector(reencoded.begin() + 2, reencoded.end()),
                ByteVector(body.begin(), body.end()))
          << name << " packet " << packet_number;
    }
    auto expected = expected_counts.find(name);
    if (expected != expected_counts.end()) {
      EXPECT_EQ(ethercat, expected->second) << name;
    }
    EXPECT_GE(datagrams, ethercat) << name;
  }
  EXPECT_GE(files, 8u);
}

}  // namespace
}  // namespace ecat::wire
