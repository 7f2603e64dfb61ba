// The built-in device profiles and what they share (private to the simulator).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim::devices {

constexpr std::uint32_t kBeckhoffVendorId = 0x00000002;
// The simulator's own vendor ID (as the reference simulator), for devices that are not a copy of
// a real product.
constexpr std::uint32_t kSimVendorId = 0x00000ACE;

// ---- Options ---------------------------------------------------------------------------------
// A number option ("0x.." hexadecimal or decimal); `fallback` when absent.
Result<std::uint32_t> option_u32(const DeviceConfig& config, const std::string& key,
                                 std::uint32_t fallback);
Result<double> option_double(const DeviceConfig& config, const std::string& key, double fallback);
// "1"/"0", "true"/"false", "yes"/"no", "on"/"off".
Result<bool> option_bool(const DeviceConfig& config, const std::string& key, bool fallback);
// Fails naming the first option the profile does not know.
Result<void> check_options(const DeviceConfig& config,
                           std::initializer_list<std::string_view> known);
// The options every StandardApplication device understands, applied to `cfg`: serial,
// require_valid_outputs, check_fmmus, mailbox_reply_us (CoeServerConfig::reply_delay).
Result<void> apply_common_options(const DeviceConfig& config, StandardConfig& cfg);
// Option names apply_common_options reads (to pass into check_options).
inline constexpr std::string_view kCommonOptions[] = {"serial", "require_valid_outputs",
                                                      "check_fmmus", "mailbox_reply_us"};

// ---- SII building ------------------------------------------------------------------------------
// Collects STRINGS entries and hands out their 1-based indices (equal strings share one).
class SiiStrings {
 public:
  explicit SiiStrings(wire::SiiImage& image) : image_(image) {}
  std::uint8_t add(std::string_view text);

 private:
  wire::SiiImage& image_;
};

// The ESC of a Beckhoff E-bus terminal (ET1200-class: 3 FMMUs, 4 SyncManagers, 1 KiB of process
// RAM, two E-bus ports, 32-bit DC) and of the EK1100 coupler (ET1100: 8/8, 8 KiB, MII and E-bus).
EscHardware terminal_hardware();
EscHardware coupler_hardware();

// Encodes the SII, builds the ESC around `application` and sets the device's DC clock.
Result<std::unique_ptr<Esc>> build_device(const DeviceConfig& config, EscHardware hardware,
                                          const wire::SiiImage& sii,
                                          std::unique_ptr<Application> application);

// The same around an EEPROM image as it is (a real device's image).
Result<std::unique_ptr<Esc>> build_device_from_eeprom(const DeviceConfig& config,
                                                      EscHardware hardware,
                                                      std::vector<std::uint8_t> eeprom,
                                                      std::unique_ptr<Application> application);
// ESC hardware for a device described by an SII image: at least 3 FMMUs and 4 SyncManagers (as
// many as the image's FMMU / SYNCM categories list, up to 8), `ram_kib` of process RAM, the port
// types of its GENERAL category.
EscHardware hardware_for(const wire::SiiImage& sii, std::uint8_t ram_kib);

// ---- CoE objects several profiles share --------------------------------------------------------
// 0x1C32 / 0x1C33 SyncManager output / input parameter (ETG.1020): 01 synchronisation type (rw),
// 02 cycle time (rw), 04 supported synchronisation types, 05 minimum cycle time, 06 calc and
// copy time, 0C cycle time too small, 20 sync error.
OdObject make_sm_parameter(std::uint16_t index, std::uint16_t sync_type, std::uint16_t supported,
                           std::uint32_t min_cycle_ns);
// A settings entry (rw in every state, flagged "settings") whose default is its value.
template <class T>
ObjectEntry setting_entry(std::uint8_t sub, std::string name, DataType type, T value,
                          std::optional<T> max = std::nullopt) {
  auto e = make_entry_of(sub, std::move(name), type, kAccessReadWrite | kAccessSettings, value);
  e.default_value = e.value;
  if (max) e.maximum = to_le_bytes(*max, e.byte_length());
  return e;
}

// 0x1011 restore default parameters: writing "load" (0x64616F6C) to subindex 1 puts every entry
// of `objects` back to its default value; other values are refused (0x08000020).
OdObject make_restore_defaults(std::vector<std::uint16_t> objects);

// ---- Profiles --------------------------------------------------------------------------------
Result<std::unique_ptr<Esc>> make_ek1100(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_ek1122(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_el1809(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_el2809(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_el3202(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_el4102(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_servo(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_mailbox_device(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_soe_drive(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_eoe_device(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_eeprom_device(const DeviceConfig& config);
Result<std::unique_ptr<Esc>> make_esi_device(const DeviceConfig& config);

// Signals for the entries the default PDO layout maps (devices rebuilt from an EEPROM image or an
// ESI): a PDO with one entry gives its PDO name ("Channel 1" -> "channel_1"), other entries the
// name of the object they map ("Control word" -> "control_word", a RECORD entry
// "<object>_<entry>"), in snake case and made unique.
struct GeneratedSignal {
  SignalInfo info;
  std::uint16_t index = 0;
  std::uint8_t subindex = 0;
};
std::vector<GeneratedSignal> signals_from_layout(const ObjectDictionary& od,
                                                 const std::vector<ProcessDataSyncManager>& sms);

// Sets the preset entries that exist (their value; writable when the preset says so; an entry
// with an abort code keeps its value) and adds objects for the others: one VAR for a lone
// subindex 0, else a RECORD of the non-zero subindices, each entry typed by its size.
void apply_object_presets(ObjectDictionary& od, const std::vector<ObjectPreset>& presets);

// "bool", "i16", "u32", "f32", ... for an entry's type.
std::string signal_type_name(const ObjectEntry& entry);

}  // namespace ecat::sim::devices
