// A master's control endpoint: a local Unix socket (ipc/line_server.hpp) through which another
// process looks at a running master and, when the endpoint allows writes, changes what it does.
// `ecat <command> --attach NAME` speaks it; so can a script in any language:
//
//   $ echo '{"op":"status"}' | socat - UNIX-CONNECT:$XDG_RUNTIME_DIR/ecat-master-line1.sock
//   {"ok":true,"state":"operational",...}
//
// One JSON request per line, one JSON reply per line, always an object with "ok" first and the
// request's "id" echoed when it had one. Errors: {"ok":false,"error":"...","code":"not_found"}
// (code: the Errc name). Requests (docs/CONTROL.md has every field):
//   ping, status, slaves, slave {slave}, domains {data?}, domain.data {domain}, dc, counters
//   events.follow {kinds?}     -> the reply, then one line per event ({"event":...,"seq":...})
//   sdo.upload {slave, index, subindex, complete_access?}            -> {"data":"hex"}
//   sdo.list {slave}, sdo.describe {slave, index}
//   signal.read {slave, signal}
//   reg.read {slave, address, length}                                 -> {"data":"hex","wkc":1}
//   sii.read {slave}                                                  -> {"data":"hex"}
//   capture.frames {seconds?}   -> {"frames":[{"t_ns","steady_ns","direction","length","data"}]}
// Writes (refused with code permission_denied unless ControlEndpointConfig::allow_writes):
//   sdo.download {slave, index, subindex, data:"hex", complete_access?}
//   output.write {slave, signal, value}
//   state.request {state: "op"|"safeop"|"preop"}       (the session: activate / deactivate)
//   state.request {slave, state: "init"|"preop"|"safeop"|"op"|"bootstrap"}
//   reg.write {slave, address, data:"hex"}
//
// Acyclic work (SDOs, register reads) goes through the master's own mailboxes and bus, as the
// master's own acyclic traffic does: it never takes the cyclic exchange's frames. Requests are
// served one at a time on the endpoint's thread; a slow one (an SDO to a slave that does not
// answer) holds the others up to its time-out, never the master.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include <ecat/result.hpp>

namespace ecat::link {
class FrameRecorder;
}

namespace ecat::master {

class Master;

// Where an endpoint named `name` listens: `name` itself when it holds a '/', else
// $XDG_RUNTIME_DIR/ecat-master-<name>.sock (/tmp without XDG_RUNTIME_DIR).
std::string control_socket_path(std::string_view name);

// For --attach: the live endpoint NAME or PATH names; with an empty name, the one endpoint of
// this user that is running (an error lists them when there are several). Errc::not_found says
// where it looked.
Result<std::string> find_control_endpoint(std::string_view name);

// An error code as replies carry it: the Errc's name in snake case ("not_found", "sdo_abort").
std::string control_error_code(Errc code);

struct ControlAccess {
  bool allow_writes = false;
  // What "capture.frames" reads (ControlEndpointConfig::flight_recorder); empty: not_found.
  std::shared_ptr<const link::FrameRecorder> flight_recorder{};
};

// The reply (one JSON line, no newline) to one request. `follow` is set when the connection
// should receive the event stream from now on. Never throws; any input gets a reply.
std::string handle_control_request(Master& master, std::string_view request,
                                   const ControlAccess& access, bool* follow = nullptr);

}  // namespace ecat::master
