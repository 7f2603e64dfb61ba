// A control loop that runs every cycle on the master's cycle thread and computes the outputs
// from this cycle's inputs (DomainConfig::on_cycle).
//
// The "controller" here is the simplest one that proves the timing: an inverter. Each cycle it
// reads the EL1809's channel_1 and writes the opposite to the EL2809's channel_1, which the
// simulated wiring of examples/default.yaml feeds back to that input. The loop therefore
// oscillates, one edge per round trip through the ring; a real loop would read sensors and
// write set points the same way.
//
//   example_control_loop [examples/default.yaml]
//
// Exit code 0 when the loop ran and the input toggled at least 100 times in one second.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <thread>

#include <ecat/ecat.hpp>

using namespace std::chrono_literals;
using ecat::master::SignalHandle;
using ecat::master::Value;

// Everything the loop uses, owned by main and shared with the cycle thread. The signals are
// resolved once, on the control side, when the session runs; `armed` hands them over to the
// cycle thread (release/acquire), which from then on reads and writes them without lookups,
// locks or allocation.
struct Loop {
  SignalHandle input;
  SignalHandle output;
  std::atomic<bool> armed{false};
  std::atomic<std::uint64_t> cycles{0};
  std::atomic<std::uint64_t> edges{0};
  bool last = false;  // touched by the cycle thread only

  // Runs on the cycle thread right after the cycle's inputs were published; what it writes goes
  // out with the next cycle. It must not block, log or throw: it delays the cycle.
  void on_cycle(ecat::master::Domain&, const ecat::master::CycleOutcome& outcome) {
    if (!outcome.valid || !armed.load(std::memory_order_acquire)) return;  // no fresh inputs
    auto value = input.read();
    if (!value) return;
    const bool level = ecat::master::as_bool(*value).value_or(false);
    if (level != last) edges.fetch_add(1, std::memory_order_relaxed);
    last = level;
    (void)output.write(Value(!level));
    cycles.fetch_add(1, std::memory_order_relaxed);
  }
};

int main(int argc, char** argv) {
  const std::string ring = argc > 1 ? argv[1] : "examples/default.yaml";

  // The callback belongs to the domain's configuration, so it is set before the session starts:
  // open_master hands the configuration read from the file to `configure` first.
  Loop loop;
  bool found = false;
  auto master = ecat::open_master(ring, {.configure = [&](ecat::master::MasterConfig& config) {
                                    for (auto& domain : config.domains) {
                                      if (domain.id != "main") continue;
                                      domain.on_cycle = [&loop](auto& d, const auto& o) {
                                        loop.on_cycle(d, o);
                                      };
                                      found = true;
                                    }
                                  }});
  if (!master) {
    std::fprintf(stderr, "%s\n", master.error().describe().c_str());
    return 1;
  }
  if (!found) {
    std::fprintf(stderr, "%s has no domain 'main'\n", ring.c_str());
    return 1;
  }
  if (auto op = (*master)->await_operational(20s); !op) {
    std::fprintf(stderr, "no OP: %s\n", op.error().describe().c_str());
    return 1;
  }
  // Resolved once; a wrong slave or signal name is an error naming it.
  auto input = (*master)->signal_handle("inputs", "channel_1");
  auto output = (*master)->signal_handle("outputs", "channel_1");
  if (!input || !output) {
    std::fprintf(stderr, "%s\n", (!input ? input.error() : output.error()).describe().c_str());
    return 1;
  }
  loop.input = std::move(*input);
  loop.output = std::move(*output);
  loop.armed.store(true, std::memory_order_release);

  // The application thread only watches; the loop runs by itself. await_next_cycle blocks until
  // the next valid cycle completed (its inputs published, the callback run): from then on the
  // loop is running.
  auto main_domain = (*master)->domain("main");
  if (!main_domain) {
    std::fprintf(stderr, "%s\n", main_domain.error().describe().c_str());
    return 1;
  }
  if (auto first = (*main_domain)->await_next_cycle(1s); !first) {
    std::fprintf(stderr, "%s\n", first.error().describe().c_str());
    return 1;
  }
  const auto cycles_before = loop.cycles.load();
  const auto edges_before = loop.edges.load();
  std::this_thread::sleep_for(1s);
  const auto cycles = loop.cycles.load() - cycles_before;
  const auto edges = loop.edges.load() - edges_before;
  std::printf("in 1 s: %llu cycles ran the loop, the input toggled %llu times\n",
              static_cast<unsigned long long>(cycles), static_cast<unsigned long long>(edges));

  // Detach the loop from the signals before they go away with the session.
  loop.armed.store(false, std::memory_order_release);
  (void)(*master)->stop();
  return edges >= 100 ? 0 : 1;
}
