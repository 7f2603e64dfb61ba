// ecat run: runs a master session. With a ring file that has a `simulator:` section and no
// --backend, the master runs against that simulated ring in this process (no hardware, no root).
//
//   ecat run examples/default.yaml --duration 3
//   ecat run my-line.yaml --backend raw:eth0
//   ecat run my-line.yaml --chase                (writes outputs: a lit bit walks over them)
//
// Backends are written raw:IFACE, udp:HOST:PORT or sim:RING.yaml. Ctrl-C (or the end of
// --duration) takes every slave back to INIT before the command exits.
//
// Exit codes: 0 the session reached its target and ran; 1 it did not (the error is printed);
// 2 bad arguments or files.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <ecat/bus/bus.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/backend.hpp>
#include <ecat/sim/ring.hpp>

#include "command.hpp"
#include "interrupt.hpp"
#include "session_view.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::master::Master;
using ecat::master::MasterConfig;
using ecat::master::MasterState;
using ecat::tool::print_domains;
using ecat::tool::print_slaves;
using ecat::tool::report_failure;
using ecat::tool::status_json;
using nlohmann::json;

struct Options {
  std::string ring;
  std::string link;
  double duration_s = 2.0;
  double timeout_s = 20.0;
  bool json = false;
  bool chase = false;  // outputs are written only when asked (--chase)
  bool events = false;
  std::string pcap;  // --pcap FILE
};

using ecat::tool::prepare;

// Walks a lit bit over every boolean output the session has, so the run shows process data
// moving (on the default ring the EL2809 outputs are wired to the EL1809 inputs).
struct Chase {
  std::vector<std::pair<ecat::master::Slave*, std::string>> outputs;
  std::size_t step = 0;

  void collect(Master& master) {
    for (const auto& s : master.slaves()) {
      auto slave = master.slave(s.name);
      if (!slave) continue;
      for (const auto& sig : (*slave)->signals()) {
        if (sig.direction == ecat::master::PdoDirection::output &&
            sig.type == ecat::master::SignalType::boolean) {
          outputs.emplace_back(*slave, sig.name);
        }
      }
    }
  }
  void advance() {
    if (outputs.empty()) return;
    for (std::size_t i = 0; i < outputs.size(); ++i) {
      (void)outputs[i].first->write_output(outputs[i].second,
                                           ecat::master::Value(i == step % outputs.size()));
    }
    ++step;
  }
};

int run_session(const Options& options) {
  ecat::tool::catch_interrupts();
  auto setup = prepare(options.ring, options.link, false, options.pcap);
  if (!setup) return 2;
  Master master(setup->config);
  if (options.events) {
    // The event stream, live: one line per event (--json: one JSON object per line).
    const auto started_at = std::chrono::steady_clock::now().time_since_epoch();
    master.subscribe_events(
        [json = options.json, started_at](const ecat::master::Event& e, std::uint64_t missed) {
          if (json) {
            if (missed > 0) {
              // Ordered: "event" leads, as in every line event_json writes.
              const nlohmann::ordered_json line{{"event", "events.missed"}, {"count", missed}};
              fmt::print("{}\n", line.dump());
            }
            fmt::print("{}\n", ecat::master::event_json(e));
          } else {
            if (missed > 0) fmt::print("({} events missed)\n", missed);
            const double t = static_cast<double>(e.time_ns - started_at.count()) / 1e9;
            fmt::print("{:9.3f}  {}\n", t, ecat::master::describe(e));
          }
          std::fflush(stdout);
        });
  } else if (!options.json) {
    master.on_state_change([](MasterState from, MasterState to) {
      fmt::print("master: {} -> {}\n", to_string(from), to_string(to));
      std::fflush(stdout);
    });
  }
  const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::duration<double>(options.timeout_s));
  if (auto started = master.start(std::move(setup->link)); !started) {
    fmt::print(stderr, "ecat: {}\n", started.error().describe());
    return 1;
  }
  if (auto running = master.await_running(timeout); !running) {
    return report_failure(master, running.error());
  }
  if (!options.json) {
    fmt::print("\nsession on {}: {}\n", setup->link_name, to_string(master.state()));
    print_slaves(master, true);
    print_domains(master);
    ecat::tool::print_dc(master);
  }
  Chase chase;
  if (options.chase) chase.collect(master);
  const auto end =
      std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::nanoseconds>(
                                             std::chrono::duration<double>(options.duration_s));
  while (std::chrono::steady_clock::now() < end && !ecat::tool::interrupted()) {
    chase.advance();
    ecat::tool::sleep_unless_interrupted(100ms);
  }
  if (options.json) {
    // With --events the output is JSON Lines throughout: the status is one line too.
    // Names come from ring files and EEPROMs: a byte that is not UTF-8 prints as U+FFFD rather than
    // making dump() throw.
    fmt::print("{}\n", status_json(master).dump(options.events ? -1 : 2, ' ', false,
                                                json::error_handler_t::replace));
  } else {
    fmt::print("\nafter {:.1f} s:\n", options.duration_s);
    print_domains(master);
    ecat::tool::print_dc(master);
    for (const auto& s : master.slaves()) {
      auto slave = master.slave(s.name);
      if (!slave) continue;
      std::string line;
      for (const auto& sig : (*slave)->signals()) {
        if (sig.direction != ecat::master::PdoDirection::input) continue;
        auto v = (*slave)->read_input(sig.name);
        if (!v) {
          line += fmt::format(" {}: {}", sig.name, v.error().message());
          break;
        }
        if (line.size() > 90) {
          line += " ...";
          break;
        }
        line += fmt::format(" {}={}", sig.name, ecat::master::to_string(*v));
      }
      if (!line.empty()) fmt::print("  {} inputs:{}\n", s.name, line);
    }
    if (auto* bus = master.bus()) {
      auto stats = bus->stats();
      fmt::print("bus: {} frames sent ({} cyclic), {} lost, {} cycle deadlines missed\n",
                 stats.frames_sent, stats.realtime_frames_sent, stats.frames_lost,
                 stats.cycle_deadlines_missed);
    }
  }
  const bool operational =
      master.state() == MasterState::operational || master.state() == MasterState::preop_ready;
  (void)master.stop();
  // After stop: the file then holds the way back to INIT too, and the bus's counters are final.
  const auto counted = master.counters();  // the session's final counts (it has stopped)
  const bool captured = !setup->capture || setup->capture->finish(&counted);
  if (options.events) (void)master.flush_events();
  if (!options.json) fmt::print("stopped: every slave back in INIT\n");
  return operational && captured ? 0 : 1;
}

void add_common(CLI::App* app, Options& o) {
  app->add_option("RING,--ring", o.ring,
                  "Ring file: the master's sections, and with a simulator section the simulated "
                  "ring to run against");
  app->add_option("--backend,--link", o.link,
                  "What the master talks to: raw:IFACE, udp:HOST:PORT or sim:RING.yaml");
  app->add_option("--timeout", o.timeout_s, "Seconds to wait for the session to get running")
      ->check(ecat::tool::timeout_seconds());
  app->add_flag("--json", o.json, "Print JSON");
  app->add_option("--pcap", o.pcap,
                  "Write every frame sent and received to this pcapng file (times, direction)");
}

ecat::tool::Command setup_run(CLI::App& parent) {
  auto* app = parent.add_subcommand("run", "Run a master session (default: on a simulated ring)");
  auto options = std::make_shared<Options>();
  add_common(app, *options);
  app->add_option("--duration", options->duration_s, "Seconds to run once operational")
      ->check(ecat::tool::run_seconds());
  app->add_flag("--chase,!--no-chase", options->chase,
                "Walk a lit bit over every boolean output (writes outputs: off by default)");
  app->add_flag("--events", options->events,
                "Print the master's event stream live (with --json: one JSON object per line)");
  return {app, [options] { return run_session(*options); }};
}

const bool registered_run = ecat::tool::register_command(&setup_run);

}  // namespace
