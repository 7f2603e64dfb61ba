// ecat sim: serve a simulated ring, and talk to a running one.
//
//   ecat sim --ring FILE (--udp ADDR:PORT | --interface IFACE [--redundant-interface IFACE2])
//            [--control PATH] [--summary]
//   ecat sim status [--json]
//   ecat sim fault inject KIND ARGS... [--next N] [--after-ms MS] [--after MILESTONE]
//   ecat sim fault inject --json '{"kind":"disconnect","slave":"outputs","next":30}'
//   ecat sim fault clear | list [--json] | kinds
//   ecat sim set SLAVE.SIGNAL VALUE | get SLAVE.SIGNAL | release SLAVE.SIGNAL
//   ecat sim plug GROUP | unplug GROUP   (hot-connect groups)
//   ecat sim profiles
//   ecat sim profile CAPTURE | verify CAPTURE   (tools/ecat/cmd_sim_verify.cpp)
//
// The client commands find the running simulator's control socket on their own when only one
// runs (or take --control PATH). Exit codes: 0 done, 1 the simulator refused the request, 2 bad
// usage or no simulator to talk to.
#include <charconv>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <pthread.h>

#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

#include "command.hpp"
#include "sim_verify_commands.hpp"

namespace ecat::tool {
namespace {

using nlohmann::json;
using sim::Fault;
using sim::Milestone;

struct Options {
  // Serving.
  std::string ring;
  std::string udp;
  std::string interface;
  // The ring's far end (the last slave's port 1), cabled to a redundant master's second port.
  std::string redundant_interface;
  // Raw serving: latency options of the RawLink (docs/BENCHMARKS.md: a sleeping receive is most
  // of the simulator's share of a veth round trip).
  bool spin = false;
  int busy_poll_us = 0;
  std::string control;
  bool summary = false;
  // Clients.
  std::string client_control;
  bool json = false;
  std::vector<std::string> words;
  std::string fault_json;
  std::uint64_t next = 0;
  double after_ms = -1;
  std::string after_milestone;
  std::string target;
  std::string value;
};

int fail(int code, const std::string& message) {
  std::fprintf(stderr, "ecat sim: %s\n", message.c_str());
  return code;
}

// ---- Serving ------------------------------------------------------------------------------------

Result<std::unique_ptr<link::RawLink>> open_raw(const Options& o, const std::string& interface,
                                                bool responder) {
  link::RawLinkOptions options;
  options.interface = interface;
  options.responder = responder;
  options.spin = o.spin;
  options.busy_poll_us = o.busy_poll_us;
  // Only EtherCAT frames reach the simulator: a shared network costs it nothing.
  options.kernel_filter = true;
  return link::RawLink::open(options);
}

// --udp ADDR:PORT, :PORT or PORT. Without an address the simulator listens on loopback only;
// another address (0.0.0.0, "*", a host's own address) is the user's choice and is said aloud.
Result<std::unique_ptr<link::Link>> open_served_link(const Options& o) {
  if (!o.udp.empty()) {
    const auto colon = o.udp.rfind(':');
    std::string host = colon == std::string::npos ? std::string() : o.udp.substr(0, colon);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
      host = host.substr(1, host.size() - 2);
    }
    const std::string port_text = colon == std::string::npos ? o.udp : o.udp.substr(colon + 1);
    std::uint16_t port = 0;
    const auto [end, ec] =
        std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
    if (port_text.empty() || ec != std::errc() || end != port_text.data() + port_text.size()) {
      return Error(Errc::invalid_argument,
                   fmt::format("--udp '{}': expected [ADDR:]PORT with PORT a number from 0 to "
                               "65535 (e.g. 127.0.0.1:34980; port 0 lets the system choose)",
                               o.udp));
    }
    if (host == "0.0.0.0" || host == "::") host = "*";
    auto link = link::UdpLink::serve(host, port);
    if (!link) return std::move(link).error();
    const bool loopback =
        host.empty() || host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0;
    if (!loopback) {
      std::fprintf(stderr,
                   "ecat sim: %s is not loopback: any host that reaches this machine can drive "
                   "the simulated ring (one at a time)\n",
                   (*link)->name().c_str());
    }
    return std::unique_ptr<link::Link>(std::move(*link));
  }
  auto link = open_raw(o, o.interface, true);
  if (!link) return std::move(link).error();
  return std::unique_ptr<link::Link>(std::move(*link));
}

// One line per second: the server's counters, or on a redundant ring the two ports' (frames
// in, replies out by either port, and how they left: crossed to the other end or bounced back).
std::string summary_line(const sim::SimStatus& st, const sim::RedundantPortsStats* ports,
                         std::uint64_t previous_frames) {
  std::size_t op = 0;
  std::size_t errors = 0;
  for (const auto& s : st.slaves) {
    op += s.al_state == wire::AlState::op ? 1 : 0;
    errors += s.al_error ? 1 : 0;
  }
  const std::uint64_t frames = ports != nullptr ? ports->frames : st.counters.frames;
  std::string traffic =
      ports != nullptr
          ? fmt::format(
                "frames {} (+{}/s)  replies {} ({} crossed, {} bounced)  lost {}  "
                "delayed {}  duplicated {}  overflowed {}",
                frames, frames - previous_frames, ports->crosses + ports->bounces, ports->crosses,
                ports->bounces, ports->lost, ports->delayed, ports->duplicated, ports->overflowed)
          : fmt::format(
                "frames {} (+{}/s)  replies {}  lost {}  delayed {}  duplicated {}  "
                "malformed {}",
                frames, frames - previous_frames, st.counters.replies, st.counters.lost,
                st.counters.delayed, st.counters.duplicated, st.counters.malformed);
  return fmt::format("{}  OP {}/{}  AL errors {}  faults: {} active, {} queued, {} scheduled",
                     traffic, op, st.slaves.size(), errors, st.faults.active.size(),
                     st.faults.queued.size(), st.faults.scheduled.size());
}

int serve(const Options& o) {
  if (o.ring.empty()) return fail(2, "--ring FILE is required to serve (see ecat sim --help)");
  if (o.udp.empty() == o.interface.empty()) {
    return fail(2, "give exactly one of --udp ADDR:PORT and --interface IFACE");
  }
  if ((o.spin || o.busy_poll_us != 0) && o.interface.empty()) {
    return fail(2, "--spin and --busy-poll apply to raw serving: give --interface IFACE");
  }
  const bool redundant = !o.redundant_interface.empty();
  if (redundant && o.interface.empty()) {
    return fail(2,
                "--redundant-interface serves the ring's second master port on a raw interface: "
                "give the first with --interface IFACE (a redundant ring is not served over UDP)");
  }
  if (redundant && o.redundant_interface == o.interface) {
    return fail(2, fmt::format("--interface and --redundant-interface are both {}: a ring's two "
                               "ends need two interfaces",
                               o.interface));
  }
  auto ring = sim::load_ring(o.ring);
  if (!ring) return fail(2, ring.error().describe());
  auto server = sim::make_server(*ring);
  if (!server) return fail(2, server.error().describe());
  if (ring->redundancy && !redundant) {
    std::fprintf(stderr,
                 "ecat sim: %s: simulator.redundancy applies only to a ring served with "
                 "--redundant-interface; ignored\n",
                 o.ring.c_str());
  }
  std::unique_ptr<sim::RedundantPorts> ports;
  Result<std::unique_ptr<link::Link>> link = std::unique_ptr<link::Link>();
  std::string link_name;
  if (redundant) {
    sim::RedundantPortsOptions options;
    if (ring->redundancy) {
      options.topology = ring->redundancy->topology;
      options.delays = ring->redundancy->delays;
    }
    auto created = sim::RedundantPorts::create(**server, options);
    if (!created) return fail(2, created.error().context(o.ring).describe());
    ports = std::move(*created);
    auto primary = open_raw(o, o.interface, false);
    if (!primary) return fail(2, primary.error().describe());
    auto secondary = open_raw(o, o.redundant_interface, false);
    if (!secondary) return fail(2, secondary.error().describe());
    link_name = fmt::format("{} (primary) and {} (secondary, the last slave's port 1)", o.interface,
                            o.redundant_interface);
    link = std::unique_ptr<link::Link>();
    if (auto r = ports->serve(std::move(*primary), std::move(*secondary)); !r) {
      return fail(2, r.error().describe());
    }
  } else {
    link = open_served_link(o);
    if (!link) return fail(2, link.error().describe());
    link_name = (*link)->name();
  }

  // SIGINT and SIGTERM are taken synchronously by this thread (sigtimedwait); every thread
  // started from here on inherits the blocked mask.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  if (!redundant) {
    if (auto r = (*server)->serve(std::move(*link)); !r) return fail(2, r.error().describe());
  }
  const std::string control_path = o.control.empty() ? sim::default_control_path() : o.control;
  // The control server is stopped before the ports (below), so it may read their counters.
  auto control = sim::ControlServer::start(**server, control_path, ports.get());
  if (!control) {
    if (ports) ports->stop();
    (*server)->stop();
    return fail(2, control.error().describe());
  }
  std::printf("ecat sim: serving %zu slaves from %s on %s; control socket %s\n",
              ring->slaves.size(), o.ring.c_str(), link_name.c_str(), control_path.c_str());
  std::fflush(stdout);

  std::uint64_t previous_frames = 0;
  int received = 0;
  while (received <= 0) {
    timespec one_second{1, 0};
    received = sigtimedwait(&stop_signals, nullptr, &one_second);
    if (received <= 0 && o.summary) {
      const auto status = (*server)->status();
      std::optional<sim::RedundantPortsStats> port_stats;
      if (ports) port_stats = ports->stats();
      std::printf(
          "%s%s\n",
          summary_line(status, port_stats ? &*port_stats : nullptr, previous_frames).c_str(),
          status.faults.ring.empty() ? "" : ("  ring: " + status.faults.ring).c_str());
      std::fflush(stdout);
      previous_frames = port_stats ? port_stats->frames : status.counters.frames;
    }
  }
  (*control)->stop();
  if (ports) ports->stop();
  (*server)->stop();
  auto stats = (*server)->stats();
  if (ports) {
    const auto p = ports->stats();
    stats.frames = p.frames;
    stats.replies = p.crosses + p.bounces;
  }
  std::printf("ecat sim: stopped by %s after %llu frames, %llu replies\n",
              received == SIGINT ? "SIGINT" : "SIGTERM",
              static_cast<unsigned long long>(stats.frames),
              static_cast<unsigned long long>(stats.replies));
  return 0;
}

// ---- Clients ---------------------------------------------------------------------------------

struct Reply {
  int code = 0;  // 0 ok, 1 refused, 2 no simulator
  json body;
  std::string raw;
};

Reply request(const Options& o, const json& message) {
  Reply reply;
  std::string path = o.client_control.empty() ? o.control : o.client_control;
  if (path.empty()) {
    auto found = sim::find_control_socket();
    if (!found) {
      reply.code = fail(2, found.error().message());
      return reply;
    }
    path = *found;
  }
  auto answer = sim::control_call(path, message.dump());
  if (!answer) {
    reply.code = fail(2, answer.error().message());
    return reply;
  }
  reply.raw = *answer;
  reply.body = json::parse(*answer, nullptr, false);
  if (reply.body.is_discarded() || !reply.body.is_object()) {
    reply.code = fail(2, "the simulator's reply is not a JSON object: " + *answer);
    return reply;
  }
  if (reply.body.value("ok", false) != true) {
    reply.code = fail(1, reply.body.value("error", std::string("request refused")));
  }
  return reply;
}

std::string hex(std::uint64_t v, int width) {
  return fmt::format("0x{:0{}X}", v, width);
}

void print_faults(const json& f) {
  const auto list = [](const json& items) {
    std::string out;
    for (const auto& item : items) {
      if (!out.empty()) out += "; ";
      if (item.is_string()) {
        out += item.get<std::string>();
        continue;
      }
      out += item.value("description", std::string());
      if (item.contains("due_in_ns")) {
        out += fmt::format(" (due in {:.1f} ms)", item["due_in_ns"].get<double>() / 1e6);
      } else if (item.contains("waiting_on")) {
        out += fmt::format(" (waiting for {}, {} to go)", item.value("waiting_on", ""),
                           item.value("remaining", 0));
      } else if (item.contains("remaining")) {
        const int remaining = item.value("remaining", 0);
        out += fmt::format(" ({} exchange{} to go)", remaining, remaining == 1 ? "" : "s");
      }
    }
    return out.empty() ? std::string("none") : out;
  };
  std::printf("faults active:    %s\n", list(f.value("active", json::array())).c_str());
  std::printf("faults queued:    %s\n", list(f.value("queued", json::array())).c_str());
  std::printf("faults scheduled: %s\n", list(f.value("scheduled", json::array())).c_str());
}

int status(const Options& o) {
  auto reply = request(o, {{"op", "status"}});
  if (reply.code != 0) return reply.code;
  if (o.json) {
    std::printf("%s\n", reply.raw.c_str());
    return 0;
  }
  const json& b = reply.body;
  const std::string link = b.value("link", std::string());
  std::printf("simulator serving %s\n", link.empty() ? "nothing" : link.c_str());
  std::printf("%4s  %-16s %-10s %-10s %-10s %-7s %-6s %s\n", "#", "name", "profile", "product",
              "station", "state", "error", "links");
  for (const auto& s : b.value("slaves", json::array())) {
    std::string links;
    for (const auto& up : s.value("links", json::array()))
      links += up.get<bool>() ? '+' : '-';
    const bool error = s.value("al_error", false);
    std::printf("%4d  %-16s %-10s %-10s %-10s %-7s %-6s %s\n", s.value("index", 0),
                s.value("name", std::string()).c_str(), s.value("profile", std::string()).c_str(),
                hex(s.value("product_code", 0u), 8).c_str(), hex(s.value("station", 0u), 4).c_str(),
                s.value("al_state", std::string()).c_str(),
                error ? hex(s.value("al_status_code", 0u), 4).c_str() : "", links.c_str());
  }
  const json& c = b["counters"];
  std::printf(
      "frames %llu  replies %llu  lost %llu  malformed %llu  delayed %llu  duplicated %llu\n",
      c.value("frames", 0ull), c.value("replies", 0ull), c.value("lost", 0ull),
      c.value("malformed", 0ull), c.value("delayed", 0ull), c.value("duplicated", 0ull));
  if (const auto it = b.find("redundant"); it != b.end() && it->is_object()) {
    const json& p = *it;
    std::printf(
        "master ports:     frames %llu  replies %llu crossed, %llu bounced  lost %llu  "
        "delayed %llu  duplicated %llu  overflowed %llu  send errors %llu\n",
        p.value("frames", 0ull), p.value("crosses", 0ull), p.value("bounces", 0ull),
        p.value("lost", 0ull), p.value("delayed", 0ull), p.value("duplicated", 0ull),
        p.value("overflowed", 0ull), p.value("send_errors", 0ull));
  }
  print_faults(b.value("faults", json::object()));
  if (const auto ring = b["faults"].value("ring", std::string()); !ring.empty()) {
    std::printf("redundant ring:   %s\n", ring.c_str());
  }
  return 0;
}

Result<Milestone> parse_milestone(const std::string& text) {
  std::vector<std::string> parts;
  std::size_t start = 0;
  while (true) {
    const auto colon = text.find(':', start);
    parts.push_back(text.substr(start, colon - start));
    if (colon == std::string::npos) break;
    start = colon + 1;
  }
  const auto bad = [&] {
    return Error(Errc::invalid_argument,
                 fmt::format("--after '{}': expected healthy_exchanges:N, healthy_polls:SLAVE:N "
                             "or mailbox_step:SLAVE:STEP:N",
                             text));
  };
  const auto count = [&](const std::string& n) -> std::optional<std::uint64_t> {
    try {
      std::size_t used = 0;
      const auto value = std::stoull(n, &used);
      if (used != n.size() || value == 0) return std::nullopt;
      return value;
    } catch (const std::exception&) {
      return std::nullopt;
    }
  };
  if (parts[0] == "healthy_exchanges" && parts.size() == 2) {
    if (auto n = count(parts[1])) return sim::fault::healthy_exchanges(*n);
  } else if (parts[0] == "healthy_polls" && parts.size() == 3) {
    if (auto n = count(parts[2])) return sim::fault::healthy_polls(parts[1], *n);
  } else if (parts[0] == "mailbox_step" && parts.size() == 4) {
    for (auto stage : {sim::MailboxStage::upload_init, sim::MailboxStage::upload_segment,
                       sim::MailboxStage::download_init, sim::MailboxStage::download_segment}) {
      if (sim::to_string(stage) != parts[2]) continue;
      if (auto n = count(parts[3])) return sim::fault::mailbox_step(parts[1], stage, *n);
    }
  }
  return bad();
}

int fault_inject(const Options& o) {
  Result<Fault> fault = Error(Errc::invalid_argument, "");
  if (!o.fault_json.empty()) {
    if (!o.words.empty()) return fail(2, "give either KIND ARGS... or --json, not both");
    fault = sim::parse_fault_json(o.fault_json);
  } else {
    fault = sim::parse_fault_words(o.words);
  }
  if (!fault) return fail(2, fault.error().message());
  Fault f = std::move(*fault);
  if (o.next != 0) f = sim::fault::next(std::move(f), o.next);
  if (o.after_ms >= 0) {
    f = sim::fault::after(
        std::move(f), std::chrono::nanoseconds(static_cast<std::int64_t>(o.after_ms * 1e6 + 0.5)));
  }
  if (!o.after_milestone.empty()) {
    auto m = parse_milestone(o.after_milestone);
    if (!m) return fail(2, m.error().message());
    f = sim::fault::after_milestone(std::move(f), std::move(*m));
  }
  if (auto valid = sim::validate(f); !valid) return fail(2, valid.error().message());
  auto reply = request(o, {{"op", "fault.inject"}, {"fault", json::parse(sim::to_json(f))}});
  if (reply.code != 0) return reply.code;
  std::printf("injected: %s\n", reply.body.value("description", std::string()).c_str());
  return 0;
}

int fault_clear(const Options& o) {
  auto reply = request(o, {{"op", "fault.clear"}});
  if (reply.code == 0) std::printf("faults cleared\n");
  return reply.code;
}

int fault_list(const Options& o) {
  auto reply = request(o, {{"op", "fault.list"}});
  if (reply.code != 0) return reply.code;
  if (o.json) {
    std::printf("%s\n", reply.raw.c_str());
  } else {
    print_faults(reply.body.value("faults", json::object()));
  }
  return 0;
}

int fault_kinds() {
  for (const auto& k : sim::fault_kinds()) {
    const std::string usage = fmt::format("{} {}", sim::to_string(k.kind), k.arguments);
    std::printf("  %-52s %s\n", usage.c_str(), std::string(k.summary).c_str());
  }
  std::printf(
      "options: --next N (exchange and reply faults), --after-ms MS, --after "
      "healthy_exchanges:N | healthy_polls:SLAVE:N | mailbox_step:SLAVE:STEP:N\n");
  return 0;
}

std::optional<std::pair<std::string, std::string>> split_target(const std::string& target) {
  const auto dot = target.find('.');
  if (dot == std::string::npos || dot == 0 || dot + 1 == target.size()) return std::nullopt;
  return std::make_pair(target.substr(0, dot), target.substr(dot + 1));
}

int signal_request(const Options& o, const std::string& op) {
  auto target = split_target(o.target);
  if (!target) {
    return fail(2, fmt::format("'{}' is not SLAVE.SIGNAL (e.g. inputs.channel_1)", o.target));
  }
  json message{{"op", op}, {"slave", target->first}, {"signal", target->second}};
  if (op == "signal.set") {
    if (o.value == "true" || o.value == "on") {
      message["value"] = 1;
    } else if (o.value == "false" || o.value == "off") {
      message["value"] = 0;
    } else {
      try {
        std::size_t used = 0;
        const double v = std::stod(o.value, &used);
        if (used != o.value.size() || !std::isfinite(v)) throw std::invalid_argument(o.value);
        message["value"] = v;
      } catch (const std::exception&) {
        return fail(2, fmt::format("'{}' is not a finite number (or true/false)", o.value));
      }
    }
  }
  auto reply = request(o, message);
  if (reply.code != 0) return reply.code;
  if (op == "signal.get") {
    std::printf("%s\n", reply.body["value"].dump().c_str());
  }
  return 0;
}

int hot_connect(const Options& o, bool plugged) {
  auto reply = request(o, json{{"op", "hotconnect"}, {"group", o.target}, {"plugged", plugged}});
  return reply.code;
}

int profiles() {
  for (const auto& p : sim::device_profiles()) {
    std::printf("  %-10s %s\n", p.name.c_str(), p.description.c_str());
  }
  return 0;
}

Command setup(CLI::App& parent) {
  auto* app = parent.add_subcommand(
      "sim",
      "Serve a simulated EtherCAT ring (--ring FILE --udp ADDR:PORT | --interface IFACE "
      "[--redundant-interface IFACE2]), "
      "or control a running one");
  auto o = std::make_shared<Options>();
  app->add_option("--ring", o->ring, "Ring file (YAML, see docs/RING-FILE.md)");
  app->add_option("--udp", o->udp,
                  "Serve EtherCAT over UDP on [ADDR:]PORT (default address: loopback only; "
                  "0.0.0.0 or * for every interface; port 0: any)");
  app->add_option("--interface", o->interface,
                  "Serve raw EtherCAT on network interface IFACE (needs CAP_NET_RAW)");
  app->add_option("--redundant-interface", o->redundant_interface,
                  "Cable redundancy: serve the ring's far end (the last slave's port 1) on IFACE2, "
                  "for a master on raw:IFACE,IFACE2 (with --interface; see simulator.redundancy "
                  "and the ring faults)");
  app->add_flag("--spin", o->spin,
                "Raw serving: wait for frames without sleeping (lowest latency; costs a CPU core)");
  app->add_option("--busy-poll", o->busy_poll_us,
                  "Raw serving: SO_BUSY_POLL for this many microseconds before sleeping")
      ->check(CLI::Range(0, 1000000));
  app->add_option("--control", o->control,
                  "Control socket path (default $XDG_RUNTIME_DIR/ecat-sim-PID.sock)");
  app->add_flag("--summary", o->summary, "Print a one-line summary every second");
  app->require_subcommand(0, 1);

  const auto add_control = [o](CLI::App* sub) {
    sub->add_option("--control", o->client_control,
                    "Control socket of the simulator (found automatically when one runs)");
  };

  auto* status_cmd = app->add_subcommand("status", "Slaves, AL states, counters and faults");
  add_control(status_cmd);
  status_cmd->add_flag("--json", o->json, "Print the JSON reply");

  auto* fault_cmd = app->add_subcommand("fault", "Inject, list or clear faults");
  fault_cmd->require_subcommand(1);
  auto* inject_cmd = fault_cmd->add_subcommand("inject", "Inject a fault: KIND ARGS...");
  add_control(inject_cmd);
  inject_cmd->add_option("words", o->words, "KIND and its arguments (see `ecat sim fault kinds`)");
  inject_cmd->add_option("--json", o->fault_json, "The fault as JSON (scripts, nesting)");
  inject_cmd->add_option("--next", o->next, "Only for the next N exchanges")
      ->check(number_in(1, 1e9, "exchanges"));
  inject_cmd->add_option("--after-ms", o->after_ms, "Activate after MS milliseconds")
      ->check(number_in(0, 86'400'000, "ms"));
  inject_cmd->add_option("--after", o->after_milestone,
                         "Activate after a milestone: healthy_exchanges:N, "
                         "healthy_polls:SLAVE:N, mailbox_step:SLAVE:STEP:N");
  auto* clear_cmd = fault_cmd->add_subcommand("clear", "Remove every fault");
  add_control(clear_cmd);
  auto* list_cmd = fault_cmd->add_subcommand("list", "Active, queued and scheduled faults");
  add_control(list_cmd);
  list_cmd->add_flag("--json", o->json, "Print the JSON reply");
  auto* kinds_cmd = fault_cmd->add_subcommand("kinds", "The fault kinds and their arguments");

  auto* set_cmd = app->add_subcommand("set", "Force an input signal: SLAVE.SIGNAL VALUE");
  add_control(set_cmd);
  set_cmd->add_option("SLAVE.SIGNAL", o->target)->required();
  set_cmd->add_option("VALUE", o->value)->required();
  auto* get_cmd = app->add_subcommand("get", "Read a signal: SLAVE.SIGNAL");
  add_control(get_cmd);
  get_cmd->add_option("SLAVE.SIGNAL", o->target)->required();
  auto* release_cmd = app->add_subcommand("release", "Stop forcing an input: SLAVE.SIGNAL");
  add_control(release_cmd);
  release_cmd->add_option("SLAVE.SIGNAL", o->target)->required();
  auto* plug_cmd = app->add_subcommand("plug", "Plug a hot-connect group in: GROUP");
  add_control(plug_cmd);
  plug_cmd->add_option("GROUP", o->target)->required();
  auto* unplug_cmd = app->add_subcommand("unplug", "Unplug a hot-connect group: GROUP");
  add_control(unplug_cmd);
  unplug_cmd->add_option("GROUP", o->target)->required();
  auto* profiles_cmd = app->add_subcommand("profiles", "List the device profiles");
  // Profiles rebuilt from captures, and the simulator proven against them.
  const Command profile_cmd = add_sim_profile_command(*app, "profile");
  const Command verify_cmd = add_sim_verify_command(*app, "verify");

  return {app, [=] {
            if (status_cmd->parsed()) return status(*o);
            if (inject_cmd->parsed()) return fault_inject(*o);
            if (clear_cmd->parsed()) return fault_clear(*o);
            if (list_cmd->parsed()) return fault_list(*o);
            if (kinds_cmd->parsed()) return fault_kinds();
            if (set_cmd->parsed()) return signal_request(*o, "signal.set");
            if (get_cmd->parsed()) return signal_request(*o, "signal.get");
            if (release_cmd->parsed()) return signal_request(*o, "signal.clear");
            if (plug_cmd->parsed()) return hot_connect(*o, true);
            if (unplug_cmd->parsed()) return hot_connect(*o, false);
            if (profiles_cmd->parsed()) return profiles();
            if (profile_cmd.app->parsed()) return profile_cmd.run();
            if (verify_cmd.app->parsed()) return verify_cmd.run();
            return serve(*o);
          }};
}

const bool registered = register_command(&setup);

}  // namespace
}  // namespace ecat::tool
