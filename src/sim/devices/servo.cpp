// "servo": a CiA 402 servo drive of the simulator's own make (vendor 0x00000ACE, product
// 0x00002402), with object indices and names as real CiA 402 drives (and the Ingenia EVS-NET ESI)
// use them.
//
// Process data, remappable in PREOP through 0x1C12 / 0x1C13 and the mapping objects 0x1600,
// 0x1601, 0x1A00, 0x1A01 (up to 8 entries each):
//   RxPDO 0x1600 (SM2): controlword 0x6040, target position 0x607A, target velocity 0x60FF,
//                        target torque 0x6071, modes of operation 0x6060        (13 bytes)
//   TxPDO 0x1A00 (SM3): statusword 0x6041, position actual 0x6064, velocity actual 0x606C,
//                        torque actual 0x6077, modes display 0x6061, error code 0x603F (15 bytes)
//   0x1601 / 0x1A01 (unassigned by default): controlword + target position / statusword +
//   position actual.
// DC: SYNC0-capable (AssignActivate 0x0300); SYNC0 needed when the option dc_required=1 is set or
// the master writes 0x1C32:01 = 2; cycle times from 0x1C32:05 (125 µs) up.
// FoE: a file store and a firmware slot written in BOOTSTRAP (option firmware_password=N: the
// password its write request must carry).
#include <fmt/format.h>

#include "sim/devices/applications.hpp"
#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

constexpr std::uint32_t kMinCycleNs = 125'000;

wire::SiiPdoEntry sii_entry(wire::SiiImage& sii, std::uint16_t index, DataType type,
                            std::uint8_t bits, std::string_view name) {
  SiiStrings strings(sii);
  return {index, 0, strings.add(name), static_cast<std::uint8_t>(type), bits, 0};
}

}  // namespace

Result<std::unique_ptr<Esc>> make_servo(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"dc_required", "min_cycle_ns", "firmware_password"}); !ok)
    return ok.error();
  auto firmware_password = option_u32(config, "firmware_password", 0);
  if (!firmware_password) return firmware_password.error();
  auto dc_required = option_bool(config, "dc_required", false);
  if (!dc_required) return dc_required.error();
  auto min_cycle = option_u32(config, "min_cycle_ns", kMinCycleNs);
  if (!min_cycle) return min_cycle.error();

  wire::SiiImage sii;
  sii.pdi_control = 0x0C08;
  sii.identity = {kSimVendorId, 0x00002402, 0x00010000, 0x2001};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  // FoE (a file store, firmware updates in BOOTSTRAP through a larger bootstrap mailbox).
  sii.bootstrap_mailbox = {0x1400, 512, 0x1600, 512};
  sii.mailbox_protocols = wire::mailbox_protocol::kCoe | wire::mailbox_protocol::kFoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("ECAT-SERVO");
  general.group_index = strings.add("Drives");
  general.name_index = strings.add("ecat sim CiA 402 servo drive");
  general.coe_details = wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo |
                        wire::sii_coe_detail::kPdoAssign | wire::sii_coe_detail::kPdoConfiguration |
                        wire::sii_coe_detail::kSdoCompleteAccess;
  general.ds402_channels = 1;
  general.physical_port = 0x0011;  // two MII ports
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kInputs,
               wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 128, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1080, 128, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn},
                       {0x1100, 13, 0x64, 0, 0x01, wire::sii_sm_type::kOutputs},
                       {0x1200, 15, 0x20, 0, 0x01, wire::sii_sm_type::kInputs}};
  auto pdo = [&](std::uint16_t index, std::uint8_t sm, std::string_view name,
                 std::vector<wire::SiiPdoEntry> entries) {
    wire::SiiPdo p;
    p.index = index;
    p.sync_manager = sm;
    p.name_index = strings.add(name);
    p.flags = sm != 0xFF ? wire::sii_pdo_flag::kDefault : 0;
    p.entries = std::move(entries);
    return p;
  };
  sii.rxpdos = {pdo(0x1600, 2, "RxPDO 1",
                    {sii_entry(sii, 0x6040, DataType::unsigned16, 16, "Controlword"),
                     sii_entry(sii, 0x607A, DataType::integer32, 32, "Target position"),
                     sii_entry(sii, 0x60FF, DataType::integer32, 32, "Target velocity"),
                     sii_entry(sii, 0x6071, DataType::integer16, 16, "Target torque"),
                     sii_entry(sii, 0x6060, DataType::integer8, 8, "Modes of operation")}),
                pdo(0x1601, 0xFF, "RxPDO 2",
                    {sii_entry(sii, 0x6040, DataType::unsigned16, 16, "Controlword"),
                     sii_entry(sii, 0x607A, DataType::integer32, 32, "Target position")})};
  sii.txpdos = {pdo(0x1A00, 3, "TxPDO 1",
                    {sii_entry(sii, 0x6041, DataType::unsigned16, 16, "Statusword"),
                     sii_entry(sii, 0x6064, DataType::integer32, 32, "Position actual value"),
                     sii_entry(sii, 0x606C, DataType::integer32, 32, "Velocity actual value"),
                     sii_entry(sii, 0x6077, DataType::integer16, 16, "Torque actual value"),
                     sii_entry(sii, 0x6061, DataType::integer8, 8, "Modes of operation display"),
                     sii_entry(sii, 0x603F, DataType::unsigned16, 16, "Error code")}),
                pdo(0x1A01, 0xFF, "TxPDO 2",
                    {sii_entry(sii, 0x6041, DataType::unsigned16, 16, "Statusword"),
                     sii_entry(sii, 0x6064, DataType::integer32, 32, "Position actual value")})};
  wire::SiiDcSync free_run;
  free_run.name_index = strings.add("FreeRun");
  free_run.description_index = strings.add("SM-Synchron");
  wire::SiiDcSync dc_sync;
  dc_sync.assign_activate = 0x0300;
  dc_sync.sync0_cycle_factor = 1;
  dc_sync.name_index = strings.add("DCSync");
  dc_sync.description_index = strings.add("DC-Synchron");
  sii.dc = {free_run, dc_sync};

  StandardConfig cfg;
  ObjectDictionary& od = cfg.dictionary;
  add_sii_identity(od, sii, 0x00020192, "A1", "1.0.0");
  od.add(make_error_settings());
  add_cia402_objects(od);
  // Mapping objects with room for 8 entries, the assignments with room for 2 PDOs; all
  // writable in PREOP.
  auto mapping = [&](std::uint16_t index, const char* name, std::vector<PdoEntryRef> entries) {
    add_pdo_mapping(od, index, name, entries, {8, true, 0});
  };
  mapping(0x1600, "RxPDO 1 mapping",
          {{0x6040, 0, 16}, {0x607A, 0, 32}, {0x60FF, 0, 32}, {0x6071, 0, 16}, {0x6060, 0, 8}});
  mapping(0x1601, "RxPDO 2 mapping", {{0x6040, 0, 16}, {0x607A, 0, 32}});
  mapping(0x1A00, "TxPDO 1 mapping",
          {{0x6041, 0, 16},
           {0x6064, 0, 32},
           {0x606C, 0, 32},
           {0x6077, 0, 16},
           {0x6061, 0, 8},
           {0x603F, 0, 16}});
  mapping(0x1A01, "TxPDO 2 mapping", {{0x6041, 0, 16}, {0x6064, 0, 32}});
  add_pdo_assignment(od, 2, PdoDirection::rx, {0x1600}, {2, true, 0});
  add_pdo_assignment(od, 3, PdoDirection::tx, {0x1A00}, {2, true, 0});
  // Synchronisation types supported: free run, SM-synchronous, DC SYNC0.
  od.add(make_sm_parameter(0x1C32, 0x0000, 0x0007, *min_cycle));
  od.add(make_sm_parameter(0x1C33, 0x0000, 0x0007, *min_cycle));
  cfg.sii = sii;
  cfg.foe.firmware_password = *firmware_password;
  cfg.dc.supported = true;
  cfg.dc.required = *dc_required;
  cfg.dc.min_cycle_ns = *min_cycle;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  EscHardware hw = coupler_hardware();
  hw.ports =
      wire::PortDescriptor{{wire::PortType::mii, wire::PortType::mii,
                            wire::PortType::not_implemented, wire::PortType::not_implemented}};
  const wire::SiiImage image = cfg.sii;
  return build_device(config, hw, image, std::make_unique<Cia402Application>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
