// Domain cycle figures against the in-process simulator (a SimServer serving a memory link on its
// own thread: no network, but real threads, a real bus and real ESC emulation). Figures only;
// nothing here asserts a timing.
//
//   BM_DomainCycle/<image bytes>/<period us>
//     One domain (EL2809 -> EL1809 loopback, plus unmapped padding up to the image size) cycled
//     by a Cycler for half a second. Counters:
//       tick_us_mean/max   bus-thread time in the domain's on_tick (staging copy + submission)
//       rtt_us_mean/max    submission to completion of an exchange (the whole LRW round trip,
//                          classification and input publication included)
//       late_us_mean/p99/max  how late the bus thread woke for a tick (woke_at - deadline)
//       period_jitter_us   standard deviation of the interval between two wake-ups
//       valid, misses      cycles classified valid / transport misses
//       skipped            deadlines the bus thread skipped because it woke too late
//
// Run: ./build/NAME/bench/domain_bench [--benchmark_filter=...]

#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <thread>
#include <vector>

#include <benchmark/benchmark.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/registers.hpp>

#include "benchmark_main.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::master::Cycler;
using ecat::master::Domain;
using ecat::master::PdoDirection;

constexpr std::uint16_t kFirstStation = 0x1001;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
)";

// Records how late each tick woke, into preallocated storage (runs on the bus thread).
class WakeProbe : public ecat::master::CyclicParticipant {
 public:
  explicit WakeProbe(std::chrono::nanoseconds period) : period_(period) {
    late_ns.resize(1 << 16);
    woke_ns.resize(1 << 16);
  }
  ~WakeProbe() override { detach_from_cycler(); }
  void on_tick(const ecat::bus::CycleTick& tick) override {
    const std::size_t i = count.load(std::memory_order_relaxed);
    if (i >= late_ns.size()) return;
    late_ns[i] = (tick.woke_at - tick.deadline).count();
    woke_ns[i] = tick.woke_at.time_since_epoch().count();
    count.store(i + 1, std::memory_order_release);
  }
  std::chrono::nanoseconds cycle_period() const noexcept override { return period_; }

  std::vector<std::int64_t> late_ns;
  std::vector<std::int64_t> woke_ns;
  std::atomic<std::size_t> count{0};

 private:
  std::chrono::nanoseconds period_;
};

bool write_register(ecat::bus::Bus& bus, std::uint16_t station, std::uint16_t offset,
                    std::vector<std::uint8_t> data) {
  ecat::bus::Transaction tx;
  tx.fpwr(station, offset, data, 1);
  return bus.transact(std::move(tx)).ok();
}

bool request_all(ecat::bus::Bus& bus, ecat::wire::AlState state) {
  for (std::uint16_t s = kFirstStation; s < kFirstStation + 3; ++s) {
    if (!write_register(bus, s, ecat::wire::reg::kAlControl,
                        {static_cast<std::uint8_t>(ecat::wire::encode_al_control(state)), 0})) {
      return false;
    }
  }
  return true;  // the terminals mirror AL control at once (device emulation)
}

bool map(ecat::bus::Bus& bus, std::uint16_t station, std::uint8_t sm, std::uint16_t start,
         std::uint8_t control, std::uint8_t fmmu, std::uint32_t logical, bool output) {
  const auto base = ecat::wire::reg::sync_manager(sm);
  const auto activate =
      static_cast<std::uint16_t>(base + ecat::wire::reg::kSyncManagerActivateOffset);
  ecat::wire::FmmuConfig f;
  f.logical_start = logical;
  f.length = sm == 0 && !output ? 2 : 1;
  f.physical_start = start;
  f.type = output ? ecat::wire::FmmuType::write : ecat::wire::FmmuType::read;
  f.active = true;
  const auto bytes = f.encode();
  const auto length = static_cast<std::uint8_t>(f.length);
  return write_register(bus, station, activate, {0}) &&
         write_register(bus, station, base,
                        {static_cast<std::uint8_t>(start), static_cast<std::uint8_t>(start >> 8),
                         length, 0, control, 0}) &&
         write_register(bus, station, activate, {1}) &&
         write_register(bus, station, ecat::wire::reg::fmmu(fmmu),
                        std::vector<std::uint8_t>(bytes.begin(), bytes.end()));
}

void BM_DomainCycle(benchmark::State& state) {
  const auto image_size = static_cast<std::size_t>(state.range(0));
  const auto period = std::chrono::microseconds(state.range(1));
  auto ring = ecat::sim::parse_ring(kRing);
  if (!ring) {
    state.SkipWithError(ring.error().describe().c_str());
    return;
  }
  auto server = ecat::sim::make_server(*ring);
  if (!server) {
    state.SkipWithError(server.error().describe().c_str());
    return;
  }
  auto link = (*server)->serve_memory();
  if (!link) {
    state.SkipWithError(link.error().describe().c_str());
    return;
  }
  ecat::bus::BusOptions options;
  options.frame_timeout = 10ms;
  ecat::bus::Bus bus(std::move(*link), options);
  if (!bus.start()) {
    state.SkipWithError("bus start failed");
    return;
  }
  for (std::uint16_t pos = 0; pos < 3; ++pos) {
    ecat::bus::Transaction tx;
    const std::uint16_t station = kFirstStation + pos;
    const std::array<std::uint8_t, 2> value{static_cast<std::uint8_t>(station),
                                            static_cast<std::uint8_t>(station >> 8)};
    tx.apwr(pos, ecat::wire::reg::kStationAddress, value, 1);
    if (!bus.transact(std::move(tx))) {
      state.SkipWithError("station assignment failed");
      return;
    }
  }
  (void)request_all(bus, ecat::wire::AlState::preop);

  ecat::master::DomainConfig config;
  config.id = "bench";
  config.period = period;
  config.max_image_size = std::max<std::size_t>(image_size, 4) + 16;
  auto created = Domain::create(bus, config);
  if (!created) {
    state.SkipWithError(created.error().describe().c_str());
    return;
  }
  Domain& domain = **created;
  const std::uint16_t inputs = kFirstStation + 1;
  const std::uint16_t outputs = kFirstStation + 2;
  if (image_size > 4) {
    (void)domain.register_pdo({0xFFFF, 0}, image_size - 4, PdoDirection::output, false);
  }
  auto out0 = domain.register_pdo({outputs, 0}, 1, PdoDirection::output);
  auto out1 = domain.register_pdo({outputs, 1}, 1, PdoDirection::output);
  auto in0 = domain.register_pdo({inputs, 0}, 2, PdoDirection::input);
  if (!out0 || !out1 || !in0 || !map(bus, outputs, 0, 0x0F00, 0x44, 0, *out0, true) ||
      !map(bus, outputs, 1, 0x0F01, 0x44, 1, *out1, true) ||
      !map(bus, inputs, 0, 0x1000, 0x00, 0, *in0, false)) {
    state.SkipWithError("process data setup failed");
    return;
  }

  WakeProbe probe(period);
  Cycler cycler(bus);
  (void)cycler.add(probe, Cycler::kPriorityDc);  // first in the tick: its wake time is the tick's
  (void)cycler.add(domain);
  (void)cycler.start();
  (void)domain.start_cycling();
  (void)request_all(bus, ecat::wire::AlState::safeop);
  (void)request_all(bus, ecat::wire::AlState::op);
  std::this_thread::sleep_for(50ms);  // settle

  const auto domain_before = domain.stats();
  const auto cycler_before = cycler.stats();
  const std::size_t probe_from = probe.count.load();
  std::uint8_t v = 0;
  for (auto _ : state) {
    const auto until = std::chrono::steady_clock::now() + 500ms;
    while (std::chrono::steady_clock::now() < until) {
      const std::array<std::uint8_t, 1> b{v++};
      (void)domain.write(ecat::master::PdoHandle{image_size > 4 ? 1u : 0u}, b);
      std::this_thread::sleep_for(period);
    }
  }
  const auto d = domain.stats();
  const auto c = cycler.stats();
  (void)cycler.stop();
  const std::size_t probe_to = probe.count.load(std::memory_order_acquire);

  const double ticks = static_cast<double>(c.ticks - cycler_before.ticks);
  state.counters["tick_us_mean"] =
      ticks > 0 ? static_cast<double>(
                      (c.total_tick_duration - cycler_before.total_tick_duration).count()) /
                      ticks / 1000.0
                : 0.0;
  state.counters["tick_us_max"] = static_cast<double>(c.max_tick_duration.count()) / 1000.0;
  state.counters["rtt_us_mean"] = static_cast<double>(d.mean_latency.count()) / 1000.0;
  state.counters["rtt_us_max"] = static_cast<double>(d.max_latency.count()) / 1000.0;
  state.counters["valid"] = static_cast<double>(d.valid_count - domain_before.valid_count);
  state.counters["misses"] =
      static_cast<double>(d.total_miss_count - domain_before.total_miss_count);
  state.counters["datagrams"] = static_cast<double>(domain.layout().size());
  state.counters["skipped"] =
      static_cast<double>(c.deadlines_skipped - cycler_before.deadlines_skipped);

  std::vector<std::int64_t> late(probe.late_ns.begin() + static_cast<std::ptrdiff_t>(probe_from),
                                 probe.late_ns.begin() + static_cast<std::ptrdiff_t>(probe_to));
  if (!late.empty()) {
    double sum = 0;
    for (auto x : late)
      sum += static_cast<double>(x);
    std::sort(late.begin(), late.end());
    state.counters["late_us_mean"] = sum / static_cast<double>(late.size()) / 1000.0;
    state.counters["late_us_p99"] = static_cast<double>(late[late.size() * 99 / 100]) / 1000.0;
    state.counters["late_us_max"] = static_cast<double>(late.back()) / 1000.0;
  }
  if (probe_to > probe_from + 2) {
    std::vector<double> intervals;
    for (std::size_t i = probe_from + 1; i < probe_to; ++i) {
      intervals.push_back(static_cast<double>(probe.woke_ns[i] - probe.woke_ns[i - 1]));
    }
    double mean = 0;
    for (auto x : intervals)
      mean += x;
    mean /= static_cast<double>(intervals.size());
    double var = 0;
    for (auto x : intervals)
      var += (x - mean) * (x - mean);
    var /= static_cast<double>(intervals.size());
    state.counters["period_us_mean"] = mean / 1000.0;
    state.counters["period_jitter_us"] = std::sqrt(var) / 1000.0;
  }
}

// Cycle cost per image size at 1 ms; jitter at 1 ms, 250 us and 100 us with the small image.
BENCHMARK(BM_DomainCycle)
    ->Args({4, 1000})
    ->Args({256, 1000})
    ->Args({1400, 1000})
    ->Args({4000, 1000})
    ->Args({4, 250})
    ->Args({4, 100})
    ->Iterations(1)
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace

int main(int argc, char** argv) {
  return ecat::bench::benchmark_main(argc, argv);
}
