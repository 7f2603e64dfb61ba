// The randomized soak test of issue 6: faults drawn from the simulator's catalogue are injected
// into a running OP ring for a bounded time; invariants are checked throughout and after.
//
//   ECAT_SOAK_SECONDS=300 ECAT_SOAK_SEED=1234 build/gcc/tests/test_scenarios --gtest_filter=Soak.*
//
// Default: 30 s (CI), a fresh seed, printed so a failure can be replayed.
//
// Invariants:
//  - no crash, no hang (every call returns; the test ends);
//  - the master never leaves the runtime states (operational / recovering; a lost slave never
//    ends the session) and never makes a transition the seed's diagram does not draw;
//  - every fault shows in the API while it lasts: an injected exchange fault is followed by an
//    invalid cycle, a slave fault by that slave's fault or state. An exchange fault acts on the
//    next N frames the simulator processes, and those can be frames the master gave up on before
//    the fault existed: on a loaded machine the simulator's thread can be off the processor for
//    longer than the frame timeout while the master goes on sending, so the frames queue up, the
//    master declares the oldest lost (an invalid cycle, counted before the injection), and once
//    the simulator runs again the fault lands on them and their replies come back too late to
//    count. No master can see such a fault. So a fault that does not show is checked frame by
//    frame (the link is logged, and the simulator's exchange count at the injection names the
//    frames the fault took): it fails unless none of its frames was an LRW frame the master was
//    still waiting for when the fault was injected;
//  - memory does not grow (resident set after the soak vs after warm-up);
//  - once the faults stop, the master returns to operational, and an output staged while the
//    ring was faulty is applied (it comes back through the loopback wiring).
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <optional>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>

#include <ecat/link/forwarding_link.hpp>
#include <ecat/link/link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/master/config.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/frame.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

namespace fault = sim::fault;

std::uint64_t env_or(const char* name, std::uint64_t fallback) {
  const char* text = std::getenv(name);
  if (text == nullptr || *text == '\0') return fallback;
  return std::strtoull(text, nullptr, 10);
}

std::size_t resident_kib() {
  std::ifstream statm("/proc/self/statm");
  std::size_t pages = 0;
  std::size_t resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<std::size_t>(::sysconf(_SC_PAGESIZE)) / 1024;
}

struct Drawn {
  std::string what;
  sim::Fault fault;
  bool exchange = false;  // shows as an invalid cycle
  std::string slave;      // shows on this slave (fault or state), when set
};

std::int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// Every frame the master sends, numbered in sending order from 1. The simulator takes the frames
// of its one memory link in the same order, so its exchange count names them: exchange k is frame
// k. (A frame the link dropped would break that: it is noted, and nothing is excused after it.)
class FrameLog {
 public:
  struct Sent {
    std::uint64_t number = 0;
    std::int64_t at_ns = 0;  // steady clock, just before the link took it
    bool lrw = false;        // carries a domain's exchange
    std::string datagrams;   // "LRW", "FPRD 0x1001:0x0130", ...
  };

  void sent(wire::Bytes frame) {
    Sent s;
    s.at_ns = steady_ns();
    if (auto decoded = wire::decode_frame(frame)) {
      for (const wire::DatagramView d : *decoded.frame) {
        if (!s.datagrams.empty()) s.datagrams += " + ";
        s.datagrams += std::string(wire::to_string(d.header.command));
        if (d.header.command == wire::Command::lrw) {
          s.lrw = true;
        } else {
          s.datagrams += fmt::format(" 0x{:04x}:0x{:04x}", d.header.adp(), d.header.ado());
        }
      }
    }
    std::lock_guard lock(mutex_);
    s.number = ++count_;
    ring_[s.number % ring_.size()] = std::move(s);
  }
  void dropped() {
    std::lock_guard lock(mutex_);
    if (!first_dropped_) first_dropped_ = count_;
  }
  std::uint64_t count() const {
    std::lock_guard lock(mutex_);
    return count_;
  }
  // Frame `number`, while it is still in the log.
  std::optional<Sent> find(std::uint64_t number) const {
    std::lock_guard lock(mutex_);
    if (number == 0 || number > count_ || count_ - number >= ring_.size()) return std::nullopt;
    if (first_dropped_ && number > *first_dropped_) return std::nullopt;
    return ring_[number % ring_.size()];
  }

 private:
  mutable std::mutex mutex_;
  std::array<Sent, 4096> ring_{};
  std::uint64_t count_ = 0;
  std::optional<std::uint64_t> first_dropped_;
};

// The master's end of the memory link, logging what it sends.
class LoggedLink final : public link::ForwardingLink {
 public:
  LoggedLink(std::unique_ptr<link::Link> inner, std::shared_ptr<FrameLog> log)
      : ForwardingLink(std::move(inner)), log_(std::move(log)) {}
  Result<void> send(wire::Bytes frame) override {
    log_->sent(frame);
    auto done = ForwardingLink::send(frame);
    const auto dropped = inner().stats().frames_dropped;
    if (dropped != dropped_) {
      dropped_ = dropped;
      log_->dropped();
    }
    return done;
  }

 private:
  std::shared_ptr<FrameLog> log_;
  std::uint64_t dropped_ = 0;
};

struct Injection {
  std::uint64_t first_frame = 0;  // the first exchange (frame) the fault acts on
  std::int64_t at_ns = 0;
  std::uint64_t frames_sent = 0;  // by the master, at the injection
};

// Injects under the simulator's lock, so that no frame is processed between reading its exchange
// count and the fault becoming active: the fault acts on exchanges count + 1, count + 2, ...
Result<Injection> inject_counted(sim::SimServer& server, const FrameLog& log,
                                 const sim::Fault& fault) {
  return server.with_segment([&](sim::Segment&, sim::FaultInjector& injector) -> Result<Injection> {
    Injection at;
    at.at_ns = steady_ns();  // the server's segment clock is CLOCK_MONOTONIC too
    at.frames_sent = log.count();
    at.first_frame = injector.stats().exchanges + 1;
    if (auto done = injector.inject(fault, at.at_ns); !done) return done.error();
    return at;
  });
}

// For a per-exchange fault that did not show: why it could not, or nullopt when one of its frames
// was an LRW frame whose reply the master was still waiting for at the injection (then the master
// missed it). `text` gets the frames either way.
std::optional<std::string> could_not_show(const FrameLog& log, const Injection& at,
                                          std::uint64_t frames, std::chrono::nanoseconds timeout,
                                          std::string& text) {
  bool excused = at.first_frame <= at.frames_sent + 1;  // else the numbering is off
  if (!excused) {
    text += fmt::format("  the simulator had taken {} frames, the master sent {}\n",
                        at.first_frame - 1, at.frames_sent);
  }
  std::uint64_t stale_lrw = 0;
  for (std::uint64_t k = at.first_frame; k < at.first_frame + frames; ++k) {
    const auto f = log.find(k);
    if (!f) {
      text += fmt::format("  frame #{}: not in the log\n", k);
      excused = false;
      continue;
    }
    const double ms = static_cast<double>(at.at_ns - f->at_ns) / 1e6;
    const bool given_up = f->at_ns + timeout.count() <= at.at_ns;
    text += fmt::format(
        "  frame #{}: {}, sent {:.1f} ms {} the injection{}\n", k, f->datagrams, std::abs(ms),
        ms >= 0 ? "before" : "after",
        f->lrw ? (given_up ? " (LRW, past its reply deadline)" : " (LRW, awaited)") : "");
    if (f->lrw && !given_up) excused = false;
    if (f->lrw && given_up) ++stale_lrw;
  }
  if (!excused) return std::nullopt;
  return fmt::format(
      "its {} frames were {} LRW frame(s) already past their {} ms reply deadline "
      "and {} other(s)",
      frames, stale_lrw, std::chrono::duration_cast<std::chrono::milliseconds>(timeout).count(),
      frames - stale_lrw);
}

Drawn draw(std::mt19937_64& rng) {
  std::uniform_int_distribution<int> kind(0, 8);
  // At least 4 exchanges: a shorter window can fall on health-poll frames only, and one poll
  // that fails is by design not yet a fault.
  std::uniform_int_distribution<std::uint64_t> count(4, 12);
  const auto n = count(rng);
  switch (kind(rng)) {
    case 0:
      return {fmt::format("drop {} replies", n), fault::next(fault::drop_responses(), n), true, ""};
    case 1:
      return {fmt::format("wkc -1 for {}", n), fault::next(fault::wkc_offset(-1), n), true, ""};
    case 2:
      return {fmt::format("outputs' logical wkc -1 for {}", n),
              fault::next(fault::logical_wkc_offset("outputs", -1), n), true, ""};
    case 3:
      return {fmt::format("truncate {} replies", n), fault::next(fault::truncate_reply(4), n), true,
              ""};
    case 4:
      return {fmt::format("disconnect outputs for {}", 20 * n),
              fault::next(fault::disconnect("outputs"), 20 * n), true, ""};
    case 5:
      return {"outputs retreat to SAFEOP", fault::retreat_to_safeop("outputs"), false, "outputs"};
    case 6:
      return {"inputs power-cycled", fault::power_cycle("inputs"), true, "inputs"};
    case 7:
      return {"outputs latch AL error 0x001D", fault::latch_al_error("outputs", 0x001D), false,
              "outputs"};
    default:
      return {fmt::format("duplicate {} replies", n), fault::next(fault::duplicate_reply(), n),
              false, ""};
  }
}

TEST(Soak, RandomFaultsOnARunningRingHealAndKeepTheInvariants) {
  const auto seconds = env_or("ECAT_SOAK_SECONDS", 30);
  const auto seed = env_or("ECAT_SOAK_SEED", std::random_device{}());
  std::printf("soak: %llu s, seed %llu (replay: ECAT_SOAK_SEED=%llu)\n",
              static_cast<unsigned long long>(seconds), static_cast<unsigned long long>(seed),
              static_cast<unsigned long long>(seed));
  RecordProperty("seed", std::to_string(seed));
  std::mt19937_64 rng(seed);

  RingSpec spec;
  spec.domain_period = 5ms;
  spec.health_poll = 20ms;
  auto log = std::make_shared<FrameLog>();
  spec.wrap_link = [log](std::unique_ptr<link::Link> inner) -> std::unique_ptr<link::Link> {
    return std::make_unique<LoggedLink>(std::move(inner), log);
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->loopback(true));
  ring->forget_states();
  const auto warm_kib = resident_kib();

  std::uint64_t injected = 0;
  std::uint64_t visible = 0;
  std::uint64_t unseeable = 0;  // exchange faults with no awaited LRW frame among theirs
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  std::uniform_int_distribution<int> pause_ms(100, 600);
  bool staged = false;
  while (std::chrono::steady_clock::now() < end) {
    auto drawn = draw(rng);
    const auto before = ring->domain_stats();
    auto at = inject_counted(*ring->server, *log, drawn.fault);
    ASSERT_TRUE(at) << drawn.what << ": " << at.error().describe() << " (seed " << seed << ")";
    ++injected;
    // Visible while it lasts: an invalid cycle, or the slave's fault/state.
    const bool seen = eventually(
        [&] {
          if (drawn.exchange) {
            const auto now = ring->domain_stats();
            if (now.wkc_mismatch_count > before.wkc_mismatch_count ||
                now.total_miss_count > before.total_miss_count) {
              return true;
            }
          }
          if (!drawn.slave.empty()) {
            auto& s = ring->slave(drawn.slave);
            if (s.info().fault || s.state() != SlaveState::op) return true;
          }
          return !drawn.exchange && drawn.slave.empty();  // nothing to see for this kind
        },
        2s);
    if (seen) {
      ++visible;
    } else {
      // Per-exchange faults act on the `exchanges` frames after the injection; the others at once.
      const auto frames = drawn.fault.form == sim::Fault::Form::effect ? drawn.fault.exchanges : 0;
      std::string text;
      std::optional<std::string> why;
      if (drawn.exchange && frames > 0) {
        why = could_not_show(*log, *at, frames, ring->master->bus()->frame_timeout(), text);
      }
      const auto after = ring->domain_stats();
      text += fmt::format("  meanwhile: {} cycles, {} valid, domain {}; {}\n",
                          after.cycle_count - before.cycle_count,
                          after.valid_count - before.valid_count, master::to_string(after.state),
                          ring->describe());
      if (why) {
        ++unseeable;
        std::printf("soak: %s could not show: %s\n%s", drawn.what.c_str(), why->c_str(),
                    text.c_str());
      } else {
        ADD_FAILURE() << drawn.what << " never showed in the API (seed " << seed << ")\n" << text;
      }
    }
    // Stage an output while the ring is faulty: it must be applied once healthy.
    if (!staged && ring->state() == MasterState::recovering) {
      ASSERT_TRUE(ring->slave("outputs").write_output("channel_1", false));
      ASSERT_TRUE(ring->slave("outputs").write_output("channel_16", true));
      staged = true;
    }
    const auto state = ring->state();
    ASSERT_TRUE(state == MasterState::operational || state == MasterState::recovering)
        << "after " << drawn.what << ": " << ring->describe() << " (seed " << seed << ")";
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(rng)));
  }

  // The faults stop: back to operational, the staged output applied.
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 30s))
      << ring->describe() << " (seed " << seed << ")";
  if (staged) {
    EXPECT_TRUE(eventually(
        [&] {
          auto a = ring->slave("inputs").read_input("channel_1");
          auto b = ring->slave("inputs").read_input("channel_16");
          return a && b && master::as_bool(*a) == false && master::as_bool(*b) == true;
        },
        10s))
        << "an output staged during the faults was not applied (seed " << seed << ")";
  }
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  for (auto s : ring->states()) {
    EXPECT_TRUE(s == MasterState::operational || s == MasterState::recovering)
        << "the master went to " << master::to_string(s) << " (seed " << seed << ")";
  }
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
  const auto end_kib = resident_kib();
  std::printf(
      "soak: %llu faults injected, %llu seen in the API, %llu could not show (none of their frames "
      "was an LRW frame the master still awaited), resident %zu -> %zu KiB\n",
      static_cast<unsigned long long>(injected), static_cast<unsigned long long>(visible),
      static_cast<unsigned long long>(unseeable), warm_kib, end_kib);
  // Bounded growth: allocator caches, not a leak per fault. Under AddressSanitizer the resident
  // set holds its quarantine of freed memory (256 MiB by default), so the bound is checked in the
  // plain build; there LeakSanitizer checks for leaks at exit instead.
#if defined(__SANITIZE_ADDRESS__)
  constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
  constexpr bool kAddressSanitizer = true;
#else
  constexpr bool kAddressSanitizer = false;
#endif
#else
  constexpr bool kAddressSanitizer = false;
#endif
  if (!kAddressSanitizer) {
    EXPECT_LT(end_kib, warm_kib + 64 * 1024) << "resident memory grew (seed " << seed << ")";
  }
}

// The redundant variant (issue 16): the same ring with a second master port (sim::RedundantPorts,
// in process) and the master on a RedundantLink. The cable breaks at a random point (between two
// slaves or at either master port) and heals, now and then together with a process-data or slave
// fault. An output staged while the cable is broken must be applied: while it is broken when
// nothing else is wrong (that is what redundancy is for), and after the heal in any case, with
// the master back in `operational` each time.
//
//   ECAT_SOAK_REDUNDANT_SECONDS=60 ECAT_SOAK_SEED=1234 build/gcc/tests/test_scenarios
//     --gtest_filter=Soak.Redundant*
//
// Default: 8 s (CI).
TEST(Soak, RedundantRingCableBreaksAndHealsAmongOtherFaults) {
  const auto seconds = env_or("ECAT_SOAK_REDUNDANT_SECONDS", 8);
  const auto seed = env_or("ECAT_SOAK_SEED", std::random_device{}());
  std::printf("redundant soak: %llu s, seed %llu (replay: ECAT_SOAK_SEED=%llu)\n",
              static_cast<unsigned long long>(seconds), static_cast<unsigned long long>(seed),
              static_cast<unsigned long long>(seed));
  RecordProperty("seed", std::to_string(seed));
  std::mt19937_64 rng(seed);

  RingSpec spec;
  spec.transport = Transport::redundant;
  spec.domain_period = 5ms;
  spec.health_poll = 20ms;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->loopback(true));
  ring->forget_states();

  const auto reads = [&](bool value) {
    auto a = ring->slave("inputs").read_input("channel_1");
    auto b = ring->slave("inputs").read_input("channel_16");
    return a && b && master::as_bool(*a) == value && master::as_bool(*b) == !value;
  };
  const auto stage = [&](bool value) {
    return ring->slave("outputs").write_output("channel_1", value) &&
           ring->slave("outputs").write_output("channel_16", !value);
  };
  std::uniform_int_distribution<int> where(0, 3);
  std::uniform_int_distribution<int> other(0, 5);
  std::uniform_int_distribution<std::uint64_t> count(4, 12);
  std::uniform_int_distribution<int> pause_ms(50, 300);
  bool value = true;
  std::uint64_t breaks = 0;
  std::uint64_t with_other = 0;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  while (std::chrono::steady_clock::now() < end) {
    // The break: after the coupler, after the inputs terminal, or at either master port.
    sim::Fault cable = fault::ring_heal();
    switch (where(rng)) {
      case 0:
        cable = fault::ring_break(1);
        break;
      case 1:
        cable = fault::ring_break(2);
        break;
      case 2:
        cable = fault::ring_cut(wire::RedundantPort::primary);
        break;
      default:
        cable = fault::ring_cut(wire::RedundantPort::secondary);
        break;
    }
    const std::string what = sim::describe(cable);
    ASSERT_TRUE(ring->server->inject(cable)) << what << " (seed " << seed << ")";
    ++breaks;
    // Now and then something else goes wrong meanwhile.
    std::optional<sim::Fault> also;
    switch (other(rng)) {
      case 0:
        also = fault::next(fault::drop_responses(), count(rng));
        break;
      case 1:
        also = fault::next(fault::wkc_offset(-1), count(rng));
        break;
      case 2:
        also = fault::retreat_to_safeop("outputs");
        break;
      default:
        break;
    }
    if (also) {
      ASSERT_TRUE(ring->server->inject(*also)) << describe(*also) << " (seed " << seed << ")";
      ++with_other;
    }
    value = !value;
    ASSERT_TRUE(stage(value));
    if (!also) {
      EXPECT_TRUE(eventually([&] { return reads(value); }, 5s))
          << "an output staged through " << what << " was not applied while it lasted (seed "
          << seed << "); " << ring->describe();
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(rng)));
    const auto state = ring->state();
    ASSERT_TRUE(state == MasterState::operational || state == MasterState::recovering)
        << "through " << what << ": " << ring->describe() << " (seed " << seed << ")";

    ASSERT_TRUE(ring->server->inject(fault::ring_heal()));
    ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 15s))
        << "not operational after healing " << what << ": " << ring->describe() << " (seed " << seed
        << ")";
    EXPECT_TRUE(eventually([&] { return reads(value); }, 10s))
        << "an output staged through " << what << (also ? " and " + describe(*also) : "")
        << " was lost (seed " << seed << "); " << ring->describe();
  }
  for (auto s : ring->states()) {
    EXPECT_TRUE(s == MasterState::operational || s == MasterState::recovering)
        << "the master went to " << master::to_string(s) << " (seed " << seed << ")";
  }
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
  EXPECT_TRUE(
      eventually([&] { return ring->redundant_link->status().ring == link::RingState::whole; }, 2s))
      << "the master's link does not see the healed ring whole (seed " << seed << ")";
  std::printf("redundant soak: %llu cable breaks healed, %llu with another fault\n",
              static_cast<unsigned long long>(breaks), static_cast<unsigned long long>(with_other));
}

// Hot connect in the fault mix (issue 16): coupler -> inputs -> outputs, then the group `tool`
// (tool_out -> tool_in, wired channel 1 to channel 1). The group is plugged and unplugged by the
// fault kinds hot_plug / hot_unplug (now, or scheduled a little later), now and then while the
// master's cable is pulled and put back, or with another process-data fault. After every change
// the master is back in `operational`, the group present when plugged and absent when not, and
// the outputs staged meanwhile (the fixed slaves' and, when present, the group's) are applied.
//
//   ECAT_SOAK_HOT_CONNECT_SECONDS=60 ECAT_SOAK_SEED=1234 build/gcc/tests/test_scenarios
//     --gtest_filter=Soak.HotConnect*
//
// Default: 5 s (CI).
TEST(Soak, HotConnectGroupPlugsAndUnplugsAmongCableBreaks) {
  const auto seconds = env_or("ECAT_SOAK_HOT_CONNECT_SECONDS", 5);
  const auto seed = env_or("ECAT_SOAK_SEED", std::random_device{}());
  std::printf("hot-connect soak: %llu s, seed %llu (replay: ECAT_SOAK_SEED=%llu)\n",
              static_cast<unsigned long long>(seconds), static_cast<unsigned long long>(seed),
              static_cast<unsigned long long>(seed));
  RecordProperty("seed", std::to_string(seed));
  std::mt19937_64 rng(seed);

  RingSpec spec;
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: tool_out, profile: EL2809, hot_connect: {group: tool, plugged: false}}
    - {name: tool_in, profile: EL1809}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: tool_out.channel_1, to: tool_in.channel_1}
)";
  spec.adjust = [](master::MasterConfig& c) {
    master::HotConnectGroup g;
    g.name = "tool";
    for (const char* name : {"tool_out", "tool_in"}) {
      master::SlaveConfig sc;
      sc.name = name;
      sc.process_data = master::ProcessDataRequest::all("main");
      sc.health_poll = 20ms;
      g.slaves.push_back(std::move(sc));
    }
    g.slaves[0].vendor_id = 0x2;
    g.slaves[0].product_code = 0x0AF93052;
    g.slaves[1].vendor_id = 0x2;
    g.slaves[1].product_code = 0x07113052;
    c.hot_connect.push_back(std::move(g));
    c.hot_connect_poll = 10ms;
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  ring->forget_states();
  auto& m = *ring->master;

  const auto group_state = [&] {
    const auto st = m.status();
    return st.hot_connect.empty() ? master::HotConnectState::absent : st.hot_connect[0].state;
  };
  const auto loop_reads = [&](const char* out, const char* in, bool value) {
    auto o = m.slave(out);
    auto i = m.slave(in);
    if (!o || !i) return false;
    auto v = (*i)->read_input("channel_1");
    return v && master::as_bool(*v) == value;
  };
  const auto stage = [&](const char* out, bool value) {
    auto o = m.slave(out);
    return o && (*o)->write_output("channel_1", master::Value(value));
  };
  std::uniform_int_distribution<int> how(0, 5);
  std::uniform_int_distribution<std::uint64_t> count(4, 12);
  std::uniform_int_distribution<int> pause_ms(0, 150);
  bool plugged = false;
  bool value = false;
  bool tool_value = false;
  std::uint64_t changes = 0;
  std::uint64_t with_cable = 0;
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  while (std::chrono::steady_clock::now() < end) {
    plugged = !plugged;
    const sim::Fault change = plugged ? fault::hot_plug("tool") : fault::hot_unplug("tool");
    std::string what = describe(change);
    switch (how(rng)) {
      case 0:  // the master's cable pulled meanwhile, put back after the change
        ASSERT_TRUE(ring->server->inject(
            fault::script({fault::master_link_down(), fault::wait(20ms), change, fault::wait(20ms),
                           fault::master_link_up()})));
        what += " with the master's cable pulled";
        ++with_cable;
        break;
      case 1:  // scheduled
        ASSERT_TRUE(ring->server->inject(fault::after(change, 30ms)));
        break;
      case 2:  // with lost frames
        ASSERT_TRUE(ring->server->inject(fault::next(fault::drop_responses(), count(rng))));
        ASSERT_TRUE(ring->server->inject(change));
        what += " among lost frames";
        break;
      default:
        ASSERT_TRUE(ring->server->inject(change)) << what;
        break;
    }
    ++changes;
    // Outputs staged while the change happens.
    value = !value;
    ASSERT_TRUE(stage("outputs", value));
    const auto want = plugged ? master::HotConnectState::present : master::HotConnectState::absent;
    ASSERT_TRUE(eventually([&] { return group_state() == want; }, 10s))
        << what << ": the group is " << master::to_string(group_state()) << " (seed " << seed
        << "); " << ring->describe();
    ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 10s))
        << "not operational after " << what << " (seed " << seed << "); " << ring->describe();
    EXPECT_TRUE(eventually([&] { return loop_reads("outputs", "inputs", value); }, 5s))
        << "an output staged through " << what << " was lost (seed " << seed << ")";
    if (plugged) {
      // The output staged for the group while it was away arrives, and a new one too.
      EXPECT_TRUE(eventually([&] { return loop_reads("tool_out", "tool_in", tool_value); }, 5s))
          << "the group's output staged before " << what << " was lost (seed " << seed << ")";
      tool_value = !tool_value;
      ASSERT_TRUE(stage("tool_out", tool_value));
      EXPECT_TRUE(eventually([&] { return loop_reads("tool_out", "tool_in", tool_value); }, 5s))
          << "the group's output was not applied after " << what << " (seed " << seed << ")";
    } else {
      tool_value = !tool_value;
      ASSERT_TRUE(stage("tool_out", tool_value));  // staged while the group is away
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(rng)));
  }
  for (auto s : ring->states()) {
    EXPECT_TRUE(s == MasterState::operational || s == MasterState::recovering)
        << "the master went to " << master::to_string(s) << " (seed " << seed << ")";
  }
  EXPECT_EQ(m.status().illegal_transitions, 0u);
  std::printf("hot-connect soak: %llu plugs and unplugs, %llu with the master's cable pulled\n",
              static_cast<unsigned long long>(changes),
              static_cast<unsigned long long>(with_cable));
}

}  // namespace
}  // namespace ecat::scenarios
