// The master's commands end to end: `ecat demo` (the README's first command), `ecat run` on a
// ring file (positional, --json, backend from the file or --backend) and `ecat slaves --json`.
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR
#include "support/tool_runner.hpp"

namespace ecat::test {
namespace {

using nlohmann::json;

std::string default_ring() {
  return std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml";
}

std::size_t count_of(const std::string& text, const std::string& needle) {
  std::size_t n = 0;
  for (auto at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1))
    ++n;
  return n;
}

TEST(MasterTool, DemoWalksTheBuiltInRingAndShowsProcessData) {
  ToolRunner tool("demo");
  const auto r = tool.run("demo --duration 0");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("awaiting_preop -> operational"), std::string::npos) << r.out;
  // Seven patterns on the EL2809, each seen on the EL1809 through the simulated wiring.
  EXPECT_EQ(count_of(r.out, "followed in"), 7u) << r.out;
  EXPECT_EQ(count_of(r.out, "DID NOT FOLLOW"), 0u) << r.out;
  EXPECT_NE(r.out.find("outputs 1.1..1.11.1..1.1  ->  inputs 1.1..1.11.1..1.1"), std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("channel_1.temperature = 25"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("enable_operation  -> operation_enabled"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("stopped: every slave back in INIT\n"), std::string::npos) << r.out;
}

TEST(MasterTool, RunPrintsAJsonStatusOfTheOperationalRing) {
  ToolRunner tool("run");
  const auto r = tool.run("run '" + default_ring() + "' --duration 0.2 --json");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  const auto doc = json::parse(r.out);
  EXPECT_EQ(doc.at("state"), "operational");
  ASSERT_EQ(doc.at("slaves").size(), 5u);
  for (const auto& s : doc.at("slaves"))
    EXPECT_EQ(s.at("state"), "op") << s.dump();
  ASSERT_EQ(doc.at("domains").size(), 1u);
  EXPECT_EQ(doc.at("domains")[0].at("expected_wkc"), 7);
}

TEST(MasterTool, CtrlCTakesEverySlaveBackToInitAndExitsCleanly) {
  ToolRunner tool("interrupt");
  // SIGINT after 3 s of a run asked to last a minute (exit status: the tool's own).
  const auto r = tool.run_script("\"$ECAT\" run '" + default_ring() +
                                 "' --duration 60 & pid=$!; sleep 3; kill -INT $pid; wait $pid");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("awaiting_preop -> operational"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("stopped: every slave back in INIT\n"), std::string::npos) << r.out;
}

// `ecat run --events`: the event stream live, one line per event; with --json one object per line
// (JSON Lines), the final status included.
TEST(MasterTool, RunShowsTheEventStream) {
  ToolRunner tool("events");
  auto r = tool.run("run '" + default_ring() + "' --duration 0.3 --events --no-chase");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("master.state idle -> discovering"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("slave.state drive: preop -> op"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("domain.state main: open -> cycling"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("master.state operational -> idle"), std::string::npos) << r.out;

  r = tool.run("run '" + default_ring() + "' --duration 0.3 --events --json --no-chase");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  std::istringstream lines(r.out);
  std::string line;
  std::size_t events = 0;
  bool status = false;
  std::uint64_t last_seq = 0;
  while (std::getline(lines, line)) {
    const auto doc = json::parse(line);  // every line is one JSON object
    if (doc.contains("event")) {
      ++events;
      EXPECT_GT(doc.at("seq").get<std::uint64_t>(), last_seq) << line;
      last_seq = doc.at("seq").get<std::uint64_t>();
    } else {
      status = doc.at("state") == "operational";
    }
  }
  EXPECT_GT(events, 10u) << r.out;
  EXPECT_TRUE(status) << r.out;
  EXPECT_NE(r.out.find(R"("event":"master.state","from":"awaiting_preop")"), std::string::npos)
      << r.out;
}

TEST(MasterTool, SlavesJsonListsIdentityAndPorts) {
  ToolRunner tool("slaves");
  const auto r = tool.run("slaves --backend 'sim:" + default_ring() + "' --json");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  const auto list = json::parse(r.out)["slaves"];
  ASSERT_TRUE(list.is_array());
  ASSERT_EQ(list.size(), 5u);
  const auto& inputs = list[1];
  EXPECT_EQ(inputs.at("position"), 1);
  EXPECT_EQ(inputs.at("station"), 0x1001);
  EXPECT_EQ(inputs.at("name"), "slave_1");
  EXPECT_EQ(inputs.at("state"), "preop");
  EXPECT_EQ(inputs.at("identity").at("vendor_id"), 2);
  EXPECT_EQ(inputs.at("identity").at("product_code"), 0x07113052);
  EXPECT_TRUE(inputs.at("identity").contains("revision"));
  EXPECT_TRUE(inputs.at("identity").contains("serial"));
  ASSERT_EQ(inputs.at("ports").size(), 4u);
  EXPECT_EQ(inputs.at("ports")[0].at("communication"), true);
  EXPECT_EQ(list[0].at("name"), "coupler");
  EXPECT_EQ(list[0].at("device"), "EK1100 EtherCAT Coupler (2A E-Bus)");
  // The last slave of a line has only its port 0 in use.
  EXPECT_EQ(list[4].at("ports")[1].at("communication"), false);
}

TEST(MasterTool, BackendComesFromTheRingFileAndBadOnesAreNamed) {
  ToolRunner tool("backend");
  const auto ring = tool.dir() / "ring.yaml";
  std::ofstream(ring) << "version: 1\nmaster:\n  backend: sim:" << default_ring()
                      << "\ndomains:\n  - {id: main, period_us: 1000}\nslaves:\n"
                         "  - {name: coupler}\n  - {name: inputs, process_data: main}\n";
  auto r = tool.run("run '" + ring.string() + "' --duration 0 --json");
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_EQ(json::parse(r.out).at("slaves").size(), 2u);

  std::ofstream(ring, std::ios::trunc) << "version: 1\nmaster:\n  backend: serial:/dev/ttyS0\n";
  r = tool.run("run '" + ring.string() + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("master.backend"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("\"serial:/dev/ttyS0\" is not a backend"), std::string::npos) << r.err;

  r = tool.run("slaves --backend nowhere:1");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("nowhere:1"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace ecat::test
