#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include <ecat/bus/bus.hpp>
#include <ecat/ipc/line_server.hpp>
#include <ecat/link/recording_link.hpp>
#include <ecat/master/control_endpoint.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/eoe.hpp>
#include <ecat/master/foe.hpp>
#include <ecat/master/mailbox_gateway.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/sii_writer.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/version.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/eoe.hpp>

#include "master/json_view.hpp"

namespace ecat::master {

namespace {

using detail::Json;

constexpr std::array<std::string_view, 35> kOps{
    "ping",          "status",       "slaves",      "slave",           "domains",
    "domain.data",   "dc",           "counters",    "events.follow",   "sdo.upload",
    "sdo.list",      "sdo.describe", "signal.read", "reg.read",        "sii.read",
    "pdos",          "foe.read",     "soe.read",    "sdo.download",    "output.write",
    "state.request", "reg.write",    "sii.write",   "alias.write",     "foe.write",
    "soe.write",     "help",         "version",     "al_status",       "capture.frames",
    "eoe.stats",     "eoe.set_ip",   "rescan",      "firmware.update", "gateway.stats"};
constexpr std::array<std::string_view, 10> kWriteOps{
    "sdo.download", "output.write", "state.request", "reg.write",  "sii.write",
    "alias.write",  "foe.write",    "soe.write",     "eoe.set_ip", "firmware.update"};

// How long firmware.update waits for the session to bring the slave back where it was.
constexpr auto kFirmwareReturnTimeout = std::chrono::seconds(30);

// Largest register range one reg.read / reg.write moves (one datagram of a standard frame).
constexpr std::size_t kMaxRegisterBytes = 1486;

}  // namespace

std::string control_error_code(Errc code) {
  std::string name(to_string(code));
  for (char& ch : name)
    ch = ch == ' ' ? '_' : static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return name;
}

namespace {

std::string error_line(std::string_view message, Errc code, const std::optional<Json>& id) {
  Json out{{"ok", false}};
  if (id) out["id"] = *id;
  out["error"] = message;
  out["code"] = control_error_code(code);
  return out.dump(-1, ' ', false, Json::error_handler_t::replace);
}

// The fields of one request, each read with the error a caller can act on.
class Request {
 public:
  explicit Request(const Json& json) : json_(json) {}

  Result<std::string> text(const char* key) const {
    auto it = json_.find(key);
    if (it == json_.end()) return missing(key);
    if (!it->is_string()) return wrong(key, "a string");
    return it->get<std::string>();
  }
  std::optional<std::string> optional_text(const char* key) const {
    auto it = json_.find(key);
    if (it == json_.end() || !it->is_string()) return std::nullopt;
    return it->get<std::string>();
  }
  // A non-negative integer up to `max`: a JSON number or a string ("0x6041" or decimal).
  Result<std::uint64_t> number(const char* key, std::uint64_t max) const {
    auto it = json_.find(key);
    if (it == json_.end()) return missing(key);
    std::optional<std::uint64_t> value;
    if (it->is_number_unsigned()) {
      value = it->get<std::uint64_t>();
    } else if (it->is_number_integer() && it->get<std::int64_t>() >= 0) {
      value = static_cast<std::uint64_t>(it->get<std::int64_t>());
    } else if (it->is_string()) {
      const std::string t = it->get<std::string>();
      const bool hex = t.size() > 2 && (t.starts_with("0x") || t.starts_with("0X"));
      const std::string digits = hex ? t.substr(2) : t;
      const char* allowed = hex ? "0123456789abcdefABCDEF" : "0123456789";
      if (!digits.empty() && digits.size() <= 16 &&
          digits.find_first_not_of(allowed) == std::string::npos) {
        value = std::stoull(digits, nullptr, hex ? 16 : 10);
      }
    }
    if (!value || *value > max) {
      return Error(Errc::invalid_argument,
                   fmt::format("{}: must be a number from 0 to {} (0x{:x})", key, max, max));
    }
    return *value;
  }
  bool flag(const char* key) const {
    auto it = json_.find(key);
    return it != json_.end() && it->is_boolean() && it->get<bool>();
  }
  Result<std::vector<std::uint8_t>> bytes(const char* key) const {
    auto t = text(key);
    if (!t) return t.error();
    std::string digits;
    for (char c : *t) {
      if (c != ' ' && c != ':') digits += c;
    }
    if (digits.size() % 2 != 0 ||
        digits.find_first_not_of("0123456789abcdefABCDEF") != std::string::npos) {
      return Error(Errc::invalid_argument,
                   fmt::format("{}: must be hex bytes (\"0a1b\" or \"0a 1b\")", key));
    }
    std::vector<std::uint8_t> out;
    for (std::size_t i = 0; i < digits.size(); i += 2)
      out.push_back(static_cast<std::uint8_t>(std::stoul(digits.substr(i, 2), nullptr, 16)));
    return out;
  }
  const Json& json() const { return json_; }

 private:
  static Error missing(const char* key) {
    return Error(Errc::invalid_argument, fmt::format("{}: missing", key));
  }
  static Error wrong(const char* key, const char* what) {
    return Error(Errc::invalid_argument, fmt::format("{}: must be {}", key, what));
  }
  const Json& json_;
};

Result<Slave*> find_slave(Master& master, const Request& r) {
  auto name = r.text("slave");
  if (!name) return name.error();
  return master.slave(*name);
}

std::optional<wire::AlState> al_state_named(std::string_view name) {
  for (const auto s : {wire::AlState::init, wire::AlState::preop, wire::AlState::bootstrap,
                       wire::AlState::safeop, wire::AlState::op}) {
    if (wire::to_string(s) == name) return s;
  }
  if (name == "boot") return wire::AlState::bootstrap;
  return std::nullopt;
}

// A JSON value as a signal value: booleans, integers, reals, "hex bytes" for byte signals.
Result<Value> signal_value(const Json& v) {
  if (v.is_boolean()) return Value(v.get<bool>());
  if (v.is_number_unsigned()) return Value(v.get<std::uint64_t>());
  if (v.is_number_integer()) return Value(v.get<std::int64_t>());
  if (v.is_number_float()) return Value(v.get<double>());
  return Error(Errc::invalid_argument, "value: must be a boolean or a number");
}

Json value_json(const Value& value) {
  return std::visit(
      [](const auto& v) -> Json {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, std::vector<std::uint8_t>>) {
          return detail::hex(v);
        } else {
          return v;
        }
      },
      value);
}

// Every registration's bytes at its offset: the process image as the application sees it
// (inputs of the latest valid cycle, outputs as staged).
Result<std::vector<std::uint8_t>> domain_image(Domain& domain) {
  const auto info = domain.info();
  std::vector<std::uint8_t> image(info.image_size, 0);
  for (const auto& reg : info.registrations) {
    auto bytes = domain.read(reg.key);
    if (!bytes) continue;  // not ready yet (no valid cycle, output never written): zeros
    std::copy_n(bytes->begin(), std::min<std::size_t>(bytes->size(), reg.size),
                image.begin() + reg.offset);
  }
  return image;
}

Result<Json> dispatch(Master& master, const Request& r, const std::string& op, bool* follow) {
  if (op == "ping") {
    return Json{{"version", ECAT_VERSION_STRING}};
  }
  if (op == "help") {
    Json ops = Json::array();
    for (auto o : kOps)
      ops.push_back(o);
    return Json{{"ops", ops}};
  }
  if (op == "status") return detail::status_json(master);
  if (op == "counters") return detail::counters_json(master.counters());
  if (op == "gateway.stats") {
    auto gateway = master.mailbox_gateway();
    if (!gateway) {
      return Error(Errc::not_found,
                   "no mailbox gateway is open (master: mailbox_gateway:, ecat serve "
                   "--mailbox-gateway)");
    }
    const MailboxGatewayStats& c = gateway->stats;
    return Json{{"address", gateway->address},
                {"port", gateway->port},
                {"queued", gateway->queued},
                {"in_flight", gateway->in_flight},
                {"datagrams", c.datagrams},
                {"malformed", c.malformed},
                {"forwarded", c.forwarded},
                {"replies", c.replies},
                {"error_replies", c.error_replies},
                {"unknown_station", c.unknown_station},
                {"unsupported", c.unsupported},
                {"too_large", c.too_large},
                {"queue_full", c.queue_full},
                {"timeouts", c.timeouts},
                {"failed", c.failed},
                {"send_errors", c.send_errors}};
  }
  if (op == "dc") return detail::dc_json(master);
  if (op == "slaves") {
    const bool verbose = r.flag("verbose");
    Json list = Json::array();
    for (const auto& s : master.slaves()) {
      auto slave = master.slave(s.name);
      if (slave) list.push_back(detail::slave_json((*slave)->info(), verbose));
    }
    return Json{{"slaves", std::move(list)}};
  }
  if (op == "slave") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    return Json{{"slave", detail::slave_json((*slave)->info(), true)}};
  }
  if (op == "domains") {
    const bool data = r.flag("data");
    Json list = Json::array();
    for (const auto& d : master.domains()) {
      Json j = detail::domain_json(d);
      if (data) {
        if (auto domain = master.domain(d.id)) {
          if (auto image = domain_image(**domain)) j["data"] = detail::hex(*image);
        }
      }
      list.push_back(std::move(j));
    }
    return Json{{"domains", std::move(list)}};
  }
  if (op == "domain.data") {
    auto id = r.text("domain");
    if (!id) return id.error();
    auto domain = master.domain(*id);
    if (!domain) return domain.error();
    auto image = domain_image(**domain);
    if (!image) return image.error();
    return Json{{"domain", *id}, {"size", image->size()}, {"data", detail::hex(*image)}};
  }
  if (op == "events.follow") {
    if (follow != nullptr) *follow = true;
    return Json{{"following", true}};
  }
  if (op == "sdo.upload" || op == "sdo.download") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto index = r.number("index", 0xFFFF);
    if (!index) return index.error();
    auto subindex = r.number("subindex", 0xFF);
    if (!subindex) return subindex.error();
    SdoOptions options;
    options.complete_access = r.flag("complete_access");
    if (op == "sdo.upload") {
      auto data = (*slave)->upload_sdo(static_cast<std::uint16_t>(*index),
                                       static_cast<std::uint8_t>(*subindex), options);
      if (!data) return data.error();
      return Json{{"size", data->size()}, {"data", detail::hex(*data)}};
    }
    auto data = r.bytes("data");
    if (!data) return data.error();
    if (data->empty()) return Error(Errc::invalid_argument, "data: at least one byte");
    auto done =
        (*slave)->download_sdo(static_cast<std::uint16_t>(*index),
                               static_cast<std::uint8_t>(*subindex), std::move(*data), options);
    if (!done) return done.error();
    return Json::object();
  }
  if (op == "sdo.list") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto list = (*slave)->object_list();
    if (!list) return list.error();
    Json indices = Json::array();
    for (auto i : *list)
      indices.push_back(fmt::format("0x{:04x}", i));
    return Json{{"objects", std::move(indices)}};
  }
  if (op == "sdo.describe") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto index = r.number("index", 0xFFFF);
    if (!index) return index.error();
    auto d = (*slave)->describe_object(static_cast<std::uint16_t>(*index));
    if (!d) return d.error();
    return Json{{"index", fmt::format("0x{:04x}", d->index)},
                {"name", d->name},
                {"data_type", d->data_type},
                {"max_subindex", d->max_subindex},
                {"object_code", static_cast<unsigned>(d->object_code)}};
  }
  if (op == "signal.read") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto signal = r.text("signal");
    if (!signal) return signal.error();
    auto value = (*slave)->read_input(*signal);
    if (!value) return value.error();
    return Json{{"value", value_json(*value)}};
  }
  if (op == "output.write") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto signal = r.text("signal");
    if (!signal) return signal.error();
    auto it = r.json().find("value");
    if (it == r.json().end()) return Error(Errc::invalid_argument, "value: missing");
    auto value = signal_value(*it);
    if (!value) return value.error();
    if (auto done = (*slave)->write_output(*signal, *value); !done) return done.error();
    return Json::object();
  }
  if (op == "state.request") {
    auto state = r.text("state");
    if (!state) return state.error();
    if (!r.optional_text("slave")) {
      Result<void> done = ok();
      if (*state == "op") {
        done = master.activate();
      } else if (*state == "safeop") {
        done = master.deactivate(TargetState::safeop);
      } else if (*state == "preop") {
        done = master.deactivate(TargetState::preop);
      } else {
        return Error(
            Errc::invalid_argument,
            fmt::format("state: '{}' is not a session target (op, safeop, preop)", *state));
      }
      if (!done) return done.error();
      return Json{{"state", std::string(to_string(master.state()))}};
    }
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    const auto target = al_state_named(*state);
    if (!target) {
      return Error(Errc::invalid_argument,
                   fmt::format("state: '{}' is not an AL state (init, preop, bootstrap, safeop, "
                               "op)",
                               *state));
    }
    if (auto done = (*slave)->request(*target); !done) return done.error();
    return Json{{"state", std::string(to_string((*slave)->state()))}};
  }
  if (op == "reg.read" || op == "reg.write") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto address = r.number("address", 0xFFFF);
    if (!address) return address.error();
    bus::Bus* bus = master.bus();
    if (bus == nullptr) return Error(Errc::not_ready, "no session runs");
    bus::Transaction tx;
    const auto station = (*slave)->station();
    if (op == "reg.read") {
      auto length = r.number("length", kMaxRegisterBytes);
      if (!length) return length.error();
      if (*length == 0) return Error(Errc::invalid_argument, "length: at least 1");
      if (*address + *length > 0x10000) {
        return Error(Errc::invalid_argument, "address + length: beyond the 64 KiB register space");
      }
      tx.fprd(station, static_cast<std::uint16_t>(*address), static_cast<std::uint16_t>(*length));
    } else {
      auto data = r.bytes("data");
      if (!data) return data.error();
      if (data->empty() || data->size() > kMaxRegisterBytes) {
        return Error(Errc::invalid_argument, fmt::format("data: 1 to {} bytes", kMaxRegisterBytes));
      }
      if (*address + data->size() > 0x10000) {
        return Error(Errc::invalid_argument, "address + length: beyond the 64 KiB register space");
      }
      tx.fpwr(station, static_cast<std::uint16_t>(*address), *data);
    }
    auto result = bus->transact(std::move(tx));
    if (!result) return result.error();
    const bus::DatagramResult d = (*result)[0];
    if (d.wkc != 1) {
      return Error(
          Errc::wkc_mismatch,
          fmt::format("slave {} (station 0x{:04x}) did not answer the {} (working "
                      "counter {})",
                      (*slave)->name(), station, op == "reg.read" ? "read" : "write", d.wkc));
    }
    Json out{{"wkc", static_cast<unsigned>(d.wkc)}};
    if (op == "reg.read") out["data"] = detail::hex(d.data);
    return out;
  }
  if (op == "version") return Json{{"version", ECAT_VERSION_STRING}};
  if (op == "al_status") {
    // Every slave's AL state and the status code it last reported, in words.
    Json list = Json::array();
    for (const auto& s : master.slaves()) {
      auto slave = master.slave(s.name);
      if (!slave) continue;
      Json j{{"name", s.name}, {"state", std::string(to_string(s.state))}};
      if (auto code = (*slave)->error()) {
        j["al_status_code"] = *code;
        j["al_status_text"] = wire::al_status_code_text(*code);
      }
      list.push_back(std::move(j));
    }
    return Json{{"slaves", std::move(list)}};
  }
  if (op == "pdos") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    const auto info = (*slave)->info();
    const auto pdo_json = [](const Pdo& p) {
      Json entries = Json::array();
      for (const auto& e : p.entries) {
        entries.push_back({{"index", fmt::format("0x{:04x}", e.index)},
                           {"subindex", e.subindex},
                           {"bit_length", e.bit_length},
                           {"data_type", e.data_type},
                           {"name", e.name}});
      }
      return Json{{"index", fmt::format("0x{:04x}", p.index)},
                  {"name", p.name},
                  {"direction", std::string(to_string(p.direction))},
                  {"fixed", p.fixed_content},
                  {"entries", std::move(entries)}};
    };
    Json sms = Json::array();
    for (const auto& sm : info.layout.sync_managers) {
      Json pdos = Json::array();
      for (const auto& p : sm.pdos)
        pdos.push_back(pdo_json(p));
      sms.push_back({{"sync_manager", sm.sync_manager},
                     {"direction", std::string(to_string(sm.direction))},
                     {"bytes", sm.byte_length()},
                     {"pdos", std::move(pdos)}});
    }
    Json unassigned = Json::array();
    for (const auto& p : info.layout.unassigned)
      unassigned.push_back(pdo_json(p));
    return Json{{"slave", info.name},
                {"sync_managers", std::move(sms)},
                {"unassigned", std::move(unassigned)}};
  }
  if (op == "sii.write" || op == "alias.write") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    if (op == "alias.write") {
      auto alias = r.number("alias", 0xFFFF);
      if (!alias) return alias.error();
      if (auto done = (*slave)->write_alias(static_cast<std::uint16_t>(*alias)); !done) {
        return done.error();
      }
      return Json{{"alias", *alias}};
    }
    auto data = r.bytes("data");
    if (!data) return data.error();
    if (auto done = (*slave)->write_sii(*data); !done) return done.error();
    return Json{{"size", data->size()}};
  }
  if (op == "foe.read" || op == "foe.write") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto file = r.text("file");
    if (!file) return file.error();
    FoeOptions options;
    if (r.json().contains("password")) {
      auto password = r.number("password", 0xFFFFFFFF);
      if (!password) return password.error();
      options.password = static_cast<std::uint32_t>(*password);
    }
    if (op == "foe.read") {
      auto data = (*slave)->foe_read(*file, options);
      if (!data) return data.error();
      return Json{{"size", data->size()}, {"data", detail::hex(*data)}};
    }
    auto data = r.bytes("data");
    if (!data) return data.error();
    const auto size = data->size();
    if (auto done = (*slave)->foe_write(*file, std::move(*data), options); !done) {
      return done.error();
    }
    return Json{{"size", size}};
  }
  if (op == "firmware.update") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto file = r.text("file");
    if (!file) return file.error();
    FoeOptions options;
    if (r.json().contains("password")) {
      auto password = r.number("password", 0xFFFFFFFF);
      if (!password) return password.error();
      options.password = static_cast<std::uint32_t>(*password);
    }
    auto data = r.bytes("data");
    if (!data) return data.error();
    const auto size = data->size();
    // The session brings the slave back to its state of before (as after a reconnect) once the
    // update returns, failed or not; the reply waits for that, so that the caller's next request
    // finds the slave where it was and a caller can tell "updated" from "updated, not back".
    // (A slave that was not running, in INIT, BOOTSTRAP or down, is not waited for.) An
    // operational session is waited for too: a restarted device has restarted its clock, and the
    // session recovers the DC lock after the slave is back.
    const SlaveState before = (*slave)->state();
    const bool running =
        before == SlaveState::preop || before == SlaveState::safeop || before == SlaveState::op;
    const bool session_operational = master.state() == MasterState::operational;
    auto done = (*slave)->update_firmware(*file, std::move(*data), options);
    const auto deadline = std::chrono::steady_clock::now() + kFirmwareReturnTimeout;
    // The lock is judged by the DC samples taken after the slave is back (a lock lost to the
    // restarted clock is seen only at the next samples).
    std::optional<std::uint64_t> dc_samples_when_back;
    const auto dc_samples = [&]() -> std::optional<std::uint64_t> {
      auto dc = master.dc_status();
      if (!dc || dc->samples == 0) return std::nullopt;  // no DC runtime: nothing to wait for
      return dc->samples;
    };
    const auto back = [&] {
      if ((*slave)->state() != before) return false;
      if (!session_operational) return true;
      if (!dc_samples_when_back) dc_samples_when_back = dc_samples().value_or(0);
      const auto samples = dc_samples();
      const bool dc_settled = !samples || *samples >= *dc_samples_when_back + 3;
      return dc_settled && master.state() == MasterState::operational;
    };
    while (running && !back() && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    if (!done) return done.error();
    const SlaveState now = (*slave)->state();
    if (running && now != before) {
      return Error(Errc::timeout,
                   fmt::format("slave {}: firmware written ({} bytes), but the slave is not back "
                               "in {} {} s later (it is in {})",
                               (*slave)->name(), size, to_string(before),
                               kFirmwareReturnTimeout.count(), to_string(now)));
    }
    return Json{{"size", size},
                {"file", *file},
                {"state", std::string(to_string(now))},
                {"session", std::string(to_string(master.state()))}};
  }
  if (op == "soe.read" || op == "soe.write") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    std::uint64_t drive = 0;
    if (r.json().contains("drive")) {
      auto d = r.number("drive", 7);
      if (!d) return d.error();
      drive = *d;
    }
    auto idn = r.number("idn", 0xFFFF);
    if (!idn) return idn.error();
    std::uint64_t elements = 0x40;  // the value
    if (r.json().contains("elements")) {
      auto e = r.number("elements", 0xFF);
      if (!e) return e.error();
      elements = *e;
    }
    if (op == "soe.read") {
      auto data =
          (*slave)->soe_read(static_cast<std::uint8_t>(drive), static_cast<std::uint16_t>(*idn),
                             static_cast<std::uint8_t>(elements));
      if (!data) return data.error();
      return Json{{"size", data->size()}, {"data", detail::hex(*data)}};
    }
    auto data = r.bytes("data");
    if (!data) return data.error();
    if (auto done =
            (*slave)->soe_write(static_cast<std::uint8_t>(drive), static_cast<std::uint16_t>(*idn),
                                static_cast<std::uint8_t>(elements), std::move(*data));
        !done) {
      return done.error();
    }
    return Json::object();
  }
  if (op == "eoe.stats") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto st = (*slave)->eoe_stats();
    if (!st) return st.error();
    return Json{
        {"frames_sent", st->frames_sent},         {"fragments_sent", st->fragments_sent},
        {"frames_received", st->frames_received}, {"fragments_received", st->fragments_received},
        {"frames_dropped", st->frames_dropped},   {"fragments_dropped", st->fragments_dropped},
        {"other_dropped", st->other_dropped}};
  }
  if (op == "eoe.set_ip") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    // Dotted IPv4 fields; absent ones are left out of the request (the device keeps them).
    const auto ipv4 = [&](const char* key) -> Result<std::optional<std::uint32_t>> {
      auto text = r.optional_text(key);
      if (!text) return std::optional<std::uint32_t>();
      unsigned a = 0, b = 0, c = 0, d = 0;
      char tail = 0;
      if (std::sscanf(text->c_str(), "%3u.%3u.%3u.%3u%c", &a, &b, &c, &d, &tail) != 4 || a > 255 ||
          b > 255 || c > 255 || d > 255) {
        return Error(Errc::invalid_argument,
                     fmt::format("{}: '{}' is not a dotted IPv4 address", key, *text));
      }
      return std::optional<std::uint32_t>((a << 24) | (b << 16) | (c << 8) | d);
    };
    wire::EoeIpParameters p;
    auto ip = ipv4("ip");
    if (!ip) return ip.error();
    auto mask = ipv4("subnet_mask");
    if (!mask) return mask.error();
    auto gateway = ipv4("gateway");
    if (!gateway) return gateway.error();
    auto dns = ipv4("dns_server");
    if (!dns) return dns.error();
    p.ip = *ip;
    p.subnet_mask = *mask;
    p.default_gateway = *gateway;
    p.dns_server = *dns;
    if (auto mac = r.optional_text("mac")) {
      std::array<unsigned, 6> m{};
      char tail = 0;
      if (std::sscanf(mac->c_str(), "%2x:%2x:%2x:%2x:%2x:%2x%c", &m[0], &m[1], &m[2], &m[3], &m[4],
                      &m[5], &tail) != 6) {
        return Error(Errc::invalid_argument,
                     fmt::format("mac: '{}' is not six hex bytes (02:00:00:00:00:01)", *mac));
      }
      std::array<std::uint8_t, 6> bytes{};
      for (std::size_t i = 0; i < 6; ++i)
        bytes[i] = static_cast<std::uint8_t>(m[i]);
      p.mac = bytes;
    }
    if (auto name = r.optional_text("dns_name")) {
      if (name->size() > 32) return Error(Errc::invalid_argument, "dns_name: at most 32 bytes");
      p.dns_name = *name;
    }
    if (auto done = (*slave)->eoe_set_ip(p); !done) return done.error();
    return Json::object();
  }
  if (op == "rescan") {
    // What is on the wire now, read without disturbing the session (Master::scan_wire: the
    // slave count, and at every position the station address and AL status, also behind a break
    // of a redundant ring). Slaves the session does not know, and session slaves the wire no
    // longer has, are listed.
    auto wire_now = master.scan_wire();
    if (!wire_now) return wire_now.error();
    const std::size_t on_wire = wire_now->size();
    const auto known = master.slaves();
    Json list = Json::array();
    std::size_t unknown = 0;
    for (std::size_t pos = 0; pos < on_wire; ++pos) {
      const auto& at = (*wire_now)[pos];
      Json j{{"position", pos}};
      if (at.station) j["station"] = *at.station;
      if (at.al_status) {
        const auto code = static_cast<std::uint8_t>(*at.al_status & 0x0F);
        const auto state = wire::al_state_from_code(code);
        j["al_state"] = state ? std::string(wire::to_string(*state)) : fmt::format("0x{:x}", code);
        j["al_error"] = (*at.al_status & 0x10) != 0;
      }
      const auto it = std::find_if(known.begin(), known.end(),
                                   [&](const SlaveSummary& k) { return k.position == pos; });
      if (it != known.end() && j.contains("station") && j["station"] == it->station) {
        j["name"] = it->name;
      } else {
        ++unknown;
        j["name"] = nullptr;
      }
      list.push_back(std::move(j));
    }
    Json missing = Json::array();
    for (const auto& k : known) {
      if (k.position >= on_wire) missing.push_back(k.name);
    }
    return Json{{"on_wire", on_wire},
                {"in_session", known.size()},
                {"unknown", unknown},
                {"missing", std::move(missing)},
                {"slaves", std::move(list)}};
  }
  if (op == "sii.read") {
    auto slave = find_slave(master, r);
    if (!slave) return slave.error();
    auto image = (*slave)->sii_image();
    if (!image) return image.error();
    return Json{{"size", image->size()}, {"data", detail::hex(*image)}};
  }
  std::string known;
  for (auto o : kOps)
    known += (known.empty() ? "" : ", ") + std::string(o);
  return Error(Errc::invalid_argument, fmt::format("op: unknown op '{}' (known: {})", op, known));
}

}  // namespace

std::string control_socket_path(std::string_view name) {
  if (name.find('/') != std::string_view::npos) return std::string(name);
  return fmt::format("{}/ecat-master-{}.sock", ipc::runtime_dir(), name);
}

Result<std::string> find_control_endpoint(std::string_view name) {
  if (!name.empty()) {
    const std::string path = control_socket_path(name);
    if (ipc::someone_listens(path)) return path;
    return Error(Errc::not_found,
                 fmt::format("no master listens on '{}' (is it running, with a control endpoint "
                             "named '{}'? `ecat serve` has one)",
                             path, name));
  }
  const auto alive = ipc::find_sockets("ecat-master-");
  if (alive.size() == 1) return alive.front();
  if (alive.empty()) {
    return Error(Errc::not_found,
                 fmt::format("no running master with a control endpoint found (no live "
                             "ecat-master-*.sock of yours in {}); start one with `ecat serve`",
                             ipc::runtime_dir()));
  }
  std::string list;
  for (const auto& p : alive)
    list += (list.empty() ? "" : ", ") + p;
  return Error(Errc::invalid_argument,
               fmt::format("several masters are running ({}); name one with --attach", list));
}

// ---- capture.frames (live capture) ------------------------------------------------------------
namespace {

// The flight recorder's last `seconds` (default: its window), at most kMaxCaptureBytes of frame
// data (the newest kept; "complete": false says older ones were left out): 16 MiB of frames make
// about 36 MiB of JSON, within the 40 MiB of unsent output the master's endpoint allows a client
// (master.cpp, open_endpoint).
constexpr std::size_t kMaxCaptureBytes = std::size_t{16} << 20;
constexpr double kMaxCaptureSeconds = 3600.0;

Result<Json> capture_frames(const ControlAccess& access, const Json& request) {
  if (!access.flight_recorder) {
    return Error(Errc::not_found,
                 "capture.frames: this master keeps no flight recorder (`ecat serve "
                 "--flight-recorder SECONDS`)");
  }
  std::optional<std::chrono::nanoseconds> last;
  if (auto it = request.find("seconds"); it != request.end()) {
    const double seconds = it->is_number() ? it->get<double>() : -1.0;
    if (!(seconds > 0.0 && seconds <= kMaxCaptureSeconds)) {
      return Error(
          Errc::invalid_argument,
          fmt::format("seconds: must be a number above 0 and at most {}", kMaxCaptureSeconds));
    }
    last = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::duration<double>(seconds));
  }
  bool cut = false;
  const auto frames = access.flight_recorder->snapshot(last, kMaxCaptureBytes, &cut);
  Json list = Json::array();
  for (const auto& f : frames) {
    list.push_back(Json{{"t_ns", f.realtime_ns},
                        {"steady_ns", f.steady_ns},
                        {"direction", link::to_string(f.direction)},
                        {"length", f.original_length},
                        {"data", detail::hex(f.data)}});
  }
  const auto window = last ? *last : access.flight_recorder->options().window;
  return Json{{"seconds", std::chrono::duration<double>(window).count()},
              {"complete", !cut},
              {"frames", std::move(list)}};
}

}  // namespace

std::string handle_control_request(Master& master, std::string_view request,
                                   const ControlAccess& access, bool* follow) {
  const Json parsed = Json::parse(request, nullptr, false);
  if (parsed.is_discarded() || !parsed.is_object()) {
    return error_line("request: not a JSON object", Errc::malformed, std::nullopt);
  }
  std::optional<Json> id;
  if (auto it = parsed.find("id"); it != parsed.end()) {
    if (!it->is_primitive()) {
      return error_line("id: must be a string, number, boolean or null", Errc::invalid_argument,
                        std::nullopt);
    }
    id = *it;
  }
  auto op_it = parsed.find("op");
  if (op_it == parsed.end() || !op_it->is_string()) {
    return error_line("op: missing (a string such as \"status\")", Errc::invalid_argument, id);
  }
  const std::string op = op_it->get<std::string>();
  if (std::find(kWriteOps.begin(), kWriteOps.end(), op) != kWriteOps.end() &&
      !access.allow_writes) {
    return error_line(fmt::format("{}: this endpoint is read-only (the master's control endpoint "
                                  "allows writes only when configured so: control.writes: true, "
                                  "`ecat serve --writes`)",
                                  op),
                      Errc::permission_denied, id);
  }
  Result<Json> result = Error(Errc::internal, "not handled");
  try {
    result = op == "capture.frames" ? capture_frames(access, parsed)
                                    : dispatch(master, Request(parsed), op, follow);
  } catch (const std::exception& e) {
    // Nothing here throws by design; a JSON type error that slipped through is still an answer.
    result = Error(Errc::internal, fmt::format("{}: {}", op, e.what()));
  }
  if (!result) return error_line(result.error().describe(), result.error().code(), id);
  Json out{{"ok", true}};
  if (id) out["id"] = *id;
  for (auto& [key, value] : result->items())
    out[key] = value;
  return out.dump(-1, ' ', false, Json::error_handler_t::replace);
}

}  // namespace ecat::master
