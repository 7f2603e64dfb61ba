// An ENI (ETG.2100) mapped onto a MasterConfig (docs/MASTER-CONFIG.md "ENI files"), and the one
// entry point that reads either a ring file or an ENI (load_master_config).
//
// The decisions, each for a reason:
// - The configurator's precomputed frames, logical addresses, process-image offsets and ESC
//   register writes are not replayed: ecat lays out its own domains and computes its own
//   SyncManager / FMMU / DC / AL writes from the SII, so replaying them would fight the master.
//   They are reported, never silently dropped.
// - What the ENI says about the devices (identities, PDO assignment and mapping, CoE start-up
//   commands, SYNC0 settings) is what a configurator knows and ecat cannot guess: that is used.
// - CoE InitCmds of INIT->PREOP and PREOP->SAFEOP become startup SDOs, in the file's order:
//   ecat runs its startup SDOs once, in PREOP, before process data is set up, which is where
//   both transitions' commands take effect. Commands of other transitions are reported.
// - PDO layout: when the CoE InitCmds themselves write the assignment (0x1C1n) or a mapping
//   object (0x1600.. / 0x1A00..), as TwinCAT's do, they carry the configuration and the layout is
//   read back from the device after them (PdoSource::coe). Otherwise, for a CoE slave, the ENI's
//   SyncManager / PDO lists are written from configuration (PdoSource::configured). A slave
//   without CoE keeps the SII's layout (nothing can be written).
#include <algorithm>
#include <cctype>
#include <map>
#include <set>

#include <fmt/format.h>

#include <ecat/config/eni.hpp>
#include <ecat/master/config.hpp>

#include "core/read_file.hpp"

namespace ecat::master {

namespace {

using config::EniFile;
using config::EniSlave;

// Slave names ecat can address on a command line and in signal paths ("slave.signal"):
// letters, digits, '_' and '-'; anything else becomes '_' (runs collapsed, ends trimmed).
std::string sanitise(std::string_view raw) {
  std::string out;
  for (const char c : raw) {
    const bool keep = std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '_' || c == '-';
    if (keep) {
      out.push_back(c);
    } else if (!out.empty() && out.back() != '_') {
      out.push_back('_');
    }
    if (out.size() >= 64) break;
  }
  while (!out.empty() && out.back() == '_')
    out.pop_back();
  return out;
}

// ESI / IEC 61131 type names as ENIs write them -> CoE data type codes (pdo.hpp coe_type).
// Unknown names give kNone: the type is informational, the bit length is what lays out the image.
std::uint16_t coe_type_of(std::string_view name) {
  static const std::map<std::string_view, std::uint16_t> kTypes{
      {"BOOL", coe_type::kBoolean},      {"BIT", coe_type::kBoolean},
      {"SINT", coe_type::kInteger8},     {"INT", coe_type::kInteger16},
      {"DINT", coe_type::kInteger32},    {"LINT", coe_type::kInteger64},
      {"USINT", coe_type::kUnsigned8},   {"UINT", coe_type::kUnsigned16},
      {"UDINT", coe_type::kUnsigned32},  {"ULINT", coe_type::kUnsigned64},
      {"REAL", coe_type::kReal32},       {"LREAL", coe_type::kReal64},
      {"BYTE", coe_type::kByte},         {"WORD", coe_type::kWord},
      {"DWORD", coe_type::kDword},       {"INT24", coe_type::kInteger24},
      {"UINT24", coe_type::kUnsigned24}, {"BITARR8", coe_type::kBitArr8},
      {"BITARR16", coe_type::kBitArr16}, {"BITARR32", coe_type::kBitArr32}};
  if (auto it = kTypes.find(name); it != kTypes.end()) return it->second;
  if (name.size() == 4 && name.starts_with("BIT") && name[3] >= '1' && name[3] <= '8') {
    return static_cast<std::uint16_t>(coe_type::kBit1 + (name[3] - '1'));
  }
  return coe_type::kNone;
}

bool has_protocol(const config::EniMailbox& mb, std::string_view protocol) {
  return std::any_of(mb.protocols.begin(), mb.protocols.end(),
                     [&](const std::string& p) { return p == protocol; });
}

bool runs_in_preop(const config::EniCoeInitCmd& cmd) {
  return std::any_of(cmd.transitions.begin(), cmd.transitions.end(),
                     [](const std::string& t) { return t == "IP" || t == "PS"; });
}

bool is_pdo_object(std::uint16_t index) {
  return (index >= 0x1C10 && index <= 0x1C2F) || (index >= 0x1600 && index <= 0x17FF) ||
         (index >= 0x1A00 && index <= 0x1BFF);
}

std::string join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& i : items)
    out += (out.empty() ? "" : ",") + i;
  return out;
}

class Mapper {
 public:
  Mapper(const EniFile& eni, std::string source) : eni_(eni), source_(std::move(source)) {}

  Result<EniImport> map() {
    EniImport out;
    MasterConfig& config = out.config;
    if (eni_.slaves.empty()) {
      return Error(Errc::invalid_argument,
                   fmt::format("{}: the ENI describes no <Slave>: nothing to configure", source_));
    }
    const auto period = domain_period();
    config.domains.push_back(DomainConfig{.id = "main", .period = period});

    std::set<std::string> names;
    for (std::size_t i = 0; i < eni_.slaves.size(); ++i) {
      auto s = slave(eni_.slaves[i], i, names);
      if (!s) return s.error();
      config.slaves.push_back(std::move(*s));
    }
    base_station(config);
    distributed_clocks(config, period);
    if (auto r = hot_connect_groups(config); !r) return r.error();
    whole_file_notes();
    if (auto valid = validate(config); !valid) {
      return valid.error().context(
          Errc::invalid_argument,
          fmt::format("{}: the configuration mapped from the ENI", source_));
    }
    out.report = std::move(report_);
    return out;
  }

 private:
  void note(std::string line) { report_.push_back(std::move(line)); }

  std::string who(const EniSlave& s) const {
    return fmt::format("slave \"{}\" (line {})", s.info.name, s.line);
  }

  // One domain "main" at the ENI's cycle. Several Cyclic entries with different cycles are
  // merged into one domain at the shortest (reported): ecat assigns slaves to domains, the ENI
  // assigns frames to cycles, and mapping frames back to slaves is not done here.
  std::chrono::nanoseconds domain_period() {
    std::optional<std::uint32_t> shortest;
    std::set<std::uint32_t> distinct;
    for (const auto& c : eni_.cyclic) {
      if (c.cycle_time_us == 0) continue;
      distinct.insert(c.cycle_time_us);
      if (!shortest || c.cycle_time_us < *shortest) shortest = c.cycle_time_us;
    }
    if (distinct.size() > 1) {
      note(
          fmt::format("Cyclic: {} different cycle times; ecat exchanges all process data in "
                      "one domain \"main\" every {} us (the shortest)",
                      distinct.size(), *shortest));
    }
    if (shortest) return std::chrono::microseconds(*shortest);
    for (const auto& s : eni_.slaves) {
      if (s.dc && s.dc->cycle_time0 > 0) {
        note(
            fmt::format("Cyclic: none with a CycleTime; domain \"main\" runs at {}'s DC "
                        "CycleTime0 ({} ns)",
                        who(s), s.dc->cycle_time0));
        return std::chrono::nanoseconds(s.dc->cycle_time0);
      }
    }
    note("Cyclic: none with a CycleTime; domain \"main\" runs every 1000 us (ecat's default)");
    return std::chrono::milliseconds(1);
  }

  Result<SlaveConfig> slave(const EniSlave& e, std::size_t index, std::set<std::string>& names) {
    SlaveConfig s;
    std::string base = sanitise(e.info.name);
    if (base.empty()) base = fmt::format("slave_{}", index);
    std::string name = base;
    for (int n = 2; names.count(name); ++n)
      name = fmt::format("{}_{}", base, n);
    names.insert(name);
    s.name = name;

    // Ring position: AutoIncAddr is 0, -1, -2 ... (written 0, 65535, 65534 ...); without it the
    // file's order.
    const std::uint16_t position =
        e.info.auto_inc_addr
            ? static_cast<std::uint16_t>((0x10000 - std::uint32_t{*e.info.auto_inc_addr}) & 0xFFFF)
            : static_cast<std::uint16_t>(index);
    if (e.info.identification_ado && *e.info.identification_ado == 0x0012 &&
        e.info.identification_value && *e.info.identification_value != 0) {
      s.alias = *e.info.identification_value;  // found wherever it sits in the ring
    } else {
      if (e.info.identification_ado) {
        note(
            fmt::format("{}: Info/Identification by register 0x{:04X}: not used (ecat identifies "
                        "by position or by the station alias, 0x0012)",
                        who(e), *e.info.identification_ado));
      }
      s.position = position;
    }
    s.vendor_id = e.info.vendor_id;
    s.product_code = e.info.product_code;
    if (e.info.revision_no) ++unchecked_revisions_;

    const bool coe =
        e.mailbox && (has_protocol(*e.mailbox, "CoE") || !e.mailbox->coe_init_cmds.empty());
    if (e.mailbox) mailbox(e, s);
    if (e.process_data) {
      if (auto r = process_data(e, coe, s); !r) return r.error();
    } else {
      s.process_data = ProcessDataRequest::none();
    }
    if (!e.init_cmds.empty()) {
      note(
          fmt::format("{}: InitCmds: {} ESC register command(s) not replayed; ecat computes its "
                      "own (station address, SyncManagers, FMMUs, DC, AL control){}",
                      who(e), e.init_cmds.size(),
                      assign_activate(e) ? " (the DC activation 0x0981 is taken from them)" : ""));
    }
    for (const auto& u : e.unrecognised) {
      note(fmt::format("{}: {} not recognised, not used", who(e), u));
    }
    return s;
  }

  void mailbox(const EniSlave& e, SlaveConfig& s) {
    const auto& mb = *e.mailbox;
    std::size_t later = 0;
    std::size_t uploads = 0;
    std::size_t disabled = 0;
    for (const auto& cmd : mb.coe_init_cmds) {
      if (cmd.disabled) {
        ++disabled;
      } else if (cmd.ccs != 1) {
        ++uploads;
      } else if (!runs_in_preop(cmd)) {
        note(fmt::format(
            "{}: CoE InitCmd (line {}) 0x{:04X}:{:02X} \"{}\" at {}: not run (ecat "
            "runs start-up SDOs in PREOP only: IP and PS)",
            who(e), cmd.line, cmd.index, cmd.subindex, cmd.comment, join(cmd.transitions)));
        ++later;
      } else {
        s.startup_sdos.push_back(SdoWrite{.index = cmd.index,
                                          .subindex = cmd.subindex,
                                          .data = cmd.data,
                                          .complete_access = cmd.complete_access});
      }
    }
    if (uploads > 0) {
      note(
          fmt::format("{}: {} CoE InitCmd upload(s) (Ccs 2): not run (ecat only downloads at "
                      "start-up)",
                      who(e), uploads));
    }
    if (disabled > 0) {
      note(fmt::format("{}: {} disabled CoE InitCmd(s): skipped, as the ENI asks", who(e),
                       disabled));
    }
    if (!mb.soe_init_cmds.empty()) {
      std::string idns;
      for (std::size_t i = 0; i < mb.soe_init_cmds.size() && i < 8; ++i) {
        const auto& c = mb.soe_init_cmds[i];
        idns += fmt::format("{}{}-{}-{:04}", idns.empty() ? "" : ", ",
                            (c.idn & 0x8000) != 0 ? 'P' : 'S', (c.idn >> 12) & 0x7, c.idn & 0x0FFF);
      }
      if (mb.soe_init_cmds.size() > 8) idns += ", ...";
      note(
          fmt::format("{}: Mailbox/SoE: {} InitCmd(s) ({}) not run: the SoE client is not part "
                      "of ecat's start-up yet",
                      who(e), mb.soe_init_cmds.size(), idns));
    }
    if (mb.has_eoe || has_protocol(mb, "EoE")) {
      note(fmt::format("{}: Mailbox/EoE settings not used (ecat configures no EoE at start-up)",
                       who(e)));
    }
  }

  // The DC activation (AssignActivate) the configurator writes to 0x0980/0x0981 in the slave's
  // ESC InitCmds (KickCAT's and TwinCAT's ENIs carry it there, not in <DC>).
  static std::optional<std::uint16_t> assign_activate(const EniSlave& e) {
    std::optional<std::uint16_t> found;
    for (const auto& c : e.init_cmds) {
      if (c.addr || c.data.empty()) continue;
      if (c.ado == 0x0980 && c.data.size() >= 2) {
        found = static_cast<std::uint16_t>(c.data[0] | (c.data[1] << 8));
      } else if (c.ado == 0x0981) {
        found = static_cast<std::uint16_t>(c.data[0] << 8);
      }
    }
    return found;
  }

  Result<void> process_data(const EniSlave& e, bool coe, SlaveConfig& s) {
    const auto& pd = *e.process_data;
    const bool any = !pd.rx_pdos.empty() || !pd.tx_pdos.empty() || !pd.sync_managers.empty() ||
                     (pd.send && pd.send->bit_length > 0) || (pd.recv && pd.recv->bit_length > 0);
    s.process_data = any ? ProcessDataRequest::all("main") : ProcessDataRequest::none();
    if (!any) return ok();

    // The assignment: <SmN><Pdo> lists when present (they are the configured assignment), else
    // the Sm attributes of the PDOs.
    std::map<std::uint8_t, CoePdoAssignment> assignments;
    for (const auto& sm : pd.sync_managers) {
      CoePdoAssignment a;
      a.sync_manager = sm.index;
      if (sm.type == "Outputs") a.direction = PdoDirection::output;
      if (sm.type == "Inputs") a.direction = PdoDirection::input;
      a.pdo_indices = sm.pdos;
      assignments[sm.index] = std::move(a);
    }
    if (pd.sync_managers.empty()) {
      const auto add = [&](const config::EniPdo& p, PdoDirection direction) {
        if (!p.sync_manager) return;
        auto& a = assignments[*p.sync_manager];
        a.sync_manager = *p.sync_manager;
        a.direction = direction;
        a.pdo_indices.push_back(p.index);
      };
      for (const auto& p : pd.rx_pdos)
        add(p, PdoDirection::output);
      for (const auto& p : pd.tx_pdos)
        add(p, PdoDirection::input);
    }
    const bool assigns = std::any_of(assignments.begin(), assignments.end(),
                                     [](const auto& a) { return !a.second.pdo_indices.empty(); });
    if (!assigns) return ok();

    if (!coe) {
      note(
          fmt::format("{}: ProcessData: no CoE mailbox, so its PDO assignment cannot be written; "
                      "the device's own (SII) layout is used",
                      who(e)));
      return ok();
    }
    const bool init_cmds_configure =
        std::any_of(s.startup_sdos.begin(), s.startup_sdos.end(),
                    [](const SdoWrite& w) { return is_pdo_object(w.index); });
    if (init_cmds_configure) {
      // The ENI's own CoE InitCmds write the assignment / mapping; read the result back.
      s.pdo_source = SlaveConfig::PdoSource::coe;
      return ok();
    }
    CoePdoConfiguration configured;
    std::set<std::uint16_t> assigned;
    for (auto& [sm, a] : assignments) {
      for (auto index : a.pdo_indices)
        assigned.insert(index);
      configured.assignments.push_back(a);
    }
    std::set<std::pair<std::uint16_t, std::uint8_t>> described;
    for (const auto* list : {&pd.rx_pdos, &pd.tx_pdos}) {
      for (const auto& p : *list) {
        if (!assigned.count(p.index)) continue;
        CoePdoMapping m;
        m.pdo_index = p.index;
        m.name = p.name;
        for (const auto& entry : p.entries) {
          m.entries.push_back(coe_mapping_entry(entry.index, entry.subindex, entry.bit_length));
          if (entry.index != 0 && described.insert({entry.index, entry.subindex}).second) {
            configured.entry_info.push_back(CoeEntryInfo{.index = entry.index,
                                                         .subindex = entry.subindex,
                                                         .data_type = coe_type_of(entry.data_type),
                                                         .name = entry.name});
          }
        }
        configured.mappings.push_back(std::move(m));
      }
    }
    // An assigned PDO the ENI does not describe is taken from the SII (pdo_layout_from_coe).
    if (auto layout = pdo_layout_from_coe(configured);
        !layout && layout.error().code() != Errc::not_found) {
      return layout.error().context(
          fmt::format("{}: {}: the ENI's PDO assignment and mapping", source_, who(e)));
    }
    s.pdo_source = SlaveConfig::PdoSource::configured;
    s.pdo_mapping = std::move(configured);
    return ok();
  }

  // Stations: ecat assigns base_station + position. When the ENI's PhysAddr follow that rule
  // with one base, that base is used, so the stations are the configurator's.
  void base_station(MasterConfig& config) {
    std::optional<int> base;
    bool consistent = true;
    for (std::size_t i = 0; i < eni_.slaves.size(); ++i) {
      const auto& e = eni_.slaves[i];
      if (!e.info.phys_addr) continue;
      const auto& s = config.slaves[i];
      const int position = s.position ? *s.position : static_cast<int>(i);
      const int b = int{*e.info.phys_addr} - position;
      if (!base) base = b;
      if (b != *base) consistent = false;
    }
    if (!base) return;
    if (consistent && *base >= 1 && *base + static_cast<int>(eni_.slaves.size()) <= 0xFFFF) {
      config.base_station = static_cast<std::uint16_t>(*base);
    } else {
      note(
          fmt::format("Slave/Info/PhysAddr: not base + position throughout; ecat assigns stations "
                      "0x{:04X} + position",
                      config.base_station));
    }
  }

  void distributed_clocks(MasterConfig& config, std::chrono::nanoseconds period) {
    std::optional<std::chrono::nanoseconds> dc_cycle;
    bool first_dc = true;
    for (std::size_t i = 0; i < eni_.slaves.size(); ++i) {
      const auto& e = eni_.slaves[i];
      if (!e.dc) continue;
      if (e.dc->reference_clock && !first_dc) {
        note(
            fmt::format("{}: DC/ReferenceClock: ecat makes the first DC-capable slave the "
                        "reference clock",
                        who(e)));
      }
      first_dc = false;
      const auto aa = assign_activate(e);
      if (e.dc->cycle_time0 <= 0) continue;
      if (aa && (*aa & 0x0100) == 0) continue;  // the configurator leaves SYNC off: free run
      SyncConfig sync;
      sync.mode = aa && (*aa & 0x0400) != 0 ? SyncMode::sync1 : SyncMode::sync0;
      sync.sync0_shift = std::chrono::nanoseconds(e.dc->shift_time);
      if (sync.mode == SyncMode::sync1 && e.dc->cycle_time1 && *e.dc->cycle_time1 > 0) {
        sync.sync1_offset = std::chrono::nanoseconds(*e.dc->cycle_time1);
      }
      sync.assign_activate = aa;
      config.slaves[i].sync = sync;
      const std::chrono::nanoseconds cycle(e.dc->cycle_time0);
      if (!dc_cycle) {
        dc_cycle = cycle;
      } else if (*dc_cycle != cycle) {
        note(
            fmt::format("{}: DC/CycleTime0 {} ns differs from the first SYNC slave's ({} ns); "
                        "ecat runs one DC cycle",
                        who(e), cycle.count(), dc_cycle->count()));
      }
    }
    DcConfig dc;
    dc.cycle = dc_cycle ? *dc_cycle : period;
    config.dc = dc;
  }

  // Slave/HotConnect (ETG.2100; element names as public ENI readers parse them: HotConnect under
  // <Slave> with GroupName, GroupMemberCnt and IdentifyCmd, an EtherCAT command whose
  // Validate/Data is the expected value; identification by the station alias 0x0012 or an
  // explicit device ID 0x0134, as Beckhoff's and VIPA's hot-connect documentation describe):
  // the head slave and the GroupMemberCnt - 1 after it in the file become a MasterConfig
  // hot-connect group (docs/MASTER-CONFIG.md "Hot connect") and leave the fixed slaves.
  Result<void> hot_connect_groups(MasterConfig& config) {
    const std::size_t n = eni_.slaves.size();
    std::vector<std::optional<std::size_t>> group_of(n);  // slave -> the group it belongs to
    std::vector<HotConnectGroup> groups;
    for (std::size_t i = 0; i < n; ++i) {
      const auto& e = eni_.slaves[i];
      if (!e.hot_connect) continue;
      const auto& hc = *e.hot_connect;
      const auto where = fmt::format("{}: {}: HotConnect (line {})", source_, who(e), hc.line);
      auto bad = [&](std::string what) {
        return Error(Errc::invalid_argument, fmt::format("{}: {}", where, what));
      };
      if (group_of[i]) {
        return bad(
            fmt::format("starts a group inside group \"{}\" (its GroupMemberCnt "
                        "reaches this slave)",
                        groups[*group_of[i]].name));
      }
      if (!hc.member_count) return bad("GroupMemberCnt (how many slaves the group has) is missing");
      if (*hc.member_count == 0 || *hc.member_count > n - i) {
        return bad(
            fmt::format("GroupMemberCnt {}: the group must hold 1..{} slaves (this one "
                        "and those after it in the file)",
                        *hc.member_count, n - i));
      }
      HotConnectGroup g;
      g.name = sanitise(hc.group_name);
      if (g.name.empty()) {
        g.name = config.slaves[i].name;
        note(fmt::format("{}: HotConnect (line {}): no GroupName; the group is named \"{}\"",
                         who(e), hc.line, g.name));
      }
      for (const auto& other : groups) {
        if (other.name == g.name) {
          return bad(fmt::format("GroupName \"{}\" is used by another group", g.name));
        }
      }
      for (const auto& cmd : hc.identify) {
        if (cmd.ado == 0x0012 && cmd.expected.size() >= 2) {
          std::uint16_t value = static_cast<std::uint16_t>(cmd.expected[0] | cmd.expected[1] << 8);
          if (cmd.mask.size() >= 2) {
            value = static_cast<std::uint16_t>(value & (cmd.mask[0] | cmd.mask[1] << 8));
          }
          if (value == 0) return bad(fmt::format("IdentifyCmd (line {}): alias 0", cmd.line));
          if (g.alias && *g.alias != value) {
            return bad(fmt::format("IdentifyCmd (line {}): alias 0x{:04X}, another says 0x{:04X}",
                                   cmd.line, value, *g.alias));
          }
          g.alias = value;
        } else if (cmd.ado == 0x0134 && cmd.expected.size() >= 2) {
          // The explicit device ID: the AL status code register after an ID request.
          std::uint16_t value = static_cast<std::uint16_t>(cmd.expected[0] | cmd.expected[1] << 8);
          if (cmd.mask.size() >= 2) {
            value = static_cast<std::uint16_t>(value & (cmd.mask[0] | cmd.mask[1] << 8));
          }
          if (value == 0) return bad(fmt::format("IdentifyCmd (line {}): device ID 0", cmd.line));
          if (g.device_id && *g.device_id != value) {
            return bad(fmt::format("IdentifyCmd (line {}): device ID {}, another says {}", cmd.line,
                                   value, *g.device_id));
          }
          g.device_id = value;
        } else if (cmd.ado == 0x0120) {
          // The ID request itself (AL control bit 5): the master sends its own.
        } else {
          note(fmt::format(
              "{}: HotConnect IdentifyCmd (line {}) reads register 0x{:04X}{}: not used; ecat "
              "recognises the group by its head's station alias (0x0012), explicit device ID "
              "(0x0134) or identity",
              who(e), cmd.line, cmd.ado, cmd.expected.empty() ? " without a value to expect" : ""));
        }
      }
      if (!g.alias && config.slaves[i].alias)
        g.alias = config.slaves[i].alias;  // Info/Identification
      for (std::size_t k = i; k < i + *hc.member_count; ++k) {
        if (k != i && eni_.slaves[k].hot_connect) {
          return Error(Errc::invalid_argument,
                       fmt::format("{}: {}: HotConnect (line {}): starts a group inside group "
                                   "\"{}\" (GroupMemberCnt {} at line {})",
                                   source_, who(eni_.slaves[k]), eni_.slaves[k].hot_connect->line,
                                   g.name, *hc.member_count, hc.line));
        }
        group_of[k] = groups.size();
        SlaveConfig s = config.slaves[k];
        s.position.reset();  // found where the group sits
        s.alias.reset();     // the group's alias identifies it
        g.slaves.push_back(std::move(s));
      }
      groups.push_back(std::move(g));
    }
    if (groups.empty()) return ok();
    // The fixed slaves' positions (AutoIncAddr, or the file's order) count the groups' slaves in
    // front of them; the master starts with the groups absent, so they are taken out.
    std::vector<SlaveConfig> fixed;
    std::uint16_t in_front = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (group_of[i]) {
        ++in_front;
        continue;
      }
      SlaveConfig s = config.slaves[i];
      if (s.position && in_front > 0) {
        s.position = static_cast<std::uint16_t>(*s.position >= in_front ? *s.position - in_front
                                                                        : *s.position);
      }
      fixed.push_back(std::move(s));
    }
    std::string listed;
    for (const auto& g : groups) {
      listed += fmt::format("{}{} ({} slave(s), by {})", listed.empty() ? "" : ", ", g.name,
                            g.slaves.size(),
                            g.device_id ? fmt::format("device ID {}", *g.device_id)
                            : g.alias   ? fmt::format("alias 0x{:04X}", *g.alias)
                                        : "identity");
    }
    note(fmt::format("HotConnect: {} group(s) may be absent and come and go: {}", groups.size(),
                     listed));
    config.slaves = std::move(fixed);
    config.hot_connect = std::move(groups);
    return ok();
  }

  void whole_file_notes() {
    if (unchecked_revisions_ > 0) {
      note(
          fmt::format("Slave/Info/RevisionNo (and SerialNo): not checked for {} slave(s); ecat "
                      "checks vendor and product code",
                      unchecked_revisions_));
    }
    for (const auto& c : eni_.cyclic) {
      std::size_t cmds = 0;
      std::string logical;
      for (const auto& frame : c.frames) {
        for (const auto& cmd : frame) {
          ++cmds;
          static const std::map<std::uint8_t, std::string_view> kNames{
              {10, "LRD"}, {11, "LWR"}, {12, "LRW"}};
          if (auto it = kNames.find(cmd.cmd); it != kNames.end() && cmd.addr) {
            if (logical.size() < 200) {
              logical += fmt::format("{}{} 0x{:08X}+{}", logical.empty() ? "" : ", ", it->second,
                                     *cmd.addr, cmd.data_length);
            }
          }
        }
      }
      note(
          fmt::format("Cyclic (line {}): {} frame(s), {} command(s){}{}: not used; ecat lays out "
                      "its own domains and logical addresses",
                      c.line, c.frames.size(), cmds, logical.empty() ? "" : ": ", logical));
    }
    if (eni_.has_process_image) {
      note(
          "ProcessImage and Slave/ProcessData Send/Recv offsets: not used; signals are named from "
          "the PDO entries and placed by ecat");
    }
    if (!eni_.master.init_cmds.empty()) {
      note(fmt::format("Master/InitCmds: {} command(s) not replayed; ecat runs its own start-up",
                       eni_.master.init_cmds.size()));
    }
    if (eni_.master.has_mailbox_states) {
      note("Master/MailboxStates: not used; ecat polls mailboxes itself");
    }
    if (eni_.master.has_eoe) note("Master/EoE: not used (ecat configures no EoE)");
    for (const auto& u : eni_.unrecognised)
      note(fmt::format("{} not recognised, not used", u));
  }

  const EniFile& eni_;
  std::string source_;
  std::vector<std::string> report_;
  std::size_t unchecked_revisions_ = 0;
};

}  // namespace

Result<EniImport> import_eni(const config::EniFile& eni, std::string source) {
  return Mapper(eni, std::move(source)).map();
}

Result<EniImport> import_eni(std::string_view xml, std::string source) {
  auto eni = config::parse_eni(xml, source);
  if (!eni) return eni.error();
  return import_eni(*eni, std::move(source));
}

Result<MasterConfig> load_master_config(const std::string& path, ConfigFileInfo* info) {
  if (info != nullptr) *info = {};
  auto text = read_file(path, FileKind::ring);
  if (!text) return std::move(text).error();
  if (!config::looks_like_eni(*text)) return parse_master_config(*text, path);
  auto imported = import_eni(std::string_view(*text), path);
  if (!imported) return imported.error();
  if (info != nullptr) {
    info->eni = true;
    info->eni_report = std::move(imported->report);
  }
  return std::move(imported->config);
}

}  // namespace ecat::master
