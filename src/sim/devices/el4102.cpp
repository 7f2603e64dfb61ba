// Beckhoff EL4102: 2-channel analog output 0..10 V with CoE.
//
// RxPDO 0x1600 / 0x1601 ("AO RxPDO-Map Outputs Ch.n") map 0x70n0:11 Analog output (INT16) on
// SM2 (0x1100, 4 bytes). 0..0x7FFF is 0..10 V; negative values give 0 V. The settings 0x80n0 hold
// user scale, presentation, the watchdog behaviour (:05; 0 default value, 1 ramp to it, 2 keep
// the last value) and the default output (:13) the channel takes when the outputs go to their
// safe state (leaving OP, process-data watchdog).
//
// Signals output_1 / output_2: the voltage at the terminal's output (V).
#include <algorithm>

#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

constexpr int kChannels = 2;
constexpr double kVoltsPerBit = 10.0 / 32767.0;

class El4102 : public StandardApplication {
 public:
  explicit El4102(StandardConfig config) : StandardApplication(std::move(config)) {
    for (int ch = 0; ch < kChannels; ++ch) {
      SignalInfo info;
      info.name = fmt::format("output_{}", ch + 1);
      info.direction = SignalDirection::output;
      info.type = "f64";
      info.unit = std::string("V");  // not the literal: GCC 12 -O3 sees a false -Wrestrict
      add_model_signal(std::move(info), [this, ch] { return volts(ch); });
    }
  }

 protected:
  void apply_safe_outputs() override {
    ObjectDictionary& od = dictionary();
    for (int ch = 0; ch < kChannels; ++ch) {
      const auto out = static_cast<std::uint16_t>(0x7000 + 0x10 * ch);
      const auto set = static_cast<std::uint16_t>(0x8000 + 0x10 * ch);
      if (od.get<std::uint8_t>(set, 0x05).value_or(0) == 2) continue;  // keep the last value
      od.set<std::int16_t>(out, 0x11, od.get<std::int16_t>(set, 0x13).value_or(0));
    }
  }

 private:
  double volts(int ch) const {
    const ObjectDictionary& od = dictionary();
    const auto out = static_cast<std::uint16_t>(0x7000 + 0x10 * ch);
    const auto set = static_cast<std::uint16_t>(0x8000 + 0x10 * ch);
    double raw = od.get<std::int16_t>(out, 0x11).value_or(0);
    if (od.get<bool>(set, 0x01).value_or(false)) {
      raw = raw * (od.get<std::int32_t>(set, 0x12).value_or(65536) / 65536.0) +
            od.get<std::int16_t>(set, 0x11).value_or(0);
    }
    return std::clamp(raw, 0.0, 32767.0) * kVoltsPerBit;
  }
};

}  // namespace

Result<std::unique_ptr<Esc>> make_el4102(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  wire::SiiImage sii;
  sii.pdi_control = 0x0005;  // SPI to the microcontroller, no device emulation
  sii.identity = {kBeckhoffVendorId, 0x10063052, 0x00130000, 0};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  sii.mailbox_protocols = wire::mailbox_protocol::kCoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("EL4102");
  general.group_index = strings.add("AnaOut");
  strings.add("Analog Output Terminals (EL4xxx)");
  general.name_index = strings.add("EL4102 2Ch. Ana. Output 0-10V");
  general.coe_details = wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo |
                        wire::sii_coe_detail::kPdoAssign | wire::sii_coe_detail::kSdoCompleteAccess;
  general.current_on_ebus_ma = 200;
  general.physical_port = 0x0033;
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kInputs,
               wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 128, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1080, 128, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn},
                       {0x1100, 4, 0x64, 0, 0x01, wire::sii_sm_type::kOutputs},
                       {0x1180, 0, 0x20, 0, 0x00, wire::sii_sm_type::kInputs}};
  const std::uint8_t value_name = strings.add("Analog output");
  for (int ch = 0; ch < kChannels; ++ch) {
    wire::SiiPdo pdo;
    pdo.index = static_cast<std::uint16_t>(0x1600 + ch);
    pdo.sync_manager = 2;
    pdo.name_index = strings.add(fmt::format("AO RxPDO-Map Outputs Ch.{}", ch + 1));
    pdo.flags = wire::sii_pdo_flag::kMandatory | wire::sii_pdo_flag::kFixedContent;
    pdo.entries.push_back({static_cast<std::uint16_t>(0x7000 + 0x10 * ch), 0x11, value_name,
                           static_cast<std::uint8_t>(DataType::integer16), 16, 0});
    sii.rxpdos.push_back(pdo);
  }

  StandardConfig cfg;
  ObjectDictionary& od = cfg.dictionary;
  add_sii_identity(od, sii, 0x01901389, "05", "04");
  std::vector<std::uint16_t> settings;
  for (int ch = 0; ch < kChannels; ++ch) {
    const auto out = static_cast<std::uint16_t>(0x7000 + 0x10 * ch);
    const auto set = static_cast<std::uint16_t>(0x8000 + 0x10 * ch);
    settings.push_back(set);
    od.add(make_record(out, fmt::format("AO Outputs Ch.{}", ch + 1),
                       {make_entry_of(0x11, "Analog output", DataType::integer16,
                                      kAccessReadWrite | kAccessRxPdo, std::int16_t{0})}));
    od.find(out, 0x11)->default_value = to_le_bytes(std::int16_t{0});
    od.add(make_record(
        set, fmt::format("AO Settings Ch.{}", ch + 1),
        {setting_entry(0x01, "Enable user scale", DataType::boolean, false),
         setting_entry<std::uint8_t>(0x02, "Presentation", DataType::bit3, 0, 2),
         setting_entry<std::uint8_t>(0x05, "Watchdog", DataType::bit2, 0, 2),
         setting_entry(0x07, "Enable user calibration", DataType::boolean, false),
         setting_entry(0x08, "Enable vendor calibration", DataType::boolean, true),
         setting_entry<std::int16_t>(0x11, "Offset", DataType::integer16, 0),
         setting_entry<std::int32_t>(0x12, "Gain", DataType::integer32, 65536),
         setting_entry<std::int16_t>(0x13, "Default output", DataType::integer16, 0),
         setting_entry<std::uint16_t>(0x14, "Default output ramp", DataType::unsigned16, 0xFFFF),
         setting_entry<std::int16_t>(0x15, "User calibration offset", DataType::integer16, 0),
         setting_entry<std::int16_t>(0x16, "User calibration gain", DataType::integer16, 16384)}));
  }
  od.add(make_restore_defaults(settings));
  add_sii_process_data(od, sii, {false, true, false});
  add_pdo_assignment(od, 2, PdoDirection::rx, {0x1600, 0x1601}, {2, true, 0});
  add_pdo_assignment(od, 3, PdoDirection::tx, {}, {2, true, 0});
  od.add(make_sm_parameter(0x1C32, 0x0001, 0x0001, 0));
  od.add(make_sm_parameter(0x1C33, 0x0001, 0x0001, 0));
  cfg.sii = sii;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  return build_device(config, terminal_hardware(), image, std::make_unique<El4102>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
