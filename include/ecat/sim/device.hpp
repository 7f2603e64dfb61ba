// Simulated devices: an Esc whose Application behaves like a particular slave (a coupler, a
// digital input terminal, a CiA 402 drive, a device rebuilt from a real EEPROM image ...).
//
// A device is built from a DeviceConfig by make_device(). Its application exposes named signals
// (channel values, temperatures, positions) so that tests, wiring and the control channel can
// see and drive the physical side of the device.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/esc.hpp>

namespace ecat::sim {

struct DeviceConfig {
  // A built-in profile ("EK1100", "EL1809", "EL2809", "EL3202", "EL4102", "servo", "mailbox",
  // "generic"), "eeprom" (file = an SII image) or "esi" (file = ESI XML, options["product"]
  // selects the device when the file holds several).
  std::string profile = "generic";
  std::string file;
  // Profile-specific settings, as text (for example {"channels", "8"}).
  std::map<std::string, std::string> options;
  // The device's distributed clock, when it has one.
  DcClockModel clock;
};

// The physical side of a device, as tests and wiring see it.
enum class SignalDirection : std::uint8_t { input, output };

struct SignalInfo {
  std::string name;  // "channel_1", "temperature_1", "position_actual", ...
  SignalDirection direction = SignalDirection::input;
  std::string type;  // "bool", "i16", "u32", "f64", ...
  std::string unit;  // "", "°C", "counts", ...
};

class DeviceApplication : public Application {
 public:
  // The device's signals: inputs the master reads, outputs the master writes.
  virtual std::vector<SignalInfo> signals() const { return {}; }
  // The present value of a signal in engineering units (an output as the device applies it, an
  // input as the device will report it). nullopt for an unknown name.
  virtual std::optional<double> signal(std::string_view name) const {
    (void)name;
    return std::nullopt;
  }
  // Forces what the device senses on an input (a wired output, a test). Returns false for an
  // unknown name or an output.
  virtual bool set_input(std::string_view name, double value) {
    (void)name;
    (void)value;
    return false;
  }
  // Releases a forced input so the device's own model drives it again.
  virtual void clear_input(std::string_view name) { (void)name; }
};

// Builds a device. Errors name the profile, file or option that was wrong.
Result<std::unique_ptr<Esc>> make_device(const DeviceConfig& config);

struct DeviceProfileInfo {
  std::string name;
  std::string description;
};
// The built-in profiles make_device knows.
std::vector<DeviceProfileInfo> device_profiles();

// The DeviceApplication of an ESC built by make_device, or nullptr.
DeviceApplication* device_application(Esc& esc) noexcept;

}  // namespace ecat::sim
