// The master's sections of a ring file (docs/MASTER-CONFIG.md). Strict: unknown keys are errors
// naming file:line and the key path.
#include <cstdint>
#include <filesystem>
#include <map>
#include <sstream>

#include <fmt/format.h>

#include <ecat/master/config.hpp>
#include <ecat/master/mailbox_gateway.hpp>

#include "config/spec_tree.hpp"
#include "core/read_file.hpp"

namespace ecat::master {
namespace {

using config::detail::check_keys;
using config::detail::index_path;
using config::detail::join_path;
using config::detail::spec_error;
using config::detail::SpecContext;
using config::detail::SpecNode;
using config::detail::to_bool;
using config::detail::to_int;
using config::detail::to_text;

class Reader {
 public:
  explicit Reader(std::string source) : ctx_{std::move(source)} {}

  Result<MasterConfig> read(const SpecNode& root) {
    MasterConfig config;
    if (!root.is_mapping()) return spec_error(ctx_, root, "", "the file must be a mapping");
    if (const auto* m = root.find("master")) {
      if (auto r = master(*m, config); !r) return r.error();
    }
    if (const auto* d = root.find("domains")) {
      if (auto r = domains(*d, config); !r) return r.error();
    }
    if (const auto* s = root.find("slaves")) {
      if (auto r = slaves(*s, config); !r) return r.error();
    }
    if (const auto* dc = root.find("dc")) {
      if (auto r = distributed_clocks(*dc, config); !r) return r.error();
    }
    if (const auto* h = root.find("hot_connect")) {
      if (auto r = hot_connect(*h, config); !r) return r.error();
    }
    if (auto valid = validate(config); !valid) {
      return valid.error().context(Errc::invalid_argument, ctx_.source);
    }
    return config;
  }

 private:
  Result<std::chrono::nanoseconds> duration(const SpecNode& node, std::string_view path,
                                            std::int64_t unit_ns, std::int64_t min,
                                            std::int64_t max) {
    auto v = to_int(ctx_, node, path, min, max);
    if (!v) return v.error();
    return std::chrono::nanoseconds(*v * unit_ns);
  }

  // raw:IFACE, udp:HOST:PORT or sim:FILE (checked for shape here; opened by the tool).
  Result<std::string> to_backend(const SpecNode& node, std::string_view path) {
    if (!node.is_scalar()) return spec_error(ctx_, node, path, "must be a string");
    const std::string& text = node.text;
    for (std::string_view prefix : {"raw:", "udp:", "sim:"}) {
      if (text.size() > prefix.size() && std::string_view(text).starts_with(prefix)) return text;
    }
    return spec_error(
        ctx_, node, path,
        fmt::format("\"{}\" is not a backend (raw:IFACE, udp:HOST:PORT or sim:FILE)", text));
  }

  Result<void> master(const SpecNode& node, MasterConfig& config) {
    const std::string path = "master";
    if (!node.is_mapping()) return spec_error(ctx_, node, path, "must be a mapping");
    if (auto r =
            check_keys(ctx_, node, path,
                       {"backend", "cycle_priority", "cycle_cpu", "cycle_dma_latency_us",
                        "cycle_lock_memory", "base_station", "frame_timeout_us", "scan_poll_ms",
                        "scan_stable_ms", "scan_link_check", "scan_timeout_ms",
                        "awaiting_preop_timeout_ms", "retry_interval_ms", "link_recovery_window_ms",
                        "control", "mailbox_gateway", "mailbox_status", "hot_connect_poll_ms"});
        !r) {
      return r.error();
    }
    for (const auto& e : node.entries) {
      const auto p = join_path(path, e.key);
      const SpecNode& v = e.value;
      if (e.key == "backend") {
        auto text = to_backend(v, p);
        if (!text) return text.error();
        config.backend = std::move(*text);
      } else if (e.key == "control") {
        if (auto r = control(v, p, config.control); !r) return r.error();
      } else if (e.key == "mailbox_gateway") {
        if (auto r = gateway(v, p, config.mailbox_gateway); !r) return r.error();
      } else if (e.key == "mailbox_status") {
        auto b = to_bool(ctx_, v, p);
        if (!b) return b.error();
        config.mailbox_status = *b;
      } else if (e.key == "cycle_priority") {
        auto n = to_int(ctx_, v, p, 1, 99);
        if (!n) return n.error();
        config.cycle_thread.fifo_priority = static_cast<int>(*n);
      } else if (e.key == "cycle_cpu") {
        auto n = to_int(ctx_, v, p, 0, 1023);
        if (!n) return n.error();
        config.cycle_thread.cpu = static_cast<int>(*n);
      } else if (e.key == "cycle_dma_latency_us") {
        auto n = to_int(ctx_, v, p, 0, 1'000'000);
        if (!n) return n.error();
        config.cycle_thread.cpu_dma_latency_us = static_cast<std::int32_t>(*n);
      } else if (e.key == "scan_link_check") {
        auto b = to_bool(ctx_, v, p);
        if (!b) return b.error();
        config.scan.link_check = *b;
      } else if (e.key == "cycle_lock_memory") {
        auto b = to_bool(ctx_, v, p);
        if (!b) return b.error();
        config.cycle_thread.lock_memory = *b;
      } else if (e.key == "base_station") {
        auto n = to_int(ctx_, v, p, 1, 0xFFFF);
        if (!n) return n.error();
        config.base_station = static_cast<std::uint16_t>(*n);
      } else if (e.key == "frame_timeout_us") {
        auto d = duration(v, p, 1000, 50, 10'000'000);
        if (!d) return d.error();
        config.frame_timeout = *d;
      } else {
        auto d = duration(v, p, 1'000'000, 1, 3'600'000);
        if (!d) return d.error();
        if (e.key == "scan_poll_ms") config.scan.poll = *d;
        if (e.key == "scan_stable_ms") config.scan.stable = *d;
        if (e.key == "scan_timeout_ms") config.scan.timeout = *d;
        if (e.key == "awaiting_preop_timeout_ms") config.awaiting_preop_timeout = *d;
        if (e.key == "retry_interval_ms") config.retry_interval = *d;
        if (e.key == "link_recovery_window_ms") config.link_recovery_window = *d;
        if (e.key == "hot_connect_poll_ms") config.hot_connect_poll = *d;
      }
    }
    return ok();
  }

  // mailbox_gateway: true | false | "ADDR:PORT" | {address: "ADDR:PORT", timeout_ms: 1000,
  //                  queue: 64, workers: 4}
  Result<void> gateway(const SpecNode& node, const std::string& path,
                       MailboxGatewayConfig& config) {
    const auto address = [&](const SpecNode& v, const std::string& p) -> Result<void> {
      if (!v.is_scalar() || v.text.empty()) {
        return spec_error(ctx_, v, p, "must be ADDR:PORT, ADDR or PORT");
      }
      if (auto r = parse_mailbox_gateway_address(v.text, config); !r) {
        return spec_error(ctx_, v, p, r.error().message());
      }
      return ok();
    };
    if (node.is_scalar()) {
      if (node.text == "true" || node.text == "false") {
        auto b = to_bool(ctx_, node, path);
        if (!b) return b.error();
        config.enabled = *b;
        return ok();
      }
      config.enabled = true;
      return address(node, path);
    }
    if (!node.is_mapping()) {
      return spec_error(ctx_, node, path,
                        "must be true, ADDR:PORT or a mapping {address, timeout_ms, queue, "
                        "workers}");
    }
    if (auto r = check_keys(ctx_, node, path, {"address", "timeout_ms", "queue", "workers"}); !r) {
      return r.error();
    }
    config.enabled = true;
    for (const auto& e : node.entries) {
      const auto p = join_path(path, e.key);
      const SpecNode& v = e.value;
      if (e.key == "address") {
        if (auto r = address(v, p); !r) return r.error();
      } else if (e.key == "timeout_ms") {
        auto d = duration(v, p, 1'000'000, 1, 600'000);
        if (!d) return d.error();
        config.request_timeout = *d;
      } else if (e.key == "queue") {
        auto n = to_int(ctx_, v, p, 1, 4096);
        if (!n) return n.error();
        config.max_queued = static_cast<std::size_t>(*n);
      } else if (e.key == "workers") {
        auto n = to_int(ctx_, v, p, 1, 64);
        if (!n) return n.error();
        config.workers = static_cast<std::size_t>(*n);
      }
    }
    return ok();
  }

  // control: NAME | {name: NAME, mode: "0660", writes: true}
  Result<void> control(const SpecNode& node, const std::string& path,
                       ControlEndpointConfig& config) {
    const auto name = [&](const SpecNode& v, const std::string& p) -> Result<void> {
      if (!v.is_scalar() || v.text.empty()) {
        return spec_error(ctx_, v, p, "must be an endpoint name or a socket path");
      }
      if (v.text.size() > 100) {
        return spec_error(ctx_, v, p, "is longer than 100 characters (a socket path's limit)");
      }
      config.name = v.text;
      return ok();
    };
    if (node.is_scalar()) return name(node, path);
    if (!node.is_mapping()) {
      return spec_error(ctx_, node, path, "must be a name or a mapping {name, mode, writes}");
    }
    if (auto r = check_keys(ctx_, node, path, {"name", "mode", "writes"}); !r) return r.error();
    for (const auto& e : node.entries) {
      const auto p = join_path(path, e.key);
      const SpecNode& v = e.value;
      if (e.key == "name") {
        if (auto r = name(v, p); !r) return r.error();
      } else if (e.key == "mode") {
        // Octal, as chmod takes it: "0660" or "660".
        const std::string& t = v.text;
        const bool octal = v.is_scalar() && !t.empty() && t.size() <= 4 &&
                           t.find_first_not_of("01234567") == std::string::npos;
        const auto mode = octal ? std::stoul(t, nullptr, 8) : 0x1000ul;
        if (mode > 0777) {
          return spec_error(ctx_, v, p, "must be an octal permission such as \"0660\"");
        }
        config.mode = static_cast<std::uint32_t>(mode);
      } else if (e.key == "writes") {
        auto b = to_bool(ctx_, v, p);
        if (!b) return b.error();
        config.allow_writes = *b;
      }
    }
    if (config.name.empty()) return spec_error(ctx_, node, path, "needs a name");
    return ok();
  }

  Result<void> domains(const SpecNode& node, MasterConfig& config) {
    if (!node.is_sequence()) return spec_error(ctx_, node, "domains", "must be a list");
    for (std::size_t i = 0; i < node.items.size(); ++i) {
      const auto& item = node.items[i];
      const auto path = index_path("domains", i);
      if (!item.is_mapping()) return spec_error(ctx_, item, path, "must be a mapping");
      if (auto r = check_keys(
              ctx_, item, path,
              {"id", "period_us", "miss_threshold", "recovery_threshold", "max_image_size"});
          !r) {
        return r.error();
      }
      DomainConfig d;
      const auto* id = item.find("id");
      if (!id) return spec_error(ctx_, item, path, "needs an id");
      auto text = to_text(ctx_, *id, join_path(path, "id"));
      if (!text) return text.error();
      d.id = *text;
      for (const auto& e : item.entries) {
        const auto p = join_path(path, e.key);
        if (e.key == "period_us") {
          auto v = duration(e.value, p, 1000, 50, 10'000'000);
          if (!v) return v.error();
          d.period = *v;
        } else if (e.key != "id") {
          auto v = to_int(ctx_, e.value, p, 1, e.key == "max_image_size" ? 1 << 20 : 1 << 30);
          if (!v) return v.error();
          if (e.key == "miss_threshold") d.miss_threshold = static_cast<std::uint32_t>(*v);
          if (e.key == "recovery_threshold") d.recovery_threshold = static_cast<std::uint32_t>(*v);
          if (e.key == "max_image_size") d.max_image_size = static_cast<std::size_t>(*v);
        }
      }
      config.domains.push_back(std::move(d));
    }
    return ok();
  }

  Result<ProcessDataRequest> process_data(const SpecNode& node, const std::string& path) {
    if (node.is_null()) return ProcessDataRequest::none();
    if (node.is_scalar()) {
      auto text = to_text(ctx_, node, path);
      if (!text) return text.error();
      if (*text == "none") return ProcessDataRequest::none();
      return ProcessDataRequest::all(*text);  // shorthand: every signal to that domain
    }
    if (node.is_mapping()) {
      if (auto r = check_keys(ctx_, node, path, {"all"}); !r) return r.error();
      const auto* all = node.find("all");
      if (!all) return spec_error(ctx_, node, path, "needs `all: DOMAIN`");
      auto text = to_text(ctx_, *all, join_path(path, "all"));
      if (!text) return text.error();
      return ProcessDataRequest::all(*text);
    }
    ProcessDataRequest request;
    request.kind = ProcessDataRequest::Kind::signals;
    for (std::size_t i = 0; i < node.items.size(); ++i) {
      const auto& item = node.items[i];
      const auto p = index_path(path, i);
      if (!item.is_mapping()) return spec_error(ctx_, item, p, "must be {signal, domain}");
      if (auto r = check_keys(ctx_, item, p, {"signal", "domain"}); !r) return r.error();
      const auto* signal = item.find("signal");
      const auto* domain = item.find("domain");
      if (!signal || !domain) return spec_error(ctx_, item, p, "needs signal and domain");
      auto s = to_text(ctx_, *signal, join_path(p, "signal"));
      if (!s) return s.error();
      auto d = to_text(ctx_, *domain, join_path(p, "domain"));
      if (!d) return d.error();
      request.routes.push_back({*s, *d});
    }
    return request;
  }

  // A startup SDO value: `value` with a `type` (u8 u16 u32 u64 i8 i16 i32 i64, or bytes given
  // as a hex string "01 02 0a").
  Result<std::vector<std::uint8_t>> sdo_value(const SpecNode& item, const std::string& path) {
    const auto* type = item.find("type");
    const auto* value = item.find("value");
    if (!value) return spec_error(ctx_, item, path, "needs a value");
    std::string t = "u32";
    if (type) {
      auto text = to_text(ctx_, *type, join_path(path, "type"));
      if (!text) return text.error();
      t = *text;
    }
    const auto vpath = join_path(path, "value");
    if (t == "bytes") {
      auto text = to_text(ctx_, *value, vpath);
      if (!text) return text.error();
      std::vector<std::uint8_t> out;
      std::istringstream in(*text);
      std::string byte;
      while (in >> byte) {
        if (byte.size() > 2 ||
            byte.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) {
          return spec_error(ctx_, *value, vpath, fmt::format("\"{}\" is not a hex byte", byte));
        }
        out.push_back(static_cast<std::uint8_t>(std::stoul(byte, nullptr, 16)));
      }
      if (out.empty()) return spec_error(ctx_, *value, vpath, "no bytes");
      return out;
    }
    static const std::map<std::string, std::pair<int, bool>> kTypes{
        {"u8", {1, false}}, {"u16", {2, false}}, {"u32", {4, false}}, {"u64", {8, false}},
        {"i8", {1, true}},  {"i16", {2, true}},  {"i32", {4, true}},  {"i64", {8, true}}};
    auto it = kTypes.find(t);
    if (it == kTypes.end()) {
      return spec_error(ctx_, type ? *type : item, join_path(path, "type"),
                        fmt::format("unknown type \"{}\" (u8..u64, i8..i64, bytes)", t));
    }
    const int size = it->second.first;
    const bool is_signed = it->second.second;
    const std::int64_t min =
        is_signed ? (size == 8 ? INT64_MIN : -(std::int64_t{1} << (8 * size - 1))) : 0;
    const std::int64_t max = size == 8 ? INT64_MAX
                                       : (is_signed ? (std::int64_t{1} << (8 * size - 1)) - 1
                                                    : (std::int64_t{1} << (8 * size)) - 1);
    auto v = to_int(ctx_, *value, vpath, min, max);
    if (!v) return v.error();
    std::vector<std::uint8_t> out(static_cast<std::size_t>(size));
    const auto raw = static_cast<std::uint64_t>(*v);
    for (int i = 0; i < size; ++i)
      out[static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(raw >> (8 * i));
    return out;
  }

  Result<void> slaves(const SpecNode& node, MasterConfig& config) {
    if (!node.is_sequence()) return spec_error(ctx_, node, "slaves", "must be a list");
    for (std::size_t i = 0; i < node.items.size(); ++i) {
      auto s = slave(node.items[i], index_path("slaves", i));
      if (!s) return s.error();
      config.slaves.push_back(std::move(*s));
    }
    return ok();
  }

  // hot_connect: [{group, alias | vendor_id + product_code | identify: {device_id}, reserve_bytes,
  //                slaves: [...]}]
  Result<void> hot_connect(const SpecNode& node, MasterConfig& config) {
    if (!node.is_sequence()) return spec_error(ctx_, node, "hot_connect", "must be a list");
    for (std::size_t i = 0; i < node.items.size(); ++i) {
      const auto& item = node.items[i];
      const auto path = index_path("hot_connect", i);
      if (!item.is_mapping()) return spec_error(ctx_, item, path, "must be a mapping");
      if (auto r = check_keys(ctx_, item, path,
                              {"group", "alias", "vendor_id", "product_code", "identify",
                               "reserve_bytes", "slaves"});
          !r) {
        return r.error();
      }
      HotConnectGroup g;
      const auto* name = item.find("group");
      if (!name) return spec_error(ctx_, item, path, "needs a group name (group: NAME)");
      auto n = to_text(ctx_, *name, join_path(path, "group"));
      if (!n) return n.error();
      if (n->empty()) return spec_error(ctx_, *name, join_path(path, "group"), "is empty");
      g.name = *n;
      const auto* list = item.find("slaves");
      if (!list) return spec_error(ctx_, item, path, "needs its slaves (slaves: [...])");
      for (const auto& e : item.entries) {
        const auto p = join_path(path, e.key);
        const SpecNode& v = e.value;
        if (e.key == "alias") {
          auto x = to_int(ctx_, v, p, 1, 0xFFFF);
          if (!x) return x.error();
          g.alias = static_cast<std::uint16_t>(*x);
        } else if (e.key == "vendor_id") {
          auto x = to_int(ctx_, v, p, 0, 0xFFFFFFFF);
          if (!x) return x.error();
          g.vendor_id = static_cast<std::uint32_t>(*x);
        } else if (e.key == "product_code") {
          auto x = to_int(ctx_, v, p, 0, 0xFFFFFFFF);
          if (!x) return x.error();
          g.product_code = static_cast<std::uint32_t>(*x);
        } else if (e.key == "identify") {
          if (!v.is_mapping()) return spec_error(ctx_, v, p, "expected {device_id: N}");
          if (auto r = check_keys(ctx_, v, p, {"device_id"}); !r) return r.error();
          const auto* id = v.find("device_id");
          if (!id)
            return spec_error(ctx_, v, p, "needs device_id (the group's explicit device ID)");
          auto x = to_int(ctx_, *id, join_path(p, "device_id"), 1, 0xFFFF);
          if (!x) return x.error();
          g.device_id = static_cast<std::uint16_t>(*x);
        } else if (e.key == "reserve_bytes") {
          auto x = to_int(ctx_, v, p, 1, 0xFFFF);
          if (!x) return x.error();
          g.reserve_bytes = static_cast<std::size_t>(*x);
        } else if (e.key == "slaves") {
          if (!v.is_sequence() || v.items.empty()) {
            return spec_error(ctx_, v, p, "must be a non-empty list");
          }
          for (std::size_t k = 0; k < v.items.size(); ++k) {
            const auto sp = index_path(p, k);
            for (const char* key : {"position", "alias"}) {
              if (v.items[k].is_mapping() && v.items[k].find(key) != nullptr) {
                return spec_error(ctx_, *v.items[k].find(key), join_path(sp, key),
                                  "is not for a hot-connect group's slave (the group is found "
                                  "where it sits, by its alias or identity)");
              }
            }
            auto s = slave(v.items[k], sp);
            if (!s) return s.error();
            g.slaves.push_back(std::move(*s));
          }
        }
      }
      config.hot_connect.push_back(std::move(g));
    }
    return ok();
  }

  Result<SlaveConfig> slave(const SpecNode& item, const std::string& path) {
    {
      if (!item.is_mapping()) return spec_error(ctx_, item, path, "must be a mapping");
      if (auto r = check_keys(
              ctx_, item, path,
              {"name", "position", "alias", "vendor_id", "product_code", "revision", "driver",
               "driver_options", "process_data", "target", "health_poll_ms", "startup_sdos",
               "pdo_source", "sync", "esi", "mailbox_status", "watchdog_us"});
          !r) {
        return r.error();
      }
      SlaveConfig s;
      const auto* name = item.find("name");
      if (!name) return spec_error(ctx_, item, path, "needs a name");
      auto n = to_text(ctx_, *name, join_path(path, "name"));
      if (!n) return n.error();
      s.name = *n;
      for (const auto& e : item.entries) {
        const auto p = join_path(path, e.key);
        const SpecNode& v = e.value;
        if (e.key == "position") {
          auto x = to_int(ctx_, v, p, 0, 0xFFFF);
          if (!x) return x.error();
          s.position = static_cast<std::uint16_t>(*x);
        } else if (e.key == "esi") {
          auto x = to_text(ctx_, v, p);
          if (!x) return x.error();
          if (x->empty()) return spec_error(ctx_, v, p, "must name an ESI file");
          // Relative to the ring file's directory.
          std::filesystem::path file(*x);
          const auto base = std::filesystem::path(ctx_.source).parent_path();
          if (file.is_relative() && !base.empty()) file = base / file;
          s.esi_file = file.string();
        } else if (e.key == "alias") {
          auto x = to_int(ctx_, v, p, 1, 0xFFFF);
          if (!x) return x.error();
          s.alias = static_cast<std::uint16_t>(*x);
        } else if (e.key == "vendor_id" || e.key == "product_code" || e.key == "revision") {
          auto x = to_int(ctx_, v, p, 0, 0xFFFFFFFFll);
          if (!x) return x.error();
          auto& field = e.key == "vendor_id"      ? s.vendor_id
                        : e.key == "product_code" ? s.product_code
                                                  : s.revision;
          field = static_cast<std::uint32_t>(*x);
        } else if (e.key == "driver") {
          auto x = to_text(ctx_, v, p);
          if (!x) return x.error();
          s.driver = *x;
        } else if (e.key == "driver_options") {
          if (!v.is_mapping()) return spec_error(ctx_, v, p, "must be a mapping");
          for (const auto& o : v.entries) {
            auto x = to_text(ctx_, o.value, join_path(p, o.key));
            if (!x) return x.error();
            s.driver_config.options[o.key] = *x;
          }
        } else if (e.key == "process_data") {
          auto x = process_data(v, p);
          if (!x) return x.error();
          s.process_data = std::move(*x);
        } else if (e.key == "target") {
          auto x = to_text(ctx_, v, p);
          if (!x) return x.error();
          if (*x == "op") {
            s.target = TargetState::op;
          } else if (*x == "safeop") {
            s.target = TargetState::safeop;
          } else if (*x == "preop") {
            s.target = TargetState::preop;
          } else {
            return spec_error(ctx_, v, p,
                              fmt::format("unknown target \"{}\" (op, safeop, preop)", *x));
          }
        } else if (e.key == "mailbox_status") {
          auto b = to_bool(ctx_, v, p);
          if (!b) return b.error();
          s.mailbox_status = *b;
        } else if (e.key == "health_poll_ms") {
          if (v.is_null()) {
            s.health_poll.reset();
          } else {
            auto x = to_int(ctx_, v, p, 0, 3'600'000);
            if (!x) return x.error();
            if (*x == 0) {
              s.health_poll.reset();
            } else {
              s.health_poll = std::chrono::milliseconds(*x);
            }
          }
        } else if (e.key == "watchdog_us") {
          // 0: off; the ESC's registers reach 171.8 s.
          auto d = duration(v, p, 1000, 0, 171'000'000);
          if (!d) return d.error();
          s.watchdog = *d;
        } else if (e.key == "pdo_source") {
          auto x = to_text(ctx_, v, p);
          if (!x) return x.error();
          if (*x == "sii") {
            s.pdo_source = SlaveConfig::PdoSource::sii;
          } else if (*x == "coe") {
            s.pdo_source = SlaveConfig::PdoSource::coe;
          } else {
            return spec_error(ctx_, v, p, fmt::format("unknown pdo_source \"{}\" (sii, coe)", *x));
          }
        } else if (e.key == "startup_sdos") {
          if (!v.is_sequence()) return spec_error(ctx_, v, p, "must be a list");
          for (std::size_t k = 0; k < v.items.size(); ++k) {
            const auto& sdo = v.items[k];
            const auto sp = index_path(p, k);
            if (!sdo.is_mapping()) return spec_error(ctx_, sdo, sp, "must be a mapping");
            if (auto r = check_keys(ctx_, sdo, sp,
                                    {"index", "subindex", "type", "value", "complete_access"});
                !r) {
              return r.error();
            }
            SdoWrite w;
            const auto* index = sdo.find("index");
            if (!index) return spec_error(ctx_, sdo, sp, "needs an index");
            auto ix = to_int(ctx_, *index, join_path(sp, "index"), 0, 0xFFFF);
            if (!ix) return ix.error();
            w.index = static_cast<std::uint16_t>(*ix);
            if (const auto* sub = sdo.find("subindex")) {
              auto sx = to_int(ctx_, *sub, join_path(sp, "subindex"), 0, 0xFF);
              if (!sx) return sx.error();
              w.subindex = static_cast<std::uint8_t>(*sx);
            }
            if (const auto* ca = sdo.find("complete_access")) {
              auto b = to_bool(ctx_, *ca, join_path(sp, "complete_access"));
              if (!b) return b.error();
              w.complete_access = *b;
            }
            auto data = sdo_value(sdo, sp);
            if (!data) return data.error();
            w.data = std::move(*data);
            s.startup_sdos.push_back(std::move(w));
          }
        } else if (e.key == "sync") {
          auto x = sync(v, p);
          if (!x) return x.error();
          s.sync = std::move(*x);
        }
      }
      return s;
    }
  }

  // [{name, unit: 0|1, edge: rising|falling}, ...]
  Result<std::vector<LatchConfig>> latch_list(const SpecNode& node, const std::string& path) {
    if (!node.is_sequence()) return spec_error(ctx_, node, path, "must be a list");
    std::vector<LatchConfig> out;
    for (std::size_t i = 0; i < node.items.size(); ++i) {
      const SpecNode& item = node.items[i];
      const auto p = fmt::format("{}[{}]", path, i);
      if (!item.is_mapping()) return spec_error(ctx_, item, p, "must be a mapping");
      if (auto r = check_keys(ctx_, item, p, {"name", "unit", "edge"}); !r) return r.error();
      LatchConfig latch;
      for (const auto& e : item.entries) {
        const auto key_path = join_path(p, e.key);
        if (e.key == "name") {
          auto x = to_text(ctx_, e.value, key_path);
          if (!x) return x.error();
          latch.name = *x;
        } else if (e.key == "unit") {
          auto x = to_int(ctx_, e.value, key_path, 0, 1);
          if (!x) return x.error();
          latch.unit = static_cast<std::uint8_t>(*x);
        } else {
          auto x = to_text(ctx_, e.value, key_path);
          if (!x) return x.error();
          if (*x != "rising" && *x != "falling") {
            return spec_error(ctx_, e.value, key_path,
                              fmt::format("unknown edge \"{}\" (rising, falling)", *x));
          }
          latch.edge = *x == "rising" ? LatchEdge::rising : LatchEdge::falling;
        }
      }
      if (latch.name.empty()) return spec_error(ctx_, item, p, "a latch needs a name");
      out.push_back(std::move(latch));
    }
    return out;
  }

  Result<SyncConfig> sync(const SpecNode& node, const std::string& path) {
    if (!node.is_mapping()) return spec_error(ctx_, node, path, "must be a mapping");
    if (auto r = check_keys(
            ctx_, node, path,
            {"mode", "pulse_ns", "shift_ns", "sync1_offset_ns", "assign_activate", "latches"});
        !r) {
      return r.error();
    }
    SyncConfig sc;
    for (const auto& e : node.entries) {
      const auto p = join_path(path, e.key);
      if (e.key == "mode") {
        auto x = to_text(ctx_, e.value, p);
        if (!x) return x.error();
        if (*x == "free_run") {
          sc.mode = SyncMode::free_run;
        } else if (*x == "sync0") {
          sc.mode = SyncMode::sync0;
        } else if (*x == "sync1") {
          sc.mode = SyncMode::sync1;
        } else if (*x == "sm_synchronous") {
          sc.mode = SyncMode::sm_synchronous;
        } else {
          return spec_error(
              ctx_, e.value, p,
              fmt::format("unknown mode \"{}\" (free_run, sm_synchronous, sync0, sync1)", *x));
        }
      } else if (e.key == "assign_activate") {
        auto x = to_int(ctx_, e.value, p, 0, 0xFFFF);
        if (!x) return x.error();
        sc.assign_activate = static_cast<std::uint16_t>(*x);
      } else if (e.key == "latches") {
        auto latches = latch_list(e.value, p);
        if (!latches) return latches.error();
        sc.latches = std::move(*latches);
      } else {
        auto x = to_int(ctx_, e.value, p, e.key == "shift_ns" ? -1'000'000'000 : 0, 4'000'000'000);
        if (!x) return x.error();
        const std::chrono::nanoseconds d(*x);
        if (e.key == "pulse_ns") sc.sync0_pulse = d;
        if (e.key == "shift_ns") sc.sync0_shift = d;
        if (e.key == "sync1_offset_ns") sc.sync1_offset = d;
      }
    }
    return sc;
  }

  Result<void> distributed_clocks(const SpecNode& node, MasterConfig& config) {
    if (node.is_null()) {
      config.dc.reset();
      return ok();
    }
    if (node.is_scalar()) {
      auto on = to_bool(ctx_, node, "dc");
      if (!on) return on.error();
      if (*on) {
        config.dc = DcConfig{};
      } else {
        config.dc.reset();
      }
      return ok();
    }
    if (!node.is_mapping()) return spec_error(ctx_, node, "dc", "must be a mapping or false");
    if (auto r =
            check_keys(ctx_, node, "dc",
                       {"cycle_us", "await_lock", "lock_policy", "lock_threshold_ns",
                        "lock_timeout_ms", "warmup_cycles", "follow_reference", "frame_lead_us"});
        !r) {
      return r.error();
    }
    DcConfig dc;
    for (const auto& e : node.entries) {
      const auto p = join_path("dc", e.key);
      if (e.key == "cycle_us") {
        auto x = duration(e.value, p, 1000, 50, 1'000'000);
        if (!x) return x.error();
        dc.cycle = *x;
      } else if (e.key == "await_lock") {
        auto x = to_bool(ctx_, e.value, p);
        if (!x) return x.error();
        dc.await_lock = *x;
      } else if (e.key == "lock_policy") {
        auto x = to_text(ctx_, e.value, p);
        if (!x) return x.error();
        if (*x == "advisory") {
          dc.lock_policy = LockPolicy::advisory;
        } else if (*x == "recovering") {
          dc.lock_policy = LockPolicy::recovering;
        } else if (*x == "fatal") {
          dc.lock_policy = LockPolicy::fatal;
        } else {
          return spec_error(
              ctx_, e.value, p,
              fmt::format("unknown lock_policy \"{}\" (advisory, recovering, fatal)", *x));
        }
      } else if (e.key == "lock_threshold_ns") {
        auto x = duration(e.value, p, 1, 1, 1'000'000'000);
        if (!x) return x.error();
        dc.lock_threshold = *x;
      } else if (e.key == "lock_timeout_ms") {
        auto x = duration(e.value, p, 1'000'000, 1, 3'600'000);
        if (!x) return x.error();
        dc.lock_timeout = *x;
      } else if (e.key == "warmup_cycles") {
        auto x = to_int(ctx_, e.value, p, 0, 1'000'000);
        if (!x) return x.error();
        dc.warmup_cycles = static_cast<std::uint32_t>(*x);
      } else if (e.key == "follow_reference") {
        auto x = to_bool(ctx_, e.value, p);
        if (!x) return x.error();
        dc.follow_reference = *x;
      } else if (e.key == "frame_lead_us") {
        auto x = duration(e.value, p, 1000, 0, 500'000);
        if (!x) return x.error();
        dc.frame_lead = *x;
      }
    }
    config.dc = dc;
    return ok();
  }

  SpecContext ctx_;
};

}  // namespace

Result<MasterConfig> parse_master_config(std::string_view yaml, std::string source) {
  SpecContext ctx{source};
  auto root = config::detail::parse_yaml(yaml, ctx);
  if (!root) return root.error();
  return Reader(std::move(source)).read(*root);
}

Result<MasterConfig> load_master_config(const std::string& path) {
  return load_master_config(path, nullptr);  // a ring file or an ENI (config_eni.cpp)
}

}  // namespace ecat::master
