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
#include <utility>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/application.hpp>
#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/esc.hpp>

namespace ecat::sim {

// ESC facts that replace a profile's own, so that a ring can look like the devices of a capture
// (`ecat sim profile` writes them): the ESC information registers 0x0000..0x0009 and how the SII
// interface behaves. Unset fields keep the profile's value.
struct EscPreset {
  std::optional<std::uint8_t> type{};                // 0x0000
  std::optional<std::uint8_t> revision{};            // 0x0001
  std::optional<std::uint16_t> build{};              // 0x0002
  std::optional<std::uint8_t> fmmu_count{};          // 0x0004 (1..16)
  std::optional<std::uint8_t> sync_manager_count{};  // 0x0005 (1..16)
  std::optional<std::uint8_t> ram_size_kib{};        // 0x0006
  std::optional<std::uint8_t> ports{};               // 0x0007, the port descriptor
  // 0x0008; bit 2 (DC) also decides whether the ESC has a DC unit at all.
  std::optional<std::uint16_t> features{};
  std::optional<std::int64_t> sii_busy_ns{};        // how long an SII command keeps the busy bit
  std::optional<std::uint8_t> sii_read_bytes{};     // 4 or 8 bytes per SII read (0x0502 bit 6)
  std::optional<std::uint8_t> sii_address_bytes{};  // 1 or 2 EEPROM address bytes (bit 7)
  std::optional<bool> sii_emulation{};              // the PDI emulates the EEPROM (bit 5)
  std::optional<std::uint32_t> dl_control{};        // 0x0100..0x0103 at power-up
  std::optional<bool> enhanced_link_detection{};    // DL status bit 2, 0x0141 bit 1
  // AL states the device refuses, with the AL status code it answers (EscHardware::al_refusals).
  std::vector<std::pair<wire::AlState, std::uint16_t>> al_refusals{};
  // A `type` without `sii_read_bytes` / `dl_control` takes the datasheet's values for that ESC
  // type (esc_type_defaults()).

  bool empty() const noexcept;
  void apply(EscHardware& hardware) const;
};

// Where a slave starts instead of station 0 in INIT: a segment a master configured before the
// simulated one was "switched on" (TwinCAT's capture starts in the middle of a session).
struct StartState {
  std::optional<std::uint16_t> station{};    // configured station address (0x0010)
  std::optional<std::uint16_t> al_status{};  // AL status (0x0130): state, error bit
};

// A CoE object entry a ring sets (or adds) in a device's dictionary: the value a capture showed,
// whether the device accepted downloads, or the abort it answered with. Profile "eeprom" only.
struct ObjectPreset {
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
  std::vector<std::uint8_t> value{};  // as on the wire (little endian; strings as their bytes)
  bool writable = false;
  std::optional<std::uint32_t> abort_code{};  // every access is refused with this code
};

struct DeviceConfig {
  // A built-in profile ("EK1100", "EL1809", "EL2809", "EL3202", "EL4102", "servo", "mailbox",
  // "generic"), "eeprom" (file = an SII image) or "esi" (file = ESI XML, options["product"]
  // selects the device when the file holds several).
  std::string profile = "generic";
  std::string file{};
  // Profile-specific settings, as text (for example {"channels", "8"}).
  std::map<std::string, std::string> options{};
  // The device's distributed clock, when it has one.
  DcClockModel clock{};
  EscPreset esc{};
  StartState start{};
  std::vector<ObjectPreset> objects{};
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
