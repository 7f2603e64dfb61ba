// Opening "whatever the master talks to" from a one-line spec: a real link (raw:IFACE,
// udp:HOST:PORT — delegated to ecat::link::open_link) or the built-in simulator (sim:RING.yaml),
// which runs in the caller's process behind a function link: the master's send() processes the
// frame at once, so runs are deterministic and need neither privileges nor threads.
//
// This lives in the simulator layer because the link layer must not depend on it.
#pragma once

#include <memory>
#include <string_view>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::sim {

struct Backend {
  std::unique_ptr<link::Link> link;
  // The in-process simulator behind `link` for "sim:" specs (null otherwise): inject faults,
  // set inputs, read status. The link keeps it alive too.
  std::shared_ptr<SimServer> simulator;
};

// Accepted specs: sim:RING.yaml, plus everything ecat::link::open_link accepts. Errors name the
// spec; ring file errors keep their file:line: key form.
Result<Backend> open_backend(std::string_view spec);

}  // namespace ecat::sim
