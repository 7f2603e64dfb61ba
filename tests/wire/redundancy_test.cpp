#include <array>
#include <cstdint>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/wire/frame.hpp>
#include <ecat/wire/redundancy.hpp>

namespace ecat::wire {
namespace {

using ByteVector = std::vector<std::uint8_t>;

struct Dg {
  Command command;
  std::uint8_t index;
  std::uint32_t address;
  ByteVector data;
  std::uint16_t wkc = 0;
  bool circulating = false;
  std::uint16_t irq = 0;
};

ByteVector build(const std::vector<Dg>& datagrams) {
  ByteVector buffer(kMaxFrameSize);
  FrameBuilder builder(buffer);
  for (const auto& d : datagrams) {
    DatagramHeader h{d.command,     d.index, d.address, static_cast<std::uint16_t>(d.data.size()),
                     d.circulating, false,   d.irq};
    EXPECT_TRUE(builder.add(h, d.data, d.wkc));
  }
  const Bytes frame = builder.finish();
  return ByteVector(frame.begin(), frame.end());
}

std::vector<DatagramView> datagrams_of(const ByteVector& frame) {
  const auto decoded = decode_frame(frame);
  EXPECT_TRUE(decoded) << decoded.error.describe();
  std::vector<DatagramView> out;
  if (decoded) {
    for (const auto d : *decoded.frame)
      out.push_back(d);
  }
  return out;
}

constexpr MacAddress kPrimary{0x02, 0x00, 0x00, 0x00, 0x00, 0x01};
constexpr MacAddress kSecondary{0x02, 0x00, 0x00, 0x00, 0x00, 0x02};

TEST(RedundancyClassify, BySourceAndPort) {
  using enum RedundantPort;
  EXPECT_EQ(classify_arrival(secondary, kPrimary, kPrimary, kSecondary),
            ArrivalKind::forward_cross);
  EXPECT_EQ(classify_arrival(primary, kSecondary, kPrimary, kSecondary),
            ArrivalKind::reverse_cross);
  EXPECT_EQ(classify_arrival(primary, kPrimary, kPrimary, kSecondary), ArrivalKind::primary_bounce);
  EXPECT_EQ(classify_arrival(secondary, kSecondary, kPrimary, kSecondary),
            ArrivalKind::secondary_bounce);
  EXPECT_EQ(classify_arrival(primary, MacAddress{1, 2, 3, 4, 5, 6}, kPrimary, kSecondary),
            ArrivalKind::unknown);
  // Two ports with one address cannot be told apart.
  EXPECT_EQ(classify_arrival(primary, kPrimary, kPrimary, kPrimary), ArrivalKind::unknown);
}

TEST(RedundancyClassify, IgnoresTheBitForwardingEscsSet) {
  MacAddress forwarded = kPrimary;
  forwarded[0] ^= 0x02;
  EXPECT_TRUE(same_station_mac(forwarded, kPrimary));
  EXPECT_EQ(classify_arrival(RedundantPort::secondary, forwarded, kPrimary, kSecondary),
            ArrivalKind::forward_cross);
  MacAddress other = kPrimary;
  other[0] ^= 0x01;
  EXPECT_FALSE(same_station_mac(other, kPrimary));
  EXPECT_EQ(to_string(ArrivalKind::reverse_cross), "reverse cross");
  EXPECT_EQ(to_string(RedundantPort::secondary), "secondary");
}

TEST(RedundancyShape, PassthroughCopyIsUntouchedRequest) {
  const auto request =
      build({{Command::fprd, 1, 0x10001000, {0, 0}}, {Command::lrw, 2, 0, {5, 6}}});
  EXPECT_TRUE(same_shape(request, request));
  EXPECT_TRUE(is_passthrough_copy(request, request));
  EXPECT_FALSE(any_processed(request));

  const auto processed =
      build({{Command::fprd, 1, 0x10001000, {0, 0}, 1}, {Command::lrw, 2, 0, {5, 6}}});
  EXPECT_TRUE(same_shape(request, processed));
  EXPECT_FALSE(is_passthrough_copy(request, processed));
  EXPECT_TRUE(any_processed(processed));

  // WKC 0 but data changed: something touched it, it is not a plain copy.
  const auto changed =
      build({{Command::fprd, 1, 0x10001000, {0, 0}}, {Command::lrw, 2, 0, {5, 7}}});
  EXPECT_FALSE(is_passthrough_copy(request, changed));

  const auto other_index =
      build({{Command::fprd, 9, 0x10001000, {0, 0}}, {Command::lrw, 2, 0, {5, 6}}});
  EXPECT_FALSE(same_shape(request, other_index));
  const auto fewer = build({{Command::fprd, 1, 0x10001000, {0, 0}}});
  EXPECT_FALSE(same_shape(request, fewer));
  const auto longer =
      build({{Command::fprd, 1, 0x10001000, {0, 0, 0}}, {Command::lrw, 2, 0, {5, 6}}});
  EXPECT_FALSE(same_shape(request, longer));
  const ByteVector garbage{0x01, 0x02, 0x03};
  EXPECT_FALSE(same_shape(request, garbage));
  EXPECT_FALSE(is_passthrough_copy(request, garbage));
  EXPECT_FALSE(any_processed(garbage));
}

TEST(RedundancyMerge, LogicalBytesMergedAndWorkingCountersSummed) {
  // Outputs 0xA0 0xA1 written by both sides (unchanged), inputs at bytes 2 and 3: byte 2 belongs
  // to a slave before the break, byte 3 to one after it.
  const auto request = build({{Command::lrw, 7, 0x00010000, {0xA0, 0xA1, 0x00, 0x00}}});
  const auto primary =
      build({{Command::lrw, 7, 0x00010000, {0xA0, 0xA1, 0x11, 0x00}, 3, false, 0x0001}});
  const auto secondary =
      build({{Command::lrw, 7, 0x00010000, {0xA0, 0xA1, 0x00, 0x22}, 3, true, 0x0100}});
  ByteVector out(request.size());
  MergeStats stats;
  const auto merged = merge_bounces(request, primary, secondary, out, &stats);
  ASSERT_TRUE(merged) << merged.error().describe();
  ASSERT_EQ(merged->size(), request.size());
  const ByteVector merged_frame(merged->begin(), merged->end());
  const auto d = datagrams_of(merged_frame);
  ASSERT_EQ(d.size(), 1u);
  EXPECT_EQ(d[0].wkc, 6);
  EXPECT_EQ(ByteVector(d[0].data.begin(), d[0].data.end()), (ByteVector{0xA0, 0xA1, 0x11, 0x22}));
  EXPECT_TRUE(d[0].header.circulating);
  EXPECT_EQ(d[0].header.irq, 0x0101);
  EXPECT_EQ(d[0].header.index, 7);
  EXPECT_EQ(stats.datagrams, 1u);
  EXPECT_EQ(stats.bytes_from_primary, 1u);
  EXPECT_EQ(stats.bytes_from_secondary, 1u);
  EXPECT_EQ(stats.conflicting_bytes, 0u);
}

TEST(RedundancyMerge, ConflictsGoToTheSideWithMoreWorkingCounter) {
  const auto request = build({{Command::lrd, 1, 0, {0, 0}}});
  const auto primary = build({{Command::lrd, 1, 0, {0x10, 0x20}, 1}});
  const auto secondary = build({{Command::lrd, 1, 0, {0x30, 0x20}, 2}});
  ByteVector out(request.size());
  MergeStats stats;
  const auto merged = merge_bounces(request, primary, secondary, out, &stats);
  ASSERT_TRUE(merged);
  const auto d = datagrams_of(out);
  EXPECT_EQ(ByteVector(d[0].data.begin(), d[0].data.end()), (ByteVector{0x30, 0x20}));
  EXPECT_EQ(d[0].wkc, 3);
  EXPECT_EQ(stats.conflicting_bytes, 1u);
}

TEST(RedundancyMerge, PhysicalReadTakesTheSideThatAnswered) {
  // FPRD of a station after the break: the primary's copy passed no such slave (WKC 0).
  const auto request =
      build({{Command::fprd, 3, 0x01301005, {0, 0}}, {Command::brd, 4, 0x01300000, {0, 0}}});
  const auto primary = build(
      {{Command::fprd, 3, 0x01301005, {0, 0}, 0}, {Command::brd, 4, 0x01300002, {0x08, 0}, 2}});
  const auto secondary = build({{Command::fprd, 3, 0x01301005, {0x08, 0x00}, 1},
                                {Command::brd, 4, 0x01300001, {0x08, 0}, 1}});
  ByteVector out(request.size() + 10);
  const auto merged = merge_bounces(request, primary, secondary, out);
  ASSERT_TRUE(merged);
  const ByteVector merged_frame(merged->begin(), merged->end());
  const auto d = datagrams_of(merged_frame);
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(d[0].wkc, 1);
  EXPECT_EQ(d[0].data[0], 0x08);
  // A broadcast read counts every slave of both sides; its address comes from the leading side.
  EXPECT_EQ(d[1].wkc, 3);
  EXPECT_EQ(d[1].header.address, 0x01300002u);
}

TEST(RedundancyMerge, ReadMultipleWriteTakesTheReadersSide) {
  // FRMW of the reference clock (station 0x1000, before the break): the primary's side reads it
  // (WKC 1 + one writer), the secondary's three slaves write the master's value (WKC 3).
  const ByteVector sent{1, 2, 3, 4};
  const ByteVector read{9, 8, 7, 6};
  const auto request = build({{Command::frmw, 5, 0x09101000, sent}});
  const auto reader = build({{Command::frmw, 5, 0x09101000, read, 2}});
  const auto writers = build({{Command::frmw, 5, 0x09101000, sent, 3}});
  const auto data_of = [&](const ByteVector& primary, const ByteVector& secondary) {
    ByteVector out(request.size());
    const auto merged = merge_bounces(request, primary, secondary, out);
    EXPECT_TRUE(merged);
    if (!merged) return std::make_pair(ByteVector{}, 0);
    const ByteVector frame(merged->begin(), merged->end());
    const auto d = datagrams_of(frame);
    EXPECT_EQ(d.size(), 1u);
    return std::make_pair(ByteVector(d.at(0).data.begin(), d.at(0).data.end()),
                          static_cast<int>(d.at(0).wkc));
  };
  EXPECT_EQ(data_of(reader, writers), std::make_pair(read, 5));
  // Mirrored: the reader behind the break.
  EXPECT_EQ(data_of(writers, reader), std::make_pair(read, 5));
  // Nobody read (the reference gone): the request's data.
  EXPECT_EQ(data_of(writers, writers), std::make_pair(sent, 6));
}

TEST(RedundancyMerge, WorkingCounterSaturates) {
  const auto request = build({{Command::brd, 1, 0, {0}}});
  const auto a = build({{Command::brd, 1, 0, {0}, 0xFFF0}});
  const auto b = build({{Command::brd, 1, 0, {0}, 0x0100}});
  ByteVector out(request.size());
  ASSERT_TRUE(merge_bounces(request, a, b, out));
  EXPECT_EQ(datagrams_of(out)[0].wkc, 0xFFFF);
}

TEST(RedundancyMerge, RefusesWhatDoesNotAnswerTheRequest) {
  const auto request = build({{Command::lrw, 1, 0, {0, 0}}});
  const auto good = build({{Command::lrw, 1, 0, {0, 1}, 1}});
  const auto wrong = build({{Command::lrw, 2, 0, {0, 1}, 1}});
  ByteVector out(request.size());
  auto r = merge_bounces(request, wrong, good, out);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code(), Errc::malformed);
  EXPECT_NE(r.error().message().find("primary"), std::string::npos);
  r = merge_bounces(request, good, wrong, out);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message().find("secondary"), std::string::npos);
  ByteVector small(request.size() - 1);
  r = merge_bounces(request, good, good, small);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  const ByteVector garbage{0xFF};
  r = merge_bounces(garbage, good, good, out);
  ASSERT_FALSE(r);
}

TEST(RedundancyMerge, RandomSplitsEqualTheWholeRing) {
  // Eight slaves, each owning one input byte of an LRW: any break position gives the whole-ring
  // result after merging, and the WKC of the whole ring.
  const ByteVector outputs{0x5A, 0xA5};
  ByteVector request_data = outputs;
  request_data.resize(10, 0);
  const auto request = build({{Command::lrw, 0x40, 0, request_data}});
  ByteVector whole = request_data;
  for (int s = 0; s < 8; ++s)
    whole[2 + s] = static_cast<std::uint8_t>(0x80 + s);
  for (int split = 0; split <= 8; ++split) {
    ByteVector a = request_data, b = request_data;
    for (int s = 0; s < 8; ++s)
      (s < split ? a : b)[2 + s] = whole[2 + s];
    // Each slave counts 3 for an LRW that reads and writes it.
    const auto pa = build({{Command::lrw, 0x40, 0, a, static_cast<std::uint16_t>(3 * split)}});
    const auto pb =
        build({{Command::lrw, 0x40, 0, b, static_cast<std::uint16_t>(3 * (8 - split))}});
    ByteVector out(request.size());
    ASSERT_TRUE(merge_bounces(request, pa, pb, out));
    const auto d = datagrams_of(out);
    EXPECT_EQ(d[0].wkc, 24) << split;
    EXPECT_EQ(ByteVector(d[0].data.begin(), d[0].data.end()), whole) << split;
  }
}

}  // namespace
}  // namespace ecat::wire
