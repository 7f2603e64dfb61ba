// Local control endpoints: a Unix stream socket carrying one request per line and one reply per
// line (JSON by convention, but this layer does not look inside). The simulator's control channel
// (sim/control.hpp) and a master's control endpoint (master/control_endpoint.hpp) are both served
// by a LineServer; `ecat` and test harnesses in any language talk to them with call() or a
// LineClient.
//
//   auto server = ipc::LineServer::start("/run/user/1000/ecat-master-line1.sock",
//                                        [](std::string_view line, const ipc::Peer& peer) {
//                                          return ipc::Reply{answer(line)};
//                                        },
//                                        error_json, {.mode = 0660});
//   auto reply = ipc::call(path, R"({"op":"status"})");
//
// Bad input never takes the server down: a line longer than the limit gets an error reply and the
// connection is closed; a client that stops reading is dropped once its pending output passes a
// bound; connections beyond the limit are told so and closed. A reply may turn its connection into
// a follower: it then receives every line published (an event stream) until it closes.
//
// Why our own code: the socket handling is a page of poll(2) with bounds that matter here
// (per-line and per-client limits, peer credentials, followers); Debian's candidates (asio,
// libuv, libevent) would add a dependency and an event model of their own for little less code.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>

namespace ecat::ipc {

inline constexpr std::size_t kMaxLine = 64 * 1024;

// Who sent a request (SO_PEERCRED, taken when the connection was accepted).
struct Peer {
  std::int64_t pid = -1;
  std::uint32_t uid = 0;
  std::uint32_t gid = 0;
  std::uint64_t connection = 0;  // numbers the server's connections from 1
};

struct Reply {
  std::string line;     // the reply, without its newline
  bool follow = false;  // from now on the connection also gets every published line
};

struct LineServerOptions {
  // Permissions of the socket file (who may connect). Owner only by default: an endpoint can
  // change what the process does.
  std::uint32_t mode = 0600;
  std::size_t max_clients = 16;
  std::size_t max_line = kMaxLine;
  // A client whose unsent output grows beyond this (it does not read) is dropped.
  std::size_t max_pending_output = 4u << 20;
  // Names the endpoint in errors: "another simulator already listens on '...'".
  std::string what = "endpoint";
};

class LineServer {
 public:
  // Called on the server's thread, one request at a time.
  using Handler = std::function<Reply(std::string_view line, const Peer& peer)>;
  // Formats the server's own refusals (line too long, too many clients) as a reply line.
  using ErrorFormatter = std::function<std::string(std::string_view message)>;

  // Serves `path`. An existing socket file nobody listens on is replaced; Errc::busy when another
  // process listens there or the path is not a socket; Errc::permission_denied when the folder
  // may not be written.
  static Result<std::unique_ptr<LineServer>> start(std::string path, Handler handler,
                                                   ErrorFormatter errors,
                                                   LineServerOptions options = {});
  ~LineServer();  // stops and removes the socket file
  LineServer(const LineServer&) = delete;
  LineServer& operator=(const LineServer&) = delete;

  const std::string& path() const noexcept;
  // Queues `line` for every follower; any thread. Never blocks on a client.
  void publish(std::string line);
  std::size_t followers() const noexcept;
  void stop();

  struct Impl;

 private:
  explicit LineServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Whether a process accepts connections on the socket at `path`.
bool someone_listens(const std::string& path);

// $XDG_RUNTIME_DIR, or /tmp without it.
std::string runtime_dir();

// The live sockets of this user named `<prefix>*.sock` in $XDG_RUNTIME_DIR and /tmp (another
// user's, or a file planted under a matching name, is never listed).
std::vector<std::string> find_sockets(std::string_view prefix);

// Sends one request line and returns the reply line. `what` names the peer in errors ("cannot
// reach the simulator at ...").
Result<std::string> call(const std::string& path, std::string_view request,
                         std::chrono::milliseconds timeout = std::chrono::seconds(5),
                         std::string_view what = "endpoint");

// A connection kept open: for streams (a follower) and several requests in a row.
class LineClient {
 public:
  static Result<LineClient> connect(const std::string& path, std::string_view what = "endpoint");
  LineClient(LineClient&& other) noexcept;
  LineClient& operator=(LineClient&& other) noexcept;
  LineClient(const LineClient&) = delete;
  LineClient& operator=(const LineClient&) = delete;
  ~LineClient();

  Result<void> send(std::string_view line);
  // The next line, without its newline; nullopt when none came within `timeout`; Errc::closed
  // when the peer closed the connection.
  Result<std::optional<std::string>> read_line(std::chrono::milliseconds timeout);
  // send + read_line, Errc::timeout when no reply came.
  Result<std::string> request(std::string_view line,
                              std::chrono::milliseconds timeout = std::chrono::seconds(5));

 private:
  LineClient(int fd, std::string path, std::string what);
  int fd_ = -1;
  std::string path_;
  std::string what_;
  std::string buffer_;
};

}  // namespace ecat::ipc
