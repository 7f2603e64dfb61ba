// `--pcap FILE`: the capture a session writes decodes with `ecat decode` (and with tshark when
// installed), every frame the session's link carried, in both directions.
#include <cstdlib>
#include <filesystem>
#include <regex>
#include <string>

#include <gtest/gtest.h>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/tool_runner.hpp"

namespace {

namespace fs = std::filesystem;

std::uint64_t number_after(const std::string& text, const std::string& pattern) {
  std::smatch m;
  if (!std::regex_search(text, m, std::regex(pattern))) return 0;
  return std::stoull(m[1].str());
}

TEST(LiveCaptureTool, RunWritesEveryFrameToPcapng) {
  ASSERT_TRUE(fs::exists(ecat::test::tool_path())) << "ecat tool not found (set ECAT_TOOL)";
  ecat::test::ToolRunner tool("live-capture-test");
  const auto file = (tool.dir() / "run.pcapng").string();
  const auto ring = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
  const auto run = tool.run("run " + ring + " --duration 0.5 --pcap " + file);
  ASSERT_EQ(run.status, 0) << run.err;
  const auto written = number_after(run.err, R"(capture .*: (\d+) frames written)");
  EXPECT_GT(written, 100u) << run.err;
  // Every frame the bus sent and received, no more, no less.
  const auto sent = number_after(run.err, R"(the bus sent (\d+))");
  const auto received = number_after(run.err, R"(and received (\d+))");
  EXPECT_GT(sent, 0u) << run.err;
  EXPECT_EQ(written, sent + received) << run.err;
  EXPECT_EQ(run.err.find("dropped"), std::string::npos) << run.err;

  const auto decoded = tool.run("decode " + file);
  ASSERT_EQ(decoded.status, 0) << decoded.err;
  EXPECT_EQ(number_after(decoded.out, R"(frames=(\d+))"), written);
  EXPECT_EQ(number_after(decoded.out, R"(ethercat=(\d+))"), written);
  // Both directions: the master's source address, and the ESCs' (bit 1 set).
  EXPECT_NE(decoded.out.find("00:00:5e:00:53:00"), std::string::npos);
  EXPECT_NE(decoded.out.find("02:00:5e:00:53:00"), std::string::npos);

  const auto bad = tool.run("run " + ring + " --duration 0.1 --pcap /nonexistent/dir/x.pcapng");
  EXPECT_EQ(bad.status, 2);
  EXPECT_NE(bad.err.find("/nonexistent/dir/x.pcapng"), std::string::npos) << bad.err;

  if (std::system("command -v tshark >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "tshark is not installed: checked with ecat decode only";
  }
  const auto count = tool.run_script("tshark -r " + file + " 2>/dev/null | wc -l");
  EXPECT_EQ(std::stoull(count.out), written);
}

// `ecat serve` keeps a flight recorder; `ecat capture --attach` writes its last seconds.
TEST(LiveCaptureTool, CaptureWritesTheFlightRecorder) {
  ASSERT_TRUE(fs::exists(ecat::test::tool_path())) << "ecat tool not found (set ECAT_TOOL)";
  ecat::test::ToolRunner tool("flight-recorder-test");
  const auto sock = (tool.dir() / "s.sock").string();
  const auto file = (tool.dir() / "fr.pcapng").string();
  const auto ring = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
  const auto run = tool.run_script(
      "\"$ECAT\" serve " + ring + " --control " + sock + " --duration 6 & pid=$!; " +
      "for i in $(seq 40); do \"$ECAT\" capture --attach " + sock + " -o " + file +
      " --seconds 1 2>/dev/null && break; sleep 0.2; done; " + "\"$ECAT\" decode " + file +
      "; kill -INT $pid; wait $pid");
  EXPECT_GT(number_after(run.out, R"(frames=(\d+))"), 0u) << run.out << run.err;
  EXPECT_EQ(number_after(run.out, R"(errors=(\d+))"), 0u);
  // Without a recorder: a clear error.
  const auto off = tool.run_script(
      "\"$ECAT\" serve " + ring + " --control " + sock + " --flight-recorder 0 --duration 6 & " +
      "pid=$!; for i in $(seq 40); do \"$ECAT\" slaves --attach " + sock +
      " >/dev/null 2>&1 && break; sleep 0.2; done; \"$ECAT\" capture --attach " + sock + " -o " +
      file + "; echo status=$?; kill -INT $pid; wait $pid");
  EXPECT_NE(off.out.find("status=1"), std::string::npos) << off.out << off.err;
  EXPECT_NE(off.err.find("no flight recorder"), std::string::npos) << off.err;
}

}  // namespace

namespace {

// `ecat serve --fault-dumps DIR`: a slave dropping out of OP (forced here through the endpoint's
// register write) gets the flight recorder written into DIR, a capture that decodes.
TEST(LiveCaptureTool, AFaultWritesTheFlightRecorder) {
  ASSERT_TRUE(fs::exists(ecat::test::tool_path())) << "ecat tool not found (set ECAT_TOOL)";
  ecat::test::ToolRunner tool("fault-dump-test");
  const auto sock = (tool.dir() / "f.sock").string();
  const auto dumps = tool.dir() / "dumps";
  fs::create_directories(dumps);
  const auto ring = std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
  const auto run = tool.run_script(
      "\"$ECAT\" serve " + ring + " --control " + sock + " --writes --fault-dumps " +
      dumps.string() + " --duration 20 2>" + (tool.dir() / "serve.err").string() +
      " & pid=$!; "
      "for i in $(seq 1 400); do \"$ECAT\" master --attach " +
      sock +
      " --json 2>/dev/null | grep -q '\"state\": \"operational\"' && break; sleep 0.05; done; "
      "\"$ECAT\" reg_write --attach " +
      sock +
      " -p 2 0x0120 0100; "
      "for i in $(seq 1 100); do ls " +
      dumps.string() + " | grep -q pcapng && break; sleep 0.05; done; kill -TERM $pid; wait $pid");
  std::string file;
  for (const auto& entry : fs::directory_iterator(dumps))
    file = entry.path().string();
  ASSERT_FALSE(file.empty()) << run.out << ecat::test::read_text_file(tool.dir() / "serve.err");
  EXPECT_NE(file.find("ecat-fault-"), std::string::npos) << file;
  const auto decoded = tool.run("decode " + file);
  EXPECT_EQ(decoded.status, 0) << decoded.err;
  EXPECT_GT(number_after(decoded.out, R"(ethercat=(\d+))"), 100u) << decoded.out;
}

}  // namespace
