// The "servo" profile: a CiA 402 drive driven through real datagrams — the power state machine
// (every controlword command, every statusword pattern), CSP following, the profile-position
// set-point handshake, the following-error fault with its emergency and fault reset, PDO
// remapping in PREOP with the SyncManager lengths that follow from it.
#include <cmath>
#include <cstdlib>

#include <gtest/gtest.h>

#include <ecat/sim/standard_application.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;
using test::SimMaster;
using wire::AlState;
namespace al = wire::al_status;

// Statusword patterns (see src/sim/devices/cia402.hpp).
constexpr std::uint16_t kSwitchOnDisabled = 0x0240;
constexpr std::uint16_t kReadyToSwitchOn = 0x0231;
constexpr std::uint16_t kSwitchedOn = 0x0233;
constexpr std::uint16_t kOperationEnabled = 0x0237;
constexpr std::uint16_t kQuickStopActive = 0x0217;
constexpr std::uint16_t kFaultReactionActive = 0x020F;
constexpr std::uint16_t kFault = 0x0208;
constexpr std::uint16_t kTargetReached = 0x0400;
constexpr std::uint16_t kBit12 = 0x1000;
constexpr std::uint16_t kFollowingErrorBit = 0x2000;

// Controlword commands.
constexpr std::uint16_t kShutdown = 0x0006;
constexpr std::uint16_t kSwitchOn = 0x0007;
constexpr std::uint16_t kEnableOperation = 0x000F;
constexpr std::uint16_t kDisableVoltage = 0x0000;
constexpr std::uint16_t kQuickStop = 0x0002;
constexpr std::uint16_t kFaultReset = 0x0080;

class Servo : public ::testing::Test {
 protected:
  void SetUp() override {
    test::add_device(segment, "servo", test::profile("servo"));
    m.assign_stations();
    m.bring_to_preop(0);
  }

  void to_op() {
    m.configure_process_data(0);
    ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
    ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  }

  // Default mapping: outputs controlword(0) target position(2) target velocity(6)
  // target torque(10) mode(12); inputs statusword(0) position(2) velocity(6) torque(10)
  // mode display(12) error code(13).
  std::uint8_t* out() { return &m.image()[m.slot(0, 2).offset]; }
  std::uint8_t* in() { return &m.image()[m.slot(0, 3).offset]; }
  void set_outputs(std::uint16_t controlword, std::int8_t mode, std::int32_t position = 0,
                   std::int32_t velocity = 0, std::int16_t torque = 0) {
    wire::store_le16(out(), controlword);
    wire::store_le32(out() + 2, static_cast<std::uint32_t>(position));
    wire::store_le32(out() + 6, static_cast<std::uint32_t>(velocity));
    wire::store_le16(out() + 10, static_cast<std::uint16_t>(torque));
    out()[12] = static_cast<std::uint8_t>(mode);
  }
  // One 1 ms cycle: time passes, then the LRW.
  void cycle() {
    m.wait(1'000'000);
    EXPECT_EQ(m.lrw(), 3);
  }
  std::uint16_t statusword() { return wire::load_le16(in()); }
  std::int32_t position() { return static_cast<std::int32_t>(wire::load_le32(in() + 2)); }
  std::int32_t velocity() { return static_cast<std::int32_t>(wire::load_le32(in() + 6)); }
  std::int8_t mode_display() { return static_cast<std::int8_t>(in()[12]); }
  std::uint16_t error_code() { return wire::load_le16(in() + 13); }
  // Sends `controlword` (mode kept) and returns the statusword of the next cycle.
  std::uint16_t command(std::uint16_t controlword, std::int8_t mode = 0) {
    wire::store_le16(out(), controlword);
    out()[12] = static_cast<std::uint8_t>(mode);
    cycle();
    cycle();
    return statusword();
  }
  void enable(std::int8_t mode) {
    set_outputs(0, mode, position());
    EXPECT_EQ(command(kShutdown, mode), kReadyToSwitchOn);
    EXPECT_EQ(command(kSwitchOn, mode), kSwitchedOn);
    EXPECT_EQ(command(kEnableOperation, mode) & 0x006F, kOperationEnabled & 0x006F);
  }

  Segment segment;
  SimMaster m{segment};
};

TEST_F(Servo, EveryControlwordCommandAndStatuswordPattern) {
  to_op();
  cycle();
  EXPECT_EQ(statusword(), kSwitchOnDisabled);
  // 2, 3, 4: shutdown, switch on, enable operation (mode 0: no mode bits).
  EXPECT_EQ(command(kShutdown), kReadyToSwitchOn);
  EXPECT_EQ(command(kSwitchOn), kSwitchedOn);
  EXPECT_EQ(command(kEnableOperation), kOperationEnabled);
  // 5: disable operation.
  EXPECT_EQ(command(kSwitchOn), kSwitchedOn);
  // 6: shutdown from switched on.
  EXPECT_EQ(command(kShutdown), kReadyToSwitchOn);
  // 3 + 4 in one step.
  EXPECT_EQ(command(kEnableOperation), kOperationEnabled);
  // 8: shutdown from operation enabled.
  EXPECT_EQ(command(kShutdown), kReadyToSwitchOn);
  // 7: disable voltage from ready to switch on.
  EXPECT_EQ(command(kDisableVoltage), kSwitchOnDisabled);
  // 7: quick stop from ready to switch on.
  command(kShutdown);
  EXPECT_EQ(command(kQuickStop), kSwitchOnDisabled);
  // 10: disable voltage / quick stop from switched on.
  command(kShutdown);
  command(kSwitchOn);
  EXPECT_EQ(command(kDisableVoltage), kSwitchOnDisabled);
  command(kShutdown);
  command(kSwitchOn);
  EXPECT_EQ(command(kQuickStop), kSwitchOnDisabled);
  // 9: disable voltage from operation enabled.
  command(kShutdown);
  EXPECT_EQ(command(kEnableOperation), kOperationEnabled);
  EXPECT_EQ(command(kDisableVoltage), kSwitchOnDisabled);
  // 11, 12: quick stop, then (option code 2) switch on disabled once the motor stood still.
  command(kShutdown);
  command(kEnableOperation);
  wire::store_le16(out(), kQuickStop);
  cycle();
  EXPECT_EQ(statusword(), kQuickStopActive);
  cycle();
  EXPECT_EQ(statusword(), kSwitchOnDisabled);
  // Commands with the fault reset bit set do nothing outside FAULT.
  EXPECT_EQ(command(kShutdown | kFaultReset), kSwitchOnDisabled);
}

TEST_F(Servo, QuickStopOptionFiveToEightStaysAndReenables) {
  ASSERT_EQ(m.download(0, 0x605A, 0, {0x06, 0x00}).abort, 0u);
  to_op();
  cycle();
  command(kShutdown);
  command(kEnableOperation);
  EXPECT_EQ(command(kQuickStop), kQuickStopActive);
  for (int i = 0; i < 50; ++i)
    cycle();
  EXPECT_EQ(statusword(), kQuickStopActive);
  // 16: enable operation from quick stop active.
  EXPECT_EQ(command(kEnableOperation), kOperationEnabled);
  // 12: disable voltage from quick stop active.
  command(kQuickStop);
  EXPECT_EQ(command(kDisableVoltage), kSwitchOnDisabled);
}

TEST_F(Servo, CspFollowsTheTargetWithAShortLag) {
  to_op();
  cycle();
  enable(8);
  EXPECT_EQ(mode_display(), 8);
  EXPECT_EQ(statusword(), kOperationEnabled | kTargetReached | kBit12);
  // A ramp of 10 counts per 1 ms cycle: 10000 counts/s.
  std::int32_t target = 0;
  for (int i = 0; i < 200; ++i) {
    target += 10;
    wire::store_le32(out() + 2, static_cast<std::uint32_t>(target));
    cycle();
  }
  // The set-point moves in 1 ms steps and the position loop (2 ms) follows each step.
  EXPECT_NEAR(position(), target - 25, 3);
  EXPECT_NEAR(velocity(), 10000, 2000);
  EXPECT_EQ(statusword() & kFollowingErrorBit, 0);
  // The target stands still: the drive settles on it.
  for (int i = 0; i < 40; ++i)
    cycle();
  EXPECT_EQ(position(), target);
  EXPECT_EQ(velocity(), 0);
  EXPECT_EQ(statusword(), kOperationEnabled | kTargetReached | kBit12);
  auto* dev = device_application(m.esc(0));
  EXPECT_EQ(dev->signal("position_actual"), target);
  EXPECT_EQ(dev->signal("statusword"), statusword());
  EXPECT_EQ(dev->signal("controlword"), kEnableOperation);
  EXPECT_EQ(dev->signal("mode"), 8);
}

TEST_F(Servo, ProfilePositionSetPointHandshake) {
  ASSERT_EQ(m.download(0, 0x6081, 0, test::le32(100000)).abort, 0u);   // profile velocity
  ASSERT_EQ(m.download(0, 0x6083, 0, test::le32(2000000)).abort, 0u);  // acceleration
  ASSERT_EQ(m.download(0, 0x6084, 0, test::le32(2000000)).abort, 0u);  // deceleration
  to_op();
  cycle();
  enable(1);
  EXPECT_EQ(statusword(), kOperationEnabled | kTargetReached);
  // New set-point: bit 4 rising; the drive acknowledges with bit 12 and starts moving.
  wire::store_le32(out() + 2, 5000);
  EXPECT_EQ(command(kEnableOperation | 0x0010, 1), kOperationEnabled | kBit12);
  // Bit 4 back to 0: the acknowledge goes away.
  EXPECT_EQ(command(kEnableOperation, 1) & (kBit12 | kTargetReached), 0);
  int cycles = 0;
  for (; cycles < 300 && (statusword() & kTargetReached) == 0; ++cycles)
    cycle();
  // 5000 counts at 2e6 counts/s² (triangular profile): about 100 ms.
  EXPECT_GT(cycles, 80);
  EXPECT_EQ(statusword(), kOperationEnabled | kTargetReached);
  EXPECT_NEAR(position(), 5000, 10);
  for (int i = 0; i < 10; ++i)
    cycle();
  EXPECT_EQ(position(), 5000);
  // A relative set-point (bit 6): 1000 further.
  wire::store_le32(out() + 2, 1000);
  command(kEnableOperation | 0x0050, 1);
  command(kEnableOperation | 0x0040, 1);
  for (int i = 0; i < 300 && (statusword() & kTargetReached) == 0; ++i)
    cycle();
  for (int i = 0; i < 10; ++i)
    cycle();
  EXPECT_EQ(position(), 6000);
}

TEST_F(Servo, FollowingErrorFaultsWithEmergencyAndFaultResetClearsIt) {
  ASSERT_EQ(m.download(0, 0x6065, 0, test::le32(100)).abort, 0u);  // window
  ASSERT_EQ(m.download(0, 0x6066, 0, {5, 0}).abort, 0u);           // 5 ms
  ASSERT_EQ(m.download(0, 0x6085, 0, test::le32(1000000000)).abort, 0u);
  to_op();
  cycle();
  enable(8);
  m.drain_emergencies(0);
  // A jump the position loop cannot follow within the window.
  wire::store_le32(out() + 2, 100000);
  cycle();
  cycle();
  EXPECT_EQ(statusword() & 0x006F, kOperationEnabled & 0x006F);
  EXPECT_NE(statusword() & kFollowingErrorBit, 0);  // exceeded, not yet for 5 ms
  // The error outlasts the time-out: fault reaction, then fault.
  bool saw_reaction = false;
  for (int i = 0; i < 20 && (statusword() & 0x004F) != (kFault & 0x004F); ++i) {
    m.wait(1'000'000);
    m.lrw();
    saw_reaction = saw_reaction || (statusword() & 0x004F) == (kFaultReactionActive & 0x004F);
  }
  EXPECT_TRUE(saw_reaction);  // the motor needs a few ms to stop
  EXPECT_EQ(statusword() & ~kFollowingErrorBit, kFault);
  EXPECT_EQ(error_code(), 0x8611);
  auto emergencies = m.drain_emergencies(0);
  ASSERT_EQ(emergencies.size(), 1u);
  EXPECT_EQ(emergencies[0].error_code, 0x8611);
  EXPECT_EQ(emergencies[0].error_register, 0x01);
  auto reg = m.upload(0, 0x1001, 0);
  ASSERT_TRUE(reg.value);
  EXPECT_EQ(*reg.value, Bytes{0x01});
  // Commands do nothing in FAULT; a rising fault reset leaves it.
  wire::store_le32(out() + 2, position());
  EXPECT_EQ(command(kEnableOperation, 8) & ~kFollowingErrorBit, kFault);
  EXPECT_EQ(command(kFaultReset, 8), kSwitchOnDisabled);
  EXPECT_EQ(error_code(), 0);
  emergencies = m.drain_emergencies(0);
  ASSERT_EQ(emergencies.size(), 1u);
  EXPECT_EQ(emergencies[0].error_code, 0x0000);
  EXPECT_EQ(command(kShutdown, 8), kReadyToSwitchOn);
}

TEST_F(Servo, CsvAndCstMoveTheMotor) {
  to_op();
  cycle();
  enable(9);
  wire::store_le32(out() + 6, static_cast<std::uint32_t>(-2000));
  for (int i = 0; i < 100; ++i)
    cycle();
  EXPECT_NEAR(velocity(), -2000, 5);
  EXPECT_LT(position(), -150);
  EXPECT_EQ(statusword(), kOperationEnabled | kBit12);
  // Mode change to CST with torque 100 per mille: the motor accelerates.
  wire::store_le16(out() + 10, 100);
  out()[12] = 10;
  for (int i = 0; i < 100; ++i)
    cycle();
  EXPECT_EQ(mode_display(), 10);
  EXPECT_GT(velocity(), 0);
  const auto torque = static_cast<std::int16_t>(wire::load_le16(in() + 10));
  EXPECT_EQ(torque, 100);
}

TEST_F(Servo, LeavingOpSwitchesThePowerStageOff) {
  to_op();
  cycle();
  enable(8);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  auto sw = m.upload(0, 0x6041, 0);
  ASSERT_TRUE(sw.value);
  EXPECT_EQ(wire::load_le16(sw.value->data()), kSwitchOnDisabled);
}

TEST_F(Servo, TheStateMachineRunsOnSdoWritesInPreop) {
  ASSERT_EQ(m.download(0, 0x6040, 0, test::le16(kShutdown)).abort, 0u);
  auto sw = m.upload(0, 0x6041, 0);
  ASSERT_TRUE(sw.value);
  EXPECT_EQ(wire::load_le16(sw.value->data()), kReadyToSwitchOn);
}

TEST_F(Servo, RemappingInPreopChangesTheSyncManagerLengths) {
  // 0x1C12 = {0x1601} (controlword + target position: 6 bytes), 0x1A01 mapped by hand.
  ASSERT_EQ(m.download(0, 0x1C12, 0, {0}).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1C12, 1, test::le16(0x1601)).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1C12, 0, {1}).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1A01, 0, {0}).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1A01, 1, test::le32(0x60410010)).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1A01, 2, test::le32(0x60640020)).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1A01, 3, test::le32(0x60610008)).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1A01, 0, {3}).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1C13, 0, {0}).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1C13, 1, test::le16(0x1A01)).abort, 0u);
  ASSERT_EQ(m.download(0, 0x1C13, 0, {1}).abort, 0u);
  // An entry that is not mappable, and a mapping change outside sub 0 = 0, are refused.
  EXPECT_EQ(m.download(0, 0x1A01, 4, test::le32(0x60650020)).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::cannot_store_device_state));
  // The SII lengths (13 / 15 bytes) no longer match: 0x001D.
  m.configure_process_data(0);
  EXPECT_EQ(m.request(0, AlState::safeop).code, al::kInvalidOutputConfiguration);
  m.write_sm(0, 2, 0x1100, 6, 0x64);
  EXPECT_EQ(m.request(0, AlState::safeop, true).code, al::kInvalidInputConfiguration);
  m.write_sm(0, 3, 0x1200, 7, 0x20);
  auto r = m.request(0, AlState::safeop, true);
  EXPECT_EQ(r.state, AlState::safeop);
  EXPECT_EQ(r.code, 0);
  // Mapping is fixed now.
  EXPECT_EQ(m.download(0, 0x1C12, 0, {0}).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::cannot_store_device_state));
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  // Process data through the new layout (the image still has the SII-length slots: the first
  // 6 / 7 bytes are what the SyncManagers carry).
  std::uint8_t* o = &m.image()[m.slot(0, 2).offset];
  std::uint8_t* i = &m.image()[m.slot(0, 3).offset];
  wire::store_le16(o, kShutdown);
  m.wait(1'000'000);
  m.lrw();
  m.wait(1'000'000);
  m.lrw();
  EXPECT_EQ(wire::load_le16(i), kReadyToSwitchOn);
  EXPECT_EQ(static_cast<std::int8_t>(i[6]), 0);
}

TEST(ServoProfile, SiiIdentityPdosAndDc) {
  auto esc = make_device(test::profile("servo"));
  ASSERT_TRUE(esc.ok());
  auto decoded = wire::decode_sii((*esc)->eeprom());
  ASSERT_TRUE(decoded.ok());
  const auto& sii = decoded->image;
  EXPECT_EQ(sii.identity.vendor_id, 0x00000ACEu);
  EXPECT_EQ(sii.identity.product_code, 0x00002402u);
  ASSERT_EQ(sii.rxpdos.size(), 2u);
  EXPECT_EQ(sii.rxpdos[0].bit_length(), 104u);
  EXPECT_EQ(sii.txpdos[0].bit_length(), 120u);
  EXPECT_EQ(sii.rxpdos[1].sync_manager, 0xFF);
  ASSERT_EQ(sii.dc.size(), 2u);
  EXPECT_EQ(sii.dc[1].assign_activate, 0x0300);
  ASSERT_TRUE(sii.general);
  EXPECT_EQ(sii.general->ds402_channels, 1);
  EXPECT_TRUE((*esc)->dc() != nullptr);
  EXPECT_FALSE(make_device(test::profile("servo", {{"dc_required", "maybe"}})).ok());
}

}  // namespace
}  // namespace ecat::sim
