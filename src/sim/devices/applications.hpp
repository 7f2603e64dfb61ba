// Firmware shared by several profiles (private to the simulator).
#pragma once

#include <ecat/sim/device.hpp>
#include <ecat/sim/standard_application.hpp>

#include "sim/devices/cia402.hpp"

namespace ecat::sim::devices {

// A device whose signals are the entries its default PDO layout maps (EEPROM images, ESI files).
// No firmware at all: a device whose ESC answers AL control by device emulation (couplers,
// simple I/O terminals without a microcontroller).
class NoFirmware : public DeviceApplication {
 public:
  void on_al_control(Esc& esc, std::uint16_t control) override {
    (void)esc;
    (void)control;
  }
  // Nothing time-driven (the ESC's own watchdog and DC are the ESC's).
  bool wants_advance(const Esc& esc, std::int64_t now_ns) const override {
    (void)esc;
    (void)now_ns;
    return false;
  }
};

class PdoSignalDevice : public StandardApplication {
 public:
  explicit PdoSignalDevice(StandardConfig config);
};

// A CiA 402 drive: the standard firmware with a Cia402Drive on its dictionary. Signals:
// position_actual, velocity_actual, torque_actual, statusword, mode (inputs) and controlword
// (output), for the objects the dictionary has.
class Cia402Application : public StandardApplication {
 public:
  explicit Cia402Application(StandardConfig config);
  Cia402Drive& drive() noexcept { return drive_; }

 protected:
  void reset_model() override;
  void update_inputs(std::int64_t now_ns) override;
  void outputs_changed(const std::vector<std::pair<std::uint16_t, std::uint8_t>>& changed) override;
  void object_written(std::uint16_t index, std::uint8_t subindex) override;
  void update(std::int64_t now_ns) override;
  // The drive's model moves with time: advanced before every frame.
  bool wants_advance(const Esc& esc, std::int64_t now_ns) const override {
    (void)esc;
    (void)now_ns;
    return true;
  }
  void on_state_changed(wire::AlState from, wire::AlState to) override;

 private:
  Cia402Drive drive_;
};

}  // namespace ecat::sim::devices
