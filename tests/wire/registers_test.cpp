#include <cstdint>
#include <limits>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <ecat/wire/registers.hpp>

namespace {

using namespace ecat::wire;
using ::testing::HasSubstr;

TEST(Registers, Addresses) {
  EXPECT_EQ(reg::kType, 0x0000);
  EXPECT_EQ(reg::kRevision, 0x0001);
  EXPECT_EQ(reg::kBuild, 0x0002);
  EXPECT_EQ(reg::kFmmuCount, 0x0004);
  EXPECT_EQ(reg::kSyncManagerCount, 0x0005);
  EXPECT_EQ(reg::kRamSize, 0x0006);
  EXPECT_EQ(reg::kPortDescriptor, 0x0007);
  EXPECT_EQ(reg::kFeatures, 0x0008);
  EXPECT_EQ(reg::kStationAddress, 0x0010);
  EXPECT_EQ(reg::kStationAlias, 0x0012);
  EXPECT_EQ(reg::kDlControl, 0x0100);
  EXPECT_EQ(reg::kDlPortControl, 0x0101);
  EXPECT_EQ(reg::kDlAliasControl, 0x0103);
  EXPECT_EQ(reg::kDlStatus, 0x0110);
  EXPECT_EQ(reg::kAlControl, 0x0120);
  EXPECT_EQ(reg::kAlStatus, 0x0130);
  EXPECT_EQ(reg::kAlStatusCode, 0x0134);
  EXPECT_EQ(reg::kPdiControl, 0x0140);
  EXPECT_EQ(reg::kEcatEventMask, 0x0200);
  EXPECT_EQ(reg::kAlEventMask, 0x0204);
  EXPECT_EQ(reg::kEcatEventRequest, 0x0210);
  EXPECT_EQ(reg::kAlEventRequest, 0x0220);
  EXPECT_EQ(reg::kRxErrorCounter, 0x0300);
  EXPECT_EQ(reg::kForwardedRxError, 0x0308);
  EXPECT_EQ(reg::kProcessingUnitError, 0x030C);
  EXPECT_EQ(reg::kPdiError, 0x030D);
  EXPECT_EQ(reg::kLostLink, 0x0310);
  EXPECT_EQ(reg::kWatchdogDivider, 0x0400);
  EXPECT_EQ(reg::kWatchdogTimePdi, 0x0410);
  EXPECT_EQ(reg::kWatchdogTimeProcessData, 0x0420);
  EXPECT_EQ(reg::kWatchdogStatus, 0x0440);
  EXPECT_EQ(reg::kWatchdogCounterProcessData, 0x0442);
  EXPECT_EQ(reg::kSiiAccess, 0x0500);
  EXPECT_EQ(reg::kSiiPdiAccess, 0x0501);
  EXPECT_EQ(reg::kSiiControl, 0x0502);
  EXPECT_EQ(reg::kSiiAddress, 0x0504);
  EXPECT_EQ(reg::kSiiData, 0x0508);
  EXPECT_EQ(reg::kMiiControl, 0x0510);
  EXPECT_EQ(reg::kFmmuBase, 0x0600);
  EXPECT_EQ(reg::kSyncManagerBase, 0x0800);
  EXPECT_EQ(reg::kDcReceiveTimePort0, 0x0900);
  EXPECT_EQ(reg::kDcSystemTime, 0x0910);
  EXPECT_EQ(reg::kDcReceiveTimeEpu, 0x0918);
  EXPECT_EQ(reg::kDcSystemTimeOffset, 0x0920);
  EXPECT_EQ(reg::kDcSystemTimeDelay, 0x0928);
  EXPECT_EQ(reg::kDcSystemTimeDifference, 0x092C);
  EXPECT_EQ(reg::kDcSpeedCounterStart, 0x0930);
  EXPECT_EQ(reg::kDcSpeedCounterDiff, 0x0932);
  EXPECT_EQ(reg::kDcSystemTimeFilterDepth, 0x0934);
  EXPECT_EQ(reg::kDcSpeedCounterFilterDepth, 0x0935);
  EXPECT_EQ(reg::kDcCyclicUnitControl, 0x0980);
  EXPECT_EQ(reg::kDcActivation, 0x0981);
  EXPECT_EQ(reg::kDcPulseLength, 0x0982);
  EXPECT_EQ(reg::kDcActivationStatus, 0x0984);
  EXPECT_EQ(reg::kDcSync0Status, 0x098E);
  EXPECT_EQ(reg::kDcSync1Status, 0x098F);
  EXPECT_EQ(reg::kDcStartTime, 0x0990);
  EXPECT_EQ(reg::kDcNextSync1, 0x0998);
  EXPECT_EQ(reg::kDcSync0CycleTime, 0x09A0);
  EXPECT_EQ(reg::kDcSync1CycleTime, 0x09A4);
  EXPECT_EQ(reg::kDcLatch0Control, 0x09A8);
  EXPECT_EQ(reg::kDcLatch1Control, 0x09A9);
  EXPECT_EQ(reg::kDcLatch0Status, 0x09AE);
  EXPECT_EQ(reg::kDcLatch1Status, 0x09AF);
  EXPECT_EQ(reg::kDcLatch0PositiveEdge, 0x09B0);
  EXPECT_EQ(reg::kDcLatch0NegativeEdge, 0x09B8);
  EXPECT_EQ(reg::kDcLatch1PositiveEdge, 0x09C0);
  EXPECT_EQ(reg::kDcLatch1NegativeEdge, 0x09C8);
  EXPECT_EQ(reg::kProcessRam, 0x1000);
}

TEST(Registers, IndexedBlocks) {
  EXPECT_EQ(reg::fmmu(0), 0x0600);
  EXPECT_EQ(reg::fmmu(1), 0x0610);
  EXPECT_EQ(reg::fmmu(15), 0x06F0);
  EXPECT_EQ(reg::sync_manager(0), 0x0800);
  EXPECT_EQ(reg::sync_manager(1), 0x0808);
  EXPECT_EQ(reg::sync_manager(15), 0x0878);
  EXPECT_EQ(reg::sync_manager(2) + reg::kSyncManagerStatusOffset, 0x0815);
  EXPECT_EQ(reg::dc_receive_time(0), 0x0900);
  EXPECT_EQ(reg::dc_receive_time(3), 0x090C);
  EXPECT_EQ(reg::kFmmuSize, 16u);
  EXPECT_EQ(reg::kSyncManagerSize, 8u);
  EXPECT_EQ(reg::kMaxFmmus, 16u);
  EXPECT_EQ(reg::kMaxSyncManagers, 16u);
}

TEST(Registers, SystemTimeDifference) {
  EXPECT_EQ(decode_system_time_difference(0x00000005), 5);
  EXPECT_EQ(decode_system_time_difference(0x80000005), -5);
  EXPECT_EQ(decode_system_time_difference(0x7FFFFFFF), 0x7FFFFFFF);
  EXPECT_EQ(decode_system_time_difference(0x80000000), 0);
  EXPECT_EQ(encode_system_time_difference(-5), 0x80000005u);
  EXPECT_EQ(encode_system_time_difference(1234), 1234u);
  EXPECT_EQ(encode_system_time_difference(0), 0u);
  EXPECT_EQ(encode_system_time_difference(std::numeric_limits<std::int32_t>::min()), 0xFFFFFFFFu);
  for (std::int32_t v : {-1000000, -1, 1, 999999, 0x7FFFFFFF}) {
    EXPECT_EQ(decode_system_time_difference(encode_system_time_difference(v)), v);
  }
}

// ---------------------------------------------------------------------------------------------
// FMMU

TEST(FmmuConfig, EncodeLayout) {
  FmmuConfig f;
  f.logical_start = 0x00010800;
  f.length = 3;
  f.logical_start_bit = 2;
  f.logical_stop_bit = 5;
  f.physical_start = 0x1100;
  f.physical_start_bit = 1;
  f.type = FmmuType::write;
  f.active = true;
  const std::array<std::uint8_t, 16> expected = {0x00, 0x08, 0x01, 0x00, 0x03, 0x00, 0x02, 0x05,
                                                 0x00, 0x11, 0x01, 0x02, 0x01, 0x00, 0x00, 0x00};
  EXPECT_EQ(f.encode(), expected);
  std::array<std::uint8_t, 20> buffer{};
  ASSERT_TRUE(f.encode(buffer).ok());
  EXPECT_TRUE(std::equal(expected.begin(), expected.end(), buffer.begin()));
  std::array<std::uint8_t, 15> small{};
  auto r = f.encode(small);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), ecat::Errc::out_of_range);
}

TEST(FmmuConfig, DecodeAndRoundTrip) {
  const std::uint8_t bytes[16] = {0x00, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x07,
                                  0x00, 0x10, 0x00, 0x01, 0x01, 0x00, 0x00, 0x00};
  auto f = FmmuConfig::decode(bytes);
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(f->logical_start, 0u);
  EXPECT_EQ(f->length, 1);
  EXPECT_EQ(f->logical_stop_bit, 7);
  EXPECT_EQ(f->physical_start, 0x1000);
  EXPECT_EQ(f->type, FmmuType::read);
  EXPECT_TRUE(f->active);
  for (FmmuType t : {FmmuType::unused, FmmuType::read, FmmuType::write, FmmuType::read_write}) {
    FmmuConfig c{0xFFFFFFFF, 0xFFFF, 7, 0, 0xFFFF, 7, t, t != FmmuType::unused};
    auto back = FmmuConfig::decode(c.encode());
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(*back, c);
  }
}

TEST(FmmuConfig, DecodeErrors) {
  std::array<std::uint8_t, 16> good = FmmuConfig{}.encode();
  auto short_one = FmmuConfig::decode(Bytes{good.data(), 15});
  ASSERT_FALSE(short_one.ok());
  EXPECT_EQ(short_one.error().code(), ecat::Errc::truncated);
  EXPECT_THAT(short_one.error().message(), HasSubstr("needs 16 bytes, got 15"));
  auto bad_bit = good;
  bad_bit[7] = 8;
  auto r = FmmuConfig::decode(bad_bit);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message(), HasSubstr("logical stop bit (byte 7) is 8"));
  auto bad_type = good;
  bad_type[11] = 0x04;
  EXPECT_FALSE(FmmuConfig::decode(bad_type).ok());
  auto bad_activate = good;
  bad_activate[12] = 0x02;
  EXPECT_FALSE(FmmuConfig::decode(bad_activate).ok());
}

// ---------------------------------------------------------------------------------------------
// SyncManager

TEST(SyncManager, ConventionalControlBytes) {
  EXPECT_EQ(kMailboxOutControl.encode(), 0x26);
  EXPECT_EQ(kMailboxInControl.encode(), 0x22);
  EXPECT_EQ(kOutputsControl.encode(), 0x64);
  EXPECT_EQ(kInputsControl.encode(), 0x20);
  auto c = SmControl::decode(0x44);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->mode, SmMode::buffered);
  EXPECT_EQ(c->direction, SmDirection::write);
  EXPECT_FALSE(c->ecat_event);
  EXPECT_FALSE(c->pdi_event);
  EXPECT_TRUE(c->watchdog);
  c = SmControl::decode(0x12);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->mode, SmMode::mailbox);
  EXPECT_EQ(c->direction, SmDirection::read);
  EXPECT_TRUE(c->ecat_event);
}

TEST(SyncManager, ControlRejectsReservedModesAndDirections) {
  for (unsigned raw = 0; raw < 256; ++raw) {
    const unsigned mode = raw & 3u;
    const unsigned dir = (raw >> 2) & 3u;
    auto c = SmControl::decode(static_cast<std::uint8_t>(raw));
    const bool valid = (mode == 0 || mode == 2) && dir < 2;
    ASSERT_EQ(c.ok(), valid) << raw;
    if (valid) {
      EXPECT_EQ(c->encode(), raw & 0x7Fu) << raw;  // bit 7 is reserved
    }
  }
  auto r = SmControl::decode(0x01);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message(), HasSubstr("reserved operation mode 1"));
  r = SmControl::decode(0x08);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message(), HasSubstr("reserved direction 2"));
}

TEST(SyncManager, StatusActivateAndPdiControlBits) {
  const auto status = SmStatus::decode(0x08);
  EXPECT_TRUE(status.mailbox_full);
  EXPECT_FALSE(status.interrupt_write);
  EXPECT_EQ(status.buffer_state, 0);
  const auto three_buffer = SmStatus::decode(0x31);
  EXPECT_TRUE(three_buffer.interrupt_write);
  EXPECT_EQ(three_buffer.buffer_state, 3);
  for (unsigned raw = 0; raw < 256; ++raw) {
    const auto b = static_cast<std::uint8_t>(raw);
    EXPECT_EQ(SmStatus::decode(b).encode(), raw & ~0x04u) << raw;
    EXPECT_EQ(SmActivate::decode(b).encode(), raw & 0xC3u) << raw;
    EXPECT_EQ(SmPdiControl::decode(b).encode(), raw & 0x03u) << raw;
  }
  EXPECT_TRUE(SmActivate::decode(0x01).enable);
  EXPECT_TRUE(SmActivate::decode(0x02).repeat_request);
  EXPECT_TRUE(SmPdiControl::decode(0x01).deactivate);
  EXPECT_TRUE(SmPdiControl::decode(0x02).repeat_ack);
}

TEST(SyncManager, EncodeDecodeMailbox) {
  SyncManagerConfig sm;
  sm.physical_start = 0x1000;
  sm.length = 128;
  sm.control = kMailboxOutControl;
  sm.activate.enable = true;
  const std::array<std::uint8_t, 8> expected = {0x00, 0x10, 0x80, 0x00, 0x26, 0x00, 0x01, 0x00};
  EXPECT_EQ(sm.encode(), expected);
  auto back = SyncManagerConfig::decode(expected);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, sm);

  const std::uint8_t full[8] = {0x80, 0x10, 0x80, 0x00, 0x22, 0x08, 0x01, 0x00};
  auto in = SyncManagerConfig::decode(full);
  ASSERT_TRUE(in.ok());
  EXPECT_EQ(in->physical_start, 0x1080);
  EXPECT_EQ(in->control, kMailboxInControl);
  EXPECT_TRUE(in->status.mailbox_full);
  EXPECT_TRUE(in->activate.enable);
}

TEST(SyncManager, DecodeErrors) {
  const std::uint8_t seven[7] = {};
  auto r = SyncManagerConfig::decode(seven);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message(), HasSubstr("needs 8 bytes, got 7"));
  const std::uint8_t reserved[8] = {0, 0x10, 1, 0, 0x03, 0, 1, 0};
  EXPECT_FALSE(SyncManagerConfig::decode(reserved).ok());
  std::array<std::uint8_t, 7> small{};
  EXPECT_FALSE(SyncManagerConfig{}.encode(small).ok());
}

// ---------------------------------------------------------------------------------------------
// DL status, features, port descriptor, information block

// The process-data watchdog's registers from a time and back: never shorter than asked, shorter
// than asked plus one tick; the power-up values are 100 ms.
TEST(ProcessDataWatchdog, ForTimeRoundTripsWithinOneTick) {
  using std::chrono::nanoseconds;
  EXPECT_EQ(ProcessDataWatchdog{}.time(), std::chrono::milliseconds(100));
  auto hundred = ProcessDataWatchdog::for_time(std::chrono::milliseconds(100));
  ASSERT_TRUE(hundred);
  EXPECT_EQ(*hundred, ProcessDataWatchdog{});
  auto off = ProcessDataWatchdog::for_time(nanoseconds(0));
  ASSERT_TRUE(off);
  EXPECT_TRUE(off->off());
  EXPECT_EQ(off->time(), nanoseconds(0));
  for (const std::int64_t ns :
       {std::int64_t{1}, std::int64_t{99'999}, std::int64_t{100'001}, std::int64_t{2'500'000},
        std::int64_t{6'553'500'000}, std::int64_t{6'553'500'001}, std::int64_t{10'000'000'000},
        std::int64_t{100'000'000'007}, ProcessDataWatchdog::kMaxTime.count()}) {
    SCOPED_TRACE(ns);
    auto w = ProcessDataWatchdog::for_time(nanoseconds(ns));
    ASSERT_TRUE(w) << w.error().describe();
    const nanoseconds tick((std::int64_t{w->divider} + 2) * 40);
    EXPECT_GE(w->time(), nanoseconds(ns));
    EXPECT_LT(w->time(), nanoseconds(ns) + tick);
    EXPECT_GT(w->ticks, 0);
    if (ns <= 6'553'500'000) {
      EXPECT_EQ(w->divider, ProcessDataWatchdog::kDefaultDivider);
    }
  }
  auto max = ProcessDataWatchdog::for_time(ProcessDataWatchdog::kMaxTime);
  ASSERT_TRUE(max);
  EXPECT_EQ(max->divider, 65535);
  EXPECT_EQ(max->ticks, 65535);
  for (const auto bad : {nanoseconds(-1), ProcessDataWatchdog::kMaxTime + nanoseconds(1)}) {
    auto w = ProcessDataWatchdog::for_time(bad);
    ASSERT_FALSE(w);
    EXPECT_EQ(w.error().code(), ecat::Errc::out_of_range);
    EXPECT_NE(w.error().message().find("process-data watchdog"), std::string::npos);
  }
}

TEST(DlStatus, DecodeExample) {
  // Last device of a line: PDI up, link and communication on port 0, ports 1..3 closed.
  const auto s = DlStatus::decode(std::uint16_t{0x5613});
  EXPECT_TRUE(s.pdi_operational);
  EXPECT_TRUE(s.pdi_watchdog_ok);
  EXPECT_FALSE(s.enhanced_link_detection);
  EXPECT_TRUE(s.ports[0].physical_link);
  EXPECT_FALSE(s.ports[0].loop_closed);
  EXPECT_TRUE(s.ports[0].communication);
  for (int p = 1; p < 4; ++p) {
    EXPECT_FALSE(s.ports[p].physical_link) << p;
    EXPECT_TRUE(s.ports[p].loop_closed) << p;
    EXPECT_FALSE(s.ports[p].communication) << p;
  }
  const std::uint8_t bytes[2] = {0x13, 0x56};
  auto from_bytes = DlStatus::decode(Bytes{bytes});
  ASSERT_TRUE(from_bytes.ok());
  EXPECT_EQ(*from_bytes, s);
  EXPECT_FALSE(DlStatus::decode(Bytes{bytes, 1}).ok());
}

TEST(DlStatus, BitPositions) {
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0004}).enhanced_link_detection);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0020}).ports[1].physical_link);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0080}).ports[3].physical_link);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0100}).ports[0].loop_closed);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0200}).ports[0].communication);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x0800}).ports[1].communication);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x1000}).ports[2].loop_closed);
  EXPECT_TRUE(DlStatus::decode(std::uint16_t{0x8000}).ports[3].communication);
  for (std::uint32_t raw = 0; raw <= 0xFFFF; ++raw) {
    ASSERT_EQ(DlStatus::decode(static_cast<std::uint16_t>(raw)).encode(), raw & ~0x0008u) << raw;
  }
}

TEST(EscFeatures, Bits) {
  const auto f = EscFeatures::decode(0x01CC);
  EXPECT_FALSE(f.fmmu_byte_oriented);
  EXPECT_TRUE(f.dc_supported);
  EXPECT_TRUE(f.dc_64bit);
  EXPECT_FALSE(f.low_jitter_ebus);
  EXPECT_FALSE(f.enhanced_link_detection_ebus);
  EXPECT_TRUE(f.enhanced_link_detection_mii);
  EXPECT_TRUE(f.separate_fcs_error_handling);
  EXPECT_TRUE(f.enhanced_dc_sync_activation);
  EXPECT_FALSE(f.lrw_not_supported);
  EXPECT_TRUE(EscFeatures::decode(0x0001).fmmu_byte_oriented);
  EXPECT_TRUE(EscFeatures::decode(0x0010).low_jitter_ebus);
  EXPECT_TRUE(EscFeatures::decode(0x0020).enhanced_link_detection_ebus);
  EXPECT_TRUE(EscFeatures::decode(0x0200).lrw_not_supported);
  EXPECT_TRUE(EscFeatures::decode(0x0400).read_write_not_supported);
  EXPECT_TRUE(EscFeatures::decode(0x0800).fixed_fmmu_sm_configuration);
  for (std::uint32_t raw = 0; raw <= 0xFFFF; ++raw) {
    ASSERT_EQ(EscFeatures::decode(static_cast<std::uint16_t>(raw)).encode(), raw & 0x0FFDu);
  }
}

TEST(PortDescriptor, TwoBitsPerPort) {
  const auto d = PortDescriptor::decode(0b00'01'10'11);
  EXPECT_EQ(d.ports[0], PortType::mii);
  EXPECT_EQ(d.ports[1], PortType::ebus);
  EXPECT_EQ(d.ports[2], PortType::not_configured);
  EXPECT_EQ(d.ports[3], PortType::not_implemented);
  EXPECT_EQ(to_string(PortType::ebus), "EBUS");
  EXPECT_EQ(to_string(PortType::mii), "MII");
  EXPECT_EQ(to_string(PortType::not_implemented), "not implemented");
  for (unsigned raw = 0; raw < 256; ++raw) {
    EXPECT_EQ(PortDescriptor::decode(static_cast<std::uint8_t>(raw)).encode(), raw);
  }
}

TEST(EscInformation, DecodeAndRoundTrip) {
  const std::uint8_t bytes[10] = {0x11, 0x02, 0x34, 0x12, 0x08, 0x08, 0x08, 0x0F, 0xFC, 0x01};
  auto info = EscInformation::decode(bytes);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->type, 0x11);
  EXPECT_EQ(info->revision, 0x02);
  EXPECT_EQ(info->build, 0x1234);
  EXPECT_EQ(info->fmmu_count, 8);
  EXPECT_EQ(info->sync_manager_count, 8);
  EXPECT_EQ(info->ram_size_kib, 8);
  EXPECT_EQ(info->ports.ports[0], PortType::mii);
  EXPECT_EQ(info->ports.ports[1], PortType::mii);
  EXPECT_EQ(info->ports.ports[2], PortType::not_implemented);
  EXPECT_TRUE(info->features.dc_supported);
  EXPECT_TRUE(info->features.low_jitter_ebus);
  const auto encoded = info->encode();
  EXPECT_TRUE(std::equal(encoded.begin(), encoded.end(), std::begin(bytes)));
  EXPECT_FALSE(EscInformation::decode(Bytes{bytes, 9}).ok());
}

TEST(RxErrorCounters, Layout) {
  const std::uint8_t bytes[8] = {1, 2, 3, 4, 5, 6, 7, 8};
  auto c = RxErrorCounters::decode(bytes);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->invalid_frame, (std::array<std::uint8_t, 4>{1, 3, 5, 7}));
  EXPECT_EQ(c->rx_error, (std::array<std::uint8_t, 4>{2, 4, 6, 8}));
  const auto encoded = c->encode();
  EXPECT_TRUE(std::equal(encoded.begin(), encoded.end(), std::begin(bytes)));
  EXPECT_FALSE(RxErrorCounters::decode(Bytes{bytes, 7}).ok());
}

TEST(SiiControlStatus, Bits) {
  const auto s = SiiControlStatus::decode(0x8140);
  EXPECT_TRUE(s.busy);
  EXPECT_TRUE(s.read_size_8);
  EXPECT_EQ(s.command, static_cast<std::uint8_t>(SiiCommand::read));
  EXPECT_FALSE(s.has_error());
  const auto e = SiiControlStatus::decode(0x2000);
  EXPECT_TRUE(e.acknowledge_error);
  EXPECT_TRUE(e.has_error());
  EXPECT_TRUE(SiiControlStatus::decode(0x0800).checksum_error);
  EXPECT_TRUE(SiiControlStatus::decode(0x1000).device_info_error);
  EXPECT_TRUE(SiiControlStatus::decode(0x4000).write_enable_error);
  EXPECT_EQ(sii_control::kCommandRead, 0x0100);
  EXPECT_EQ(sii_control::kCommandWrite | sii_control::kWriteEnable, 0x0201);
  EXPECT_EQ(sii_control::kCommandReload, 0x0400);
  EXPECT_EQ(sii_control::kErrorMask, 0x7800);
  for (std::uint32_t raw = 0; raw <= 0xFFFF; ++raw) {
    ASSERT_EQ(SiiControlStatus::decode(static_cast<std::uint16_t>(raw)).encode(), raw & ~0x001Eu);
  }
}

}  // namespace
