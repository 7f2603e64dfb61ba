// Distributed-clock figures against the in-process simulator (a SimServer serving a memory link
// on its own thread, a real bus, a Cycler at 1 ms). Figures only; nothing here asserts a timing.
//
// For lines of 1, 8 and 64 slaves with clocks drifting by up to +-100 ppm and random start
// offsets (fixed seed):
//   init_ms        initialize_dc: latch, plan, writes, static drift compensation
//   drift_frames   FRMWs the static drift compensation sent
//   lock_ms        from starting the DcMaintainer to lock (all |0x092C| < 100 ns, 5 samples)
//   resid_ns       max |0x092C| over the samples after lock (mean / max)
//   phase_us       master-to-SYNC0 phase error at the reference clock over the run
//                  (first / last / min / max; the cycle runs on the host clock, so without cycle
//                  steering it walks at the reference's drift against the host)
//   walk_ns_s      the phase error's slope (ns per second of run)
//   ref_ppm        the maintainer's estimate of the reference clock's rate against the host
//
// Run: ./build/NAME/bench/dc_bench [--seconds S]   (default 2 s per ring; the figure is
// --seconds 60)

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/registers.hpp>

namespace {

using namespace std::chrono_literals;
using ecat::master::Cycler;
using ecat::master::DcMaintainer;

constexpr std::uint16_t kFirstStation = 0x1001;

std::string drifting_line(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> drift(-100.0, 100.0);
  std::uniform_int_distribution<std::int64_t> offset(0, 10'000'000'000);
  std::string yaml = "version: 1\nsimulator:\n  slaves:\n";
  for (std::size_t i = 0; i < n; ++i) {
    yaml += fmt::format(
        "    - {{name: s{}, profile: generic, clock: {{drift_ppm: {:.3f}, offset_ns: {}}}}}\n", i,
        drift(rng), offset(rng));
  }
  return yaml;
}

ecat::exec::Task<ecat::Result<void>> assign(ecat::exec::EventLoop& loop, ecat::bus::Bus& bus,
                                            std::size_t n) {
  ecat::bus::Transaction tx;
  for (std::size_t i = 0; i < n; ++i) {
    const auto station = static_cast<std::uint16_t>(kFirstStation + i);
    const std::uint8_t bytes[2] = {static_cast<std::uint8_t>(station),
                                   static_cast<std::uint8_t>(station >> 8)};
    tx.apwr(static_cast<std::uint16_t>(i), ecat::wire::reg::kStationAddress, bytes, 1);
  }
  auto reply = co_await ecat::exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error();
  co_return ecat::ok();
}

struct Row {
  std::size_t slaves = 0;
  double init_ms = 0;
  std::uint32_t drift_frames = 0;
  bool converged = false;
  double lock_ms = -1;
  double resid_mean = 0;
  std::int64_t resid_max = 0;
  // Unwrapped (the walk is continuous), so min/max may exceed +-cycle/2.
  double phase_first_us = 0, phase_last_us = 0, phase_min_us = 0, phase_max_us = 0;
  double walk_ns_s = 0;
  double ref_ppm = 0;
  std::string error;
};

Row run(std::size_t n, double seconds) {
  Row row;
  row.slaves = n;
  auto failed = [&row](std::string message) {
    row.error = std::move(message);
    return row;
  };
  auto ring = ecat::sim::parse_ring(drifting_line(n, 1000 + n));
  if (!ring) return failed(ring.error().describe());
  auto server = ecat::sim::make_server(*ring);
  if (!server) return failed(server.error().describe());
  auto link = (*server)->serve_memory();
  if (!link) return failed(link.error().describe());
  ecat::bus::Bus bus(std::move(*link));
  if (auto started = bus.start(); !started) return failed(started.error().describe());
  ecat::exec::EventLoop loop;
  loop.start_thread("bench-control");
  auto finish = [&] {
    loop.stop();
    loop.join();
    bus.stop();
    (*server)->stop();
  };

  auto assigned = ecat::exec::run_blocking(loop, assign(loop, bus, n), 10s);
  if (!assigned || !*assigned) {
    finish();
    return failed("station assignment failed");
  }
  std::vector<std::uint16_t> stations;
  for (std::size_t i = 0; i < n; ++i)
    stations.push_back(static_cast<std::uint16_t>(kFirstStation + i));
  const auto t0 = std::chrono::steady_clock::now();
  auto init = ecat::exec::run_blocking(loop, ecat::master::initialize_dc(loop, bus, stations), 30s);
  const auto t1 = std::chrono::steady_clock::now();
  if (!init || !*init) {
    finish();
    return failed(init ? init->error().describe() : "initialize_dc timed out");
  }
  row.init_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  row.drift_frames = (*init)->drift_frames;
  row.converged = (*init)->converged;

  {
    Cycler cycler(bus);
    ecat::master::DcRuntimeOptions options;
    options.period = 1ms;
    options.read_every = 5;
    options.history = 1 << 16;
    DcMaintainer maintainer(bus, **init, options);
    (void)cycler.add(maintainer, Cycler::kPriorityDc);
    (void)cycler.start();
    const auto start = std::chrono::steady_clock::now();
    while (!maintainer.locked() && std::chrono::steady_clock::now() - start < 20s)
      std::this_thread::sleep_for(1ms);
    if (maintainer.locked()) {
      row.lock_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
    }
    const auto samples_at_lock = maintainer.status().samples;
    std::vector<std::pair<double, std::int64_t>> phase;  // (s, ns)
    const auto run_start = std::chrono::steady_clock::now();
    while (std::chrono::steady_clock::now() - run_start < std::chrono::duration<double>(seconds)) {
      std::this_thread::sleep_for(10ms);
      const auto s = maintainer.status();
      phase.emplace_back(
          std::chrono::duration<double>(std::chrono::steady_clock::now() - run_start).count(),
          s.phase_error_ns);
    }
    const auto status = maintainer.status();
    row.ref_ppm = status.reference_drift_ppm;
    const std::size_t after_lock =
        std::min<std::size_t>(status.history.size(), status.samples - samples_at_lock);
    if (after_lock > 0) {
      double sum = 0;
      for (std::size_t k = status.history.size() - after_lock; k < status.history.size(); ++k) {
        sum += static_cast<double>(status.history[k]);
        row.resid_max = std::max(row.resid_max, status.history[k]);
      }
      row.resid_mean = sum / static_cast<double>(after_lock);
    }
    if (!phase.empty()) {
      // Unwrap: the phase lives in (-cycle/2, cycle/2] and a drifting reference walks across.
      constexpr std::int64_t kCycle = 1'000'000;
      for (std::size_t k = 1; k < phase.size(); ++k) {
        std::int64_t step = phase[k].second - phase[k - 1].second;
        if (step > kCycle / 2) step -= kCycle;
        if (step < -kCycle / 2) step += kCycle;
        phase[k].second = phase[k - 1].second + step;
      }
      row.phase_first_us = static_cast<double>(phase.front().second) / 1e3;
      row.phase_last_us = static_cast<double>(phase.back().second) / 1e3;
      row.phase_min_us = row.phase_max_us = row.phase_first_us;
      double sx = 0, sy = 0, sxx = 0, sxy = 0;
      for (auto [x, y] : phase) {
        const double us = static_cast<double>(y) / 1e3;
        row.phase_min_us = std::min(row.phase_min_us, us);
        row.phase_max_us = std::max(row.phase_max_us, us);
        sx += x;
        sy += static_cast<double>(y);
        sxx += x * x;
        sxy += x * static_cast<double>(y);
      }
      const double m = static_cast<double>(phase.size());
      const double den = m * sxx - sx * sx;
      if (den > 0) row.walk_ns_s = (m * sxy - sx * sy) / den;
    }
  }
  finish();
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 2.0;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--seconds") == 0 && i + 1 < argc) {
      seconds = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: %s [--seconds S]\n", argv[0]);
      return 2;
    }
  }
  fmt::print(
      "{:>6} {:>9} {:>7} {:>5} {:>9} {:>10} {:>9} {:>10} {:>10} {:>10} {:>10} {:>10} {:>8}\n",
      "slaves", "init_ms", "frames", "conv", "lock_ms", "resid_mean", "resid_max", "ph_first",
      "ph_last", "ph_min", "ph_max", "walk_ns_s", "ref_ppm");
  for (std::size_t n : {std::size_t{1}, std::size_t{8}, std::size_t{64}}) {
    const Row r = run(n, seconds);
    if (!r.error.empty()) {
      fmt::print("{:>6} error: {}\n", n, r.error);
      continue;
    }
    fmt::print(
        "{:>6} {:>9.1f} {:>7} {:>5} {:>9.1f} {:>10.1f} {:>9} {:>10.2f} {:>10.2f} {:>10.2f} "
        "{:>10.2f} {:>10.1f} {:>8.2f}\n",
        r.slaves, r.init_ms, r.drift_frames, r.converged ? "yes" : "no", r.lock_ms, r.resid_mean,
        r.resid_max, r.phase_first_us, r.phase_last_us, r.phase_min_us, r.phase_max_us, r.walk_ns_s,
        r.ref_ppm);
  }
  fmt::print("(phase in us at the reference clock against its 1 ms SYNC0 grid; {} s per ring)\n",
             seconds);
  return 0;
}
