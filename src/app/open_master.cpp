#include <utility>

#include <fmt/format.h>

#include <ecat/app/open_master.hpp>
#include <ecat/log.hpp>
#include <ecat/sim/backend.hpp>
#include <ecat/sim/ring.hpp>

namespace ecat {

namespace {

// What the master talks to: the caller's choice, else the file's `master: backend:`, else the
// file's own simulated ring (the order `ecat run` uses).
Result<std::string> backend_spec(const std::string& ring_file, const master::MasterConfig& config,
                                 const OpenMasterOptions& options, bool eni) {
  if (!options.backend.empty()) return options.backend;
  if (!config.backend.empty()) return config.backend;
  if (eni) {
    return Error(Errc::invalid_argument,
                 fmt::format("{}: an ENI names no backend and has no simulator section: give the "
                             "backend (--backend raw:IFACE, udp:HOST:PORT or sim:RING.yaml)",
                             ring_file));
  }
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
  master::ConfigFileInfo file_info;  // a ring file or an ENI
  auto config = master::load_master_config(ring_file, &file_info);
  if (!config) return failed(config.error(), "reading its master sections");
  // What of an ENI ecat does not use: on the library's log (`ecat serve` shows it on stderr).
  for (const auto& line : file_info.eni_report) {
    ECAT_LOG(LogLevel::warn, "config", fmt::format("{}: not used: {}", ring_file, line));
  }
  auto spec = backend_spec(ring_file, *config, options, file_info.eni);
  if (!spec) return failed(spec.error(), "choosing the backend");
  if (options.configure) options.configure(*config);
  auto backend = sim::open_backend(*spec);
  if (!backend) return failed(backend.error(), fmt::format("opening backend {}", *spec));
  if (options.wrap_link) {
    backend->link = options.wrap_link(std::move(backend->link));
    if (!backend->link) {
      return failed(Error(Errc::internal, "wrap_link returned no link"),
                    fmt::format("opening backend {}", *spec));
    }
  }
  auto master = std::make_unique<master::Master>();
  if (auto started = master->start(std::move(backend->link), std::move(*config)); !started) {
    return failed(started.error(), fmt::format("starting on backend {}", *spec));
  }
  return master;
}

}  // namespace ecat
