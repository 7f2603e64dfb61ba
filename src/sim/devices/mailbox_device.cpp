// "mailbox": a device for exercising the mailbox, as the reference simulator's :mailbox_device
// (vendor 0x00000ACE, product 0x00001602). A 64-byte mailbox makes most objects segmented:
//   0x2000:01 u16 0x1234 (rw), 0x2000:02 u8 0 (rw)
//   0x2001:01 12-byte blob "hello-sim\0\0\0", 0x2002:01 80 bytes 0..79,
//   0x2003:01 192 bytes 0..191, 0x2004:01 4096 bytes (byte i = i * 7 mod 256); all rw
// Small process data: RxPDO 0x1600 led0, led1 (u8, SM2 0x1100, 2 bytes); TxPDO 0x1A00 button1
// (u8, SM3 0x1180, 1 byte), which mirrors led0 unless forced. VoE: every message is echoed with
// vendor type + 1. FoE: a file store and a firmware slot written in BOOTSTRAP (option
// firmware_password=N: the password its write request must carry).
#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

std::vector<std::uint8_t> pattern(std::size_t n, unsigned step) {
  std::vector<std::uint8_t> out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * step) & 0xFF);
  return out;
}

class MailboxDevice : public StandardApplication {
 public:
  explicit MailboxDevice(StandardConfig config) : StandardApplication(std::move(config)) {
    add_entry_signal({"led_0", SignalDirection::output, "u8", ""}, 0x7000, 1);
    add_entry_signal({"led_1", SignalDirection::output, "u8", ""}, 0x7000, 2);
    add_entry_signal({"button_1", SignalDirection::input, "u8", ""}, 0x6000, 1);
    // VoE (declared in the SII): every message echoed with vendor type + 1.
    if (auto* coe = coe_server()) {
      coe->set_protocol_handler(wire::MailboxType::voe, voe_handler(voe_echo));
    }
  }

 protected:
  void update_inputs(std::int64_t now_ns) override {
    (void)now_ns;
    dictionary().set<std::uint8_t>(0x6000, 1,
                                   dictionary().get<std::uint8_t>(0x7000, 1).value_or(0));
  }
};

}  // namespace

Result<std::unique_ptr<Esc>> make_mailbox_device(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"firmware_password"}); !ok) return ok.error();
  auto firmware_password = option_u32(config, "firmware_password", 0);
  if (!firmware_password) return firmware_password.error();
  wire::SiiImage sii;
  sii.identity = {kSimVendorId, 0x00001602, 0x00000001, 0x00000002};
  sii.standard_mailbox = {0x1000, 64, 0x1040, 64};
  // FoE (a file store, firmware updates in BOOTSTRAP through a larger bootstrap mailbox).
  sii.bootstrap_mailbox = {0x1200, 256, 0x1300, 256};
  sii.mailbox_protocols =
      wire::mailbox_protocol::kCoe | wire::mailbox_protocol::kFoe | wire::mailbox_protocol::kVoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("ECAT-MBX");
  general.group_index = strings.add("Test");
  general.name_index = strings.add("ecat sim mailbox device");
  general.coe_details = wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo |
                        wire::sii_coe_detail::kSdoCompleteAccess;
  general.physical_port = 0x0011;
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kOutputs, wire::sii_fmmu_usage::kInputs,
               wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 64, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1040, 64, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn},
                       {0x1100, 2, 0x64, 0, 0x01, wire::sii_sm_type::kOutputs},
                       {0x1180, 1, 0x20, 0, 0x01, wire::sii_sm_type::kInputs}};
  wire::SiiPdo rx;
  rx.index = 0x1600;
  rx.sync_manager = 2;
  rx.name_index = strings.add("Outputs");
  rx.entries = {
      {0x7000, 1, strings.add("led0"), static_cast<std::uint8_t>(DataType::unsigned8), 8, 0},
      {0x7000, 2, strings.add("led1"), static_cast<std::uint8_t>(DataType::unsigned8), 8, 0}};
  wire::SiiPdo tx;
  tx.index = 0x1A00;
  tx.sync_manager = 3;
  tx.name_index = strings.add("Inputs");
  tx.entries = {
      {0x6000, 1, strings.add("button1"), static_cast<std::uint8_t>(DataType::unsigned8), 8, 0}};
  sii.rxpdos = {rx};
  sii.txpdos = {tx};

  StandardConfig cfg;
  ObjectDictionary& od = cfg.dictionary;
  add_sii_identity(od, sii);
  od.add(make_record(
      0x2000, "Settings",
      {make_entry_of(1, "vendor_word", DataType::unsigned16, kAccessReadWrite,
                     std::uint16_t{0x1234}),
       make_entry_of(2, "enable_flag", DataType::unsigned8, kAccessReadWrite, std::uint8_t{0})}));
  const std::string hello = "hello-sim";
  std::vector<std::uint8_t> blob(hello.begin(), hello.end());
  blob.resize(12, 0);
  od.add(make_record(0x2001, "Blob", {make_octet_entry(1, "blob", blob, kAccessReadWrite)}));
  od.add(make_record(0x2002, "Segmented blob",
                     {make_octet_entry(1, "segmented_blob", pattern(80, 1), kAccessReadWrite)}));
  od.add(
      make_record(0x2003, "Multi-segment blob",
                  {make_octet_entry(1, "multi_segment_blob", pattern(192, 1), kAccessReadWrite)}));
  od.add(make_record(0x2004, "Large blob",
                     {make_octet_entry(1, "large_blob", pattern(4096, 7), kAccessReadWrite)}));
  for (auto index : {0x2000, 0x2001, 0x2002, 0x2003, 0x2004}) {
    for (auto& e : od.find(static_cast<std::uint16_t>(index))->entries)
      e.default_value = e.value;
  }
  add_sii_process_data(od, sii);
  cfg.sii = sii;
  cfg.foe.firmware_password = *firmware_password;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  EscHardware hw;
  hw.ports =
      wire::PortDescriptor{{wire::PortType::mii, wire::PortType::mii,
                            wire::PortType::not_implemented, wire::PortType::not_implemented}};
  return build_device(config, hw, image, std::make_unique<MailboxDevice>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
