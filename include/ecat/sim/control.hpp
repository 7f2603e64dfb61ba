// The simulator's control channel: a Unix stream socket carrying one JSON request per line and
// one JSON reply per line, for `ecat sim status|fault|set` and for test harnesses in any
// language. docs/RING-FILE.md lists the requests; faults use the same vocabulary as ring files.
//
//   -> {"op":"fault.inject","fault":{"kind":"disconnect","slave":"outputs","next":30}}
//   <- {"ok":true,"description":"next 30 exchanges disconnect outputs"}
//   -> {"op":"signal.set","slave":"inputs","signal":"channel_1","value":1}
//   <- {"ok":true}
//   -> {"op":"nonsense"}
//   <- {"ok":false,"error":"op: unknown op 'nonsense' (known: ...)"}
//
// Any input gets a reply (never a crash); lines longer than kMaxControlLine are refused and the
// connection is closed. A request may carry "id" (any scalar), which the reply echoes.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::sim {

constexpr std::size_t kMaxControlLine = 64 * 1024;

// Executes one request against `server` and returns the reply (JSON, without newline). With
// `redundant` (the server's second master port, which must outlive the call), the status reply
// also carries the two ports' counters and cabling ("redundant").
std::string handle_control_request(SimServer& server, std::string_view request,
                                   const RedundantPorts* redundant = nullptr);

// The status reply as `{"ok":true,...}` (what {"op":"status"} returns).
std::string status_json(const SimStatus& status);

// Serves the control channel on a Unix socket at `path` on its own thread. An existing socket
// file nobody listens on is replaced; Errc::busy when another process listens there.
class ControlServer {
 public:
  // `redundant`, when given, must outlive the ControlServer (see handle_control_request).
  static Result<std::unique_ptr<ControlServer>> start(SimServer& server, std::string path,
                                                      const RedundantPorts* redundant = nullptr);
  ~ControlServer();  // stops and removes the socket file
  ControlServer(const ControlServer&) = delete;
  ControlServer& operator=(const ControlServer&) = delete;

  const std::string& path() const noexcept;
  void stop();

  struct Impl;

 private:
  explicit ControlServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// $XDG_RUNTIME_DIR/ecat-sim-<pid>.sock, or /tmp/ecat-sim-<pid>.sock without XDG_RUNTIME_DIR.
std::string default_control_path();
// The control socket of the one running simulator found in $XDG_RUNTIME_DIR and /tmp; an error
// naming the candidates when there are none or several.
Result<std::string> find_control_socket();
// Sends one request line and returns the reply line.
Result<std::string> control_call(const std::string& path, std::string_view request,
                                 std::chrono::milliseconds timeout = std::chrono::seconds(5));

}  // namespace ecat::sim
