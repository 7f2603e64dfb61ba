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
using ecat::master::Slave;
using ecat::master::Value;

// Shared between the application and the cycle thread: plain atomics, no locks.
struct Loop {
  std::atomic<Slave*> inputs{nullptr};  // set once the session is operational
  std::atomic<Slave*> outputs{nullptr};
  std::atomic<std::uint64_t> cycles{0};
  std::atomic<std::uint64_t> edges{0};
  bool last = false;  // touched by the cycle thread only

  // Runs on the cycle thread right after the cycle's inputs were published; what it writes goes
  // out with the next cycle. It must not block, log or throw: it delays the cycle.
  // read_input/write_output neither wait nor allocate (after their first use).
  void on_cycle(ecat::master::Domain&, const ecat::master::CycleOutcome& outcome) {
    Slave* in = inputs.load(std::memory_order_acquire);
    Slave* out = outputs.load(std::memory_order_acquire);
    if (!outcome.valid || in == nullptr || out == nullptr) return;  // no fresh inputs: hold
    auto value = in->read_input("channel_1");
    if (!value) return;
    const bool level = ecat::master::as_bool(*value).value_or(false);
    if (level != last) edges.fetch_add(1, std::memory_order_relaxed);
    last = level;
    (void)out->write_output("channel_1", Value(!level));
    cycles.fetch_add(1, std::memory_order_relaxed);
  }
};

int main(int argc, char** argv) {
  const std::string ring = argc > 1 ? argv[1] : "examples/default.yaml";
  auto config = ecat::master::load_master_config(ring);
  auto backend = ecat::sim::open_backend("sim:" + ring);
  if (!config || !backend) {
    std::fprintf(stderr, "%s\n", (!config ? config.error() : backend.error()).describe().c_str());
    return 1;
  }

  // The callback belongs to the domain's configuration, so it is set before the session starts;
  // the slaves it talks to exist only afterwards, hence the atomics.
  Loop loop;
  bool found = false;
  for (auto& domain : config->domains) {
    if (domain.id != "main") continue;
    domain.on_cycle = [&loop](ecat::master::Domain& d, const ecat::master::CycleOutcome& o) {
      loop.on_cycle(d, o);
    };
    found = true;
  }
  if (!found) {
    std::fprintf(stderr, "%s has no domain 'main'\n", ring.c_str());
    return 1;
  }

  ecat::master::Master master(*config);
  if (auto started = master.start(std::move(backend->link)); !started) {
    std::fprintf(stderr, "%s\n", started.error().describe().c_str());
    return 1;
  }
  auto op = master.await_operational(20s);
  auto inputs = master.slave("inputs");
  auto outputs = master.slave("outputs");
  if (!op || !inputs || !outputs) {
    std::fprintf(stderr, "%s\n", !op ? op.error().describe().c_str() : "no inputs/outputs");
    return 1;
  }
  loop.inputs.store(*inputs, std::memory_order_release);
  loop.outputs.store(*outputs, std::memory_order_release);

  // The application thread only watches; the loop runs by itself.
  const auto cycles_before = loop.cycles.load();
  const auto edges_before = loop.edges.load();
  std::this_thread::sleep_for(1s);
  const auto cycles = loop.cycles.load() - cycles_before;
  const auto edges = loop.edges.load() - edges_before;
  std::printf("in 1 s: %llu cycles ran the loop, the input toggled %llu times\n",
              static_cast<unsigned long long>(cycles), static_cast<unsigned long long>(edges));

  // Detach the loop from the slaves before they go away with the session.
  loop.inputs.store(nullptr, std::memory_order_release);
  loop.outputs.store(nullptr, std::memory_order_release);
  (void)master.stop();
  return edges >= 100 ? 0 : 1;
}
