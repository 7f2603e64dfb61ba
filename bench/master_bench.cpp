// The master session's figures (issue 4, "Benchmarks"): one table per section, printed; nothing
// here asserts a timing.
//
//   1. cyclic round trip over raw veth: the master's domain cycling against sim::SimServer serving
//      a raw link on the other end of a veth pair (private network namespace), 1 / 16 / 64
//      slaves, against a bare echo on the same pair paced at the same period (the floor).
//   2. cycle-start jitter at 1, 4 and 8 kHz: a CyclicParticipant added to the master's own
//      Cycler records, every tick, how late the bus thread started the tick after its absolute
//      deadline (the moment the domain's LRW is staged and submitted in the same tick), with the
//      simulator in process (memory link) and in a process of its own over veth, beside
//      cyclictest alone and cyclictest run while the same master + simulator pair serves the
//      same frames (the machine's floor under ecat's load); the bus's own trace of the same
//      ticks (Bus::set_cycle_trace) says which step held the late ones; steal time and the
//      timed thread's involuntary context switches per row say what the host did meanwhile.
//   3. Master::start to operational for 64 / 128 / 256 / 512 / 1024 simulated terminals behind an
//      EK1100 (in-process memory link), five runs each with --full: min / median / max, the frames
//      each run sent, and where the time went (discovery, the slaves' bring-up to PREOP, the rest
//      to OP), from a ring file the bench writes (simulator and master sections).
//   4. hot-path cost: Slave::read_input / write_output and Domain read / write / sample.
//      (bench/domain_bench.cpp covers the domain's cycle cost by image size; not repeated here.)
//   5. heap allocations per cycle on the cycle (bus) thread in steady OP (must be 0), with global
//      operator new replaced by the tests' counting allocator.
//   6. cable redundancy: cycles lost at a cable break and at its heal, the master on a
//      link::RedundantLink over sim::RedundantPorts (in process) with a 1 ms domain, the break at
//      a random point each time (between two random slaves, or a master port's cable); target:
//      none beyond the one in flight at the moment of the change.
//
// Run: ./build/DIR/bench/master_bench [--quick | --full] [--startup [--terminals N] [--runs N]]
//                                     [--fifo PRIORITY]
//   --quick (default) keeps the whole run under about a minute; --full takes longer samples.
//   --startup runs section 3 alone, five runs per size (--terminals N: at that size only;
//   --runs N: N runs per size).
//   --fifo runs the jitter section's cycle thread with SCHED_FIFO at PRIORITY.
//   --cpu N pins the jitter section's cycle thread and its cyclictest runs to CPU N.
//   --jitter-link memory|veth|both: section 2 against the in-process simulator (memory link), the
//   simulator in another process over veth (needs root), or both (default).
//   --only jitter|hot|alloc|redundancy runs one section (--breaks N: section 6's breaks).
// The veth section needs root (a veth pair in a private network namespace); without it, it
// prints "skipped: <reason>". docs/BENCHMARKS.md explains every figure.

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/klog.h>
#include <sys/resource.h>
#include <sys/utsname.h>
#include <sys/wait.h>
#include <unistd.h>

#include <ecat/bus/bus.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/cycler.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/signal.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/wire/frame.hpp>

#include "build_info.hpp"
#include "support/counting_allocator.hpp"
#include "veth_namespace.hpp"

namespace {

using namespace std::chrono_literals;
namespace allocs = ecat::test::allocations;
using ecat::master::CycleOutcome;
using ecat::master::Domain;
using ecat::master::Master;
using ecat::master::MasterConfig;
using ecat::master::MasterState;
using Clock = std::chrono::steady_clock;

struct Mode {
  bool full = false;
  bool startup_only = false;
  std::optional<std::size_t> terminals;  // section 3 at this size only
  std::optional<std::size_t> runs;       // section 3's runs per size
  std::optional<int> fifo;
  std::optional<int> cpu;             // section 2: the cycle thread and cyclictest pinned here
  std::optional<int> jitter_seconds;  // section 2's length per rate
  std::optional<int> alloc_seconds;   // section 5's window
  std::string only;                   // run one section: jitter, hot, alloc, redundancy
  std::optional<int> breaks;          // section 6's breaks
  std::string jitter_link = "both";   // section 2: memory, veth or both
};

double ms_since(Clock::time_point from, Clock::time_point to) {
  return std::chrono::duration<double, std::milli>(to - from).count();
}
double ms_between(std::int64_t from_ns, std::int64_t to_ns) {
  return static_cast<double>(to_ns - from_ns) / 1e6;
}

// Nearest-rank percentiles of nanosecond samples, in microseconds.
struct Distribution {
  std::size_t n = 0;
  double min = 0, p50 = 0, p99 = 0, p999 = 0, max = 0;
};

Distribution distribution(std::vector<std::int64_t> ns) {
  Distribution d;
  d.n = ns.size();
  if (ns.empty()) return d;
  std::sort(ns.begin(), ns.end());
  const auto at = [&](double q) {
    const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(ns.size())));
    return static_cast<double>(ns[std::clamp<std::size_t>(rank, 1, ns.size()) - 1]) / 1e3;
  };
  d.min = static_cast<double>(ns.front()) / 1e3;
  d.p50 = at(0.50);
  d.p99 = at(0.99);
  d.p999 = at(0.999);
  d.max = static_cast<double>(ns.back()) / 1e3;
  return d;
}

// ---- what the host did meanwhile (the figures' attribution)
// ------------------------------------------------------------------------

// The guest's steal time summed over its CPUs (/proc/stat "cpu" line, 8th value, in USER_HZ
// ticks): time a vCPU was runnable but the host ran something else. nullopt: unreadable.
std::optional<std::uint64_t> steal_ticks() {
  std::FILE* file = std::fopen("/proc/stat", "r");
  if (file == nullptr) return std::nullopt;
  unsigned long long v[8] = {};
  const int got = std::fscanf(file, "cpu %llu %llu %llu %llu %llu %llu %llu %llu", &v[0], &v[1],
                              &v[2], &v[3], &v[4], &v[5], &v[6], &v[7]);
  std::fclose(file);
  if (got != 8) return std::nullopt;
  return v[7];
}

// A thread's involuntary context switches (the guest scheduler took the CPU from it), from
// /proc/self/task/<tid>/status. nullopt: unreadable.
std::optional<std::uint64_t> involuntary_switches(pid_t tid) {
  std::FILE* file = std::fopen(fmt::format("/proc/self/task/{}/status", tid).c_str(), "r");
  if (file == nullptr) return std::nullopt;
  std::optional<std::uint64_t> found;
  char line[256];
  while (std::fgets(line, sizeof line, file) != nullptr) {
    unsigned long long n = 0;
    if (std::sscanf(line, "nonvoluntary_ctxt_switches: %llu", &n) == 1) found = n;
  }
  std::fclose(file);
  return found;
}

// Steal time over a window, both CPUs together, in ms ("-" when /proc/stat is unreadable).
class StealWindow {
 public:
  StealWindow() : from_(steal_ticks()) {}
  std::string ms() const {
    const auto to = steal_ticks();
    if (!from_ || !to) return "-";
    const long hz = ::sysconf(_SC_CLK_TCK);
    return fmt::format("{}", (*to - *from_) * 1000 / static_cast<std::uint64_t>(hz > 0 ? hz : 100));
  }

 private:
  std::optional<std::uint64_t> from_;
};

std::string difference(std::optional<std::uint64_t> from, std::optional<std::uint64_t> to) {
  return from && to ? fmt::format("{}", *to - *from) : std::string("-");
}

// The kernel's preemption model as far as it can be read: debugfs (the current model in
// parentheses), else the boot log's "Dynamic Preempt: X" line (PREEMPT_DYNAMIC kernels), else a
// preempt= on the command line, else "unknown"; with where it came from.
std::string preemption_model() {
  const auto slurp = [](const char* path) {
    std::string text;
    if (std::FILE* file = std::fopen(path, "r")) {
      char buffer[4096];
      std::size_t n = 0;
      while ((n = std::fread(buffer, 1, sizeof buffer, file)) > 0)
        text.append(buffer, n);
      std::fclose(file);
    }
    return text;
  };
  const std::string debugfs = slurp("/sys/kernel/debug/sched/preempt");
  if (const auto open = debugfs.find('('); open != std::string::npos) {
    const auto close = debugfs.find(')', open);
    if (close != std::string::npos)
      return debugfs.substr(open + 1, close - open - 1) + " (/sys/kernel/debug/sched/preempt)";
  }
  const int size = ::klogctl(10, nullptr, 0);  // SYSLOG_ACTION_SIZE_BUFFER
  if (size > 0) {
    std::string log(static_cast<std::size_t>(size), '\0');
    const int got = ::klogctl(3, log.data(), size);  // SYSLOG_ACTION_READ_ALL
    if (got > 0) {
      log.resize(static_cast<std::size_t>(got));
      constexpr std::string_view kTag = "Dynamic Preempt: ";
      if (const auto at = log.rfind(kTag); at != std::string::npos) {
        const auto from = at + kTag.size();
        const auto end = log.find_first_of("\r\n", from);
        return log.substr(from, end == std::string::npos ? std::string::npos : end - from) +
               " (boot log \"Dynamic Preempt\")";
      }
    }
  }
  const std::string cmdline = slurp("/proc/cmdline");
  if (const auto at = cmdline.find("preempt="); at != std::string::npos) {
    const auto end = cmdline.find_first_of(" \n", at);
    return cmdline.substr(at + 8, end == std::string::npos ? std::string::npos : end - at - 8) +
           " (kernel command line)";
  }
  return "unknown";
}

std::string kernel_line() {
  struct utsname u {};
  if (::uname(&u) != 0) return "kernel: unknown";
  return fmt::format("kernel: {} {}; preemption model: {}", u.release, u.version,
                     preemption_model());
}

std::string us_columns(const Distribution& d) {
  return fmt::format("{:>9.1f} {:>9.1f} {:>9.1f} {:>9.1f} {:>9.1f}", d.min, d.p50, d.p99, d.p999,
                     d.max);
}

// An EK1100 followed by `terminals` terminals, EL1809 and EL2809 alternating; the first EL2809's
// channel 1 is wired back to the first EL1809's.
std::string ring_yaml(std::size_t terminals) {
  std::string yaml = "version: 1\nsimulator:\n  slaves:\n    - {name: coupler, profile: EK1100}\n";
  for (std::size_t i = 0; i < terminals; ++i) {
    yaml += fmt::format("    - {{name: t{}, profile: {}}}\n", i, i % 2 == 0 ? "EL1809" : "EL2809");
  }
  if (terminals >= 2) yaml += "  wiring:\n    - {from: t1.channel_1, to: t0.channel_1}\n";
  return yaml;
}

// One domain "main" at `period`, every terminal's process data in it, no DC, a short discovery
// stability window (the default 1 s window would dominate the start-up figures).
MasterConfig master_config(std::size_t terminals, std::chrono::nanoseconds period) {
  MasterConfig config;
  config.scan = {.poll = 10ms, .stable = 50ms, .timeout = 10s};
  config.dc.reset();
  config.awaiting_preop_timeout = 120s;
  ecat::master::DomainConfig domain;
  domain.id = "main";
  domain.period = period;
  config.domains.push_back(std::move(domain));
  ecat::master::SlaveConfig coupler;
  coupler.name = "coupler";
  config.slaves.push_back(std::move(coupler));
  for (std::size_t i = 0; i < terminals; ++i) {
    ecat::master::SlaveConfig terminal;
    terminal.name = fmt::format("t{}", i);
    terminal.process_data = ecat::master::ProcessDataRequest::all("main");
    config.slaves.push_back(std::move(terminal));
  }
  return config;
}

// The same ring as one ring file (docs/RING-FILE.md): the simulator's section and the master's
// (one domain "main" at 1 ms holding every terminal's process data, no DC, the short discovery
// window), written to `path`. Nothing in it sizes the domain or the bus: the ring does.
bool write_ring_file(const std::string& path, std::size_t terminals) {
  std::string yaml = ring_yaml(terminals);
  yaml +=
      "master: {scan_poll_ms: 10, scan_timeout_ms: 10000, "
      "awaiting_preop_timeout_ms: 120000}\n"
      "dc: false\n"
      "domains:\n  - {id: main, period_us: 1000}\n"
      "slaves:\n  - {name: coupler}\n";
  for (std::size_t i = 0; i < terminals; ++i)
    yaml += fmt::format("  - {{name: t{}, process_data: main}}\n", i);
  std::FILE* file = std::fopen(path.c_str(), "w");
  if (file == nullptr) return false;
  const bool written = std::fwrite(yaml.data(), 1, yaml.size(), file) == yaml.size();
  return std::fclose(file) == 0 && written;
}

ecat::Result<std::unique_ptr<ecat::sim::SimServer>> make_server(std::size_t terminals) {
  auto ring = ecat::sim::parse_ring(ring_yaml(terminals));
  if (!ring) return ring.error();
  return ecat::sim::make_server(*ring);
}

template <class Predicate>
bool wait_for(Predicate done, std::chrono::nanoseconds limit) {
  const auto until = Clock::now() + limit;
  while (!done()) {
    if (Clock::now() >= until) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

std::int64_t now_ns() {
  return Clock::now().time_since_epoch().count();
}

// A simulated ring (memory link or a link the caller serves) with a master in OP on it.
struct Session {
  std::unique_ptr<ecat::sim::SimServer> server;
  std::string error;
  // Steady-clock ns: start() called, awaiting_preop entered, operational entered.
  std::atomic<std::int64_t> started{0}, awaiting_preop{0}, operational{0};
  // From the master's slave.state events (time_ns: when raised): the last slave to enter PREOP,
  // and the events the subscription missed (then it is a lower bound).
  std::atomic<std::int64_t> last_preop{0};
  std::atomic<std::uint64_t> events_missed{0};
  std::chrono::nanoseconds await_limit = 180s;
  // Last: destroyed (stopped) first, before the server and what its callback writes.
  std::unique_ptr<Master> master;

  // Brings the master up on `link` (the server must already serve the other end).
  bool run(std::unique_ptr<ecat::link::Link> link, MasterConfig config) {
    master = std::make_unique<Master>(std::move(config));
    master->on_state_change([this](MasterState, MasterState to) {
      if (to == MasterState::awaiting_preop) awaiting_preop = now_ns();
      if (to == MasterState::operational) operational = now_ns();
    });
    (void)master->subscribe_events([this](const ecat::master::Event& e, std::uint64_t missed) {
      events_missed += missed;
      if (e.kind != ecat::master::EventKind::slave_state) return;
      auto latest = [&](std::atomic<std::int64_t>& at) {
        if (e.time_ns > at.load()) at = e.time_ns;
      };
      const std::string_view to = e.to_name();
      if (to == "preop") latest(last_preop);
    });
    started = now_ns();
    if (auto r = master->start(std::move(link)); !r) return error = r.error().describe(), false;
    if (auto r = master->await_operational(await_limit); !r) {
      error = r.error().describe();
      // What held the session up, for the figures' reader.
      const auto status = master->status();
      const auto counters = master->counters();
      for (const auto& fault : status.runtime_faults)
        error += "; runtime fault: " + fault;
      for (std::size_t i = 0; i < status.activation_failures.size() && i < 3; ++i) {
        error += "; activation failure: " + status.activation_failures[i].slave + ": " +
                 status.activation_failures[i].error.describe();
      }
      if (status.last_failure) error += "; last failure: " + status.last_failure->error.describe();
      error += fmt::format(
          "; frames sent {}, lost {}, transaction timeouts {}, retries {}, realtime expired {}",
          counters.frames_sent, counters.frames_lost, counters.transaction_timeouts,
          counters.retries, counters.realtime_expired);
      for (const auto& d : counters.domains) {
        error += fmt::format("; domain {}: cycles {}, valid {}, wkc mismatches {}, misses {}", d.id,
                             d.cycles, d.valid, d.wkc_mismatches, d.misses);
      }
      return false;
    }
    // The callback runs on the control thread, maybe just after await_operational returned.
    (void)wait_for([&] { return operational.load() != 0; }, 5s);
    return true;
  }
  // A ring file's ring (its simulator section) served over an in-process memory link, the master
  // configured by the same file.
  bool run_ring_file(const std::string& path) {
    auto ring = ecat::sim::load_ring(path);
    if (!ring) return error = ring.error().describe(), false;
    auto config = ecat::master::load_master_config(path);
    if (!config) return error = config.error().describe(), false;
    auto made = ecat::sim::make_server(*ring);
    if (!made) return error = made.error().describe(), false;
    server = std::move(*made);
    auto link = server->serve_memory();
    if (!link) return error = link.error().describe(), false;
    return run(std::move(*link), std::move(*config));
  }
  // The ring served over an in-process memory link.
  bool run_memory(std::size_t terminals, MasterConfig config) {
    auto made = make_server(terminals);
    if (!made) return error = made.error().describe(), false;
    server = std::move(*made);
    auto link = server->serve_memory();
    if (!link) return error = link.error().describe(), false;
    return run(std::move(*link), std::move(config));
  }
  Domain* domain() {
    auto d = master->domain("main");
    return d ? *d : nullptr;
  }
};

// Added to the master's own Cycler: records how late each tick started, into preallocated
// storage, and marks the bus thread for the counting allocator.
class TickProbe final : public ecat::master::CyclicParticipant {
 public:
  TickProbe(std::chrono::nanoseconds period, std::size_t capacity)
      : period_(period), late_ns_(capacity) {}
  ~TickProbe() override { detach_from_cycler(); }

  void on_tick(const ecat::bus::CycleTick& tick) override {
    allocs::is_bus_thread = true;
    if (tid_.load(std::memory_order_relaxed) == 0)
      tid_.store(::gettid(), std::memory_order_release);
    ticks_.fetch_add(1, std::memory_order_relaxed);
    if (!recording_.load(std::memory_order_acquire)) return;
    const std::size_t i = count_.load(std::memory_order_relaxed);
    if (i >= late_ns_.size()) return;
    missed_.fetch_add(tick.missed, std::memory_order_relaxed);
    // Against the deadline that was due, not the latest one passed: comparable with cyclictest.
    const auto due = tick.deadline - static_cast<std::int64_t>(tick.missed) * period_;
    late_ns_[i] = (tick.woke_at - due).count();
    count_.store(i + 1, std::memory_order_release);
  }
  std::chrono::nanoseconds cycle_period() const noexcept override { return period_; }

  void record() { recording_.store(true, std::memory_order_release); }
  bool full() const { return count_.load(std::memory_order_acquire) >= late_ns_.size(); }
  std::uint64_t ticks() const { return ticks_.load(std::memory_order_relaxed); }
  std::uint64_t missed() const { return missed_.load(std::memory_order_relaxed); }
  // The cycle (bus) thread's id, once it ticked (0 before).
  pid_t tid() const { return tid_.load(std::memory_order_acquire); }
  std::vector<std::int64_t> samples() const {
    const auto n = static_cast<std::ptrdiff_t>(count_.load(std::memory_order_acquire));
    return {late_ns_.begin(), late_ns_.begin() + n};
  }

 private:
  std::chrono::nanoseconds period_;
  std::atomic<pid_t> tid_{0};
  std::vector<std::int64_t> late_ns_;
  std::atomic<std::size_t> count_{0};
  std::atomic<std::uint64_t> ticks_{0};
  std::atomic<std::uint64_t> missed_{0};
  std::atomic<bool> recording_{false};
};

// The domain's per-cycle callback: the round trip (submission to completion) of each valid cycle.
class RoundTripRecorder {
 public:
  explicit RoundTripRecorder(std::size_t capacity) : ns_(capacity) {}

  void on_cycle(Domain& domain, const CycleOutcome& outcome) noexcept {
    if (!recording_.load(std::memory_order_acquire)) return;
    if (!outcome.valid) {
      invalid_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    const std::size_t i = count_.load(std::memory_order_relaxed);
    if (i >= ns_.size()) return;
    ns_[i] = domain.stats().last_latency.count();
    count_.store(i + 1, std::memory_order_release);
  }
  ecat::master::CycleCallback callback() {
    return [this](Domain& d, const CycleOutcome& o) { on_cycle(d, o); };
  }
  void record() { recording_.store(true, std::memory_order_release); }
  bool full() const { return count_.load(std::memory_order_acquire) >= ns_.size(); }
  std::uint64_t invalid() const { return invalid_.load(std::memory_order_relaxed); }
  std::vector<std::int64_t> samples() const {
    const auto n = static_cast<std::ptrdiff_t>(count_.load(std::memory_order_acquire));
    return {ns_.begin(), ns_.begin() + n};
  }

 private:
  std::vector<std::int64_t> ns_;
  std::atomic<std::size_t> count_{0};
  std::atomic<std::uint64_t> invalid_{0};
  std::atomic<bool> recording_{false};
};

void heading(const char* title) {
  fmt::print("\n== {}\n", title);
}

// ---- 1. round trip over raw veth ---------------------------------------------------------------

// The same frame the domain sends: one LRW over an image of `image_size` bytes.
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

// Send, wait for the echo, at every period (as the domain does), `count` times.
std::vector<std::int64_t> echo_round_trips(ecat::link::Link& master,
                                           const std::vector<std::uint8_t>& frame,
                                           std::chrono::nanoseconds period, std::size_t count,
                                           std::size_t& lost) {
  std::vector<std::int64_t> ns;
  ns.reserve(count);
  auto deadline = Clock::now();
  for (std::size_t i = 0; i < count; ++i) {
    deadline += period;
    std::this_thread::sleep_until(deadline);
    const auto t0 = Clock::now();
    if (!master.send(frame).ok()) {
      ++lost;
      continue;
    }
    auto r = master.receive(100ms);
    const auto t1 = Clock::now();
    if (!r.ok() || !r->has_value()) {
      ++lost;
      continue;
    }
    ns.push_back((t1 - t0).count());
  }
  return ns;
}

void section_veth(const Mode& mode) {
  heading("1. cyclic round trip over raw veth (us), master domain at 1 kHz vs bare echo");
  ecat::bench::VethPair pair;
  if (!pair.problem().empty()) {
    fmt::print("skipped: {}\n", pair.problem());
    return;
  }
  const auto period = 1ms;
  const std::size_t samples = mode.full ? 30000 : 1500;
  fmt::print("{:>9} {:<20} {:>6} {:>6} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8}\n", "terminals", "path",
             "image", "n", "min", "p50", "p99", "p99.9", "max", "p50/echo");
  for (const std::size_t terminals : {std::size_t{1}, std::size_t{16}, std::size_t{64}}) {
    // The master against the simulator.
    Distribution master_rtt;
    std::size_t image_size = 0;
    std::uint64_t invalid = 0;
    std::string error;
    {
      Session session;
      auto server = make_server(terminals);
      auto segment_end = pair.open("s", true);
      auto master_end = pair.open("m", false);
      if (!server) {
        error = server.error().describe();
      } else if (!segment_end || !master_end) {
        error = pair.problem();
      } else {
        session.server = std::move(*server);
        if (auto r = session.server->serve(std::move(segment_end)); !r) {
          error = r.error().describe();
        } else {
          RoundTripRecorder recorder(samples);
          auto config = master_config(terminals, period);
          config.domains[0].on_cycle = recorder.callback();
          if (!session.run(std::move(master_end), std::move(config))) {
            error = session.error;
          } else {
            image_size = session.master->domains().at(0).image_size;
            std::this_thread::sleep_for(100ms);  // settle after activation
            recorder.record();
            const auto limit = period * static_cast<std::int64_t>(samples) * 4 + 10s;
            if (!wait_for([&] { return recorder.full(); }, limit)) {
              error = "the domain did not complete its samples in time";
            }
            master_rtt = distribution(recorder.samples());
            invalid = recorder.invalid();
          }
          (void)session.master->stop();
        }
      }
    }
    if (!error.empty()) {
      fmt::print("{:>9} error: {}\n", terminals, error);
      continue;
    }
    // The floor: a bare echo on the same pair, same frame, same pacing.
    auto master_end = pair.open("m", false);
    auto segment_end = pair.open("s", true);
    if (!master_end || !segment_end) {
      fmt::print("{:>9} echo error: {}\n", terminals, pair.problem());
      continue;
    }
    std::size_t lost = 0;
    Distribution echo;
    {
      ecat::bench::Echo responder(*segment_end);
      echo =
          distribution(echo_round_trips(*master_end, lrw_frame(image_size), period, samples, lost));
    }
    fmt::print("{:>9} {:<20} {:>6} {:>6} {} {:>8.2f}\n", terminals, "master + simulator",
               image_size, master_rtt.n, us_columns(master_rtt),
               echo.p50 > 0 ? master_rtt.p50 / echo.p50 : 0.0);
    fmt::print("{:>9} {:<20} {:>6} {:>6} {} {:>8}\n", terminals, "bare echo (floor)", image_size,
               echo.n, us_columns(echo), "1.00");
    if (invalid > 0 || lost > 0) {
      fmt::print("{:>9} ({} invalid cycles, {} echoes lost while sampling)\n", "", invalid, lost);
    }
  }
  fmt::print(
      "Ring: EK1100 + N terminals (EL1809/EL2809 alternating). image: LRW data bytes. master + "
      "simulator: the domain's submission to completion of each valid cycle "
      "(DomainStats::last_latency, read in DomainConfig::on_cycle on the bus thread). bare echo: "
      "send() to receive() of the same frame on the same raw link, paced at the same period.\n");
}

// ---- 2. cycle-start jitter
// ------------------------------------------------------------------------

// cyclictest (Debian's rt-tests) at the same rate, priority and length: the machine's own floor
// for a thread that sleeps to absolute deadlines. Its histogram (1 us buckets) gives the
// percentiles; samples beyond the histogram count at its reported maximum.
struct Cyclictest {
  std::string note;  // why there are no figures ("not installed", its error)
  Distribution d;
  std::uint64_t beyond_period = 0;  // wake-ups later than one period (the machine's own floor)
  std::string involuntary = "-";    // the cyclictest process's involuntary context switches
  bool ok = false;
};

bool on_path(const char* program) {
  const char* path = std::getenv("PATH");
  std::string dirs = path ? path : "/usr/bin:/bin";
  std::size_t at = 0;
  while (at <= dirs.size()) {
    const std::size_t colon = std::min(dirs.find(':', at), dirs.size());
    const std::string candidate = dirs.substr(at, colon - at) + "/" + program;
    if (::access(candidate.c_str(), X_OK) == 0) return true;
    at = colon + 1;
  }
  return false;
}

Cyclictest run_cyclictest(std::chrono::nanoseconds period, std::size_t loops,
                          std::optional<int> fifo, std::optional<int> cpu) {
  Cyclictest out;
  if (!on_path("cyclictest")) {
    out.note = "not installed (Debian package rt-tests, which scripts/setup installs)";
    return out;
  }
  constexpr int kHistogramUs = 10000;
  const auto command =
      fmt::format("cyclictest -q -m -t1 -p{} -i{} -l{} -h{}{} 2>&1", fifo.value_or(0),
                  std::chrono::duration_cast<std::chrono::microseconds>(period).count(), loops,
                  kHistogramUs, cpu ? fmt::format(" -a{}", *cpu) : std::string());
  // Its involuntary context switches: the children's rusage gains exactly this child's (the
  // shell execs cyclictest) when pclose reaps it.
  struct rusage children_before {};
  const bool counted = ::getrusage(RUSAGE_CHILDREN, &children_before) == 0;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) {
    out.note = fmt::format("cannot run it: {}", std::strerror(errno));
    return out;
  }
  std::vector<std::uint64_t> buckets(kHistogramUs, 0);
  std::uint64_t overflows = 0, max_us = 0, total = 0;
  std::string first_line;
  char line[512];
  while (std::fgets(line, sizeof line, pipe) != nullptr) {
    if (first_line.empty()) first_line = line;
    unsigned long us = 0, count = 0;
    if (std::sscanf(line, "%lu %lu", &us, &count) == 2 && line[0] != '#') {
      if (us < buckets.size()) buckets[us] += count;
      total += count;
    } else if (std::sscanf(line, "# Histogram Overflows: %lu", &count) == 1) {
      overflows += count;
    } else if (std::sscanf(line, "# Max Latencies: %lu", &count) == 1) {
      max_us = count;
    }
  }
  const int status = ::pclose(pipe);
  struct rusage children_after {};
  if (counted && ::getrusage(RUSAGE_CHILDREN, &children_after) == 0)
    out.involuntary = fmt::format("{}", children_after.ru_nivcsw - children_before.ru_nivcsw);
  if (status != 0 || total + overflows == 0) {
    while (!first_line.empty() && (first_line.back() == '\n' || first_line.back() == '\r'))
      first_line.pop_back();
    out.note = fmt::format("failed (exit status {}): {}", status, first_line);
    return out;
  }
  const auto period_us = std::chrono::duration_cast<std::chrono::microseconds>(period).count();
  for (std::size_t us = static_cast<std::size_t>(period_us) + 1; us < buckets.size(); ++us)
    out.beyond_period += buckets[us];
  out.beyond_period += overflows;
  std::vector<std::int64_t> ns;
  ns.reserve(total + overflows);
  for (std::size_t us = 0; us < buckets.size(); ++us)
    ns.insert(ns.end(), buckets[us], static_cast<std::int64_t>(us) * 1000);
  ns.insert(ns.end(), overflows, static_cast<std::int64_t>(max_us) * 1000);
  out.d = distribution(std::move(ns));
  out.d.max = static_cast<double>(max_us);
  out.ok = true;
  return out;
}

// Where a late tick's time went, from the bus's own record of it (Bus::set_cycle_trace), in us
// after the deadline that was due. Steps that ended before the deadline count nothing.
struct LateTick {
  double late = 0;     // woke - due
  double busy = 0;     // the bus thread went into its last wait only after the deadline
  double target = 0;   // that wait asked to be woken after the deadline
  double wake = 0;     // it came back from the wait late (the kernel's wake-up, or a lock)
  double after = 0;    // from receive() returning to the tick (frames matched, queues taken)
  bool frame = false;  // the last wait ended with a frame, not at its timeout
  const ecat::bus::CycleTraceRecord* previous = nullptr;  // the tick before, if recorded
};

LateTick explain(const ecat::bus::CycleTraceRecord& r, const ecat::bus::CycleTraceRecord* prev) {
  LateTick t;
  const auto us = [](std::int64_t ns) {
    return static_cast<double>(std::max<std::int64_t>(ns, 0)) / 1e3;
  };
  const std::int64_t due = r.due_ns;
  t.late = us(r.woke_ns - due);
  t.previous = prev;
  if (r.wait_entered_ns == 0) return t;  // no wait recorded before this tick
  t.busy = us(r.wait_entered_ns - due);
  const std::int64_t went = std::max(due, r.wait_entered_ns);
  t.target = us(r.wait_until_ns - went);
  t.wake = us(r.wait_returned_ns - std::max(went, r.wait_until_ns));
  t.after = us(r.woke_ns - std::max(due, r.wait_returned_ns));
  t.frame = r.wait_got_frame;
  return t;
}

// The worst ticks of a traced run, one line each, and which step held the late ones (later than
// one period).
void print_late_ticks(const ecat::bus::CycleTrace& trace, std::chrono::nanoseconds period) {
  const std::size_t n = trace.size();
  if (n == 0) return;
  std::vector<std::size_t> order(n);
  for (std::size_t i = 0; i < n; ++i)
    order[i] = i;
  const auto late_ns = [&](std::size_t i) { return trace[i].woke_ns - trace[i].due_ns; };
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return late_ns(a) > late_ns(b); });
  const auto previous = [&](std::size_t i) -> const ecat::bus::CycleTraceRecord* {
    return i > 0 && trace[i - 1].cycle + 1 == trace[i].cycle ? &trace[i - 1] : nullptr;
  };
  std::size_t late = 0, by_busy = 0, by_target = 0, by_wake = 0, by_after = 0, by_frame = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (late_ns(i) <= period.count()) continue;
    ++late;
    const LateTick t = explain(trace[i], previous(i));
    const double top = std::max({t.busy, t.target, t.wake, t.after});
    if (top == t.wake) {
      ++by_wake;
      if (t.frame) ++by_frame;
    } else if (top == t.busy) {
      ++by_busy;
    } else if (top == t.target) {
      ++by_target;
    } else {
      ++by_after;
    }
  }
  fmt::print(
      "        ticks later than one period: {} of {}; the longest step: wake-up {} ({} of them "
      "woken by a frame), busy at the deadline {}, wait asked past it {}, after the wake {}\n",
      late, n, by_wake, by_frame, by_busy, by_target, by_after);
  fmt::print(
      "        {:>8} {:>8} {:>8} {:>8} {:>8} {:>6} | previous tick, us after its deadline: "
      "{:>6} {:>6} {:>6} {:>6} {:>5}\n",
      "late", "busy", "target", "wake-up", "after", "ended", "ticked", "sent", "reply", "done",
      "turns");
  for (std::size_t k = 0; k < std::min<std::size_t>(5, n); ++k) {
    const std::size_t i = order[k];
    const LateTick t = explain(trace[i], previous(i));
    std::string prev = "(not recorded)";
    if (const auto* q = t.previous) {
      const auto at = [&](std::int64_t ns) {
        return ns == 0 ? std::string("-")
                       : fmt::format("{:.1f}", static_cast<double>(ns - q->due_ns) / 1e3);
      };
      prev = fmt::format("{:>6} {:>6} {:>6} {:>6} {:>5}", at(q->participants_ns), at(q->sent_ns),
                         at(q->reply_ns), at(q->completed_ns), q->turns);
    }
    fmt::print("        {:>8.1f} {:>8.1f} {:>8.1f} {:>8.1f} {:>8.1f} {:>6} |{:>38}{}\n", t.late,
               t.busy, t.target, t.wake, t.after,
               trace[i].wait_entered_ns == 0 ? "?"
               : t.frame                     ? "frame"
                                             : "timer",
               "", prev);
  }
}

// The simulator in a process of its own on the segment's end of a veth pair, as a real ring
// answers from outside the master's machine: it shares no lock, no memory link and no scheduler
// class with the master's threads. Stopped (its pipe closed, then reaped) on destruction.
class ChildSimulator {
 public:
  ChildSimulator(ecat::bench::VethPair& pair, std::size_t terminals) {
    int stop_pipe[2] = {-1, -1};
    int ready_pipe[2] = {-1, -1};
    if (::pipe2(stop_pipe, O_CLOEXEC) != 0 || ::pipe2(ready_pipe, O_CLOEXEC) != 0) {
      problem_ = fmt::format("pipe: {}", std::strerror(errno));
      return;
    }
    std::fflush(stdout);
    pid_ = ::fork();
    if (pid_ == 0) {
      // The child: nothing but the simulator's own thread runs here.
      ::close(stop_pipe[1]);
      ::close(ready_pipe[0]);
      auto server = make_server(terminals);
      auto end = pair.open("s", true);
      const char ok = server && end && (*server)->serve(std::move(end)) ? 1 : 0;
      (void)!::write(ready_pipe[1], &ok, 1);
      char c = 0;
      while (::read(stop_pipe[0], &c, 1) < 0 && errno == EINTR) {
      }
      if (server) (*server)->stop();
      ::_exit(0);
    }
    ::close(stop_pipe[0]);
    ::close(ready_pipe[1]);
    stop_fd_ = stop_pipe[1];
    if (pid_ < 0) {
      problem_ = fmt::format("fork: {}", std::strerror(errno));
      ::close(ready_pipe[0]);
      return;
    }
    char ok = 0;
    if (::read(ready_pipe[0], &ok, 1) != 1 || ok != 1) {
      problem_ = "the simulator process could not serve the veth pair's segment end";
    }
    ::close(ready_pipe[0]);
  }
  ~ChildSimulator() {
    if (stop_fd_ >= 0) ::close(stop_fd_);
    if (pid_ > 0) (void)::waitpid(pid_, nullptr, 0);
  }
  ChildSimulator(const ChildSimulator&) = delete;
  ChildSimulator& operator=(const ChildSimulator&) = delete;
  const std::string& problem() const { return problem_; }

 private:
  pid_t pid_ = -1;
  int stop_fd_ = -1;
  std::string problem_;
};

void section_jitter(const Mode& mode) {
  heading("2. cycle-start lateness (us after the deadline that was due), ecat vs cyclictest");
  fmt::print("{:>7} {:<18} {:>7} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>6} {:>6}  {}\n",
             "rate", "thread", "n", "min", "p50", "p99", "p99.9", "max", ">period", "skipped",
             "steal", "invol", "setup");
  // In process (the simulator's thread beside the master's, over a memory link) and, with root,
  // over veth with the simulator in a process of its own.
  ecat::bench::VethPair pair;
  const bool veth = mode.jitter_link != "memory" && pair.problem().empty();
  const bool memory = mode.jitter_link != "veth";
  const std::string pinned = mode.cpu ? fmt::format(", CPU {}", *mode.cpu) : std::string();
  for (const auto period : {std::chrono::nanoseconds(1ms), std::chrono::nanoseconds(250us),
                            std::chrono::nanoseconds(125us)}) {
    const auto seconds = mode.jitter_seconds ? std::chrono::seconds(*mode.jitter_seconds)
                         : mode.full         ? 60s
                                             : 3s;
    const auto samples = static_cast<std::size_t>(seconds / period);
    const auto rate = fmt::format("{} Hz", 1s / period);
    const auto print_cyclictest = [&](const char* label, const Cyclictest& ct,
                                      const std::string& steal, const std::string& setup) {
      if (!ct.ok) {
        fmt::print("{:>7} {:<18} {}\n", rate, label, ct.note);
        return;
      }
      fmt::print("{:>7} {:<18} {:>7} {} {:>8} {:>8} {:>6} {:>6}  {}\n", rate, label, ct.d.n,
                 us_columns(ct.d), ct.beyond_period, "-", steal, ct.involuntary,
                 fmt::format("-p{} -m{}, cpu_dma_latency 0{}", mode.fifo.value_or(0),
                             mode.cpu ? fmt::format(" -a{}", *mode.cpu) : std::string(), setup));
    };
    // ecat's own run (`floor` false): the master's cycle thread with the realtime setup asked
    // for, a probe in its Cycler. The floor under the same load (`floor` true): the same master
    // and simulator, the same domain at the same period, serving the same frames, but the
    // master's cycle thread at default scheduling, while cyclictest runs with the realtime
    // setup ecat had: what this machine gives a SCHED_FIFO thread beside that load.
    const auto run = [&](const char* label, bool over_veth, bool floor) {
      auto config = master_config(2, period);
      if (mode.fifo && !floor) {
        // A realtime user's setup, as cyclictest makes it: SCHED_FIFO, cpu_dma_latency held at
        // 0, memory locked (and the cycle thread's stack pre-faulted).
        config.cycle_thread.fifo_priority = *mode.fifo;
        config.cycle_thread.cpu_dma_latency_us = 0;
        config.cycle_thread.lock_memory = true;
      }
      if (mode.cpu && !floor) config.cycle_thread.cpu = *mode.cpu;
      std::optional<ChildSimulator> child;
      Session session;
      if (over_veth) {
        child.emplace(pair, 2);
        if (!child->problem().empty()) {
          fmt::print("{:>7} {:<18} error: {}\n", rate, label, child->problem());
          return;
        }
        auto master_end = pair.open("m", false);
        if (!master_end) {
          fmt::print("{:>7} {:<18} error: {}\n", rate, label, pair.problem());
          return;
        }
        (void)session.run(std::move(master_end), std::move(config));
      } else {
        (void)session.run_memory(2, std::move(config));
      }
      if (!session.error.empty()) {
        fmt::print("{:>7} {:<18} error: {}\n", rate, label, session.error);
        return;
      }
      Domain* domain = session.domain();
      ecat::master::Cycler* cycler = domain ? domain->cycler() : nullptr;
      if (!cycler) {
        fmt::print("{:>7} {:<18} error: the master's domain is not in a Cycler\n", rate, label);
        return;
      }
      if (floor) {
        const auto cycles = [&] {
          const auto counters = session.master->counters();
          std::uint64_t n = 0;
          for (const auto& d : counters.domains)
            n += d.valid;
          return n;
        };
        std::this_thread::sleep_for(100ms);
        const std::uint64_t before = cycles();
        const auto t0 = Clock::now();
        const StealWindow steal;
        const auto ct = run_cyclictest(period, samples, mode.fifo, mode.cpu);
        const std::string steal_ms = steal.ms();
        const std::uint64_t served = cycles() - before;
        const double window_s = ms_since(t0, Clock::now()) / 1e3;
        print_cyclictest(
            label, ct, steal_ms,
            fmt::format("; beside the {} pair: {:.0f} valid cycles/s served over cyclictest's run "
                        "(domain at {} Hz), master cycle thread at default scheduling",
                        over_veth ? "veth" : "memory-link", static_cast<double>(served) / window_s,
                        1s / period));
        (void)session.master->stop();
        return;
      }
      TickProbe probe(period, samples);
      if (auto r = cycler->add(probe, ecat::master::Cycler::kPriorityDc); !r) {
        fmt::print("{:>7} {:<18} error: {}\n", rate, label, r.error().describe());
        return;
      }
      // The bus's own record of every tick in the same window (where a late tick's time went).
      ecat::bus::CycleTrace trace(samples + samples / 8 + 64);
      std::this_thread::sleep_for(100ms);
      ecat::bus::Bus* bus = session.master->bus();
      if (bus) (void)bus->set_cycle_trace(&trace);
      const pid_t tid = probe.tid();
      const auto switches_before = tid != 0 ? involuntary_switches(tid) : std::nullopt;
      const StealWindow steal;
      probe.record();
      (void)wait_for([&] { return probe.full(); }, seconds * 3 + 5s);
      const std::string steal_ms = steal.ms();
      const auto switches_after = tid != 0 ? involuntary_switches(tid) : std::nullopt;
      if (bus) (void)bus->set_cycle_trace(nullptr);
      (void)cycler->remove(probe);
      const auto late = probe.samples();
      const auto beyond = std::count_if(late.begin(), late.end(),
                                        [&](std::int64_t ns) { return ns > period.count(); });
      const auto d = distribution(late);
      const auto thread = session.master->status().cycle_thread;
      fmt::print("{:>7} {:<18} {:>7} {} {:>8} {:>8} {:>6} {:>6}  {}\n", rate, label, d.n,
                 us_columns(d), beyond, probe.missed(), steal_ms,
                 difference(switches_before, switches_after),
                 thread.empty() ? "default scheduling" : thread);
      print_late_ticks(trace, period);
      (void)session.master->stop();
    };
    if (memory) {
      run("ecat memory", false, false);
      run("cyclictest+memory", false, true);
    }
    if (veth) {
      run("ecat veth", true, false);
      run("cyclictest+veth", true, true);
    }
    const StealWindow steal;
    const auto ct = run_cyclictest(period, samples, mode.fifo, mode.cpu);
    print_cyclictest("cyclictest alone", ct, steal.ms(), "; nothing else of the bench running");
  }
  if (mode.jitter_link != "memory" && !pair.problem().empty()) {
    fmt::print("ecat veth: skipped: {}\n", pair.problem());
  }
  fmt::print(
      "ecat memory: the simulator's thread in the same process, over a memory link; ecat veth: the "
      "simulator in a process of its own on the other end of a veth pair (raw sockets, as a real "
      "ring). ecat: a CyclicParticipant added to the master's own Cycler (the domain's) records, "
      "every tick, CycleTick::woke_at minus the deadline that was due (CycleTick::deadline - "
      "missed x period), the start of the tick in which the domain stages its outputs and submits "
      "its LRW. >period: wake-ups later than one period. skipped: deadlines passed while the "
      "thread was late (it then runs once, never in a burst). Below each ecat line, from the "
      "bus's own record of the same ticks (Bus::set_cycle_trace): for the ticks later than one "
      "period, which step took most of the time, and the five latest ticks: busy (the bus thread "
      "went into its last wait only after the deadline), target (that wait asked to wake after "
      "it), wake-up (it came back from the wait late: the kernel's wake-up or a lock), after "
      "(from the wait to the tick), ended (the wait ended by a frame or at its timer), and the "
      "previous tick's steps. cyclictest: one thread, clock_nanosleep to absolute deadlines, the "
      "same rate, priority, pinning and number of samples; 1 us buckets. cyclictest+memory / "
      "cyclictest+veth: the floor under the same load: the same master and simulator pair as the "
      "ecat row above (same ring, same domain period, so the same frames: its valid cycles per "
      "second are printed), its cycle thread at default scheduling, while cyclictest runs with "
      "ecat's realtime setup{}. cyclictest alone: nothing else of the bench running. steal: ms of "
      "the guest's steal time (/proc/stat, both vCPUs together) during the row's window: the host "
      "ran something else on a vCPU that had work. invol: involuntary context switches of the "
      "timed thread in the window (ecat: the cycle thread, /proc/self/task/<tid>/status; "
      "cyclictest: its whole process, from the children's rusage).\n",
      pinned);
}

// ---- 3. start to operational
// ----------------------------------------------------------------------

void section_startup(const Mode& mode) {
  heading("3. Master::start to operational (ms), in-process simulator, 1 ms domain");
  const std::size_t runs = mode.runs ? *mode.runs : mode.full || mode.startup_only ? 5 : 1;
  struct Run {
    double total = 0, discovery = 0, preop = 0, op = 0;
    std::uint64_t events_missed = 0;
    ecat::master::MasterCounters counters;
  };
  struct Row {
    std::size_t terminals = 0;
    std::vector<Run> runs;
    std::string error;
  };
  const auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  std::vector<Row> rows;
  fmt::print("{:>9} {:>4} {:>8} {:>9} {:>8} {:>8} {:>8} {:>6} {:>8} {:>8}  {}\n", "terminals",
             "run", "total", "discovery", "->preop", "->op", "frames", "lost", "retries",
             "timeouts", "flag");
  std::vector<std::size_t> sizes{64, 128, 256, 512, 1024};
  if (mode.terminals) sizes = {*mode.terminals};
  const std::string path =
      fmt::format("/tmp/ecat-master-bench-{}.yaml", static_cast<long>(getpid()));
  for (const std::size_t terminals : sizes) {
    Row row;
    row.terminals = terminals;
    if (!write_ring_file(path, terminals)) row.error = "cannot write the ring file " + path;
    for (std::size_t run = 0; run < runs && row.error.empty(); ++run) {
      Session session;
      session.await_limit = 30s;  // the goal is 2 s at 1,024 terminals
      if (!session.run_ring_file(path)) {
        row.error = session.error;
        break;
      }
      (void)session.master->flush_events(5s);
      Run r;
      r.total = ms_between(session.started, session.operational);
      r.discovery = ms_between(session.started, session.awaiting_preop);
      r.preop = ms_between(session.awaiting_preop, session.last_preop);
      r.op = ms_between(session.last_preop, session.operational);
      r.events_missed = session.events_missed;
      r.counters = session.master->counters();
      row.runs.push_back(std::move(r));
    }
    if (!row.runs.empty()) {
      std::vector<double> frames;
      for (const auto& r : row.runs)
        frames.push_back(static_cast<double>(r.counters.frames_sent));
      const double frames_median = median(frames);
      for (std::size_t i = 0; i < row.runs.size(); ++i) {
        const Run& r = row.runs[i];
        const bool storm = static_cast<double>(r.counters.frames_sent) > 2 * frames_median;
        std::string flag = storm ? "> 2x median frames" : "";
        if (r.events_missed > 0) flag += fmt::format(" ({} events missed)", r.events_missed);
        fmt::print("{:>9} {:>4} {:>8.1f} {:>9.1f} {:>8.1f} {:>8.1f} {:>8} {:>6} {:>8} {:>8}  {}\n",
                   terminals, i + 1, r.total, r.discovery, r.preop, r.op, r.counters.frames_sent,
                   r.counters.frames_lost, r.counters.retries, r.counters.transaction_timeouts,
                   flag);
      }
    }
    if (!row.error.empty()) fmt::print("{:>9} error: {}\n", terminals, row.error);
    rows.push_back(std::move(row));
  }
  std::remove(path.c_str());
  fmt::print("\n{:>9} {:>5} {:>10} {:>10} {:>10} {:>10} {:>8} {:>8} {:>10}\n", "terminals", "runs",
             "total min", "total p50", "total max", "discovery", "->preop", "->op", "frames p50");
  for (const Row& row : rows) {
    if (row.runs.empty()) continue;
    std::vector<double> total, discovery, preop, op, frames;
    for (const auto& r : row.runs) {
      total.push_back(r.total);
      discovery.push_back(r.discovery);
      preop.push_back(r.preop);
      op.push_back(r.op);
      frames.push_back(static_cast<double>(r.counters.frames_sent));
    }
    fmt::print("{:>9} {:>5} {:>10.1f} {:>10.1f} {:>10.1f} {:>10.1f} {:>8.1f} {:>8.1f} {:>10.0f}\n",
               row.terminals, row.runs.size(), *std::min_element(total.begin(), total.end()),
               median(total), *std::max_element(total.begin(), total.end()), median(discovery),
               median(preop), median(op), median(frames));
  }
  fmt::print(
      "Ring: a ring file (simulator and master sections) of EK1100 + N terminals (EL1809/EL2809 "
      "alternating), every terminal's process data in one domain, no DC. discovery: start -> "
      "awaiting_preop (slave count polled every 10 ms until two polls agree on the count and a "
      "complete link picture, else until stable for 1 s, the default scan_stable_ms; station "
      "addresses, reset block, INIT); ->preop: until the "
      "last slave entered PREOP (SII read, mailbox set-up, PREOP writes: the slaves' bring-up); "
      "->op: from there until the master was operational (quiesce, the domain starting to cycle, "
      "the SAFEOP and OP walks). Phases from the master's slave.state events (time_ns). "
      "frames/lost/retries/timeouts: the master's bus counters at "
      "operational; flag: a run that sent more than twice the median's frames (goal: 512 "
      "terminals < 1 s, 1024 < 2 s, every run). Medians over the runs.\n");
}

// ---- 4. hot path
// ----------------------------------------------------------------------------------

struct HotPathRow {
  const char* name = "";
  double median_ns = 0;
  double min_ns = 0;
  std::size_t failures = 0;
  double allocations_per_call = 0;
  double cpu_median_ns = 0;       // the same batches timed by the thread's CPU clock
  std::string steal_ms = "-";     // the guest's steal time over the row's batches
  std::string involuntary = "-";  // this thread's involuntary context switches meanwhile
};

// Runs `call` `calls` times in 20 batches; ns per call of the median and the fastest batch, and
// the heap allocations it made on this thread.
template <class Call>
HotPathRow time_calls(const char* name, std::size_t calls, Call call) {
  constexpr std::size_t kBatches = 20;
  const std::size_t per_batch = std::max<std::size_t>(calls / kBatches, 1);
  std::vector<double> batch_ns;
  HotPathRow row;
  row.name = name;
  for (std::size_t i = 0; i < per_batch / 10; ++i)
    (void)call(i);  // warm up
  struct rusage before {};
  const bool switches = ::getrusage(RUSAGE_THREAD, &before) == 0;
  const StealWindow steal;
  const auto counted_before = allocs::counted.load();
  allocs::count_this_thread = true;
  // Each batch by the wall clock and by this thread's CPU clock: a batch slow by the wall clock
  // only lost its CPU (preempted, or the vCPU not running); slow by both, the CPU itself ran
  // the same instructions slower.
  std::vector<double> cpu_ns;
  const auto thread_ns = [] {
    timespec t{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return static_cast<std::int64_t>(t.tv_sec) * 1'000'000'000 + t.tv_nsec;
  };
  for (std::size_t b = 0; b < kBatches; ++b) {
    const std::int64_t c0 = thread_ns();
    const auto t0 = Clock::now();
    for (std::size_t i = 0; i < per_batch; ++i) {
      if (!call(i)) ++row.failures;
    }
    const auto t1 = Clock::now();
    const std::int64_t c1 = thread_ns();
    batch_ns.push_back(static_cast<double>((t1 - t0).count()) / static_cast<double>(per_batch));
    cpu_ns.push_back(static_cast<double>(c1 - c0) / static_cast<double>(per_batch));
  }
  allocs::count_this_thread = false;
  row.steal_ms = steal.ms();
  struct rusage after {};
  if (switches && ::getrusage(RUSAGE_THREAD, &after) == 0)
    row.involuntary = fmt::format("{}", after.ru_nivcsw - before.ru_nivcsw);
  row.allocations_per_call = static_cast<double>(allocs::counted.load() - counted_before) /
                             static_cast<double>(per_batch * kBatches);
  std::sort(batch_ns.begin(), batch_ns.end());
  row.median_ns = batch_ns[kBatches / 2];
  row.min_ns = batch_ns.front();
  std::sort(cpu_ns.begin(), cpu_ns.end());
  row.cpu_median_ns = cpu_ns[kBatches / 2];
  return row;
}

void section_hot_path(const Mode& mode, Session& session) {
  heading("4. hot-path cost (ns per call), application thread, domain cycling at 1 kHz");
  const std::size_t calls = mode.full ? 2'000'000 : 200'000;
  auto in = session.master->slave("t0");   // EL1809
  auto out = session.master->slave("t1");  // EL2809
  Domain* domain = session.domain();
  if (!in || !out || !domain) {
    fmt::print("error: the session has no t0 / t1 / main\n");
    return;
  }
  ecat::master::Slave& inputs = **in;
  ecat::master::Slave& outputs = **out;
  if (!wait_for([&] { return inputs.read_input("channel_1").ok(); }, 5s)) {
    fmt::print("error: inputs never became readable\n");
    return;
  }
  // The domain proves inputs fresh from a TSC stamp once it has calibrated the counter against
  // the clock (a first window of 5 ms of cycles): before that every read also reads the clock,
  // which would time the start-up rather than the steady state an application sees.
  std::this_thread::sleep_for(50ms);
  std::optional<ecat::master::PdoRegistration> in_reg, out_reg;
  for (const auto& r : domain->registrations()) {
    if (r.key.slave == inputs.info().station && !in_reg) in_reg = r;
    if (r.key.slave == outputs.info().station && !out_reg) out_reg = r;
  }
  if (!in_reg || !out_reg) {
    fmt::print("error: no registrations for t0 / t1\n");
    return;
  }
  const ecat::master::Value on(true), off(false);
  std::array<std::uint8_t, 64> buffer{};
  std::array<std::uint8_t, 64> staged{};
  const ecat::wire::Bytes out_bytes(staged.data(), out_reg->size);
  const ecat::wire::MutableBytes into(buffer.data(), buffer.size());
  std::vector<HotPathRow> rows;
  rows.push_back(time_calls("Slave::read_input", calls,
                            [&](std::size_t) { return inputs.read_input("channel_1").ok(); }));
  rows.push_back(time_calls("Slave::write_output", calls, [&](std::size_t i) {
    return outputs.write_output("channel_1", (i & 1) != 0 ? on : off).ok();
  }));
  auto in_handle = ecat::master::SignalHandle::resolve(*session.master, "t0", "channel_1");
  auto out_handle = ecat::master::SignalHandle::resolve(*session.master, "t1", "channel_1");
  if (in_handle && out_handle) {
    rows.push_back(time_calls("SignalHandle::read", calls,
                              [&](std::size_t) { return in_handle->read().ok(); }));
    rows.push_back(time_calls("SignalHandle::write", calls, [&](std::size_t i) {
      return out_handle->write((i & 1) != 0 ? on : off).ok();
    }));
  }
  rows.push_back(time_calls("Domain::read(handle)", calls,
                            [&](std::size_t) { return domain->read(in_reg->handle, into).ok(); }));
  rows.push_back(time_calls("Domain::read(key)", calls,
                            [&](std::size_t) { return domain->read(in_reg->key, into).ok(); }));
  rows.push_back(time_calls("Domain::write(handle)", calls, [&](std::size_t i) {
    staged[0] = static_cast<std::uint8_t>(i);
    return domain->write(out_reg->handle, out_bytes).ok();
  }));
  rows.push_back(time_calls("Domain::write(key)", calls, [&](std::size_t i) {
    staged[0] = static_cast<std::uint8_t>(i);
    return domain->write(out_reg->key, out_bytes).ok();
  }));
  rows.push_back(time_calls("Domain::sample(handle)", calls, [&](std::size_t) {
    return domain->sample(in_reg->handle, into).ok();
  }));
  // The floor under every freshness check: one read of the clock the domains stamp with.
  rows.push_back(time_calls("steady_clock::now", calls, [](std::size_t) {
    return Clock::now().time_since_epoch().count() != 0;
  }));
  // The CPU's own speed in this run: a chain of 8 dependent multiply-adds (no memory, no clock,
  // no lock; latency-bound, so a busy sibling hardware thread barely slows it, a lower clock
  // does).
  std::uint64_t chain = 1;  // carried from call to call: the calls cannot overlap
  rows.push_back(time_calls("reference: 8 dep. mul", calls, [&chain](std::size_t) {
    std::uint64_t x = chain;
    for (int k = 0; k < 8; ++k) {
      x = x * 0x9E3779B97F4A7C15ull + 1;
      asm volatile("" : "+r"(x));  // keeps the chain: no closed form, no vectorising
    }
    chain = x;
    return true;
  }));
  fmt::print("{:<24} {:>10} {:>10} {:>10} {:>9} {:>12} {:>6} {:>6}\n", "call", "ns median",
             "ns best", "cpu median", "failures", "allocs/call", "steal", "invol");
  for (const auto& r : rows) {
    fmt::print("{:<24} {:>10.1f} {:>10.1f} {:>10.1f} {:>9} {:>12.3f} {:>6} {:>6}\n", r.name,
               r.median_ns, r.min_ns, r.cpu_median_ns, r.failures, r.allocations_per_call,
               r.steal_ms, r.involuntary);
  }
  fmt::print(
      "{} calls each in 20 batches; 'median' / 'best' are the batches' mean ns per call. Signals: "
      "channel_1 of an EL1809 (input, 1 bit) and an EL2809 (output, 1 bit); Domain calls on their "
      "SyncManager images ({} and {} bytes). cpu median: the median batch by this thread's CPU "
      "clock (CLOCK_THREAD_CPUTIME_ID): as slow as 'ns median', the CPU itself ran slower; "
      "faster, the thread lost its CPU meanwhile. reference: the CPU's speed in this run, one "
      "latency-bound chain of 8 dependent 64-bit multiply-adds per call. steal: ms of the guest's "
      "steal time "
      "(/proc/stat, both vCPUs) during the row's batches; invol: this thread's involuntary context "
      "switches "
      "meanwhile (getrusage RUSAGE_THREAD).\n",
      calls, in_reg->size, out_reg->size);
}

// ---- 5. allocations per cycle
// ---------------------------------------------------------------------

void section_allocations(const Mode& mode, Session& session, const char* what) {
  fmt::print("-- {}\n", what);
  Domain* domain = session.domain();
  ecat::master::Cycler* cycler = domain ? domain->cycler() : nullptr;
  if (!cycler) {
    fmt::print("error: the master's domain is not in a Cycler\n");
    return;
  }
  // The probe marks the bus thread for the counting allocator on its first tick.
  TickProbe probe(1ms, 0);
  if (auto r = cycler->add(probe); !r) {
    fmt::print("error: {}\n", r.error().describe());
    return;
  }
  (void)wait_for([&] { return probe.ticks() > 10; }, 5s);
  const auto window = mode.alloc_seconds ? std::chrono::seconds(*mode.alloc_seconds)
                      : mode.full        ? 60s
                                         : 3s;
  const auto before = domain->stats();
  const auto bus_before = allocs::bus_thread.load();
  const auto total_before = allocs::total.load();
  allocs::count_bus_thread = true;
  std::this_thread::sleep_for(window);
  allocs::count_bus_thread = false;
  const auto after = domain->stats();
  const auto bus_allocations = allocs::bus_thread.load() - bus_before;
  const auto total_allocations = allocs::total.load() - total_before;
  (void)cycler->remove(probe);
  const auto cycles = after.cycle_count - before.cycle_count;
  const auto valid = after.valid_count - before.valid_count;
  fmt::print("{:>8} {:>8} {:>14} {:>16} {:>20}\n", "cycles", "valid", "cycle-thread", "per cycle",
             "(whole process)");
  fmt::print("{:>8} {:>8} {:>14} {:>16} {:>20}\n", cycles, valid, bus_allocations,
             cycles > 0 ? fmt::format("{:.3f}", static_cast<double>(bus_allocations) /
                                                    static_cast<double>(cycles))
                        : std::string("n/a"),
             total_allocations);
  fmt::print(
      "{} s of OP with {} slaves at 1 kHz. cycle-thread: operator new calls on the bus thread "
      "(tick, LRW, reply, classification, publication, on_cycle, and the bus's share of any "
      "other traffic). whole process (for reference): the control loop, the simulator, this "
      "thread.\n",
      std::chrono::duration_cast<std::chrono::seconds>(window).count(),
      session.master->status().slave_count);
}

// ---- 6. cable redundancy: cycles lost at a break ----------------------------------------------

// Cycles that did not come back valid.
std::uint64_t invalid_cycles(const ecat::master::DomainStats& s) {
  return s.wkc_mismatch_count + s.timeout_count + s.expired_count + s.overrun_count +
         s.link_error_count;
}

void section_redundancy(const Mode& mode) {
  using ecat::sim::RedundantTopology;
  using ecat::wire::RedundantPort;
  heading("6. cable redundancy: cycles lost at a cable break and at its heal (in process)");
  constexpr std::size_t kTerminals = 16;
  auto made = make_server(kTerminals);
  if (!made) {
    fmt::print("error: {}\n", made.error().describe());
    return;
  }
  Session session;
  session.server = std::move(*made);
  ecat::sim::RedundantPortsOptions port_options;
  auto ports = ecat::sim::RedundantPorts::create(*session.server, port_options);
  if (!ports) {
    fmt::print("error: {}\n", ports.error().describe());
    return;
  }
  ecat::link::RedundantLinkOptions link_options;
  link_options.primary_mac = port_options.primary_mac;
  link_options.secondary_mac = port_options.secondary_mac;
  auto link =
      ecat::link::RedundantLink::open((*ports)->take_link(RedundantPort::primary),
                                      (*ports)->take_link(RedundantPort::secondary), link_options);
  if (!link) {
    fmt::print("error: {}\n", link.error().describe());
    return;
  }
  ecat::link::RedundantLink* redundant = link->get();
  if (!session.run(std::move(*link), master_config(kTerminals, 1ms))) {
    fmt::print("error: cannot bring up the redundant session: {}\n", session.error);
    return;
  }
  Domain* domain = session.domain();
  if (domain == nullptr) {
    fmt::print("error: no domain\n");
    return;
  }
  const std::size_t slaves = kTerminals + 1;
  const int breaks = mode.breaks ? *mode.breaks : mode.full ? 500 : 60;
  // After each change: this many cycles must pass before the next (the change's losses have
  // shown by then: a frame is lost or late within its own cycle and the next).
  constexpr std::uint64_t kSettleCycles = 30;
  std::uint64_t seed = 0x9E3779B97F4A7C15ull;
  const auto next_random = [&seed] {
    seed ^= seed << 13;
    seed ^= seed >> 7;
    seed ^= seed << 17;
    return seed;
  };
  struct Tally {
    std::uint64_t events = 0, lost = 0, worst = 0, none = 0, one = 0, more = 0, stuck = 0;
    void add(std::uint64_t n) {
      ++events;
      lost += n;
      worst = std::max(worst, n);
      (n == 0 ? none : n == 1 ? one : more) += 1;
    }
  };
  Tally at_break, at_heal, at_cut;
  const auto change = [&](const RedundantTopology& topology, Tally& tally) {
    const auto before = domain->stats();
    if (auto r = (*ports)->set_topology(topology); !r) {
      fmt::print("error: {}\n", r.error().describe());
      return false;
    }
    const bool settled = wait_for(
        [&] { return domain->stats().cycle_count >= before.cycle_count + kSettleCycles; }, 5s);
    const auto after = domain->stats();
    if (!settled) ++tally.stuck;
    tally.add(invalid_cycles(after) - invalid_cycles(before));
    return true;
  };
  const auto started = Clock::now();
  for (int i = 0; i < breaks; ++i) {
    // One in eight a master port's cable, else between two slaves.
    const std::uint64_t r = next_random();
    const bool cut = r % 8 == 0;
    const RedundantTopology topology =
        cut ? RedundantTopology::cut_at((r >> 3) % 2 == 0 ? RedundantPort::primary
                                                          : RedundantPort::secondary)
            : RedundantTopology::broken_after(1 + (r >> 3) % (slaves - 1));
    if (!change(topology, cut ? at_cut : at_break)) return;
    if (!change(RedundantTopology::whole_ring(), at_heal)) return;
  }
  const double seconds = ms_since(started, Clock::now()) / 1e3;
  const auto link_status = redundant->status();
  fmt::print("{:<28} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}   {}\n", "change", "events", "lost", "max",
             "0 lost", "1 lost", ">1 lost", "target");
  const auto row = [](const char* what, const Tally& t) {
    fmt::print("{:<28} {:>7} {:>7} {:>7} {:>7} {:>7} {:>7}   {}\n", what, t.events, t.lost, t.worst,
               t.none, t.one, t.more, "<= 1 per change (the one in flight)");
  };
  row("break between two slaves", at_break);
  row("master port cable cut", at_cut);
  row("heal (ring whole again)", at_heal);
  const std::uint64_t stuck = at_break.stuck + at_cut.stuck + at_heal.stuck;
  fmt::print(
      "{} slaves, 1 ms domain, {} changes in {:.1f} s, each followed by {} cycles; lost: cycles "
      "that did not come back valid (working counter, timeout, expiry, overrun, link error) from "
      "the change to {} cycles after it{}. link: {} breaks, {} heals seen, {} merged replies, {} "
      "lone bounces, {} merge-window timeouts. master: {}\n",
      slaves, at_break.events + at_cut.events + at_heal.events, seconds, kSettleCycles,
      kSettleCycles,
      stuck > 0 ? fmt::format(" ({} changes saw fewer cycles within 5 s)", stuck) : std::string(),
      link_status.ring_breaks, link_status.ring_heals, link_status.merged, link_status.lone_bounces,
      link_status.merge_timeouts, ecat::master::to_string(session.master->state()));
  (void)session.master->stop();
  session.master.reset();
  ports->reset();
}

int usage(const char* self) {
  std::fprintf(
      stderr,
      "usage: %s [--quick | --full] [--startup [--terminals N] [--runs N]] [--fifo PRIORITY]\n"
      "          [--cpu N]\n"
      "          [--only jitter|hot|alloc|redundancy] [--jitter-seconds S] [--alloc-seconds S]\n"
      "          [--breaks N] [--jitter-link memory|veth|both]\n",
      self);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  Mode mode;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      mode.full = false;
    } else if (std::strcmp(argv[i], "--full") == 0) {
      mode.full = true;
    } else if (std::strcmp(argv[i], "--startup") == 0) {
      mode.startup_only = true;
    } else if (std::strcmp(argv[i], "--terminals") == 0 && i + 1 < argc) {
      mode.terminals = static_cast<std::size_t>(std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--runs") == 0 && i + 1 < argc) {
      mode.runs = static_cast<std::size_t>(std::max(1, std::atoi(argv[++i])));
    } else if (std::strcmp(argv[i], "--fifo") == 0 && i + 1 < argc) {
      mode.fifo = std::atoi(argv[++i]);
    } else if (std::strcmp(argv[i], "--cpu") == 0 && i + 1 < argc) {
      mode.cpu = std::max(0, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--jitter-seconds") == 0 && i + 1 < argc) {
      mode.jitter_seconds = std::max(1, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--alloc-seconds") == 0 && i + 1 < argc) {
      mode.alloc_seconds = std::max(1, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--jitter-link") == 0 && i + 1 < argc) {
      mode.jitter_link = argv[++i];
      if (mode.jitter_link != "memory" && mode.jitter_link != "veth" &&
          mode.jitter_link != "both") {
        return usage(argv[0]);
      }
    } else if (std::strcmp(argv[i], "--breaks") == 0 && i + 1 < argc) {
      mode.breaks = std::max(1, std::atoi(argv[++i]));
    } else if (std::strcmp(argv[i], "--only") == 0 && i + 1 < argc) {
      mode.only = argv[++i];
      if (mode.only != "jitter" && mode.only != "hot" && mode.only != "alloc" &&
          mode.only != "redundancy") {
        return usage(argv[0]);
      }
    } else {
      return usage(argv[0]);
    }
  }
  const auto t0 = Clock::now();
  fmt::print("master_bench ({}): figures only, nothing asserted\n", mode.full ? "full" : "quick");
  fmt::print("{}\n", ecat::bench::build_info());
  fmt::print("{}\n", kernel_line());
  if (mode.startup_only) {
    section_startup(mode);
    fmt::print("\n(total {:.1f} s)\n", ms_since(t0, Clock::now()) / 1e3);
    return 0;
  }
  const auto runs = [&mode](const char* section) {
    return mode.only.empty() || mode.only == section;
  };
  if (mode.only.empty()) section_veth(mode);
  if (runs("jitter")) section_jitter(mode);
  if (mode.only.empty()) section_startup(mode);
  if (runs("hot") || runs("alloc")) {
    Session session;
    if (!session.run_memory(16, master_config(16, 1ms))) {
      fmt::print("\nerror: cannot bring up the 16-terminal session: {}\n", session.error);
    } else {
      if (runs("hot")) section_hot_path(mode, session);
      if (runs("alloc")) {
        heading("5. heap allocations per cycle in steady OP (cycle thread; must be 0)");
        section_allocations(mode, session, "default slave health polls (AL status every 250 ms)");
      }
    }
  }
  if (runs("alloc")) {
    // The cyclic path alone: no acyclic traffic shares the bus thread.
    auto config = master_config(16, 1ms);
    for (auto& slave : config.slaves)
      slave.health_poll.reset();
    Session session;
    if (session.run_memory(16, std::move(config))) {
      section_allocations(mode, session, "health polls off (the cyclic path alone)");
    } else {
      fmt::print("error: {}\n", session.error);
    }
  }
  if (runs("redundancy")) section_redundancy(mode);
  fmt::print("\n(total {:.1f} s)\n", ms_since(t0, Clock::now()) / 1e3);
  return 0;
}
