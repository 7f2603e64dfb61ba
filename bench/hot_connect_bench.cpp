// Hot connect (issue 16, "A benchmark shows ... the time from plugging a hot-connect group to its
// slaves in OP"): a simulated ring (EK1100 + EL1809 + EL2809, in-process memory link, domain at
// 1 ms) with a group of N terminals (EL2809 + EL1809 pairs) behind it; each round plugs the group
// in the simulator and times
//   plug -> present: from SimServer::plug to MasterStatus showing the group present (every slave
//                    of it in OP), as an application sees it, polled every 100 us;
//   noticed -> OP:   the master's own figure (HotConnectStatus::last_join): from recognising the
//                    group to its last slave in OP (without the wait for the next count poll);
//   unplug -> absent: from unplugging to the group reported absent;
// at two count-poll periods (hot_connect_poll 10 ms and 50 ms). Figures only, nothing asserted.
//
// Run: ./build/DIR/bench/hot_connect_bench [--rounds N]   (default 10 per configuration)

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include <ecat/master/master.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "build_info.hpp"

namespace {

using namespace std::chrono_literals;
using namespace ecat;
using Clock = std::chrono::steady_clock;

std::string ring_yaml(int pairs) {
  std::string y = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
)";
  for (int i = 0; i < pairs; ++i) {
    if (i == 0) {
      y +=
          "    - {name: tool_out_0, profile: EL2809, hot_connect: {group: tool, plugged: false}}\n";
    } else {
      y += fmt::format("    - {{name: tool_out_{}, profile: EL2809}}\n", i);
    }
    y += fmt::format("    - {{name: tool_in_{}, profile: EL1809}}\n", i);
  }
  return y;
}

master::MasterConfig config(int pairs, std::chrono::milliseconds poll) {
  master::MasterConfig c;
  c.scan = {.poll = 2ms, .stable = 10ms, .timeout = 5s};
  c.dc.reset();
  c.frame_timeout = 20ms;
  c.hot_connect_poll = poll;
  master::DomainConfig main;
  main.id = "main";
  main.period = 1ms;
  c.domains.push_back(main);
  for (const char* name : {"coupler", "inputs", "outputs"}) {
    master::SlaveConfig s;
    s.name = name;
    if (std::strcmp(name, "coupler") != 0) s.process_data = master::ProcessDataRequest::all("main");
    c.slaves.push_back(s);
  }
  master::HotConnectGroup g;
  g.name = "tool";
  for (int i = 0; i < pairs; ++i) {
    for (const char* kind : {"tool_out", "tool_in"}) {
      master::SlaveConfig s;
      s.name = fmt::format("{}_{}", kind, i);
      s.process_data = master::ProcessDataRequest::all("main");
      g.slaves.push_back(s);
    }
  }
  g.slaves[0].vendor_id = 0x2;
  g.slaves[0].product_code = 0x0AF93052;
  c.hot_connect.push_back(g);
  return c;
}

master::HotConnectStatus group(master::Master& m) {
  auto st = m.status();
  return st.hot_connect.empty() ? master::HotConnectStatus{} : st.hot_connect.front();
}

bool wait_for(master::Master& m, master::HotConnectState state, std::chrono::seconds limit) {
  const auto end = Clock::now() + limit;
  while (Clock::now() < end) {
    if (group(m).state == state) return true;
    std::this_thread::sleep_for(100us);
  }
  return false;
}

struct Figures {
  std::vector<double> plug_ms, join_ms, unplug_ms;
};

std::string summary(std::vector<double> v) {
  if (v.empty()) return "-";
  std::sort(v.begin(), v.end());
  return fmt::format("{:7.2f} {:7.2f} {:7.2f}", v.front(), v[v.size() / 2], v.back());
}

bool run(int pairs, std::chrono::milliseconds poll, int rounds, Figures& out) {
  auto ring = sim::parse_ring(ring_yaml(pairs));
  if (!ring) {
    fmt::print("ring: {}\n", ring.error().describe());
    return false;
  }
  auto server = sim::make_server(*ring);
  if (!server) {
    fmt::print("simulator: {}\n", server.error().describe());
    return false;
  }
  auto link = (*server)->serve_memory();
  if (!link) return false;
  master::Master m(config(pairs, poll));
  if (auto r = m.start(std::move(*link)); !r) {
    fmt::print("start: {}\n", r.error().describe());
    return false;
  }
  if (auto op = m.await_operational(10s); !op) {
    fmt::print("operational: {}\n", op.error().describe());
    return false;
  }
  for (int i = 0; i < rounds; ++i) {
    // A random phase against the count poll: the plug lands anywhere in its period.
    std::this_thread::sleep_for(std::chrono::microseconds(std::rand() % (poll.count() * 1000)));
    const auto plugged = Clock::now();
    if (!(*server)->plug("tool", true)) return false;
    if (!wait_for(m, master::HotConnectState::present, 10s)) {
      fmt::print("round {}: not present ({})\n", i, group(m).detail);
      return false;
    }
    out.plug_ms.push_back(
        std::chrono::duration<double, std::milli>(Clock::now() - plugged).count());
    if (auto j = group(m).last_join) {
      out.join_ms.push_back(std::chrono::duration<double, std::milli>(*j).count());
    }
    std::this_thread::sleep_for(20ms);
    const auto unplugged = Clock::now();
    if (!(*server)->plug("tool", false)) return false;
    if (!wait_for(m, master::HotConnectState::absent, 10s)) return false;
    out.unplug_ms.push_back(
        std::chrono::duration<double, std::milli>(Clock::now() - unplugged).count());
    if (m.state() != master::MasterState::operational) {
      fmt::print("round {}: the session left operational ({})\n", i, master::to_string(m.state()));
    }
  }
  (void)m.stop();
  (*server)->stop();
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  int rounds = 10;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--rounds") == 0 && i + 1 < argc) {
      rounds = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: %s [--rounds N]\n", argv[0]);
      return 2;
    }
  }
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 0) load[0] = load[1] = load[2] = -1;
  fmt::print("hot_connect_bench: figures only, nothing asserted\n{}\n", ecat::bench::build_info());
  fmt::print("machine: {} CPUs, load average {:.2f} {:.2f} {:.2f} at start\n",
             std::thread::hardware_concurrency(), load[0], load[1], load[2]);
  fmt::print("{} rounds each; min / median / max in ms\n\n", rounds);
  fmt::print("{:>6} {:>8} | {:^23} | {:^23} | {:^23}\n", "slaves", "poll", "plug -> present",
             "noticed -> OP", "unplug -> absent");
  for (int pairs : {1, 8}) {
    for (auto poll : {10ms, 50ms}) {
      Figures f;
      if (!run(pairs, poll, rounds, f)) {
        fmt::print("{:>6} {:>6}ms | failed\n", 2 * pairs, poll.count());
        continue;
      }
      fmt::print("{:>6} {:>6}ms | {} | {} | {}\n", 2 * pairs, poll.count(), summary(f.plug_ms),
                 summary(f.join_ms), summary(f.unplug_ms));
    }
  }
  if (getloadavg(load, 3) >= 0) {
    fmt::print("\nload average {:.2f} {:.2f} {:.2f} at the end\n", load[0], load[1], load[2]);
  }
  return 0;
}
