#include "session_view.hpp"

#include <string>

#include <fmt/format.h>

#include <ecat/sim/backend.hpp>
#include <ecat/sim/ring.hpp>

#include "master/json_view.hpp"

namespace ecat::tool {
namespace {

using nlohmann::json;

std::string identity_text(const master::SlaveInfo& info) {
  if (!info.identity) return "-";
  return fmt::format("{:08x}:{:08x} rev {:08x}", info.identity->vendor_id,
                     info.identity->product_code, info.identity->revision);
}

// "0:up 1:up 2:- 3:-": which ports have a link (communication established).
std::string ports_text(const master::SlaveInfo& info) {
  if (!info.dl_status) return "-";
  std::string out;
  for (std::size_t p = 0; p < info.dl_status->ports.size(); ++p) {
    if (!out.empty()) out += ' ';
    const auto& port = info.dl_status->ports[p];
    out += fmt::format("{}:{}", p, port.communication ? "up" : port.physical_link ? "link" : "-");
  }
  return out;
}

}  // namespace

void print_slaves(master::Master& master, bool with_signals) {
  fmt::print("{:>3}  {:<6}  {:<12} {:<7} {:<10} {:<34} {:<19} {}\n", "pos", "station", "name",
             "state", "driver", "identity", "ports", "device");
  for (const auto& s : master.slaves()) {
    auto slave = master.slave(s.name);
    if (!slave) continue;
    auto info = (*slave)->info();
    fmt::print("{:>3}  0x{:04x}  {:<12} {:<7} {:<10} {:<34} {:<19} {}\n", info.position,
               info.station, info.name, to_string(info.state),
               info.driver.empty() ? "-" : info.driver, identity_text(info), ports_text(info),
               info.device_name);
    if (info.configuration_error) fmt::print("       ! {}\n", *info.configuration_error);
    if (with_signals && !info.signals.empty()) {
      std::string names;
      for (const auto& sig : info.signals) {
        if (!names.empty()) names += ' ';
        names += sig.name;
      }
      fmt::print("       signals: {}\n", names);
    }
  }
}

void print_domains(master::Master& master) {
  for (const auto& d : master.domains()) {
    fmt::print(
        "domain {}: {} every {} us, {} bytes at 0x{:08x}, expected wkc {}, {} cycles, {} "
        "missed, {}\n",
        d.id, d.state, d.period.count() / 1000, d.image_size, d.logical_base, d.expected_wkc,
        d.cycles, d.total_misses, d.healthy ? "healthy" : "unhealthy");
  }
}

void print_dc(master::Master& master) {
  auto dc = master.dc_status();
  if (!dc) {
    fmt::print("distributed clocks: {}\n", dc.error().message());
    return;
  }
  auto reference = master.reference_clock();
  fmt::print(
      "distributed clocks: {}, reference {} (0x{:04x}), {} DC slaves, max |difference| {} "
      "ns, {} lock(s) / {} loss(es)\n",
      dc->locked ? "locked" : "NOT locked", reference ? reference->slave : "?",
      dc->reference_station, dc->slaves.size(), dc->max_difference_ns, dc->lock_count,
      dc->unlock_count);
  if (dc->follows_reference) {
    fmt::print(
        "  cycle follows the reference ({}): rate {:+.1f} ppm, frames {} us before SYNC0, "
        "phase error {} ns (max {} ns since settled), reference drift {:+.1f} ppm\n",
        dc->phase_settled ? "settled" : "settling", dc->cycle_rate_ppm, -dc->phase_target_ns / 1000,
        dc->phase_error_ns, dc->max_abs_phase_error_ns, dc->reference_drift_ppm);
  } else {
    fmt::print(
        "  cycle free-running against the reference: phase {} ns, reference drift {:+.1f} "
        "ppm\n",
        dc->phase_ns, dc->reference_drift_ppm);
  }
}

nlohmann::ordered_json slave_json(const master::SlaveInfo& info) {
  return master::detail::slave_json(info);
}

nlohmann::ordered_json status_json(master::Master& master) {
  return master::detail::status_json(master);
}

std::optional<Setup> prepare(const std::string& ring_file, const std::string& backend, bool dynamic,
                             const std::string& pcap) {
  Setup setup;
  std::string spec = backend;
  if (!ring_file.empty()) {
    ecat::master::ConfigFileInfo file_info;  // a ring file or an ENI
    auto config = ecat::master::load_master_config(ring_file, &file_info);
    if (!config) {
      fmt::print(stderr, "ecat: {}\n", config.error().describe());
      return std::nullopt;
    }
    if (!file_info.eni_report.empty()) {
      fmt::print(stderr, "ecat: {} is an ENI; what of it ecat does not use:\n", ring_file);
      for (const auto& line : file_info.eni_report) {
        fmt::print(stderr, "  {}\n", line);
      }
    }
    setup.config = std::move(*config);
    if (spec.empty()) spec = setup.config.backend;
    if (spec.empty() && file_info.eni) {
      fmt::print(stderr,
                 "ecat: {} is an ENI, which has no simulator section: give the master's link with "
                 "--backend\n",
                 ring_file);
      return std::nullopt;
    }
    if (spec.empty()) {
      auto ring = ecat::sim::load_ring(ring_file);
      if (!ring) {
        fmt::print(stderr, "ecat: {}\n", ring.error().describe());
        return std::nullopt;
      }
      if (ring->slaves.empty()) {
        fmt::print(stderr,
                   "ecat: {} has no simulator section: give the master's link with --backend\n",
                   ring_file);
        return std::nullopt;
      }
      spec = "sim:" + ring_file;
    }
  }
  if (spec.empty()) {
    fmt::print(stderr, "ecat: give a ring file (a simulated ring) or --backend SPEC\n");
    return std::nullopt;
  }
  if (dynamic) {
    setup.config.slaves.clear();
    setup.config.domains.clear();
  }
  auto opened = ecat::sim::open_backend(spec);
  if (!opened) {
    fmt::print(stderr, "ecat: {}\n", opened.error().describe());
    return std::nullopt;
  }
  setup.link = std::move(opened->link);
  setup.link_name = spec;
  if (!pcap.empty()) {
    setup.capture = LiveCapture::open(pcap, spec);
    if (!setup.capture) return std::nullopt;
    setup.link = setup.capture->wrap(std::move(setup.link));
  }
  return setup;
}

int report_failure(master::Master& master, const Error& error) {
  fmt::print(stderr, "ecat: the session did not get running: {}\n", error.describe());
  auto status = master.status();
  // Each slave that is not where the session wants it, with what it last reported.
  for (const auto& s : status.slaves) {
    if (s.startup_error) {
      fmt::print(stderr, "  slave {} ({}): not in PREOP: {}\n", s.name, to_string(s.state),
                 *s.startup_error);
    } else if (s.fault) {
      fmt::print(stderr, "  slave {} ({}): {}\n", s.name, to_string(s.state), *s.fault);
    }
  }
  for (const auto& f : status.activation_failures) {
    fmt::print(stderr, "  slave {}: {}\n", f.slave, f.error.describe());
  }
  if (status.last_failure) {
    fmt::print(stderr, "  last failure ({}): {}\n", status.last_failure->kind,
               status.last_failure->error.describe());
  }
  return 1;
}

}  // namespace ecat::tool
