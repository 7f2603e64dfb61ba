#include <string>

#include <fmt/format.h>

#include <ecat/sim/device.hpp>
#include <ecat/wire/sii.hpp>

#include "sim/devices/profiles.hpp"

namespace ecat::sim {

namespace reg = wire::reg;

namespace {

// A device with an AL state machine and an identity, nothing else: for ESC-level tests and as a
// placeholder in rings.
class GenericApplication : public DeviceApplication {
 public:
  void start(Esc& esc) override { basic_.start(esc); }
  void on_al_control(Esc& esc, std::uint16_t control) override {
    basic_.on_al_control(esc, control);
  }
  bool wants_advance(const Esc& esc, std::int64_t now_ns) const override {
    return basic_.wants_advance(esc, now_ns);
  }

 private:
  BasicApplication basic_;
};

Result<std::unique_ptr<Esc>> make_generic(const DeviceConfig& config) {
  if (auto ok = devices::check_options(config, {"vendor_id", "product_code", "revision"}); !ok) {
    return ok.error();
  }
  wire::SiiImage image;
  auto vendor = devices::option_u32(config, "vendor_id", devices::kSimVendorId);
  auto product = devices::option_u32(config, "product_code", 0x00000001);
  auto revision = devices::option_u32(config, "revision", 1);
  auto serial = devices::option_u32(config, "serial", 0);
  for (auto* r : {&vendor, &product, &revision, &serial}) {
    if (!r->ok()) return r->error();
  }
  image.identity = {*vendor, *product, *revision, *serial};
  image.strings = {"Generic"};
  // PDI control 0x08 (a microcontroller runs the AL state machine) and ESC configuration 0x0C
  // (SYNC out and latch in units on): with DC units off the system time unit stays powered down
  // (0x0910.. answer with WKC 0), so DC tests could not use generic slaves. As the servo profile.
  image.pdi_control = 0x0C08;
  return devices::build_device(config, EscHardware{}, image,
                               std::make_unique<GenericApplication>());
}

struct Profile {
  const char* name;
  const char* description;
  Result<std::unique_ptr<Esc>> (*make)(const DeviceConfig&);
};

constexpr Profile kProfiles[] = {
    {"generic", "an ESC with an identity and the AL state machine, no process data", &make_generic},
    {"EK1100", "Beckhoff EK1100 EtherCAT coupler: no mailbox, no process data, 2 ports + E-bus",
     &devices::make_ek1100},
    {"EK1122",
     "Beckhoff EK1122 2-port junction: E-bus in (port 0) and out (port 3), junction ports 1 and 2",
     &devices::make_ek1122},
    {"EL1809", "Beckhoff EL1809 16 digital inputs: 16 x 1-bit TxPDOs 0x1A00..0x1A0F (2 bytes)",
     &devices::make_el1809},
    {"EL2809",
     "Beckhoff EL2809 16 digital outputs: 16 x 1-bit RxPDOs 0x1600..0x160F on SM0/SM1, watchdog",
     &devices::make_el2809},
    {"EL3202", "Beckhoff EL3202 2-channel PT100 input: CoE, 0x1A00/0x1A01, settings 0x8000/0x8010",
     &devices::make_el3202},
    {"EL4102", "Beckhoff EL4102 2-channel analog output 0..10 V: CoE, 16-bit RxPDO per channel",
     &devices::make_el4102},
    {"servo", "CiA 402 servo drive: CoE, DC SYNC0, CSP/CSV/CST/PP, remappable PDOs",
     &devices::make_servo},
    {"mailbox", "mailbox device with large objects for segmented SDO transfers, small process data",
     &devices::make_mailbox_device},
    {"soe_drive",
     "SERCOS servo drive over SoE (no CoE): IDNs S-0-0001.., fragmented reads, SII process data",
     &devices::make_soe_drive},
    {"eoe_device", "a network node over EoE (CoE + EoE, no process data): answers ARP and ping",
     &devices::make_eoe_device},
    {"eeprom", "a device rebuilt from a real SII EEPROM image (file=path)",
     &devices::make_eeprom_device},
    {"esi", "a device built from an ESI XML description (file=path, product=0x...)",
     &devices::make_esi_device},
};

}  // namespace

Result<std::unique_ptr<Esc>> make_device(const DeviceConfig& config) {
  for (const auto& p : kProfiles) {
    if (config.profile != p.name) continue;
    auto esc = p.make(config);
    if (!esc) return esc;
    if (config.start.station) (*esc)->pdi_write_u16(reg::kStationAddress, *config.start.station);
    if (config.start.al_status) {
      // AL control as the master left it: the requested state the status shows.
      const std::uint16_t status = *config.start.al_status;
      (*esc)->pdi_write_u16(reg::kAlStatus, status);
      (*esc)->pdi_write_u16(reg::kAlControl, static_cast<std::uint16_t>(status & 0x0F));
    }
    return esc;
  }
  std::string known;
  for (const auto& p : kProfiles)
    known += (known.empty() ? "" : ", ") + std::string(p.name);
  return Error(Errc::not_found,
               fmt::format("unknown device profile '{}' (known: {})", config.profile, known));
}

std::vector<DeviceProfileInfo> device_profiles() {
  std::vector<DeviceProfileInfo> out;
  for (const auto& p : kProfiles)
    out.push_back({p.name, p.description});
  return out;
}

DeviceApplication* device_application(Esc& esc) noexcept {
  return dynamic_cast<DeviceApplication*>(&esc.application());
}

}  // namespace ecat::sim
