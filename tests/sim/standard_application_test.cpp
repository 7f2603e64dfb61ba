// The firmware every simulated device shares (StandardApplication), driven through real datagrams:
// every AL refusal with its exact status code, error acknowledge, the process-data watchdog, the
// SyncManager checks, DC synchronisation checks, valid-output checks, device identification,
// power cycles and the SII-derived dictionary.
#include <cmath>

#include <gtest/gtest.h>

#include <ecat/sim/standard_application.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using test::AlResult;
using test::Bytes;
using test::SimMaster;
using wire::AlState;
namespace al = wire::al_status;
namespace reg = wire::reg;

struct Rig {
  explicit Rig(const std::string& name, std::map<std::string, std::string> options = {})
      : master(segment) {
    test::add_device(segment, "dut", test::profile(name, std::move(options)));
    master.assign_stations();
  }
  StandardApplication& app() {
    return dynamic_cast<StandardApplication&>(segment.esc(0).application());
  }
  Segment segment;
  SimMaster master;
};

void expect_al(const AlResult& r, AlState state, bool error, std::uint16_t code) {
  EXPECT_EQ(r.state, state);
  EXPECT_EQ(r.error, error);
  EXPECT_EQ(r.code, code) << "AL status code 0x" << std::hex << r.code;
}

TEST(AlStateMachine, UnknownStateIs0x0012AndKeepsTheState) {
  Rig rig("EL3202");
  rig.master.exchange(wire::Command::fpwr, test::fp(rig.master.station(0), reg::kAlControl),
                      test::le16(0x0005));
  expect_al(rig.master.al_status(0), AlState::init, true, al::kUnknownRequestedState);
}

TEST(AlStateMachine, TransitionsTheDiagramLacksAre0x0011) {
  Rig rig("EL3202");
  expect_al(rig.master.request(0, AlState::safeop), AlState::init, true,
            al::kInvalidRequestedStateChange);
  expect_al(rig.master.request(0, AlState::init, true), AlState::init, false, 0);
  expect_al(rig.master.request(0, AlState::op), AlState::init, true,
            al::kInvalidRequestedStateChange);
}

TEST(AlStateMachine, BootstrapWithoutABootstrapMailboxIs0x0013) {
  Rig rig("EL3202");
  expect_al(rig.master.request(0, AlState::bootstrap), AlState::init, true,
            al::kBootstrapNotSupported);
}

TEST(AlStateMachine, PreopNeedsTheSiiMailboxConfiguration) {
  Rig rig("EL3202");
  auto& m = rig.master;
  // Nothing configured.
  expect_al(m.request(0, AlState::preop), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  // Wrong length on SM0, right SM1.
  m.write_sm(0, 0, 0x1000, 64, wire::kMailboxOutControl.encode());
  m.write_sm(0, 1, 0x1080, 128, wire::kMailboxInControl.encode());
  expect_al(m.request(0, AlState::preop, true), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  // Wrong start on SM1.
  m.write_sm(0, 0, 0x1000, 128, wire::kMailboxOutControl.encode());
  m.write_sm(0, 1, 0x10C0, 128, wire::kMailboxInControl.encode());
  expect_al(m.request(0, AlState::preop, true), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  // Buffered instead of mailbox mode.
  m.write_sm(0, 1, 0x1080, 128, wire::kInputsControl.encode());
  expect_al(m.request(0, AlState::preop, true), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  // Directions swapped.
  m.write_sm(0, 0, 0x1000, 128, wire::kMailboxInControl.encode());
  m.write_sm(0, 1, 0x1080, 128, wire::kMailboxOutControl.encode());
  expect_al(m.request(0, AlState::preop, true), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  // SM1 not enabled.
  m.write_sm(0, 0, 0x1000, 128, wire::kMailboxOutControl.encode());
  m.write_sm(0, 1, 0x1080, 128, wire::kMailboxInControl.encode(), false);
  expect_al(m.request(0, AlState::preop, true), AlState::init, true,
            al::kInvalidMailboxConfigurationPreop);
  m.write_sm(0, 1, 0x1080, 128, wire::kMailboxInControl.encode());
  expect_al(m.request(0, AlState::preop, true), AlState::preop, false, 0);
}

TEST(AlStateMachine, AnUnacknowledgedErrorOnlyLetsTheDeviceStepDown) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.bring_to_preop(0);
  // SAFEOP refused (no process data configured): 0x001E.
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidInputConfiguration);
  m.configure_process_data(0);
  // Without acknowledge the request is not taken, the error stays.
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidInputConfiguration);
  // A step down is taken, the error stays with its code.
  expect_al(m.request(0, AlState::init), AlState::init, true, al::kInvalidInputConfiguration);
  // The same state with acknowledge clears it.
  expect_al(m.request(0, AlState::init, true), AlState::init, false, 0);
  expect_al(m.request(0, AlState::preop), AlState::preop, false, 0);
  expect_al(m.request(0, AlState::safeop), AlState::safeop, false, 0);
  expect_al(m.request(0, AlState::op), AlState::op, false, 0);
  // Back down the other way: OP -> PREOP and SAFEOP -> INIT are valid.
  expect_al(m.request(0, AlState::preop), AlState::preop, false, 0);
}

TEST(AlStateMachine, BootstrapWithABootstrapMailbox) {
  wire::SiiImage sii;
  sii.identity = {0x0ACE, 0x77, 1, 0};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  sii.bootstrap_mailbox = {0x1000, 256, 0x1400, 256};
  sii.mailbox_protocols = wire::mailbox_protocol::kCoe | wire::mailbox_protocol::kFoe;
  StandardConfig cfg;
  cfg.sii = sii;
  auto eeprom = wire::encode_sii(sii);
  ASSERT_TRUE(eeprom.ok());
  Segment segment;
  ASSERT_TRUE(segment
                  .add_slave("boot", std::make_unique<Esc>(
                                         EscHardware{}, *eeprom,
                                         std::make_unique<StandardApplication>(std::move(cfg))))
                  .ok());
  SimMaster m(segment);
  m.assign_stations();
  // The standard mailbox configuration is not the bootstrap one: 0x0015.
  m.write_sm(0, 0, 0x1000, 128, wire::kMailboxOutControl.encode());
  m.write_sm(0, 1, 0x1080, 128, wire::kMailboxInControl.encode());
  expect_al(m.request(0, AlState::bootstrap), AlState::init, true,
            al::kInvalidMailboxConfigurationBootstrap);
  m.write_sm(0, 0, 0x1000, 256, wire::kMailboxOutControl.encode());
  m.write_sm(0, 1, 0x1400, 256, wire::kMailboxInControl.encode());
  expect_al(m.request(0, AlState::bootstrap, true), AlState::bootstrap, false, 0);
  // From BOOT only INIT.
  expect_al(m.request(0, AlState::preop), AlState::bootstrap, true,
            al::kInvalidRequestedStateChange);
  expect_al(m.request(0, AlState::init, true), AlState::init, false, 0);
}

TEST(AlStateMachine, DeviceIdentificationRequestShowsTheAlias) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.exchange(wire::Command::fpwr, test::fp(m.station(0), reg::kAlControl),
             test::le16(wire::encode_al_control(AlState::init) | wire::kAlControlIdRequest));
  auto r = m.exchange(wire::Command::fprd, test::fp(m.station(0), reg::kAlStatus), Bytes(6, 0));
  EXPECT_EQ(r.data[0], 0x21);                 // INIT + ID loaded
  EXPECT_EQ(wire::load_le16(&r.data[4]), 0);  // the SII alias of the profile
}

// ---- process data --------------------------------------------------------------------------

TEST(ProcessDataChecks, OutputSyncManagerMismatchesAre0x001D) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.bring_to_preop(0);
  // Length 2 instead of the 4 bytes 0x1C12 maps.
  m.configure_process_data(0, {{2, 2}});
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidOutputConfiguration);
  // Wrong start address.
  m.write_sm(0, 2, 0x1200, 4, wire::kOutputsControl.encode());
  expect_al(m.request(0, AlState::safeop, true), AlState::preop, true,
            al::kInvalidOutputConfiguration);
  // Read direction.
  m.write_sm(0, 2, 0x1100, 4, wire::kInputsControl.encode());
  expect_al(m.request(0, AlState::safeop, true), AlState::preop, true,
            al::kInvalidOutputConfiguration);
  // Mailbox mode.
  m.write_sm(0, 2, 0x1100, 4, 0x26);
  expect_al(m.request(0, AlState::safeop, true), AlState::preop, true,
            al::kInvalidOutputConfiguration);
  // Not enabled.
  m.write_sm(0, 2, 0x1100, 4, wire::kOutputsControl.encode(), false);
  expect_al(m.request(0, AlState::safeop, true), AlState::preop, true,
            al::kInvalidOutputConfiguration);
  m.write_sm(0, 2, 0x1100, 4, 0x24);
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
}

TEST(ProcessDataChecks, InputSyncManagerMismatchIs0x001E) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0, {{3, 4}});  // 8 bytes expected
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidInputConfiguration);
  m.write_sm(0, 3, 0x1180, 8, 0x20);
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
}

TEST(ProcessDataChecks, AMappingThatNamesAMissingObjectIs0x0025) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  // Firmware whose dictionary lost the object a PDO maps (a broken device description).
  ASSERT_TRUE(rig.app().dictionary().remove(0x7010));
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidOutputMapping);
}

TEST(ProcessDataChecks, FmmusAreCheckedOnlyWhenAsked) {
  for (const bool check : {false, true}) {
    Rig rig("EL3202", {{"check_fmmus", check ? "1" : "0"}});
    auto& m = rig.master;
    m.bring_to_preop(0);
    m.write_sm(0, 3, 0x1180, 8, 0x20);  // SM right, no FMMU
    const auto r = m.request(0, AlState::safeop);
    if (check) {
      expect_al(r, AlState::preop, true, al::kInvalidInputConfiguration);
      m.write_fmmu(0, 0, 0, 8, 0x1180, false);
      expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
    } else {
      expect_al(r, AlState::safeop, false, 0);
    }
  }
}

TEST(ProcessDataChecks, ChangingASyncManagerInOpDropsToPreopWithTheCode) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  m.write_sm(0, 2, 0x1100, 4, wire::kOutputsControl.encode(), false);
  expect_al(m.al_status(0), AlState::preop, true, al::kInvalidOutputConfiguration);
}

TEST(ProcessDataChecks, ValidOutputsAreRequiredForOpWhenConfigured) {
  Rig rig("EL4102", {{"require_valid_outputs", "1"}});
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  expect_al(m.request(0, AlState::op), AlState::safeop, true, al::kNoValidOutputs);
  EXPECT_EQ(m.lrw(), 2);  // an LRW that writes counts 2 per slave
  expect_al(m.request(0, AlState::op, true), AlState::op, false, 0);
}

TEST(ProcessDataChecks, AnExpiredWatchdogRefusesOpWith0x001B) {
  Rig rig("EL4102", {{"require_valid_outputs", "1"}});
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  m.lrw();
  m.wait(150'000'000);  // the default process-data watchdog is 100 ms
  EXPECT_EQ(m.esc(0).read_u16(reg::kWatchdogStatus) & 1, 0);
  expect_al(m.request(0, AlState::op), AlState::safeop, true, al::kSyncManagerWatchdog);
}

TEST(Watchdog, ExpiryInOpDropsToSafeopWith0x001BAndSafeOutputs) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  wire::store_le16(&m.image()[m.slot(0, 2).offset], 0x7FFF);
  EXPECT_EQ(m.lrw(), 2);
  auto* dev = device_application(m.esc(0));
  EXPECT_NEAR(*dev->signal("output_1"), 10.0, 1e-9);
  // Cycling keeps it in OP.
  for (int i = 0; i < 5; ++i) {
    m.wait(50'000'000);
    m.lrw();
  }
  expect_al(m.al_status(0), AlState::op, false, 0);
  // No outputs for longer than the watchdog time.
  m.wait(120'000'000);
  expect_al(m.al_status(0), AlState::safeop, true, al::kSyncManagerWatchdog);
  EXPECT_EQ(dev->signal("output_1"), 0.0);
  // The master acknowledges and goes back to OP.
  m.lrw();
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
  expect_al(m.request(0, AlState::op), AlState::op, false, 0);
  m.lrw();
  EXPECT_NEAR(*dev->signal("output_1"), 10.0, 1e-9);
}

TEST(Watchdog, ADisabledWatchdogNeverFires) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.exchange(wire::Command::fpwr, test::fp(m.station(0), reg::kWatchdogTimeProcessData),
             test::le16(0));
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  m.wait(1'000'000'000);
  expect_al(m.al_status(0), AlState::op, false, 0);
}

TEST(DeviceEmulation, TheEscMirrorsAlControlAndTheWatchdogOnlyClearsOutputs) {
  Rig rig("EL2809");
  auto& m = rig.master;
  EXPECT_EQ(m.esc(0).read_u8(reg::kEscConfiguration) & 0x01, 0x01);
  // No mailbox, nothing configured: a terminal without firmware takes any state.
  expect_al(m.request(0, AlState::op), AlState::op, false, 0);
  expect_al(m.request(0, AlState::init), AlState::init, false, 0);
  // The ESC copies the acknowledge bit too, as real terminals show it.
  expect_al(m.request(0, AlState::init, true), AlState::init, true, 0);
  m.configure_process_data(0);
  expect_al(m.request(0, AlState::safeop), AlState::safeop, false, 0);
  expect_al(m.request(0, AlState::op), AlState::op, false, 0);
  m.image()[0] = 0x81;  // channels 1 and 8
  m.image()[1] = 0x80;  // channel 16
  EXPECT_EQ(m.lrw(), 2);
  auto* dev = device_application(m.esc(0));
  EXPECT_EQ(dev->signal("channel_1"), 1.0);
  EXPECT_EQ(dev->signal("channel_8"), 1.0);
  EXPECT_EQ(dev->signal("channel_16"), 1.0);
  EXPECT_EQ(dev->signal("channel_2"), 0.0);
  m.wait(150'000'000);
  expect_al(m.al_status(0), AlState::op, false, 0);
  EXPECT_EQ(dev->signal("channel_1"), 0.0);
  EXPECT_EQ(dev->signal("channel_16"), 0.0);
  m.lrw();
  EXPECT_EQ(dev->signal("channel_1"), 1.0);
}

// ---- DC ------------------------------------------------------------------------------------

void configure_sync0(SimMaster& m, std::uint32_t cycle_ns, std::uint8_t activation = 0x03) {
  const auto s = m.station(0);
  m.exchange(wire::Command::fpwr, test::fp(s, reg::kDcActivation), {0});
  m.exchange(wire::Command::fpwr, test::fp(s, reg::kDcSync0CycleTime), test::le32(cycle_ns));
  auto now = m.exchange(wire::Command::fprd, test::fp(s, reg::kDcSystemTime), Bytes(8, 0));
  const std::uint64_t start = wire::load_le64(now.data.data()) + 10'000'000;
  Bytes start_bytes(8);
  wire::store_le64(start_bytes.data(), start);
  m.exchange(wire::Command::fpwr, test::fp(s, reg::kDcStartTime), start_bytes);
  m.exchange(wire::Command::fpwr, test::fp(s, reg::kDcActivation), {activation});
}

TEST(DcChecks, RequiredSync0MissingIs0x0030) {
  Rig rig("servo", {{"dc_required", "1"}});
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidDcSyncConfiguration);
  configure_sync0(m, 1'000'000);
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
}

TEST(DcChecks, ACycleTimeOutsideTheLimitsIs0x0035) {
  Rig rig("servo");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  configure_sync0(m, 50'000);  // below 0x1C32:05 = 125 µs
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kDcInvalidSyncCycleTime);
  configure_sync0(m, 250'000);
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
}

TEST(DcChecks, SyncTypeDcWrittenByTheMasterMakesSync0Required) {
  Rig rig("servo");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  EXPECT_EQ(m.download(0, 0x1C32, 1, {0x02, 0x00}).abort, 0u);
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidDcSyncConfiguration);
}

TEST(DcChecks, ADeviceWithoutDcCannotBeMadeSynchronous) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  // Its ESC has no SYNC unit enabled (SII ESC configuration): activation does not take.
  configure_sync0(m, 1'000'000);
  EXPECT_EQ(m.esc(0).read_u8(reg::kDcActivation), 0);
  // Asking for DC synchronisation through 0x1C32:01 is refused at SAFEOP.
  EXPECT_EQ(m.download(0, 0x1C32, 1, {0x02, 0x00}).abort, 0u);
  expect_al(m.request(0, AlState::safeop), AlState::preop, true, al::kInvalidDcSyncConfiguration);
  EXPECT_EQ(m.download(0, 0x1C32, 1, {0x00, 0x00}).abort, 0u);
  expect_al(m.request(0, AlState::safeop, true), AlState::safeop, false, 0);
}

TEST(DcChecks, InputsAreLatchedAtSync0) {
  Rig rig("servo");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  configure_sync0(m, 1'000'000);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  m.wait(20'000'000);
  ASSERT_GT(m.esc(0).dc()->sync0_count(), 5u);
  // The statusword in the image is the one latched at the last pulse (switch on disabled).
  m.lrw();
  const auto& in = m.slot(0, 3);
  EXPECT_EQ(wire::load_le16(&m.image()[in.offset]), 0x0240);
}

// ---- power cycle, emergencies, SII dictionary -------------------------------------------------

TEST(PowerCycle, ResetsStateDictionaryAndForcedInputs) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.bring_to_preop(0);
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x08, 0x00}).abort, 0u);
  EXPECT_EQ(rig.app().dictionary().get<std::uint16_t>(0x8000, 0x19), 8);
  EXPECT_TRUE(rig.app().set_input("temperature_1", 50.0));
  m.esc(0).power_cycle(m.now());
  EXPECT_EQ(m.esc(0).al_state(), AlState::init);
  EXPECT_EQ(rig.app().dictionary().get<std::uint16_t>(0x8000, 0x19), 0);
  EXPECT_EQ(rig.app().signal("temperature_1"), 25.0);
}

TEST(Emergencies, SetTheErrorRegisterAndReachTheMaster) {
  Rig rig("EL3202");
  auto& m = rig.master;
  m.bring_to_preop(0);
  rig.app().emergency(m.esc(0), 0x5000, 0x81, {1, 2, 3, 4, 5});
  EXPECT_EQ(rig.app().dictionary().get<std::uint8_t>(0x1001, 0), 0x81);
  auto emergencies = m.drain_emergencies(0);
  ASSERT_EQ(emergencies.size(), 1u);
  EXPECT_EQ(emergencies[0].error_code, 0x5000);
  EXPECT_EQ(emergencies[0].error_register, 0x81);
  EXPECT_EQ(emergencies[0].data, (std::array<std::uint8_t, 5>{1, 2, 3, 4, 5}));
}

TEST(DeviceErrors, RaiseAlErrorStepsDownWithTheCode) {
  Rig rig("EL4102");
  auto& m = rig.master;
  m.bring_to_preop(0);
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  rig.app().raise_al_error(m.esc(0), 0x8001, AlState::safeop);
  expect_al(m.al_status(0), AlState::safeop, true, 0x8001);
  // Raising a code for a higher state keeps the present one.
  rig.app().raise_al_error(m.esc(0), 0x8002, AlState::op);
  expect_al(m.al_status(0), AlState::safeop, true, 0x8002);
}

TEST(SiiDictionary, PdosBecomeMappingAndAssignmentObjects) {
  wire::SiiImage sii;
  sii.sync_managers = {{0x0F00, 0, 0x44, 0, 0x09, wire::sii_sm_type::kOutputs},
                       {0x1000, 0, 0x00, 0, 0x01, wire::sii_sm_type::kInputs},
                       {0x0998, 0, 0x00, 0, 0x04, wire::sii_sm_type::kInputs}};
  sii.strings = {"Channel 1", "Output", "Status", "Value"};
  for (std::uint16_t ch = 0; ch < 4; ++ch) {
    wire::SiiPdo p;
    p.index = static_cast<std::uint16_t>(0x1600 + ch);
    p.sync_manager = 0;
    p.name_index = 1;
    p.entries = {{static_cast<std::uint16_t>(0x7000 + 0x10 * ch), 1, 2, 0x01, 1, 0}};
    sii.rxpdos.push_back(p);
  }
  wire::SiiPdo in;
  in.index = 0x1A00;
  in.sync_manager = 1;
  in.entries = {{0x6000, 1, 3, 0x01, 1, 0}, {0, 0, 0, 0, 7, 0}, {0x6000, 0x11, 4, 0x03, 16, 0}};
  sii.txpdos = {in};
  wire::SiiPdo unassigned;
  unassigned.index = 0x1A01;
  unassigned.sync_manager = 0xFF;
  unassigned.entries = {{0x6010, 0, 0, 0x07, 32, 0}};
  sii.txpdos.push_back(unassigned);

  EXPECT_EQ(process_data_sync_managers(sii),
            (std::vector<ProcessDataSyncManager>{{0, PdoDirection::rx, 0x0F00},
                                                 {1, PdoDirection::tx, 0x1000}}));
  ObjectDictionary od;
  add_sii_process_data(od, sii);
  auto out = process_data_layout(od, 0);
  ASSERT_TRUE(out.ok());
  EXPECT_EQ(out->bit_length, 4u);
  EXPECT_EQ(out->byte_length, 1u);
  EXPECT_EQ(out->pdos, (std::vector<std::uint16_t>{0x1600, 0x1601, 0x1602, 0x1603}));
  EXPECT_EQ(out->entries[2].index, 0x7020);
  EXPECT_EQ(out->entries[2].bit_offset, 2u);
  auto input = process_data_layout(od, 1);
  ASSERT_TRUE(input.ok());
  EXPECT_EQ(input->bit_length, 24u);
  EXPECT_TRUE(input->entries[1].gap);
  EXPECT_EQ(input->entries[2].bit_offset, 8u);
  const ObjectEntry* value = od.find(0x6000, 0x11);
  ASSERT_NE(value, nullptr);
  EXPECT_EQ(value->data_type, DataType::integer16);
  EXPECT_TRUE(value->tx_mappable());
  EXPECT_EQ(od.find(0x7000, 1)->data_type, DataType::boolean);
  EXPECT_TRUE(od.find(0x7000, 1)->rx_mappable());
  EXPECT_EQ(od.find(0x7000, 1)->name, "Output");
  EXPECT_NE(od.find(0x1A01), nullptr);  // the mapping exists ...
  EXPECT_EQ(od.find(0x1C12), nullptr);  // ... but no SyncManager 2 has PDOs
  EXPECT_EQ(od.get<std::uint16_t>(0x1C11, 1), 0x1A00);
  EXPECT_EQ(od.get<std::uint8_t>(0x1C11, 0), 1);
  // Mapping and assignment are fixed unless asked otherwise.
  AccessContext preop;
  preop.state = AlState::preop;
  EXPECT_EQ(od.sdo_write(0x1C11, 0, Bytes{0}, preop).code(),
            static_cast<std::uint32_t>(wire::SdoAbortCode::write_of_read_only));
  ObjectDictionary writable;
  add_sii_process_data(writable, sii, {true, true, true});
  EXPECT_TRUE(writable.sdo_write(0x1C11, 0, Bytes{0}, preop).ok());
}

TEST(EntryNumbers, SignedUnsignedRealAndClamping) {
  ObjectDictionary od;
  od.add(make_var(0x2000, "i16", make_entry(0, "", DataType::integer16, kAccessReadWrite)));
  od.add(make_var(0x2001, "u8", make_entry(0, "", DataType::unsigned8, kAccessReadWrite)));
  od.add(make_var(0x2002, "f32", make_entry(0, "", DataType::real32, kAccessReadWrite)));
  od.add(make_var(0x2003, "s", make_string_entry(0, "", "abc")));
  EXPECT_TRUE(set_entry_number(od, 0x2000, 0, -1234.4));
  EXPECT_EQ(entry_number(od, 0x2000, 0), -1234.0);
  EXPECT_TRUE(set_entry_number(od, 0x2000, 0, 1e9));
  EXPECT_EQ(entry_number(od, 0x2000, 0), 32767.0);
  EXPECT_TRUE(set_entry_number(od, 0x2001, 0, -5));
  EXPECT_EQ(entry_number(od, 0x2001, 0), 0.0);
  EXPECT_TRUE(set_entry_number(od, 0x2001, 0, 300));
  EXPECT_EQ(entry_number(od, 0x2001, 0), 255.0);
  EXPECT_TRUE(set_entry_number(od, 0x2002, 0, 1.5));
  EXPECT_EQ(entry_number(od, 0x2002, 0), 1.5);
  EXPECT_FALSE(set_entry_number(od, 0x2003, 0, 1));
  EXPECT_EQ(entry_number(od, 0x2003, 0), std::nullopt);
  EXPECT_FALSE(set_entry_number(od, 0x2000, 0, std::nan("")));
  EXPECT_EQ(entry_number(od, 0x2999, 0), std::nullopt);
}

}  // namespace
}  // namespace ecat::sim
