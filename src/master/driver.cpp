#include <algorithm>
#include <charconv>
#include <set>

#include <fmt/format.h>

#include <ecat/master/driver.hpp>

namespace ecat::master {

// ---- DriverConfig ------------------------------------------------------------------------------

std::optional<std::string_view> DriverConfig::text(std::string_view key) const {
  const auto it = options.find(key);
  if (it == options.end()) return std::nullopt;
  return std::string_view(it->second);
}

Result<std::optional<double>> DriverConfig::number(std::string_view key) const {
  const auto t = text(key);
  if (!t) return std::optional<double>();
  Signal probe;
  probe.name = std::string(key);
  probe.type = SignalType::real64;
  probe.bit_length = 64;
  auto v = parse_value(probe, *t);
  if (!v) {
    return Error(Errc::invalid_argument,
                 fmt::format("driver option {}: \"{}\" is not a number", key, *t));
  }
  return std::optional<double>(as_double(*v));
}

Result<std::optional<std::int64_t>> DriverConfig::integer(std::string_view key) const {
  const auto t = text(key);
  if (!t) return std::optional<std::int64_t>();
  Signal probe;
  probe.name = std::string(key);
  probe.type = SignalType::int64;
  probe.bit_length = 64;
  auto v = parse_value(probe, *t);
  const auto i = v ? as_int64(*v) : std::nullopt;
  if (!i) {
    return Error(Errc::invalid_argument,
                 fmt::format("driver option {}: \"{}\" is not an integer", key, *t));
  }
  return std::optional<std::int64_t>(*i);
}

Result<std::optional<bool>> DriverConfig::boolean(std::string_view key) const {
  const auto t = text(key);
  if (!t) return std::optional<bool>();
  Signal probe;
  probe.name = std::string(key);
  probe.type = SignalType::boolean;
  probe.bit_length = 1;
  auto v = parse_value(probe, *t);
  if (!v) {
    return Error(Errc::invalid_argument,
                 fmt::format("driver option {}: \"{}\" is not a boolean (true/false)", key, *t));
  }
  return std::optional<bool>(std::get<bool>(*v));
}

Result<void> DriverConfig::check_known(std::initializer_list<std::string_view> known) const {
  for (const auto& [key, value] : options) {
    if (std::find(known.begin(), known.end(), key) == known.end()) {
      std::string list;
      for (auto k : known) {
        if (!list.empty()) list += ", ";
        list += k;
      }
      return Error(Errc::invalid_argument, fmt::format("unknown driver option \"{}\" (known: {})",
                                                       key, list.empty() ? "none" : list));
    }
  }
  return ok();
}

// ---- sync
// ----------------------------------------------------------------------------------------

std::string_view to_string(SmSyncMode mode) noexcept {
  switch (mode) {
    case SmSyncMode::free_run:
      return "free_run";
    case SmSyncMode::sm_event:
      return "sm_event";
    case SmSyncMode::sync0:
      return "sync0";
    case SmSyncMode::sync1:
      return "sync1";
    case SmSyncMode::sm2_event:
      return "sm2_event";
  }
  return "unknown";
}

Result<std::vector<SdoWrite>> sync_mode_writes(const SyncSettings& sync) {
  std::vector<SdoWrite> out;
  auto add = [&](std::uint16_t object, SmSyncMode mode) {
    const auto m = static_cast<std::uint16_t>(mode);
    out.push_back(
        {object, 0x01, {static_cast<std::uint8_t>(m), static_cast<std::uint8_t>(m >> 8)}});
    if (sync.cycle_ns != 0) {
      const std::uint32_t c = sync.cycle_ns;
      out.push_back({object,
                     0x02,
                     {static_cast<std::uint8_t>(c), static_cast<std::uint8_t>(c >> 8),
                      static_cast<std::uint8_t>(c >> 16), static_cast<std::uint8_t>(c >> 24)}});
    }
  };
  if (sync.output) {
    if (*sync.output == SmSyncMode::sm2_event) {
      return Error(Errc::invalid_argument,
                   "0x1C32 (outputs) cannot use sm2_event: that mode is for inputs (0x1C33)");
    }
    add(0x1C32, *sync.output);
  }
  if (sync.input) add(0x1C33, *sync.input);
  return out;
}

// ---- values ------------------------------------------------------------------------------------

const Value* SignalValues::find(std::string_view name) const noexcept {
  const std::size_t n = size();
  for (std::size_t i = 0; i < n; ++i) {
    if (signals_[i].name == name) return &values_[i];
  }
  return nullptr;
}

const Signal* SignalValues::find_signal(std::string_view name) const noexcept {
  for (const auto& s : signals_) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

const Value* DeviceState::find(std::string_view name) const noexcept {
  for (const auto& v : values) {
    if (v.name == name) return &v.value;
  }
  return nullptr;
}

void DeviceState::set(std::string name, Value value) {
  for (auto& v : values) {
    if (v.name == name) {
      v.value = std::move(value);
      return;
    }
  }
  values.push_back({std::move(name), std::move(value)});
}

const Value* find_arg(const CommandArgs& args, std::string_view name) noexcept {
  for (const auto& a : args) {
    if (a.name == name) return &a.value;
  }
  return nullptr;
}

// ---- Driver defaults -------------------------------------------------------------------------

bool Driver::matches(const wire::SiiIdentity& identity) const {
  const auto ids = identities();
  return std::any_of(ids.begin(), ids.end(),
                     [&](const DriverIdentity& id) { return id.matches(identity); });
}

Result<std::vector<SdoWrite>> Driver::startup_sdos(const DriverConfig& config, StartupPhase phase,
                                                   const SyncSettings& sync) const {
  (void)config;
  if (phase == StartupPhase::preop) return std::vector<SdoWrite>{};
  return sync_mode_writes(sync);
}

Result<std::unique_ptr<DriverState>> Driver::init(const DriverConfig& config) const {
  (void)config;
  return std::unique_ptr<DriverState>();
}

Result<DeviceState> Driver::project_state(const SignalValues& current, const DeviceState* previous,
                                          DriverState* state) const {
  (void)previous;
  (void)state;
  DeviceState out;
  out.values.reserve(current.size());
  for (std::size_t i = 0; i < current.size(); ++i)
    out.values.push_back({current.signal(i).name, current.value(i)});
  return out;
}

Result<std::vector<OutputWrite>> Driver::set_output(const CommandArgs& args,
                                                    const SignalValues& current) {
  const Value* signal = find_arg(args, "signal");
  const Value* value = find_arg(args, "value");
  const auto* name = signal != nullptr ? std::get_if<std::string>(signal) : nullptr;
  if (name == nullptr || value == nullptr) {
    return Error(Errc::invalid_argument,
                 "command set_output needs arguments signal (a signal name) and value");
  }
  const Signal* s = current.find_signal(*name);
  if (s == nullptr) {
    return Error(Errc::not_found, fmt::format("set_output: no signal named '{}'", *name));
  }
  if (s->direction != PdoDirection::output) {
    return Error(Errc::invalid_argument, fmt::format("set_output: signal '{}' is an input", *name));
  }
  return std::vector<OutputWrite>{{*name, *value}};
}

Error Driver::unknown_command(std::string_view driver, std::string_view command) {
  return Error(Errc::not_found, fmt::format("driver {} has no command '{}'", driver, command));
}

Result<std::vector<OutputWrite>> Driver::command(std::string_view name, const CommandArgs& args,
                                                 const SignalValues& current,
                                                 const DeviceState& state,
                                                 DriverState* driver_state) const {
  (void)state;
  (void)driver_state;
  if (name == "set_output") return set_output(args, current);
  return unknown_command(this->name(), name);
}

Description Driver::describe(std::span<const Signal> model) const {
  Description d;
  d.device_type = "generic";
  for (const auto& s : model) {
    d.endpoints.push_back({s.name, s.direction, s.type, s.unit, s.name, ""});
  }
  d.commands.push_back(
      {"set_output", "write an output signal (engineering units)", {"signal", "value"}});
  return d;
}

// ---- generic driver ----------------------------------------------------------------------------

Result<std::vector<Signal>> generic_signal_model(const PdoLayout& layout) {
  std::vector<Signal> out;
  std::set<std::string> used;
  for (const auto& sm : layout.sync_managers) {
    for (const auto& pdo : sm.pdos) {
      std::string pdo_name = snake_case(pdo.name);
      if (pdo_name.empty()) pdo_name = fmt::format("pdo_{:04x}", pdo.index);
      for (const auto& e : pdo.entries) {
        if (e.padding()) continue;
        std::string entry_name = snake_case(e.name);
        if (entry_name.empty()) entry_name = fmt::format("{:04x}_{:02x}", e.index, e.subindex);
        const std::string base = pdo_name + "." + entry_name;
        std::string name = base;
        for (int n = 2; used.count(name) != 0; ++n)
          name = fmt::format("{}_{}", base, n);
        used.insert(name);
        Signal s;
        s.name = std::move(name);
        s.direction = sm.direction;
        s.sync_manager = sm.sync_manager;
        s.bit_offset = e.bit_offset;
        s.bit_length = e.bit_length;
        s.type = signal_type_for(e.data_type, e.bit_length);
        s.pdo_index = pdo.index;
        s.index = e.index;
        s.subindex = e.subindex;
        if (auto valid = validate_signal(s, sm.byte_length()); !valid) return valid.error();
        out.push_back(std::move(s));
      }
    }
  }
  return out;
}

namespace {

class GenericDriver final : public Driver {
 public:
  std::string_view name() const noexcept override { return "generic"; }
  Result<std::vector<Signal>> signal_model(const PdoLayout& layout,
                                           const DriverConfig& config) const override {
    if (auto known = config.check_known({}); !known) return known.error();
    return generic_signal_model(layout);
  }
};

}  // namespace

std::shared_ptr<const Driver> generic_driver() {
  static const std::shared_ptr<const Driver> driver = std::make_shared<GenericDriver>();
  return driver;
}

// ---- registry
// ------------------------------------------------------------------------------------

void DriverRegistry::add(std::shared_ptr<const Driver> driver) {
  if (driver) drivers_.push_back(std::move(driver));
}

std::shared_ptr<const Driver> DriverRegistry::find(const wire::SiiIdentity& identity) const {
  for (auto it = drivers_.rbegin(); it != drivers_.rend(); ++it) {
    if ((*it)->matches(identity)) return *it;
  }
  return generic_driver();
}

std::shared_ptr<const Driver> DriverRegistry::find(std::string_view name) const {
  for (auto it = drivers_.rbegin(); it != drivers_.rend(); ++it) {
    if ((*it)->name() == name) return *it;
  }
  if (name == "generic") return generic_driver();
  return nullptr;
}

}  // namespace ecat::master
