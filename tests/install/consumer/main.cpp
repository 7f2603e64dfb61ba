// A user of the installed package (tests/install/run.sh builds it four ways: find_package and
// pkg-config, shared and static library). It brings the built-in simulated ring
// (examples/default.yaml, given as the argument) to OP in this process, switches an EL2809 output
// on and off and sees each level come back on the EL1809 input wired to it, stops, and checks
// that every simulated slave is back in INIT. Exit code 0 only when all of that happened.
#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

#include <ecat/ecat.hpp>
#include <ecat/sim/backend.hpp>  // the built-in simulated ring

namespace {

using namespace std::chrono_literals;

int fail(const std::string& what) {
  std::fprintf(stderr, "consumer: %s\n", what.c_str());
  return 1;
}

bool input_becomes(ecat::master::Slave& inputs, bool level) {
  const auto deadline = std::chrono::steady_clock::now() + 2s;
  while (std::chrono::steady_clock::now() < deadline) {
    auto value = inputs.read_input("channel_3");
    if (value && ecat::master::as_bool(*value) == level) return true;
    std::this_thread::sleep_for(1ms);
  }
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) return fail("usage: consumer RING.yaml");
  const std::string ring = argv[1];
  auto config = ecat::master::load_master_config(ring);
  if (!config) return fail(config.error().describe());
  auto backend = ecat::sim::open_backend("sim:" + ring);
  if (!backend) return fail(backend.error().describe());
  auto simulator = backend->simulator;  // outlives the session: the slaves' AL states after stop
  if (!simulator) return fail("sim: backend without a simulator");

  ecat::master::Master master(*config);
  if (auto started = master.start(std::move(backend->link)); !started) {
    return fail(started.error().describe());
  }
  if (auto op = master.await_operational(30s); !op) return fail(op.error().describe());
  auto outputs = master.slave("outputs");
  auto inputs = master.slave("inputs");
  if (!outputs || !inputs) return fail("no slaves named outputs and inputs");

  for (const bool level : {true, false}) {
    if (auto w = (*outputs)->write_output("channel_3", ecat::master::Value(level)); !w) {
      return fail(w.error().describe());
    }
    if (!input_becomes(**inputs, level)) {
      return fail(std::string("inputs.channel_3 did not follow outputs.channel_3 = ") +
                  (level ? "1" : "0"));
    }
  }
  if (auto stopped = master.stop(); !stopped) return fail(stopped.error().describe());

  const auto status = simulator->status();
  for (const auto& slave : status.slaves) {
    if (slave.al_state != ecat::wire::AlState::init) {
      return fail(slave.name + " is not in INIT after stop()");
    }
  }
  std::printf("ecat %s: %zu slaves to OP, output seen on the input both ways, back to INIT\n",
              ecat::kVersion, status.slaves.size());
  return 0;
}
