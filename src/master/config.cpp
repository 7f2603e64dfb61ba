#include <set>

#include <fmt/format.h>

#include <ecat/drivers/builtin.hpp>
#include <ecat/master/config.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

DriverRegistry builtin_drivers() {
  return drivers::builtin_registry();
}

std::string_view to_string(SyncMode mode) noexcept {
  switch (mode) {
    case SyncMode::free_run:
      return "free_run";
    case SyncMode::sync0:
      return "sync0";
    case SyncMode::sync1:
      return "sync1";
    case SyncMode::sm_synchronous:
      return "sm_synchronous";
  }
  return "unknown";
}

std::string_view to_string(LockPolicy policy) noexcept {
  switch (policy) {
    case LockPolicy::advisory:
      return "advisory";
    case LockPolicy::recovering:
      return "recovering";
    case LockPolicy::fatal:
      return "fatal";
  }
  return "unknown";
}

Result<void> validate(const MasterConfig& config) {
  auto bad = [](std::string message) { return Error(Errc::invalid_argument, std::move(message)); };
  if (config.base_station == 0) return bad("base_station: 0 is not a station address");
  if (const auto& g = config.mailbox_gateway; g.enabled) {
    if (g.request_timeout <= std::chrono::nanoseconds::zero()) {
      return bad("mailbox_gateway: request_timeout must be > 0");
    }
    if (g.workers == 0 || g.workers > 64) {
      return bad(fmt::format("mailbox_gateway: workers must be 1..64, not {}", g.workers));
    }
    if (g.max_queued == 0 || g.max_queued > 4096) {
      return bad(fmt::format("mailbox_gateway: max_queued must be 1..4096, not {}", g.max_queued));
    }
  }
  std::set<std::string> domain_ids;
  for (std::size_t i = 0; i < config.domains.size(); ++i) {
    const auto& d = config.domains[i];
    if (d.id.empty()) return bad(fmt::format("domains[{}]: the id is empty", i));
    if (!domain_ids.insert(d.id).second) {
      return bad(fmt::format("domains[{}]: the id \"{}\" is used twice", i, d.id));
    }
    if (d.period < Domain::kMinPeriod) {
      return bad(fmt::format("domain {}: period {} ns is below the minimum {} ns", d.id,
                             d.period.count(), Domain::kMinPeriod.count()));
    }
    if (d.miss_threshold == 0)
      return bad(fmt::format("domain {}: miss_threshold must be > 0", d.id));
    if (d.recovery_threshold == 0) {
      return bad(fmt::format("domain {}: recovery_threshold must be > 0", d.id));
    }
  }
  auto check_slave = [&](const SlaveConfig& s) -> Result<void> {
    if (s.process_data.kind == ProcessDataRequest::Kind::all &&
        !domain_ids.count(s.process_data.domain)) {
      return bad(fmt::format("slave {}: process_data goes to unknown domain \"{}\"", s.name,
                             s.process_data.domain));
    }
    for (const auto& route : s.process_data.routes) {
      if (!domain_ids.count(route.domain)) {
        return bad(fmt::format("slave {}: signal {} goes to unknown domain \"{}\"", s.name,
                               route.signal, route.domain));
      }
    }
    if (s.health_poll && s.health_poll->count() <= 0) {
      return bad(fmt::format("slave {}: health_poll must be positive", s.name));
    }
    if (s.watchdog) {
      if (auto w = wire::ProcessDataWatchdog::for_time(*s.watchdog); !w) {
        return bad(fmt::format("slave {}: watchdog: {}", s.name, w.error().message()));
      }
    }
    if (s.pdo_source == SlaveConfig::PdoSource::configured && !s.pdo_mapping) {
      return bad(fmt::format("slave {}: pdo_source configured needs a pdo_mapping", s.name));
    }
    if (s.sync && (s.sync->mode == SyncMode::sync0 || s.sync->mode == SyncMode::sync1) &&
        !config.dc) {
      return bad(fmt::format("slave {}: sync mode {} needs distributed clocks (dc is disabled)",
                             s.name, to_string(s.sync->mode)));
    }
    return ok();
  };
  std::set<std::string> names;
  std::set<std::uint16_t> positions;
  std::int64_t previous = -1;
  for (std::size_t i = 0; i < config.slaves.size(); ++i) {
    const auto& s = config.slaves[i];
    if (s.name.empty()) return bad(fmt::format("slaves[{}]: the name is empty", i));
    if (!names.insert(s.name).second) {
      return bad(fmt::format("slaves[{}]: the name \"{}\" is used twice", i, s.name));
    }
    const std::int64_t next = s.position ? *s.position : previous + 1;
    if (next > 0xFFFF) return bad(fmt::format("slave {}: position {} is past 65535", s.name, next));
    const auto pos = static_cast<std::uint16_t>(next);
    previous = next;
    if (!positions.insert(pos).second) {
      return bad(fmt::format("slave {}: position {} is taken by another slave", s.name, pos));
    }
    if (auto r = check_slave(s); !r) return r;
  }
  if (!config.hot_connect.empty() && config.slaves.empty()) {
    return bad("hot_connect: needs the fixed slaves listed in slaves (a dynamic session has none)");
  }
  if (config.hot_connect.size() > kMaxHotConnectGroups) {
    return bad(fmt::format("hot_connect: {} groups, at most {}", config.hot_connect.size(),
                           kMaxHotConnectGroups));
  }
  std::set<std::string> groups;
  std::size_t group_slaves = 0;
  for (std::size_t g = 0; g < config.hot_connect.size(); ++g) {
    const auto& group = config.hot_connect[g];
    if (group.name.empty()) return bad(fmt::format("hot_connect[{}]: the name is empty", g));
    if (!groups.insert(group.name).second) {
      return bad(fmt::format("hot_connect[{}]: the name \"{}\" is used twice", g, group.name));
    }
    const auto who = fmt::format("hot_connect group {}", group.name);
    if (group.slaves.empty()) return bad(fmt::format("{}: lists no slaves", who));
    const auto& first = group.slaves.front();
    const bool by_identity =
        (group.vendor_id || first.vendor_id) && (group.product_code || first.product_code);
    if (!group.alias && !by_identity && !group.device_id) {
      return bad(
          fmt::format("{}: cannot be recognised: give an alias, a device_id (identify), or a "
                      "vendor_id and product_code (of the group or of its first slave {})",
                      who, first.name));
    }
    if (group.reserve_bytes > 0xFFFF) {
      return bad(fmt::format("{}: reserve_bytes {} is past 65535", who, group.reserve_bytes));
    }
    for (const auto& s : group.slaves) {
      if (s.name.empty()) return bad(fmt::format("{}: a slave's name is empty", who));
      if (!names.insert(s.name).second) {
        return bad(fmt::format("{}: the slave name \"{}\" is used twice", who, s.name));
      }
      if (s.position) {
        return bad(
            fmt::format("{}: slave {} has a position (a group's slaves sit where the "
                        "group is found)",
                        who, s.name));
      }
      if (s.alias) {
        return bad(fmt::format("{}: slave {} has an alias (the group's alias identifies it)", who,
                               s.name));
      }
      if (auto r = check_slave(s); !r) return r;
      ++group_slaves;
    }
  }
  // One more station: the scratch address a newly found slave is identified at. The group's
  // stations follow the last fixed position (positions may leave gaps).
  std::size_t fixed = config.slaves.size();
  for (const auto& s : config.slaves) {
    if (s.position) fixed = std::max<std::size_t>(fixed, std::size_t{*s.position} + 1);
  }
  if (group_slaves > 0 &&
      static_cast<std::uint32_t>(config.base_station) + fixed + group_slaves > 0xFFFF) {
    return bad(
        fmt::format("hot_connect: stations 0x{:04x} + {} fixed positions and {} group slaves "
                    "(and one to identify them at) run past 0xffff",
                    config.base_station, fixed, group_slaves));
  }
  if (config.hot_connect_poll.count() <= 0) return bad("hot_connect_poll must be positive");
  if (config.dc && config.dc->cycle.count() <= 0) return bad("dc.cycle must be positive");
  if (config.dc && config.dc->frame_lead &&
      (config.dc->frame_lead->count() < 0 || *config.dc->frame_lead * 2 >= config.dc->cycle)) {
    return bad(fmt::format("dc.frame_lead {} ns must lie in 0 .. half the DC cycle ({} ns)",
                           config.dc->frame_lead->count(), config.dc->cycle.count()));
  }
  if (config.scan.poll.count() <= 0) return bad("scan poll period must be positive");
  if (config.awaiting_preop_timeout.count() <= 0)
    return bad("awaiting_preop_timeout must be positive");
  if (config.retry_interval.count() <= 0) return bad("retry_interval must be positive");
  if (config.link_recovery_window.count() <= 0) return bad("link_recovery_window must be positive");
  return ok();
}

}  // namespace ecat::master
