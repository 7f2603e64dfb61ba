// Bring a ring to OP, switch an output on and off, and stop.
//
// The ring is simulated in this process, so this runs anywhere: examples/default.yaml describes
// both sides of the wire. Its `simulator:` section is the segment (an EK1100 coupler, an EL1809
// whose 16 inputs are wired to the 16 outputs of an EL2809, an EL3202 and a CiA 402 drive); its
// master sections (`domains:`, `slaves:`, `dc:`, docs/MASTER-CONFIG.md) tell the master what to
// make of it. On real hardware, open "raw:eth0" instead of "sim:FILE" (root or CAP_NET_RAW).
//
//   example_reach_op [examples/default.yaml]
//
// Exit code 0 when the input followed the output both ways, 1 otherwise.
#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

#include <ecat/ecat.hpp>

using namespace std::chrono_literals;
using ecat::master::Value;

// Waits until `signal` of `slave` reads `expected`: an output written now goes out with the next
// cycle (1 ms here) and comes back through the wiring a cycle or two later.
static bool input_becomes(ecat::master::Slave& slave, const char* signal, bool expected) {
  const auto deadline = std::chrono::steady_clock::now() + 1s;
  while (std::chrono::steady_clock::now() < deadline) {
    auto value = slave.read_input(signal);  // an error until the first valid cycle
    if (value && ecat::master::as_bool(*value) == expected) return true;
    std::this_thread::sleep_for(1ms);
  }
  return false;
}

int main(int argc, char** argv) {
  const std::string ring = argc > 1 ? argv[1] : "examples/default.yaml";

  // What the master is told to do: its sections of the ring file (the simulator's are ignored).
  auto config = ecat::master::load_master_config(ring);
  if (!config) {
    std::fprintf(stderr, "%s\n", config.error().describe().c_str());
    return 1;
  }
  // What it talks to: "sim:FILE" runs the file's simulated ring behind an in-process link.
  auto backend = ecat::sim::open_backend("sim:" + ring);
  if (!backend) {
    std::fprintf(stderr, "%s\n", backend.error().describe().c_str());
    return 1;
  }

  // start() returns at once; discovery and the walk INIT -> PREOP -> SAFEOP -> OP run on the
  // master's own threads. Every call returns a Result: a value, or an Error naming what failed.
  ecat::master::Master master(*config);
  if (auto started = master.start(std::move(backend->link)); !started) {
    std::fprintf(stderr, "%s\n", started.error().describe().c_str());
    return 1;
  }
  if (auto op = master.await_operational(20s); !op) {
    std::fprintf(stderr, "no OP: %s\n", op.error().describe().c_str());
    return 1;
  }
  std::printf("operational: %zu slaves\n", master.slaves().size());

  // Slaves are named by the configuration; their process data are named signals.
  auto outputs = master.slave("outputs");  // the EL2809
  auto inputs = master.slave("inputs");    // the EL1809
  if (!outputs || !inputs) {
    std::fprintf(stderr, "the ring has no slaves named outputs and inputs\n");
    return 1;
  }
  bool followed = true;
  for (const bool level : {true, false}) {
    // Staged into the process image; the next cycle sends it. Never waits for the bus.
    if (auto written = (*outputs)->write_output("channel_1", Value(level)); !written) {
      std::fprintf(stderr, "%s\n", written.error().describe().c_str());
      followed = false;
      break;
    }
    const bool seen = input_becomes(**inputs, "channel_1", level);
    std::printf("outputs.channel_1 = %d -> inputs.channel_1 %s\n", level ? 1 : 0,
                seen ? "followed" : "DID NOT FOLLOW");
    followed = followed && seen;
  }

  // stop() takes every slave back to INIT and ends the session (the destructor would too).
  if (auto stopped = master.stop(); !stopped) {
    std::fprintf(stderr, "%s\n", stopped.error().describe().c_str());
    return 1;
  }
  std::printf("stopped: every slave back in INIT\n");
  return followed ? 0 : 1;
}
