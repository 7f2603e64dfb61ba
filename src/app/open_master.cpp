#include <utility>

#include <fmt/format.h>

#include <ecat/app/open_master.hpp>
#include <ecat/sim/backend.hpp>
#include <ecat/sim/ring.hpp>

namespace ecat {

namespace {

// What the master talks to: the caller's choice, else the file's `master: backend:`, else the
// file's own simulated ring (the order `ecat run` uses).
Result<std::string> backend_spec(const std::string& ring_file, const master::MasterConfig& config,
                                 const OpenMasterOptions& options) {
  if (!options.backend.empty()) return options.backend;
  if (!config.backend.empty()) return config.backend;
  auto ring = sim::load_ring(ring_file);
  if (!ring) return std::move(ring).error();
  if (ring->slaves.empty()) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: names no backend (master: backend: raw:IFACE, udp:HOST:PORT or "
                             "sim:RING.yaml) and has no simulator section to run instead",
                             ring_file));
  }
  return "sim:" + ring_file;
}

}  // namespace

Result<std::unique_ptr<master::Master>> open_master(const std::string& ring_file,
                                                    OpenMasterOptions options) {
  const auto failed = [&](const Error& error, std::string_view what) {
    return error.context(fmt::format("starting a master from {}: {}", ring_file, what));
  };
  auto config = master::load_master_config(ring_file);
  if (!config) return failed(config.error(), "reading its master sections");
  auto spec = backend_spec(ring_file, *config, options);
  if (!spec) return failed(spec.error(), "choosing the backend");
  if (options.configure) options.configure(*config);
  auto backend = sim::open_backend(*spec);
  if (!backend) return failed(backend.error(), fmt::format("opening backend {}", *spec));
  auto master = std::make_unique<master::Master>();
  if (auto started = master->start(std::move(backend->link), std::move(*config)); !started) {
    return failed(started.error(), fmt::format("starting on backend {}", *spec));
  }
  return master;
}

}  // namespace ecat
