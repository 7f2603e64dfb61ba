// `ecat sim verify` / `ecat sim profile`: summary line format and exit codes on captures the test
// writes itself, and the figures on the shared real-device captures.
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/capture/capture_file.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

#include "support/shared_data.hpp"
#include "support/tool_runner.hpp"

namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<std::uint8_t>;

std::string last_line(const std::string& text) {
  std::string t = text;
  while (!t.empty() && t.back() == '\n')
    t.pop_back();
  const auto at = t.rfind('\n');
  return at == std::string::npos ? t : t.substr(at + 1);
}

// One datagram frame: command, index, address, data, WKC.
Bytes frame(std::uint8_t command, std::uint32_t address, const Bytes& data, std::uint16_t wkc) {
  Bytes f(2 + 10 + data.size() + 2);
  f[2] = command;
  f[3] = 1;
  ecat::wire::store_le32(&f[4], address);
  ecat::wire::store_le16(&f[8], static_cast<std::uint16_t>(data.size()));
  for (std::size_t i = 0; i < data.size(); ++i)
    f[12 + i] = data[i];
  ecat::wire::store_le16(&f[12 + data.size()], wkc);
  ecat::wire::store_le16(f.data(), static_cast<std::uint16_t>((f.size() - 2) | 0x1000));
  return f;
}

Bytes ethernet(const Bytes& payload, bool from_master) {
  Bytes p(14 + payload.size(), 0xFF);
  for (std::size_t i = 6; i < 12; ++i)
    p[i] = 0x10;
  if (!from_master) p[6] = 0x12;
  p[12] = 0x88;
  p[13] = 0xA4;
  for (std::size_t i = 0; i < payload.size(); ++i)
    p[14 + i] = payload[i];
  return p;
}

class SimVerifyTool : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(ecat::test::tool_path()))
        << "ecat tool not found at " << ecat::test::tool_path() << " (set ECAT_TOOL)";
    tool_ = std::make_unique<ecat::test::ToolRunner>("sim-verify-test");
    dir_ = tool_->dir();
    verify_ = "sim verify";
    profile_ = "sim profile";
  }
  ecat::test::ToolRun run(const std::string& arguments) const { return tool_->run(arguments); }

  fs::path capture(const std::string& name, const std::vector<Bytes>& packets) const {
    std::vector<ecat::capture::OutputPacket> out;
    std::int64_t t = 1'600'000'000'000'000'000;
    for (const auto& p : packets)
      out.push_back({t += 50'000, p});
    const auto path = dir_ / name;
    EXPECT_TRUE(ecat::capture::write_pcap(path.string(), out).ok());
    return path;
  }

  // Two slaves: a BRD counts them, then the master assigns station 0x1000 to the first and reads
  // its AL status (INIT).
  fs::path good_capture() const {
    return capture("good.pcap",
                   {ethernet(frame(0x07, 0, {0}, 0), true),  // BRD 0x0000
                    ethernet(frame(0x07, 0x0002, {0x13}, 2), false),
                    ethernet(frame(0x02, 0x00100000, {0x00, 0x10}, 0), true),  // APWR 0x0010
                    ethernet(frame(0x02, 0x00100002, {0x00, 0x10}, 1), false),
                    ethernet(frame(0x04, 0x01301000, {0, 0}, 0), true),  // FPRD 0x0130
                    ethernet(frame(0x04, 0x01301000, {0x01, 0}, 1), false)});
  }

  std::unique_ptr<ecat::test::ToolRunner> tool_;
  fs::path dir_;
  std::string verify_;
  std::string profile_;
};

const std::regex kSummary(R"(datagrams=\d+ wkc_match=\d+/\d+ data_match=\d+/\d+ malformed=\d+)");

TEST_F(SimVerifyTool, MatchingCaptureEndsWithTheSummaryLineAndExitsZero) {
  const auto r = run(fmt::format("{} '{}'", verify_, good_capture().string()));
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_TRUE(std::regex_match(last_line(r.out), kSummary)) << r.out;
  EXPECT_EQ(last_line(r.out), "datagrams=3 wkc_match=3/3 data_match=2/2 malformed=0");
  EXPECT_NE(r.out.find("mismatches: 0"), std::string::npos) << r.out;
  EXPECT_TRUE(r.err.empty()) << r.err;
}

// Hostile input (issue 11): a capture that compares nothing proves nothing, and frames that do
// not decode are errors, as `ecat decode` reports them.
TEST_F(SimVerifyTool, NothingComparedFails) {
  // A capture of other traffic only (an IPv4 packet): no EtherCAT frame to replay.
  Bytes ip(60, 0);
  ip[12] = 0x08;
  const auto other = capture("other.pcap", {ip, ip});
  auto r = run(fmt::format("{} '{}'", verify_, other.string()));
  EXPECT_EQ(r.status, 1) << r.out << r.err;
  EXPECT_EQ(last_line(r.out), "datagrams=0 wkc_match=0/0 data_match=0/0 malformed=0");
  EXPECT_NE(r.out.find("nothing was compared"), std::string::npos) << r.out;
  r = run(fmt::format("{} '{}' --json", verify_, other.string()));
  EXPECT_EQ(r.status, 1) << r.out << r.err;
  EXPECT_EQ(nlohmann::json::parse(r.out).at("passed"), false);
}

TEST_F(SimVerifyTool, MalformedFramesAreCountedAsErrors) {
  Bytes broken = frame(0x07, 0, {0}, 0);
  broken[0] = 0xFF;  // the frame header claims 2047 bytes of datagrams
  broken[1] = 0x17;
  const auto path = capture(
      "broken.pcap", {ethernet(frame(0x07, 0, {0}, 0), true),
                      ethernet(frame(0x07, 0x0001, {0x11}, 1), false), ethernet(broken, true)});
  const auto r = run(fmt::format("{} '{}'", verify_, path.string()));
  EXPECT_EQ(r.status, 1) << r.out << r.err;
  EXPECT_EQ(last_line(r.out), "datagrams=1 wkc_match=1/1 data_match=1/1 malformed=1");
  EXPECT_NE(r.out.find("malformed EtherCAT frames (do not decode; counted as errors): 1"),
            std::string::npos)
      << r.out;
  const auto decoded = run(fmt::format("decode '{}'", path.string()));
  EXPECT_NE(decoded.status, 0) << decoded.out;
}

TEST_F(SimVerifyTool, MismatchingCaptureListsTheDatagramAndExitsOne) {
  // The reply's WKC says 2 slaves answered while the address increment says 1 passed.
  const auto path = capture("bad.pcap", {ethernet(frame(0x07, 0, {0}, 0), true),
                                         ethernet(frame(0x07, 0x0001, {0x11}, 2), false)});
  const auto r = run(fmt::format("{} '{}'", verify_, path.string()));
  EXPECT_EQ(r.status, 1) << r.out << r.err;
  EXPECT_EQ(last_line(r.out), "datagrams=1 wkc_match=0/1 data_match=1/1 malformed=0");
  EXPECT_NE(r.out.find("frame 1 datagram 0 BRD adp=0x0000 ado=0x0000: WKC expected 2, got 1"),
            std::string::npos)
      << r.out;
}

TEST_F(SimVerifyTool, JsonCarriesTheSameSummary) {
  const auto r = run(fmt::format("{} '{}' --json", verify_, good_capture().string()));
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j.at("summary"), "datagrams=3 wkc_match=3/3 data_match=2/2 malformed=0");
  EXPECT_EQ(j.at("wkc_matched"), 3);
  EXPECT_EQ(j.at("passed"), true);
  EXPECT_EQ(j.at("per_command").at("FPRD").at("data_matched"), 1);
}

TEST_F(SimVerifyTool, UnreadableFilesExitTwo) {
  const auto missing = run(fmt::format("{} '{}'", verify_, (dir_ / "missing.pcap").string()));
  EXPECT_EQ(missing.status, 2);
  EXPECT_NE(missing.err.find("missing.pcap: no such capture"), std::string::npos) << missing.err;
  std::ofstream(dir_ / "junk.pcap") << "not a capture";
  const auto junk = run(fmt::format("{} '{}'", verify_, (dir_ / "junk.pcap").string()));
  EXPECT_EQ(junk.status, 2);
  EXPECT_NE(junk.err.find("is neither pcap nor pcapng"), std::string::npos) << junk.err;
  const auto ring = run(fmt::format("{} '{}' --ring '{}'", verify_, good_capture().string(),
                                    (dir_ / "missing.yaml").string()));
  EXPECT_EQ(ring.status, 2) << ring.out;
  const auto profile = run(fmt::format("{} '{}'", profile_, (dir_ / "junk.pcap").string()));
  EXPECT_EQ(profile.status, 2);
}

TEST_F(SimVerifyTool, ProfileWritesImagesRingAndJson) {
  const auto out = dir_ / "profile";
  const auto r =
      run(fmt::format("{} '{}' --out '{}'", profile_, good_capture().string(), out.string()));
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("good.pcap: 2 slave(s)"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(out / "slave0.bin"));
  EXPECT_TRUE(fs::exists(out / "slave1.bin"));
  EXPECT_TRUE(fs::exists(out / "ring.yaml"));
  const auto j = nlohmann::json::parse(ecat::test::read_text_file(out / "profile.json"));
  EXPECT_EQ(j.at("slave_count"), 2);
  EXPECT_EQ(j.at("slaves").at(0).at("station"), "0x1000");
}

TEST_F(SimVerifyTool, SharedCapturesMeetTheTarget) {
  ECAT_SHARED_DATA_OR_SKIP(dc, "captures/replay-dc.pcapng");
  const auto r = run(fmt::format("{} '{}'", verify_, dc.string()));
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(last_line(r.out),
            "datagrams=2838 wkc_match=2838/2838 data_match=2114/2114 malformed=0");
  ECAT_SHARED_DATA_OR_SKIP(empty, "captures/soem-sdinfo-no-slaves.pcapng");
  const auto e = run(fmt::format("{} '{}'", verify_, empty.string()));
  EXPECT_EQ(e.status, 0) << e.out;
  EXPECT_EQ(last_line(e.out), "datagrams=19 wkc_match=19/19 data_match=0/0 malformed=0");
}

}  // namespace
