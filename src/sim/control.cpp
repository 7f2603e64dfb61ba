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

constexpr std::array<std::string_view, 13> kOps{
    "status",      "fault.inject", "fault.clear",  "fault.list",  "signals",
    "signal.get",  "signal.set",   "signal.clear", "power_cycle", "link",
    "memory.read", "profiles",     "ping"};

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
                         {"send_errors", c.send_errors},
                         {"receive_errors", c.receive_errors},
                         {"idle_advances", c.idle_advances},
                         {"datagrams", st.segment.datagrams},
                         {"exchanges", st.fault_stats.exchanges},
                         {"healthy_exchanges", st.fault_stats.healthy_exchanges},
                         {"responses_dropped", st.fault_stats.responses_dropped},
                         {"replies_altered", st.fault_stats.replies_altered}};
  out["faults"] = faults_json(st.faults);
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

std::string dispatch(SimServer& server, const RequestReader& r, const std::string& op,
                     const RequestId& id) {
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

std::string handle_control_request(SimServer& server, std::string_view request) {
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
  return dispatch(server, RequestReader(*parsed), op->text, id);
}

// ---- The socket -----------------------------------------------------------------------------

namespace {

constexpr std::size_t kMaxClients = 16;
constexpr std::size_t kMaxPendingOutput = 4u << 20;

Result<sockaddr_un> unix_address(const std::string& path) {
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  if (path.empty() || path.size() >= sizeof address.sun_path) {
    return Error(Errc::invalid_argument,
                 fmt::format("control socket path '{}' must be 1 to {} bytes long", path,
                             sizeof address.sun_path - 1));
  }
  std::memcpy(address.sun_path, path.data(), path.size());
  return address;
}

bool someone_listens(const std::string& path) {
  auto address = unix_address(path);
  if (!address) return false;
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  const bool ok = ::connect(fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address) == 0;
  ::close(fd);
  return ok;
}

}  // namespace

struct ControlServer::Impl {
  struct Client {
    int fd = -1;
    std::string input;
    std::string output;
    bool closing = false;  // close once the output is flushed
  };

  SimServer* server = nullptr;
  std::string path;
  int listen_fd = -1;
  int wake[2] = {-1, -1};
  std::thread thread;
  std::atomic<bool> stopping{false};
  std::vector<Client> clients;

  ~Impl() {
    for (auto& c : clients)
      ::close(c.fd);
    if (listen_fd >= 0) ::close(listen_fd);
    for (int fd : wake) {
      if (fd >= 0) ::close(fd);
    }
  }

  void flush(Client& c) {
    while (!c.output.empty()) {
      const ssize_t n = ::send(c.fd, c.output.data(), c.output.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
      if (n > 0) {
        c.output.erase(0, static_cast<std::size_t>(n));
        continue;
      }
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
      c.output.clear();
      c.closing = true;
      c.input.clear();
      return;
    }
  }

  // Returns false when the client is gone.
  bool read_client(Client& c) {
    char chunk[4096];
    const ssize_t n = ::recv(c.fd, chunk, sizeof chunk, MSG_DONTWAIT);
    if (n == 0) return false;
    if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
    if (c.closing) return true;
    c.input.append(chunk, static_cast<std::size_t>(n));
    std::size_t start = 0;
    while (true) {
      const auto newline = c.input.find('\n', start);
      if (newline == std::string::npos) break;
      const std::string_view line(c.input.data() + start, newline - start);
      if (!line.empty() && line.find_first_not_of(" \t\r") != std::string_view::npos) {
        c.output += handle_control_request(*server, line);
        c.output += '\n';
      }
      start = newline + 1;
    }
    c.input.erase(0, start);
    if (c.input.size() > kMaxControlLine) {
      c.output +=
          error_reply(fmt::format("request: line longer than {} bytes; closing", kMaxControlLine));
      c.output += '\n';
      c.input.clear();
      c.closing = true;
    }
    if (c.output.size() > kMaxPendingOutput) return false;  // a client that never reads
    return true;
  }

  void run() {
    std::vector<pollfd> fds;
    while (!stopping.load()) {
      fds.clear();
      fds.push_back({wake[0], POLLIN, 0});
      fds.push_back({listen_fd, POLLIN, 0});
      for (const auto& c : clients) {
        short events = POLLIN;
        if (!c.output.empty()) events |= POLLOUT;
        fds.push_back({c.fd, events, 0});
      }
      if (::poll(fds.data(), fds.size(), -1) < 0) {
        if (errno == EINTR) continue;
        break;
      }
      if (fds[0].revents != 0) break;
      if ((fds[1].revents & POLLIN) != 0) {
        const int fd = ::accept4(listen_fd, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
        if (fd >= 0) {
          if (clients.size() >= kMaxClients) {
            const std::string busy =
                error_reply(fmt::format("too many control clients (at most {})", kMaxClients)) +
                "\n";
            (void)::send(fd, busy.data(), busy.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
            ::close(fd);
          } else {
            clients.push_back(Client{fd, {}, {}, false});
          }
        }
      }
      // fds[2 + i] belongs to clients[i] as they were before accepting.
      const std::size_t polled = fds.size() - 2;
      std::vector<std::size_t> gone;
      for (std::size_t i = 0; i < polled; ++i) {
        Client& c = clients[i];
        const short revents = fds[2 + i].revents;
        bool alive = true;
        if ((revents & POLLIN) != 0) alive = read_client(c);
        if (alive && (revents & (POLLERR | POLLNVAL)) != 0) alive = false;
        if (alive && (revents & POLLHUP) != 0 && (revents & POLLIN) == 0) alive = false;
        if (alive) flush(c);
        if (alive && c.closing && c.output.empty()) alive = false;
        if (!alive) gone.push_back(i);
      }
      for (auto it = gone.rbegin(); it != gone.rend(); ++it) {
        ::close(clients[*it].fd);
        clients.erase(clients.begin() + static_cast<std::ptrdiff_t>(*it));
      }
    }
  }
};

ControlServer::ControlServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

ControlServer::~ControlServer() {
  stop();
}

const std::string& ControlServer::path() const noexcept {
  return impl_->path;
}

Result<std::unique_ptr<ControlServer>> ControlServer::start(SimServer& server, std::string path) {
  auto address = unix_address(path);
  if (!address) return std::move(address).error();
  struct stat info {};
  if (::lstat(path.c_str(), &info) == 0) {
    if (!S_ISSOCK(info.st_mode)) {
      return Error(Errc::busy,
                   fmt::format("control socket path '{}' exists and is not a socket", path));
    }
    if (someone_listens(path)) {
      return Error(Errc::busy, fmt::format("another simulator already listens on '{}'", path));
    }
    ::unlink(path.c_str());
  }
  auto impl = std::make_unique<Impl>();
  impl->server = &server;
  impl->path = path;
  impl->listen_fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (impl->listen_fd < 0) {
    return Error(Errc::io_error, fmt::format("control socket: {}", std::strerror(errno)));
  }
  // Owner only: the channel can power-cycle slaves and inject faults.
  const mode_t old_mask = ::umask(0077);
  const int bound =
      ::bind(impl->listen_fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address);
  const int bind_errno = errno;
  ::umask(old_mask);
  if (bound != 0) {
    return Error(
        bind_errno == EACCES ? Errc::permission_denied : Errc::io_error,
        fmt::format("cannot bind the control socket '{}': {}", path, std::strerror(bind_errno)));
  }
  if (::listen(impl->listen_fd, 8) != 0 || ::pipe2(impl->wake, O_CLOEXEC | O_NONBLOCK) != 0) {
    const int err = errno;
    ::unlink(path.c_str());
    return Error(Errc::io_error, fmt::format("control socket '{}': {}", path, std::strerror(err)));
  }
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->run(); });
  return std::unique_ptr<ControlServer>(new ControlServer(std::move(impl)));
}

void ControlServer::stop() {
  if (!impl_ || !impl_->thread.joinable()) return;
  impl_->stopping = true;
  const char byte = 1;
  (void)!::write(impl_->wake[1], &byte, 1);
  impl_->thread.join();
  ::unlink(impl_->path.c_str());
}

std::string default_control_path() {
  const char* runtime = std::getenv("XDG_RUNTIME_DIR");
  const std::string dir = runtime != nullptr && *runtime != '\0' ? runtime : "/tmp";
  return fmt::format("{}/ecat-sim-{}.sock", dir, ::getpid());
}

Result<std::string> find_control_socket() {
  std::vector<std::string> dirs;
  if (const char* runtime = std::getenv("XDG_RUNTIME_DIR"); runtime != nullptr && *runtime) {
    dirs.emplace_back(runtime);
  }
  dirs.emplace_back("/tmp");
  std::vector<std::string> alive;
  for (const auto& dir : dirs) {
    std::error_code ec;
    for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (name.rfind("ecat-sim-", 0) != 0 || name.size() < 5 ||
          name.substr(name.size() - 5) != ".sock") {
        continue;
      }
      const std::string path = it->path().string();
      // Only this user's own sockets: another user's simulator (or a socket planted in /tmp under
      // a matching name) is never talked to unless named with --control.
      struct stat st {};
      if (::lstat(path.c_str(), &st) != 0 || !S_ISSOCK(st.st_mode) || st.st_uid != ::geteuid()) {
        continue;
      }
      if (std::find(alive.begin(), alive.end(), path) == alive.end() && someone_listens(path)) {
        alive.push_back(path);
      }
    }
  }
  if (alive.size() == 1) return alive.front();
  std::string where;
  for (const auto& d : dirs)
    where += (where.empty() ? "" : " and ") + d;
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
  auto address = unix_address(path);
  if (!address) return std::move(address).error();
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return Error(Errc::io_error, fmt::format("socket: {}", std::strerror(errno)));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&*address), sizeof *address) != 0) {
    const int err = errno;
    return Error(err == ENOENT || err == ECONNREFUSED ? Errc::not_found : Errc::io_error,
                 fmt::format("cannot reach the simulator at '{}': {}", path, std::strerror(err)));
  }
  std::string line(request);
  while (!line.empty() && (line.back() == '\n' || line.back() == '\r'))
    line.pop_back();
  if (line.find('\n') != std::string::npos) {
    return Error(Errc::invalid_argument, "a control request is one line");
  }
  line += '\n';
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  const auto remaining_ms = [&] {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    return static_cast<int>(std::max<std::int64_t>(0, left.count()));
  };
  for (std::size_t sent = 0; sent < line.size();) {
    const ssize_t n = ::send(fd, line.data() + sent, line.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return Error(Errc::io_error, fmt::format("sending to '{}': {}", path, std::strerror(errno)));
    }
    sent += static_cast<std::size_t>(n);
  }
  std::string reply;
  char chunk[8192];
  while (true) {
    pollfd p{fd, POLLIN, 0};
    const int ready = ::poll(&p, 1, remaining_ms());
    if (ready < 0 && errno == EINTR) continue;
    if (ready <= 0) {
      return Error(Errc::timeout, fmt::format("no reply from the simulator at '{}' within {} ms",
                                              path, timeout.count()));
    }
    const ssize_t n = ::recv(fd, chunk, sizeof chunk, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      return Error(Errc::closed, fmt::format("the simulator at '{}' closed the connection", path));
    }
    reply.append(chunk, static_cast<std::size_t>(n));
    if (const auto newline = reply.find('\n'); newline != std::string::npos) {
      reply.resize(newline);
      return reply;
    }
    if (reply.size() > (64u << 20)) {
      return Error(Errc::malformed, "the simulator's reply is longer than 64 MiB");
    }
  }
}

}  // namespace ecat::sim
