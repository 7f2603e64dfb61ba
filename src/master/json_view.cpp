#include "master/json_view.hpp"

#include <string>

#include <fmt/format.h>

#include <ecat/master/dc.hpp>
#include <ecat/master/states.hpp>

namespace ecat::master::detail {

std::string hex(std::span<const std::uint8_t> bytes) {
  std::string out;
  out.reserve(bytes.size() * 2);
  for (const auto b : bytes)
    fmt::format_to(std::back_inserter(out), "{:02x}", b);
  return out;
}

namespace {

Json ports_json(const SlaveInfo& info, bool verbose) {
  Json ports = Json::array();
  if (!info.dl_status) return ports;
  for (const auto& port : info.dl_status->ports) {
    Json p{{"link", port.physical_link}, {"communication", port.communication}};
    if (verbose) p["loop_closed"] = port.loop_closed;
    ports.push_back(std::move(p));
  }
  return ports;
}

}  // namespace

Json slave_json(const SlaveInfo& info, bool verbose) {
  Json j{{"position", info.position},
         {"station", info.station},
         {"name", info.name},
         {"state", std::string(to_string(info.state))},
         {"target", std::string(to_string(info.target))},
         {"driver", info.driver},
         {"device", info.device_name}};
  if (info.identity) {
    j["identity"] = {{"vendor_id", info.identity->vendor_id},
                     {"product_code", info.identity->product_code},
                     {"revision", info.identity->revision},
                     {"serial", info.identity->serial}};
  } else {
    j["identity"] = nullptr;
  }
  j["ports"] = ports_json(info, verbose);
  if (info.al_status_code) j["al_status_code"] = *info.al_status_code;
  if (info.configuration_error) j["configuration_error"] = *info.configuration_error;
  if (info.fault) j["fault"] = *info.fault;
  if (info.startup_error) j["startup_error"] = *info.startup_error;
  if (!verbose) {
    j["signals"] = Json::array();
    for (const auto& sig : info.signals)
      j["signals"].push_back(sig.name);
    return j;
  }
  const auto& esc = info.esc;
  j["esc"] = {{"type", esc.type},
              {"revision", esc.revision},
              {"build", esc.build},
              {"fmmus", esc.fmmu_count},
              {"sync_managers", esc.sync_manager_count},
              {"ram_kib", esc.ram_size_kib},
              {"dc", esc.features.dc_supported},
              {"dc_64bit", esc.features.dc_64bit}};
  if (info.dl_status) {
    j["dl_status"] = {{"pdi_operational", info.dl_status->pdi_operational},
                      {"pdi_watchdog_ok", info.dl_status->pdi_watchdog_ok},
                      {"enhanced_link_detection", info.dl_status->enhanced_link_detection}};
  }
  j["mailbox"] = {{"present", info.has_mailbox}, {"coe", info.coe}};
  if (!info.mailbox_status_domain.empty()) {
    j["mailbox"]["status_domain"] = info.mailbox_status_domain;
    j["mailbox"]["status_fmmu"] = info.mailbox_status_fmmu;
  }
  j["attachments"] = Json::array();
  for (const auto& a : info.attachments) {
    j["attachments"].push_back({{"sync_manager", a.sync_manager},
                                {"direction", std::string(to_string(a.direction))},
                                {"domain", a.domain},
                                {"logical", a.logical_address},
                                {"physical", a.physical_address},
                                {"size", a.size},
                                {"fmmu", a.fmmu}});
  }
  j["signals"] = Json::array();
  for (const auto& sig : info.signals) {
    Json s{{"name", sig.name},
           {"direction", std::string(to_string(sig.direction))},
           {"type", std::string(to_string(sig.type))},
           {"sync_manager", sig.sync_manager},
           {"bit_offset", sig.bit_offset},
           {"bit_length", sig.bit_length}};
    if (sig.index != 0) s["object"] = fmt::format("0x{:04x}:{:02x}", sig.index, sig.subindex);
    if (!sig.unit.empty()) s["unit"] = sig.unit;
    j["signals"].push_back(std::move(s));
  }
  return j;
}

Json domain_json(const DomainSummary& d) {
  return Json{{"id", d.id},
              {"state", d.state},
              {"period_ns", d.period.count()},
              {"logical_base", d.logical_base},
              {"image_size", d.image_size},
              {"expected_wkc", d.expected_wkc},
              {"cycles", d.cycles},
              {"misses", d.total_misses},
              {"healthy", d.healthy}};
}

Json dc_json(Master& master) {
  auto dc = master.dc_status();
  if (!dc) return Json{{"error", dc.error().message()}};
  Json out{{"locked", dc->locked},
           {"reference_station", dc->reference_station},
           {"max_difference_ns", dc->max_difference_ns},
           {"phase_error_ns", dc->phase_error_ns},
           {"phase_target_ns", dc->phase_target_ns},
           {"follows_reference", dc->follows_reference},
           {"phase_settled", dc->phase_settled},
           {"cycle_rate_ppm", dc->cycle_rate_ppm},
           {"reference_drift_ppm", dc->reference_drift_ppm},
           {"lock_count", dc->lock_count},
           {"unlock_count", dc->unlock_count},
           {"slaves", dc->slaves.size()}};
  Json free_running = Json::array();
  for (const auto& s : dc->slaves)
    if (s.free_running) free_running.push_back(s.station);
  out["free_running"] = std::move(free_running);
  if (auto reference = master.reference_clock()) out["reference"] = reference->slave;
  return out;
}

Json counters_json(const MasterCounters& c) {
  Json out{{"frames_sent", c.frames_sent},
           {"frames_received", c.frames_received},
           {"frames_lost", c.frames_lost},
           {"transaction_timeouts", c.transaction_timeouts},
           {"retries", c.retries},
           {"realtime_expired", c.realtime_expired},
           {"cycle_deadlines_missed", c.cycle_deadlines_missed}};
  out["domains"] = Json::array();
  for (const auto& d : c.domains) {
    out["domains"].push_back({{"id", d.id},
                              {"cycles", d.cycles},
                              {"valid", d.valid},
                              {"wkc_mismatches", d.wkc_mismatches},
                              {"misses", d.misses}});
  }
  out["slaves"] = Json::array();
  for (const auto& s : c.slaves) {
    out["slaves"].push_back({{"name", s.name},
                             {"wkc_errors", s.wkc_errors},
                             {"mailbox_retries", s.mailbox_retries},
                             {"sdo_failures", s.sdo_failures}});
  }
  if (c.dc_max_difference_ns) out["dc_max_difference_ns"] = *c.dc_max_difference_ns;
  return out;
}

Json redundancy_json(const link::RedundancyStatus& r) {
  const auto port = [](const link::RedundantPortStatus& p) {
    return Json{{"name", p.name},
                {"healthy", p.healthy},
                {"frames_sent", p.frames_sent},
                {"frames_received", p.frames_received},
                {"reopens", p.reopens}};
  };
  Json out{{"topology", std::string(link::to_string(r.topology))},
           {"ring", std::string(link::to_string(r.ring))},
           {"primary", port(r.primary)},
           {"secondary", port(r.secondary)},
           {"ring_breaks", r.ring_breaks},
           {"ring_heals", r.ring_heals},
           {"merged", r.merged},
           {"lone_bounces", r.lone_bounces},
           {"merge_timeouts", r.merge_timeouts},
           {"late_halves", r.late_halves}};
  if (r.break_location) {
    const auto& b = *r.break_location;
    out["break"] = {
        {"where", std::string(link::to_string(b.where))},
        {"before",
         {{"position", b.before_position}, {"station", b.before_station}, {"port", b.before_port}}},
        {"after",
         {{"position", b.after_position}, {"station", b.after_station}, {"port", b.after_port}}},
        {"text", link::describe(b)}};
  } else {
    out["break"] = nullptr;
  }
  return out;
}

Json status_json(Master& master) {
  const MasterStatus st = master.status();
  Json out{{"state", std::string(to_string(st.state))},
           {"desired_target", std::string(to_string(st.desired_target))},
           {"link", st.link},
           {"slave_count", st.slave_count}};
  out["slaves"] = Json::array();
  for (const auto& s : st.slaves) {
    Json j{{"position", s.position},
           {"station", s.station},
           {"name", s.name},
           {"state", std::string(to_string(s.state))},
           {"target", std::string(to_string(s.target))}};
    if (s.fault) j["fault"] = *s.fault;
    if (s.startup_error) j["startup_error"] = *s.startup_error;
    out["slaves"].push_back(std::move(j));
  }
  out["domains"] = Json::array();
  for (const auto& d : st.domains)
    out["domains"].push_back(domain_json(d));
  out["activation_failures"] = Json::array();
  for (const auto& f : st.activation_failures) {
    Json j{{"slave", f.slave},
           {"wanted", std::string(wire::to_string(f.wanted))},
           {"error", f.error.describe()}};
    if (f.al_status_code) j["al_status_code"] = *f.al_status_code;
    out["activation_failures"].push_back(std::move(j));
  }
  out["runtime_faults"] = st.runtime_faults;
  if (!st.hot_connect.empty()) {
    Json groups = Json::array();
    for (const auto& g : st.hot_connect) {
      Json j{{"group", g.group},
             {"state", std::string(to_string(g.state))},
             {"slaves", g.slaves},
             {"appearances", g.appearances},
             {"losses", g.losses}};
      j["position"] = g.position ? Json(*g.position) : Json(nullptr);
      if (!g.detail.empty()) j["detail"] = g.detail;
      if (g.last_join) j["last_join_us"] = g.last_join->count() / 1000;
      groups.push_back(std::move(j));
    }
    out["hot_connect"] = std::move(groups);
    if (!st.hot_connect_refused.empty()) out["hot_connect_refused"] = st.hot_connect_refused;
  }
  if (st.last_failure) {
    out["last_failure"] = {{"kind", st.last_failure->kind},
                           {"error", st.last_failure->error.describe()}};
  } else {
    out["last_failure"] = nullptr;
  }
  out["illegal_transitions"] = {{"master", st.illegal_transitions},
                                {"slaves", st.illegal_slave_transitions},
                                {"domains", st.illegal_domain_transitions},
                                {"reservations", st.illegal_reservation_transitions}};
  if (!st.last_illegal_transition.empty()) {
    out["illegal_transitions"]["last_master"] = st.last_illegal_transition;
  }
  out["dc"] = dc_json(master);
  if (!st.cycle_thread.empty()) out["cycle_thread"] = st.cycle_thread;
  if (st.redundancy) out["redundancy"] = redundancy_json(*st.redundancy);
  return out;
}

}  // namespace ecat::master::detail
