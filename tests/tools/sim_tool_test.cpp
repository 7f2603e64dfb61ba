// `ecat sim`: runs the built tool (env ECAT_TOOL) as a simulator on UDP, talks to it as a master
// would and through its control socket with the client subcommands, then stops it with SIGTERM.
#include <array>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <poll.h>
#include <sched.h>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/link/redundant_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nlohmann::json;
using ::testing::HasSubstr;

std::string tool_path() {
  if (const char* env = std::getenv("ECAT_TOOL")) return env;
  return std::string(ECAT_BINARY_DIR) + "/tools/ecat/ecat";
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

struct ToolRun {
  int status = -1;
  std::string out;
  std::string err;
};

std::vector<std::uint8_t> brd_frame(std::uint8_t index) {
  std::array<std::uint8_t, 64> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  ecat::wire::DatagramHeader header;
  header.command = ecat::wire::Command::brd;
  header.index = index;
  header.address = ecat::wire::physical_address(0, ecat::wire::reg::kType);
  header.length = 1;
  EXPECT_TRUE(builder.add(header).has_value());
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

class SimTool : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           fmt::format("ecat-sim-tool-{}-{}", ::getpid(),
                       ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ring_ = dir_ / "ring.yaml";
    std::ofstream(ring_) << "simulator:\n  slaves:\n    - {name: s0, profile: generic}\n"
                            "    - {name: s1, profile: generic}\n"
                            "    - {name: s2, profile: generic}\n";
    socket_ = (dir_ / "ctl.sock").string();
  }

  void TearDown() override {
    if (child_ > 0) {
      ::kill(child_, SIGKILL);
      ::waitpid(child_, nullptr, 0);
    }
    if (out_fd_ >= 0) ::close(out_fd_);
    fs::remove_all(dir_);
  }

  ToolRun run_tool(const std::string& arguments) const {
    const auto out = dir_ / "stdout";
    const auto err = dir_ / "stderr";
    const auto command =
        fmt::format("'{}' sim {} >'{}' 2>'{}'", tool_path(), arguments, out.string(), err.string());
    const int raw = std::system(command.c_str());
    ToolRun result;
    result.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
    result.out = read_text(out);
    result.err = read_text(err);
    return result;
  }

  // Starts `ecat sim ...` with stdout on a pipe; returns its first line (or "" after 10 s).
  std::string start_server(const std::vector<std::string>& arguments) {
    int pipe_fds[2];
    EXPECT_EQ(::pipe2(pipe_fds, O_CLOEXEC), 0);
    const std::string tool = tool_path();
    std::vector<std::string> args{tool, "sim"};
    args.insert(args.end(), arguments.begin(), arguments.end());
    child_ = ::fork();
    if (child_ == 0) {
      ::dup2(pipe_fds[1], STDOUT_FILENO);
      std::vector<char*> argv;
      for (auto& a : args)
        argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(tool.c_str(), argv.data());
      ::_exit(127);
    }
    ::close(pipe_fds[1]);
    out_fd_ = pipe_fds[0];
    return read_line(10s);
  }

  std::string read_line(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (true) {
      if (const auto nl = pending_.find('\n'); nl != std::string::npos) {
        std::string line = pending_.substr(0, nl);
        pending_.erase(0, nl + 1);
        return line;
      }
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) return {};
      pollfd p{out_fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return {};
      char buffer[512];
      const ssize_t n = ::read(out_fd_, buffer, sizeof buffer);
      if (n <= 0) return {};
      pending_.append(buffer, static_cast<std::size_t>(n));
    }
  }

  // Waits for the child to exit; returns its wait status (or -1 after the timeout).
  int wait_child(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      int status = 0;
      if (::waitpid(child_, &status, WNOHANG) == child_) {
        child_ = -1;
        return status;
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }

  std::uint16_t brd_wkc(ecat::link::Link& link, std::uint8_t index) {
    EXPECT_TRUE(link.send(brd_frame(index)).ok());
    auto r = link.receive(2s);
    EXPECT_TRUE(r.ok());
    if (!r.ok() || !r->has_value()) return 0xFFFF;
    auto decoded = ecat::wire::decode_frame((*r)->frame);
    EXPECT_TRUE(decoded);
    if (!decoded) return 0xFFFF;
    for (const auto& d : *decoded.frame)
      return d.wkc;
    return 0xFFFF;
  }

  fs::path dir_;
  fs::path ring_;
  std::string socket_;
  pid_t child_ = -1;
  int out_fd_ = -1;
  std::string pending_;
};

TEST_F(SimTool, ServesUdpAnswersControlRequestsAndStopsOnSigterm) {
  const std::string first =
      start_server({"--ring", ring_.string(), "--udp", "127.0.0.1:0", "--control", socket_});
  ASSERT_THAT(first, HasSubstr("ecat sim: serving 3 slaves from "));
  const auto at = first.find("udp-server:127.0.0.1:");
  ASSERT_NE(at, std::string::npos) << first;
  const int port = std::stoi(first.substr(at + std::string("udp-server:127.0.0.1:").size()));
  ASSERT_GT(port, 0);
  EXPECT_THAT(first, HasSubstr("control socket " + socket_));

  auto link = ecat::link::UdpLink::connect("127.0.0.1", static_cast<std::uint16_t>(port));
  ASSERT_TRUE(link.ok()) << link.error().describe();
  EXPECT_EQ(brd_wkc(**link, 1), 3);

  auto r = run_tool("status --json --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  json status = json::parse(r.out);
  ASSERT_EQ(status["slaves"].size(), 3u);
  EXPECT_EQ(status["slaves"][2]["name"], "s2");
  EXPECT_EQ(status["slaves"][2]["profile"], "generic");
  EXPECT_EQ(status["counters"]["frames"], 1);
  EXPECT_EQ(status["counters"]["replies"], 1);

  r = run_tool("status --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("s1"));
  EXPECT_THAT(r.out, HasSubstr("frames 1  replies 1  lost 0"));

  r = run_tool("fault inject disconnect s1 --next 2 --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, "injected: next 2 exchanges disconnect s1\n");
  EXPECT_EQ(brd_wkc(**link, 2), 2);

  r = run_tool("fault list --json --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  json list = json::parse(r.out);
  ASSERT_EQ(list["faults"]["queued"].size(), 1u);
  EXPECT_EQ(list["faults"]["queued"][0]["remaining"], 1);
  EXPECT_EQ(brd_wkc(**link, 3), 2);
  EXPECT_EQ(brd_wkc(**link, 4), 3);

  r = run_tool("fault inject wkc_offset -1 --after healthy_exchanges:1 --control '" + socket_ +
               "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, "injected: after 1 healthy exchange: WKC offset -1\n");
  EXPECT_EQ(brd_wkc(**link, 5), 3);
  EXPECT_EQ(brd_wkc(**link, 6), 2);
  r = run_tool("fault clear --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(brd_wkc(**link, 7), 3);

  r = run_tool("fault inject --json '{\"kind\":\"drop_responses\",\"next\":1}' --control '" +
               socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, "injected: next exchange drop responses\n");

  // Refused by the simulator: exit 1 and its message.
  r = run_tool("fault inject disconnect nobody --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(r.err, "ecat sim: unknown slave 'nobody' (known: s0, s1, s2)\n");
  // Refused before asking: exit 2.
  r = run_tool("fault inject disconnect --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("disconnect: expected 1 argument, got 0"));
  r = run_tool("fault inject power_cycle s0 --next 3 --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("'next' applies only to exchange and reply faults"));
  r = run_tool("set s0.channel_1 1 --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("slave 's0' has no signal 'channel_1'"));
  r = run_tool("set s0 1 --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 2);

  ASSERT_EQ(::kill(child_, SIGTERM), 0);
  const std::string last = read_line(10s);
  EXPECT_THAT(last, HasSubstr("stopped by SIGTERM"));
  const int exit_status = wait_child(10s);
  ASSERT_NE(exit_status, -1) << "ecat sim did not exit after SIGTERM";
  EXPECT_TRUE(WIFEXITED(exit_status));
  EXPECT_EQ(WEXITSTATUS(exit_status), 0);
  EXPECT_FALSE(fs::exists(socket_));
}

TEST_F(SimTool, PrintsASummaryEverySecondAndStopsOnSigint) {
  const std::string first = start_server(
      {"--ring", ring_.string(), "--udp", "127.0.0.1:0", "--control", socket_, "--summary"});
  ASSERT_THAT(first, HasSubstr("ecat sim: serving 3 slaves"));
  const std::string summary = read_line(5s);
  EXPECT_THAT(
      summary,
      HasSubstr(
          "frames 0 (+0/s)  replies 0  lost 0  delayed 0  duplicated 0  malformed 0  OP 0/3"));
  ASSERT_EQ(::kill(child_, SIGINT), 0);
  std::string last;
  for (int i = 0; i < 5; ++i) {
    last = read_line(10s);
    if (last.find("stopped") != std::string::npos) break;
  }
  EXPECT_THAT(last, HasSubstr("stopped by SIGINT"));
  const int exit_status = wait_child(10s);
  ASSERT_NE(exit_status, -1);
  EXPECT_EQ(WEXITSTATUS(exit_status), 0);
}

TEST_F(SimTool, UsageErrors) {
  auto r = run_tool("--ring '" + (dir_ / "missing.yaml").string() + "' --udp 127.0.0.1:0");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("missing.yaml: no such ring file"));
  r = run_tool("--ring '" + ring_.string() + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("give exactly one of --udp ADDR:PORT and --interface IFACE"));
  r = run_tool("--ring '" + ring_.string() + "' --udp 127.0.0.1:0 --redundant-interface eth9");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("--redundant-interface serves the ring's second master port on a "
                               "raw interface: give the first with --interface IFACE"));
  r = run_tool("--ring '" + ring_.string() + "' --interface eth9 --redundant-interface eth9");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("--interface and --redundant-interface are both eth9"));
  r = run_tool("--ring '" + ring_.string() + "' --udp 127.0.0.1:99999");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(
      r.err,
      HasSubstr(
          "--udp '127.0.0.1:99999': expected [ADDR:]PORT with PORT a number from 0 to 65535"));
  std::ofstream(ring_) << "simulator:\n  slaves:\n    - {name: s0, profile: EL9999}\n";
  r = run_tool("--ring '" + ring_.string() + "' --udp 127.0.0.1:0");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr(ring_.string() +
                               ":3: simulator.slaves[0].profile: unknown profile 'EL9999'"));
  r = run_tool("status --control '" + (dir_ / "none.sock").string() + "'");
  EXPECT_EQ(r.status, 2);
  EXPECT_THAT(r.err, HasSubstr("cannot reach the simulator"));
}

TEST_F(SimTool, ListsProfilesAndFaultKinds) {
  auto r = run_tool("profiles");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("generic"));
  r = run_tool("fault kinds");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("mailbox_abort SLAVE INDEX:SUB CODE [STAGE]"));
  EXPECT_THAT(r.out, HasSubstr("delay_replies MS"));
}

// The test thread in a private network namespace with two veth pairs, `master` <-> `segment` and
// `master2` <-> `segment2` (children forked from this thread live there too); back out at the end.
class TwoVethPairs {
 public:
  TwoVethPairs() {
    if (::geteuid() != 0) {
      why_not_ = "needs root for a private network namespace with two veth pairs";
      return;
    }
    original_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
    if (original_ < 0 || ::unshare(CLONE_NEWNET) != 0) {
      why_not_ = fmt::format("network namespaces are not available: {}", std::strerror(errno));
      return;
    }
    inside_ = true;
    for (const char* command : {"ip link add name master type veth peer name segment",
                                "ip link add name master2 type veth peer name segment2",
                                "ip link set dev master up", "ip link set dev segment up",
                                "ip link set dev master2 up", "ip link set dev segment2 up"}) {
      const int status = std::system((std::string(command) + " >/dev/null 2>&1").c_str());
      if (status == -1 || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
        why_not_ = fmt::format("`{}` failed (iproute2 and the veth driver needed)", command);
        return;
      }
    }
  }
  ~TwoVethPairs() {
    if (inside_) (void)::setns(original_, CLONE_NEWNET);
    if (original_ >= 0) ::close(original_);
  }
  TwoVethPairs(const TwoVethPairs&) = delete;
  TwoVethPairs& operator=(const TwoVethPairs&) = delete;
  const std::string& why_not() const { return why_not_; }

 private:
  int original_ = -1;
  bool inside_ = false;
  std::string why_not_;
};

TEST_F(SimTool, ServesARedundantRingOnTwoInterfacesAndBreaksItOnRequest) {
  TwoVethPairs ns;
  if (!ns.why_not().empty()) GTEST_SKIP() << ns.why_not();
  const std::string first =
      start_server({"--ring", ring_.string(), "--interface", "segment", "--redundant-interface",
                    "segment2", "--control", socket_});
  ASSERT_THAT(first, HasSubstr("ecat sim: serving 3 slaves from "));
  EXPECT_THAT(first, HasSubstr("segment (primary) and segment2 (secondary"));
  auto link = ecat::link::RedundantLink::open_raw("master", "master2");
  ASSERT_TRUE(link.ok()) << link.error().describe();
  // This sender waits up to 2 s for a reply (brd_wkc): on a loaded host the two sides of a
  // broken ring may answer more than the 500 us merge window apart, and are merged within it.
  (*link)->set_frame_budget(2s);
  EXPECT_EQ(brd_wkc(**link, 1), 3);
  EXPECT_EQ((*link)->status().ring, ecat::link::RingState::whole);

  auto r = run_tool("fault inject ring_break 1 --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("ring break after slave 1"));
  // Both halves answer: the coupler by the primary, the two behind the break by the secondary.
  EXPECT_EQ(brd_wkc(**link, 2), 3);
  EXPECT_EQ((*link)->status().ring, ecat::link::RingState::broken);
  EXPECT_GT((*link)->status().merged, 0u);
  r = run_tool("status --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("redundant ring:   break after 1"));
  EXPECT_THAT(r.out, HasSubstr("master ports:     frames "));
  EXPECT_THAT(r.out, HasSubstr(" bounced  lost "));
  r = run_tool("fault inject ring_break 3 --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("cannot break after slave 3 (1..2)"));
  r = run_tool("fault inject ring_heal --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(brd_wkc(**link, 3), 3);
  EXPECT_EQ((*link)->status().ring, ecat::link::RingState::whole);

  ::kill(child_, SIGTERM);
  std::string last;
  for (int i = 0; i < 5; ++i) {
    last = read_line(10s);
    if (last.find("stopped") != std::string::npos) break;
  }
  EXPECT_THAT(last, HasSubstr("stopped by SIGTERM"));
  const int exit_status = wait_child(10s);
  ASSERT_NE(exit_status, -1);
  EXPECT_EQ(WEXITSTATUS(exit_status), 0);
}

}  // namespace

TEST_F(SimTool, PlugsAndUnplugsAHotConnectGroup) {
  std::ofstream(ring_) << "simulator:\n  slaves:\n    - {name: s0, profile: generic}\n"
                          "    - {name: s1, profile: generic,"
                          " hot_connect: {group: tool, plugged: false}}\n"
                          "    - {name: s2, profile: generic}\n";
  const std::string first =
      start_server({"--ring", ring_.string(), "--udp", "127.0.0.1:0", "--control", socket_});
  const auto at = first.find("udp-server:127.0.0.1:");
  ASSERT_NE(at, std::string::npos) << first;
  const int port = std::stoi(first.substr(at + std::string("udp-server:127.0.0.1:").size()));
  auto link = ecat::link::UdpLink::connect("127.0.0.1", static_cast<std::uint16_t>(port));
  ASSERT_TRUE(link.ok()) << link.error().describe();
  EXPECT_EQ(brd_wkc(**link, 1), 1);  // the group is unplugged: s0 alone

  auto plugged = [&] {
    auto r = run_tool("status --json --control '" + socket_ + "'");
    EXPECT_EQ(r.status, 0) << r.err;
    json status = json::parse(r.out);
    EXPECT_EQ(status["hot_connect"].size(), 1u);
    EXPECT_EQ(status["hot_connect"][0]["group"], "tool");
    EXPECT_EQ(status["hot_connect"][0]["first"], "s1");
    EXPECT_EQ(status["hot_connect"][0]["slaves"], 2);
    return status["hot_connect"][0]["plugged"].get<bool>();
  };
  EXPECT_FALSE(plugged());
  auto r = run_tool("plug tool --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(plugged());
  EXPECT_EQ(brd_wkc(**link, 2), 3);
  r = run_tool("unplug tool --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_FALSE(plugged());
  EXPECT_EQ(brd_wkc(**link, 3), 1);
  r = run_tool("plug nothing --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("no hot-connect group 'nothing' (known: tool)"));
  // The same as faults: ecat sim fault inject hot_plug / hot_unplug.
  r = run_tool("fault inject hot_plug tool --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(plugged());
  EXPECT_EQ(brd_wkc(**link, 4), 3);
  r = run_tool("fault inject hot_unplug tool --control '" + socket_ + "'");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_FALSE(plugged());
  r = run_tool("fault inject hot_unplug nothing --control '" + socket_ + "'");
  EXPECT_EQ(r.status, 1);
  EXPECT_THAT(r.err, HasSubstr("hot_unplug: unknown hot-connect group 'nothing' (known: tool)"));
}
