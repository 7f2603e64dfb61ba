#include "session_view.hpp"

#include <string>

#include <fmt/format.h>

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

json slave_json(const master::SlaveInfo& info) {
  json j{{"position", info.position}, {"station", info.station},
         {"name", info.name},         {"state", std::string(to_string(info.state))},
         {"driver", info.driver},     {"device", info.device_name}};
  if (info.identity) {
    j["identity"] = {{"vendor_id", info.identity->vendor_id},
                     {"product_code", info.identity->product_code},
                     {"revision", info.identity->revision},
                     {"serial", info.identity->serial}};
  } else {
    j["identity"] = nullptr;
  }
  j["ports"] = json::array();
  if (info.dl_status) {
    for (const auto& port : info.dl_status->ports) {
      j["ports"].push_back({{"link", port.physical_link},
                            {"loop_closed", port.loop_closed},
                            {"communication", port.communication}});
    }
  }
  if (info.configuration_error) j["configuration_error"] = *info.configuration_error;
  j["signals"] = json::array();
  for (const auto& sig : info.signals)
    j["signals"].push_back(sig.name);
  return j;
}

json status_json(master::Master& master) {
  json out;
  out["state"] = std::string(to_string(master.state()));
  out["slaves"] = json::array();
  for (const auto& s : master.slaves()) {
    auto slave = master.slave(s.name);
    if (slave) out["slaves"].push_back(slave_json((*slave)->info()));
  }
  out["domains"] = json::array();
  for (const auto& d : master.domains()) {
    out["domains"].push_back({{"id", d.id},
                              {"state", d.state},
                              {"period_ns", d.period.count()},
                              {"image_size", d.image_size},
                              {"expected_wkc", d.expected_wkc},
                              {"cycles", d.cycles},
                              {"misses", d.total_misses},
                              {"healthy", d.healthy}});
  }
  if (auto dc = master.dc_status()) {
    out["dc"] = {{"locked", dc->locked},
                 {"reference_station", dc->reference_station},
                 {"max_difference_ns", dc->max_difference_ns},
                 {"phase_error_ns", dc->phase_error_ns},
                 {"phase_target_ns", dc->phase_target_ns},
                 {"follows_reference", dc->follows_reference},
                 {"phase_settled", dc->phase_settled},
                 {"cycle_rate_ppm", dc->cycle_rate_ppm},
                 {"reference_drift_ppm", dc->reference_drift_ppm},
                 {"lock_count", dc->lock_count},
                 {"unlock_count", dc->unlock_count}};
  } else {
    out["dc"] = {{"error", dc.error().message()}};
  }
  return out;
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
