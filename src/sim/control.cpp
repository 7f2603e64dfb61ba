#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <ecat/sim/control.hpp>
#include <ecat/sim/faults.hpp>

#include "sim/fault_spec.hpp"
#include "sim/spec_tree.hpp"

namespace ecat::sim {

namespace {

using detail::append_json_string;
using detail::SpecContext;
using detail::SpecNode;

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

std::string number(double value) {
  if (!std::isfinite(value)) return "null";
  if (value == std::floor(value) && std::fabs(value) < 1e15) {
    return fmt::format("{}", static_cast<std::int64_t>(value));
  }
  return fmt::format("{}", value);
}

void append_string_array(std::string& out, const std::vector<std::string>& items) {
  out += '[';
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (i != 0) out += ',';
    append_json_string(out, items[i]);
  }
  out += ']';
}

void append_faults(std::string& out, const FaultInfo& f) {
  out += "{\"active\":";
  append_string_array(out, f.active);
  out += ",\"queued\":[";
  for (std::size_t i = 0; i < f.queued.size(); ++i) {
    if (i != 0) out += ',';
    out += "{\"description\":";
    append_json_string(out, f.queued[i].description);
    out += fmt::format(",\"remaining\":{}}}", f.queued[i].remaining);
  }
  out += "],\"scheduled\":[";
  for (std::size_t i = 0; i < f.scheduled.size(); ++i) {
    const auto& s = f.scheduled[i];
    if (i != 0) out += ',';
    out += "{\"description\":";
    append_json_string(out, s.description);
    if (s.due_in_ns) out += fmt::format(",\"due_in_ns\":{}", *s.due_in_ns);
    if (!s.waiting_on.empty()) {
      out += ",\"waiting_on\":";
      append_json_string(out, s.waiting_on);
      out += fmt::format(",\"remaining\":{}", s.remaining);
    }
    out += fmt::format(",\"step\":{}}}", s.step);
  }
  out += fmt::format("],\"drop_responses\":{},\"wkc_offset\":{}", f.drop_responses, f.wkc_offset);
  out += ",\"command_wkc_offsets\":{";
  bool first = true;
  for (const auto& [command, delta] : f.command_wkc_offsets) {
    if (!first) out += ',';
    first = false;
    append_json_string(out, command);
    out += fmt::format(":{}", delta);
  }
  out += "},\"logical_wkc_offsets\":{";
  first = true;
  for (const auto& [slave, delta] : f.logical_wkc_offsets) {
    if (!first) out += ',';
    first = false;
    append_json_string(out, slave);
    out += fmt::format(":{}", delta);
  }
  out += "},\"disconnected\":";
  append_string_array(out, f.disconnected);
  out += ",\"links_down\":";
  append_string_array(out, f.links_down);
  out += '}';
}

std::string error_reply(std::string_view message, const std::string& id) {
  std::string out = "{\"ok\":false,";
  if (!id.empty()) out += "\"id\":" + id + ",";
  out += "\"error\":";
  append_json_string(out, message);
  out += '}';
  return out;
}

// {"ok":true[,"id":..]  — the caller appends fields and the closing brace.
std::string ok_open(const std::string& id) {
  std::string out = "{\"ok\":true";
  if (!id.empty()) out += ",\"id\":" + id;
  return out;
}

class RequestReader {
 public:
  explicit RequestReader(const SpecNode& root) : root_(root) {}

  Result<std::string> text(std::string_view key) const {
    auto node = detail::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return detail::to_text(c_, **node, key);
  }
  Result<std::int64_t> integer(std::string_view key, std::int64_t min, std::int64_t max) const {
    auto node = detail::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return detail::to_int(c_, **node, key, min, max);
  }
  Result<double> real(std::string_view key) const {
    auto node = detail::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return detail::to_double(c_, **node, key);
  }
  Result<bool> boolean(std::string_view key) const {
    auto node = detail::require(c_, root_, "", key);
    if (!node) return std::move(node).error();
    return detail::to_bool(c_, **node, key);
  }
  Result<void> keys(std::initializer_list<std::string_view> known) const {
    return detail::check_keys(c_, root_, "", known);
  }
  const SpecNode& root() const { return root_; }
  const SpecContext& context() const { return c_; }

 private:
  const SpecNode& root_;
  SpecContext c_{};
};

std::string dispatch(SimServer& server, const RequestReader& r, const std::string& op,
                     const std::string& id) {
  const auto fail = [&](const Error& e) { return error_reply(e.message(), id); };
#define ECAT_CHECK(expr)               \
  if (auto check_ = (expr); !check_) { \
    return fail(check_.error());       \
  }
  if (op == "ping") {
    ECAT_CHECK(r.keys({"op", "id"}));
    return ok_open(id) + "}";
  }
  if (op == "status") {
    ECAT_CHECK(r.keys({"op", "id"}));
    std::string out = status_json(server.status());
    // After "{\"ok\":true", where every other reply has its id.
    if (!id.empty()) out.insert(std::string_view("{\"ok\":true").size(), ",\"id\":" + id);
    return out;
  }
  if (op == "profiles") {
    ECAT_CHECK(r.keys({"op", "id"}));
    std::string out = ok_open(id) + ",\"profiles\":[";
    const auto profiles = device_profiles();
    for (std::size_t i = 0; i < profiles.size(); ++i) {
      if (i != 0) out += ',';
      out += "{\"name\":";
      append_json_string(out, profiles[i].name);
      out += ",\"description\":";
      append_json_string(out, profiles[i].description);
      out += '}';
    }
    return out + "]}";
  }
  if (op == "fault.inject") {
    ECAT_CHECK(r.keys({"op", "id", "fault"}));
    auto node = detail::require(r.context(), r.root(), "", "fault");
    if (!node) return fail(node.error());
    auto fault = detail::parse_fault_node(r.context(), **node, "fault");
    if (!fault) return fail(fault.error());
    ECAT_CHECK(server.inject(*fault));
    std::string out = ok_open(id) + ",\"description\":";
    append_json_string(out, describe(*fault));
    return out + "}";
  }
  if (op == "fault.clear") {
    ECAT_CHECK(r.keys({"op", "id"}));
    server.clear_faults();
    return ok_open(id) + "}";
  }
  if (op == "fault.list") {
    ECAT_CHECK(r.keys({"op", "id"}));
    std::string out = ok_open(id) + ",\"faults\":";
    append_faults(out, server.fault_info());
    return out + "}";
  }
  if (op == "signals") {
    ECAT_CHECK(r.keys({"op", "id", "slave"}));
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto signals = server.signals(*slave);
    if (!signals) return fail(signals.error());
    std::string out = ok_open(id) + ",\"signals\":[";
    for (std::size_t i = 0; i < signals->size(); ++i) {
      const auto& s = (*signals)[i];
      if (i != 0) out += ',';
      out += "{\"name\":";
      append_json_string(out, s.name);
      out += fmt::format(",\"direction\":\"{}\",\"type\":",
                         s.direction == SignalDirection::input ? "input" : "output");
      append_json_string(out, s.type);
      out += ",\"unit\":";
      append_json_string(out, s.unit);
      const auto value = server.signal(*slave, s.name);
      out += ",\"value\":" + (value ? number(*value) : std::string("null")) + "}";
    }
    return out + "]}";
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
      return ok_open(id) + ",\"value\":" + number(*value) + "}";
    }
    if (op == "signal.clear") {
      ECAT_CHECK(server.clear_input(*slave, *signal));
      return ok_open(id) + "}";
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
    return ok_open(id) + "}";
  }
  if (op == "power_cycle") {
    ECAT_CHECK(r.keys({"op", "id", "slave"}));
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    ECAT_CHECK(server.power_cycle(*slave));
    return ok_open(id) + "}";
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
      return ok_open(id) + "}";
    }
    auto slave = r.text("slave");
    if (!slave) return fail(slave.error());
    auto port = r.integer("port", 0, 3);
    if (!port) return fail(port.error());
    ECAT_CHECK(server.set_link(*slave, static_cast<std::uint8_t>(*port), *up));
    return ok_open(id) + "}";
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
    return ok_open(id) + ",\"bytes\":\"" + hex_bytes(*bytes) + "\"}";
  }
#undef ECAT_CHECK
  std::string known;
  for (auto k : kOps)
    known += (known.empty() ? "" : ", ") + std::string(k);
  return error_reply(fmt::format("op: unknown op '{}' (known: {})", op, known), id);
}

}  // namespace

std::string status_json(const SimStatus& st) {
  std::string out = "{\"ok\":true";
  out += fmt::format(",\"time_ns\":{},\"link\":", st.time_ns);
  append_json_string(out, st.link);
  out += ",\"slaves\":[";
  for (std::size_t i = 0; i < st.slaves.size(); ++i) {
    const auto& s = st.slaves[i];
    if (i != 0) out += ',';
    out += fmt::format("{{\"index\":{},\"name\":", s.index);
    append_json_string(out, s.name);
    out += ",\"profile\":";
    append_json_string(out, s.profile);
    out += fmt::format(
        ",\"vendor_id\":{},\"product_code\":{},\"revision\":{},\"station\":{},\"alias\":{},"
        "\"al_state\":\"{}\",\"al_error\":{},\"al_status_code\":{},\"dc\":{},"
        "\"links\":[{},{},{},{}]}}",
        s.vendor_id, s.product_code, s.revision, s.station, s.alias, wire::to_string(s.al_state),
        s.al_error, s.al_status_code, s.dc, s.links[0], s.links[1], s.links[2], s.links[3]);
  }
  const auto& c = st.counters;
  out += fmt::format(
      "],\"counters\":{{\"frames\":{},\"replies\":{},\"lost\":{},\"malformed\":{},"
      "\"delayed\":{},\"send_errors\":{},\"receive_errors\":{},\"idle_advances\":{},"
      "\"datagrams\":{},\"exchanges\":{},\"healthy_exchanges\":{},\"responses_dropped\":{},"
      "\"replies_altered\":{}}}",
      c.frames, c.replies, c.lost, c.malformed, c.delayed, c.send_errors, c.receive_errors,
      c.idle_advances, st.segment.datagrams, st.fault_stats.exchanges,
      st.fault_stats.healthy_exchanges, st.fault_stats.responses_dropped,
      st.fault_stats.replies_altered);
  out += ",\"faults\":";
  append_faults(out, st.faults);
  out += '}';
  return out;
}

std::string handle_control_request(SimServer& server, std::string_view request) {
  while (!request.empty() && (request.back() == '\n' || request.back() == '\r')) {
    request.remove_suffix(1);
  }
  if (request.size() > kMaxControlLine) {
    return error_reply(fmt::format("request: longer than {} bytes", kMaxControlLine), "");
  }
  auto tree = detail::parse_json(request);
  if (!tree) return error_reply(fmt::format("request: {}", tree.error().message()), "");
  if (!tree->is_mapping()) {
    return error_reply(
        fmt::format("request: expected a JSON object, found {}", detail::type_name(*tree)), "");
  }
  std::string id;
  if (const SpecNode* id_node = tree->find("id")) {
    if (!id_node->is_scalar() && !id_node->is_null()) {
      return error_reply("id: expected a string or a number", "");
    }
    if (id_node->is_null()) {
      id = "null";
    } else if (id_node->quoted) {
      id = detail::json_string(id_node->text);
    } else {
      id = id_node->text;  // a number or true/false, already valid JSON
    }
  }
  const SpecNode* op = tree->find("op");
  if (op == nullptr) return error_reply("op: missing (e.g. {\"op\":\"status\"})", id);
  if (!op->is_scalar()) return error_reply("op: expected a string", id);
  return dispatch(server, RequestReader(*tree), op->text, id);
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
      c.output += error_reply(
          fmt::format("request: line longer than {} bytes; closing", kMaxControlLine), "");
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
                error_reply(fmt::format("too many control clients (at most {})", kMaxClients), "") +
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
