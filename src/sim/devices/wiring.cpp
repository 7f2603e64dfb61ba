#include <string>

#include <fmt/format.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/wiring.hpp>

namespace ecat::sim {

namespace {

Result<std::size_t> device_slave(const Segment& segment, std::string_view name) {
  auto index = segment.find(name);
  if (!index) return Error(Errc::not_found, fmt::format("wiring: no slave named '{}'", name));
  return *index;
}

Result<void> check_signal(DeviceApplication& app, std::string_view slave, std::string_view signal,
                          SignalDirection direction) {
  for (const auto& s : app.signals()) {
    if (s.name != signal) continue;
    if (s.direction == direction) return {};
    return Error(Errc::invalid_argument,
                 fmt::format("wiring: signal '{}' of slave '{}' is an {}, not an {}", signal, slave,
                             s.direction == SignalDirection::input ? "input" : "output",
                             direction == SignalDirection::input ? "input" : "output"));
  }
  std::string known;
  for (const auto& s : app.signals())
    known += (known.empty() ? "" : ", ") + s.name;
  return Error(Errc::not_found, fmt::format("wiring: slave '{}' has no signal '{}' (it has: {})",
                                            slave, signal, known.empty() ? "none" : known));
}

}  // namespace

Result<void> wire_signals(Segment& segment, std::string_view from_slave,
                          std::string_view from_signal, std::string_view to_slave,
                          std::string_view to_signal) {
  auto from = device_slave(segment, from_slave);
  if (!from) return from.error();
  auto to = device_slave(segment, to_slave);
  if (!to) return to.error();
  DeviceApplication* source = device_application(segment.esc(*from));
  DeviceApplication* target = device_application(segment.esc(*to));
  if (source == nullptr || target == nullptr) {
    return Error(Errc::invalid_argument,
                 fmt::format("wiring: slave '{}' is not a device with signals",
                             source == nullptr ? from_slave : to_slave));
  }
  if (auto ok = check_signal(*source, from_slave, from_signal, SignalDirection::output); !ok) {
    return ok;
  }
  if (auto ok = check_signal(*target, to_slave, to_signal, SignalDirection::input); !ok) return ok;
  // The callback looks the devices up again by index: a power cycle keeps the Esc and its
  // application, so the pointers stay valid as long as the segment does.
  segment.add_after_frame([from_index = *from, to_index = *to, out = std::string(from_signal),
                           in = std::string(to_signal)](Segment& s, std::int64_t) {
    DeviceApplication* src = device_application(s.esc(from_index));
    DeviceApplication* dst = device_application(s.esc(to_index));
    if (src == nullptr || dst == nullptr) return;
    if (auto value = src->signal(out)) dst->set_input(in, *value);
  });
  return {};
}

}  // namespace ecat::sim
