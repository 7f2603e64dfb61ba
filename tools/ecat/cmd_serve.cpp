// ecat serve RING: runs a master as a long-lived service with a control endpoint, so that other
// processes (`ecat ... --attach`, scripts, dashboards) can look at it while it runs.
//
//   ecat serve examples/default.yaml                      endpoint "default" (the file's name)
//   ecat serve line.yaml --control line1 --writes         endpoint allowing writes
//   ecat slaves --attach line1
//   ecat serve line.yaml --mailbox-gateway                the ETG.8200 gateway, 127.0.0.1:34980
//   ecat upload --gateway 127.0.0.1:34980 --station 0x1003 0x6041 0 --type uint16
//
// Service behaviour (systemd Type=simple): logs go to stderr; SIGTERM or SIGINT stops the session
// cleanly (every slave back to INIT) and exits 0; a session that does not get running within
// --timeout, or that ends by itself (the link lost for good), exits 1; bad arguments or files 2.
// The session is brought to the file's targets: outputs move only as the application (or a
// client allowed to write) sets them.
#include <algorithm>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include <fmt/format.h>

#include <ecat/app/open_master.hpp>
#include <ecat/link/recording_link.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/mailbox_gateway.hpp>
#include <ecat/master/master.hpp>

#include "command.hpp"
#include "interrupt.hpp"
#include "session_view.hpp"

namespace {

using namespace std::chrono_literals;

struct Options {
  std::string ring;
  std::string backend;
  std::string control;
  std::string mode = "0600";
  bool writes = false;
  double timeout_s = 60.0;
  double duration_s = 0.0;
  std::string pcap;                 // --pcap FILE: every frame
  double flight_recorder_s = 10.0;  // --flight-recorder SECONDS: the recent past in memory, 0 off
  std::string fault_dumps;          // --fault-dumps DIR: the recorder written there on a fault
  // --mailbox-gateway [ADDR:PORT]: the ETG.8200 gateway (the option given without a value:
  // 127.0.0.1:34980).
  std::string gateway;
  CLI::Option* gateway_option = nullptr;
};

// A state worth a dump: the session left its running states by itself (recovering, blocked) or
// ended.
bool fault_state(ecat::master::MasterState s) {
  using ecat::master::MasterState;
  return s == MasterState::recovering || s == MasterState::activation_blocked ||
         s == MasterState::idle;
}

// The flight recorder's window written to DIR/ecat-fault-<UTC time>-<what>.pcapng.
void dump_on_fault(const ecat::link::FrameRecorder& recorder, const std::string& dir,
                   const std::string& what, const std::string& link_name) {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  std::tm utc{};
  ::gmtime_r(&t, &utc);
  const std::string path = fmt::format("{}/ecat-fault-{:04}{:02}{:02}-{:02}{:02}{:02}-{}.pcapng",
                                       dir, utc.tm_year + 1900, utc.tm_mon + 1, utc.tm_mday,
                                       utc.tm_hour, utc.tm_min, utc.tm_sec, what);
  const auto frames = recorder.snapshot();
  if (auto written = ecat::tool::write_recorded_frames(path, frames, link_name); !written) {
    fmt::print(stderr, "ecat serve: {}: writing the flight recorder failed: {}\n", what,
               written.error().describe());
    return;
  }
  fmt::print(stderr, "ecat serve: {}: the last {} frames written to {}\n", what, frames.size(),
             path);
}

// The flight recorder's memory: about what 10 s of a busy 4 kHz ring take, bounded.
std::size_t flight_recorder_budget(double seconds) {
  const double bytes = seconds * 3.2e6;
  return static_cast<std::size_t>(std::clamp(bytes, 1.0 * (1 << 20), 256.0 * (1 << 20)));
}

int serve(const Options& o) {
  ecat::tool::catch_interrupts();
  // The endpoint: --control, else the file's `master: control:`, else the file's stem.
  std::uint32_t mode = 0600;
  if (o.mode.empty() || o.mode.size() > 4 ||
      o.mode.find_first_not_of("01234567") != std::string::npos ||
      std::stoul(o.mode, nullptr, 8) > 0777) {
    fmt::print(stderr, "ecat: --mode '{}' is not an octal permission such as 0660\n", o.mode);
    return 2;
  }
  mode = static_cast<std::uint32_t>(std::stoul(o.mode, nullptr, 8));
  // The gateway: --mailbox-gateway (its address, or loopback:34980), else the file's
  // `master: mailbox_gateway:`. Enabling it lets configuration tools write to the slaves (SDO
  // downloads) as they ask: the user asked for that by enabling it.
  std::optional<ecat::master::MailboxGatewayConfig> gateway;
  if (o.gateway_option != nullptr && o.gateway_option->count() > 0) {
    gateway.emplace();
    gateway->enabled = true;
    if (!o.gateway.empty()) {
      if (auto parsed = ecat::master::parse_mailbox_gateway_address(o.gateway, *gateway); !parsed) {
        fmt::print(stderr, "ecat: --mailbox-gateway: {}\n", parsed.error().message());
        return 2;
      }
    }
  }
  ecat::OpenMasterOptions options;
  options.backend = o.backend;
  const std::string stem = std::filesystem::path(o.ring).stem().string();
  options.configure = [&](ecat::master::MasterConfig& config) {
    if (!o.control.empty()) {
      config.control.name = o.control;
    } else if (config.control.name.empty()) {
      config.control.name = stem;
    }
    if (!o.control.empty() || config.control.mode == 0600) config.control.mode = mode;
    if (o.writes) config.control.allow_writes = true;
    if (gateway) {
      // The address from the command line; the file's timeout, queue and workers stay.
      config.mailbox_gateway.enabled = true;
      config.mailbox_gateway.address = gateway->address;
      config.mailbox_gateway.port = gateway->port;
    }
  };
  // Recording: --pcap streams every frame to a file; the flight recorder keeps the last seconds
  // for `ecat capture --attach` (the endpoint's capture.frames). One link may carry both.
  std::unique_ptr<ecat::tool::LiveCapture> capture;
  if (!o.pcap.empty()) {
    capture = ecat::tool::LiveCapture::open(o.pcap, o.backend.empty() ? o.ring : o.backend);
    if (!capture) return 2;
  }
  std::shared_ptr<ecat::link::FrameRecorder> flight;
  if (o.flight_recorder_s > 0) {
    ecat::link::FrameRecorderOptions fr;
    fr.window = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::duration<double>(o.flight_recorder_s));
    fr.byte_budget = flight_recorder_budget(o.flight_recorder_s);
    flight = std::make_shared<ecat::link::FrameRecorder>(fr);
  }
  const auto configure = std::move(options.configure);
  options.configure = [&, configure](ecat::master::MasterConfig& config) {
    configure(config);
    config.control.flight_recorder = flight;
  };
  options.wrap_link = [&](std::unique_ptr<ecat::link::Link> link) {
    if (capture) link = capture->wrap(std::move(link));
    if (flight) link = std::make_unique<ecat::link::RecordingLink>(std::move(link), flight);
    return link;
  };
  auto opened = ecat::open_master(o.ring, std::move(options));
  if (!opened) {
    fmt::print(stderr, "ecat: {}\n", opened.error().describe());
    return opened.error().code() == ecat::Errc::busy ? 1 : 2;
  }
  auto& master = **opened;
  const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::duration<double>(o.timeout_s));
  if (auto running = master.await_running(timeout); !running) {
    const int code = ecat::tool::report_failure(master, running.error());
    (void)master.stop();
    return code;
  }
  const auto path = ecat::master::find_control_endpoint(o.control.empty() ? stem : o.control);
  fmt::print(stderr, "ecat serve: {} is {}; control endpoint {}\n", o.ring,
             to_string(master.state()), path ? *path : std::string("(none)"));
  if (const auto g = master.mailbox_gateway()) {
    fmt::print(stderr, "ecat serve: mailbox gateway (ETG.8200) on udp {}:{}\n", g->address,
               g->port);
  }
  const auto end = o.duration_s > 0 ? std::chrono::steady_clock::now() +
                                          std::chrono::duration_cast<std::chrono::nanoseconds>(
                                              std::chrono::duration<double>(o.duration_s))
                                    : std::chrono::steady_clock::time_point::max();
  int code = 0;
  // A fault raised (a slave's or the session's) or the session leaving its running states asks
  // for a dump; the loop writes it (never the event dispatcher's thread).
  std::mutex fault_mutex;
  std::optional<std::string> fault;
  if (flight && !o.fault_dumps.empty()) {
    master.subscribe_events([&](const ecat::master::Event& e, std::uint64_t) {
      const bool raised = e.kind == ecat::master::EventKind::fault_raised;
      const bool left = e.kind == ecat::master::EventKind::master_state &&
                        fault_state(static_cast<ecat::master::MasterState>(e.to));
      if (!raised && !left) return;
      std::lock_guard lock(fault_mutex);
      if (!fault) fault = raised ? "fault" : std::string(e.to_name());
    });
  }
  std::optional<std::chrono::steady_clock::time_point> last_dump;
  while (!ecat::tool::interrupted() && std::chrono::steady_clock::now() < end) {
    const auto state = master.state();
    std::optional<std::string> reason;
    {
      std::lock_guard lock(fault_mutex);
      reason.swap(fault);
    }
    // At most one dump per 10 s: a flapping session does not fill the disk. The recorder keeps
    // recording meanwhile, so the dump holds the lead-up and the first moments after.
    if (reason && (!last_dump || std::chrono::steady_clock::now() - *last_dump > 10s)) {
      dump_on_fault(*flight, o.fault_dumps, *reason, o.backend.empty() ? o.ring : o.backend);
      last_dump = std::chrono::steady_clock::now();
    }
    if (state == ecat::master::MasterState::idle) {
      // The session ended by itself (link lost for good, a fatal DC policy).
      const auto failure = master.last_failure();
      fmt::print(stderr, "ecat serve: the session ended: {}\n",
                 failure ? failure->kind + ": " + failure->error.describe() : "stopped");
      code = 1;
      break;
    }
    ecat::tool::sleep_unless_interrupted(100ms);
  }
  (void)master.stop();
  fmt::print(stderr, "ecat serve: stopped; every slave back in INIT\n");
  if (capture && !capture->finish()) code = 1;
  return code;
}

ecat::tool::Command setup(CLI::App& parent) {
  auto o = std::make_shared<Options>();
  auto* app = parent.add_subcommand(
      "serve", "Run a master as a service with a control endpoint (see `--attach`)");
  app->add_option("RING", o->ring, "Ring file (its master sections and backend)")->required();
  app->add_option("--backend,--link", o->backend,
                  "Replaces the file's backend: raw:IFACE, udp:HOST:PORT or sim:RING.yaml");
  app->add_option("--control", o->control,
                  "Endpoint name or socket path (default: the file's master: control:, else the "
                  "file's name)");
  app->add_option("--mode", o->mode, "Socket permissions, octal (default 0600: you only)");
  app->add_flag("--writes", o->writes,
                "Let clients write: outputs, states, SDO downloads, registers");
  app->add_option("--timeout", o->timeout_s, "Seconds the session may take to get running")
      ->check(ecat::tool::timeout_seconds());
  app->add_option("--duration", o->duration_s, "Stop after this many seconds (default: never)")
      ->check(ecat::tool::run_seconds());
  app->add_option("--pcap", o->pcap,
                  "Write every frame sent and received to this pcapng file (times, direction)");
  app->add_option("--flight-recorder", o->flight_recorder_s,
                  "Keep the frames of the last SECONDS in memory for `ecat capture --attach` "
                  "(default 10, 0: off)")
      ->check(ecat::tool::number_in(0, 3600, "seconds"));
  app->add_option("--fault-dumps", o->fault_dumps,
                  "When the session goes recovering, blocked or idle by itself, write the flight "
                  "recorder to a pcapng file in this folder (at most one per 10 s)")
      ->check(CLI::ExistingDirectory);
  o->gateway_option =
      app->add_option("--mailbox-gateway", o->gateway,
                      "Open the ETG.8200 mailbox gateway (UDP) on ADDR:PORT, ADDR or PORT "
                      "(default 127.0.0.1:34980): configuration tools reach the slaves' mailboxes, "
                      "SDO downloads included")
          ->expected(0, 1);
  return {app, [o] { return serve(*o); }};
}

const bool registered = ecat::tool::register_command(&setup);

}  // namespace
