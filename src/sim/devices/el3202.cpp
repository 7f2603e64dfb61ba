// Beckhoff EL3202: 2-channel RTD (PT100) input with CoE.
//
// Objects as the EL32xx documentation describes them: TxPDO 0x1A00 / 0x1A01 ("RTD Inputs
// Channel n") map 0x60n0:01 Underrange, :02 Overrange, :03 Limit 1 (BIT2), :05 Limit 2 (BIT2),
// :07 Error, a 7-bit gap, :0F TxPDO State, :10 TxPDO Toggle and :11 Value (INT16): 4 bytes per
// channel on SM3 (0x1180). The settings 0x80n0 hold the RTD element (:19; 0 PT100, 1 Ni100,
// 2 PT1000, 3 PT500, 4 PT200, 5 Ni1000, 6 Ni1000 TK1500, 7 Ni120, 8 resistance 1/16 Ω,
// 9 resistance 1/64 Ω), the connection technology (:1A; 0 2-wire, 1 3-wire, 2 4-wire, 3 not
// connected), the presentation (:02; 0 signed 1/10 °C, 1 absolute value with MSB as sign,
// 2 high resolution 1/100 °C), limits, user scale and filter settings; 0x1011:01 "load" restores
// them. The startup SDOs masters write (0x1C12/0x1C13 assignment, 0x8000:xx settings, 0x1011)
// are accepted.
//
// The physical side: signals temperature_1 / temperature_2 (°C) are what the sensors sense
// (25 °C unless forced; NaN stands for an open circuit). Out-of-range temperatures set the
// underrange / overrange and error bits and clamp the value to the range limit; a broken wire
// reports overrange + error. The resistance modes report the resistance of a PT100 at that
// temperature (IEC 60751 Callendar-Van Dusen).
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

constexpr int kChannels = 2;
constexpr double kAmbientC = 25.0;

ObjectEntry input_entry(std::uint8_t sub, std::string name, DataType type) {
  return make_entry(sub, std::move(name), type, kAccessRead | kAccessTxPdo);
}

// IEC 60751: resistance of a platinum sensor with R0 at temperature t (°C).
double platinum_ohms(double r0, double t) {
  constexpr double a = 3.9083e-3;
  constexpr double b = -5.775e-7;
  constexpr double c = -4.183e-12;
  double r = r0 * (1 + a * t + b * t * t);
  if (t < 0) r += r0 * c * (t - 100) * t * t * t;
  return r;
}

struct Element {
  double min_c;
  double max_c;
};

// The measuring range of an RTD element (0x80n0:19), in °C.
Element element_range(std::uint16_t element) {
  switch (element) {
    case 1:  // Ni100
    case 5:  // Ni1000
      return {-60, 250};
    case 6:  // Ni1000 TK1500
      return {-30, 160};
    case 7:  // Ni120
      return {-60, 320};
    default:  // platinum elements
      return {-200, 850};
  }
}

class El3202 : public StandardApplication {
 public:
  explicit El3202(StandardConfig config) : StandardApplication(std::move(config)) {
    for (int ch = 0; ch < kChannels; ++ch) {
      SignalInfo info;
      info.name = fmt::format("temperature_{}", ch + 1);
      info.direction = SignalDirection::input;
      info.type = "f64";
      info.unit = "°C";
      const std::string name = info.name;
      add_model_signal(std::move(info), [this, name] { return sensed(name); });
    }
  }

 protected:
  void reset_model() override { toggle_ = false; }

  void update_inputs(std::int64_t now_ns) override {
    (void)now_ns;
    toggle_ = !toggle_;
    for (int ch = 0; ch < kChannels; ++ch)
      update_channel(ch);
  }

 private:
  double sensed(const std::string& name) const { return forced(name).value_or(kAmbientC); }

  void update_channel(int ch) {
    ObjectDictionary& od = dictionary();
    const auto in = static_cast<std::uint16_t>(0x6000 + 0x10 * ch);
    const auto set = static_cast<std::uint16_t>(0x8000 + 0x10 * ch);
    const double t = sensed(fmt::format("temperature_{}", ch + 1));
    const auto element = od.get<std::uint16_t>(set, 0x19).value_or(0);
    const auto connection = od.get<std::uint16_t>(set, 0x1A).value_or(0);
    const auto presentation = od.get<std::uint8_t>(set, 0x02).value_or(0);

    bool under = false;
    bool over = false;
    double value = 0;
    if (connection == 3) {
      value = 0;  // channel switched off: nothing measured, nothing flagged
    } else if (std::isnan(t)) {
      over = true;  // open circuit: the resistance is "infinite"
      value = std::numeric_limits<std::int16_t>::max();
    } else if (element == 8 || element == 9) {
      const double ohms = platinum_ohms(100.0, t);
      const double resolution = element == 8 ? 16.0 : 64.0;
      const double limit = 65535.0 / resolution;
      under = ohms < 0;
      over = ohms > limit;
      value = std::round(std::clamp(ohms, 0.0, limit) * resolution);
      if (value > 32767) value -= 65536;  // the INT16 carries an unsigned resistance
    } else {
      const Element range = element_range(element);
      under = t < range.min_c;
      over = t > range.max_c;
      const double clamped = std::clamp(t, range.min_c, range.max_c);
      const double scale = presentation == 2 ? 100.0 : 10.0;
      value = std::clamp(std::round(clamped * scale), -32768.0, 32767.0);
      if (presentation == 1 && value < 0) value = -value + 32768 - 65536;  // MSB as sign
    }
    if (od.get<bool>(set, 0x01).value_or(false) && element < 8) {
      const double gain = od.get<std::int32_t>(set, 0x12).value_or(65536) / 65536.0;
      value = std::clamp(std::round(value * gain + od.get<std::int16_t>(set, 0x11).value_or(0)),
                         -32768.0, 32767.0);
    }
    const bool error = under || over;
    const auto raw = static_cast<std::int16_t>(value);
    od.set<bool>(in, 0x01, under);
    od.set<bool>(in, 0x02, over);
    od.set<std::uint8_t>(in, 0x03, limit_state(set, 0x07, 0x13, raw));
    od.set<std::uint8_t>(in, 0x05, limit_state(set, 0x08, 0x14, raw));
    od.set<bool>(in, 0x07, error);
    od.set<bool>(in, 0x0F, error);
    od.set<bool>(in, 0x10, toggle_);
    od.set<std::int16_t>(in, 0x11, raw);
  }

  // Limit monitoring: 0 off, 1 value above the limit, 2 below, 3 equal.
  std::uint8_t limit_state(std::uint16_t set, std::uint8_t enable, std::uint8_t limit,
                           std::int16_t value) const {
    const ObjectDictionary& od = dictionary();
    if (!od.get<bool>(set, enable).value_or(false)) return 0;
    const auto l = od.get<std::int16_t>(set, limit).value_or(0);
    return value > l ? 1 : value < l ? 2 : 3;
  }

  bool toggle_ = false;
};

}  // namespace

Result<std::unique_ptr<Esc>> make_el3202(const DeviceConfig& config) {
  if (auto ok = check_options(config, {}); !ok) return ok.error();
  wire::SiiImage sii;
  sii.pdi_control = 0x0005;  // SPI to the microcontroller, no device emulation
  sii.identity = {kBeckhoffVendorId, 0x0C823052, 0x00150000, 0};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  sii.mailbox_protocols = wire::mailbox_protocol::kCoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("EL3202");
  general.group_index = strings.add("AnaIn");
  strings.add("Analog Input Terminals (EL3xxx)");
  general.name_index = strings.add("EL3202 2Ch. Ana. Input PT100 (RTD)");
  general.coe_details = wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo |
                        wire::sii_coe_detail::kPdoAssign | wire::sii_coe_detail::kSdoCompleteAccess;
  general.current_on_ebus_ma = 190;
  general.physical_port = 0x0033;
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kInputs,
               wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 128, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1080, 128, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn},
                       {0x1100, 0, 0x04, 0, 0x00, wire::sii_sm_type::kOutputs},
                       {0x1180, 8, 0x20, 0, 0x01, wire::sii_sm_type::kInputs}};
  const std::uint8_t status_names[] = {
      strings.add("Status__Underrange"),   strings.add("Status__Overrange"),
      strings.add("Status__Limit 1"),      strings.add("Status__Limit 2"),
      strings.add("Status__Error"),        strings.add("Status__TxPDO State"),
      strings.add("Status__TxPDO Toggle"), strings.add("Value")};
  for (int ch = 0; ch < kChannels; ++ch) {
    wire::SiiPdo pdo;
    pdo.index = static_cast<std::uint16_t>(0x1A00 + ch);
    pdo.sync_manager = 3;
    pdo.name_index = strings.add(fmt::format("RTD Inputs Channel {}", ch + 1));
    pdo.flags = wire::sii_pdo_flag::kMandatory | wire::sii_pdo_flag::kFixedContent;
    const auto obj = static_cast<std::uint16_t>(0x6000 + 0x10 * ch);
    auto entry = [&](std::uint16_t index, std::uint8_t sub, std::uint8_t name, DataType type,
                     std::uint8_t bits) {
      pdo.entries.push_back({index, sub, name, static_cast<std::uint8_t>(type), bits, 0});
    };
    entry(obj, 0x01, status_names[0], DataType::boolean, 1);
    entry(obj, 0x02, status_names[1], DataType::boolean, 1);
    entry(obj, 0x03, status_names[2], DataType::bit2, 2);
    entry(obj, 0x05, status_names[3], DataType::bit2, 2);
    entry(obj, 0x07, status_names[4], DataType::boolean, 1);
    entry(0, 0, 0, DataType::boolean, 7);
    pdo.entries.back().data_type = 0;
    entry(obj, 0x0F, status_names[5], DataType::boolean, 1);
    entry(obj, 0x10, status_names[6], DataType::boolean, 1);
    entry(obj, 0x11, status_names[7], DataType::integer16, 16);
    sii.txpdos.push_back(pdo);
  }

  StandardConfig cfg;
  ObjectDictionary& od = cfg.dictionary;
  add_sii_identity(od, sii, 0x01401389, "06", "03");
  std::vector<std::uint16_t> settings;
  for (int ch = 0; ch < kChannels; ++ch) {
    const auto in = static_cast<std::uint16_t>(0x6000 + 0x10 * ch);
    const auto set = static_cast<std::uint16_t>(0x8000 + 0x10 * ch);
    settings.push_back(set);
    od.add(make_record(
        in, fmt::format("RTD Inputs Ch.{}", ch + 1),
        {input_entry(0x01, "Underrange", DataType::boolean),
         input_entry(0x02, "Overrange", DataType::boolean),
         input_entry(0x03, "Limit 1", DataType::bit2), input_entry(0x05, "Limit 2", DataType::bit2),
         input_entry(0x07, "Error", DataType::boolean),
         input_entry(0x0F, "TxPDO State", DataType::boolean),
         input_entry(0x10, "TxPDO Toggle", DataType::boolean),
         input_entry(0x11, "Value", DataType::integer16)}));
    od.add(make_record(
        set, fmt::format("RTD Settings Ch.{}", ch + 1),
        {setting_entry(0x01, "Enable user scale", DataType::boolean, false),
         setting_entry<std::uint8_t>(0x02, "Presentation", DataType::bit3, 0, 2),
         setting_entry(0x05, "Siemens bits", DataType::boolean, false),
         setting_entry(0x06, "Enable filter", DataType::boolean, true),
         setting_entry(0x07, "Enable limit 1", DataType::boolean, false),
         setting_entry(0x08, "Enable limit 2", DataType::boolean, false),
         setting_entry(0x0A, "Enable user calibration", DataType::boolean, false),
         setting_entry(0x0B, "Enable vendor calibration", DataType::boolean, true),
         setting_entry<std::int16_t>(0x11, "User scale offset", DataType::integer16, 0),
         setting_entry<std::int32_t>(0x12, "User scale gain", DataType::integer32, 65536),
         setting_entry<std::int16_t>(0x13, "Limit 1", DataType::integer16, 0),
         setting_entry<std::int16_t>(0x14, "Limit 2", DataType::integer16, 0),
         setting_entry<std::uint16_t>(0x15, "Filter settings", DataType::unsigned16, 0, 15),
         setting_entry<std::int16_t>(0x17, "User calibration offset", DataType::integer16, 0),
         setting_entry<std::uint16_t>(0x18, "User calibration gain", DataType::unsigned16, 0xFFFF),
         setting_entry<std::uint16_t>(0x19, "RTD element", DataType::unsigned16, 0, 9),
         setting_entry<std::uint16_t>(0x1A, "Connection technology", DataType::unsigned16, 0, 3),
         setting_entry<std::int16_t>(0x1B, "Wire calibration 1/32 Ohm", DataType::integer16, 0)}));
  }
  od.add(make_restore_defaults(settings));
  add_sii_process_data(od, sii, {false, true, false});
  // The assignment is the master's to change in PREOP (TwinCAT and IgH write it at startup).
  add_pdo_assignment(od, 2, PdoDirection::rx, {}, {2, true, 0});
  add_pdo_assignment(od, 3, PdoDirection::tx, {0x1A00, 0x1A01}, {2, true, 0});
  od.add(make_sm_parameter(0x1C32, 0x0000, 0x0001, 0));
  od.add(make_sm_parameter(0x1C33, 0x0000, 0x0001, 0));
  od.add(make_record(0xF000, "Modular device profile",
                     {make_entry_of(1, "Module index distance", DataType::unsigned16, kAccessRead,
                                    std::uint16_t{0x10}),
                      make_entry_of(2, "Maximum number of modules", DataType::unsigned16,
                                    kAccessRead, std::uint16_t{kChannels})}));
  od.add(make_array(0xF010, "Module list", DataType::integer32, kChannels, kAccessRead,
                    {to_le_bytes(std::int32_t{320}), to_le_bytes(std::int32_t{320})}));
  cfg.sii = sii;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  return build_device(config, terminal_hardware(), image, std::make_unique<El3202>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
