// Round-trip latency of each link: the benchmark thread sends a frame and waits for the echo that
// a second thread sends back. Reports ns per round trip; never asserts a timing.
//
// Then (after the Google Benchmark table, or alone with --table-only) the issue-17 table: one
// terminal over a veth pair in a private network namespace, the master's domain at 1 kHz against
// the simulator, over AF_PACKET and over AF_XDP, with and without busy polling, against a bare
// echo paced the same way (the floor): median and p99 of each, and the median's ratio to the
// floor's. --samples N sets the cycles per row (default 3000), taken in --rounds R turns
// (default 3). Needs root; prints why not.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include <benchmark/benchmark.h>
#include <fmt/format.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/link/xdp_link.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>

#include "build_info.hpp"
#include "veth_namespace.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::bench::Echo;
using ecat::link::Link;

void round_trips(benchmark::State& state, Link& master, Link& segment) {
  const auto size = static_cast<std::size_t>(state.range(0));
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> frame{};
  Echo echo(segment);
  std::int64_t lost = 0;
  for (auto _ : state) {
    if (!master.send(ecat::wire::Bytes(frame.data(), size)).ok()) {
      state.SkipWithError("send failed");
      break;
    }
    auto r = master.receive(1s);
    if (!r.ok()) {
      state.SkipWithError(r.error().describe().c_str());
      break;
    }
    if (!r->has_value()) ++lost;
  }
  state.counters["lost"] = static_cast<double>(lost);
  state.SetItemsProcessed(state.iterations());
}

void BM_MemoryPairRoundTrip(benchmark::State& state) {
  auto [master, segment] = ecat::link::make_memory_link_pair();
  round_trips(state, *master, *segment);
}
BENCHMARK(BM_MemoryPairRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

void BM_FunctionLinkRoundTrip(benchmark::State& state) {
  auto link = ecat::link::make_function_link(
      [](ecat::wire::Bytes request, ecat::link::ReplySink& replies) { replies.reply(request); });
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> frame{};
  const auto size = static_cast<std::size_t>(state.range(0));
  for (auto _ : state) {
    (void)link->send(ecat::wire::Bytes(frame.data(), size));
    auto r = link->receive(0ns);
    benchmark::DoNotOptimize(r);
  }
}
BENCHMARK(BM_FunctionLinkRoundTrip)->Arg(60)->Arg(1500);

void BM_UdpLoopbackRoundTrip(benchmark::State& state) {
  auto server = ecat::link::UdpLink::serve("127.0.0.1", 0);
  if (!server.ok()) {
    state.SkipWithError(server.error().describe().c_str());
    return;
  }
  auto client = ecat::link::UdpLink::connect("127.0.0.1", (*server)->local_port());
  if (!client.ok()) {
    state.SkipWithError(client.error().describe().c_str());
    return;
  }
  round_trips(state, **client, **server);
}
BENCHMARK(BM_UdpLoopbackRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

// A veth pair in an anonymous network namespace (bench/veth_namespace.hpp).
void BM_RawVethRoundTrip(benchmark::State& state) {
  ecat::bench::VethPair pair;
  if (!pair.problem().empty()) {
    state.SkipWithError(pair.problem().c_str());
    return;
  }
  auto master = pair.open("m", false);
  auto segment = pair.open("s", false);
  if (master && segment) {
    round_trips(state, *master, *segment);
  } else {
    state.SkipWithError(pair.problem().c_str());
  }
}
BENCHMARK(BM_RawVethRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

// The same over AF_XDP on the master's end ("m", copy mode: veth has no zero-copy), a raw echo on
// the other.
void BM_XdpVethRoundTrip(benchmark::State& state) {
  ecat::bench::VethPair pair;
  if (!pair.problem().empty()) {
    state.SkipWithError(pair.problem().c_str());
    return;
  }
  ecat::link::XdpLinkOptions options;
  options.interface = "m";
  auto master = ecat::link::XdpLink::open(options);
  if (!master) {
    state.SkipWithError(master.error().describe().c_str());
    return;
  }
  auto segment = pair.open("s", false);
  if (!segment) {
    state.SkipWithError(pair.problem().c_str());
    return;
  }
  round_trips(state, **master, *segment);
}
BENCHMARK(BM_XdpVethRoundTrip)->Arg(60)->Arg(1500)->UseRealTime();

// ---- One terminal over veth: AF_PACKET vs AF_XDP vs the floor -------------------------------

using Clock = std::chrono::steady_clock;

struct Percentiles {
  std::size_t n = 0;
  double p50 = 0, p99 = 0;  // microseconds
};

Percentiles percentiles(std::vector<std::int64_t> ns) {
  Percentiles p;
  p.n = ns.size();
  if (ns.empty()) return p;
  std::sort(ns.begin(), ns.end());
  const auto at = [&](double q) {
    const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(ns.size())));
    return static_cast<double>(ns[std::clamp<std::size_t>(rank, 1, ns.size()) - 1]) / 1e3;
  };
  p.p50 = at(0.50);
  p.p99 = at(0.99);
  return p;
}

// The frame the master's domain sends at one terminal: one LRW over the EL1809's image.
std::vector<std::uint8_t> lrw_frame(std::size_t image_size) {
  std::array<std::uint8_t, ecat::wire::kMaxFrameSize> buffer{};
  ecat::wire::FrameBuilder builder(buffer);
  ecat::wire::DatagramHeader lrw;
  lrw.command = ecat::wire::Command::lrw;
  lrw.length = static_cast<std::uint16_t>(image_size);
  const std::vector<std::uint8_t> data(image_size, 0);
  (void)builder.add(lrw, ecat::wire::Bytes(data));
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

// Send, wait for the echo, once per period (as the domain does), `count` times.
std::vector<std::int64_t> paced_echo(Link& master, const std::vector<std::uint8_t>& frame,
                                     std::chrono::nanoseconds period, std::size_t count) {
  std::vector<std::int64_t> ns;
  ns.reserve(count);
  auto deadline = Clock::now();
  for (std::size_t i = 0; i < count; ++i) {
    deadline += period;
    std::this_thread::sleep_until(deadline);
    const auto t0 = Clock::now();
    if (!master.send(frame).ok()) continue;
    auto r = master.receive(100ms);
    const auto t1 = Clock::now();
    if (r.ok() && r->has_value()) ns.push_back((t1 - t0).count());
  }
  return ns;
}

// The domain's round trip (submission to completion) of each valid cycle, from its callback.
class RoundTrips {
 public:
  explicit RoundTrips(std::size_t capacity) : ns_(capacity) {}
  ecat::master::CycleCallback callback() {
    return [this](ecat::master::Domain& domain, const ecat::master::CycleOutcome& outcome) {
      if (!recording_.load(std::memory_order_acquire) || !outcome.valid) return;
      const std::size_t i = count_.load(std::memory_order_relaxed);
      if (i >= ns_.size()) return;
      ns_[i] = domain.stats().last_latency.count();
      count_.store(i + 1, std::memory_order_release);
    };
  }
  void record() { recording_.store(true, std::memory_order_release); }
  bool full() const { return count_.load(std::memory_order_acquire) >= ns_.size(); }
  std::vector<std::int64_t> samples() const {
    const auto n = static_cast<std::ptrdiff_t>(count_.load(std::memory_order_acquire));
    return {ns_.begin(), ns_.begin() + n};
  }

 private:
  std::vector<std::int64_t> ns_;
  std::atomic<std::size_t> count_{0};
  std::atomic<bool> recording_{false};
};

constexpr const char* kOneTerminalRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: t0, profile: EL1809}
)";

ecat::master::MasterConfig one_terminal_config(std::chrono::nanoseconds period) {
  ecat::master::MasterConfig config;
  config.scan = {.poll = 10ms, .stable = 50ms, .timeout = 10s};
  config.dc.reset();
  ecat::master::DomainConfig domain;
  domain.id = "main";
  domain.period = period;
  config.domains.push_back(std::move(domain));
  ecat::master::SlaveConfig coupler;
  coupler.name = "coupler";
  config.slaves.push_back(std::move(coupler));
  ecat::master::SlaveConfig terminal;
  terminal.name = "t0";
  terminal.process_data = ecat::master::ProcessDataRequest::all("main");
  config.slaves.push_back(std::move(terminal));
  return config;
}

// A link on the pair by spec ("raw:m", "xdp:m,busy_poll=50", ...). The segment's end is opened
// in responder mode, which open_link has no option for: "raw:s" / "xdp:s", and ",spin" or
// ",busy_poll=US" after it.
ecat::Result<std::unique_ptr<Link>> open_end(const std::string& spec, bool responder) {
  if (!responder) return ecat::link::open_link(spec);
  const auto colon = spec.find(':');
  const auto comma = spec.find(',');
  const std::string interface = spec.substr(colon + 1, comma - colon - 1);
  const bool spin = spec.find(",spin") != std::string::npos;
  const auto busy = spec.find(",busy_poll=");
  const int busy_poll_us = busy == std::string::npos ? 0 : std::atoi(spec.c_str() + busy + 11);
  if (spec.rfind("xdp:", 0) == 0) {
    ecat::link::XdpLinkOptions options;
    options.interface = interface;
    options.responder = true;
    options.spin = spin;
    options.busy_poll_us = busy_poll_us;
    auto link = ecat::link::XdpLink::open(options);
    if (!link) return std::move(link).error();
    return std::unique_ptr<Link>(std::move(*link));
  }
  ecat::link::RawLinkOptions options;
  options.interface = interface;
  options.responder = true;
  options.kernel_filter = true;
  options.spin = spin || busy_poll_us > 0;
  options.busy_poll_us = busy_poll_us;
  auto link = ecat::link::RawLink::open(options);
  if (!link) return std::move(link).error();
  return std::unique_ptr<Link>(std::move(*link));
}

struct Row {
  std::string path;
  std::vector<std::int64_t> ns;  // every round's samples
  std::string error;
};

// The master on `master_spec` against the simulator served on `segment_spec`.
Row master_row(const std::string& master_spec, const std::string& segment_spec, std::size_t samples,
               std::size_t& image_size) {
  Row row;
  row.path = fmt::format("master {} + sim {}", master_spec, segment_spec);
  auto ring = ecat::sim::parse_ring(kOneTerminalRing);
  if (!ring) return row.error = ring.error().describe(), row;
  auto server = ecat::sim::make_server(*ring);
  if (!server) return row.error = server.error().describe(), row;
  auto segment_end = open_end(segment_spec, true);
  if (!segment_end) return row.error = segment_end.error().describe(), row;
  if (auto r = (*server)->serve(std::move(*segment_end)); !r) {
    return row.error = r.error().describe(), row;
  }
  auto master_end = open_end(master_spec, false);
  if (!master_end) return row.error = master_end.error().describe(), row;
  RoundTrips recorder(samples);
  auto config = one_terminal_config(1ms);
  config.domains[0].on_cycle = recorder.callback();
  ecat::master::Master master(std::move(config));
  if (auto r = master.start(std::move(*master_end)); !r) {
    return row.error = r.error().describe(), row;
  }
  if (auto r = master.await_operational(30s); !r) {
    row.error = r.error().describe();
    (void)master.stop();
    return row;
  }
  image_size = master.domains().at(0).image_size;
  std::this_thread::sleep_for(100ms);
  recorder.record();
  const auto until = Clock::now() + samples * 4ms + 10s;
  while (!recorder.full() && Clock::now() < until)
    std::this_thread::sleep_for(5ms);
  row.ns = recorder.samples();
  (void)master.stop();
  (*server)->stop();
  return row;
}

Row echo_row(const std::string& master_spec, const std::string& segment_spec, std::size_t samples,
             std::size_t image_size) {
  Row row;
  row.path = fmt::format("bare echo {} <- {}", master_spec, segment_spec);
  auto segment_end = open_end(segment_spec, true);
  if (!segment_end) return row.error = segment_end.error().describe(), row;
  auto master_end = open_end(master_spec, false);
  if (!master_end) return row.error = master_end.error().describe(), row;
  ecat::bench::Echo echo(**segment_end);
  row.ns = paced_echo(**master_end, lrw_frame(image_size), 1ms, samples);
  return row;
}

void one_terminal_table(std::size_t samples, std::size_t rounds) {
  fmt::print(
      "\n== one terminal over veth, 1 kHz: AF_PACKET vs AF_XDP vs the paced echo floor "
      "(us)\n");
  ecat::bench::VethPair pair;
  if (!pair.problem().empty()) {
    fmt::print("skipped: {}\n", pair.problem());
    return;
  }
  struct Spec {
    bool echo;
    const char* master;
    const char* segment;
  };
  // The floor first. Rows take turns round by round, so that a burst of load elsewhere on the
  // machine falls on all of them rather than on one.
  const std::vector<Spec> specs{
      {true, "raw:m", "raw:s"},
      {false, "raw:m", "raw:s"},
      {true, "xdp:m", "raw:s"},
      {false, "xdp:m", "raw:s"},
      {false, "raw:m", "raw:s,spin"},
      {false, "xdp:m", "raw:s,spin"},
      {false, "raw:m,busy_poll=50,spin", "raw:s"},
      {false, "xdp:m,busy_poll=50", "raw:s"},
      {false, "xdp:m", "xdp:s"},
      {false, "raw:m,spin", "raw:s,spin"},
  };
  std::vector<Row> rows(specs.size());
  std::size_t image_size = 2;  // EL1809: 16 inputs (the master reports it)
  const std::size_t per_round = std::max<std::size_t>(samples / rounds, 10);
  for (std::size_t round = 0; round < rounds; ++round) {
    for (std::size_t i = 0; i < specs.size(); ++i) {
      const Spec& spec = specs[i];
      Row got = spec.echo ? echo_row(spec.master, spec.segment, per_round, image_size)
                          : master_row(spec.master, spec.segment, per_round, image_size);
      rows[i].path = got.path;
      if (!got.error.empty()) rows[i].error = got.error;
      rows[i].ns.insert(rows[i].ns.end(), got.ns.begin(), got.ns.end());
    }
  }
  const Percentiles floor = percentiles(rows[0].ns);
  fmt::print("{:<48} {:>6} {:>9} {:>9} {:>9}\n", "path", "n", "p50", "p99", "p50/floor");
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const Row& r = rows[i];
    if (!r.error.empty()) {
      fmt::print("{:<48} error: {}\n", r.path, r.error);
      continue;
    }
    const Percentiles p = percentiles(r.ns);
    fmt::print("{:<48} {:>6} {:>9.1f} {:>9.1f} {:>9.2f}\n", r.path + (i == 0 ? " (floor)" : ""),
               p.n, p.p50, p.p99, floor.p50 > 0 ? p.p50 / floor.p50 : 0.0);
  }
  fmt::print(
      "Ring: EK1100 + EL1809 ({}-byte LRW), {} rounds of {} cycles per row. master + sim: the "
      "domain's submission to completion of each valid cycle (DomainStats::last_latency), the "
      "simulator (SimServer) serving the other end of the pair (raw: an AF_PACKET responder with "
      "the EtherCAT socket filter; xdp: an XdpLink responder). bare echo: send() to receive() of "
      "the same frame once per 1 ms period, a thread echoing it on the other end (sleeping in "
      "receive, as the simulator's thread does). spin: receive never sleeps; busy_poll=US: "
      "SO_BUSY_POLL too (AF_XDP: and SO_PREFER_BUSY_POLL); both cost a core while waiting.\n",
      image_size, rounds, per_round);
}

}  // namespace

// BENCHMARK_MAIN, plus what the figures were measured with (bench/build_info.hpp) in the context.
int main(int argc, char** argv) {
  benchmark::AddCustomContext("ecat build", ecat::bench::build_info());
  bool table_only = false;
  std::size_t samples = 3000;
  std::size_t rounds = 3;
  int kept = 1;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--table-only") == 0) {
      table_only = true;
    } else if (std::strcmp(argv[i], "--samples") == 0 && i + 1 < argc) {
      samples = static_cast<std::size_t>(std::max(10L, std::strtol(argv[++i], nullptr, 10)));
    } else if (std::strcmp(argv[i], "--rounds") == 0 && i + 1 < argc) {
      rounds = static_cast<std::size_t>(std::clamp(std::strtol(argv[++i], nullptr, 10), 1L, 100L));
    } else {
      argv[kept++] = argv[i];
    }
  }
  argc = kept;
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  if (!table_only) benchmark::RunSpecifiedBenchmarks();
  one_terminal_table(samples, rounds);
  benchmark::Shutdown();
  return 0;
}
