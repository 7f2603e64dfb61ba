#include "preop_plan.hpp"

#include <algorithm>
#include <array>
#include <map>
#include <set>
#include <utility>

#include <fmt/format.h>

#include <ecat/wire/bytes.hpp>

namespace ecat::master::detail {

namespace reg = wire::reg;

namespace {

// SDOs go through the mailbox: a slave without one cannot take them, and the plan says so before
// anything is written.
Result<void> check_mailbox_for(const PreopFacts& facts, const std::vector<SdoWrite>& sdos,
                               std::size_t from) {
  if (facts.has_mailbox || from >= sdos.size()) return ok();
  return Error(Errc::unsupported, fmt::format("{}: SDO {} needs a mailbox, the slave has none",
                                              facts.who, to_string(sdos[from])));
}

void append(std::vector<SdoWrite>& to, const std::vector<SdoWrite>& more) {
  to.insert(to.end(), more.begin(), more.end());
}

// The SII's own control byte when it describes a buffered (3-buffer) SyncManager, else the usual
// one for the direction.
wire::SyncManagerConfig sync_manager_config(const wire::SiiSyncManager& sii_sm, std::uint16_t start,
                                            std::uint16_t length, PdoDirection direction) {
  wire::SyncManagerConfig smc;
  smc.physical_start = start;
  smc.length = length;
  auto control = wire::SmControl::decode(sii_sm.control);
  smc.control =
      control && control->mode == wire::SmMode::buffered
          ? *control
          : (direction == PdoDirection::output ? wire::kOutputsControl : wire::kInputsControl);
  smc.activate.enable = true;
  return smc;
}

const DomainFacts* find_domain(const PreopFacts& facts, const std::string& id) {
  for (const auto& d : facts.domains) {
    if (d.id == id) return &d;
  }
  return nullptr;
}

}  // namespace

Result<std::shared_ptr<const Driver>> choose_driver(const DriverRegistry& drivers,
                                                    const SlaveConfig& config,
                                                    const wire::SiiIdentity& identity,
                                                    const std::string& who) {
  if (config.driver.empty()) return drivers.find(identity);
  auto named = drivers.find(std::string_view(config.driver));
  if (!named) {
    return Error(Errc::not_found, fmt::format("{}: unknown driver \"{}\"", who, config.driver));
  }
  return named;
}

Result<LayoutPlan> plan_layout(const PreopFacts& facts, const SlaveConfig& config,
                               const Driver& driver) {
  LayoutPlan plan;
  auto sii_layout = pdo_layout_from_sii(facts.sii);
  if (!sii_layout) return sii_layout.error().context(fmt::format("{}: SII PDOs", facts.who));
  plan.sii_layout = std::move(*sii_layout);
  plan.layout = plan.sii_layout;

  SyncSettings sync_settings;  // DC sync modes come with the distributed-clocks work
  auto driver_preop = driver.startup_sdos(config.driver_config, StartupPhase::preop, sync_settings);
  if (!driver_preop) return driver_preop.error();
  append(plan.sdos, *driver_preop);
  append(plan.sdos, config.startup_sdos);
  if (auto mailbox = check_mailbox_for(facts, plan.sdos, 0); !mailbox) return mailbox.error();

  if (config.pdo_source == SlaveConfig::PdoSource::configured) {
    if (!config.pdo_mapping) {
      return Error(
          Errc::invalid_argument,
          fmt::format("{}: pdo_source is 'configured' but no mapping is given", facts.who));
    }
    auto wanted = pdo_layout_from_coe(*config.pdo_mapping, &plan.sii_layout);
    if (!wanted) {
      return wanted.error().context(fmt::format("{}: configured PDO mapping", facts.who));
    }
    auto writes = coe_mapping_writes(*wanted);
    if (!writes) return writes.error();
    const auto first_mapping_write = plan.sdos.size();
    append(plan.sdos, *writes);
    if (auto mailbox = check_mailbox_for(facts, plan.sdos, first_mapping_write); !mailbox) {
      return mailbox.error();
    }
    plan.layout = std::move(*wanted);
  } else if (config.pdo_source == SlaveConfig::PdoSource::coe) {
    if (!facts.has_mailbox) {
      return Error(Errc::unsupported,
                   fmt::format("{}: PDO layout from CoE needs a mailbox, the slave has none",
                               facts.who))
          .context(fmt::format("{}: reading the PDO mapping", facts.who));
    }
    plan.read_from_coe = true;
    plan.layout = {};
  }
  return plan;
}

std::vector<CoePdoAssignment> coe_assignments_to_read(const wire::SiiImage& sii) {
  // Process-data SyncManagers are 2 (outputs) and 3 (inputs) on nearly every device; read the
  // assignment of every SyncManager the SII describes beyond the mailbox.
  std::vector<CoePdoAssignment> out;
  const auto& sms = sii.sync_managers;
  for (std::size_t i = 2; i < sms.size() && i < kMaxSyncManagers; ++i) {
    CoePdoAssignment assignment;
    assignment.sync_manager = static_cast<std::uint8_t>(i);
    if (sms[i].type == wire::sii_sm_type::kOutputs) {
      assignment.direction = PdoDirection::output;
    } else if (sms[i].type == wire::sii_sm_type::kInputs) {
      assignment.direction = PdoDirection::input;
    }
    out.push_back(std::move(assignment));
  }
  return out;
}

Result<ProcessDataPlan> plan_process_data(const PreopFacts& facts, const SlaveConfig& config,
                                          const Driver& driver, const LayoutPlan& layout,
                                          const CoePdoConfiguration* coe) {
  ProcessDataPlan plan;
  if (layout.read_from_coe) {
    if (coe == nullptr) {
      return Error(
          Errc::invalid_argument,
          fmt::format("{}: the PDO layout is to be read from CoE, and was not", facts.who));
    }
    auto read = pdo_layout_from_coe(*coe, &layout.sii_layout);
    if (!read) return read.error().context(fmt::format("{}: reading the PDO mapping", facts.who));
    plan.layout = std::move(*read);
  } else {
    plan.layout = layout.layout;
  }

  auto driver_sync =
      driver.startup_sdos(config.driver_config, StartupPhase::sync_update, SyncSettings{});
  if (!driver_sync) return driver_sync.error();
  plan.sdos = std::move(*driver_sync);
  if (auto mailbox = check_mailbox_for(facts, plan.sdos, 0); !mailbox) return mailbox.error();

  auto model = driver.signal_model(plan.layout, config.driver_config);
  if (!model) return model.error().context(fmt::format("{}: signal model", facts.who));
  plan.signals = std::move(*model);

  // Which SyncManager goes to which domains.
  std::map<std::uint8_t, std::set<std::string>> sm_domains;
  const auto& request = config.process_data;
  if (request.kind == ProcessDataRequest::Kind::all) {
    for (const auto& sig : plan.signals)
      sm_domains[sig.sync_manager].insert(request.domain);
  } else if (request.kind == ProcessDataRequest::Kind::signals) {
    for (const auto& route : request.routes) {
      auto it = std::find_if(plan.signals.begin(), plan.signals.end(),
                             [&](const Signal& s) { return s.name == route.signal; });
      if (it == plan.signals.end()) {
        return Error(Errc::not_found,
                     fmt::format("{}: process_data names signal \"{}\", which the {} driver "
                                 "does not have",
                                 facts.who, route.signal, driver.name()));
      }
      sm_domains[it->sync_manager].insert(route.domain);
    }
  }
  for (const auto& [sm, ids] : sm_domains) {
    for (const auto& id : ids) {
      if (!find_domain(facts, id)) {
        return Error(
            Errc::not_found,
            fmt::format("{}: process data routed to unknown domain \"{}\"", facts.who, id));
      }
    }
  }

  // One FMMU per (SyncManager, domain).
  std::uint8_t next_fmmu = 0;
  for (const auto& [sm_index, ids] : sm_domains) {
    const auto* sm = plan.layout.find_sync_manager(sm_index);
    if (!sm || sm->byte_length() == 0) continue;
    if (sm_index >= facts.sii.sync_managers.size()) {
      return Error(Errc::invalid_argument,
                   fmt::format("{}: PDOs assigned to SyncManager {}, which the SII does not "
                               "describe",
                               facts.who, sm_index));
    }
    for (const auto& id : ids) {
      SmAttachment a;
      a.sync_manager = sm_index;
      a.direction = sm->direction;
      a.domain = id;
      a.physical_address = facts.sii.sync_managers[sm_index].start;
      a.size = sm->byte_length();
      a.fmmu = next_fmmu++;
      plan.attachments.push_back(a);
    }
  }
  const unsigned fmmu_available = facts.fmmu_count == 0 ? 16u : facts.fmmu_count;
  if (plan.attachments.size() > fmmu_available) {
    return Error(Errc::out_of_range, fmt::format("{}: needs {} FMMUs, the ESC has {}", facts.who,
                                                 plan.attachments.size(), fmmu_available));
  }

  // Registrations: one the slave has from before a reconnect is kept (it must be the same size
  // and direction: a cycling domain's image cannot change); the others are made, after the room
  // for all of them was checked domain by domain.
  std::map<std::string, DomainRoom> room;
  for (std::size_t i = 0; i < plan.attachments.size(); ++i) {
    auto& a = plan.attachments[i];
    const auto* domain = find_domain(facts, a.domain);
    const auto existing =
        std::find_if(domain->registered.begin(), domain->registered.end(), [&](const auto& r) {
          return r.sync_manager == a.sync_manager && r.kind == RegistrationKind::process_data;
        });
    if (existing != domain->registered.end()) {
      if (existing->size != a.size || existing->direction != a.direction) {
        return Error(Errc::wrong_state,
                     fmt::format("{}: SyncManager {} is registered in domain \"{}\" with {} "
                                 "bytes, now {}: the domain must be rebuilt",
                                 facts.who, a.sync_manager, a.domain, existing->size, a.size));
      }
      a.logical_address = existing->logical_address;
      continue;
    }
    plan.new_registrations.push_back(i);
    auto& need = room[a.domain];
    need.domain = a.domain;
    ++need.count;
    need.bytes += a.size;
  }

  // The mailbox status: where the slave has it registered already (a rebuild: the image of a
  // cycling domain cannot change, so it stays mapped whatever the option says now), else, when
  // asked for, in the fastest of its domains; only with an FMMU to spare.
  if (facts.has_mailbox && !plan.attachments.empty() && plan.attachments.size() < fmmu_available) {
    MailboxStatusMapping m;
    m.sync_manager = facts.mailbox_in_sync_manager;
    m.physical_address = static_cast<std::uint16_t>(reg::sync_manager(m.sync_manager) +
                                                    reg::kSyncManagerStatusOffset);
    m.fmmu = static_cast<std::uint8_t>(plan.attachments.size());
    const DomainFacts* fastest = nullptr;
    for (const auto& d : facts.domains) {
      for (const auto& r : d.registered) {
        if (r.kind == RegistrationKind::sm_status && r.sync_manager == m.sync_manager) {
          m.domain = d.id;
          m.logical_address = r.logical_address;
          m.new_registration = false;
        }
      }
    }
    for (const auto& a : plan.attachments) {
      const auto* d = find_domain(facts, a.domain);
      if (fastest == nullptr || d->period < fastest->period) fastest = d;
    }
    if (m.new_registration && facts.mailbox_status) {
      m.domain = fastest->id;
      auto& need = room[m.domain];
      need.domain = m.domain;
      ++need.count;
      need.bytes += 1;
    }
    if (!m.domain.empty()) plan.mailbox_status = std::move(m);
  }
  for (auto& [id, need] : room)
    plan.room.push_back(std::move(need));

  // SyncManagers: those with an FMMU, then those routed nowhere.
  std::set<std::uint8_t> planned;
  for (const auto& a : plan.attachments) {
    if (!planned.insert(a.sync_manager).second) continue;
    plan.sync_managers.push_back(
        {a.sync_manager, sync_manager_config(facts.sii.sync_managers[a.sync_manager],
                                             a.physical_address, a.size, a.direction)});
  }
  for (const auto& sm : plan.layout.sync_managers) {
    if (sm.byte_length() == 0 || planned.count(sm.sync_manager) != 0 ||
        sm.sync_manager >= facts.sii.sync_managers.size()) {
      continue;
    }
    const auto& sii_sm = facts.sii.sync_managers[sm.sync_manager];
    auto sm_config = sync_manager_config(sii_sm, sii_sm.start, sm.byte_length(), sm.direction);
    // Nothing writes an output SyncManager routed nowhere: with the SII's watchdog trigger left
    // on, the process-data watchdog would expire one watchdog time after OP and the slave fall
    // back to SAFEOP (AL status 0x001B), again after every recovery. Its outputs stay in their
    // safe state; the watchdog still guards any SyncManager that is written.
    if (sm.direction == PdoDirection::output) sm_config.control.watchdog = false;
    plan.sync_managers.push_back({sm.sync_manager, sm_config});
  }

  // The process-data watchdog against the periods of the domains that write the outputs.
  const DomainFacts* slowest = nullptr;
  for (const auto& a : plan.attachments) {
    if (a.direction != PdoDirection::output) continue;
    const auto* d = find_domain(facts, a.domain);
    if (slowest == nullptr || d->period > slowest->period) slowest = d;
  }
  if (config.watchdog) {
    auto w = wire::ProcessDataWatchdog::for_time(*config.watchdog);
    if (!w) return w.error().context(fmt::format("{}: watchdog", facts.who));
    if (slowest != nullptr && !w->off() && w->time() <= slowest->period) {
      return Error(Errc::invalid_argument,
                   fmt::format("{}: a watchdog of {} us is not longer than the {} us period of "
                               "domain \"{}\", which writes its outputs: the slave would leave "
                               "OP between two writes",
                               facts.who, w->time().count() / 1000, slowest->period.count() / 1000,
                               slowest->id));
    }
    plan.watchdog = *w;
  } else if (slowest != nullptr && 3 * slowest->period > wire::ProcessDataWatchdog{}.time()) {
    auto w = wire::ProcessDataWatchdog::for_time(std::min<std::chrono::nanoseconds>(
        3 * slowest->period, wire::ProcessDataWatchdog::kMaxTime));
    if (!w) return w.error().context(fmt::format("{}: watchdog", facts.who));
    plan.watchdog = *w;
  }
  return plan;
}

std::vector<RegisterWrite> process_data_writes(const ProcessDataPlan& plan) {
  std::vector<RegisterWrite> out;
  std::set<std::uint8_t> written;
  // A SyncManager is deactivated before its configuration is written (an ESC takes a new
  // configuration only while the SyncManager is disabled); the write enables it again.
  auto write_sync_manager = [&](const PlannedSyncManager& sm) {
    const auto base = static_cast<std::uint16_t>(reg::kSyncManagerBase + 8 * sm.sync_manager);
    out.push_back({static_cast<std::uint16_t>(base + reg::kSyncManagerActivateOffset), {0}});
    const auto encoded = sm.config.encode();
    out.push_back({base, std::vector<std::uint8_t>(encoded.begin(), encoded.end())});
    written.insert(sm.sync_manager);
  };
  if (const auto& w = plan.watchdog) {
    for (const auto& [address, value] : {std::pair{reg::kWatchdogDivider, w->divider},
                                         std::pair{reg::kWatchdogTimeProcessData, w->ticks}}) {
      std::vector<std::uint8_t> data(2);
      wire::store_le16(data.data(), value);
      out.push_back({address, std::move(data)});
    }
  }
  for (const auto& a : plan.attachments) {
    if (written.count(a.sync_manager) == 0) {
      for (const auto& sm : plan.sync_managers) {
        if (sm.sync_manager == a.sync_manager) write_sync_manager(sm);
      }
    }
    wire::FmmuConfig f;
    f.logical_start = a.logical_address;
    f.length = a.size;
    f.logical_start_bit = 0;
    f.logical_stop_bit = 7;
    f.physical_start = a.physical_address;
    f.type = a.direction == PdoDirection::output ? wire::FmmuType::write : wire::FmmuType::read;
    f.active = true;
    const auto encoded = f.encode();
    out.push_back({static_cast<std::uint16_t>(reg::kFmmuBase + reg::kFmmuSize * a.fmmu),
                   std::vector<std::uint8_t>(encoded.begin(), encoded.end())});
  }
  for (const auto& sm : plan.sync_managers) {
    if (written.count(sm.sync_manager) == 0) write_sync_manager(sm);
  }
  if (const auto& m = plan.mailbox_status) {
    wire::FmmuConfig f;
    f.logical_start = m->logical_address;
    f.length = 1;
    f.logical_start_bit = 0;
    f.logical_stop_bit = 7;
    f.physical_start = m->physical_address;
    f.type = wire::FmmuType::read;
    f.active = true;
    const auto encoded = f.encode();
    out.push_back({static_cast<std::uint16_t>(reg::kFmmuBase + reg::kFmmuSize * m->fmmu),
                   std::vector<std::uint8_t>(encoded.begin(), encoded.end())});
  }
  return out;
}

}  // namespace ecat::master::detail
