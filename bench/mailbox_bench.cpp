// Frames per SDO upload with the mailbox status in the cyclic frame, against polling SM1.
//
// A simulated mailbox device (profile `mailbox`: mailbox, process data, 3 FMMUs) behind an
// EK1100, in OP with a 1 ms domain, health polls off, DC off, over the in-process memory link.
// For each firmware reply delay (how long the device takes to put its answer into SM1: 0, 0.5, 1
// and 3 ms) the same expedited SDO upload (0x1018:01) is made N times with
// MasterConfig::mailbox_status off (the mailbox polls SM1 every 200 us) and on (it waits for
// "mailbox full" in the domain's image), and the bus's reliable frames (every frame that is not
// the domain's) are counted: frames per SDO, the ratio, and the mean time per SDO.
//
// Run: ./build/DIR/bench/mailbox_bench [--uploads N]   (default 200)
// docs/BENCHMARKS.md explains the figures. Nothing is asserted.

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <thread>

#include <fmt/format.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using ecat::master::MasterConfig;

std::string ring_yaml(unsigned reply_us) {
  return fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
    - {{name: io, profile: mailbox, options: {{mailbox_reply_us: {}}}}}
)",
                     reply_us);
}

MasterConfig master_config(bool mailbox_status) {
  MasterConfig config;
  config.scan = {.poll = 10ms, .stable = 50ms, .timeout = 10s};
  config.dc.reset();
  config.frame_timeout = 20ms;
  config.mailbox_status = mailbox_status;
  ecat::master::DomainConfig domain;
  domain.id = "main";
  domain.period = 1ms;
  config.domains.push_back(std::move(domain));
  ecat::master::SlaveConfig coupler;
  coupler.name = "coupler";
  coupler.health_poll.reset();
  config.slaves.push_back(std::move(coupler));
  ecat::master::SlaveConfig io;
  io.name = "io";
  io.process_data = ecat::master::ProcessDataRequest::all("main");
  io.health_poll.reset();
  config.slaves.push_back(std::move(io));
  return config;
}

struct Figures {
  bool ok = false;
  std::string error;
  double frames_per_sdo = 0;
  double ms_per_sdo = 0;
  bool mapped = false;
};

Figures measure(unsigned reply_us, bool mailbox_status, int uploads) {
  Figures f;
  auto ring = ecat::sim::parse_ring(ring_yaml(reply_us));
  if (!ring) return f.error = ring.error().describe(), f;
  auto server = ecat::sim::make_server(*ring);
  if (!server) return f.error = server.error().describe(), f;
  auto link = (*server)->serve_memory();
  if (!link) return f.error = link.error().describe(), f;
  auto master = std::make_unique<ecat::master::Master>(master_config(mailbox_status));
  if (auto r = master->start(std::move(*link)); !r) return f.error = r.error().describe(), f;
  if (auto r = master->await_operational(30s); !r) {
    f.error = r.error().describe();
    (void)master->stop();
    return f;
  }
  auto io = master->slave("io");
  if (!io) return f.error = io.error().describe(), f;
  f.mapped = !(*io)->info().mailbox_status_domain.empty();
  // A few uploads first (the first exchange of a session is not typical), then the count.
  for (int i = 0; i < 5; ++i)
    (void)(*io)->upload_sdo(0x1018, 1);
  const auto before = master->bus()->stats();
  const auto t0 = Clock::now();
  for (int i = 0; i < uploads; ++i) {
    if (auto r = (*io)->upload_sdo(0x1018, 1); !r) {
      f.error = r.error().describe();
      (void)master->stop();
      return f;
    }
  }
  const auto t1 = Clock::now();
  const auto after = master->bus()->stats();
  const auto reliable = (after.frames_sent - after.realtime_frames_sent) -
                        (before.frames_sent - before.realtime_frames_sent);
  f.frames_per_sdo = static_cast<double>(reliable) / uploads;
  f.ms_per_sdo = std::chrono::duration<double, std::milli>(t1 - t0).count() / uploads;
  f.ok = true;
  (void)master->stop();
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  int uploads = 200;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--uploads") == 0 && i + 1 < argc) {
      uploads = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: %s [--uploads N]\n", argv[0]);
      return 2;
    }
  }
  fmt::print(
      "mailbox_bench: frames per SDO upload (0x1018:01, expedited), slave in OP, 1 ms domain, "
      "{} uploads each; figures only, nothing asserted\n",
      uploads);
  fmt::print("{:>9} | {:>14} {:>10} | {:>14} {:>10} | {:>12}\n", "reply_ms", "polling fr/SDO",
             "ms/SDO", "status fr/SDO", "ms/SDO", "frames ratio");
  for (const unsigned reply_us : {0u, 500u, 1000u, 3000u}) {
    const Figures polling = measure(reply_us, false, uploads);
    const Figures status = measure(reply_us, true, uploads);
    if (!polling.ok || !status.ok) {
      fmt::print("{:>9.1f} | error: {}\n", reply_us / 1000.0,
                 polling.ok ? status.error : polling.error);
      continue;
    }
    fmt::print("{:>9.1f} | {:>14.2f} {:>10.2f} | {:>14.2f} {:>10.2f} | {:>11.1f}x{}\n",
               reply_us / 1000.0, polling.frames_per_sdo, polling.ms_per_sdo, status.frames_per_sdo,
               status.ms_per_sdo,
               status.frames_per_sdo > 0 ? polling.frames_per_sdo / status.frames_per_sdo : 0.0,
               status.mapped ? "" : "  (status NOT mapped)");
  }
  fmt::print(
      "fr/SDO: the bus's frames that are not the domain's (reliable frames), per upload. "
      "polling: MasterConfig::mailbox_status off (SM1 read every 200 us until it holds the "
      "reply); status: on (SM1's status byte in the 1 ms LRW, SM1 read once it shows full). The "
      "request frame also reads SM1 in both modes.\n");
  return 0;
}
