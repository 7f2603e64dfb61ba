// ecat demo: the whole product in one command, no hardware, no root, no network. The built-in
// simulated ring (examples/default.yaml, embedded: an EK1100 coupler, an EL1809 whose 16 inputs are
// wired to the 16 outputs of an EL2809, an EL3202 RTD terminal and a CiA 402 servo drive) runs in
// this process; the master brings it to OP, walks a bit over the outputs and shows the inputs
// follow, reads the temperatures, enables the drive in cyclic synchronous velocity mode and shows
// it moving, then takes every slave back to INIT.
//
// Exit code 0 when every step did what it shows; 1 otherwise (the failing step is printed).
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <variant>

#include <fmt/format.h>

#include <ecat/bus/bus.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "command.hpp"
#include "default_ring.hpp"
#include "interrupt.hpp"
#include "session_view.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::master::Master;
using ecat::master::MasterState;
using ecat::master::Slave;
using ecat::master::Value;

struct Options {
  double duration_s = 5.0;
  double timeout_s = 20.0;
};

// Polls `condition` every millisecond until it holds or `limit` passed.
bool wait_for(const std::function<bool()>& condition, std::chrono::milliseconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (!condition()) {
    if (std::chrono::steady_clock::now() >= end || ecat::tool::interrupted()) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

std::string bits_text(std::uint16_t bits) {
  std::string out;
  for (int ch = 16; ch >= 1; --ch)
    out += ((bits >> (ch - 1)) & 1u) != 0 ? '1' : '.';
  return out;
}

std::optional<std::uint16_t> read_inputs(Slave& inputs) {
  std::uint16_t bits = 0;
  for (int ch = 1; ch <= 16; ++ch) {
    auto v = inputs.read_input(fmt::format("channel_{}", ch));
    if (!v) return std::nullopt;
    if (ecat::master::as_bool(*v).value_or(false))
      bits |= static_cast<std::uint16_t>(1u << (ch - 1));
  }
  return bits;
}

// The outputs of the EL2809 come back on the inputs of the EL1809 through the simulated wiring.
bool show_digital_loopback(Slave& outputs, Slave& inputs) {
  fmt::print("\n-- digital loopback: EL2809 outputs are wired to EL1809 inputs\n");
  bool all = true;
  for (const std::uint16_t pattern : {0x0001, 0x0003, 0x00F0, 0x0F00, 0xF000, 0xA5A5, 0xFFFF}) {
    const auto sent = std::chrono::steady_clock::now();
    if (auto r = outputs.command("set_channels", {{"mask", Value(std::uint64_t{pattern})}}); !r) {
      fmt::print("  set_channels failed: {}\n", r.error().describe());
      return false;
    }
    std::optional<std::uint16_t> seen;
    const bool followed = wait_for(
        [&] {
          seen = read_inputs(inputs);
          return seen && *seen == pattern;
        },
        1000ms);
    const auto took =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - sent);
    fmt::print("  outputs {}  ->  inputs {}  {}\n", bits_text(pattern),
               seen ? bits_text(*seen) : std::string("(no valid cycle)"),
               followed ? fmt::format("followed in {:.1f} ms", took.count()) : "DID NOT FOLLOW");
    all = all && followed;
  }
  (void)outputs.command("set_channels", {{"mask", Value(std::uint64_t{0})}});
  return all;
}

bool show_temperatures(Slave& rtd) {
  fmt::print("\n-- EL3202 RTD terminal\n");
  bool ok = true;
  for (int ch = 1; ch <= 2; ++ch) {
    const auto name = fmt::format("channel_{}.temperature", ch);
    auto v = rtd.read_input(name);
    if (v) {
      fmt::print("  {} = {} °C\n", name, ecat::master::to_string(*v));
    } else {
      fmt::print("  {}: {}\n", name, v.error().describe());
      ok = false;
    }
  }
  return ok;
}

std::string drive_state(Slave& drive) {
  const auto info = drive.info();
  const Value* state = info.device_state.find("state");
  if (state == nullptr) return "?";
  if (const auto* text = std::get_if<std::string>(state)) return *text;
  return ecat::master::to_string(*state);
}

// A fresh value, waiting up to 200 ms for one: on a loaded machine the cycle thread can be off the
// processor long enough for the inputs to go stale for a moment, which says nothing about the
// drive.
std::optional<std::int64_t> read_int(Slave& slave, const char* signal) {
  const auto until = std::chrono::steady_clock::now() + 200ms;
  for (;;) {
    auto v = slave.read_input(signal);
    if (v) return ecat::master::as_int64(*v);
    if (v.error().code() != ecat::Errc::stale || std::chrono::steady_clock::now() >= until) {
      return std::nullopt;
    }
    std::this_thread::sleep_for(2ms);
  }
}

// CiA 402: select cyclic synchronous velocity, walk the device state machine to
// operation_enabled, command a velocity and watch the position follow.
bool show_drive(Slave& drive) {
  fmt::print("\n-- CiA 402 servo drive (cyclic synchronous velocity)\n");
  fmt::print("  state {}\n", drive_state(drive));
  if (auto r = drive.command("set_mode", {{"mode", Value(std::string("csv"))}}); !r) {
    fmt::print("  set_mode csv failed: {}\n", r.error().describe());
    return false;
  }
  struct Step {
    const char* command;
    const char* reaches;
  };
  for (const Step step :
       {Step{"fault_reset", nullptr}, Step{"shutdown", "ready_to_switch_on"},
        Step{"switch_on", "switched_on"}, Step{"enable_operation", "operation_enabled"}}) {
    if (auto r = drive.command(step.command); !r) {
      fmt::print("  {} failed: {}\n", step.command, r.error().describe());
      return false;
    }
    if (step.reaches == nullptr) continue;
    const bool reached = wait_for([&] { return drive_state(drive) == step.reaches; }, 2000ms);
    fmt::print("  {:<17} -> {}\n", step.command, drive_state(drive));
    if (!reached) return false;
  }
  constexpr std::int64_t kVelocity = 100'000;  // counts/s
  if (auto r = drive.write_output("target_velocity", Value(kVelocity)); !r) {
    fmt::print("  target_velocity: {}\n", r.error().describe());
    return false;
  }
  fmt::print("  target_velocity = {} counts/s\n", kVelocity);
  const auto first = read_int(drive, "position_actual");
  std::optional<std::int64_t> last;
  for (int i = 0; i < 5 && !ecat::tool::interrupted(); ++i) {
    ecat::tool::sleep_unless_interrupted(200ms);
    last = read_int(drive, "position_actual");
    const auto velocity = read_int(drive, "velocity_actual");
    fmt::print("  t+{:.1f} s  position_actual {:>9}  velocity_actual {:>7}\n", 0.2 * (i + 1),
               last ? fmt::to_string(*last) : "?", velocity ? fmt::to_string(*velocity) : "?");
  }
  (void)drive.write_output("target_velocity", Value(std::int64_t{0}));
  (void)drive.command("shutdown");
  const bool moved = first && last && *last > *first;
  if (!moved) fmt::print("  the drive did not move\n");
  return moved;
}

int run_demo(const Options& options) {
  ecat::tool::catch_interrupts();
  auto ring = ecat::sim::parse_ring(ecat::tool::kDefaultRing, "built-in default ring");
  if (!ring) {
    fmt::print(stderr, "ecat: {}\n", ring.error().describe());
    return 1;
  }
  auto config =
      ecat::master::parse_master_config(ecat::tool::kDefaultRing, "built-in default ring");
  if (!config) {
    fmt::print(stderr, "ecat: {}\n", config.error().describe());
    return 1;
  }
  auto server = ecat::sim::make_server(*ring);
  if (!server) {
    fmt::print(stderr, "ecat: {}\n", server.error().describe());
    return 1;
  }
  // The simulator answers each frame inside the master's send (the in-process function link, as
  // `ecat run` against a simulated ring does): whatever the machine's load, every frame gets its
  // reply at once, so what the demo shows about the ring is true. A simulator on a thread of its
  // own could be starved past the frame timeout and make frames look lost.
  auto link = (*server)->function_link("sim:built-in");
  fmt::print("ecat demo: a simulated ring of {} slaves in this process (examples/default.yaml)\n",
             ring->slaves.size());
  Master master(std::move(*config));
  master.on_state_change([](MasterState from, MasterState to) {
    fmt::print("master: {} -> {}\n", to_string(from), to_string(to));
    std::fflush(stdout);
  });
  if (auto started = master.start(std::move(link)); !started) {
    fmt::print(stderr, "ecat: {}\n", started.error().describe());
    return 1;
  }
  const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::duration<double>(options.timeout_s));
  if (auto op = master.await_operational(timeout); !op) {
    const int code = ecat::tool::report_failure(master, op.error());
    (void)master.stop();
    return code;
  }
  const auto began = std::chrono::steady_clock::now();
  fmt::print("\n");
  ecat::tool::print_slaves(master, false);
  ecat::tool::print_domains(master);
  if (auto locked = master.await_dc_locked(timeout); locked) {
    ecat::tool::print_dc(master);
  } else if (locked.error().code() != ecat::Errc::unsupported) {
    fmt::print("distributed clocks: {}\n", locked.error().describe());
  }

  bool ok = true;
  auto outputs = master.slave("outputs");
  auto inputs = master.slave("inputs");
  auto rtd = master.slave("rtd");
  auto drive = master.slave("drive");
  if (!outputs || !inputs || !rtd || !drive) {
    fmt::print(stderr, "ecat: the default ring lacks one of outputs/inputs/rtd/drive\n");
    ok = false;
  } else {
    ok = show_digital_loopback(**outputs, **inputs) && ok;
    ok = show_temperatures(**rtd) && ok;
    ok = show_drive(**drive) && ok;
  }
  const auto rest = std::chrono::duration_cast<std::chrono::nanoseconds>(
                        std::chrono::duration<double>(options.duration_s)) -
                    (std::chrono::steady_clock::now() - began);
  if (rest > 0ns) ecat::tool::sleep_unless_interrupted(rest);

  fmt::print("\n");
  ecat::tool::print_domains(master);
  ecat::tool::print_dc(master);
  if (auto* bus = master.bus()) {
    const auto stats = bus->stats();
    fmt::print("bus: {} frames sent ({} cyclic), {} lost, {} cycle deadlines missed\n",
               stats.frames_sent, stats.realtime_frames_sent, stats.frames_lost,
               stats.cycle_deadlines_missed);
  }
  if (master.state() != MasterState::operational) {
    fmt::print("master left operational: {}\n", to_string(master.state()));
    ok = false;
  }
  (void)master.stop();
  fmt::print("stopped: every slave back in INIT{}\n", ok ? "" : " (a step above failed)");
  return ok ? 0 : 1;
}

ecat::tool::Command setup_demo(CLI::App& parent) {
  auto* app = parent.add_subcommand(
      "demo", "Run the master against the built-in simulated ring (no hardware, no root)");
  auto options = std::make_shared<Options>();
  app->add_option("--duration", options->duration_s,
                  "Seconds to keep the ring in OP (at least as long as the walkthrough)")
      ->check(ecat::tool::run_seconds());
  app->add_option("--timeout", options->timeout_s, "Seconds to wait for OP")
      ->check(ecat::tool::timeout_seconds());
  return {app, [options] { return run_demo(*options); }};
}

const bool registered_demo = ecat::tool::register_command(&setup_demo);

}  // namespace
