// "eeprom": a device rebuilt from a real SII EEPROM image (file=path). The ESC serves the image
// as it is; the firmware takes the mailboxes, process-data SyncManagers and PDOs from it. Real
// images often leave the SyncManager lengths at 0: the lengths the device expects follow from the
// PDOs (an EL2004's four 1-bit RxPDOs make 1 byte), as a master computes them. An image declaring
// CoE gets an object dictionary with 0x1000, 0x1008, 0x1018 and the PDO mapping and assignment
// objects built from its PDOs (writable in PREOP when its CoE details offer PDO assignment or
// configuration), plus the ring's object presets. Signals: one per mapped entry (see
// signals_from_layout). Option firmware=none: no firmware at all, for devices whose ESC answers
// AL control by device emulation (the SII's ESC configuration must say so).

#include <fmt/format.h>

#include "core/read_file.hpp"
#include "sim/devices/applications.hpp"
#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

Result<std::unique_ptr<Esc>> make_eeprom_device(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"firmware"}); !ok) return ok.error();
  const auto firmware = config.options.find("firmware");
  const bool no_firmware = firmware != config.options.end() && firmware->second == "none";
  if (firmware != config.options.end() && !no_firmware && firmware->second != "standard") {
    return Error(Errc::invalid_argument,
                 fmt::format("profile 'eeprom': firmware '{}' is not 'standard' or 'none'",
                             firmware->second));
  }
  if (config.file.empty()) {
    return Error(Errc::invalid_argument, "profile 'eeprom' needs file=<path of an SII image>");
  }
  auto read = read_binary_file(config.file, FileKind::eeprom);
  if (!read) {
    return Error(read.error().code(), fmt::format("profile 'eeprom': {}", read.error().message()));
  }
  std::vector<std::uint8_t> eeprom = std::move(*read);
  auto decoded = wire::decode_sii(eeprom);
  if (!decoded) {
    return decoded.error().context(fmt::format("profile 'eeprom': SII image '{}'", config.file));
  }
  StandardConfig cfg;
  cfg.sii = decoded->image;
  const wire::SiiImage& sii = cfg.sii;
  const bool coe =
      sii.standard_mailbox.present() && (sii.mailbox_protocols & wire::mailbox_protocol::kCoe) != 0;
  if (coe) add_sii_identity(cfg.dictionary, sii);
  SiiDictionaryOptions options;
  options.writable = coe && sii.general &&
                     (sii.general->coe_details & (wire::sii_coe_detail::kPdoAssign |
                                                  wire::sii_coe_detail::kPdoConfiguration)) != 0;
  add_sii_process_data(cfg.dictionary, sii, options);
  cfg.dc.supported = !sii.dc.empty();
  const std::uint32_t serial_before = cfg.sii.identity.serial;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  // After the common options: a ring's preset of 0x1018:04 is what the device answers.
  apply_object_presets(cfg.dictionary, config.objects);
  if (cfg.sii.identity.serial != serial_before && eeprom.size() >= 0x20) {
    // The serial number lives outside the checksummed words: patch the image itself.
    wire::store_le32(&eeprom[2 * wire::sii_word::kSerialNumber], cfg.sii.identity.serial);
  }
  const EscHardware hw = hardware_for(sii, 4);
  if (no_firmware) {
    return build_device_from_eeprom(config, hw, std::move(eeprom), std::make_unique<NoFirmware>());
  }
  return build_device_from_eeprom(config, hw, std::move(eeprom),
                                  std::make_unique<PdoSignalDevice>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
