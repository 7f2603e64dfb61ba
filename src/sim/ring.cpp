#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <iterator>
#include <limits>
#include <map>

#include <fmt/format.h>

#include <ecat/sim/ring.hpp>
#include <ecat/sim/wiring.hpp>

#include "config/spec_tree.hpp"
#include "core/read_file.hpp"
#include "sim/fault_spec.hpp"

namespace ecat::sim {

namespace {

namespace tree = config::detail;
using tree::spec_error;
using tree::SpecContext;
using tree::SpecNode;

constexpr std::array<std::string_view, 7> kMasterSections{
    "master", "link", "slaves", "domains", "dc", "targets", "hot_connect"};
constexpr std::size_t kMaxSlaves = 4096;

// ---- Ring sections ----------------------------------------------------------------------------

bool valid_name(std::string_view name) {
  if (name.empty() || name.size() > 64) return false;
  const auto c0 = static_cast<unsigned char>(name[0]);
  if (!std::isalpha(c0) && c0 != '_') return false;
  return std::all_of(name.begin(), name.end(), [](char ch) {
    const auto c = static_cast<unsigned char>(ch);
    return std::isalnum(c) || c == '_' || c == '-';
  });
}

std::string known_profiles() {
  std::string known;
  bool eeprom = false;
  bool esi = false;
  for (const auto& p : device_profiles()) {
    known += (known.empty() ? "" : ", ") + p.name;
    eeprom = eeprom || p.name == "eeprom";
    esi = esi || p.name == "esi";
  }
  if (!eeprom) known += ", eeprom";
  if (!esi) known += ", esi";
  return known;
}

bool profile_known(const std::string& profile) {
  if (profile == "eeprom" || profile == "esi") return true;
  const auto profiles = device_profiles();
  return std::any_of(profiles.begin(), profiles.end(),
                     [&](const DeviceProfileInfo& p) { return p.name == profile; });
}

class RingParser {
 public:
  RingParser(SpecContext context, std::string base_dir)
      : c_(std::move(context)), base_dir_(std::move(base_dir)) {}

  Result<Ring> parse(const SpecNode& root) {
    Ring ring;
    ring.source = c_.source;
    if (root.is_null()) {
      return spec_error(c_, root, "", "the file is empty (expected a 'simulator:' section)");
    }
    if (!root.is_mapping()) {
      return spec_error(
          c_, root, "",
          fmt::format("expected a mapping of sections, found {}", tree::type_name(root)));
    }
    const SpecNode* simulator = nullptr;
    for (const auto& [key, value] : root.entries) {
      if (key == "simulator") {
        simulator = &value;
      } else if (key == "version") {
        auto v = tree::to_int(c_, value, "version", 1, 1);
        if (!v) return std::move(v).error();
      } else if (std::find(kMasterSections.begin(), kMasterSections.end(), key) !=
                 kMasterSections.end()) {
        ring.master_sections.push_back(key);
      } else {
        std::string master;
        for (auto s : kMasterSections)
          master += (master.empty() ? "" : ", ") + std::string(s);
        return spec_error(c_, value, key,
                          fmt::format("unknown top-level section (known: version, simulator; "
                                      "for the master: {})",
                                      master));
      }
    }
    if (simulator == nullptr) {
      return spec_error(c_, root, "",
                        "no 'simulator:' section (the simulator needs simulator.slaves)");
    }
    if (auto r = parse_simulator(*simulator, ring); !r) return std::move(r).error();
    return ring;
  }

 private:
  Result<void> parse_simulator(const SpecNode& node, Ring& ring) {
    const std::string path = "simulator";
    if (auto r = tree::check_keys(c_, node, path, {"slaves", "wiring", "faults", "redundancy"}); !r)
      return r;
    auto slaves = tree::require(c_, node, path, "slaves");
    if (!slaves) return std::move(slaves).error();
    const SpecNode& list = **slaves;
    const std::string slaves_path = "simulator.slaves";
    if (!list.is_sequence() || list.items.empty()) {
      return spec_error(c_, list, slaves_path, "expected a non-empty list of slaves");
    }
    for (std::size_t i = 0; i < list.items.size(); ++i) {
      if (auto r = parse_slave(list.items[i], tree::index_path(slaves_path, i), ring); !r) {
        return r;
      }
    }
    if (const SpecNode* wiring = node.find("wiring")) {
      const std::string wiring_path = "simulator.wiring";
      if (!wiring->is_null()) {
        if (!wiring->is_sequence()) {
          return spec_error(c_, *wiring, wiring_path, "expected a list of {from, to}");
        }
        for (std::size_t i = 0; i < wiring->items.size(); ++i) {
          if (auto r = parse_wire(wiring->items[i], tree::index_path(wiring_path, i), ring); !r) {
            return r;
          }
        }
      }
    }
    if (const SpecNode* redundancy = node.find("redundancy")) {
      if (auto r = parse_redundancy(*redundancy, ring); !r) return r;
    }
    if (const SpecNode* faults = node.find("faults")) {
      const std::string faults_path = "simulator.faults";
      if (!faults->is_null()) {
        if (!faults->is_sequence()) {
          return spec_error(c_, *faults, faults_path, "expected a list of faults");
        }
        for (std::size_t i = 0; i < faults->items.size(); ++i) {
          const std::string p = tree::index_path(faults_path, i);
          auto f = detail::parse_fault_node(c_, faults->items[i], p);
          if (!f) return std::move(f).error();
          if (auto r = check_fault_slaves(*f, faults->items[i], p, ring); !r) return r;
          ring.faults.push_back(RingFault{std::move(*f), faults->items[i].line});
        }
      }
    }
    return ok();
  }

  // simulator.redundancy: the cabling of the second master port when the ring is served
  // redundantly: {break_after: N | cut: PORT, delays: [{port, ms, from}]}.
  Result<void> parse_redundancy(const SpecNode& node, Ring& ring) {
    const std::string path = "simulator.redundancy";
    RedundantCabling cabling;
    if (!node.is_null()) {
      if (!node.is_mapping()) {
        return spec_error(c_, node, path, "expected a mapping {break_after | cut, delays}");
      }
      if (auto r = tree::check_keys(c_, node, path, {"break_after", "cut", "delays"}); !r) return r;
      const SpecNode* after = node.find("break_after");
      const SpecNode* cut = node.find("cut");
      if (after != nullptr && cut != nullptr) {
        return spec_error(c_, *cut, tree::join_path(path, "cut"),
                          "a ring breaks at one place: give break_after or cut, not both");
      }
      if (after != nullptr) {
        const std::string p = tree::join_path(path, "break_after");
        const auto max = static_cast<std::int64_t>(ring.slaves.size()) - 1;
        if (max < 1) {
          return spec_error(c_, *after, p, "a ring of one slave has no cable between slaves");
        }
        auto n = tree::to_int(c_, *after, p, 1, max);
        if (!n) return std::move(n).error();
        cabling.topology = RedundantTopology::broken_after(static_cast<std::size_t>(*n));
      }
      if (cut != nullptr) {
        auto port = master_port(*cut, tree::join_path(path, "cut"));
        if (!port) return std::move(port).error();
        cabling.topology = RedundantTopology::cut_at(*port);
      }
      if (const SpecNode* delays = node.find("delays"); delays != nullptr && !delays->is_null()) {
        const std::string dp = tree::join_path(path, "delays");
        if (!delays->is_sequence()) {
          return spec_error(c_, *delays, dp, "expected a list of {port, ms, from}");
        }
        for (std::size_t i = 0; i < delays->items.size(); ++i) {
          const SpecNode& d = delays->items[i];
          const std::string ip = tree::index_path(dp, i);
          if (auto r = tree::check_keys(c_, d, ip, {"port", "ms", "from"}); !r) return r;
          auto port_node = tree::require(c_, d, ip, "port");
          if (!port_node) return std::move(port_node).error();
          auto port = master_port(**port_node, tree::join_path(ip, "port"));
          if (!port) return std::move(port).error();
          auto ms_node = tree::require(c_, d, ip, "ms");
          if (!ms_node) return std::move(ms_node).error();
          auto ms = tree::to_double(c_, **ms_node, tree::join_path(ip, "ms"));
          if (!ms) return std::move(ms).error();
          if (!(*ms >= 0 && *ms <= 86'400'000.0)) {
            return spec_error(
                c_, **ms_node, tree::join_path(ip, "ms"),
                fmt::format("{} ms is out of range (0 to 86400000)", (*ms_node)->text));
          }
          RedundantPortDelay delay;
          delay.delay =
              std::chrono::nanoseconds(static_cast<std::int64_t>(std::llround(*ms * 1e6)));
          if (const SpecNode* from = d.find("from")) {
            auto f = master_port(*from, tree::join_path(ip, "from"));
            if (!f) return std::move(f).error();
            delay.from = *f;
          }
          cabling.delays[static_cast<std::size_t>(*port)] = delay;
        }
      }
    }
    ring.redundancy = cabling;
    return ok();
  }

  Result<wire::RedundantPort> master_port(const SpecNode& node, const std::string& path) {
    auto text = tree::to_text(c_, node, path);
    if (!text) return std::move(text).error();
    if (*text == "primary") return wire::RedundantPort::primary;
    if (*text == "secondary") return wire::RedundantPort::secondary;
    return spec_error(c_, node, path,
                      fmt::format("unknown master port '{}' (known: primary, secondary)", *text));
  }

  Result<void> check_slave_name(const std::string& name, const SpecNode& where,
                                const std::string& path, const Ring& ring) {
    if (ring.find(name) != nullptr) return ok();
    std::string known;
    const std::size_t shown = std::min<std::size_t>(ring.slaves.size(), 16);
    for (std::size_t i = 0; i < shown; ++i)
      known += (i ? ", " : "") + ring.slaves[i].name;
    if (ring.slaves.size() > shown) known += ", ...";
    return spec_error(c_, where, path, fmt::format("unknown slave '{}' (known: {})", name, known),
                      Errc::not_found);
  }

  Result<void> check_fault_slaves(const Fault& f, const SpecNode& where, const std::string& path,
                                  const Ring& ring) {
    if (f.form == Fault::Form::effect && !f.effect.slave.empty()) {
      if (auto r = check_slave_name(f.effect.slave, where, path, ring); !r) return r;
    }
    if (f.form == Fault::Form::effect && !f.effect.group.empty()) {
      std::string known;
      for (const auto& s : ring.slaves) {
        if (!s.hot_connect_group) continue;
        if (*s.hot_connect_group == f.effect.group) return ok();
        known += (known.empty() ? "" : ", ") + *s.hot_connect_group;
      }
      return spec_error(c_, where, path,
                        fmt::format("unknown hot-connect group '{}' (known: {})", f.effect.group,
                                    known.empty() ? "none" : known));
    }
    if ((f.form == Fault::Form::after_milestone || f.form == Fault::Form::wait_for) &&
        !f.milestone.slave.empty()) {
      if (auto r = check_slave_name(f.milestone.slave, where, path, ring); !r) return r;
    }
    for (const auto& step : f.steps) {
      if (auto r = check_fault_slaves(step, where, path, ring); !r) return r;
    }
    return ok();
  }

  Result<std::string> file_path(const std::string& file) const {
    std::filesystem::path p(file);
    if (p.is_relative() && !base_dir_.empty()) p = std::filesystem::path(base_dir_) / p;
    return p.lexically_normal().string();
  }

  Result<void> parse_slave(const SpecNode& node, const std::string& path, Ring& ring) {
    if (auto r = tree::check_keys(
            c_, node, path,
            {"name", "profile", "file", "options", "clock", "esc", "start", "objects", "parent",
             "port", "cable_delay_ns", "timing", "count", "hot_connect", "device_id"});
        !r) {
      return r;
    }
    RingSlave slave;
    slave.line = node.line;
    auto name_node = tree::require(c_, node, path, "name");
    if (!name_node) return std::move(name_node).error();
    const std::string name_path = tree::join_path(path, "name");
    auto name = tree::to_text(c_, **name_node, name_path);
    if (!name) return std::move(name).error();
    if (!valid_name(*name)) {
      return spec_error(c_, **name_node, name_path,
                        fmt::format("'{}' is not a slave name (letters, digits, '_' and '-', "
                                    "starting with a letter or '_', at most 64)",
                                    *name));
    }
    auto profile_node = tree::require(c_, node, path, "profile");
    if (!profile_node) return std::move(profile_node).error();
    const std::string profile_path = tree::join_path(path, "profile");
    auto profile = tree::to_text(c_, **profile_node, profile_path);
    if (!profile) return std::move(profile).error();
    if (!profile_known(*profile)) {
      return spec_error(c_, **profile_node, profile_path,
                        fmt::format("unknown profile '{}' (known: {})", *profile, known_profiles()),
                        Errc::not_found);
    }
    slave.device.profile = *profile;
    if (const SpecNode* file = node.find("file")) {
      auto text = tree::to_text(c_, *file, tree::join_path(path, "file"));
      if (!text) return std::move(text).error();
      if (text->empty()) return spec_error(c_, *file, tree::join_path(path, "file"), "empty");
      auto resolved = file_path(*text);
      if (!resolved) return std::move(resolved).error();
      slave.device.file = *resolved;
    } else if (*profile == "eeprom" || *profile == "esi") {
      return spec_error(c_, node, path,
                        fmt::format("profile '{}' needs 'file' (the {} to build the device from)",
                                    *profile, *profile == "eeprom" ? "SII image" : "ESI XML"));
    }
    if (const SpecNode* options = node.find("options")) {
      const std::string options_path = tree::join_path(path, "options");
      if (!options->is_mapping()) {
        return spec_error(c_, *options, options_path,
                          fmt::format("expected a mapping of option: value, found {}",
                                      tree::type_name(*options)));
      }
      for (const auto& [key, value] : options->entries) {
        auto text = tree::to_text(c_, value, tree::join_path(options_path, key));
        if (!text) return std::move(text).error();
        slave.device.options[key] = *text;
      }
    }
    if (const SpecNode* clock = node.find("clock")) {
      if (auto r = parse_clock(*clock, tree::join_path(path, "clock"), slave.device.clock); !r) {
        return r;
      }
    }
    if (const SpecNode* esc = node.find("esc")) {
      if (auto r = parse_esc(*esc, tree::join_path(path, "esc"), slave.device.esc); !r) return r;
    }
    if (const SpecNode* start = node.find("start")) {
      if (auto r = parse_start(*start, tree::join_path(path, "start"), slave.device.start); !r) {
        return r;
      }
    }
    if (const SpecNode* objects = node.find("objects")) {
      const std::string op = tree::join_path(path, "objects");
      if (*profile != "eeprom") {
        return spec_error(
            c_, *objects, op,
            fmt::format("profile '{}' takes no objects (only 'eeprom' does)", *profile));
      }
      if (!objects->is_sequence()) {
        return spec_error(
            c_, *objects, op,
            fmt::format("expected a list of objects, found {}", tree::type_name(*objects)));
      }
      for (std::size_t i = 0; i < objects->items.size(); ++i) {
        auto o = parse_object(objects->items[i], tree::index_path(op, i));
        if (!o) return std::move(o).error();
        slave.device.objects.push_back(std::move(*o));
      }
    }
    if (const SpecNode* timing = node.find("timing")) {
      const std::string tp = tree::join_path(path, "timing");
      if (auto r =
              tree::check_keys(c_, *timing, tp, {"processing_delay_ns", "forwarding_delay_ns"});
          !r) {
        return r;
      }
      if (const SpecNode* v = timing->find("processing_delay_ns")) {
        auto ns = tree::to_int(c_, *v, tree::join_path(tp, "processing_delay_ns"), 0, 1'000'000);
        if (!ns) return std::move(ns).error();
        slave.timing.processing_delay_ns = *ns;
      }
      if (const SpecNode* v = timing->find("forwarding_delay_ns")) {
        auto ns = tree::to_int(c_, *v, tree::join_path(tp, "forwarding_delay_ns"), 0, 1'000'000);
        if (!ns) return std::move(ns).error();
        slave.timing.forwarding_delay_ns = *ns;
      }
    }
    if (const SpecNode* delay = node.find("cable_delay_ns")) {
      auto ns = tree::to_int(c_, *delay, tree::join_path(path, "cable_delay_ns"), 0, 1'000'000);
      if (!ns) return std::move(ns).error();
      slave.cable_delay_ns = *ns;
    }
    if (ring.slaves.empty() && (node.find("parent") != nullptr || node.find("port") != nullptr)) {
      const SpecNode* where = node.find("parent") ? node.find("parent") : node.find("port");
      return spec_error(c_, *where, path,
                        "the first slave is cabled to the master: it has no parent or port");
    }
    if (const SpecNode* parent = node.find("parent")) {
      const std::string pp = tree::join_path(path, "parent");
      auto text = tree::to_text(c_, *parent, pp);
      if (!text) return std::move(text).error();
      if (auto r = check_slave_name(*text, *parent, pp, ring); !r) {
        return spec_error(c_, *parent, pp,
                          fmt::format("unknown slave '{}': a parent must be listed before its "
                                      "children",
                                      *text),
                          Errc::not_found);
      }
      slave.parent = *text;
    }
    if (const SpecNode* port = node.find("port")) {
      auto p = tree::to_int(c_, *port, tree::join_path(path, "port"), 1, 3);
      if (!p) return std::move(p).error();
      slave.port = static_cast<std::uint8_t>(*p);
    }
    if (const SpecNode* hc = node.find("hot_connect")) {
      const std::string hp = tree::join_path(path, "hot_connect");
      if (!hc->is_mapping()) {
        return spec_error(c_, *hc, hp, "expected {group: NAME, plugged: true|false}");
      }
      if (auto r = tree::check_keys(c_, *hc, hp, {"group", "plugged"}); !r) return r;
      const SpecNode* group = hc->find("group");
      if (group == nullptr) return spec_error(c_, *hc, hp, "needs a group name (group: NAME)");
      auto text = tree::to_text(c_, *group, tree::join_path(hp, "group"));
      if (!text) return std::move(text).error();
      if (text->empty()) return spec_error(c_, *group, tree::join_path(hp, "group"), "is empty");
      if (ring.slaves.empty()) {
        return spec_error(c_, *hc, hp,
                          "the first slave is cabled to the master: it cannot be hot-connected");
      }
      for (const auto& other : ring.slaves) {
        if (other.hot_connect_group == *text) {
          return spec_error(c_, *group, tree::join_path(hp, "group"),
                            fmt::format("group '{}' already starts at slave '{}' (line {})", *text,
                                        other.name, other.line));
        }
      }
      slave.hot_connect_group = *text;
      if (const SpecNode* plugged = hc->find("plugged")) {
        auto b = tree::to_bool(c_, *plugged, tree::join_path(hp, "plugged"));
        if (!b) return std::move(b).error();
        slave.plugged = *b;
      }
    }
    if (const SpecNode* id = node.find("device_id")) {
      auto v = tree::to_int(c_, *id, tree::join_path(path, "device_id"), 1, 0xFFFF);
      if (!v) return std::move(v).error();
      slave.device_id = static_cast<std::uint16_t>(*v);
    }
    std::int64_t count = 1;
    if (const SpecNode* count_node = node.find("count")) {
      auto n = tree::to_int(c_, *count_node, tree::join_path(path, "count"), 1, 1024);
      if (!n) return std::move(n).error();
      count = *n;
    }
    if (ring.slaves.size() + static_cast<std::size_t>(count) > kMaxSlaves) {
      return spec_error(c_, node, path, fmt::format("more than {} slaves", kMaxSlaves),
                        Errc::out_of_range);
    }
    for (std::int64_t k = 0; k < count; ++k) {
      RingSlave copy = slave;
      copy.name = count == 1 ? *name : fmt::format("{}_{}", *name, k + 1);
      if (k > 0) {
        copy.parent.reset();
        copy.port = 1;
        copy.hot_connect_group.reset();  // the group starts at the first copy
      }
      if (ring.find(copy.name) != nullptr) {
        return spec_error(c_, **name_node, name_path,
                          fmt::format("a slave named '{}' already exists", copy.name));
      }
      // Where it attaches, to report a port taken twice here rather than at build time.
      if (!ring.slaves.empty()) {
        std::size_t parent = ring.slaves.size() - 1;
        if (copy.parent) {
          for (std::size_t i = 0; i < ring.slaves.size(); ++i) {
            if (ring.slaves[i].name == *copy.parent) parent = i;
          }
        }
        const auto key = std::make_pair(parent, copy.port);
        if (auto it = ports_.find(key); it != ports_.end()) {
          const SpecNode* where = node.find("port") ? node.find("port") : &node;
          return spec_error(c_, *where, path,
                            fmt::format("port {} of '{}' is already cabled to '{}'", copy.port,
                                        ring.slaves[parent].name, it->second));
        }
        ports_[key] = copy.name;
      }
      ring.slaves.push_back(std::move(copy));
    }
    return ok();
  }

  // Sets `out` from the integer at `key` of `node`, when present.
  template <class T>
  Result<void> optional_int(const SpecNode& node, const std::string& path, std::string_view key,
                            std::int64_t min, std::int64_t max, std::optional<T>& out) {
    const SpecNode* v = node.find(key);
    if (v == nullptr) return ok();
    auto n = tree::to_int(c_, *v, tree::join_path(path, key), min, max);
    if (!n) return std::move(n).error();
    out = static_cast<T>(*n);
    return ok();
  }

  Result<void> optional_bool(const SpecNode& node, const std::string& path, std::string_view key,
                             std::optional<bool>& out) {
    const SpecNode* v = node.find(key);
    if (v == nullptr) return ok();
    auto b = tree::to_bool(c_, *v, tree::join_path(path, key));
    if (!b) return std::move(b).error();
    out = *b;
    return ok();
  }

  // {state: op, code: 0x001D}: the device refuses `state` with AL status code `code`.
  Result<std::pair<wire::AlState, std::uint16_t>> parse_al_refusal(const SpecNode& node,
                                                                   const std::string& path) {
    if (auto r = tree::check_keys(c_, node, path, {"state", "code"}); !r) {
      return std::move(r).error();
    }
    auto state_node = tree::require(c_, node, path, "state");
    if (!state_node) return std::move(state_node).error();
    const std::string sp = tree::join_path(path, "state");
    auto name = tree::to_text(c_, **state_node, sp);
    if (!name) return std::move(name).error();
    std::optional<wire::AlState> state;
    for (const auto& [n, st] :
         {std::pair<std::string_view, wire::AlState>{"init", wire::AlState::init},
          {"preop", wire::AlState::preop},
          {"bootstrap", wire::AlState::bootstrap},
          {"safeop", wire::AlState::safeop},
          {"op", wire::AlState::op}}) {
      if (*name == n) state = st;
    }
    if (!state) {
      return spec_error(
          c_, **state_node, sp,
          fmt::format("'{}' is not an AL state (init, preop, bootstrap, safeop, op)", *name));
    }
    auto code_node = tree::require(c_, node, path, "code");
    if (!code_node) return std::move(code_node).error();
    // 0 would be "no error": a refusal always names its reason.
    auto code = tree::to_int(c_, **code_node, tree::join_path(path, "code"), 1, 0xFFFF);
    if (!code) return std::move(code).error();
    return std::pair{*state, static_cast<std::uint16_t>(*code)};
  }

  Result<void> parse_esc(const SpecNode& node, const std::string& path, EscPreset& esc) {
    if (auto r = tree::check_keys(
            c_, node, path,
            {"type", "revision", "build", "fmmus", "sync_managers", "ram_kib", "ports", "features",
             "sii_busy_ns", "sii_read_bytes", "sii_address_bytes", "sii_emulation", "dl_control",
             "enhanced_link_detection", "al_refusals"});
        !r) {
      return r;
    }
    // 16 FMMUs / SyncManagers is the register map's limit (0x0600.., 0x0800..).
    for (auto r :
         {optional_int(node, path, "type", 0, 0xFF, esc.type),
          optional_int(node, path, "revision", 0, 0xFF, esc.revision),
          optional_int(node, path, "build", 0, 0xFFFF, esc.build),
          optional_int(node, path, "fmmus", 1, 16, esc.fmmu_count),
          optional_int(node, path, "sync_managers", 1, 16, esc.sync_manager_count),
          optional_int(node, path, "ram_kib", 0, 60, esc.ram_size_kib),
          optional_int(node, path, "ports", 0, 0xFF, esc.ports),
          optional_int(node, path, "features", 0, 0xFFFF, esc.features),
          optional_int(node, path, "sii_busy_ns", 0, 1'000'000'000, esc.sii_busy_ns),
          optional_int(node, path, "sii_read_bytes", 4, 8, esc.sii_read_bytes),
          optional_int(node, path, "sii_address_bytes", 1, 2, esc.sii_address_bytes),
          optional_int(node, path, "dl_control", 0, 0xFFFF'FFFF, esc.dl_control),
          optional_bool(node, path, "sii_emulation", esc.sii_emulation),
          optional_bool(node, path, "enhanced_link_detection", esc.enhanced_link_detection)}) {
      if (!r) return r;
    }
    if (const SpecNode* list = node.find("al_refusals")) {
      const std::string lp = tree::join_path(path, "al_refusals");
      if (!list->is_sequence()) {
        return spec_error(
            c_, *list, lp,
            fmt::format("expected a list of {{state, code}}, found {}", tree::type_name(*list)));
      }
      for (std::size_t i = 0; i < list->items.size(); ++i) {
        auto refusal = parse_al_refusal(list->items[i], tree::index_path(lp, i));
        if (!refusal) return std::move(refusal).error();
        esc.al_refusals.push_back(*refusal);
      }
    }
    if (esc.sii_read_bytes && *esc.sii_read_bytes != 4 && *esc.sii_read_bytes != 8) {
      const std::string p = tree::join_path(path, "sii_read_bytes");
      return spec_error(c_, *node.find("sii_read_bytes"), p,
                        fmt::format("{} bytes: an SII interface reads 4 or 8", *esc.sii_read_bytes),
                        Errc::out_of_range);
    }
    return ok();
  }

  Result<ObjectPreset> parse_object(const SpecNode& node, const std::string& path) {
    if (auto r =
            tree::check_keys(c_, node, path, {"index", "subindex", "value", "writable", "abort"});
        !r) {
      return std::move(r).error();
    }
    ObjectPreset o;
    auto index = tree::require(c_, node, path, "index");
    if (!index) return std::move(index).error();
    auto i = tree::to_int(c_, **index, tree::join_path(path, "index"), 0, 0xFFFF);
    if (!i) return std::move(i).error();
    o.index = static_cast<std::uint16_t>(*i);
    std::optional<std::uint8_t> sub;
    if (auto r = optional_int(node, path, "subindex", 0, 0xFF, sub); !r)
      return std::move(r).error();
    o.subindex = sub.value_or(0);
    if (const SpecNode* value = node.find("value")) {
      const std::string vp = tree::join_path(path, "value");
      auto text = tree::to_text(c_, *value, vp);
      if (!text) return std::move(text).error();
      auto bytes = hex_bytes(*text);
      if (!bytes) return spec_error(c_, *value, vp, bytes.error().message());
      o.value = std::move(*bytes);
    }
    if (const SpecNode* writable = node.find("writable")) {
      auto b = tree::to_bool(c_, *writable, tree::join_path(path, "writable"));
      if (!b) return std::move(b).error();
      o.writable = *b;
    }
    if (auto r = optional_int(node, path, "abort", 0, 0xFFFFFFFF, o.abort_code); !r) {
      return std::move(r).error();
    }
    if (o.value.empty() && !o.abort_code) {
      return spec_error(c_, node, path, "an object needs a 'value' or an 'abort' code");
    }
    return o;
  }

  // "02000000" or "02 00 00 00": the bytes as on the wire.
  static Result<std::vector<std::uint8_t>> hex_bytes(std::string_view text) {
    std::vector<std::uint8_t> out;
    int high = -1;
    for (std::size_t k = 0; k < text.size(); ++k) {
      const char ch = text[k];
      if (ch == ' ') continue;
      const int v = std::isxdigit(static_cast<unsigned char>(ch)) == 0 ? -1
                    : ch <= '9'                                        ? ch - '0'
                                : (std::tolower(ch) - 'a' + 10);
      if (v < 0) {
        return Error(Errc::invalid_argument,
                     fmt::format("'{}' at offset {} is not a hex digit (bytes as hex: "
                                 "\"02000000\")",
                                 ch, k));
      }
      if (high < 0) {
        high = v;
      } else {
        out.push_back(static_cast<std::uint8_t>(high << 4 | v));
        high = -1;
      }
      if (out.size() > 4096) return Error(Errc::out_of_range, "more than 4096 bytes");
    }
    if (high >= 0) return Error(Errc::invalid_argument, "an odd number of hex digits");
    return out;
  }

  Result<void> parse_start(const SpecNode& node, const std::string& path, StartState& start) {
    if (auto r = tree::check_keys(c_, node, path, {"station", "al_status"}); !r) return r;
    if (auto r = optional_int(node, path, "station", 0, 0xFFFF, start.station); !r) return r;
    if (auto r = optional_int(node, path, "al_status", 0, 0xFFFF, start.al_status); !r) return r;
    if (start.al_status) {
      const auto state = static_cast<std::uint8_t>(*start.al_status & 0x0F);
      if (state != 1 && state != 2 && state != 3 && state != 4 && state != 8) {
        return spec_error(c_, *node.find("al_status"), tree::join_path(path, "al_status"),
                          fmt::format("0x{:04X} holds no AL state (INIT 1, PREOP 2, BOOT 3, "
                                      "SAFEOP 4, OP 8; + 0x10 for the error flag)",
                                      *start.al_status),
                          Errc::out_of_range);
      }
    }
    return ok();
  }

  Result<void> parse_clock(const SpecNode& node, const std::string& path, DcClockModel& clock) {
    if (auto r = tree::check_keys(c_, node, path,
                                  {"drift_ppm", "offset_ns", "jitter_ns", "jitter_seed"});
        !r) {
      return r;
    }
    if (const SpecNode* v = node.find("drift_ppm")) {
      const std::string p = tree::join_path(path, "drift_ppm");
      auto ppm = tree::to_double(c_, *v, p);
      if (!ppm) return std::move(ppm).error();
      if (std::fabs(*ppm) > 1000.0) {
        return spec_error(c_, *v, p, fmt::format("{} ppm is out of range (-1000 to 1000)", v->text),
                          Errc::out_of_range);
      }
      clock.drift_ppm = *ppm;
    }
    if (const SpecNode* v = node.find("offset_ns")) {
      auto ns = tree::to_int(c_, *v, tree::join_path(path, "offset_ns"), 0, std::int64_t{1} << 62);
      if (!ns) return std::move(ns).error();
      clock.start_offset_ns = *ns;
    }
    if (const SpecNode* v = node.find("jitter_ns")) {
      auto ns = tree::to_int(c_, *v, tree::join_path(path, "jitter_ns"), 0, 1'000'000);
      if (!ns) return std::move(ns).error();
      clock.jitter_ns = *ns;
    }
    if (const SpecNode* v = node.find("jitter_seed")) {
      auto seed = tree::to_int(c_, *v, tree::join_path(path, "jitter_seed"), 0,
                               std::numeric_limits<std::int64_t>::max());
      if (!seed) return std::move(seed).error();
      clock.jitter_seed = static_cast<std::uint64_t>(*seed);
    }
    return ok();
  }

  Result<std::pair<std::string, std::string>> endpoint(const SpecNode& node,
                                                       const std::string& path, const Ring& ring) {
    auto text = tree::to_text(c_, node, path);
    if (!text) return std::move(text).error();
    const auto dot = text->find('.');
    if (dot == std::string::npos || dot == 0 || dot + 1 == text->size()) {
      return spec_error(c_, node, path,
                        fmt::format("'{}' is not SLAVE.SIGNAL (e.g. outputs.channel_1)", *text));
    }
    std::string slave = text->substr(0, dot);
    if (auto r = check_slave_name(slave, node, path, ring); !r) return std::move(r).error();
    return std::make_pair(std::move(slave), text->substr(dot + 1));
  }

  Result<void> parse_wire(const SpecNode& node, const std::string& path, Ring& ring) {
    if (auto r = tree::check_keys(c_, node, path, {"from", "to"}); !r) return r;
    auto from_node = tree::require(c_, node, path, "from");
    if (!from_node) return std::move(from_node).error();
    auto to_node = tree::require(c_, node, path, "to");
    if (!to_node) return std::move(to_node).error();
    auto from = endpoint(**from_node, tree::join_path(path, "from"), ring);
    if (!from) return std::move(from).error();
    auto to = endpoint(**to_node, tree::join_path(path, "to"), ring);
    if (!to) return std::move(to).error();
    for (const auto& w : ring.wiring) {
      if (w.to_slave == to->first && w.to_signal == to->second) {
        return spec_error(c_, **to_node, tree::join_path(path, "to"),
                          fmt::format("{}.{} is already driven by {}.{} (line {})", to->first,
                                      to->second, w.from_slave, w.from_signal, w.line));
      }
    }
    ring.wiring.push_back(RingWire{from->first, from->second, to->first, to->second, node.line});
    return ok();
  }

  SpecContext c_;
  std::string base_dir_;
  std::map<std::pair<std::size_t, std::uint8_t>, std::string> ports_;
};

}  // namespace

const RingSlave* Ring::find(std::string_view name) const noexcept {
  for (const auto& s : slaves) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

std::span<const std::string_view> ring_master_sections() noexcept {
  return kMasterSections;
}

Result<Ring> parse_ring(std::string_view text, std::string source, std::string base_dir) {
  SpecContext context{std::move(source)};
  if (text.size() > max_file_bytes(FileKind::ring)) {
    return Error(Errc::out_of_range, fmt::format("{}: larger than {}", context.source,
                                                 describe_size(max_file_bytes(FileKind::ring))));
  }
  auto root = tree::parse_yaml(text, context);
  if (!root) return std::move(root).error();
  return RingParser(context, std::move(base_dir)).parse(*root);
}

Result<Ring> load_ring(const std::string& path) {
  auto text = read_file(path, FileKind::ring);
  if (!text) return std::move(text).error();
  const std::string base = std::filesystem::path(path).parent_path().string();
  return parse_ring(*text, path, base);
}

Result<std::unique_ptr<Segment>> build_segment(const Ring& ring) {
  auto segment = std::make_unique<Segment>();
  const auto where = [&](const RingSlave& s, std::size_t i) {
    return fmt::format("{}:{}: simulator.slaves[{}] ({})", ring.source, s.line, i, s.name);
  };
  for (std::size_t i = 0; i < ring.slaves.size(); ++i) {
    const RingSlave& s = ring.slaves[i];
    auto esc = make_device(s.device);
    if (!esc) return Error(esc.error().code(), where(s, i) + ": " + esc.error().describe());
    if (s.device_id) (*esc)->set_device_id(s.device_id);
    Attachment attachment;
    if (s.parent) attachment.parent = segment->find(*s.parent);
    attachment.parent_port = s.port;
    attachment.cable_delay_ns = s.cable_delay_ns;
    auto added = segment->add_slave(s.name, std::move(*esc), attachment, s.timing);
    if (!added) return Error(added.error().code(), where(s, i) + ": " + added.error().describe());
  }
  for (std::size_t i = 0; i < ring.slaves.size(); ++i) {
    const RingSlave& s = ring.slaves[i];
    if (!s.hot_connect_group) continue;
    if (auto r = segment->add_hot_connect_group(*s.hot_connect_group, i); !r) {
      return Error(r.error().code(), where(s, i) + ": hot_connect: " + r.error().describe());
    }
    if (!s.plugged) (void)segment->plug(*s.hot_connect_group, false, 0);
  }
  for (std::size_t i = 0; i < ring.wiring.size(); ++i) {
    const RingWire& w = ring.wiring[i];
    auto wired = wire_signals(*segment, w.from_slave, w.from_signal, w.to_slave, w.to_signal);
    if (!wired) {
      return Error(wired.error().code(),
                   fmt::format("{}:{}: simulator.wiring[{}] ({}.{} -> {}.{}): {}", ring.source,
                               w.line, i, w.from_slave, w.from_signal, w.to_slave, w.to_signal,
                               wired.error().describe()));
    }
  }
  return segment;
}

}  // namespace ecat::sim
