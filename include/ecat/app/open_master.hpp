// Starting a master from a ring file in one call: the file's master sections
// (docs/MASTER-CONFIG.md) configure it, and the backend it names (`master: backend:` — raw:IFACE,
// udp:HOST:PORT, sim:RING.yaml — or, when it names none, the file's own `simulator:` section run
// in-process) is opened and handed to Master::start.
//
// This is the one place that knows both the master and the simulator: it sits in a layer of its
// own above both (CMakeLists.txt, ecat_layer(app)), since the master may not reach into the
// simulator nor the simulator into the master.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include <ecat/link/link.hpp>
#include <ecat/master/master.hpp>
#include <ecat/result.hpp>

namespace ecat {

struct OpenMasterOptions {
  // Replaces the file's `master: backend:` when not empty (what `ecat run --backend` does).
  std::string backend{};
  // Changes made to the configuration read from the file before the master starts (a domain's
  // on_cycle callback, the application's own drivers ...). Runs on the caller's thread.
  std::function<void(master::MasterConfig&)> configure{};
  // Wraps the opened backend's link before the master gets it (`ecat serve --pcap` puts a
  // link::RecordingLink around it). Runs on the caller's thread; must return a link.
  std::function<std::unique_ptr<link::Link>(std::unique_ptr<link::Link>)> wrap_link{};
};

// Reads `ring_file`, opens its backend and starts a master on it (idle -> discovering; returns
// at once: await_running / await_operational wait). Every error names the file: a missing or
// malformed file (with file:line), a file that names no backend and has no simulator section, a
// backend that does not open, a configuration Master::start refuses.
Result<std::unique_ptr<master::Master>> open_master(const std::string& ring_file,
                                                    OpenMasterOptions options = {});

}  // namespace ecat
