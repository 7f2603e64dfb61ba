// The pcapng writer: what it writes reads back through libpcap (CaptureFile) with the same bytes
// and nanosecond times; the direction (epb_flags, which libpcap does not expose) is decoded here
// from the blocks; tshark, when installed, reads the file too.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/capture/capture_file.hpp>
#include <ecat/capture/pcapng_writer.hpp>

namespace {

using namespace ecat::capture;
using Bytes = std::vector<std::uint8_t>;

std::uint32_t le32(const Bytes& b, std::size_t at) {
  return static_cast<std::uint32_t>(b[at]) | static_cast<std::uint32_t>(b[at + 1]) << 8 |
         static_cast<std::uint32_t>(b[at + 2]) << 16 | static_cast<std::uint32_t>(b[at + 3]) << 24;
}

// The decoder of our own encoding's one field libpcap leaves out: each EPB's epb_flags direction
// (0 when absent). Walks the blocks by their lengths; fails the test on a malformed layout.
std::vector<std::uint32_t> epb_directions(const Bytes& file) {
  std::vector<std::uint32_t> out;
  std::size_t at = 0;
  while (at + 12 <= file.size()) {
    const std::uint32_t type = le32(file, at);
    const std::uint32_t length = le32(file, at + 4);
    EXPECT_EQ(length % 4, 0u);
    EXPECT_LE(at + length, file.size());
    EXPECT_EQ(le32(file, at + length - 4), length) << "trailing block length";
    if (type == 6) {
      const std::uint32_t captured = le32(file, at + 20);
      std::size_t opt = at + 28 + (captured + 3) / 4 * 4;
      std::uint32_t direction = 0;
      while (opt + 4 <= at + length - 4) {
        const std::uint16_t code = static_cast<std::uint16_t>(file[opt] | file[opt + 1] << 8);
        const std::uint16_t len = static_cast<std::uint16_t>(file[opt + 2] | file[opt + 3] << 8);
        if (code == 0) break;
        if (code == 2 && len == 4) direction = le32(file, opt + 4) & 0x3;
        opt += 4 + (len + 3u) / 4 * 4;
      }
      out.push_back(direction);
    }
    if (length < 12) break;
    at += length;
  }
  EXPECT_EQ(at, file.size());
  return out;
}

std::vector<PcapngPacket> sample(std::vector<Bytes>& storage) {
  storage.clear();
  for (int i = 0; i < 5; ++i) {
    Bytes ethercat(10 + static_cast<std::size_t>(i) * 7);
    for (std::size_t k = 0; k < ethercat.size(); ++k)
      ethercat[k] = static_cast<std::uint8_t>(i * 31 + static_cast<int>(k));
    storage.push_back(ethernet_for_capture(ethercat, i % 2 == 0));
  }
  std::vector<PcapngPacket> packets;
  for (std::size_t i = 0; i < storage.size(); ++i) {
    packets.push_back({1'795'580'551'015'914'622 + static_cast<std::int64_t>(i) * 123'457,
                       storage[i],
                       i % 2 == 0 ? PacketDirection::outbound : PacketDirection::inbound, 0});
  }
  packets[4].direction = PacketDirection::unknown;
  return packets;
}

TEST(PcapngWriter, RoundTripsThroughLibpcap) {
  std::vector<Bytes> storage;
  const auto packets = sample(storage);
  const Bytes file = encode_pcapng(packets, {kLinkTypeEthernet, "sim:test", 262144});
  auto reader = CaptureFile::from_bytes(file, "written.pcapng");
  ASSERT_TRUE(reader) << reader.error().describe();
  EXPECT_EQ(reader->format(), CaptureFormat::pcapng);
  EXPECT_EQ(reader->link_type(), kLinkTypeEthernet);
  for (const auto& want : packets) {
    auto got = reader->next();
    ASSERT_TRUE(got) << got.error().describe();
    ASSERT_TRUE(got->has_value());
    EXPECT_EQ((*got)->timestamp_ns, want.timestamp_ns);
    EXPECT_EQ(Bytes((*got)->data.begin(), (*got)->data.end()),
              Bytes(want.data.begin(), want.data.end()));
    auto ethercat = extract_ethercat((*got)->link_type, (*got)->data);
    ASSERT_TRUE(ethercat);
  }
  auto end = reader->next();
  ASSERT_TRUE(end);
  EXPECT_FALSE(end->has_value());
  EXPECT_EQ(epb_directions(file), (std::vector<std::uint32_t>{2, 1, 2, 1, 0}));
}

TEST(PcapngWriter, EthernetWrapperMarksTheDirectionInTheSource) {
  const Bytes frame{0x0e, 0x10, 0x07, 0x00};
  const auto out = ethernet_for_capture(frame, true);
  const auto back = ethernet_for_capture(frame, false);
  EXPECT_EQ(out.size(), 60u);  // padded as on the wire
  EXPECT_EQ(out[6] & 0x02, 0);
  EXPECT_EQ(back[6] & 0x02, 0x02);
  auto ethercat = extract_ethercat(kLinkTypeEthernet, back);
  ASSERT_TRUE(ethercat);
  EXPECT_EQ(Bytes(ethercat->frame.begin(), ethercat->frame.begin() + 4), frame);
}

TEST(PcapngWriter, FileWriterAndErrors) {
  const auto dir =
      std::filesystem::temp_directory_path() / ("ecat-pcapng-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::vector<Bytes> storage;
  const auto packets = sample(storage);
  const auto path = (dir / "out.pcapng").string();
  ASSERT_TRUE(write_pcapng(path, packets));
  auto reader = CaptureFile::open(path);
  ASSERT_TRUE(reader) << reader.error().describe();
  std::size_t n = 0;
  while (true) {
    auto p = reader->next();
    ASSERT_TRUE(p);
    if (!p->has_value()) break;
    ++n;
  }
  EXPECT_EQ(n, packets.size());
  auto bad = PcapngWriter::create((dir / "absent" / "x.pcapng").string(), {});
  ASSERT_FALSE(bad);
  EXPECT_EQ(bad.error().code(), ecat::Errc::io_error);
  EXPECT_NE(bad.error().describe().find("absent"), std::string::npos);

  // tshark, when installed, reads the same frames and directions.
  if (std::system("command -v tshark >/dev/null 2>&1") != 0) {
    std::filesystem::remove_all(dir);
    GTEST_SKIP() << "tshark is not installed: the file was checked with libpcap only";
  }
  const std::string command =
      "tshark -r '" + path + "' -T fields -e frame.packet_flags_direction 2>/dev/null";
  FILE* pipe = ::popen(command.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string text;
  char buffer[256];
  while (std::fgets(buffer, sizeof buffer, pipe) != nullptr)
    text += buffer;
  EXPECT_EQ(::pclose(pipe), 0);
  std::size_t lines = 0;
  for (char c : text)
    lines += c == '\n';
  EXPECT_EQ(lines, packets.size()) << text;
  std::filesystem::remove_all(dir);
}

}  // namespace
