// Bring a ring to OP, switch an output on and off, and stop.
//
// The ring is simulated in this process, so this runs anywhere: examples/default.yaml describes
// both sides of the wire. Its `simulator:` section is the segment (an EK1100 coupler, an EL1809
// whose 16 inputs are wired to the 16 outputs of an EL2809, an EL3202 and a CiA 402 drive); its
// master sections (`domains:`, `slaves:`, `dc:`, docs/MASTER-CONFIG.md) tell the master what to
// make of it. On real hardware, write `master: backend: raw:eth0` in the file (root or
// CAP_NET_RAW).
//
//   example_reach_op [examples/default.yaml]
//
// Exit code 0 when the input followed the output both ways, 1 otherwise.
#include <chrono>
#include <cstdio>
#include <string>

#include <ecat/ecat.hpp>

using namespace std::chrono_literals;
using ecat::master::Value;

// Waits until `signal` of `slave` reads `expected`: an output written now goes out with the next
// cycle (1 ms here) and comes back through the wiring a cycle or two later.
// Domain::await_next_cycle blocks until the next cycle's inputs are in.
static bool input_becomes(ecat::master::Domain& domain, ecat::master::Slave& slave,
                          const char* signal, bool expected) {
  for (int cycles = 0; cycles < 1000; ++cycles) {
    if (!domain.await_next_cycle(100ms)) return false;
    auto value = slave.read_input(signal);
    if (value && ecat::master::as_bool(*value) == expected) return true;
  }
  return false;
}

int main(int argc, char** argv) {
  const std::string ring = argc > 1 ? argv[1] : "examples/default.yaml";

  // One call reads the file's master sections (`domains:`, `slaves:`, `dc:`, `master:`) and opens
  // what the master talks to: the file's `master: backend:` (raw:IFACE, udp:HOST:PORT,
  // sim:RING.yaml) or, as here, its own `simulator:` section run in this process. start() returns
  // at once; discovery and the walk INIT -> PREOP -> SAFEOP -> OP run on the master's own
  // threads. Every call returns a Result: a value, or an Error naming what failed.
  auto opened = ecat::open_master(ring);
  if (!opened) {
    std::fprintf(stderr, "%s\n", opened.error().describe().c_str());
    return 1;
  }
  ecat::master::Master& master = **opened;
  if (auto op = master.await_operational(20s); !op) {
    std::fprintf(stderr, "no OP: %s\n", op.error().describe().c_str());
    return 1;
  }
  std::printf("operational: %zu slaves\n", master.slaves().size());

  // Slaves are named by the configuration; their process data are named signals.
  auto outputs = master.slave("outputs");  // the EL2809
  auto inputs = master.slave("inputs");    // the EL1809
  auto domain = master.domain("main");     // the process image both are exchanged in
  if (!outputs || !inputs || !domain) {
    std::fprintf(stderr, "the ring has no slaves named outputs and inputs in a domain main\n");
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
    const bool seen = input_becomes(**domain, **inputs, "channel_1", level);
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
