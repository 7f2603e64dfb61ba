// Capture files through libpcap (src/capture/capture_file.cpp): the one reader and writer of pcap
// and pcapng that `ecat decode`, `ecat sim profile/verify` and the fuzz target share.
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/capture/capture_file.hpp>
#include <ecat/wire/bytes.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/shared_data.hpp"

namespace ecat::capture {
namespace {

using Buffer = std::vector<std::uint8_t>;

std::filesystem::path scratch(const std::string& name) {
  const auto dir = std::filesystem::path(ECAT_BINARY_DIR) / "tests" / "capture_scratch";
  std::filesystem::create_directories(dir);
  return dir / name;
}

Buffer bytes_of(wire::Bytes b) {
  return Buffer(b.begin(), b.end());
}

// ---- pcap -----------------------------------------------------------------------------------

TEST(CaptureFile, PcapRoundTripsPacketsAndNanosecondTimes) {
  const Buffer a{1, 2, 3};
  const Buffer b{4};
  const std::vector<OutputPacket> packets{{1'000'000'123, a}, {2'500'000'000, b}, {-5, a}};
  const Buffer encoded = encode_pcap(packets);
  // libpcap's nanosecond pcap, little-endian on this host.
  ASSERT_GE(encoded.size(), 24u);
  EXPECT_EQ(wire::load_le32(encoded.data()), 0xA1B23C4Du);
  auto file = CaptureFile::from_bytes(encoded, "x.pcap");
  ASSERT_TRUE(file.ok()) << file.error().describe();
  EXPECT_EQ(file->format(), CaptureFormat::pcap);
  EXPECT_EQ(file->link_type(), kLinkTypeEthernet);
  EXPECT_EQ(file->name(), "x.pcap");
  auto p1 = file->next();
  ASSERT_TRUE(p1.ok() && p1->has_value());
  EXPECT_EQ((*p1)->number, 1u);
  EXPECT_EQ((*p1)->timestamp_ns, 1'000'000'123);
  EXPECT_EQ((*p1)->link_type, kLinkTypeEthernet);
  EXPECT_EQ((*p1)->original_length, 3u);
  EXPECT_EQ(bytes_of((*p1)->data), a);
  auto p2 = file->next();
  ASSERT_TRUE(p2.ok() && p2->has_value());
  EXPECT_EQ((*p2)->number, 2u);
  EXPECT_EQ((*p2)->timestamp_ns, 2'500'000'000);
  EXPECT_EQ(bytes_of((*p2)->data), b);
  auto p3 = file->next();
  ASSERT_TRUE(p3.ok() && p3->has_value());
  EXPECT_EQ((*p3)->timestamp_ns, 0);  // before the epoch: written as 0
  auto end = file->next();
  ASSERT_TRUE(end.ok());
  EXPECT_FALSE(end->has_value());
  // The end stays the end.
  auto again = file->next();
  ASSERT_TRUE(again.ok());
  EXPECT_FALSE(again->has_value());
}

TEST(CaptureFile, WritesAndOpensFilesOfOtherLinkTypes) {
  const Buffer sll(16, 0x11);
  const std::vector<OutputPacket> packets{{7, sll}};
  const auto path = scratch("sll.pcap");
  ASSERT_TRUE(write_pcap(path.string(), packets, kLinkTypeLinuxSll).ok());
  auto file = CaptureFile::open(path.string());
  ASSERT_TRUE(file.ok()) << file.error().describe();
  EXPECT_EQ(file->link_type(), kLinkTypeLinuxSll);
  EXPECT_EQ(file->name(), path.string());
  auto p = file->next();
  ASSERT_TRUE(p.ok() && p->has_value());
  EXPECT_EQ((*p)->link_type, kLinkTypeLinuxSll);
  EXPECT_EQ((*p)->timestamp_ns, 7);
  EXPECT_EQ(bytes_of((*p)->data), sll);

  // The same bytes as the in-memory writer.
  std::ifstream in(path, std::ios::binary);
  const Buffer on_disk{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  EXPECT_EQ(on_disk, encode_pcap(packets, kLinkTypeLinuxSll));

  const auto refused = write_pcap((scratch("no-such-dir") / "x" / "y.pcap").string(), packets);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::io_error);
  EXPECT_NE(refused.error().message().find("y.pcap"), std::string::npos);
}

TEST(CaptureFile, MicrosecondAndBigEndianPcapAreReadInNanoseconds) {
  // Header: magic a1b2c3d4 big-endian, version 2.4, snaplen 65535, Ethernet; one record.
  Buffer file{0xA1, 0xB2, 0xC3, 0xD4, 0, 2, 0,    4,    0, 0, 0, 0,
              0,    0,    0,    0,    0, 0, 0xFF, 0xFF, 0, 0, 0, 1};
  const Buffer record{0, 0, 0, 3, 0, 0x07, 0xA1, 0x20, 0, 0, 0, 2, 0, 0, 0, 60, 0xAB, 0xCD};
  file.insert(file.end(), record.begin(), record.end());
  auto capture = CaptureFile::from_bytes(file, "be.pcap");
  ASSERT_TRUE(capture.ok()) << capture.error().describe();
  auto p = capture->next();
  ASSERT_TRUE(p.ok() && p->has_value()) << (p.ok() ? "" : p.error().describe());
  EXPECT_EQ((*p)->timestamp_ns, 3'500'000'000);  // 3 s + 500000 us
  EXPECT_EQ((*p)->original_length, 60u);
  EXPECT_EQ(bytes_of((*p)->data), (Buffer{0xAB, 0xCD}));
}

// ---- pcapng ---------------------------------------------------------------------------------

Buffer block(std::uint32_t type, Buffer body) {
  while (body.size() % 4 != 0)
    body.push_back(0);
  Buffer out(8);
  wire::store_le32(&out[0], type);
  const auto length = static_cast<std::uint32_t>(body.size() + 12);
  wire::store_le32(&out[4], length);
  out.insert(out.end(), body.begin(), body.end());
  out.resize(out.size() + 4);
  wire::store_le32(&out[out.size() - 4], length);
  return out;
}

Buffer epb(std::uint32_t interface, std::uint64_t ticks, Buffer data) {
  Buffer body(20);
  wire::store_le32(&body[0], interface);
  wire::store_le32(&body[4], static_cast<std::uint32_t>(ticks >> 32));
  wire::store_le32(&body[8], static_cast<std::uint32_t>(ticks));
  wire::store_le32(&body[12], static_cast<std::uint32_t>(data.size()));
  wire::store_le32(&body[16], static_cast<std::uint32_t>(data.size() + 10));
  body.insert(body.end(), data.begin(), data.end());
  return block(6, body);
}

void append(Buffer& out, const Buffer& more) {
  out.insert(out.end(), more.begin(), more.end());
}

// Interface 0: Ethernet, default microseconds. Interface 1: `second_link_type`, tsresol 2^-10 s.
Buffer pcapng_with_two_interfaces(std::uint8_t second_link_type = kLinkTypeEthernet) {
  Buffer shb{0x4D, 0x3C, 0x2B, 0x1A, 1, 0, 0, 0};
  shb.resize(16, 0xFF);  // section length -1
  Buffer out = block(0x0A0D0D0A, shb);
  append(out, block(1, {1, 0, 0, 0, 0, 0, 0, 0}));
  append(out,
         block(1, {second_link_type, 0, 0, 0, 0, 0, 0, 0, 9, 0, 1, 0, 0x8A, 0, 0, 0, 0, 0, 0, 0}));
  append(out, epb(0, 1'500'000, {0xAA, 0xBB}));  // 1.5 s in microseconds
  append(out, block(5, Buffer(8)));              // interface statistics: skipped
  append(out, epb(1, 3 * 1024 + 512, {0xCC}));   // 3.5 s in 1/1024 s
  return out;
}

TEST(CaptureFile, PcapngReadsInterfacesResolutionsAndSkipsOtherBlocks) {
  auto file = CaptureFile::from_bytes(pcapng_with_two_interfaces(), "x.pcapng");
  ASSERT_TRUE(file.ok()) << file.error().describe();
  EXPECT_EQ(file->format(), CaptureFormat::pcapng);
  EXPECT_EQ(file->link_type(), kLinkTypeEthernet);
  auto p0 = file->next();
  ASSERT_TRUE(p0.ok() && p0->has_value()) << (p0.ok() ? "" : p0.error().describe());
  EXPECT_EQ((*p0)->timestamp_ns, 1'500'000'000);
  EXPECT_EQ((*p0)->link_type, kLinkTypeEthernet);
  EXPECT_EQ((*p0)->original_length, 12u);
  auto p1 = file->next();
  ASSERT_TRUE(p1.ok() && p1->has_value()) << (p1.ok() ? "" : p1.error().describe());
  EXPECT_EQ((*p1)->number, 2u);
  EXPECT_EQ((*p1)->timestamp_ns, 3'500'000'000);
  EXPECT_EQ((*p1)->data.size(), 1u);
  auto end = file->next();
  ASSERT_TRUE(end.ok());
  EXPECT_FALSE(end->has_value());
}

TEST(CaptureFile, PcapngInterfacesOfDifferentLinkTypesAreAnError) {
  // libpcap gives one link type per file: a second interface of another type is refused when
  // its description is reached, with libpcap's reason and the packet that needed it.
  auto file = CaptureFile::from_bytes(pcapng_with_two_interfaces(kLinkTypeLinuxSll), "mixed");
  if (!file.ok()) {
    EXPECT_NE(file.error().message().find("mixed"), std::string::npos);
    return;
  }
  bool failed = false;
  for (int i = 0; i < 3 && !failed; ++i) {
    auto p = file->next();
    if (!p.ok()) {
      failed = true;
      EXPECT_NE(p.error().message().find("capture 'mixed'"), std::string::npos)
          << p.error().message();
    } else if (p->has_value()) {
      EXPECT_EQ((*p)->link_type, kLinkTypeEthernet);
    }
  }
  EXPECT_TRUE(failed);
}

// ---- damaged input --------------------------------------------------------------------------

TEST(CaptureFile, DamagedFilesAreErrorsNamingTheFileAndThePacket) {
  auto empty = CaptureFile::from_bytes({}, "empty");
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.error().code(), Errc::truncated);
  EXPECT_NE(empty.error().message().find("capture 'empty'"), std::string::npos);

  auto junk = CaptureFile::from_bytes({'h', 'e', 'l', 'l', 'o', ' ', 'w', 'o', 'r', 'l', 'd', '!',
                                       'h', 'e', 'l', 'l', 'o', ' ', 'w', 'o', 'r', 'l', 'd', '!'},
                                      "junk");
  ASSERT_FALSE(junk.ok());
  EXPECT_EQ(junk.error().code(), Errc::malformed);
  EXPECT_NE(junk.error().message().find("capture 'junk' is neither pcap nor pcapng (libpcap: "),
            std::string::npos)
      << junk.error().message();

  const Buffer short_header{0xD4, 0xC3, 0xB2, 0xA1, 2, 0};
  auto header = CaptureFile::from_bytes(short_header, "short");
  ASSERT_FALSE(header.ok());
  EXPECT_EQ(header.error().code(), Errc::truncated) << header.error().message();

  const Buffer data{1, 2, 3, 4};
  const std::vector<OutputPacket> packets{{0, data}};
  auto bytes = encode_pcap(packets);
  bytes.resize(bytes.size() - 2);
  auto cut = CaptureFile::from_bytes(bytes, "cut.pcap");
  ASSERT_TRUE(cut.ok());
  auto p = cut->next();
  ASSERT_FALSE(p.ok());
  EXPECT_EQ(p.error().code(), Errc::truncated);
  EXPECT_NE(p.error().message().find("capture 'cut.pcap': cannot read packet 1: "),
            std::string::npos)
      << p.error().message();

  auto ng = pcapng_with_two_interfaces();
  wire::store_le32(&ng[ng.size() - 4], 12345);  // trailing length of the last block
  auto bad = CaptureFile::from_bytes(ng, "bad.pcapng");
  ASSERT_TRUE(bad.ok());
  ASSERT_TRUE(bad->next().ok());
  auto last = bad->next();
  ASSERT_FALSE(last.ok());
  EXPECT_NE(last.error().message().find("capture 'bad.pcapng': cannot read packet 2: "),
            std::string::npos)
      << last.error().message();
}

TEST(CaptureFile, AbsurdLengthsAreRefusedWithoutReadingThem) {
  // A record claiming 4 GiB of captured bytes: an error, not an allocation.
  Buffer file = encode_pcap(std::vector<OutputPacket>{});
  Buffer record(16);
  wire::store_le32(&record[8], 0xFFFFFFF0u);
  wire::store_le32(&record[12], 0xFFFFFFF0u);
  append(file, record);
  auto capture = CaptureFile::from_bytes(file, "huge.pcap");
  ASSERT_TRUE(capture.ok());
  auto p = capture->next();
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.error().message().find("packet 1"), std::string::npos) << p.error().message();

  // A pcapng block claiming 4 GiB.
  Buffer ng = pcapng_with_two_interfaces();
  Buffer huge_block(12);
  wire::store_le32(&huge_block[0], 6);
  wire::store_le32(&huge_block[4], 0xFFFFFFF0u);
  append(ng, huge_block);
  auto capture_ng = CaptureFile::from_bytes(ng, "huge.pcapng");
  ASSERT_TRUE(capture_ng.ok());
  for (int i = 0; i < 2; ++i)
    ASSERT_TRUE(capture_ng->next().ok());
  EXPECT_FALSE(capture_ng->next().ok());
}

TEST(CaptureFile, OnlyRegularFilesAreOpened) {
  auto missing = CaptureFile::open(scratch("missing.pcap").string());
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);

  auto directory = CaptureFile::open(scratch("").parent_path().string());
  ASSERT_FALSE(directory.ok());
  EXPECT_EQ(directory.error().code(), Errc::invalid_argument);

  const auto text = scratch("notes.txt");
  std::ofstream(text) << "not a capture at all, but long enough to be read\n";
  auto not_capture = CaptureFile::open(text.string());
  ASSERT_FALSE(not_capture.ok());
  EXPECT_EQ(not_capture.error().code(), Errc::malformed);
  EXPECT_NE(not_capture.error().message().find(text.string()), std::string::npos);
}

TEST(CaptureFile, MovedFilesKeepReading) {
  const Buffer a{9, 8, 7};
  const std::vector<OutputPacket> packets{{1, a}, {2, a}};
  auto file = CaptureFile::from_bytes(encode_pcap(packets), "m.pcap");
  ASSERT_TRUE(file.ok());
  ASSERT_TRUE(file->next().ok());
  CaptureFile moved = std::move(*file);
  auto p = moved.next();
  ASSERT_TRUE(p.ok() && p->has_value());
  EXPECT_EQ((*p)->number, 2u);
  EXPECT_EQ(bytes_of((*p)->data), a);
}

// ---- real captures --------------------------------------------------------------------------

TEST(CaptureFile, SharedCapturesReadToTheEndWithEtherCatInside) {
  ECAT_SHARED_DATA_OR_SKIP(dir, "captures");
  std::size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    const auto ext = entry.path().extension();
    if (ext != ".pcap" && ext != ".pcapng") continue;
    ++files;
    auto file = CaptureFile::open(entry.path().string());
    ASSERT_TRUE(file.ok()) << file.error().describe();
    EXPECT_EQ(file->format(), ext == ".pcapng" ? CaptureFormat::pcapng : CaptureFormat::pcap);
    EXPECT_TRUE(link_type_supported(file->link_type())) << entry.path();
    std::uint64_t packets = 0;
    std::uint64_t ethercat = 0;
    std::int64_t last_time = 0;
    for (;;) {
      auto p = file->next();
      ASSERT_TRUE(p.ok()) << p.error().describe();
      if (!p->has_value()) break;
      ++packets;
      EXPECT_EQ((*p)->number, packets);
      // Real captures from 2000 on, in nanoseconds.
      EXPECT_GT((*p)->timestamp_ns, 946'684'800'000'000'000) << entry.path();
      EXPECT_GE((*p)->timestamp_ns, last_time - 1'000'000'000) << entry.path();
      last_time = (*p)->timestamp_ns;
      ethercat += extract_ethercat((*p)->link_type, (*p)->data).has_value();
    }
    EXPECT_GT(packets, 0u) << entry.path();
    EXPECT_GT(ethercat, 0u) << entry.path();
  }
  EXPECT_GT(files, 0u);
}

}  // namespace
}  // namespace ecat::capture
