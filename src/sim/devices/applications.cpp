#include "sim/devices/applications.hpp"

#include <ecat/sim/esc.hpp>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

PdoSignalDevice::PdoSignalDevice(StandardConfig config) : StandardApplication(std::move(config)) {
  for (auto& s : signals_from_layout(dictionary(), process_data())) {
    add_entry_signal(std::move(s.info), s.index, s.subindex);
  }
}

Cia402Application::Cia402Application(StandardConfig config)
    : StandardApplication(std::move(config)),
      drive_(dictionary(), [this](std::uint16_t code, std::uint8_t error_register) {
        emergency(esc(), code, error_register);
      }) {
  struct Signal {
    const char* name;
    SignalDirection direction;
    std::uint16_t index;
    const char* unit;
  };
  static constexpr Signal kSignals[] = {
      {"position_actual", SignalDirection::input, 0x6064, "counts"},
      {"velocity_actual", SignalDirection::input, 0x606C, "counts/s"},
      {"torque_actual", SignalDirection::input, 0x6077, "‰"},
      {"statusword", SignalDirection::input, 0x6041, ""},
      {"controlword", SignalDirection::output, 0x6040, ""},
      {"mode", SignalDirection::input, 0x6061, ""},
  };
  for (const auto& s : kSignals) {
    const ObjectEntry* entry = dictionary().find(s.index, 0);
    // Absent, or nothing a number can be read from (an ESI may describe the object so): no signal.
    if (entry == nullptr || !entry_number(dictionary(), s.index, 0)) continue;
    SignalInfo info;
    info.name = s.name;
    info.direction = s.direction;
    info.type = signal_type_name(*entry);
    info.unit = s.unit;
    add_entry_signal(std::move(info), s.index, 0);
  }
}

void Cia402Application::reset_model() {
  drive_.reset(esc().now_ns());
}

void Cia402Application::update_inputs(std::int64_t now_ns) {
  drive_.advance(now_ns);
}

void Cia402Application::outputs_changed(
    const std::vector<std::pair<std::uint16_t, std::uint8_t>>& changed) {
  (void)changed;
  // Set-points count even when unchanged (CSP); the state machine sees every cycle's command.
  drive_.command(esc().now_ns());
}

void Cia402Application::object_written(std::uint16_t index, std::uint8_t subindex) {
  (void)subindex;
  if (index >= 0x6000 && index <= 0x67FF) drive_.command(esc().now_ns());
}

void Cia402Application::update(std::int64_t now_ns) {
  drive_.advance(now_ns);
}

void Cia402Application::on_state_changed(wire::AlState from, wire::AlState to) {
  if (from == wire::AlState::op && to != wire::AlState::op) {
    drive_.communication_lost(esc().now_ns());
  }
}

}  // namespace ecat::sim::devices
