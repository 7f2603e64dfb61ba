// The engineer's instrument: commands that look at a ring and its slaves (and, when asked, change
// them), each working two ways:
//   attached    --attach [NAME|PATH]  talks to a running master's control endpoint
//                                     (`ecat serve`, or any application with `master: control:`)
//   standalone  --ring FILE / --backend SPEC  runs a short session of its own, every slave held in
//                                     PREOP: nothing moves (domains are laid out but do not
//                                     cycle; attach to a running master for live process data)
// Both ways send the same requests (master/control_endpoint.hpp): standalone, to the master in
// this process, attached, through the socket; so both print the same.
//
//   ecat slaves --attach line1 -v
//   ecat upload --ring examples/default.yaml --name drive 0x6041 0 --type uint16
//   ecat download --attach --name drive 0x6060 0 8 --type int8
//   ecat upload --gateway 127.0.0.1:34980 --station 0x1003 0x6041 0 --type uint16
//   ecat reg_read --backend raw:eth0 -p 1 0x0130 2
//   ecat events --attach line1 --json
//
// Exit codes: 0 done; 1 the operation failed (the error says why); 2 bad arguments.
#include <cctype>
#include <cinttypes>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include <ecat/ipc/line_server.hpp>
#include <ecat/link/mailbox_gateway_client.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/master.hpp>
#include <ecat/version.hpp>

#include "command.hpp"
#include "interrupt.hpp"
#include "session_view.hpp"

namespace {

using namespace std::chrono_literals;
using Json = nlohmann::ordered_json;
using ecat::Errc;
using ecat::Error;
using ecat::Result;

// ---- Progress on a terminal --------------------------------------------------------------------

// A line on stderr that says a long operation is still going ("foe_write 'fw.efw': 4.2 s"),
// redrawn every 200 ms while it runs, when stderr is a terminal; silent in pipes and files. The
// endpoint answers a request as a whole, so what is shown is the time taken, and for loops the
// step (`step(i, n)`).
class Progress {
 public:
  explicit Progress(std::string what)
      : what_(std::move(what)), active_(::isatty(STDERR_FILENO) == 1) {
    if (!active_) return;
    started_ = std::chrono::steady_clock::now();
    thread_ = std::thread([this] {
      std::unique_lock lock(mutex_);
      while (!done_) {
        changed_.wait_for(lock, 200ms);
        if (done_) break;
        draw_locked();
      }
    });
  }
  ~Progress() {
    if (!active_) return;
    {
      std::lock_guard lock(mutex_);
      done_ = true;
    }
    changed_.notify_all();
    thread_.join();
    std::fprintf(stderr, "\r\033[K");  // the line goes: the result is printed instead
  }
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  void step(std::size_t done, std::size_t total) {
    if (!active_) return;
    std::lock_guard lock(mutex_);
    step_ = fmt::format(" {}/{}", done, total);
  }

 private:
  void draw_locked() {
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
    std::fprintf(stderr, "\r\033[K%s%s: %.1f s", what_.c_str(), step_.c_str(), seconds);
    std::fflush(stderr);
  }

  std::string what_;
  bool active_ = false;
  std::chrono::steady_clock::time_point started_{};
  std::mutex mutex_;
  std::condition_variable changed_;
  bool done_ = false;
  std::string step_;
  std::thread thread_;
};

// ---- Where the requests go --------------------------------------------------------------------

struct Target {
  std::optional<std::string> attach;  // set (maybe empty: the one running) when attached
  std::string ring;
  std::string backend;
  double timeout_s = 20.0;
  bool json = false;
  std::string pcap;  // --pcap FILE (standalone only)
};

class Connection {
 public:
  // Prints why not (as JSON with --json) and returns nullptr.
  // Why not goes to `exit_code`: 2 for bad arguments or files, 1 for a session that failed.
  static std::unique_ptr<Connection> open(const Target& target, int* exit_code = nullptr) {
    int ignored = 0;
    int& code = exit_code != nullptr ? *exit_code : ignored;
    code = 1;
    auto c = std::unique_ptr<Connection>(new Connection());
    if (target.attach) {
      if (!target.pcap.empty()) {
        code = 2;
        return c->fail(
            Error(Errc::invalid_argument,
                  "--pcap records a session of this command's own (--ring/--backend); "
                  "a running master's recent frames: ecat capture --attach NAME -o FILE"),
            target.json);
      }
      auto path = ecat::master::find_control_endpoint(*target.attach);
      if (!path) return c->fail(path.error(), target.json);
      c->path_ = *path;
      return c;
    }
    if (target.ring.empty() && target.backend.empty()) {
      code = 2;
      return c->fail(Error(Errc::invalid_argument,
                           "give --attach [NAME] (a running master), or --ring FILE / --backend "
                           "SPEC (a session of this command's own)"),
                     target.json);
    }
    // A ring file's slaves keep their names and configuration, held in PREOP; a bare backend
    // gives the dynamic session (every slave found, named by position, in PREOP). (SAFEOP for the
    // process-data commands would let inputs move, but a session whose every slave targets
    // SAFEOP has no drawn way out of awaiting_preop: the seed's diagram goes from there to
    // preop_ready, operational or activation_blocked only.)
    auto setup = ecat::tool::prepare(target.ring, target.backend, target.ring.empty(), target.pcap);
    if (!setup) {
      code = 2;
      return nullptr;
    }
    for (auto& slave : setup->config.slaves)
      slave.target = ecat::master::TargetState::preop;
    c->capture_ = std::move(setup->capture);
    c->master_ = std::make_unique<ecat::master::Master>(setup->config);
    if (auto started = c->master_->start(std::move(setup->link)); !started) {
      return c->fail(started.error(), target.json);
    }
    const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::duration<double>(target.timeout_s));
    if (auto running = c->master_->await_running(timeout); !running) {
      if (target.json) return c->fail(running.error(), true);
      (void)ecat::tool::report_failure(*c->master_, running.error());
      return nullptr;
    }
    return c;
  }

  ~Connection() {
    if (master_) (void)master_->stop();
    if (capture_) (void)capture_->finish();
  }

  // The reply's fields (without "ok"), or the error it carries.
  Result<Json> call(const Json& request) {
    std::string reply;
    if (master_) {
      // The user asked for this very command: standalone, writes are theirs to make.
      reply = ecat::master::handle_control_request(*master_, request.dump(),
                                                   ecat::master::ControlAccess{true});
    } else {
      auto answered = ecat::ipc::call(path_, request.dump(), 60s, "master");
      if (!answered) return answered.error();
      reply = std::move(*answered);
    }
    Json parsed = Json::parse(reply, nullptr, false);
    if (parsed.is_discarded() || !parsed.is_object()) {
      return Error(Errc::malformed, fmt::format("the master's reply is not JSON: {}", reply));
    }
    if (!parsed.value("ok", false)) {
      const std::string code = parsed.value("code", "internal");
      Errc errc = Errc::internal;
      for (int i = 0; i <= static_cast<int>(Errc::internal); ++i) {
        if (ecat::master::control_error_code(static_cast<Errc>(i)) == code) {
          errc = static_cast<Errc>(i);
        }
      }
      return Error(errc, parsed.value("error", std::string("failed")));
    }
    parsed.erase("ok");
    return parsed;
  }

  const std::string& path() const { return path_; }

 private:
  Connection() = default;
  std::unique_ptr<Connection> fail(const Error& error, bool json) {
    print_error(error, json);
    return nullptr;
  }

 public:
  static void print_error(const Error& error, bool json) {
    if (json) {
      const Json out{{"ok", false},
                     {"error", error.describe()},
                     {"code", ecat::master::control_error_code(error.code())}};
      fmt::print("{}\n", out.dump(-1, ' ', false, Json::error_handler_t::replace));
    } else {
      fmt::print(stderr, "ecat: {}\n", error.describe());
    }
  }

 private:
  std::string path_;
  std::unique_ptr<ecat::tool::LiveCapture> capture_;  // declared first: outlives master_
  std::unique_ptr<ecat::master::Master> master_;
};

void add_target(CLI::App* app, Target& t) {
  app->add_option("--attach", t.attach,
                  "Talk to a running master: its control endpoint NAME or socket PATH (empty: "
                  "the one running)")
      ->expected(0, 1);
  app->add_option("--ring", t.ring, "Run a session of this command's own from this ring file");
  app->add_option("--backend,--link", t.backend,
                  "... or on this link: raw:IFACE, udp:HOST:PORT or sim:RING.yaml");
  app->add_option("--timeout", t.timeout_s, "Seconds the own session may take to get running")
      ->check(ecat::tool::timeout_seconds());
  app->add_flag("--json", t.json, "Print JSON (errors too)");
  app->add_option("--pcap", t.pcap, "With --ring/--backend: write every frame to this pcapng file");
}

int finish(const Result<Json>& result, bool json, const std::function<void(const Json&)>& text) {
  if (!result) {
    Connection::print_error(result.error(), json);
    return 1;
  }
  if (json) {
    Json out{{"ok", true}};
    for (const auto& [k, v] : result->items())
      out[k] = v;
    fmt::print("{}\n", out.dump(2, ' ', false, Json::error_handler_t::replace));
  } else {
    text(*result);
  }
  return 0;
}

// ---- Slave selection --------------------------------------------------------------------------

struct SlaveChoice {
  std::optional<unsigned> position;
  std::string name;
  std::optional<std::string> alias;  // the configured station alias (register 0x0012)
  bool given() const { return position || !name.empty() || alias; }
};

void add_slave_choice(CLI::App* app, SlaveChoice& s, bool required) {
  auto* p = app->add_option("-p,--position", s.position, "The slave at this ring position");
  auto* n = app->add_option("--name", s.name, "The slave with this name");
  auto* a = app->add_option("-a,--alias", s.alias,
                            "The slave with this configured station alias (0x0012)");
  p->excludes(n);
  a->excludes(p);
  a->excludes(n);
  if (required) {
    app->callback([p, n, a] {
      if (p->count() == 0 && n->count() == 0 && a->count() == 0) {
        throw CLI::RequiredError("-p POSITION, -a ALIAS or --name NAME");
      }
    });
  }
}

// The name the endpoint knows the chosen slave by.
Result<std::string> slave_name(Connection& c, const SlaveChoice& s) {
  if (!s.name.empty()) return s.name;
  if (!s.position && !s.alias) {
    return Error(Errc::invalid_argument, "give -p POSITION, -a ALIAS or --name NAME");
  }
  auto slaves = c.call(Json{{"op", "slaves"}});
  if (!slaves) return slaves.error();
  std::optional<unsigned long> alias;
  if (s.alias) {
    const std::string& t = *s.alias;
    const bool hex = t.starts_with("0x") || t.starts_with("0X");
    const std::string digits = hex ? t.substr(2) : t;
    if (digits.empty() || digits.size() > 5 ||
        digits.find_first_not_of(hex ? "0123456789abcdefABCDEF" : "0123456789") !=
            std::string::npos ||
        std::stoul(digits, nullptr, hex ? 16 : 10) > 0xFFFF) {
      return Error(Errc::invalid_argument,
                   fmt::format("alias '{}' is not a number from 0 to 0xffff", t));
    }
    alias = std::stoul(digits, nullptr, hex ? 16 : 10);
  }
  for (const auto& j : (*slaves)["slaves"]) {
    if (s.position && j.value("position", -1) == static_cast<int>(*s.position)) {
      return j.value("name", "");
    }
    if (alias) {
      // The alias register as the ESC holds it now (loaded from SII word 4 at power-up).
      auto r = c.call(Json{
          {"op", "reg.read"}, {"slave", j.value("name", "")}, {"address", 0x0012}, {"length", 2}});
      if (!r) continue;
      const auto hex = r->value("data", "");
      if (hex.size() == 4 &&
          std::stoul(hex.substr(2, 2) + hex.substr(0, 2), nullptr, 16) == *alias) {
        return j.value("name", "");
      }
    }
  }
  if (alias) return Error(Errc::not_found, fmt::format("no slave with alias 0x{:04x}", *alias));
  return Error(Errc::not_found, fmt::format("no slave at position {}", *s.position));
}

// ---- Typed values -----------------------------------------------------------------------------

constexpr const char* kTypes =
    "uint8, uint16, uint32, uint64, int8, int16, int32, int64, float, double, string, octets";

std::optional<std::size_t> type_size(const std::string& type) {
  if (type == "uint8" || type == "int8") return 1;
  if (type == "uint16" || type == "int16") return 2;
  if (type == "uint32" || type == "int32" || type == "float") return 4;
  if (type == "uint64" || type == "int64" || type == "double") return 8;
  return std::nullopt;
}

std::vector<std::uint8_t> from_hex(const std::string& hex) {
  std::vector<std::uint8_t> out;
  for (std::size_t i = 0; i + 1 < hex.size(); i += 2)
    out.push_back(static_cast<std::uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
  return out;
}

std::string to_hex(const std::vector<std::uint8_t>& bytes, const char* separator = "") {
  std::string out;
  for (std::size_t i = 0; i < bytes.size(); ++i)
    out += fmt::format("{}{:02x}", i == 0 ? "" : separator, bytes[i]);
  return out;
}

// Little endian, exactly the type's size; octets as hex; a string as its bytes.
Result<std::vector<std::uint8_t>> encode_typed(const std::string& type, const std::string& text) {
  if (type == "octets") {
    std::string digits;
    for (char ch : text) {
      if (ch != ' ' && ch != ':') digits += ch;
    }
    if (digits.empty() || digits.size() % 2 != 0 ||
        digits.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) {
      return Error(Errc::invalid_argument,
                   fmt::format("value '{}' is not hex octets (\"0a1b\" or \"0a:1b\")", text));
    }
    return from_hex(digits);
  }
  if (type == "string") return std::vector<std::uint8_t>(text.begin(), text.end());
  const auto size = type_size(type);
  if (!size) {
    return Error(Errc::invalid_argument,
                 fmt::format("--type '{}' is not a type ({})", type, kTypes));
  }
  std::uint64_t raw = 0;
  const bool is_float = type == "float" || type == "double";
  if (is_float) {
    char* end = nullptr;
    const double d = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || !std::isfinite(d)) {
      return Error(Errc::invalid_argument, fmt::format("value '{}' is not a number", text));
    }
    if (type == "float") {
      const float f = static_cast<float>(d);
      std::uint32_t bits = 0;
      std::memcpy(&bits, &f, 4);
      raw = bits;
    } else {
      std::memcpy(&raw, &d, 8);
    }
  } else {
    const bool is_signed = type[0] == 'i';
    const unsigned bits = static_cast<unsigned>(*size * 8);
    errno = 0;
    char* end = nullptr;
    const int base = text.starts_with("0x") || text.starts_with("0X") ? 16 : 10;
    if (is_signed) {
      const long long v = std::strtoll(text.c_str(), &end, base);
      const long long min =
          bits == 64 ? std::numeric_limits<long long>::min() : -(1LL << (bits - 1));
      const long long max =
          bits == 64 ? std::numeric_limits<long long>::max() : (1LL << (bits - 1)) - 1;
      if (text.empty() || *end != '\0' || errno != 0 || v < min || v > max) {
        return Error(Errc::invalid_argument,
                     fmt::format("value '{}' is not an {} ({} .. {})", text, type, min, max));
      }
      raw = static_cast<std::uint64_t>(v);
    } else {
      const unsigned long long v = std::strtoull(text.c_str(), &end, base);
      const unsigned long long max =
          bits == 64 ? std::numeric_limits<unsigned long long>::max() : (1ULL << bits) - 1;
      if (text.empty() || text[0] == '-' || *end != '\0' || errno != 0 || v > max) {
        return Error(Errc::invalid_argument,
                     fmt::format("value '{}' is not a {} (0 .. {})", text, type, max));
      }
      raw = v;
    }
  }
  std::vector<std::uint8_t> out(*size);
  for (std::size_t i = 0; i < *size; ++i)
    out[i] = static_cast<std::uint8_t>(raw >> (8 * i));
  return out;
}

// The bytes as the type, or why they are not one.
Result<Json> decode_typed(const std::string& type, const std::vector<std::uint8_t>& bytes) {
  if (type.empty() || type == "octets") return Json(to_hex(bytes, " "));
  if (type == "string") {
    std::string text(bytes.begin(), bytes.end());
    if (auto nul = text.find('\0'); nul != std::string::npos) text.resize(nul);
    return Json(text);
  }
  const auto size = type_size(type);
  if (!size) {
    return Error(Errc::invalid_argument,
                 fmt::format("--type '{}' is not a type ({})", type, kTypes));
  }
  if (bytes.size() != *size) {
    return Error(Errc::invalid_argument,
                 fmt::format("the value has {} bytes, a {} has {} (raw: {})", bytes.size(), type,
                             *size, to_hex(bytes, " ")));
  }
  std::uint64_t raw = 0;
  for (std::size_t i = 0; i < *size; ++i)
    raw |= std::uint64_t{bytes[i]} << (8 * i);
  if (type == "float") {
    float f = 0;
    const auto bits = static_cast<std::uint32_t>(raw);
    std::memcpy(&f, &bits, 4);
    return Json(static_cast<double>(f));
  }
  if (type == "double") {
    double d = 0;
    std::memcpy(&d, &raw, 8);
    return Json(d);
  }
  if (type[0] == 'i') {
    const unsigned bits = static_cast<unsigned>(*size * 8);
    std::int64_t v = static_cast<std::int64_t>(raw);
    if (bits < 64 && (raw >> (bits - 1)) != 0) v -= static_cast<std::int64_t>(1ULL << bits);
    return Json(v);
  }
  return Json(raw);
}

std::string show(const Json& value) {
  return value.is_string() ? value.get<std::string>() : value.dump();
}

// ---- Commands ---------------------------------------------------------------------------------

struct Common {
  Target target;
  SlaveChoice slave;
  bool verbose = false;
};

int cmd_slaves(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto r = c->call(Json{{"op", "slaves"}, {"verbose", o.verbose}});
  SlaveChoice chosen = o.slave;
  if (r && chosen.alias) {
    auto name = slave_name(*c, chosen);
    if (!name) return finish(name.error(), o.target.json, {});
    chosen = SlaveChoice{std::nullopt, *name, std::nullopt};
  }
  if (r && (chosen.position || !chosen.name.empty())) {
    Json kept = Json::array();
    for (const auto& j : (*r)["slaves"]) {
      if ((chosen.position && j.value("position", -1) == static_cast<int>(*chosen.position)) ||
          (!chosen.name.empty() && j.value("name", "") == chosen.name)) {
        kept.push_back(j);
      }
    }
    if (kept.empty())
      r = Error(Errc::not_found, "no such slave");
    else
      (*r)["slaves"] = kept;
  }
  return finish(r, o.target.json, [&](const Json& j) {
    fmt::print("{:>3}  {:<7} {:<14} {:<9} {:<36} {}\n", "pos", "station", "name", "state",
               "identity (vendor:product rev)", "device");
    for (const auto& s : j["slaves"]) {
      std::string identity = "-";
      if (s["identity"].is_object()) {
        identity = fmt::format("{:08x}:{:08x} rev {:08x}", s["identity"].value("vendor_id", 0u),
                               s["identity"].value("product_code", 0u),
                               s["identity"].value("revision", 0u));
      }
      fmt::print("{:>3}  0x{:04x}  {:<14} {:<9} {:<36} {}\n", s.value("position", 0),
                 s.value("station", 0), s.value("name", ""), s.value("state", ""), identity,
                 s.value("device", ""));
      if (s.contains("fault")) fmt::print("       fault: {}\n", show(s["fault"]));
      if (s.contains("configuration_error")) {
        fmt::print("       ! {}\n", show(s["configuration_error"]));
      }
      if (!o.verbose) continue;
      const auto& esc = s["esc"];
      fmt::print(
          "       ESC type 0x{:02x} rev {} build {}, {} FMMUs, {} SMs, {} KiB RAM, DC {}\n",
          esc.value("type", 0), esc.value("revision", 0), esc.value("build", 0),
          esc.value("fmmus", 0), esc.value("sync_managers", 0), esc.value("ram_kib", 0),
          esc.value("dc", false) ? (esc.value("dc_64bit", false) ? "64-bit" : "32-bit") : "no");
      std::string ports;
      for (std::size_t p = 0; p < s["ports"].size(); ++p) {
        const auto& port = s["ports"][p];
        ports += fmt::format(" {}:{}", p,
                             port.value("communication", false) ? "up"
                             : port.value("link", false)        ? "link"
                                                                : "-");
      }
      fmt::print("       ports{}; mailbox {}{}\n", ports,
                 s["mailbox"].value("present", false) ? "yes" : "no",
                 s["mailbox"].value("coe", false) ? " (CoE)" : "");
      for (const auto& a : s["attachments"]) {
        fmt::print("       SM{} {} {} bytes -> domain {} at 0x{:08x}\n", a.value("sync_manager", 0),
                   a.value("direction", ""), a.value("size", 0), a.value("domain", ""),
                   a.value("logical", 0u));
      }
      for (const auto& sig : s["signals"]) {
        fmt::print("       {} {} {} ({} bits)\n", sig.value("direction", ""), sig.value("name", ""),
                   sig.value("type", ""), sig.value("bit_length", 0));
      }
    }
  });
}

int cmd_master(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto status = c->call(Json{{"op", "status"}});
  if (status) {
    auto counters = c->call(Json{{"op", "counters"}});
    if (!counters) {
      status = counters.error();
    } else {
      (*status)["counters"] = *counters;
    }
  }
  return finish(status, o.target.json, [&](const Json& j) {
    fmt::print("state: {} (desired {})\nlink: {}\nslaves: {}\n", j.value("state", ""),
               j.value("desired_target", ""), j.value("link", ""), j.value("slave_count", 0));
    for (const auto& d : j["domains"]) {
      fmt::print("domain {}: {} every {} us, {} bytes, {} cycles, {} missed\n", d.value("id", ""),
                 d.value("state", ""), d.value("period_ns", 0) / 1000, d.value("image_size", 0),
                 d.value("cycles", 0), d.value("misses", 0));
    }
    const auto& k = j["counters"];
    fmt::print(
        "frames: {} sent, {} received, {} lost; {} transaction time-outs, {} retries; {} cycle "
        "deadlines missed\n",
        k.value("frames_sent", 0), k.value("frames_received", 0), k.value("frames_lost", 0),
        k.value("transaction_timeouts", 0), k.value("retries", 0),
        k.value("cycle_deadlines_missed", 0));
    if (j.contains("redundancy") && j["redundancy"].is_object()) {
      const auto& r = j["redundancy"];
      const auto port = [](const Json& p) {
        return fmt::format("{} {}", p.value("name", ""),
                           p.value("healthy", false) ? "healthy" : "failing");
      };
      std::string where;
      if (r["break"].is_object()) where = " " + r["break"].value("text", "");
      fmt::print("redundancy: {}, ring {}{} (primary {}, secondary {}; {} breaks, {} heals)\n",
                 r.value("topology", ""), r.value("ring", ""), where, port(r["primary"]),
                 port(r["secondary"]), r.value("ring_breaks", 0), r.value("ring_heals", 0));
    }
    for (const auto& f : j["activation_failures"])
      fmt::print("activation failure: {}: {}\n", f.value("slave", ""), f.value("error", ""));
    for (const auto& f : j["runtime_faults"])
      fmt::print("runtime fault: {}\n", show(f));
    if (j["last_failure"].is_object()) {
      fmt::print("last failure ({}): {}\n", j["last_failure"].value("kind", ""),
                 j["last_failure"].value("error", ""));
    }
  });
}

int cmd_domains(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto r = c->call(Json{{"op", "domains"}, {"data", o.verbose}});
  return finish(r, o.target.json, [&](const Json& j) {
    for (const auto& d : j["domains"]) {
      fmt::print(
          "domain {}: {} every {} us, {} bytes at 0x{:08x}, expected wkc {}, {} cycles, "
          "{} missed, {}\n",
          d.value("id", ""), d.value("state", ""), d.value("period_ns", 0) / 1000,
          d.value("image_size", 0), d.value("logical_base", 0u), d.value("expected_wkc", 0),
          d.value("cycles", 0), d.value("misses", 0),
          d.value("healthy", false) ? "healthy" : "unhealthy");
      if (!o.verbose || !d.contains("data")) continue;
      const auto bytes = from_hex(d.value("data", ""));
      for (std::size_t i = 0; i < bytes.size(); i += 16) {
        std::vector<std::uint8_t> row(
            bytes.begin() + static_cast<std::ptrdiff_t>(i),
            bytes.begin() + static_cast<std::ptrdiff_t>(std::min(bytes.size(), i + 16)));
        fmt::print("  {:04x}  {}\n", i, to_hex(row, " "));
      }
    }
  });
}

struct DataOptions {
  Common common;
  std::string domain;
};

int cmd_data(const DataOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  std::string id = o.domain;
  if (id.empty()) {
    auto list = c->call(Json{{"op", "domains"}});
    if (!list) return finish(list, o.common.target.json, {});
    if ((*list)["domains"].size() != 1) {
      return finish(Error(Errc::invalid_argument,
                          fmt::format("the master has {} domains: name one with --domain",
                                      (*list)["domains"].size())),
                    o.common.target.json, {});
    }
    id = (*list)["domains"][0].value("id", "");
  }
  auto r = c->call(Json{{"op", "domain.data"}, {"domain", id}});
  return finish(r, o.common.target.json, [](const Json& j) {
    // Raw bytes, for a pipe into xxd, od or a file.
    const auto bytes = from_hex(j.value("data", ""));
    std::fwrite(bytes.data(), 1, bytes.size(), stdout);
  });
}

struct SdoOptions {
  Common common;
  std::string index;
  std::string subindex;
  std::string value;
  std::string type;
  bool complete_access = false;
  // --gateway ADDR:PORT --station 0x1003: through a master's ETG.8200 mailbox gateway instead.
  std::string gateway;
  std::string station;
};

// A number as the command line writes it: decimal or 0x-hex, at most `max`.
std::optional<unsigned long> parse_number(const std::string& text, unsigned long max) {
  const bool hex = text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X');
  const std::string digits = hex ? text.substr(2) : text;
  if (digits.empty() || digits.size() > 8 ||
      digits.find_first_not_of(hex ? "0123456789abcdefABCDEF" : "0123456789") !=
          std::string::npos) {
    return std::nullopt;
  }
  const unsigned long value = std::stoul(digits, nullptr, hex ? 16 : 10);
  if (value > max) return std::nullopt;
  return value;
}

// upload / download through a mailbox gateway (link/mailbox_gateway_client.hpp): the slave by its
// station address, the SDO as a configuration tool would make it. `value`: empty for an upload.
int gateway_sdo(const SdoOptions& o, const std::vector<std::uint8_t>* download) {
  const bool json = o.common.target.json;
  const auto station = parse_number(o.station, 0xFFFF);
  const auto index = parse_number(o.index, 0xFFFF);
  const auto subindex = parse_number(o.subindex, 0xFF);
  if (!station || *station == 0 || !index || !subindex) {
    Connection::print_error(
        Error(Errc::invalid_argument,
              fmt::format("--gateway needs --station (1..0xffff), and INDEX and SUBINDEX numbers "
                          "(station '{}', index '{}', subindex '{}')",
                          o.station, o.index, o.subindex)),
        json);
    return 2;
  }
  if (o.complete_access || o.common.slave.given() || o.common.target.attach ||
      !o.common.target.ring.empty() || !o.common.target.backend.empty()) {
    Connection::print_error(Error(Errc::invalid_argument,
                                  "--gateway takes --station, not --complete-access, -p, -a, "
                                  "--name, --attach, --ring or --backend"),
                            json);
    return 2;
  }
  auto client = ecat::link::MailboxGatewayClient::connect(o.gateway);
  if (!client) {
    Connection::print_error(client.error(), json);
    return 2;
  }
  const auto timeout = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::duration<double>(o.common.target.timeout_s));
  const auto s = static_cast<std::uint16_t>(*station);
  const auto i = static_cast<std::uint16_t>(*index);
  const auto sub = static_cast<std::uint8_t>(*subindex);
  if (download != nullptr) {
    auto done = (*client)->download_sdo(s, i, sub, *download, timeout);
    Result<Json> r = done ? Result<Json>(Json::object()) : Result<Json>(done.error());
    return finish(r, json, [&](const Json&) {
      fmt::print("station {:#06x} {}:{} <- {}\n", s, o.index, o.subindex, o.value);
    });
  }
  auto bytes = (*client)->upload_sdo(s, i, sub, timeout);
  Result<Json> r =
      bytes ? Result<Json>(Json{{"data", to_hex(*bytes)}}) : Result<Json>(bytes.error());
  if (r) {
    auto value = decode_typed(o.type, *bytes);
    if (!value) {
      r = value.error();
    } else {
      (*r)["value"] = *value;
    }
  }
  return finish(r, json, [](const Json& j) { fmt::print("{}\n", show(j["value"])); });
}

// Without --gateway one of -p, -a, --name is needed.
bool need_slave(const SdoOptions& o) {
  if (!o.gateway.empty() || o.common.slave.given()) return false;
  Connection::print_error(Error(Errc::invalid_argument,
                                "give -p POSITION, -a ALIAS or --name NAME (or --gateway with "
                                "--station)"),
                          o.common.target.json);
  return true;
}

int cmd_upload(const SdoOptions& o) {
  if (need_slave(o)) return 2;
  if (!o.gateway.empty()) return gateway_sdo(o, nullptr);
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(Json{{"op", "sdo.upload"},
                        {"slave", *name},
                        {"index", o.index},
                        {"subindex", o.subindex},
                        {"complete_access", o.complete_access}});
  if (r) {
    auto value = decode_typed(o.type, from_hex(r->value("data", "")));
    if (!value) {
      r = value.error();
    } else {
      (*r)["value"] = *value;
    }
  }
  return finish(r, o.common.target.json,
                [](const Json& j) { fmt::print("{}\n", show(j["value"])); });
}

int cmd_download(const SdoOptions& o) {
  const std::string type = o.type.empty() ? "octets" : o.type;
  if (need_slave(o)) return 2;
  auto bytes = encode_typed(type, o.value);
  if (!bytes) {
    Connection::print_error(bytes.error(), o.common.target.json);
    return 2;
  }
  if (!o.gateway.empty()) return gateway_sdo(o, &*bytes);
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(Json{{"op", "sdo.download"},
                        {"slave", *name},
                        {"index", o.index},
                        {"subindex", o.subindex},
                        {"data", to_hex(*bytes)},
                        {"complete_access", o.complete_access}});
  return finish(r, o.common.target.json, [&](const Json&) {
    fmt::print("{} {}:{} <- {}\n", *name, o.index, o.subindex, o.value);
  });
}

struct StateOptions {
  Common common;
  std::string state;
};

int cmd_states(const StateOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  Json request{{"op", "state.request"}, {"state", o.state}};
  if (o.common.slave.given()) {
    auto name = slave_name(*c, o.common.slave);
    if (!name) return finish(name.error(), o.common.target.json, {});
    request["slave"] = *name;
  }
  auto r = c->call(request);
  return finish(r, o.common.target.json,
                [](const Json& j) { fmt::print("now {}\n", j.value("state", "")); });
}

struct RegOptions {
  Common common;
  std::string address;
  std::string length_or_value;
  std::string type;
};

int cmd_reg_read(const RegOptions& o) {
  std::string length = o.length_or_value;
  if (length.empty()) {
    const auto size = type_size(o.type);
    if (!size) {
      Connection::print_error(
          Error(Errc::invalid_argument, "give LENGTH, or a --type with a size (uint16 ...)"),
          o.common.target.json);
      return 2;
    }
    length = std::to_string(*size);
  }
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(
      Json{{"op", "reg.read"}, {"slave", *name}, {"address", o.address}, {"length", length}});
  if (r) {
    auto value = decode_typed(o.type, from_hex(r->value("data", "")));
    if (!value) {
      r = value.error();
    } else {
      (*r)["value"] = *value;
    }
  }
  return finish(r, o.common.target.json,
                [](const Json& j) { fmt::print("{}\n", show(j["value"])); });
}

int cmd_reg_write(const RegOptions& o) {
  auto bytes = encode_typed(o.type.empty() ? "octets" : o.type, o.length_or_value);
  if (!bytes) {
    Connection::print_error(bytes.error(), o.common.target.json);
    return 2;
  }
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(Json{
      {"op", "reg.write"}, {"slave", *name}, {"address", o.address}, {"data", to_hex(*bytes)}});
  return finish(r, o.common.target.json, [&](const Json&) {
    fmt::print("{} {} <- {}\n", *name, o.address, to_hex(*bytes, " "));
  });
}

struct SiiOptions {
  Common common;
  std::string output;
  bool decode = false;
};

int cmd_sii_read(const SiiOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(Json{{"op", "sii.read"}, {"slave", *name}});
  if (r && o.decode) {
    // Decoded as `ecat sii` decodes a file (text or JSON).
    return ecat::tool::print_sii(from_hex(r->value("data", "")),
                                 fmt::format("slave {} (SII as read)", *name),
                                 o.common.target.json);
  }
  if (r && !o.output.empty()) {
    const auto bytes = from_hex(r->value("data", ""));
    std::ofstream out(o.output, std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
    if (!out) r = Error(Errc::io_error, fmt::format("cannot write '{}'", o.output));
  }
  return finish(r, o.common.target.json, [&](const Json& j) {
    if (!o.output.empty()) {
      fmt::print("{} bytes written to {} (decode with `ecat sii {}`)\n", j.value("size", 0),
                 o.output, o.output);
      return;
    }
    const auto bytes = from_hex(j.value("data", ""));
    for (std::size_t i = 0; i < bytes.size(); i += 16) {
      std::vector<std::uint8_t> row(
          bytes.begin() + static_cast<std::ptrdiff_t>(i),
          bytes.begin() + static_cast<std::ptrdiff_t>(std::min(bytes.size(), i + 16)));
      fmt::print("{:04x}  {}\n", i / 2, to_hex(row, " "));
    }
  });
}

struct SdosOptions {
  Common common;
  bool values = false;
};

int cmd_sdos(const SdosOptions& so) {
  const Common& o = so.common;
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.slave);
  if (!name) return finish(name.error(), o.target.json, {});
  auto list = c->call(Json{{"op", "sdo.list"}, {"slave", *name}});
  Result<Json> r = list;
  if (list) {
    Json objects = Json::array();
    Progress progress(fmt::format("sdos {}", *name));
    std::size_t step = 0;
    for (const auto& index : (*list)["objects"]) {
      progress.step(++step, (*list)["objects"].size());
      auto d = c->call(Json{{"op", "sdo.describe"}, {"slave", *name}, {"index", index}});
      Json object = d ? *d : Json{{"index", index}, {"error", d.error().message()}};
      if (d && so.values) {
        // Every subindex's value, as the slave gives it (hex; a refusal says why).
        Json values = Json::array();
        const int last = object.value("max_subindex", 0);
        for (int sub = 0; sub <= last; ++sub) {
          auto v = c->call(
              Json{{"op", "sdo.upload"}, {"slave", *name}, {"index", index}, {"subindex", sub}});
          values.push_back(v ? Json{{"subindex", sub}, {"data", v->value("data", "")}}
                             : Json{{"subindex", sub}, {"error", v.error().message()}});
        }
        object["values"] = std::move(values);
      }
      objects.push_back(std::move(object));
    }
    r = Json{{"slave", *name}, {"objects", objects}};
  }
  return finish(r, o.target.json, [](const Json& j) {
    for (const auto& d : j["objects"]) {
      if (d.contains("error")) {
        fmt::print("{}  ({})\n", show(d["index"]), show(d["error"]));
        continue;
      }
      fmt::print("{}  {:<40} type 0x{:04x}, {} subindices\n", show(d["index"]), d.value("name", ""),
                 d.value("data_type", 0), d.value("max_subindex", 0));
      if (!d.contains("values")) continue;
      for (const auto& v : d["values"]) {
        fmt::print("    :{:02x} {}\n", v.value("subindex", 0),
                   v.contains("error") ? "(" + show(v["error"]) + ")"
                                       : to_hex(from_hex(v.value("data", "")), " "));
      }
    }
  });
}

struct EventsOptions {
  Common common;
  double duration_s = 0;
};

int cmd_events(const EventsOptions& o) {
  ecat::tool::catch_interrupts();
  if (!o.common.target.attach) {
    Connection::print_error(
        Error(Errc::invalid_argument, "events follows a running master: give --attach [NAME]"),
        o.common.target.json);
    return 2;
  }
  auto path = ecat::master::find_control_endpoint(*o.common.target.attach);
  if (!path) {
    Connection::print_error(path.error(), o.common.target.json);
    return 1;
  }
  auto client = ecat::ipc::LineClient::connect(*path, "master");
  if (!client) {
    Connection::print_error(client.error(), o.common.target.json);
    return 1;
  }
  auto first = client->request(R"({"op":"events.follow"})");
  if (!first) {
    Connection::print_error(first.error(), o.common.target.json);
    return 1;
  }
  const auto end = o.duration_s > 0 ? std::chrono::steady_clock::now() +
                                          std::chrono::duration_cast<std::chrono::nanoseconds>(
                                              std::chrono::duration<double>(o.duration_s))
                                    : std::chrono::steady_clock::time_point::max();
  while (!ecat::tool::interrupted() && std::chrono::steady_clock::now() < end) {
    auto line = client->read_line(100ms);
    if (!line) {
      if (line.error().code() == Errc::closed) return 0;  // the master went away
      Connection::print_error(line.error(), o.common.target.json);
      return 1;
    }
    if (!*line) continue;
    if (o.common.target.json) {
      fmt::print("{}\n", **line);
    } else {
      const Json e = Json::parse(**line, nullptr, false);
      if (e.is_discarded()) continue;
      std::string rest;
      for (const auto& [k, v] : e.items()) {
        if (k == "event" || k == "seq" || k == "time_ns") continue;
        rest += fmt::format(" {}={}", k, show(v));
      }
      fmt::print("{:>6}  {:<16}{}\n", e.value("seq", 0u), e.value("event", ""), rest);
    }
    std::fflush(stdout);
  }
  return 0;
}

struct FileOptions {
  Common common;
  std::string remote;  // the file's name on the slave
  std::string local;   // the file here
  std::optional<std::string> password;
  bool firmware =
      false;  // foe_write --firmware: through BOOTSTRAP (the endpoint's firmware.update)
};

std::optional<std::vector<std::uint8_t>> read_local(const std::string& path, bool json) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    Connection::print_error(Error(Errc::not_found, fmt::format("cannot read '{}'", path)), json);
    return std::nullopt;
  }
  std::vector<std::uint8_t> bytes{std::istreambuf_iterator<char>(in),
                                  std::istreambuf_iterator<char>()};
  if (bytes.size() > (16u << 20)) {
    Connection::print_error(
        Error(Errc::out_of_range, fmt::format("'{}' is larger than 16 MiB", path)), json);
    return std::nullopt;
  }
  return bytes;
}

Result<void> write_local(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  if (!out) return Error(Errc::io_error, fmt::format("cannot write '{}'", path));
  return {};
}

int cmd_foe(const FileOptions& o, bool write) {
  std::vector<std::uint8_t> bytes;
  if (write) {
    auto read = read_local(o.local, o.common.target.json);
    if (!read) return 2;
    bytes = std::move(*read);
  }
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  const bool firmware = write && o.firmware;
  Json request{{"op", firmware ? "firmware.update"
                      : write  ? "foe.write"
                               : "foe.read"},
               {"slave", *name},
               {"file", o.remote}};
  if (o.password) request["password"] = *o.password;
  if (write) request["data"] = to_hex(bytes);
  Result<Json> r = Error(Errc::internal, "not sent");
  {
    Progress progress(fmt::format("{}{} '{}'", write ? "foe_write" : "foe_read",
                                  firmware ? " --firmware" : "", o.remote));
    r = c->call(request);
  }
  if (firmware) {
    return finish(r, o.common.target.json, [&](const Json& j) {
      fmt::print("firmware '{}' ({} bytes) written to {} in BOOTSTRAP; restarted, back in {}\n",
                 o.remote, j.value("size", 0), *name, j.value("state", std::string("?")));
    });
  }
  if (r && !write) {
    if (auto done = write_local(o.local, from_hex(r->value("data", ""))); !done) {
      r = done.error();
    } else {
      r->erase("data");
    }
  }
  return finish(r, o.common.target.json, [&](const Json& j) {
    fmt::print("{} bytes {} {} '{}'\n", j.value("size", 0), write ? "written to" : "read from",
               *name, o.remote);
  });
}

struct SoeOptions {
  Common common;
  std::string idn;
  std::string value;
  std::string type;
  unsigned drive = 0;
  std::string elements = "0x40";
};

// "S-0-0047", "P-0-0010" or a number.
std::optional<std::string> idn_number(const std::string& text) {
  if (text.size() == 8 && (text[0] == 'S' || text[0] == 'P') && text[1] == '-' && text[3] == '-' &&
      text[2] >= '0' && text[2] <= '7' &&
      text.find_first_not_of("0123456789", 4) == std::string::npos) {
    const unsigned number = static_cast<unsigned>(std::stoul(text.substr(4)));
    if (number > 4095) return std::nullopt;
    const unsigned idn =
        (text[0] == 'P' ? 0x8000u : 0u) | (static_cast<unsigned>(text[2] - '0') << 12) | number;
    return std::to_string(idn);
  }
  if (!text.empty() && text.find_first_not_of("0123456789abcdefABCDEFx") == std::string::npos) {
    return text;
  }
  return std::nullopt;
}

int cmd_soe(const SoeOptions& o, bool write) {
  const auto idn = idn_number(o.idn);
  if (!idn) {
    Connection::print_error(
        Error(Errc::invalid_argument,
              fmt::format("IDN '{}' is not S-x-nnnn, P-x-nnnn or a number", o.idn)),
        o.common.target.json);
    return 2;
  }
  std::vector<std::uint8_t> bytes;
  if (write) {
    auto encoded = encode_typed(o.type.empty() ? "octets" : o.type, o.value);
    if (!encoded) {
      Connection::print_error(encoded.error(), o.common.target.json);
      return 2;
    }
    bytes = std::move(*encoded);
  }
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  Json request{{"op", write ? "soe.write" : "soe.read"},
               {"slave", *name},
               {"drive", o.drive},
               {"idn", *idn},
               {"elements", o.elements}};
  if (write) request["data"] = to_hex(bytes);
  auto r = c->call(request);
  if (r && !write) {
    auto value = decode_typed(o.type, from_hex(r->value("data", "")));
    if (!value) {
      r = value.error();
    } else {
      (*r)["value"] = *value;
    }
  }
  return finish(r, o.common.target.json, [&](const Json& j) {
    if (write) {
      fmt::print("{} {} <- {}\n", *name, o.idn, o.value);
    } else {
      fmt::print("{}\n", show(j["value"]));
    }
  });
}

struct AliasOptions {
  Common common;
  std::string alias;
};

int cmd_alias(const AliasOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  auto r = c->call(Json{{"op", "alias.write"}, {"slave", *name}, {"alias", o.alias}});
  return finish(r, o.common.target.json, [&](const Json& j) {
    fmt::print("{}: alias 0x{:04x} written to the EEPROM (the ESC takes it at its next power-up)\n",
               *name, j.value("alias", 0u));
  });
}

int cmd_sii_write(const SiiOptions& o) {
  auto bytes = read_local(o.output, o.common.target.json);
  if (!bytes) return 2;
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  Result<Json> r = Error(Errc::internal, "not sent");
  {
    Progress progress(fmt::format("sii_write {} ({} bytes)", *name, bytes->size()));
    r = c->call(Json{{"op", "sii.write"}, {"slave", *name}, {"data", to_hex(*bytes)}});
  }
  return finish(r, o.common.target.json, [&](const Json& j) {
    fmt::print("{}: {} bytes written to the EEPROM and verified\n", *name, j.value("size", 0));
  });
}

struct PdosOptions {
  Common common;
  bool read = false;
};

// The assignment (0x1C10 + SM) and mapping objects as the device holds them now, read by SDO
// (complete access, as the master reads a CoE layout): {"sync_managers": [{sync_manager, pdos:
// [{index, entries: [{index, subindex, bit_length}]}]}]}, or why not.
Json pdos_as_read(Connection& c, const std::string& name, const Json& configured) {
  const auto upload = [&](unsigned index) -> std::optional<std::vector<std::uint8_t>> {
    auto r = c.call(Json{{"op", "sdo.upload"},
                         {"slave", name},
                         {"index", index},
                         {"subindex", 0},
                         {"complete_access", true}});
    if (!r) return std::nullopt;
    return from_hex(r->value("data", ""));
  };
  Json sms = Json::array();
  for (const auto& sm : configured["sync_managers"]) {
    const unsigned number = sm.value("sync_manager", 0u);
    const auto assignment = upload(0x1C10 + number);
    if (!assignment || assignment->size() < 2) {
      return Json{{"error", fmt::format("0x{:04x} (the assignment of SM{}) does not read",
                                        0x1C10 + number, number)}};
    }
    // Complete access from subindex 0: the count padded to 16 bits, then the entries.
    const std::size_t count = (*assignment)[0];
    Json pdos = Json::array();
    for (std::size_t i = 0; i < count && 2 + 2 * i + 1 < assignment->size(); ++i) {
      const unsigned pdo = (*assignment)[2 + 2 * i] | ((*assignment)[3 + 2 * i] << 8);
      Json entries = Json::array();
      if (const auto mapping = upload(pdo); mapping && mapping->size() >= 2) {
        for (std::size_t k = 0; k < (*mapping)[0] && 2 + 4 * k + 3 < mapping->size(); ++k) {
          const std::size_t at = 2 + 4 * k;
          const unsigned value = (*mapping)[at] | ((*mapping)[at + 1] << 8) |
                                 ((*mapping)[at + 2] << 16) |
                                 (static_cast<unsigned>((*mapping)[at + 3]) << 24);
          entries.push_back({{"index", fmt::format("0x{:04x}", value >> 16)},
                             {"subindex", (value >> 8) & 0xFF},
                             {"bit_length", value & 0xFF}});
        }
      }
      pdos.push_back({{"index", fmt::format("0x{:04x}", pdo)}, {"entries", std::move(entries)}});
    }
    sms.push_back({{"sync_manager", number}, {"pdos", std::move(pdos)}});
  }
  return Json{{"sync_managers", std::move(sms)}};
}

int cmd_pdos(const PdosOptions& po) {
  const Common& o = po.common;
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.slave);
  if (!name) return finish(name.error(), o.target.json, {});
  auto r = c->call(Json{{"op", "pdos"}, {"slave", *name}});
  if (r && po.read) (*r)["as_read"] = pdos_as_read(*c, *name, *r);
  return finish(r, o.target.json, [](const Json& j) {
    const auto print_pdo = [](const Json& p, const char* indent) {
      fmt::print("{}{} {} \"{}\"{}\n", indent, show(p["index"]), p.value("direction", ""),
                 p.value("name", ""), p.value("fixed", false) ? " (fixed)" : "");
      for (const auto& e : p["entries"]) {
        fmt::print("{}  {}:{:02x} {:>2} bits \"{}\"\n", indent, show(e["index"]),
                   e.value("subindex", 0), e.value("bit_length", 0), e.value("name", ""));
      }
    };
    for (const auto& sm : j["sync_managers"]) {
      fmt::print("SM{} {} ({} bytes)\n", sm.value("sync_manager", 0), sm.value("direction", ""),
                 sm.value("bytes", 0));
      for (const auto& p : sm["pdos"])
        print_pdo(p, "  ");
    }
    if (!j["unassigned"].empty()) fmt::print("not assigned:\n");
    for (const auto& p : j["unassigned"])
      print_pdo(p, "  ");
    if (!j.contains("as_read")) return;
    const auto& read = j["as_read"];
    fmt::print("as read from the device (CoE):\n");
    if (read.contains("error")) {
      fmt::print("  {}\n", show(read["error"]));
      return;
    }
    for (const auto& sm : read["sync_managers"]) {
      fmt::print("SM{}\n", sm.value("sync_manager", 0));
      for (const auto& p : sm["pdos"]) {
        fmt::print("  {}\n", show(p["index"]));
        for (const auto& e : p["entries"]) {
          fmt::print("    {}:{:02x} {:>2} bits\n", show(e["index"]), e.value("subindex", 0),
                     e.value("bit_length", 0));
        }
      }
    }
  });
}

// The ESC's error counters (0x0300..0x0313): per port RX errors (invalid frame, physical layer),
// forwarded RX errors, processing unit and PDI errors, lost links.
int cmd_crc(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto slaves = c->call(Json{{"op", "slaves"}});
  if (!slaves) return finish(slaves.error(), o.target.json, {});
  std::string only = o.slave.name;
  if (o.slave.alias) {
    auto named = slave_name(*c, o.slave);
    if (!named) return finish(named.error(), o.target.json, {});
    only = *named;
  }
  Json rows = Json::array();
  for (const auto& s : (*slaves)["slaves"]) {
    const std::string name = s.value("name", "");
    if (!only.empty() && name != only) continue;
    if (o.slave.position && s.value("position", -1) != static_cast<int>(*o.slave.position)) {
      continue;
    }
    auto r =
        c->call(Json{{"op", "reg.read"}, {"slave", name}, {"address", 0x0300}, {"length", 20}});
    if (!r) {
      rows.push_back({{"name", name}, {"error", r.error().message()}});
      continue;
    }
    const auto b = from_hex(r->value("data", ""));
    if (b.size() != 20) continue;
    Json ports = Json::array();
    for (int p = 0; p < 4; ++p) {
      ports.push_back({{"invalid_frames", b[2 * p]},
                       {"rx_errors", b[2 * p + 1]},
                       {"forwarded_errors", b[8 + p]},
                       {"lost_links", b[16 + p]}});
    }
    rows.push_back({{"name", name},
                    {"position", s.value("position", 0)},
                    {"ports", ports},
                    {"processing_unit_errors", b[12]},
                    {"pdi_errors", b[13]}});
  }
  return finish(Json{{"slaves", rows}}, o.target.json, [](const Json& j) {
    fmt::print("{:>3}  {:<14} {:>23} {:>23} {:>23} {:>23}  {:>4} {:>4}\n", "pos", "name",
               "port 0 inv/rx/fwd/lost", "port 1", "port 2", "port 3", "pu", "pdi");
    for (const auto& s : j["slaves"]) {
      if (s.contains("error")) {
        fmt::print("     {:<14} {}\n", s.value("name", ""), show(s["error"]));
        continue;
      }
      std::string cells;
      for (const auto& p : s["ports"]) {
        cells += fmt::format(
            " {:>23}",
            fmt::format("{}/{}/{}/{}", p.value("invalid_frames", 0), p.value("rx_errors", 0),
                        p.value("forwarded_errors", 0), p.value("lost_links", 0)));
      }
      fmt::print("{:>3}  {:<14}{}  {:>4} {:>4}\n", s.value("position", 0), s.value("name", ""),
                 cells, s.value("processing_unit_errors", 0), s.value("pdi_errors", 0));
    }
  });
}

// What is wrong now, per slave, in words: the session's failures and faults, each slave's state
// against its target and the AL status code it reported, and the ESC error counters that count.
int cmd_diag(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto status = c->call(Json{{"op", "status"}});
  if (!status) return finish(status.error(), o.target.json, {});
  auto al = c->call(Json{{"op", "al_status"}});
  if (!al) return finish(al.error(), o.target.json, {});
  Json findings = Json::array();
  for (const auto& f : (*status)["activation_failures"]) {
    findings.push_back({{"slave", f.value("slave", "")}, {"problem", f.value("error", "")}});
  }
  for (const auto& f : (*status)["runtime_faults"])
    findings.push_back({{"slave", ""}, {"problem", show(f)}});
  if ((*status)["last_failure"].is_object()) {
    findings.push_back({{"slave", ""},
                        {"problem", fmt::format("the last session ended: {}",
                                                (*status)["last_failure"].value("error", ""))}});
  }
  std::map<std::string, Json> codes;
  for (const auto& s : (*al)["slaves"])
    codes[s.value("name", "")] = s;
  for (const auto& s : (*status)["slaves"]) {
    const std::string name = s.value("name", "");
    const std::string state = s.value("state", "");
    const std::string target = s.value("target", "");
    if (state != target && (*status).value("state", "") != "preop_ready") {
      std::string why = fmt::format("{} instead of {}", state, target);
      if (codes[name].contains("al_status_text")) {
        why += fmt::format(" (AL status 0x{:04x}: {})", codes[name].value("al_status_code", 0),
                           codes[name].value("al_status_text", ""));
      }
      findings.push_back({{"slave", name}, {"problem", why}});
    }
    if (s.contains("fault")) findings.push_back({{"slave", name}, {"problem", show(s["fault"])}});
    if (s.contains("startup_error")) {
      findings.push_back({{"slave", name}, {"problem", show(s["startup_error"])}});
    }
    auto counters =
        c->call(Json{{"op", "reg.read"}, {"slave", name}, {"address", 0x0300}, {"length", 20}});
    if (!counters) {
      findings.push_back(
          {{"slave", name},
           {"problem", "its error counters do not read: " + counters.error().message()}});
      continue;
    }
    const auto b = from_hex(counters->value("data", ""));
    for (int p = 0; p < 4 && b.size() == 20; ++p) {
      if (b[2 * p] != 0 || b[2 * p + 1] != 0) {
        findings.push_back({{"slave", name},
                            {"problem", fmt::format("port {} received {} invalid frame(s) and {} "
                                                    "physical layer error(s): a cable or "
                                                    "connector on that port",
                                                    p, b[2 * p], b[2 * p + 1])}});
      }
      if (b[16 + p] != 0) {
        findings.push_back(
            {{"slave", name},
             {"problem", fmt::format("port {} lost its link {} time(s)", p, b[16 + p])}});
      }
    }
  }
  return finish(Json{{"state", (*status).value("state", "")}, {"findings", findings}},
                o.target.json, [](const Json& j) {
                  fmt::print("master: {}\n", j.value("state", ""));
                  if (j["findings"].empty()) fmt::print("nothing wrong found\n");
                  for (const auto& f : j["findings"]) {
                    const std::string who = f.value("slave", "");
                    fmt::print("  {}{}\n", who.empty() ? "" : who + ": ", f.value("problem", ""));
                  }
                });
}

int cmd_version(const Common& o) {
  Json out{{"tool", ECAT_VERSION_STRING}};
  if (o.target.attach) {
    int code = 0;
    auto c = Connection::open(o.target, &code);
    if (!c) return code;
    auto r = c->call(Json{{"op", "version"}});
    if (!r) return finish(r.error(), o.target.json, {});
    out["master"] = r->value("version", "");
  }
  return finish(out, o.target.json, [](const Json& j) {
    fmt::print("ecat {}\n", j.value("tool", ""));
    if (j.contains("master")) fmt::print("attached master: ecat {}\n", j.value("master", ""));
  });
}

// ---- The ring as a file and as a picture ------------------------------------------------------

struct ConfigOptions {
  Common common;
  std::string output;
  unsigned period_us = 1000;
};

// A name for a slave from its device name: the first word when it is a product code ("EK1100
// EtherCAT Coupler" -> "ek1100"), made unique with _2, _3 ...; else slave_<position>.
std::string slave_name_for(const Json& s, std::map<std::string, int>& used) {
  const std::string device = s.value("device", "");
  std::string word = device.substr(0, device.find(' '));
  std::string name;
  for (char ch : word) {
    if (std::isalnum(static_cast<unsigned char>(ch)) != 0) {
      name += static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    }
  }
  if (name.empty() || name.find_first_of("0123456789") == std::string::npos ||
      std::isalpha(static_cast<unsigned char>(name[0])) == 0) {
    name = fmt::format("slave_{}", s.value("position", 0));
  }
  const int n = ++used[name];
  return n == 1 ? name : fmt::format("{}_{}", name, n);
}

int cmd_config(const ConfigOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto status = c->call(Json{{"op", "status"}});
  auto slaves = status ? c->call(Json{{"op", "slaves"}, {"verbose", true}}) : status;
  if (!slaves) return finish(slaves.error(), o.common.target.json, {});
  std::string backend = o.common.target.backend;
  if (backend.empty()) backend = status->value("link", "");
  if (backend.starts_with("sim:") && !o.common.target.ring.empty()) {
    backend = "sim:" + std::filesystem::absolute(o.common.target.ring).string();
  }
  std::string yaml = fmt::format(
      "# Written by `ecat config` from the ring as it was found: every slave with its identity, "
      "those\n# with process data in domain main. Edit the names; docs/MASTER-CONFIG.md has every "
      "key.\nversion: 1\nmaster:\n  backend: {}\ndomains:\n  - {{id: main, period_us: {}}}\n"
      "slaves:\n",
      backend, o.period_us);
  std::map<std::string, int> used;
  Json listed = Json::array();
  for (const auto& s : (*slaves)["slaves"]) {
    const std::string name = slave_name_for(s, used);
    std::string line = fmt::format("  - {{name: {}, position: {}", name, s.value("position", 0));
    if (s["identity"].is_object()) {
      line += fmt::format(", vendor_id: 0x{:08x}, product_code: 0x{:08x}",
                          s["identity"].value("vendor_id", 0u),
                          s["identity"].value("product_code", 0u));
    }
    auto pdos = c->call(Json{{"op", "pdos"}, {"slave", s.value("name", "")}});
    bool process_data = false;
    if (pdos) {
      for (const auto& sm : (*pdos)["sync_managers"]) {
        if (!sm["pdos"].empty()) process_data = true;
      }
    }
    if (process_data) line += ", process_data: main";
    line += "}";
    const std::string device = s.value("device", "");
    if (!device.empty()) line += "   # " + device;
    yaml += line + "\n";
    listed.push_back(
        {{"name", name}, {"position", s.value("position", 0)}, {"process_data", process_data}});
  }
  if (!o.output.empty()) {
    if (auto done = write_local(o.output, std::vector<std::uint8_t>(yaml.begin(), yaml.end()));
        !done) {
      return finish(done.error(), o.common.target.json, {});
    }
  }
  return finish(Json{{"file", o.output}, {"slaves", listed}, {"yaml", yaml}}, o.common.target.json,
                [&](const Json& j) {
                  if (o.output.empty()) {
                    fmt::print("{}", yaml);
                  } else {
                    fmt::print("{} slaves written to {}\n", j["slaves"].size(), o.output);
                  }
                });
}

struct GraphOptions {
  Common common;
  std::string output;
  std::string svg;
};

// The topology as Graphviz DOT: each slave hangs off the nearest slave before it in ring order
// that still has an open port with a link (ports other than 0, the one the frame enters by):
// how the frame travels a tree (port 0 -> 3 -> 1 -> 2), so a line is a chain and a junction's
// branches fan out. `dot -Tsvg` turns it into a picture.
int cmd_graph(const GraphOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto slaves = c->call(Json{{"op", "slaves"}, {"verbose", true}});
  if (!slaves) return finish(slaves.error(), o.common.target.json, {});
  std::string dot =
      "digraph ethercat {\n  rankdir=LR;\n  node [shape=box, fontname=\"sans\"];\n"
      "  master [label=\"master\", shape=ellipse];\n";
  struct Open {
    std::size_t node;
    int free;
  };
  std::vector<Open> stack;
  Json edges = Json::array();
  const auto& list = (*slaves)["slaves"];
  for (std::size_t i = 0; i < list.size(); ++i) {
    const auto& s = list[i];
    int linked = 0;
    for (std::size_t p = 1; p < s["ports"].size(); ++p) {
      if (s["ports"][p].value("communication", false)) ++linked;
    }
    dot += fmt::format("  s{} [label=\"{}\\n{} (0x{:04x})\"];\n", i, s.value("name", ""),
                       s.value("device", "").substr(0, 24), s.value("station", 0));
    while (!stack.empty() && stack.back().free == 0)
      stack.pop_back();
    std::string parent = "master";
    if (!stack.empty()) {
      parent = fmt::format("s{}", stack.back().node);
      --stack.back().free;
    }
    dot += fmt::format("  {} -> s{};\n", parent, i);
    edges.push_back({{"from", parent == "master" ? Json("master")
                                                 : Json(list[stack.back().node].value("name", ""))},
                     {"to", s.value("name", "")}});
    stack.push_back({i, linked});
  }
  dot += "}\n";
  if (!o.svg.empty()) {
    // Rendered by Graphviz when it is installed; the DOT text is what ecat itself makes.
    if (std::system("command -v dot >/dev/null 2>&1") != 0) {
      return finish(Error(Errc::unsupported,
                          "--svg needs Graphviz's `dot` (apt install graphviz); --output writes "
                          "the DOT text"),
                    o.common.target.json, {});
    }
    const std::string quoted = "'" + o.svg + "'";
    if (o.svg.find('\'') != std::string::npos) {
      return finish(Error(Errc::invalid_argument, "--svg: a path without a quote, please"),
                    o.common.target.json, {});
    }
    FILE* pipe = ::popen(("dot -Tsvg -o " + quoted).c_str(), "w");
    if (pipe == nullptr) {
      return finish(Error(Errc::io_error, "cannot run dot"), o.common.target.json, {});
    }
    std::fwrite(dot.data(), 1, dot.size(), pipe);
    if (::pclose(pipe) != 0) {
      return finish(Error(Errc::io_error, fmt::format("dot could not write '{}'", o.svg)),
                    o.common.target.json, {});
    }
  }
  if (!o.output.empty()) {
    if (auto done = write_local(o.output, std::vector<std::uint8_t>(dot.begin(), dot.end()));
        !done) {
      return finish(done.error(), o.common.target.json, {});
    }
  }
  return finish(Json{{"edges", edges}, {"dot", dot}}, o.common.target.json, [&](const Json&) {
    if (o.output.empty()) {
      fmt::print("{}", dot);
    } else {
      fmt::print("written to {} (render: dot -Tsvg {} -o ring.svg)\n", o.output, o.output);
    }
  });
}

// A C identifier from a name: letters, digits and '_', not starting with a digit.
std::string c_identifier(const std::string& text) {
  std::string out;
  for (char ch : text) {
    const auto u = static_cast<unsigned char>(ch);
    out += std::isalnum(u) != 0 ? static_cast<char>(std::tolower(u)) : '_';
  }
  if (out.empty() || std::isdigit(static_cast<unsigned char>(out[0])) != 0) out = "_" + out;
  return out;
}

// The C type of a whole-byte signal, or "" (then only offset macros are written).
std::string c_type(const std::string& type, unsigned bits) {
  static const std::map<std::string, std::string> types{
      {"int8", "int8_t"},   {"int16", "int16_t"},   {"int32", "int32_t"},   {"int64", "int64_t"},
      {"uint8", "uint8_t"}, {"uint16", "uint16_t"}, {"uint32", "uint32_t"}, {"uint64", "uint64_t"},
      {"real32", "float"},  {"real64", "double"}};
  if (type == "bytes" && bits % 8 == 0) return fmt::format("uint8_t[{}]", bits / 8);
  auto it = types.find(type);
  return it == types.end() ? "" : it->second;
}

struct CStructOptions {
  Common common;
  std::string output;
};

// A C header of each domain's process image: a packed struct with a member per whole-byte
// signal (reserved bytes between), and for every signal its byte offset, bit and bit length as
// macros (bit signals are reached through those). Little endian, as the wire is.
int cmd_cstruct(const CStructOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto domains = c->call(Json{{"op", "domains"}});
  auto slaves = domains ? c->call(Json{{"op", "slaves"}, {"verbose", true}}) : domains;
  if (!slaves) return finish(slaves.error(), o.common.target.json, {});
  struct Field {
    std::uint64_t bit = 0;  // in the image
    unsigned bits = 0;
    std::string name;
    std::string type;
    std::string direction;
  };
  std::string header =
      "/* Generated by `ecat cstruct`: the process image of each domain. Little endian; the image "
      "is\n   what Domain::read/write and `ecat data` see, from the domain's logical base on. */\n"
      "#pragma once\n#include <stdint.h>\n\n";
  Json out = Json::array();
  for (const auto& d : (*domains)["domains"]) {
    const std::string id = d.value("id", "");
    const std::uint64_t base = d.value("logical_base", 0u);
    const std::uint64_t size = d.value("image_size", 0u);
    std::vector<Field> fields;
    for (const auto& sl : (*slaves)["slaves"]) {
      for (const auto& a : sl["attachments"]) {
        if (a.value("domain", "") != id) continue;
        const std::uint64_t at = (a.value("logical", 0u) - base) * 8;
        for (const auto& sig : sl["signals"]) {
          if (sig.value("sync_manager", -1) != a.value("sync_manager", -2)) continue;
          fields.push_back({at + sig.value("bit_offset", 0u), sig.value("bit_length", 0u),
                            c_identifier(sl.value("name", "") + "_" + sig.value("name", "")),
                            sig.value("type", ""), sig.value("direction", "")});
        }
      }
    }
    std::sort(fields.begin(), fields.end(),
              [](const Field& a, const Field& b) { return a.bit < b.bit; });
    const std::string prefix = c_identifier("ecat_" + id);
    std::string macros;
    std::string members;
    std::uint64_t byte = 0;
    unsigned reserved = 0;
    for (const auto& f : fields) {
      std::string upper = prefix + "_" + f.name;
      std::transform(upper.begin(), upper.end(), upper.begin(),
                     [](unsigned char ch) { return static_cast<char>(std::toupper(ch)); });
      macros +=
          fmt::format("#define {}_BYTE {}\n#define {}_BIT {}\n#define {}_BITS {}  /* {} {} */\n",
                      upper, f.bit / 8, upper, f.bit % 8, upper, f.bits, f.direction, f.type);
      const std::string type = c_type(f.type, f.bits);
      if (type.empty() || f.bit % 8 != 0 || f.bits % 8 != 0 || f.bit / 8 < byte) continue;
      if (f.bit / 8 > byte)
        members += fmt::format("  uint8_t reserved_{}[{}];\n", reserved++, f.bit / 8 - byte);
      const auto bracket = type.find('[');
      if (bracket == std::string::npos) {
        members += fmt::format("  {} {};  /* {} */\n", type, f.name, f.direction);
      } else {
        members += fmt::format("  {} {}{};  /* {} */\n", type.substr(0, bracket), f.name,
                               type.substr(bracket), f.direction);
      }
      byte = f.bit / 8 + f.bits / 8;
    }
    if (size > byte) members += fmt::format("  uint8_t reserved_{}[{}];\n", reserved, size - byte);
    header += fmt::format("/* domain \"{}\": {} bytes at logical 0x{:08x} */\n{}\n", id, size, base,
                          macros);
    header += fmt::format("typedef struct __attribute__((packed)) {{\n{}}} {}_image_t;\n", members,
                          prefix);
    header +=
        fmt::format("_Static_assert(sizeof({}_image_t) == {}, \"the image of domain {}\");\n\n",
                    prefix, size, id);
    out.push_back({{"domain", id}, {"size", size}, {"signals", fields.size()}});
  }
  if (!o.output.empty()) {
    if (auto done = write_local(o.output, std::vector<std::uint8_t>(header.begin(), header.end()));
        !done) {
      return finish(done.error(), o.common.target.json, {});
    }
  }
  return finish(Json{{"domains", out}, {"header", header}}, o.common.target.json, [&](const Json&) {
    if (o.output.empty()) {
      fmt::print("{}", header);
    } else {
      fmt::print("written to {}\n", o.output);
    }
  });
}

// The ESI name of a CoE data type (ETG.2000), for `ecat xml`; "" when unknown.
std::string_view esi_type(unsigned code) {
  switch (code) {
    case 0x0001:
      return "BOOL";
    case 0x0002:
      return "SINT";
    case 0x0003:
      return "INT";
    case 0x0004:
      return "DINT";
    case 0x0005:
      return "USINT";
    case 0x0006:
      return "UINT";
    case 0x0007:
      return "UDINT";
    case 0x0008:
      return "REAL";
    case 0x0011:
      return "LREAL";
    case 0x0015:
      return "LINT";
    case 0x001B:
      return "ULINT";
    default:
      return "";
  }
}

std::string xml_text(const std::string& text) {
  std::string out;
  for (char ch : text) {
    switch (ch) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += ch;
    }
  }
  return out;
}

struct XmlOptions {
  Common common;
  std::string output;
};

// A device description in the ESI form (EtherCATInfo) of each chosen slave, from what the master
// read: identity, name, the SyncManagers process data uses, the PDOs with their entries as
// configured. Enough for a configuration tool to know the device; not a full ESI (no
// dictionary, no DC opmodes).
int cmd_xml(const XmlOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto slaves = c->call(Json{{"op", "slaves"}, {"verbose", true}});
  if (!slaves) return finish(slaves.error(), o.common.target.json, {});
  std::string only;
  if (o.common.slave.given()) {
    auto name = slave_name(*c, o.common.slave);
    if (!name) return finish(name.error(), o.common.target.json, {});
    only = *name;
  }
  std::string xml =
      "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<!-- Written by `ecat xml` from "
      "what the master read of the slaves. -->\n";
  std::size_t devices = 0;
  for (const auto& s : (*slaves)["slaves"]) {
    const std::string name = s.value("name", "");
    if (!only.empty() && name != only) continue;
    if (!s["identity"].is_object()) continue;
    const auto& id = s["identity"];
    auto pdos = c->call(Json{{"op", "pdos"}, {"slave", name}});
    xml += fmt::format(
        "<EtherCATInfo>\n  <Vendor>\n    <Id>#x{:08x}</Id>\n  </Vendor>\n  <Descriptions>\n"
        "    <Devices>\n      <Device>\n        <Type ProductCode=\"#x{:08x}\" "
        "RevisionNo=\"#x{:08x}\">{}</Type>\n        <Name>{}</Name>\n",
        id.value("vendor_id", 0u), id.value("product_code", 0u), id.value("revision", 0u),
        xml_text(s.value("device", "").substr(0, s.value("device", "").find(' '))),
        xml_text(s.value("device", "")));
    for (const auto& a : s["attachments"]) {
      xml += fmt::format("        <Sm StartAddress=\"#x{:04x}\" DefaultSize=\"{}\">{}</Sm>\n",
                         a.value("physical", 0), a.value("size", 0),
                         a.value("direction", "") == "output" ? "Outputs" : "Inputs");
    }
    if (pdos) {
      for (const auto& sm : (*pdos)["sync_managers"]) {
        for (const auto& p : sm["pdos"]) {
          const char* tag = p.value("direction", "") == "output" ? "RxPdo" : "TxPdo";
          xml += fmt::format(
              "        <{} Sm=\"{}\"{}>\n          <Index>#x{}</Index>\n"
              "          <Name>{}</Name>\n",
              tag, sm.value("sync_manager", 0), p.value("fixed", false) ? " Fixed=\"1\"" : "",
              show(p["index"]).substr(2), xml_text(p.value("name", "")));
          for (const auto& e : p["entries"]) {
            xml += fmt::format(
                "          <Entry>\n            <Index>#x{}</Index>\n"
                "            <SubIndex>{}</SubIndex>\n"
                "            <BitLen>{}</BitLen>\n",
                show(e["index"]).substr(2), e.value("subindex", 0), e.value("bit_length", 0));
            if (show(e["index"]) != "0x0000") {
              xml += fmt::format("            <Name>{}</Name>\n", xml_text(e.value("name", "")));
              const auto type = esi_type(e.value("data_type", 0u));
              if (!type.empty()) xml += fmt::format("            <DataType>{}</DataType>\n", type);
            }
            xml += "          </Entry>\n";
          }
          xml += fmt::format("        </{}>\n", tag);
        }
      }
    }
    xml += "      </Device>\n    </Devices>\n  </Descriptions>\n</EtherCATInfo>\n";
    ++devices;
  }
  if (!o.output.empty()) {
    if (auto done = write_local(o.output, std::vector<std::uint8_t>(xml.begin(), xml.end()));
        !done) {
      return finish(done.error(), o.common.target.json, {});
    }
  }
  return finish(Json{{"devices", devices}, {"xml", xml}}, o.common.target.json, [&](const Json&) {
    if (o.output.empty()) {
      fmt::print("{}", xml);
    } else {
      fmt::print("{} device(s) written to {}\n", devices, o.output);
    }
  });
}

struct EoeCommandOptions {
  Common common;
  std::string ip, subnet_mask, gateway, dns_server, mac, dns_name;
  bool setting() const {
    return !ip.empty() || !subnet_mask.empty() || !gateway.empty() || !dns_server.empty() ||
           !mac.empty() || !dns_name.empty();
  }
};

// EoE: the tunnel's counters, or (with any parameter) the Set IP Parameter service.
int cmd_eoe(const EoeCommandOptions& o) {
  int code = 0;
  auto c = Connection::open(o.common.target, &code);
  if (!c) return code;
  auto name = slave_name(*c, o.common.slave);
  if (!name) return finish(name.error(), o.common.target.json, {});
  if (!o.setting()) {
    auto r = c->call(Json{{"op", "eoe.stats"}, {"slave", *name}});
    return finish(r, o.common.target.json, [&](const Json& j) {
      fmt::print(
          "{}: {} frames sent ({} fragments), {} received ({} fragments), {} frames and {} "
          "fragments dropped\n",
          *name, j.value("frames_sent", 0), j.value("fragments_sent", 0),
          j.value("frames_received", 0), j.value("fragments_received", 0),
          j.value("frames_dropped", 0), j.value("fragments_dropped", 0));
    });
  }
  Json request{{"op", "eoe.set_ip"}, {"slave", *name}};
  const std::pair<const char*, const std::string*> fields[] = {
      {"ip", &o.ip},           {"subnet_mask", &o.subnet_mask},
      {"gateway", &o.gateway}, {"dns_server", &o.dns_server},
      {"mac", &o.mac},         {"dns_name", &o.dns_name}};
  for (const auto& [key, value] : fields) {
    if (!value->empty()) request[key] = *value;
  }
  auto r = c->call(request);
  return finish(r, o.common.target.json,
                [&](const Json&) { fmt::print("{}: IP parameters set\n", *name); });
}

// What is on the wire now against what the session knows (attached: without disturbing it).
int cmd_rescan(const Common& o) {
  int code = 0;
  auto c = Connection::open(o.target, &code);
  if (!c) return code;
  auto r = c->call(Json{{"op", "rescan"}});
  return finish(r, o.target.json, [](const Json& j) {
    fmt::print("{} slaves on the wire, {} in the session\n", j.value("on_wire", 0),
               j.value("in_session", 0));
    for (const auto& s : j["slaves"]) {
      fmt::print("{:>3}  0x{:04x}  {:<14} {}{}\n", s.value("position", 0), s.value("station", 0),
                 s["name"].is_string() ? s["name"].get<std::string>() : "(not in the session)",
                 s.value("al_state", "?"), s.value("al_error", false) ? " +error" : "");
    }
    for (const auto& m : j["missing"])
      fmt::print("     {} is no longer on the wire\n", show(m));
  });
}

// ---- Registration -----------------------------------------------------------------------------

template <class O>
CLI::App* base(CLI::App& parent, const char* name, const char* help, O& o, bool slave,
               bool slave_required) {
  auto* app = parent.add_subcommand(name, help);
  add_target(app, o.target);
  if (slave) add_slave_choice(app, o.slave, slave_required);
  return app;
}

ecat::tool::Command setup_slaves(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app =
      base(parent, "slaves", "List the slaves (standalone: every slave found, held in PREOP)", *o,
           true, false);
  app->add_flag("-v,--verbose", o->verbose, "ESC, ports, mailbox, SyncManagers and signals");
  return {app, [o] { return cmd_slaves(*o); }};
}

ecat::tool::Command setup_master(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app =
      base(parent, "master", "The master: state, link, domains, frame counters", *o, false, false);
  return {app, [o] { return cmd_master(*o); }};
}

ecat::tool::Command setup_domains(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app = base(parent, "domains",
                   "The domains (standalone: laid out, not cycling: every slave held in PREOP)", *o,
                   false, false);
  app->add_flag("-v,--verbose", o->verbose, "With the process image in hex");
  return {app, [o] { return cmd_domains(*o); }};
}

ecat::tool::Command setup_data(CLI::App& parent) {
  auto o = std::make_shared<DataOptions>();
  auto* app =
      base(parent, "data", "A domain's process image, raw, to stdout", o->common, false, false);
  app->add_option("--domain", o->domain, "The domain (needed when there are several)");
  return {app, [o] { return cmd_data(*o); }};
}

void add_sdo_address(CLI::App* app, SdoOptions& o) {
  auto* gateway = app->add_option(
      "--gateway", o.gateway,
      "Through a master's ETG.8200 mailbox gateway at HOST:PORT (`ecat serve --mailbox-gateway`), "
      "the slave named by --station");
  app->add_option("--station", o.station,
                  "With --gateway: the slave's configured station address (0x1001)")
      ->needs(gateway);
  app->add_option("INDEX", o.index, "Object index (0x6041)")->required();
  app->add_option("SUBINDEX", o.subindex, "Subindex (0)")->required();
  app->add_option("--type", o.type, std::string("Value type: ") + kTypes);
  app->add_flag("--complete-access,-c", o.complete_access, "The whole object at once");
}

ecat::tool::Command setup_upload(CLI::App& parent) {
  auto o = std::make_shared<SdoOptions>();
  auto* app = base(parent, "upload", "Read an SDO", o->common, true, false);
  add_sdo_address(app, *o);
  return {app, [o] { return cmd_upload(*o); }};
}

ecat::tool::Command setup_download(CLI::App& parent) {
  auto o = std::make_shared<SdoOptions>();
  auto* app = base(parent, "download", "Write an SDO (attached: the endpoint must allow writes)",
                   o->common, true, false);
  add_sdo_address(app, *o);
  app->add_option("VALUE", o->value, "The value, as --type says (default: hex octets)")->required();
  return {app, [o] { return cmd_download(*o); }};
}

ecat::tool::Command setup_states(CLI::App& parent) {
  auto o = std::make_shared<StateOptions>();
  auto* app = base(parent, "states",
                   "Request a state: the session's (op, safeop, preop) or, with -p/--name, one "
                   "slave's (init, preop, bootstrap, safeop, op)",
                   o->common, true, false);
  app->add_option("STATE", o->state, "The state")->required();
  return {app, [o] { return cmd_states(*o); }};
}

ecat::tool::Command setup_reg_read(CLI::App& parent) {
  auto o = std::make_shared<RegOptions>();
  auto* app = base(parent, "reg_read", "Read ESC registers", o->common, true, true);
  app->add_option("ADDRESS", o->address, "Register address (0x0130)")->required();
  app->add_option("LENGTH", o->length_or_value, "Bytes (default: the --type's size)");
  app->add_option("--type", o->type, std::string("Show as: ") + kTypes);
  return {app, [o] { return cmd_reg_read(*o); }};
}

ecat::tool::Command setup_reg_write(CLI::App& parent) {
  auto o = std::make_shared<RegOptions>();
  auto* app =
      base(parent, "reg_write", "Write ESC registers (attached: the endpoint must allow writes)",
           o->common, true, true);
  app->add_option("ADDRESS", o->address, "Register address (0x0120)")->required();
  app->add_option("VALUE", o->length_or_value, "The value, as --type says (default: hex octets)")
      ->required();
  app->add_option("--type", o->type, std::string("Value type: ") + kTypes);
  return {app, [o] { return cmd_reg_write(*o); }};
}

ecat::tool::Command setup_sii_read(CLI::App& parent) {
  auto o = std::make_shared<SiiOptions>();
  auto* app = base(parent, "sii_read", "A slave's SII EEPROM image (as read at bring-up)",
                   o->common, true, true);
  app->add_option("-o,--output", o->output, "Write the raw image to this file");
  app->add_flag("-d,--decode", o->decode, "Decode it (as `ecat sii FILE` does)");
  return {app, [o] { return cmd_sii_read(*o); }};
}

ecat::tool::Command setup_sdos(CLI::App& parent) {
  auto o = std::make_shared<SdosOptions>();
  auto* app =
      base(parent, "sdos", "A slave's object dictionary (SDO information)", o->common, true, true);
  app->add_flag("--values", o->values, "With every subindex's value");
  return {app, [o] { return cmd_sdos(*o); }};
}

ecat::tool::Command setup_events(CLI::App& parent) {
  auto o = std::make_shared<EventsOptions>();
  auto* app = base(parent, "events", "Follow a running master's event stream (--attach)", o->common,
                   false, false);
  app->add_option("--duration", o->duration_s, "Seconds to follow (default: until Ctrl-C)")
      ->check(ecat::tool::run_seconds());
  return {app, [o] { return cmd_events(*o); }};
}

void add_file_options(CLI::App* app, FileOptions& o, bool write) {
  app->add_option("FILE", o.remote, "The file's name on the slave")->required();
  app->add_option(write ? "SOURCE" : "-o,--output", o.local,
                  write ? "The local file to send" : "Where to write what was read")
      ->required();
  app->add_option("--password", o.password, "FoE password (a number)");
}

ecat::tool::Command setup_foe_read(CLI::App& parent) {
  auto o = std::make_shared<FileOptions>();
  auto* app = base(parent, "foe_read", "Read a file from a slave (FoE)", o->common, true, true);
  add_file_options(app, *o, false);
  return {app, [o] { return cmd_foe(*o, false); }};
}

ecat::tool::Command setup_foe_write(CLI::App& parent) {
  auto o = std::make_shared<FileOptions>();
  auto* app = base(parent, "foe_write",
                   "Write a file to a slave (FoE; attached: the endpoint must allow writes)",
                   o->common, true, true);
  add_file_options(app, *o, true);
  app->add_flag("--firmware", o->firmware,
                "A firmware update: the slave is taken through INIT to BOOTSTRAP, the file "
                "written there, and the slave restarted and brought back to where it was");
  return {app, [o] { return cmd_foe(*o, true); }};
}

void add_soe_options(CLI::App* app, SoeOptions& o) {
  app->add_option("IDN", o.idn, "S-0-0047, P-0-0010 or a number")->required();
  app->add_option("--drive", o.drive, "Drive number (0..7)")->check(CLI::Range(0, 7));
  app->add_option("--elements", o.elements, "Element flags (0x40: the value)");
  app->add_option("--type", o.type, std::string("Value type: ") + kTypes);
}

ecat::tool::Command setup_soe_read(CLI::App& parent) {
  auto o = std::make_shared<SoeOptions>();
  auto* app = base(parent, "soe_read", "Read an IDN of a servo drive (SoE)", o->common, true, true);
  add_soe_options(app, *o);
  return {app, [o] { return cmd_soe(*o, false); }};
}

ecat::tool::Command setup_soe_write(CLI::App& parent) {
  auto o = std::make_shared<SoeOptions>();
  auto* app = base(parent, "soe_write",
                   "Write an IDN of a servo drive (SoE; attached: the endpoint must allow writes)",
                   o->common, true, true);
  add_soe_options(app, *o);
  app->add_option("VALUE", o->value, "The value, as --type says (default: hex octets)")->required();
  return {app, [o] { return cmd_soe(*o, true); }};
}

ecat::tool::Command setup_alias(CLI::App& parent) {
  auto o = std::make_shared<AliasOptions>();
  auto* app = base(parent, "alias",
                   "Write a slave's station alias into its EEPROM (SII word 4, checksum fixed)",
                   o->common, true, true);
  app->add_option("ALIAS", o->alias, "The alias (0x1234 or decimal)")->required();
  return {app, [o] { return cmd_alias(*o); }};
}

ecat::tool::Command setup_sii_write(CLI::App& parent) {
  auto o = std::make_shared<SiiOptions>();
  auto* app =
      base(parent, "sii_write", "Write an SII image into a slave's EEPROM (written words verified)",
           o->common, true, true);
  app->add_option("IMAGE", o->output, "The raw image file (as sii_read -o writes it)")->required();
  return {app, [o] { return cmd_sii_write(*o); }};
}

ecat::tool::Command setup_pdos(CLI::App& parent) {
  auto o = std::make_shared<PdosOptions>();
  auto* app = base(parent, "pdos",
                   "A slave's PDO assignment and mapping, as configured (and --read: as the "
                   "device holds them, by SDO)",
                   o->common, true, true);
  app->add_flag("--read", o->read, "Also read the assignment and mapping objects from the device");
  return {app, [o] { return cmd_pdos(*o); }};
}

ecat::tool::Command setup_crc(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app = base(parent, "crc", "The ESCs' frame error and lost-link counters (0x0300..)", *o,
                   true, false);
  return {app, [o] { return cmd_crc(*o); }};
}

ecat::tool::Command setup_diag(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app = base(parent, "diag", "What is wrong now, per slave, in words", *o, false, false);
  return {app, [o] { return cmd_diag(*o); }};
}

ecat::tool::Command setup_config(CLI::App& parent) {
  auto o = std::make_shared<ConfigOptions>();
  auto* app = base(parent, "config",
                   "Write a ring file from the ring as found: the first configuration in one "
                   "command",
                   o->common, false, false);
  app->add_option("-o,--output", o->output, "The file to write (default: stdout)");
  app->add_option("--period-us", o->period_us, "The domain's period")
      ->check(CLI::Range(50u, 10'000'000u));
  return {app, [o] { return cmd_config(*o); }};
}

ecat::tool::Command setup_graph(CLI::App& parent) {
  auto o = std::make_shared<GraphOptions>();
  auto* app = base(parent, "graph", "The ring's topology as Graphviz DOT", o->common, false, false);
  app->add_option("-o,--output", o->output, "The file to write (default: stdout)");
  app->add_option("--svg", o->svg, "Also render it as SVG into this file (needs Graphviz)");
  return {app, [o] { return cmd_graph(*o); }};
}

ecat::tool::Command setup_cstruct(CLI::App& parent) {
  auto o = std::make_shared<CStructOptions>();
  auto* app = base(parent, "cstruct",
                   "A C header of each domain's process image (packed structs and offsets)",
                   o->common, false, false);
  app->add_option("-o,--output", o->output, "The file to write (default: stdout)");
  return {app, [o] { return cmd_cstruct(*o); }};
}

ecat::tool::Command setup_xml(CLI::App& parent) {
  auto o = std::make_shared<XmlOptions>();
  auto* app = base(parent, "xml",
                   "Device descriptions (ESI form: identity, SyncManagers, PDOs) of the slaves",
                   o->common, true, false);
  app->add_option("-o,--output", o->output, "The file to write (default: stdout)");
  return {app, [o] { return cmd_xml(*o); }};
}

ecat::tool::Command setup_eoe(CLI::App& parent) {
  auto o = std::make_shared<EoeCommandOptions>();
  auto* app = base(parent, "eoe",
                   "A slave's EoE tunnel: its counters, or Set IP Parameter with --ip ... "
                   "(attached: the endpoint must allow writes)",
                   o->common, true, true);
  app->add_option("--ip", o->ip, "IPv4 address (a.b.c.d)");
  app->add_option("--subnet-mask", o->subnet_mask, "Subnet mask (a.b.c.d)");
  app->add_option("--gateway", o->gateway, "Default gateway (a.b.c.d)");
  app->add_option("--dns-server", o->dns_server, "DNS server (a.b.c.d)");
  app->add_option("--mac", o->mac, "MAC address (02:00:00:00:00:01)");
  app->add_option("--dns-name", o->dns_name, "DNS name (at most 32 bytes)");
  return {app, [o] { return cmd_eoe(*o); }};
}

ecat::tool::Command setup_rescan(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app = base(parent, "rescan",
                   "Read what is on the wire now (count, stations, AL states) against the "
                   "session, without disturbing it",
                   *o, false, false);
  return {app, [o] { return cmd_rescan(*o); }};
}

ecat::tool::Command setup_version(CLI::App& parent) {
  auto o = std::make_shared<Common>();
  auto* app =
      base(parent, "version", "The tool's version (and an attached master's)", *o, false, false);
  return {app, [o] { return cmd_version(*o); }};
}

const bool registered = [] {
  for (auto setup :
       {&setup_slaves,    &setup_master, &setup_domains,   &setup_data,      &setup_upload,
        &setup_download,  &setup_states, &setup_reg_read,  &setup_reg_write, &setup_sii_read,
        &setup_sdos,      &setup_events, &setup_foe_read,  &setup_foe_write, &setup_soe_read,
        &setup_soe_write, &setup_alias,  &setup_sii_write, &setup_pdos,      &setup_crc,
        &setup_diag,      &setup_config, &setup_graph,     &setup_cstruct,   &setup_xml,
        &setup_eoe,       &setup_rescan, &setup_version}) {
    ecat::tool::register_command(setup);
  }
  return true;
}();

}  // namespace
