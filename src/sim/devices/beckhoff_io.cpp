// Beckhoff EK1100 coupler and the EL1809 / EL2809 digital terminals: devices without a mailbox
// whose process data the SII alone describes (one 1-bit PDO per channel).
//
// Identities: vendor 0x00000002; product codes EK1100 0x044C2C52, EL1809 0x07113052, EL2809
// 0x0AF93052 (the number in the upper word, 0x3052 "EL" / 0x2C52 "EK"); revisions of the
// -0018 production variants (0x00120000). SyncManagers as the terminals have them: the EL1809
// reads its 16 inputs through SM0 at 0x1000 (2 bytes), the EL2809 drives its outputs from the
// ESC's digital output register with SM0 (0x0F00, channels 1..8) and SM1 (0x0F01, channels
// 9..16), both with the process-data watchdog enabled. Like the real terminals (no
// microcontroller) their SII enables device emulation: the ESC mirrors AL control into AL status
// and nothing is refused (see standard_application.hpp).
#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

wire::SiiImage beckhoff_sii(std::uint32_t product_code, std::uint32_t revision,
                            std::string_view order, std::string_view group,
                            std::string_view group_name, std::string_view name,
                            std::int16_t ebus_ma, std::uint16_t ports, std::uint16_t pdi_control) {
  wire::SiiImage sii;
  sii.pdi_control = pdi_control;
  sii.identity = {kBeckhoffVendorId, product_code, revision, 0};
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add(order);
  general.group_index = strings.add(group);
  strings.add(group_name);
  general.name_index = strings.add(name);
  general.current_on_ebus_ma = ebus_ma;
  general.physical_port = ports;
  sii.general = general;
  return sii;
}

// One PDO per channel, each mapping the channel object's subindex 1 as a BOOLEAN.
void add_channel_pdos(wire::SiiImage& sii, std::vector<wire::SiiPdo>& pdos, std::uint16_t pdo_base,
                      std::uint16_t object_base, int channels, std::string_view entry_name,
                      int per_sm) {
  SiiStrings strings(sii);
  const std::uint8_t entry_name_index = strings.add(entry_name);
  for (int ch = 0; ch < channels; ++ch) {
    wire::SiiPdo pdo;
    pdo.index = static_cast<std::uint16_t>(pdo_base + ch);
    pdo.sync_manager = static_cast<std::uint8_t>(ch / per_sm);
    pdo.name_index = strings.add(fmt::format("Channel {}", ch + 1));
    pdo.flags = wire::sii_pdo_flag::kMandatory | wire::sii_pdo_flag::kFixedContent;
    wire::SiiPdoEntry entry;
    entry.index = static_cast<std::uint16_t>(object_base + 0x10 * ch);
    entry.subindex = 1;
    entry.name_index = entry_name_index;
    entry.data_type = static_cast<std::uint8_t>(DataType::boolean);
    entry.bit_length = 1;
    pdo.entries.push_back(entry);
    pdos.push_back(pdo);
  }
}

// A digital terminal: the standard firmware plus one bool signal per channel.
class DigitalTerminal : public StandardApplication {
 public:
  DigitalTerminal(StandardConfig config, std::uint16_t object_base, int channels,
                  SignalDirection direction)
      : StandardApplication(std::move(config)) {
    for (int ch = 0; ch < channels; ++ch) {
      SignalInfo info;
      info.name = fmt::format("channel_{}", ch + 1);
      info.direction = direction;
      info.type = "bool";
      add_entry_signal(std::move(info), static_cast<std::uint16_t>(object_base + 0x10 * ch), 1);
    }
  }
};

StandardConfig sii_only_config(wire::SiiImage sii) {
  StandardConfig cfg;
  add_sii_process_data(cfg.dictionary, sii);
  cfg.sii = std::move(sii);
  return cfg;
}

}  // namespace

Result<std::unique_ptr<Esc>> make_ek1100(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  auto sii = beckhoff_sii(0x044C2C52, 0x00120000, "EK1100", "SystemBk", "System Couplers",
                          "EK1100 EtherCAT Coupler (2A E-Bus)", -2000, 0x0131, 0x0D00);
  StandardConfig cfg = sii_only_config(std::move(sii));
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  return build_device(config, coupler_hardware(), image,
                      std::make_unique<StandardApplication>(std::move(cfg)));
}

// An EK1122-like 2-port junction: an E-bus terminal (port 0 in, port 3 on to the next terminal)
// with two EtherCAT junction ports (1 and 2) for branches or hot-connect groups; no process data.
Result<std::unique_ptr<Esc>> make_ek1122(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  auto sii = beckhoff_sii(0x04622C52, 0x00120000, "EK1122", "SystemBk", "System Couplers",
                          "EK1122 2 port EtherCAT junction", 220, 0x3113, 0x0D00);
  StandardConfig cfg = sii_only_config(std::move(sii));
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  EscHardware hw = coupler_hardware();
  hw.ports = wire::PortDescriptor{
      {wire::PortType::ebus, wire::PortType::mii, wire::PortType::mii, wire::PortType::ebus}};
  return build_device(config, hw, image, std::make_unique<StandardApplication>(std::move(cfg)));
}

Result<std::unique_ptr<Esc>> make_el1809(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  auto sii =
      beckhoff_sii(0x07113052, 0x00120000, "EL1809", "DigIn", "Digital Input Terminals (EL1xxx)",
                   "EL1809 16Ch. Dig. Input 24V, 3ms", 100, 0x0033, 0x0104);
  sii.fmmus = {wire::sii_fmmu_usage::kInputs};
  sii.sync_managers = {{0x1000, 2, 0x00, 0x00, 0x01, wire::sii_sm_type::kInputs}};
  add_channel_pdos(sii, sii.txpdos, 0x1A00, 0x6000, 16, "Input", 16);
  StandardConfig cfg = sii_only_config(std::move(sii));
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  return build_device(
      config, terminal_hardware(), image,
      std::make_unique<DigitalTerminal>(std::move(cfg), 0x6000, 16, SignalDirection::input));
}

Result<std::unique_ptr<Esc>> make_el2809(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  auto sii =
      beckhoff_sii(0x0AF93052, 0x00120000, "EL2809", "DigOut", "Digital Output Terminals (EL2xxx)",
                   "EL2809 16Ch. Dig. Output 24V, 0.5A", 110, 0x0033, 0x0104);
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kOutputs};
  sii.sync_managers = {{0x0F00, 1, 0x44, 0x00, 0x09, wire::sii_sm_type::kOutputs},
                       {0x0F01, 1, 0x44, 0x00, 0x09, wire::sii_sm_type::kOutputs}};
  add_channel_pdos(sii, sii.rxpdos, 0x1600, 0x7000, 16, "Output", 8);
  StandardConfig cfg = sii_only_config(std::move(sii));
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  return build_device(
      config, terminal_hardware(), image,
      std::make_unique<DigitalTerminal>(std::move(cfg), 0x7000, 16, SignalDirection::output));
}

}  // namespace ecat::sim::devices
