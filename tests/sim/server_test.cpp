// SimServer on every link it serves: the in-process function link (deterministic), a memory pair,
// UDP on 127.0.0.1 with an OS-chosen port, and a raw veth pair in a private network namespace
// (root only). Plus the control channel (requests, bad requests, the socket) and open_backend.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <linux/capability.h>
#include <nlohmann/json.hpp>
#include <poll.h>
#include <sched.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/sim/backend.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

namespace ecat::sim {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;
using ::testing::HasSubstr;
using ::testing::StartsWith;
using wire::Command;
namespace fs = std::filesystem;
namespace reg = wire::reg;

constexpr std::int64_t kMs = 1'000'000;

std::vector<std::uint8_t> brd_frame(std::uint8_t index = 0x11) {
  std::array<std::uint8_t, 64> buffer{};
  wire::FrameBuilder builder(buffer);
  wire::DatagramHeader header;
  header.command = Command::brd;
  header.index = index;
  header.address = wire::physical_address(0, reg::kType);
  header.length = 1;
  EXPECT_TRUE(builder.add(header).has_value());
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

struct Decoded {
  std::uint16_t wkc = 0xFFFF;
  std::uint8_t index = 0;
  std::vector<std::uint8_t> data;
};

Decoded decode(wire::Bytes bytes) {
  Decoded out;
  auto decoded = wire::decode_frame(bytes);
  EXPECT_TRUE(decoded) << decoded.error.describe();
  if (!decoded) return out;
  for (const auto& d : *decoded.frame) {
    out.wkc = d.wkc;
    out.index = d.header.index;
    out.data.assign(d.data.begin(), d.data.end());
    break;
  }
  return out;
}

std::unique_ptr<Segment> generic_segment(std::size_t slaves) {
  auto segment = std::make_unique<Segment>();
  for (std::size_t i = 0; i < slaves; ++i) {
    auto esc = make_device(DeviceConfig{});
    EXPECT_TRUE(esc.ok());
    EXPECT_TRUE(segment->add_slave("s" + std::to_string(i), std::move(*esc)).ok());
  }
  return segment;
}

// A manual clock: tests decide when time passes.
struct ManualClock {
  std::shared_ptr<std::int64_t> t = std::make_shared<std::int64_t>(10'000 * kMs);
  std::function<std::int64_t()> fn() const {
    auto p = t;
    return [p] { return *p; };
  }
};

std::vector<std::uint8_t> receive_one(link::Link& link, std::chrono::nanoseconds timeout = 2s) {
  auto r = link.receive(timeout);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().describe());
  if (!r.ok() || !r->has_value()) return {};
  return {(*r)->frame.begin(), (*r)->frame.end()};
}

// ---- Function link and synchronous exchange ------------------------------------------------

TEST(SimServerFunctionLink, AnswersInTheCallersThread) {
  SimServer server(generic_segment(3));
  auto link = server.function_link("sim:test");
  EXPECT_EQ(link->name(), "sim:test");
  ASSERT_TRUE(link->send(brd_frame()).ok());
  const auto reply = receive_one(*link, 0ns);
  ASSERT_FALSE(reply.empty());
  EXPECT_EQ(decode(reply).wkc, 3);
  EXPECT_EQ(decode(reply).index, 0x11);
  EXPECT_EQ(decode(reply).data, std::vector<std::uint8_t>{0x11});  // ESC type
  // Nothing more: the function link never waits.
  auto none = link->receive(1s);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
  const auto stats = server.stats();
  EXPECT_EQ(stats.frames, 1u);
  EXPECT_EQ(stats.replies, 1u);
  EXPECT_FALSE(server.serving());
}

TEST(SimServerFunctionLink, PaddingIsNotEchoedAndGarbageIsIgnored) {
  SimServer server(generic_segment(1));
  auto frame = brd_frame();
  const std::size_t length = frame.size();
  frame.resize(46, 0);  // Ethernet padding after the EtherCAT frame
  auto replies = server.exchange(frame);
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0].size(), length);
  const std::vector<std::uint8_t> garbage{0x05, 0x10, 0xFF};
  EXPECT_TRUE(server.exchange(garbage).empty());
  EXPECT_EQ(server.stats().malformed, 1u);
  EXPECT_EQ(server.stats().lost, 0u);
}

TEST(SimServerFunctionLink, ReplyFaultsShapeWhatLeaves) {
  ManualClock clock;
  SimServerOptions options;
  options.clock = clock.fn();
  SimServer server(generic_segment(2), options);

  ASSERT_TRUE(server.inject(fault::next(fault::duplicate_reply(), 1)).ok());
  EXPECT_EQ(server.exchange(brd_frame(1)).size(), 2u);
  EXPECT_EQ(server.stats().duplicated, 1u);
  EXPECT_EQ(server.stats().replies, 2u);

  ASSERT_TRUE(server.inject(fault::next(fault::drop_responses(), 1)).ok());
  EXPECT_TRUE(server.exchange(brd_frame(2)).empty());
  EXPECT_EQ(server.stats().lost, 1u);

  // Reorder: the first reply is held and follows the second.
  ASSERT_TRUE(server.inject(fault::next(fault::reorder_replies(), 1)).ok());
  EXPECT_TRUE(server.exchange(brd_frame(3)).empty());
  auto replies = server.exchange(brd_frame(4));
  ASSERT_EQ(replies.size(), 2u);
  EXPECT_EQ(decode(replies[0]).index, 4);
  EXPECT_EQ(decode(replies[1]).index, 3);

  // Delay: the reply comes out with the first exchange after it is due.
  ASSERT_TRUE(server.inject(fault::next(fault::delay_replies(5ms), 1)).ok());
  EXPECT_TRUE(server.exchange(brd_frame(5)).empty());
  *clock.t += 4 * kMs;
  replies = server.exchange(brd_frame(6));
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(decode(replies[0]).index, 6);
  *clock.t += 1 * kMs;
  replies = server.exchange(brd_frame(7));
  ASSERT_EQ(replies.size(), 2u);
  EXPECT_EQ(decode(replies[0]).index, 5);
  EXPECT_EQ(decode(replies[1]).index, 7);

  // clear_faults also forgets held and delayed replies.
  ASSERT_TRUE(server.inject(fault::next(fault::delay_replies(1ms), 1)).ok());
  EXPECT_TRUE(server.exchange(brd_frame(8)).empty());
  server.clear_faults();
  *clock.t += 2 * kMs;
  EXPECT_EQ(server.exchange(brd_frame(9)).size(), 1u);
  EXPECT_EQ(server.stats().delayed, 3u);
}

TEST(SimServerControl, ThreadSafeOperations) {
  SimServer server(generic_segment(2));
  auto bytes = server.read_memory("s1", reg::kType, 1);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, std::vector<std::uint8_t>{0x11});
  auto bad = server.read_memory("s1", 0xFFFF, 4);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code(), Errc::out_of_range);
  auto unknown = server.signal("nope", "x");
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().message(), "unknown slave 'nope' (known: s0, s1)");
  auto no_signal = server.signal("s0", "channel_1");
  ASSERT_FALSE(no_signal.ok());
  EXPECT_EQ(no_signal.error().message(), "slave 's0' has no signal 'channel_1' (known: none)");

  ASSERT_TRUE(server.set_link("s0", 1, false).ok());
  EXPECT_EQ(decode(server.exchange(brd_frame()).at(0)).wkc, 1);
  EXPECT_EQ(server.status().slaves.at(1).links[0], false);
  ASSERT_TRUE(server.set_link("s0", 1, true).ok());
  server.set_master_link(false);
  EXPECT_TRUE(server.exchange(brd_frame()).empty());
  server.set_master_link(true);
  EXPECT_EQ(decode(server.exchange(brd_frame()).at(0)).wkc, 2);
  ASSERT_TRUE(server.power_cycle("s1").ok());
  EXPECT_FALSE(server.power_cycle("x").ok());

  const SimStatus status = server.status();
  ASSERT_EQ(status.slaves.size(), 2u);
  EXPECT_EQ(status.slaves[0].name, "s0");
  EXPECT_EQ(status.slaves[0].vendor_id, 0x00000ACEu);
  EXPECT_EQ(status.slaves[0].al_state, wire::AlState::init);
  EXPECT_TRUE(status.slaves[0].dc);
  EXPECT_EQ(status.counters.frames, 3u);
  EXPECT_EQ(status.counters.lost, 1u);
}

// ---- Serving threads -------------------------------------------------------------------------

TEST(SimServerThread, ServesAMemoryPairAndAdvancesWhileIdle) {
  SimServer server(generic_segment(4));
  auto master = server.serve_memory();
  ASSERT_TRUE(master.ok()) << master.error().describe();
  EXPECT_TRUE(server.serving());
  EXPECT_EQ(server.status().link, "memory:b");
  for (std::uint8_t i = 0; i < 20; ++i) {
    ASSERT_TRUE((*master)->send(brd_frame(i)).ok());
    const auto reply = receive_one(**master);
    ASSERT_FALSE(reply.empty());
    EXPECT_EQ(decode(reply).wkc, 4);
    EXPECT_EQ(decode(reply).index, i);
  }
  const auto advances = server.stats().idle_advances;
  std::this_thread::sleep_for(50ms);
  // At least 1 kHz while idle; a loaded machine may lose some, but not most.
  EXPECT_GE(server.stats().idle_advances - advances, 10u);
  auto again = server.serve_memory();
  ASSERT_FALSE(again.ok());
  EXPECT_EQ(again.error().code(), Errc::wrong_state);
  server.stop();
  EXPECT_FALSE(server.serving());
  // Served again after a stop.
  master = server.serve_memory();
  ASSERT_TRUE(master.ok());
  ASSERT_TRUE((*master)->send(brd_frame(99)).ok());
  EXPECT_EQ(decode(receive_one(**master)).index, 99);
}

TEST(SimServerThread, TimedFaultsFireWhileIdle) {
  SimServer server(generic_segment(1));
  auto master = server.serve_memory();
  ASSERT_TRUE(master.ok());
  ASSERT_TRUE(server.inject(fault::after(fault::drop_responses(), 5ms)).ok());
  std::this_thread::sleep_for(40ms);
  const auto info = server.fault_info();
  EXPECT_TRUE(info.scheduled.empty());
  EXPECT_TRUE(info.drop_responses);
  ASSERT_TRUE((*master)->send(brd_frame()).ok());
  auto r = (*master)->receive(50ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(SimServerThread, DelayedRepliesLeaveOnTime) {
  SimServer server(generic_segment(1));
  auto master = server.serve_memory();
  ASSERT_TRUE(master.ok());
  ASSERT_TRUE(server.inject(fault::next(fault::delay_replies(30ms), 1)).ok());
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE((*master)->send(brd_frame(7)).ok());
  const auto reply = receive_one(**master, 2s);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  ASSERT_FALSE(reply.empty());
  EXPECT_EQ(decode(reply).index, 7);
  EXPECT_GE(elapsed, 29ms);
  EXPECT_LT(elapsed, 1s);
}

TEST(SimServerThread, ServesUdpOnAnOsChosenPort) {
  SimServer server(generic_segment(2));
  auto udp = link::UdpLink::serve("127.0.0.1", 0);
  ASSERT_TRUE(udp.ok()) << udp.error().describe();
  const std::uint16_t port = (*udp)->local_port();
  ASSERT_NE(port, 0);
  ASSERT_TRUE(server.serve(std::move(*udp)).ok());
  EXPECT_THAT(server.status().link, HasSubstr(std::to_string(port)));
  auto client = link::UdpLink::connect("127.0.0.1", port);
  ASSERT_TRUE(client.ok()) << client.error().describe();
  for (std::uint8_t i = 0; i < 10; ++i) {
    ASSERT_TRUE((*client)->send(brd_frame(i)).ok());
    const auto reply = receive_one(**client);
    ASSERT_FALSE(reply.empty());
    EXPECT_EQ(decode(reply).wkc, 2);
    EXPECT_EQ(decode(reply).index, i);
  }
  // Garbage gets no answer and is counted.
  const std::vector<std::uint8_t> garbage{1, 2, 3};
  ASSERT_TRUE((*client)->send(garbage).ok());
  auto none = (*client)->receive(100ms);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
  EXPECT_EQ(server.stats().malformed, 1u);
  EXPECT_EQ(server.stats().replies, 10u);
  server.stop();
}

// ---- Raw veth in a private network namespace --------------------------------------------------

bool has_capability(int cap) {
  __user_cap_header_struct header{_LINUX_CAPABILITY_VERSION_3, 0};
  std::array<__user_cap_data_struct, 2> data{};
  if (::syscall(SYS_capget, &header, data.data()) != 0) return false;
  return (data[static_cast<std::size_t>(cap / 32)].effective & (1u << (cap % 32))) != 0;
}

bool run(const std::string& command) {
  const int status = std::system((command + " >/dev/null 2>&1").c_str());
  return status != -1 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

TEST(SimServerRaw, AnswersOnAVethPairAsAResponder) {
  if (!has_capability(CAP_NET_ADMIN) || !has_capability(CAP_NET_RAW) ||
      !has_capability(CAP_SYS_ADMIN)) {
    GTEST_SKIP() << "needs root to create a network namespace with a veth pair";
  }
  if (!run("command -v ip")) GTEST_SKIP() << "the `ip` command is not installed";
  // The namespace belongs to this thread; the kernel removes it (and the veths) once the thread
  // is gone and every socket is closed.
  std::string failure;
  bool skipped = false;
  std::thread worker([&] {
    if (::unshare(CLONE_NEWNET) != 0) {
      skipped = true;
      return;
    }
    for (const char* knob : {"/proc/sys/net/ipv6/conf/default/disable_ipv6",
                             "/proc/sys/net/ipv6/conf/all/disable_ipv6"}) {
      std::ofstream(knob) << "1\n";
    }
    if (!run("ip link add name m type veth peer name s") || !run("ip link set dev m up") ||
        !run("ip link set dev s up") || !run("ip link set dev m address 10:00:00:00:00:0a")) {
      skipped = true;
      return;
    }
    SimServer server(generic_segment(3));
    link::RawLinkOptions sim_options;
    sim_options.interface = "s";
    sim_options.responder = true;
    auto sim_link = link::RawLink::open(sim_options);
    if (!sim_link.ok()) {
      failure = sim_link.error().describe();
      return;
    }
    if (auto r = server.serve(std::move(*sim_link)); !r) {
      failure = r.error().describe();
      return;
    }
    link::RawLinkOptions master_options;
    master_options.interface = "m";
    auto master = link::RawLink::open(master_options);
    if (!master.ok()) {
      failure = master.error().describe();
      return;
    }
    for (std::uint8_t i = 0; i < 5; ++i) {
      if (!(*master)->send(brd_frame(i)).ok()) {
        failure = "send failed";
        return;
      }
      auto r = (*master)->receive(2s);
      if (!r.ok() || !r->has_value()) {
        failure = "no reply to frame " + std::to_string(i);
        return;
      }
      const auto d = decode((*r)->frame);
      if (d.wkc != 3 || d.index != i) {
        failure = "wrong reply to frame " + std::to_string(i);
        return;
      }
      // A responder marks the source address as a real ESC does (bit 1 of the first byte).
      if ((*r)->source[0] != 0x12) failure = "the reply's source address is not rewritten";
    }
    server.stop();
  });
  worker.join();
  if (skipped) GTEST_SKIP() << "network namespaces or veth are not available";
  EXPECT_EQ(failure, "");
}

// ---- Control channel ---------------------------------------------------------------------------

json call(SimServer& server, const std::string& request) {
  const std::string reply = handle_control_request(server, request);
  EXPECT_EQ(reply.find('\n'), std::string::npos);
  auto parsed = json::parse(reply, nullptr, false);
  EXPECT_FALSE(parsed.is_discarded()) << reply;
  return parsed;
}

TEST(ControlRequests, StatusFaultsAndSlaves) {
  SimServer server(generic_segment(2));
  json status = call(server, R"({"op":"status","id":7})");
  ASSERT_EQ(status["ok"], true);
  EXPECT_EQ(status["id"], 7);
  ASSERT_EQ(status["slaves"].size(), 2u);
  EXPECT_EQ(status["slaves"][1]["name"], "s1");
  EXPECT_EQ(status["slaves"][1]["al_state"], "INIT");
  EXPECT_EQ(status["slaves"][1]["links"][0], true);
  EXPECT_EQ(status["counters"]["frames"], 0);

  json r =
      call(server, R"({"op":"fault.inject","fault":{"kind":"disconnect","slave":"s1","next":30}})");
  EXPECT_EQ(r["ok"], true);
  EXPECT_EQ(r["description"], "next 30 exchanges disconnect s1");
  r = call(server, R"({"op":"fault.inject","fault":{"after_ms":100,"fault":"drop_responses"}})");
  EXPECT_EQ(r["description"], "after 100 ms: drop responses");
  r = call(server, R"({"op":"fault.list","id":"x"})");
  EXPECT_EQ(r["id"], "x");
  ASSERT_EQ(r["faults"]["queued"].size(), 1u);
  EXPECT_EQ(r["faults"]["queued"][0]["remaining"], 30);
  ASSERT_EQ(r["faults"]["scheduled"].size(), 1u);
  EXPECT_GT(r["faults"]["scheduled"][0]["due_in_ns"].get<std::int64_t>(), 0);
  EXPECT_EQ(r["faults"]["disconnected"][0], "s1");

  EXPECT_EQ(decode(server.exchange(brd_frame()).at(0)).wkc, 1);
  status = call(server, R"({"op":"status"})");
  EXPECT_EQ(status["counters"]["frames"], 1);
  EXPECT_EQ(status["counters"]["replies"], 1);
  EXPECT_EQ(status["faults"]["queued"][0]["remaining"], 29);

  r = call(server, R"({"op":"fault.clear"})");
  EXPECT_EQ(r["ok"], true);
  EXPECT_EQ(call(server, R"({"op":"fault.list"})")["faults"]["scheduled"].size(), 0u);

  r = call(server, R"({"op":"link","slave":"s0","port":1,"up":false})");
  EXPECT_EQ(r["ok"], true);
  EXPECT_EQ(decode(server.exchange(brd_frame()).at(0)).wkc, 1);
  call(server, R"({"op":"link","slave":"s0","port":1,"up":true})");
  r = call(server, R"({"op":"link","up":false})");
  EXPECT_EQ(r["ok"], true);
  EXPECT_TRUE(server.exchange(brd_frame()).empty());
  call(server, R"({"op":"link","up":true})");
  r = call(server, R"({"op":"memory.read","slave":"s0","address":"0x0000","length":2})");
  EXPECT_EQ(r["bytes"], "1100");
  r = call(server, R"({"op":"power_cycle","slave":"s1"})");
  EXPECT_EQ(r["ok"], true);
  r = call(server, R"({"op":"profiles"})");
  EXPECT_EQ(r["profiles"][0]["name"], "generic");
  EXPECT_EQ(call(server, R"({"op":"ping"})")["ok"], true);
}

TEST(ControlRequests, BadRequestsNameWhatWasWrong) {
  SimServer server(generic_segment(1));
  const auto error = [&](const std::string& request) {
    json r = call(server, request);
    EXPECT_EQ(r["ok"], false) << request;
    return r.contains("error") ? r["error"].get<std::string>() : std::string();
  };
  // JSON errors name the byte (from 0) where the text stopped being valid, and why.
  EXPECT_EQ(error("not json"),
            "request: invalid JSON at byte 1: syntax error while parsing value - invalid "
            "literal; last read: 'no'");
  EXPECT_THAT(error(R"({"op":"ping")"), StartsWith("request: invalid JSON at byte 12 (the end): "));
  EXPECT_THAT(error(R"({"op":"ping"} x)"),
              StartsWith("request: invalid JSON at byte 14: syntax error while parsing value"));
  EXPECT_EQ(error(R"({"op":"ping", "id":1, "op":"status"})"),
            "request: invalid JSON at byte 22: duplicate key 'op'");
  EXPECT_THAT(error(R"({"op":"ping","id":1e400})"),
              StartsWith("request: invalid JSON at byte 22: number overflow parsing '1e400'"));
  EXPECT_THAT(error("{\"op\":\"ping\",\"id\":\"\x01\"}"),
              StartsWith("request: invalid JSON at byte 19: syntax error while parsing value - "
                         "invalid string: control character U+0001"));
  // Integers and fractions stay apart: a port is an integer, 1.0 is not.
  EXPECT_EQ(error(R"({"op":"link","slave":"s0","port":1.0,"up":false})"),
            "port: '1.0' is not an integer (decimal or 0x hex)");
  EXPECT_EQ(error("[1,2]"), "request: expected a JSON object, found a list");
  EXPECT_EQ(error("{}"), R"(op: missing (e.g. {"op":"status"}))");
  EXPECT_THAT(error(R"({"op":"explode"})"),
              StartsWith("op: unknown op 'explode' (known: status, fault.inject,"));
  EXPECT_EQ(error(R"({"op":"status","verbose":true})"), "verbose: unknown key (known: op, id)");
  EXPECT_EQ(error(R"({"op":"fault.inject"})"), "missing key 'fault'");
  EXPECT_EQ(error(R"({"op":"fault.inject","fault":{"kind":"disconnect","slave":"zz"}})"),
            "unknown slave 'zz' (known: s0)");
  EXPECT_EQ(error(R"({"op":"fault.inject","fault":{"kind":"wkc_offset","delta":1e99}})"),
            "fault.delta: '1e99' is not an integer (decimal or 0x hex)");
  EXPECT_EQ(error(R"({"op":"signal.set","slave":"s0","signal":"x"})"), "missing key 'value'");
  EXPECT_EQ(error(R"({"op":"signal.set","slave":"s0","signal":"x","value":"high"})"),
            "value: 'high' is not a number");
  EXPECT_EQ(error(R"({"op":"link","slave":"s0","port":9,"up":false})"),
            "port: 9 is out of range (0 to 3)");
  EXPECT_EQ(error(R"({"op":"link","port":1,"up":false})"),
            "port: the master link has no port (give a slave for a slave's port)");
  EXPECT_EQ(error(R"({"op":"memory.read","slave":"s0","address":70000,"length":1})"),
            "address: 70000 is out of range (0 to 65535)");
  EXPECT_EQ(error(R"({"op":"status","id":[1]})"), "id: expected a string or a number");
  EXPECT_THAT(error(std::string(kMaxControlLine + 10, '{')),
              StartsWith("request: longer than 65536 bytes"));
  // The 33rd bracket is refused where it opens, before anything deeper is built.
  EXPECT_EQ(error(std::string(200, '[') + std::string(200, ']')),
            "request: invalid JSON at byte 32: nested deeper than 32 levels");
  EXPECT_EQ(error(R"({"op":"ping","id":)" + std::string(50'000, '[')),
            "request: invalid JSON at byte 49: nested deeper than 32 levels");
  EXPECT_EQ(error(R"({"op":"ping","id":)" + std::string(31, '[') + std::string(31, ']') + "}"),
            "id: expected a string or a number");  // 32 levels are still read
  // A string with bytes that are not UTF-8 still yields a parsable reply.
  json r = call(server, "{\"op\":\"signal.get\",\"slave\":\"\xff\xfe\",\"signal\":\"x\"}");
  EXPECT_EQ(r["ok"], false);
  EXPECT_THAT(r["error"].get<std::string>(),
              StartsWith("request: invalid JSON at byte 28: syntax error while parsing value - "
                         "invalid string: ill-formed UTF-8 byte"));
}

TEST(ControlRequests, TheIdIsEchoedAsWritten) {
  SimServer server(generic_segment(1));
  EXPECT_EQ(handle_control_request(server, R"({"op":"ping","id":7})"), R"({"ok":true,"id":7})");
  EXPECT_EQ(handle_control_request(server, R"({"id":"a\"b","op":"ping"})"),
            R"({"ok":true,"id":"a\"b"})");
  EXPECT_EQ(handle_control_request(server, R"({"op":"ping","id":null})"),
            R"({"ok":true,"id":null})");
  EXPECT_EQ(handle_control_request(server, R"({"op":"ping","id":-2.5})"),
            R"({"ok":true,"id":-2.5})");
  EXPECT_EQ(handle_control_request(server, R"({"op":"ping","id":18446744073709551615})"),
            R"({"ok":true,"id":18446744073709551615})");
  EXPECT_EQ(
      handle_control_request(server, R"({"op":"nope","id":true})"),
      R"x({"ok":false,"id":true,"error":"op: unknown op 'nope' (known: status, )x"
      R"x(fault.inject, fault.clear, fault.list, signals, signal.get, signal.set, )x"
      R"x(signal.clear, power_cycle, link, memory.read, profiles, ring, ping, hotconnect)"})x");
}

class ControlSocket : public ::testing::Test {
 protected:
  void SetUp() override {
    path = (fs::temp_directory_path() /
            fmt::format("ecat-ctl-{}-{}.sock", ::getpid(),
                        ::testing::UnitTest::GetInstance()->current_test_info()->name()))
               .string();
    auto started = ControlServer::start(server, path);
    ASSERT_TRUE(started.ok()) << started.error().describe();
    control = std::move(*started);
  }
  SimServer server{generic_segment(2)};
  std::string path;
  std::unique_ptr<ControlServer> control;
};

TEST_F(ControlSocket, AnswersOneLinePerRequest) {
  auto reply = control_call(path, R"({"op":"status"})");
  ASSERT_TRUE(reply.ok()) << reply.error().describe();
  json status = json::parse(*reply);
  EXPECT_EQ(status["slaves"].size(), 2u);
  reply = control_call(path, "garbage");
  ASSERT_TRUE(reply.ok());
  EXPECT_EQ(json::parse(*reply)["ok"], false);

  // Several requests on one connection, split across writes.
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::snprintf(address.sun_path, sizeof address.sun_path, "%s", path.c_str());
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
  const std::string part1 = R"({"op":"ping","id":1})"
                            "\n"
                            R"({"op":"pi)";
  const std::string part2 = R"(ng","id":2})"
                            "\n\n";
  ASSERT_EQ(::write(fd, part1.data(), part1.size()), static_cast<ssize_t>(part1.size()));
  std::this_thread::sleep_for(20ms);
  ASSERT_EQ(::write(fd, part2.data(), part2.size()), static_cast<ssize_t>(part2.size()));
  std::string got;
  char buffer[256];
  while (std::count(got.begin(), got.end(), '\n') < 2) {
    pollfd p{fd, POLLIN, 0};
    ASSERT_GT(::poll(&p, 1, 2000), 0);
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    ASSERT_GT(n, 0);
    got.append(buffer, static_cast<std::size_t>(n));
  }
  EXPECT_EQ(got, "{\"ok\":true,\"id\":1}\n{\"ok\":true,\"id\":2}\n");
  ::close(fd);
}

TEST_F(ControlSocket, OverlongLinesAreRefusedAndTheConnectionClosed) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::snprintf(address.sun_path, sizeof address.sun_path, "%s", path.c_str());
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
  const std::string flood(kMaxControlLine + 4096, 'x');
  std::size_t sent = 0;
  while (sent < flood.size()) {
    const ssize_t n = ::send(fd, flood.data() + sent, flood.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) break;
    sent += static_cast<std::size_t>(n);
  }
  std::string got;
  char buffer[512];
  while (true) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 2000) <= 0) break;
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n <= 0) break;  // closed by the server
    got.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  EXPECT_THAT(got, HasSubstr("line longer than 65536 bytes; closing"));
  // The server is still fine.
  auto reply = control_call(path, R"({"op":"ping"})");
  ASSERT_TRUE(reply.ok());
  EXPECT_EQ(*reply, R"({"ok":true})");
}

TEST_F(ControlSocket, TheSocketPathIsExclusiveAndRemovedOnStop) {
  auto second = ControlServer::start(server, path);
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.error().code(), Errc::busy);
  control.reset();
  EXPECT_FALSE(fs::exists(path));
  auto missing = control_call(path, R"({"op":"ping"})");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  // A stale socket file nobody listens on is replaced.
  {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::snprintf(address.sun_path, sizeof address.sun_path, "%s", path.c_str());
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
    ::close(fd);
  }
  auto again = ControlServer::start(server, path);
  ASSERT_TRUE(again.ok()) << again.error().describe();
  // Owner only: the channel can power-cycle slaves and inject faults.
  EXPECT_EQ(fs::status(path).permissions() & (fs::perms::group_all | fs::perms::others_all),
            fs::perms::none);
}

TEST(ControlPaths, DefaultPathUsesXdgRuntimeDir) {
  const char* saved = std::getenv("XDG_RUNTIME_DIR");
  const std::string restore = saved != nullptr ? saved : "";
  ::setenv("XDG_RUNTIME_DIR", "/run/user/4242", 1);
  EXPECT_EQ(default_control_path(), fmt::format("/run/user/4242/ecat-sim-{}.sock", ::getpid()));
  ::unsetenv("XDG_RUNTIME_DIR");
  EXPECT_EQ(default_control_path(), fmt::format("/tmp/ecat-sim-{}.sock", ::getpid()));
  if (saved != nullptr) ::setenv("XDG_RUNTIME_DIR", restore.c_str(), 1);
}

// ---- Backends -----------------------------------------------------------------------------------

TEST(Backend, SimSpecRunsTheRingInProcess) {
  auto backend = open_backend(std::string("sim:") + ECAT_SOURCE_DIR + "/examples/faults.yaml");
  ASSERT_TRUE(backend.ok()) << backend.error().describe();
  ASSERT_NE(backend->simulator, nullptr);
  link::Link& link = *backend->link;
  // The ring's start faults: the first three exchanges are one WKC short.
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(link.send(brd_frame(static_cast<std::uint8_t>(i))).ok());
    const auto reply = receive_one(link, 0ns);
    ASSERT_FALSE(reply.empty());
    EXPECT_EQ(decode(reply).wkc, i < 3 ? 2 : 3) << "exchange " << i;
  }
  EXPECT_EQ(backend->simulator->stats().frames, 5u);
  // The link keeps the simulator alive on its own.
  auto link_only = std::move(backend->link);
  backend->simulator.reset();
  ASSERT_TRUE(link_only->send(brd_frame()).ok());
  EXPECT_FALSE(receive_one(*link_only, 0ns).empty());
}

TEST(Backend, ErrorsAndDelegation) {
  auto empty = open_backend("sim:");
  ASSERT_FALSE(empty.ok());
  EXPECT_EQ(empty.error().message(), "invalid backend 'sim:': no ring file after 'sim:'");
  auto missing = open_backend("sim:/nonexistent.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().message(), "/nonexistent.yaml: no such ring file");
  auto bogus = open_backend("bogus");
  ASSERT_FALSE(bogus.ok());
  EXPECT_THAT(bogus.error().message(), HasSubstr("no kind prefix"));

  // udp: goes to the link layer; here to a simulator served over UDP.
  SimServer server(generic_segment(1));
  auto udp = link::UdpLink::serve("127.0.0.1", 0);
  ASSERT_TRUE(udp.ok());
  const auto port = (*udp)->local_port();
  ASSERT_TRUE(server.serve(std::move(*udp)).ok());
  auto backend = open_backend(fmt::format("udp:127.0.0.1:{}", port));
  ASSERT_TRUE(backend.ok()) << backend.error().describe();
  EXPECT_EQ(backend->simulator, nullptr);
  ASSERT_TRUE(backend->link->send(brd_frame()).ok());
  EXPECT_EQ(decode(receive_one(*backend->link)).wkc, 1);

  auto at_link_layer = link::open_link("sim:ring.yaml");
  ASSERT_FALSE(at_link_layer.ok());
  EXPECT_THAT(at_link_layer.error().message(), HasSubstr("ecat::sim::open_backend"));
}

// ---- With device profiles
// ------------------------------------------------------------------------

TEST(ServerProfiles, SignalsOfADigitalTerminal) {
  auto ring = parse_ring("simulator:\n  slaves:\n    - {name: inputs, profile: EL1809}\n");
  if (!ring.ok()) GTEST_SKIP() << ring.error().message();
  auto server = make_server(*ring);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  json r = call(**server, R"({"op":"signals","slave":"inputs"})");
  ASSERT_EQ(r["ok"], true) << r.dump();
  ASSERT_EQ(r["signals"].size(), 16u);
  EXPECT_EQ(r["signals"][0]["name"], "channel_1");
  EXPECT_EQ(r["signals"][0]["direction"], "input");
  r = call(**server, R"({"op":"signal.set","slave":"inputs","signal":"channel_3","value":true})");
  EXPECT_EQ(r["ok"], true) << r.dump();
  r = call(**server, R"({"op":"signal.get","slave":"inputs","signal":"channel_3"})");
  EXPECT_EQ(r["value"], 1);
  r = call(**server, R"({"op":"signal.clear","slave":"inputs","signal":"channel_3"})");
  EXPECT_EQ(r["ok"], true);
  r = call(**server, R"({"op":"signal.set","slave":"inputs","signal":"channel_99","value":1})");
  EXPECT_EQ(r["ok"], false);
  EXPECT_THAT(r["error"].get<std::string>(),
              StartsWith("slave 'inputs' has no signal 'channel_99' (known: channel_1,"));
}

TEST(ServerProfiles, DefaultRingServesOverTheFunctionLink) {
  auto backend = open_backend(std::string("sim:") + ECAT_SOURCE_DIR + "/examples/default.yaml");
  if (!backend.ok() && backend.error().message().find("unknown profile") != std::string::npos) {
    GTEST_SKIP() << backend.error().message();
  }
  ASSERT_TRUE(backend.ok()) << backend.error().describe();
  ASSERT_TRUE(backend->link->send(brd_frame()).ok());
  EXPECT_EQ(decode(receive_one(*backend->link, 0ns)).wkc, 5);
  const auto status = backend->simulator->status();
  ASSERT_EQ(status.slaves.size(), 5u);
  EXPECT_EQ(status.slaves[0].profile, "EK1100");
  EXPECT_EQ(status.slaves[0].product_code, 0x044C2C52u);
}

}  // namespace
}  // namespace ecat::sim
