#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <ecat/ipc/line_server.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/faults.hpp>

#include "config/spec_tree.hpp"
#include "sim/fault_spec.hpp"

namespace ecat::sim {

namespace {

namespace tree = config::detail;
using tree::SpecContext;
using tree::SpecNode;
// Replies keep their keys in the order written: "ok" first, then "id", as clients read them.
using Json = nlohmann::ordered_json;
// The request's "id" as it will be echoed; none when the request had none.
using RequestId = std::optional<Json>;

constexpr std::array<std::string_view, 15> kOps{
    "status",      "fault.inject", "fault.clear",  "fault.list",  "signals",
    "signal.get",  "signal.set",   "signal.clear", "power_cycle", "link",
    "memory.read", "profiles",     "ring",         "ping",        "hotconnect"};

std::string hex_bytes(std::span<const std::uint8_t> bytes) {
  std::string out;
  out.reserve(bytes.size() * 2);
  for (auto b : bytes)
    out += fmt::format("{:02x}", b);
  return out;
}

// Whole values print as integers (a digital input reads 1, not 1.0); JSON has no NaN or infinity.
Json number(double value) {
  if (!std::isfinite(value)) return nullptr;
  if (value == std::floor(value) && std::fabs(value) < 1e15) {
    return static_cast<std::int64_t>(value);
  }
  return value;
}

Json faults_json(const FaultInfo& f) {
  Json queued = Json::array();
  for (const auto& q : f.queued) {
    queued.push_back(Json{{"description", q.description}, {"remaining", q.remaining}});
  }
  Json scheduled = Json::array();
  for (const auto& s : f.scheduled) {
    Json item{{"description", s.description}};
    if (s.due_in_ns) item["due_in_ns"] = *s.due_in_ns;
    if (!s.waiting_on.empty()) {
      item["waiting_on"] = s.waiting_on;
      item["remaining"] = s.remaining;
    }
    item["step"] = s.step;
    scheduled.push_back(std::move(item));
  }
  Json out{{"active", f.active},
           {"queued", std::move(queued)},
           {"scheduled", std::move(scheduled)},
           {"drop_responses", f.drop_responses},
           {"wkc_offset", f.wkc_offset}};
  out["command_wkc_offsets"] = Json::object();
  for (const auto& [command, delta] : f.command_wkc_offsets)
    out["command_wkc_offsets"][command] = delta;
  out["logical_wkc_offsets"] = Json::object();
  for (const auto& [slave, delta] : f.logical_wkc_offsets)
    out["logical_wkc_offsets"][slave] = delta;
  out["disconnected"] = f.disconnected;
  out["links_down"] = f.links_down;
  if (!f.ring.empty()) out["ring"] = f.ring;
  return out;
}

// {"ok":true[,"id":..]}: the caller adds the op's fields.
Json ok_reply(const RequestId& id) {
  Json out{{"ok", true}};
  if (id) out["id"] = *id;
  return out;
}

std::string error_reply(std::string_view message, const RequestId& id = std::nullopt) {
  Json out{{"ok", false}};
  if (id) out["id"] = *id;
  out["error"] = std::string(message);
  return tree::dump_json(out);
}

// Adds the status fields to `out` (after "ok" and "id").
void add_status(Json& out, const SimStatus& st) {
  out["time_ns"] = st.time_ns;
  out["link"] = st.link;
  Json slaves = Json::array();
  for (const auto& s : st.slaves) {
    slaves.push_back(
        Json{{"index", s.index},
             {"name", s.name},
             {"profile", s.profile},
             {"vendor_id", s.vendor_id},
             {"product_code", s.product_code},
             {"revision", s.revision},
             {"station", s.station},
             {"alias", s.alias},
             {"al_state", wire::to_string(s.al_state)},
             {"al_error", s.al_error},
             {"al_status_code", s.al_status_code},
             {"dc", s.dc},
             {"links", Json::array({s.links[0], s.links[1], s.links[2], s.links[3]})}});
  }
  out["slaves"] = std::move(slaves);
  const auto& c = st.counters;
  out["counters"] = Json{{"frames", c.frames},
                         {"replies", c.replies},
                         {"lost", c.lost},
                         {"malformed", c.malformed},
                         {"delayed", c.delayed},
                         {"duplicated", c.duplicated},
                         {"send_errors", c.send_errors},
                         {"receive_errors", c.receive_errors},
                         {"idle_advances", c.idle_advances},
                         {"datagrams", st.segment.datagrams},
                         {"exchanges", st.fault_stats.exchanges},
                         {"healthy_exchanges", st.fault_stats.healthy_exchanges},
                         {"responses_dropped", st.fault_stats.responses_dropped},
                         {"replies_altered", st.fault_stats.replies_altered}};
  out["faults"] = faults_json(st.faults);
  Json groups = Json::array();
  for (const auto& g : st.hot_connect) {
    groups.push_back(Json{{"group", g.name},
                          {"first", g.first < st.slaves.size() ? st.slaves[g.first].name : ""},
                          {"slaves", g.slaves},
                          {"plugged", g.plugged}});
  }
  out["hot_connect"] = std::move(groups);
}

// The second master port's counters and cabling (a redundant ring), beside the server's.
void add_redundant(Json& out, const RedundantPorts& ports) {
  const RedundantPortsStats p = ports.stats();
  out["redundant"] = Json{{"topology", describe(ports.topology())},
                          {"frames", p.frames},
                          {"crosses", p.crosses},
                          {"bounces", p.bounces},
                          {"lost", p.lost},
                          {"overflowed", p.overflowed},
                          {"delayed", p.delayed},
                          {"duplicated", p.duplicated},
                          {"send_errors", p.send_errors}};
}

// The id echoed as the client wrote it: a string stays a string, a number a number.
Json id_value(const SpecNode& node) {
  if (node.is_null()) return nullptr;
  if (node.quoted) return node.text;
  if (node.text == "true") return true;
  if (node.text == "false") return false;
  const char* first = node.text.data();
  const char* last = first + node.text.size();
  const auto whole = [&](std::from_chars_result r) { return r.ec == std::errc() && r.ptr == last; };
  if (std::int64_t i = 0; whole(std::from_chars(first, last, i))) return i;
  if (std::uint64_t u = 0; whole(std::from_chars(first, last, u))) return u;
  if (double d = 0; whole(std::from_chars(first, last, d)) && std::isfinite(d)) return d;
  return node.text;  // not reached: the parser only lets JSON numbers through unquoted
}

class RequestReader {
 public:
  explicit RequestReader(const SpecNode& root) : root_(root) {}

  Result<std::string> text(std::string_view key) const {
    auto node = tree::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return tree::to_text(c_, **node, key);
  }
  Result<std::int64_t> integer(std::string_view key, std::int64_t min, std::int64_t max) const {
    auto node = tree::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return tree::to_int(c_, **node, key, min, max);
  }
  Result<double> real(std::string_view key) const {
    auto node = tree::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return tree::to_double(c_, **node, key);
  }
  Result<bool> boolean(std::string_view key) const {
    auto node = tree::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return tree::to_bool(c_, **node, key);
  }
  Result<void> keys(std::initializer_list<std::string_view> known) const {
    return tree::check_keys(c_, root_, "", known);
  }
  const SpecNode& root() const { return root_; }
  const SpecContext& context() const { return c_; }

 private:
  const SpecNode& root_;
  SpecContext c_{};
};

Result<wire::RedundantPort> master_port(const RequestReader& r, std::string_view key) {
  auto text = r.text(key);
  if (!text) return std::move(text).error();
  if (*text == "primary") return wire::RedundantPort::primary;
  if (*text == "secondary") return wire::RedundantPort::secondary;
  return Error(Errc::invalid_argument,
               fmt::format("{}: unknown master port '{}' (known: primary, secondary)", key, *text));
}

std::string dispatch(SimServer& server, const RedundantPorts* redundant, const RequestReader& r,
                     const std::string& op, const RequestId& id) {
  const auto fail = [&](const Error& e) { return error_reply(e.message(), id); };
  const auto reply = [](const Json& out) { return tree::dump_json(out); };
#define ECAT_CHECK(expr)               \
  if (auto check_ = (expr); !check_) { \
    return fail(check_.error());       \
  }
  if (op == "ping") {
    ECAT_CHECK(r.keys({"op", "id"}));
    return reply(ok_reply(id));
  }
  if (op == "status") {
    ECAT_CHECK(r.keys({"op", "id"}));
    Json out = ok_reply(id);
    add_status(out, server.status());
    if (redundant != nullptr) add_redundant(out, *redundant);
    return reply(out);
  }
  if (op == "profiles") {
    ECAT_CHECK(r.keys({"op", "id"}));
    Json profiles = Json::array();
    for (const auto& p : device_profiles()) {
      profiles.push_back(Json{{"name", p.name}, {"description", p.description}});
    }
    Json out = ok_reply(id);
    out["profiles"] = std::move(profiles);
    return reply(out);
  }
  if (op == "fault.inject") {
    ECAT_CHECK(r.keys({"op", "id", "fault"}));
    auto node = tree::require(r.context(), r.root(), "", "fault");
    if (!node) return fail(node.error());
    auto fault = detail::parse_fault_node(r.context(), **node, "fault");
    if (!fault) return fail(fault.error());
    ECAT_CHECK(server.inject(*fault));
    Json out = ok_reply(id);
    out["description"] = describe(*fault);
    return reply(out);
  }
  if (op == "fault.clear") {
    ECAT_CHECK(r.keys({"op", "id"}));
    server.clear_faults();
    return reply(ok_reply(id));
  }
  if (op == "fault.list") {
    ECAT_CHECK(r.keys({"op", "id"}));
    Json out = ok_reply(id);
    out["faults"] = faults_json(server.fault_info());
    return reply(out);
  }
  if (op == "signals") {
    ECAT_CHECK(r.keys({"op", "id", "slave"}));
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto signals = server.signals(*slave);
    if (!signals) return fail(signals.error());
    Json list = Json::array();
    for (const auto& s : *signals) {
      const auto value = server.signal(*slave, s.name);
      list.push_back(Json{{"name", s.name},
                          {"direction", s.direction == SignalDirection::input ? "input" : "output"},
                          {"type", s.type},
                          {"unit", s.unit},
                          {"value", value ? number(*value) : Json(nullptr)}});
    }
    Json out = ok_reply(id);
    out["signals"] = std::move(list);
    return reply(out);
  }
  if (op == "signal.get" || op == "signal.set" || op == "signal.clear") {
    if (op == "signal.set") {
      ECAT_CHECK(r.keys({"op", "id", "slave", "signal", "value"}));
    } else {
      ECAT_CHECK(r.keys({"op", "id", "slave", "signal"}));
    }
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto signal = r.text("signal");
    if (!signal) return fail(signal.error());
    if (op == "signal.get") {
      auto value = server.signal(*slave, *signal);
      if (!value) return fail(value.error());
      Json out = ok_reply(id);
      out["value"] = number(*value);
      return reply(out);
    }
    if (op == "signal.clear") {
      ECAT_CHECK(server.clear_input(*slave, *signal));
      return reply(ok_reply(id));
    }
    // Booleans are accepted for digital signals.
    double value = 0;
    if (const SpecNode* v = r.root().find("value");
        v && v->is_scalar() && !v->quoted && (v->text == "true" || v->text == "false")) {
      value = v->text == "true" ? 1.0 : 0.0;
    } else {
      auto number_value = r.real("value");
      if (!number_value) return fail(number_value.error());
      value = *number_value;
    }
    ECAT_CHECK(server.set_input(*slave, *signal, value));
    return reply(ok_reply(id));
  }
  if (op == "power_cycle") {
    ECAT_CHECK(r.keys({"op", "id", "slave"}));
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    ECAT_CHECK(server.power_cycle(*slave));
    return reply(ok_reply(id));
  }
  if (op == "link") {
    ECAT_CHECK(r.keys({"op", "id", "slave", "port", "up"}));
    auto up = r.boolean("up");
    if (!up) return fail(up.error());
    if (r.root().find("slave") == nullptr) {
      if (r.root().find("port") != nullptr) {
        return error_reply("port: the master link has no port (give a slave for a slave's port)",
                           id);
      }
      server.set_master_link(*up);
      return reply(ok_reply(id));
    }
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto port = r.integer("port", 0, 3);
    if (!port) return fail(port.error());
    ECAT_CHECK(server.set_link(*slave, static_cast<std::uint8_t>(*port), *up));
    return reply(ok_reply(id));
  }
  if (op == "ring") {
    // The cabling of a redundant segment: one change (break_after, cut, heal, or a port's delay),
    // made as the ring fault of the same meaning, or none to read it.
    ECAT_CHECK(r.keys({"op", "id", "break_after", "cut", "heal", "port", "delay_ms", "from"}));
    const auto has = [&](std::string_view key) { return r.root().find(key) != nullptr; };
    const int changes = (has("break_after") ? 1 : 0) + (has("cut") ? 1 : 0) +
                        (has("heal") ? 1 : 0) + (has("delay_ms") ? 1 : 0);
    if (changes > 1) {
      return error_reply("ring: give one of break_after, cut, heal and delay_ms", id);
    }
    if ((has("port") || has("from")) && !has("delay_ms")) {
      return error_reply("ring: port and from go with delay_ms", id);
    }
    std::optional<Fault> change;
    if (has("break_after")) {
      auto after = r.integer("break_after", 1, 4095);
      if (!after) return fail(after.error());
      change = fault::ring_break(static_cast<std::uint32_t>(*after));
    } else if (has("cut")) {
      auto port = master_port(r, "cut");
      if (!port) return fail(port.error());
      change = fault::ring_cut(*port);
    } else if (has("heal")) {
      auto heal = r.boolean("heal");
      if (!heal) return fail(heal.error());
      if (!*heal) return error_reply("heal: only true heals (break_after or cut break)", id);
      change = fault::ring_heal();
    } else if (has("delay_ms")) {
      auto port = master_port(r, "port");
      if (!port) return fail(port.error());
      auto ms = r.real("delay_ms");
      if (!ms) return fail(ms.error());
      if (!std::isfinite(*ms) || *ms < 0 || *ms > 86'400'000.0) {
        return error_reply(fmt::format("delay_ms: {} is out of range (0 to 86400000)", *ms), id);
      }
      std::optional<wire::RedundantPort> from;
      if (has("from")) {
        auto parsed = master_port(r, "from");
        if (!parsed) return fail(parsed.error());
        from = *parsed;
      }
      change = fault::port_delay(
          *port, std::chrono::nanoseconds(static_cast<std::int64_t>(std::llround(*ms * 1e6))),
          from);
    }
    if (change) ECAT_CHECK(server.inject(*change));
    const auto info = server.fault_info();
    if (info.ring.empty()) {
      return error_reply("ring: the segment has no second master port (serve it redundantly)", id);
    }
    Json out = ok_reply(id);
    out["ring"] = info.ring;
    return reply(out);
  }
  if (op == "hotconnect") {
    ECAT_CHECK(r.keys({"op", "id", "group", "plugged"}));
    auto group = r.text("group");
    if (!group) return fail(group.error());
    auto plugged = r.boolean("plugged");
    if (!plugged) return fail(plugged.error());
    ECAT_CHECK(server.plug(*group, *plugged));
    return reply(ok_reply(id));
  }
  if (op == "memory.read") {
    ECAT_CHECK(r.keys({"op", "id", "slave", "address", "length"}));
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto address = r.integer("address", 0, 0xFFFF);
    if (!address) return fail(address.error());
    auto length = r.integer("length", 1, 4096);
    if (!length) return fail(length.error());
    auto bytes = server.read_memory(*slave, static_cast<std::uint32_t>(*address),
                                    static_cast<std::size_t>(*length));
    if (!bytes) return fail(bytes.error());
    Json out = ok_reply(id);
    out["bytes"] = hex_bytes(*bytes);
    return reply(out);
  }
#undef ECAT_CHECK
  std::string known;
  for (auto k : kOps)
    known += (known.empty() ? "" : ", ") + std::string(k);
  return error_reply(fmt::format("op: unknown op '{}' (known: {})", op, known), id);
}

}  // namespace

std::string status_json(const SimStatus& st) {
  Json out{{"ok", true}};
  add_status(out, st);
  return tree::dump_json(out);
}

std::string handle_control_request(SimServer& server, std::string_view request,
                                   const RedundantPorts* redundant) {
  while (!request.empty() && (request.back() == '\n' || request.back() == '\r')) {
    request.remove_suffix(1);
  }
  if (request.size() > kMaxControlLine) {
    return error_reply(fmt::format("request: longer than {} bytes", kMaxControlLine));
  }
  auto parsed = tree::parse_json(request);
  if (!parsed) return error_reply(fmt::format("request: {}", parsed.error().message()));
  if (!parsed->is_mapping()) {
    return error_reply(
        fmt::format("request: expected a JSON object, found {}", tree::type_name(*parsed)));
  }
  RequestId id;
  if (const SpecNode* id_node = parsed->find("id")) {
    if (!id_node->is_scalar() && !id_node->is_null()) {
      return error_reply("id: expected a string or a number");
    }
    id = id_value(*id_node);
  }
  const SpecNode* op = parsed->find("op");
  if (op == nullptr) return error_reply("op: missing (e.g. {\"op\":\"status\"})", id);
  if (!op->is_scalar()) return error_reply("op: expected a string", id);
  return dispatch(server, redundant, RequestReader(*parsed), op->text, id);
}

// ---- The socket -----------------------------------------------------------------------------

struct ControlServer::Impl {
  std::unique_ptr<ipc::LineServer> server;
};

ControlServer::ControlServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

ControlServer::~ControlServer() {
  stop();
}

const std::string& ControlServer::path() const noexcept {
  return impl_->server->path();
}

Result<std::unique_ptr<ControlServer>> ControlServer::start(SimServer& server, std::string path,
                                                            const RedundantPorts* redundant) {
  auto impl = std::make_unique<Impl>();
  // Owner only (the default mode): the channel can power-cycle slaves and inject faults.
  auto started = ipc::LineServer::start(
      std::move(path),
      [&server, redundant](std::string_view line, const ipc::Peer&) {
        return ipc::Reply{handle_control_request(server, line, redundant)};
      },
      [](std::string_view message) { return error_reply(message); },
      {.max_line = kMaxControlLine, .what = "simulator"});
  if (!started) return std::move(started).error();
  impl->server = std::move(*started);
  return std::unique_ptr<ControlServer>(new ControlServer(std::move(impl)));
}

void ControlServer::stop() {
  if (impl_ && impl_->server) impl_->server->stop();
}

std::string default_control_path() {
  return fmt::format("{}/ecat-sim-{}.sock", ipc::runtime_dir(), ::getpid());
}

Result<std::string> find_control_socket() {
  const auto alive = ipc::find_sockets("ecat-sim-");
  if (alive.size() == 1) return alive.front();
  std::string where = std::getenv("XDG_RUNTIME_DIR") != nullptr && *std::getenv("XDG_RUNTIME_DIR")
                          ? std::string(std::getenv("XDG_RUNTIME_DIR")) + " and /tmp"
                          : std::string("/tmp");
  if (alive.empty()) {
    return Error(Errc::not_found,
                 fmt::format("no running simulator found (no live ecat-sim-*.sock of yours in {}); "
                             "start "
                             "`ecat sim` or pass --control PATH",
                             where));
  }
  std::string list;
  for (const auto& p : alive)
    list += (list.empty() ? "" : ", ") + p;
  return Error(Errc::invalid_argument,
               fmt::format("several simulators are running ({}); pass --control PATH", list));
}

Result<std::string> control_call(const std::string& path, std::string_view request,
                                 std::chrono::milliseconds timeout) {
  return ipc::call(path, request, timeout, "simulator");
}

}  // namespace ecat::sim
