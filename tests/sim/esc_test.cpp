// Register-level behaviour of the emulated ESC and the segment: addressing, working counters,
// read-only registers, FMMU bit mapping, SyncManager handshakes, SII interface, AL control,
// topology order and DC receive-time latching.
#include <array>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/application.hpp>
#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/sim/standard_application.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim {
namespace {

using wire::Command;
namespace reg = wire::reg;

// `pdi_control`: SII word 0, loaded into 0x0140 (PDI control) and 0x0141 (ESC configuration).
// The default has a PDI (0x05, SPI) and both DC units on (0x0C), no device emulation.
std::vector<std::uint8_t> test_eeprom(std::uint32_t product, bool mailbox,
                                      std::uint16_t pdi_control = 0x0C05) {
  wire::SiiImage image;
  image.pdi_control = pdi_control;
  image.identity = {0x0000'0ACE, product, 1, product * 10};
  if (mailbox) {
    image.standard_mailbox = {0x1000, 128, 0x1080, 128};
    image.mailbox_protocols = 0x0004;
  }
  image.strings = {"TestDevice"};
  auto bytes = wire::encode_sii(image);
  EXPECT_TRUE(bytes.ok());
  return *bytes;
}

std::unique_ptr<Esc> make_esc(std::uint32_t product, bool mailbox = false,
                              std::unique_ptr<Application> app = nullptr) {
  return std::make_unique<Esc>(EscHardware{}, test_eeprom(product, mailbox), std::move(app));
}

struct Reply {
  std::vector<std::uint8_t> data;
  std::uint16_t wkc = 0;
  std::uint16_t adp = 0;
  bool returned = false;
};

// Sends one datagram through the segment as a frame and decodes the reply.
Reply exchange(Segment& segment, Command command, std::uint32_t address,
               std::vector<std::uint8_t> data, std::int64_t now_ns = 1'000'000) {
  std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
  wire::FrameBuilder builder(buffer);
  wire::DatagramHeader header;
  header.command = command;
  header.index = 7;
  header.address = address;
  header.length = static_cast<std::uint16_t>(data.size());
  EXPECT_TRUE(builder.add(header, data).has_value());
  const auto frame = builder.finish();
  std::vector<std::uint8_t> bytes(frame.begin(), frame.end());
  Reply reply;
  reply.returned = segment.process_frame(bytes, now_ns);
  auto decoded = wire::decode_frame(bytes);
  EXPECT_TRUE(decoded) << decoded.error.describe();
  for (const auto& d : *decoded.frame) {
    reply.data.assign(d.data.begin(), d.data.end());
    reply.wkc = d.wkc;
    reply.adp = d.header.adp();
  }
  return reply;
}

std::vector<std::uint8_t> le16(std::uint16_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8)};
}

std::uint32_t fp(std::uint16_t station, std::uint16_t offset) {
  return wire::physical_address(station, offset);
}

class ThreeSlaves : public ::testing::Test {
 protected:
  void SetUp() override {
    for (std::uint32_t i = 0; i < 3; ++i) {
      ASSERT_TRUE(segment.add_slave("s" + std::to_string(i), make_esc(0x100 + i)).ok());
    }
    for (std::uint16_t pos = 0; pos < 3; ++pos) {
      auto r = exchange(segment, Command::apwr,
                        wire::physical_address(wire::position_adp(pos), reg::kStationAddress),
                        le16(static_cast<std::uint16_t>(0x1000 + pos)));
      ASSERT_EQ(r.wkc, 1);
    }
  }
  Segment segment;
};

TEST_F(ThreeSlaves, BroadcastReadCountsEverySlaveAndIncrementsPosition) {
  auto r = exchange(segment, Command::brd, fp(0, reg::kType), {0});
  EXPECT_EQ(r.wkc, 3);
  EXPECT_EQ(r.adp, 3);
  EXPECT_EQ(r.data[0], 0x11);
}

TEST_F(ThreeSlaves, BroadcastReadOrsTheSlavesValues) {
  // Give each slave a different AL status code through the PDI, then BRD them.
  segment.esc(0).pdi_set_al_status(wire::AlState::init, false, 0x0001);
  segment.esc(1).pdi_set_al_status(wire::AlState::init, false, 0x0010);
  segment.esc(2).pdi_set_al_status(wire::AlState::init, false, 0x0100);
  auto r = exchange(segment, Command::brd, fp(0, reg::kAlStatusCode), {0, 0});
  EXPECT_EQ(r.wkc, 3);
  EXPECT_EQ(wire::load_le16(r.data.data()), 0x0111);
}

TEST_F(ThreeSlaves, AutoIncrementAddressesByPosition) {
  auto r = exchange(segment, Command::aprd,
                    wire::physical_address(wire::position_adp(2), reg::kStationAddress), {0, 0});
  EXPECT_EQ(r.wkc, 1);
  EXPECT_EQ(wire::load_le16(r.data.data()), 0x1002);
  // Each slave increments ADP: -2 + 3 = 1.
  EXPECT_EQ(r.adp, 1);
  auto none = exchange(segment, Command::aprd,
                       wire::physical_address(wire::position_adp(3), reg::kStationAddress), {0, 0});
  EXPECT_EQ(none.wkc, 0);
  EXPECT_EQ(wire::load_le16(none.data.data()), 0);
}

TEST_F(ThreeSlaves, ConfiguredAddressMatchesOnlyThatStation) {
  auto r = exchange(segment, Command::fprd, fp(0x1001, reg::kStationAddress), {0, 0});
  EXPECT_EQ(r.wkc, 1);
  EXPECT_EQ(wire::load_le16(r.data.data()), 0x1001);
  EXPECT_EQ(r.adp, 0x1001);  // FPxx leave ADP alone
  EXPECT_EQ(exchange(segment, Command::fprd, fp(0x2000, 0), {0}).wkc, 0);
}

TEST_F(ThreeSlaves, StationAliasAddressesOnlyWhenEnabled) {
  segment.esc(1).pdi_write_u16(reg::kStationAlias, 0x0BEE);
  EXPECT_EQ(exchange(segment, Command::fprd, fp(0x0BEE, reg::kType), {0}).wkc, 0);
  ASSERT_EQ(exchange(segment, Command::fpwr, fp(0x1001, reg::kDlAliasControl), {1}).wkc, 1);
  EXPECT_EQ(exchange(segment, Command::fprd, fp(0x0BEE, reg::kType), {0}).wkc, 1);
}

TEST_F(ThreeSlaves, ReadWriteReturnsOldValueWritesNewAndCountsThree) {
  auto r = exchange(segment, Command::fprw, fp(0x1000, reg::kEcatEventMask), le16(0x1234));
  EXPECT_EQ(r.wkc, 3);
  EXPECT_EQ(wire::load_le16(r.data.data()), 0x0000);
  EXPECT_EQ(segment.esc(0).read_u16(reg::kEcatEventMask), 0x1234);
}

TEST_F(ThreeSlaves, ReadMultipleWriteReadsAtTargetAndWritesOthers) {
  // FRMW of the user RAM: the addressed slave's value travels on to the others.
  segment.esc(1).pdi_write_u16(reg::kUserRam, 0xBEEF);
  auto r = exchange(segment, Command::frmw, fp(0x1001, reg::kUserRam), le16(0));
  EXPECT_EQ(r.wkc, 3);
  EXPECT_EQ(wire::load_le16(r.data.data()), 0xBEEF);
  // Slave 0 came before the reader and received the datagram's original data.
  EXPECT_EQ(segment.esc(0).read_u16(reg::kUserRam), 0x0000);
  EXPECT_EQ(segment.esc(2).read_u16(reg::kUserRam), 0xBEEF);
}

// Real ESCs ignore writes to read-only registers and do not count them: BWR 0x092C (system time
// difference) comes back with WKC 0 from the DC-capable EK1100 and EL2889 in
// replay-ek1100-el2828-el2889.pcapng, while BWR 0x0928 next to it counts both.
TEST_F(ThreeSlaves, ReadOnlyRegistersIgnoreWritesAndDoNotCount) {
  auto r = exchange(segment, Command::fpwr, fp(0x1000, reg::kAlStatus), le16(0x0008));
  EXPECT_EQ(r.wkc, 0);
  EXPECT_EQ(segment.esc(0).al_state(), wire::AlState::init);
  EXPECT_EQ(exchange(segment, Command::bwr, fp(0, reg::kType), {0x55}).wkc, 0);
  EXPECT_EQ(segment.esc(2).read_u8(reg::kType), 0x11);
  EXPECT_EQ(exchange(segment, Command::bwr, fp(0, 0x092C), {1, 2, 3, 4}).wkc, 0);
  EXPECT_EQ(exchange(segment, Command::bwr, fp(0, reg::kDcSystemTimeDelay), {0, 0, 0, 0}).wkc, 3);
  // A write that reaches one writable byte counts (AL status + reserved + AL status code: no).
  EXPECT_EQ(exchange(segment, Command::fpwr, fp(0x1000, 0x012E), {0, 0, 0, 0}).wkc, 0);
  EXPECT_EQ(exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), {1, 0, 0, 0}).wkc, 1);
}

// Registers an ESC does not have leave the working counter alone, for reads and writes: BWR to
// FMMU 3 counts only the EK1100 (8 FMMUs), not the two 3-FMMU terminals, in
// replay-ek1100-el2828-el2889.pcapng; BWR to SyncManager 4 likewise.
TEST(UnimplementedRegisters, FmmusAndSyncManagersBeyondTheCountDoNotAnswer) {
  Segment segment;
  EscHardware coupler;
  EscHardware terminal;
  terminal.fmmu_count = 3;
  terminal.sync_manager_count = 4;
  ASSERT_TRUE(
      segment.add_slave("c", std::make_unique<Esc>(coupler, test_eeprom(1, false), nullptr)).ok());
  ASSERT_TRUE(
      segment.add_slave("t", std::make_unique<Esc>(terminal, test_eeprom(2, false), nullptr)).ok());
  const std::vector<std::uint8_t> zeros16(16);
  EXPECT_EQ(exchange(segment, Command::bwr, reg::fmmu(2) * 0x10000u, zeros16).wkc, 2);
  EXPECT_EQ(exchange(segment, Command::bwr, std::uint32_t{reg::fmmu(3)} << 16, zeros16).wkc, 1);
  EXPECT_EQ(exchange(segment, Command::bwr, std::uint32_t{0x0680} << 16, zeros16).wkc, 0);
  EXPECT_EQ(exchange(segment, Command::bwr, std::uint32_t{reg::sync_manager(4)} << 16,
                     std::vector<std::uint8_t>(8))
                .wkc,
            1);
  auto read =
      exchange(segment, Command::aprd, wire::physical_address(wire::position_adp(1), reg::fmmu(3)),
               std::vector<std::uint8_t>(16, 0xAA));
  EXPECT_EQ(read.wkc, 0);
  EXPECT_EQ(read.data[0], 0xAA) << "the datagram passes unchanged";
}

// The DC system time unit is off when the ESC configuration (SII word 0 high byte -> 0x0141)
// enables neither SYNC out (bit 2) nor latch in (bit 3). The EL1004 in
// soem-sdinfo-ek1100-el1004.pcapng reads 0x0141 = 0x01 and answers FPRD 0x0918 with WKC 0 but
// FPRD 0x0900 (port receive time) with WKC 1; the EK1100 (0x0D) answers both. The EL2828 of the
// replay captures (SII word 0 = 0x0104) drops out of FRMW 0x0910 the same way.
TEST(DistributedClocks, SystemTimeUnitFollowsTheEscConfiguration) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("ek1100", make_esc(1)).ok());
  ASSERT_TRUE(segment
                  .add_slave("el1004", std::make_unique<Esc>(
                                           EscHardware{}, test_eeprom(2, false, 0x0104), nullptr))
                  .ok());
  EXPECT_TRUE(segment.esc(0).dc_system_time());
  EXPECT_FALSE(segment.esc(1).dc_system_time());
  const auto ap = [](std::uint16_t pos, std::uint16_t offset) {
    return wire::physical_address(wire::position_adp(pos), offset);
  };
  EXPECT_EQ(
      exchange(segment, Command::aprd, ap(1, reg::kDcSystemTime + 8), std::vector<std::uint8_t>(8))
          .wkc,
      0);
  EXPECT_EQ(
      exchange(segment, Command::aprd, ap(0, reg::kDcSystemTime + 8), std::vector<std::uint8_t>(8))
          .wkc,
      1);
  EXPECT_EQ(exchange(segment, Command::aprd, ap(1, reg::dc_receive_time(0)),
                     std::vector<std::uint8_t>(16))
                .wkc,
            1);
  EXPECT_EQ(exchange(segment, Command::bwr, reg::dc_receive_time(0) * 0x10000u, {0, 0, 0, 0}).wkc,
            2);
  EXPECT_EQ(exchange(segment, Command::bwr, std::uint32_t{reg::kDcSystemTimeOffset} << 16,
                     std::vector<std::uint8_t>(8))
                .wkc,
            1);
  // FRMW from the reference: it reads, the slave without system time neither reads nor writes.
  segment.esc(0).pdi_write_u16(reg::kStationAddress, 0x1000);
  EXPECT_EQ(
      exchange(segment, Command::frmw, fp(0x1000, reg::kDcSystemTime), std::vector<std::uint8_t>(8))
          .wkc,
      1);
}

// With device emulation (0x0141 bit 0) the ESC copies AL control into AL status itself, the error
// acknowledge bit included: after BWR 0x0120 = 0x0011 the EK1100, EL2828 and EL2889 of
// replay-ek1100-el2828-el2889.pcapng read AL status 0x0011, and SOEM reads 0x0012 after 0x12.
TEST(DeviceEmulation, AlStatusFollowsAlControl) {
  class Silent : public Application {
   public:
    void on_al_control(Esc&, std::uint16_t) override {}
  };
  Segment segment;
  ASSERT_TRUE(
      segment
          .add_slave("el2828", std::make_unique<Esc>(EscHardware{}, test_eeprom(1, false, 0x0104),
                                                     std::make_unique<Silent>()))
          .ok());
  ASSERT_TRUE(segment
                  .add_slave("no_emulation",
                             std::make_unique<Esc>(EscHardware{}, test_eeprom(2, false, 0x0005),
                                                   std::make_unique<Silent>()))
                  .ok());
  EXPECT_EQ(exchange(segment, Command::bwr, std::uint32_t{reg::kAlControl} << 16, le16(0x0011)).wkc,
            2);
  EXPECT_EQ(segment.esc(0).read_u16(reg::kAlStatus), 0x0011);
  EXPECT_EQ(segment.esc(1).read_u16(reg::kAlStatus), 0x0001) << "no firmware answered";
  exchange(segment, Command::bwr, std::uint32_t{reg::kAlControl} << 16, {0x02});
  EXPECT_EQ(segment.esc(0).read_u16(reg::kAlStatus), 0x0002);
}

// Nothing reloads the PDI watchdog of an ESC without a PDI: the EK1100 (SII word 0 = 0x0D00, PDI
// control 0) reports DL status 0x5A31 in the replay captures, the terminals with a PDI 0x5A33 /
// 0x1356 (bit 1 set).
TEST(DlStatus, PdiWatchdogBitNeedsAPdi) {
  Segment segment;
  ASSERT_TRUE(segment
                  .add_slave("ek1100", std::make_unique<Esc>(
                                           EscHardware{}, test_eeprom(1, false, 0x0D00), nullptr))
                  .ok());
  ASSERT_TRUE(segment
                  .add_slave("el2828", std::make_unique<Esc>(
                                           EscHardware{}, test_eeprom(2, false, 0x0104), nullptr))
                  .ok());
  auto first = exchange(segment, Command::aprd, wire::physical_address(0, reg::kDlStatus), {0, 0});
  auto last = exchange(segment, Command::aprd,
                       wire::physical_address(wire::position_adp(1), reg::kDlStatus), {0, 0});
  EXPECT_EQ(wire::load_le16(first.data.data()), 0x5A31);
  EXPECT_EQ(wire::load_le16(last.data.data()), 0x5613);
}

TEST_F(ThreeSlaves, RxErrorCountersClearOnWrite) {
  segment.esc(0).pdi_write(reg::kRxErrorCounter, std::vector<std::uint8_t>{1, 2, 3, 4});
  exchange(segment, Command::fpwr, fp(0x1000, reg::kRxErrorCounter + 2), {9});
  EXPECT_EQ(segment.esc(0).read_u32(reg::kRxErrorCounter), 0u);
}

TEST_F(ThreeSlaves, AlControlWalksValidTransitionsAndRefusesInvalidOnes) {
  auto& esc = segment.esc(0);
  exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), le16(0x0002));
  EXPECT_EQ(esc.al_state(), wire::AlState::preop);
  EXPECT_FALSE(esc.al_error());

  exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), le16(0x0008));  // PREOP -> OP
  EXPECT_EQ(esc.al_state(), wire::AlState::preop);
  EXPECT_TRUE(esc.al_error());
  EXPECT_EQ(esc.al_status_code(), wire::al_status::kInvalidRequestedStateChange);
  auto status = exchange(segment, Command::fprd, fp(0x1000, reg::kAlStatus), {0, 0, 0, 0, 0, 0});
  EXPECT_EQ(status.data[0], 0x12);
  EXPECT_EQ(wire::load_le16(&status.data[4]), 0x0011);

  // Without acknowledge the error blocks a step up; with it the request proceeds.
  exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), le16(0x0004));
  EXPECT_EQ(esc.al_state(), wire::AlState::preop);
  EXPECT_TRUE(esc.al_error());
  exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), le16(0x0014));
  EXPECT_EQ(esc.al_state(), wire::AlState::safeop);
  EXPECT_FALSE(esc.al_error());

  exchange(segment, Command::fpwr, fp(0x1000, reg::kAlControl), le16(0x0007));  // not a state
  EXPECT_TRUE(esc.al_error());
  EXPECT_EQ(esc.al_status_code(), wire::al_status::kUnknownRequestedState);
}

TEST_F(ThreeSlaves, SiiReadsThroughTheEepromInterface) {
  // Word 0x0A holds the product code.
  auto w = exchange(segment, Command::fpwr, fp(0x1002, reg::kSiiAddress), {0x0A, 0, 0, 0});
  ASSERT_EQ(w.wkc, 1);
  exchange(segment, Command::fpwr, fp(0x1002, reg::kSiiControl), le16(0x0100));
  auto control = exchange(segment, Command::fprd, fp(0x1002, reg::kSiiControl), {0, 0});
  const auto status = wire::SiiControlStatus::decode(wire::load_le16(control.data.data()));
  EXPECT_FALSE(status.busy);
  EXPECT_FALSE(status.has_error());
  EXPECT_TRUE(status.read_size_8);
  auto data =
      exchange(segment, Command::fprd, fp(0x1002, reg::kSiiData), std::vector<std::uint8_t>(8));
  EXPECT_EQ(wire::load_le32(data.data.data()), 0x102u);
  EXPECT_EQ(wire::load_le32(&data.data[4]), 1u);  // revision
}

// The command bits read back only while the EEPROM works: FPWR 0x0502 = 0x0100 is followed by
// polls reading 0x8140 (busy, read) and then 0x0040, in every replay capture; bit 7 (two address
// bytes) stays 0 with the 2 KiB EEPROMs of all captured slaves.
TEST(SiiControl, CommandBitsClearWhenTheCommandCompletes) {
  Segment segment;
  EscHardware hw;
  hw.sii_busy_ns = 700'000;  // the EK1100's EEPROM takes 676..711 us for an 8-byte read
  ASSERT_TRUE(
      segment.add_slave("s", std::make_unique<Esc>(hw, test_eeprom(1, false), nullptr)).ok());
  const auto ap = wire::physical_address(0, reg::kSiiControl);
  EXPECT_EQ(wire::load_le16(exchange(segment, Command::aprd, ap, {0, 0}, 900'000).data.data()),
            0x0040);
  exchange(segment, Command::apwr, ap, {0x00, 0x01, 0x08, 0x00, 0x00, 0x00}, 1'000'000);
  EXPECT_EQ(wire::load_le16(exchange(segment, Command::aprd, ap, {0, 0}, 1'300'000).data.data()),
            0x8140);
  EXPECT_EQ(wire::load_le16(exchange(segment, Command::aprd, ap, {0, 0}, 1'800'000).data.data()),
            0x0040);
  auto data = exchange(segment, Command::aprd, wire::physical_address(0, reg::kSiiData),
                       std::vector<std::uint8_t>(8), 1'900'000);
  EXPECT_EQ(wire::load_le32(data.data.data()), 0x0000'0ACEu) << "word 8: vendor ID";
  // Without a busy time the command is done at once.
  Segment quick;
  ASSERT_TRUE(quick.add_slave("s", make_esc(1)).ok());
  exchange(quick, Command::apwr, ap, {0x00, 0x01, 0x08, 0x00, 0x00, 0x00});
  EXPECT_EQ(wire::load_le16(exchange(quick, Command::aprd, ap, {0, 0}).data.data()), 0x0040);
}

// The ESC keeps its SII status apart from the register (Esc::advance does not read 0x0502 per
// frame): a PDI write over the register is noticed all the same, marks the ESC as having work
// due, and the next frame's advance stores the ESC's own status back, as it did when advance
// compared the register.
TEST(SiiControl, PdiWriteOverTheStatusIsRestoredAtTheNextFrame) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  Esc& esc = segment.esc(0);
  const auto ap = wire::physical_address(0, reg::kSiiControl);
  EXPECT_EQ(wire::load_le16(exchange(segment, Command::aprd, ap, {0, 0}).data.data()), 0x0040);
  EXPECT_FALSE(esc.advance_due(esc.now_ns()));
  esc.pdi_write_u16(reg::kSiiControl, 0xFFFF);
  EXPECT_TRUE(esc.advance_due(esc.now_ns()));
  EXPECT_EQ(wire::load_le16(exchange(segment, Command::aprd, ap, {0, 0}).data.data()), 0x0040);
  EXPECT_FALSE(esc.advance_due(esc.now_ns()));
  const std::array<std::uint8_t, 4> bytes{0x00, 0x00, 0x12, 0x34};  // 0x0500..0x0503
  esc.pdi_write(reg::kSiiAccess, bytes);
  EXPECT_TRUE(esc.advance_due(esc.now_ns()));
  esc.advance(esc.now_ns());
  EXPECT_EQ(esc.read_u16(reg::kSiiControl), 0x0040);
  // A PDI write elsewhere leaves the SII alone.
  esc.pdi_write_u16(reg::kAlStatusCode, 0);
  EXPECT_FALSE(esc.advance_due(esc.now_ns()));
}

// The FMMUs the hardware has, and no more, are visible.
TEST(FmmuConfiguration, CountFollowsTheHardware) {
  EscHardware hw;
  hw.fmmu_count = 3;
  Esc esc(hw, test_eeprom(1, false), nullptr);
  EXPECT_EQ(esc.fmmu_count(), 3u);
  EXPECT_NO_THROW((void)esc.fmmu(2));
  EXPECT_THROW((void)esc.fmmu(3), std::out_of_range);
  EXPECT_EQ(esc.read_u8(reg::kFmmuCount), 3);
}

TEST_F(ThreeSlaves, SiiInvalidCommandAndMissingWriteEnableSetErrors) {
  exchange(segment, Command::fpwr, fp(0x1000, reg::kSiiControl), le16(0x0300));
  EXPECT_TRUE(
      wire::SiiControlStatus::decode(segment.esc(0).read_u16(reg::kSiiControl)).acknowledge_error);
  exchange(segment, Command::fpwr, fp(0x1000, reg::kSiiControl), le16(0x0000));  // clears
  EXPECT_FALSE(
      wire::SiiControlStatus::decode(segment.esc(0).read_u16(reg::kSiiControl)).has_error());
  exchange(segment, Command::fpwr, fp(0x1000, reg::kSiiControl), le16(0x0200));
  EXPECT_TRUE(
      wire::SiiControlStatus::decode(segment.esc(0).read_u16(reg::kSiiControl)).write_enable_error);
}

TEST(SiiBusy, BusyBitHoldsUntilTheConfiguredTimePasses) {
  Segment segment;
  EscHardware hw;
  hw.sii_busy_ns = 50'000;
  ASSERT_TRUE(
      segment.add_slave("s", std::make_unique<Esc>(hw, test_eeprom(1, false), nullptr)).ok());
  exchange(segment, Command::apwr, wire::physical_address(0, reg::kSiiControl), le16(0x0100),
           1'000'000);
  auto busy = exchange(segment, Command::aprd, wire::physical_address(0, reg::kSiiControl), {0, 0},
                       1'010'000);
  EXPECT_TRUE(wire::SiiControlStatus::decode(wire::load_le16(busy.data.data())).busy);
  auto done = exchange(segment, Command::aprd, wire::physical_address(0, reg::kSiiControl), {0, 0},
                       1'060'000);
  EXPECT_FALSE(wire::SiiControlStatus::decode(wire::load_le16(done.data.data())).busy);
}

// Answers every mailbox request by echoing it back through SM1.
class EchoMailbox : public BasicApplication {
 public:
  void on_buffer_written(Esc& esc, std::size_t sm) override {
    if (sm != 0) return;
    auto request = esc.pdi_mailbox_received(0);
    if (!request) return;
    std::vector<std::uint8_t> copy(request->begin(), request->end());
    esc.pdi_mailbox_release(0);
    replies += esc.pdi_mailbox_send(1, copy) ? 1 : 0;
  }
  int replies = 0;
};

std::vector<std::uint8_t> sm_config(std::uint16_t start, std::uint16_t length,
                                    wire::SmControl control, bool enable) {
  wire::SyncManagerConfig c;
  c.physical_start = start;
  c.length = length;
  c.control = control;
  c.activate.enable = enable;
  auto bytes = c.encode();
  return {bytes.begin(), bytes.end()};
}

TEST(SyncManagerMailbox, WriteBlocksWhenFullAndReadFailsWhenEmpty) {
  Segment segment;
  auto app = std::make_unique<BasicApplication>();
  ASSERT_TRUE(segment.add_slave("mbx", make_esc(1, true, std::move(app))).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  ASSERT_EQ(exchange(segment, Command::apwr, ap(reg::sync_manager(0)),
                     sm_config(0x1000, 128, wire::kMailboxOutControl, true))
                .wkc,
            1);
  ASSERT_EQ(exchange(segment, Command::apwr, ap(reg::sync_manager(1)),
                     sm_config(0x1080, 128, wire::kMailboxInControl, true))
                .wkc,
            1);
  // Reading the empty slave->master mailbox fails: WKC 0, data untouched.
  auto empty = exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128, 0xAB));
  EXPECT_EQ(empty.wkc, 0);
  EXPECT_EQ(empty.data[0], 0xAB);

  std::vector<std::uint8_t> request(128, 0x11);
  EXPECT_EQ(exchange(segment, Command::aprd, ap(0x1000), std::vector<std::uint8_t>(128)).wkc, 0)
      << "the master cannot read its own write mailbox";
  EXPECT_EQ(exchange(segment, Command::apwr, ap(0x1000), request).wkc, 1);
  EXPECT_TRUE(segment.esc(0).sync_manager(0).mailbox_full);
  auto sm_status = exchange(segment, Command::aprd, ap(reg::sync_manager(0) + 5), {0});
  EXPECT_EQ(sm_status.data[0] & 0x08, 0x08);
  // Full: a second write is refused.
  EXPECT_EQ(exchange(segment, Command::apwr, ap(0x1000), request).wkc, 0);

  // The firmware takes the request; the master may write again. The status shows the read event
  // (0x02) until then, as SM0 of the EL3004 in replay-ek1914-el3004-mailbox.pcapng does.
  segment.esc(0).pdi_mailbox_release(0);
  EXPECT_EQ(exchange(segment, Command::aprd, ap(reg::sync_manager(0) + 5), {0}).data[0], 0x02);
  EXPECT_EQ(exchange(segment, Command::apwr, ap(0x1000), request).wkc, 1);
  EXPECT_EQ(exchange(segment, Command::aprd, ap(reg::sync_manager(0) + 5), {0}).data[0], 0x09);
}

// Real slaves answer a master's SDO request with mailbox address 0: the EK1914 and EL3004 of
// replay-ek1914-*.pcapng reply "0a 00 00 00 ..." from stations 0x1000 and 0x1001.
TEST(SyncManagerMailbox, SdoRepliesCarryMailboxAddressZero) {
  StandardConfig config;
  config.sii.identity = {0x0ACE, 1, 1, 1};
  config.sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  config.sii.mailbox_protocols = wire::mailbox_protocol::kCoe;
  config.dictionary.add(make_var(
      0x2000, "Value",
      make_entry_of(0, "Value", DataType::unsigned16, kAccessRead, std::uint16_t{0x1234})));
  auto eeprom = wire::encode_sii(config.sii);
  ASSERT_TRUE(eeprom.ok());
  Segment segment;
  ASSERT_TRUE(segment
                  .add_slave("s", std::make_unique<Esc>(
                                      EscHardware{}, *eeprom,
                                      std::make_unique<StandardApplication>(std::move(config))))
                  .ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  exchange(segment, Command::apwr, ap(reg::kStationAddress), le16(0x1001));
  exchange(segment, Command::apwr, ap(reg::sync_manager(0)),
           sm_config(0x1000, 128, wire::kMailboxOutControl, true));
  exchange(segment, Command::apwr, ap(reg::sync_manager(1)),
           sm_config(0x1080, 128, wire::kMailboxInControl, true));
  exchange(segment, Command::apwr, ap(reg::kAlControl), le16(0x0002));
  ASSERT_EQ(segment.esc(0).al_state(), wire::AlState::preop);
  auto sdo = wire::encode_sdo(wire::SdoInitiateUploadRequest{0x2000, 0, false});
  ASSERT_TRUE(sdo.ok());
  std::vector<std::uint8_t> request(128);
  wire::MailboxHeader header;
  header.counter = 1;
  ASSERT_TRUE(wire::encode_mailbox(header, *sdo, request).ok());
  ASSERT_EQ(exchange(segment, Command::apwr, ap(0x1000), request).wkc, 1);
  auto reply = exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128));
  ASSERT_EQ(reply.wkc, 1);
  auto box = wire::decode_mailbox(reply.data);
  ASSERT_TRUE(box.ok());
  EXPECT_EQ(box->header.address, 0);
  EXPECT_EQ(box->header.type, wire::MailboxType::coe);
}

TEST(SyncManagerMailbox, ReplyIsReadOnceThenTheMailboxIsEmpty) {
  Segment segment;
  auto app = std::make_unique<EchoMailbox>();
  auto* echo = app.get();
  ASSERT_TRUE(segment.add_slave("mbx", make_esc(1, true, std::move(app))).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  exchange(segment, Command::apwr, ap(reg::sync_manager(0)),
           sm_config(0x1000, 128, wire::kMailboxOutControl, true));
  exchange(segment, Command::apwr, ap(reg::sync_manager(1)),
           sm_config(0x1080, 128, wire::kMailboxInControl, true));
  std::vector<std::uint8_t> request(128);
  for (std::size_t i = 0; i < request.size(); ++i)
    request[i] = static_cast<std::uint8_t>(i);
  ASSERT_EQ(exchange(segment, Command::apwr, ap(0x1000), request).wkc, 1);
  EXPECT_EQ(echo->replies, 1);
  auto reply = exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128));
  EXPECT_EQ(reply.wkc, 1);
  EXPECT_EQ(reply.data, request);
  EXPECT_EQ(exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128)).wkc, 0);

  // Repeat request: the last reply comes back.
  exchange(segment, Command::apwr, ap(reg::sync_manager(1) + 6), {0x03});
  EXPECT_EQ(segment.esc(0).sync_manager(1).config.pdi_control.repeat_ack, false)
      << "the BasicApplication does not implement repeat";
  segment.esc(0).pdi_mailbox_repeat(1);
  auto again = exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128));
  EXPECT_EQ(again.wkc, 1);
  EXPECT_EQ(again.data, request);
  EXPECT_TRUE(segment.esc(0).sync_manager(1).config.pdi_control.repeat_ack);

  // A shorter reply overwrites only its own bytes: the rest of the buffer still holds the tail
  // of the earlier one, as real ESC RAM does (replay-ek1914-el3004-mailbox.pcapng).
  const std::vector<std::uint8_t> short_reply{0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7};
  ASSERT_TRUE(segment.esc(0).pdi_mailbox_send(1, short_reply));
  auto tail = exchange(segment, Command::aprd, ap(0x1080), std::vector<std::uint8_t>(128));
  ASSERT_EQ(tail.wkc, 1);
  std::vector<std::uint8_t> expected = request;
  std::copy(short_reply.begin(), short_reply.end(), expected.begin());
  EXPECT_EQ(tail.data, expected);
}

TEST(SyncManagerConfiguration, StartAndLengthOnlyChangeWhileDisabled) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1100, 4, wire::kOutputsControl, true));
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1200, 8, wire::kOutputsControl, true));
  EXPECT_EQ(segment.esc(0).sync_manager(2).config.physical_start, 0x1100);
  EXPECT_EQ(segment.esc(0).sync_manager(2).config.length, 4);
  exchange(segment, Command::apwr, ap(reg::sync_manager(2) + 6), {0});
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1200, 8, wire::kOutputsControl, true));
  EXPECT_EQ(segment.esc(0).sync_manager(2).config.physical_start, 0x1200);
  EXPECT_TRUE(segment.esc(0).sync_manager(2).enabled);
}

// Physical accesses look up the enabled SyncManagers' areas in a table the ESC rebuilds when one
// is enabled, disabled or moved, and take RAM outside every area directly: the table must follow
// each change, and a power cycle.
TEST(SyncManagerConfiguration, AccessesFollowEnableMoveDisableAndPowerCycle) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  auto& esc = segment.esc(0);
  const auto plain_write_lands = [&](std::uint16_t at, std::uint8_t value) {
    const auto r = exchange(segment, Command::apwr, ap(at), {value, value});
    return r.wkc == 1 && esc.read_u16(at) == static_cast<std::uint16_t>(value * 0x0101);
  };
  EXPECT_TRUE(plain_write_lands(0x1100, 0x11));
  // An output SM over 0x1100..0x1103: half a buffer is no longer visible.
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1100, 4, wire::kOutputsControl, true));
  EXPECT_FALSE(plain_write_lands(0x1100, 0x22));
  EXPECT_EQ(esc.read_u16(0x1100), 0x1111);
  // A read that overlaps the area's end only: the bytes before it are plain RAM.
  esc.pdi_write(0x10FE, std::vector<std::uint8_t>{0xAB, 0xCD});
  EXPECT_EQ(exchange(segment, Command::aprd, ap(0x10FE), {0, 0}).data,
            (std::vector<std::uint8_t>{0xAB, 0xCD}));
  // Disabled: plain RAM again.
  exchange(segment, Command::apwr, ap(reg::sync_manager(2) + reg::kSyncManagerActivateOffset), {0});
  EXPECT_TRUE(plain_write_lands(0x1100, 0x33));
  // Moved to 0x1200 and enabled: 0x1100 plain, 0x1200 buffered.
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1200, 4, wire::kOutputsControl, true));
  EXPECT_TRUE(plain_write_lands(0x1100, 0x44));
  EXPECT_FALSE(plain_write_lands(0x1200, 0x55));
  // An input SM refuses writes from ECAT; a power cycle disables every SM.
  exchange(segment, Command::apwr, ap(reg::sync_manager(3)),
           sm_config(0x1180, 2, wire::kInputsControl, true));
  EXPECT_EQ(exchange(segment, Command::apwr, ap(0x1180), {1, 2}).wkc, 0);
  esc.power_cycle(2'000'000);
  EXPECT_TRUE(plain_write_lands(0x1180, 0x66));
  EXPECT_TRUE(plain_write_lands(0x1200, 0x77));
}

TEST(SyncManagerBuffered, OutputsBecomeVisibleOnlyWhenTheLastByteIsWritten) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1100, 4, wire::kOutputsControl, true));
  auto& esc = segment.esc(0);
  exchange(segment, Command::apwr, ap(0x1100), {1, 2});
  EXPECT_EQ(esc.read_u32(0x1100), 0u) << "half a buffer is not a buffer";
  exchange(segment, Command::apwr, ap(0x1100), {1, 2, 3, 4});
  EXPECT_EQ(esc.read_u32(0x1100), 0x04030201u);
  EXPECT_EQ(esc.sync_manager(2).buffers_written, 1u);
  // Writes to an input (ECAT-read) SyncManager are refused.
  exchange(segment, Command::apwr, ap(reg::sync_manager(3)),
           sm_config(0x1180, 2, wire::kInputsControl, true));
  esc.pdi_write_buffer(3, std::vector<std::uint8_t>{0xAA, 0xBB});
  EXPECT_EQ(exchange(segment, Command::apwr, ap(0x1180), {0, 0}).wkc, 0);
  auto in = exchange(segment, Command::aprd, ap(0x1180), {0, 0});
  EXPECT_EQ(in.wkc, 1);
  EXPECT_EQ(in.data, (std::vector<std::uint8_t>{0xAA, 0xBB}));
}

std::vector<std::uint8_t> fmmu_config(std::uint32_t logical, std::uint16_t length,
                                      std::uint8_t start_bit, std::uint8_t stop_bit,
                                      std::uint16_t physical, std::uint8_t physical_bit,
                                      wire::FmmuType type) {
  wire::FmmuConfig f;
  f.logical_start = logical;
  f.length = length;
  f.logical_start_bit = start_bit;
  f.logical_stop_bit = stop_bit;
  f.physical_start = physical;
  f.physical_start_bit = physical_bit;
  f.type = type;
  f.active = true;
  auto bytes = f.encode();
  return {bytes.begin(), bytes.end()};
}

TEST_F(ThreeSlaves, LogicalReadWriteMapsSingleBitsAndCountsPerSlave) {
  // Slave 0: output bit at logical 0x10000 bit 2 -> physical 0x1100 bit 0.
  // Slave 1: input bits at logical 0x10000 bits 4..5 <- physical 0x1180 bits 1..2.
  // Slave 2: output byte at logical 0x10001 -> physical 0x1100, input byte at 0x10002.
  exchange(segment, Command::fpwr, fp(0x1000, reg::fmmu(0)),
           fmmu_config(0x10000, 1, 2, 2, 0x1100, 0, wire::FmmuType::write));
  exchange(segment, Command::fpwr, fp(0x1001, reg::fmmu(0)),
           fmmu_config(0x10000, 1, 4, 5, 0x1180, 1, wire::FmmuType::read));
  exchange(segment, Command::fpwr, fp(0x1002, reg::fmmu(0)),
           fmmu_config(0x10001, 1, 0, 7, 0x1100, 0, wire::FmmuType::write));
  exchange(segment, Command::fpwr, fp(0x1002, reg::fmmu(1)),
           fmmu_config(0x10002, 1, 0, 7, 0x1180, 0, wire::FmmuType::read));
  segment.esc(1).pdi_write(0x1180, std::vector<std::uint8_t>{0b0000'0110});  // bits 1, 2 set
  segment.esc(2).pdi_write(0x1180, std::vector<std::uint8_t>{0x5A});

  auto r = exchange(segment, Command::lrw, 0x10000, {0b0000'0100, 0xC3, 0x00});
  // Slave 0 wrote (+2), slave 1 read (+1), slave 2 read and wrote (+3).
  EXPECT_EQ(r.wkc, 6);
  EXPECT_EQ(segment.esc(0).read_u8(0x1100), 0x01);
  EXPECT_EQ(segment.esc(2).read_u8(0x1100), 0xC3);
  EXPECT_EQ(r.data[0], 0b0011'0100) << "input bits 4, 5 merged with the output bit 2";
  EXPECT_EQ(r.data[2], 0x5A);

  // A bit write leaves the neighbouring physical bits alone.
  segment.esc(0).pdi_write(0x1100, std::vector<std::uint8_t>{0xF0});
  exchange(segment, Command::lwr, 0x10000, {0x00});
  EXPECT_EQ(segment.esc(0).read_u8(0x1100), 0xF0);
  EXPECT_EQ(exchange(segment, Command::lrd, 0x10000, {0}).wkc, 1);
  EXPECT_EQ(exchange(segment, Command::lwr, 0x20000, {0}).wkc, 0);
}

TEST(Topology, BranchesAreVisitedInForwardingOrder) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("coupler", make_esc(1)).ok());
  ASSERT_TRUE(segment.add_slave("a", make_esc(2)).ok());                    // coupler port 1
  ASSERT_TRUE(segment.add_slave("b", make_esc(3), Attachment{0, 3}).ok());  // coupler port 3
  ASSERT_TRUE(segment.add_slave("c", make_esc(4), Attachment{2, 1}).ok());  // behind b
  EXPECT_EQ(segment.processing_order(), (std::vector<std::size_t>{0, 2, 3, 1}));
  EXPECT_FALSE(segment.add_slave("d", make_esc(5), Attachment{0, 3}).ok());
  EXPECT_FALSE(segment.add_slave("e", make_esc(6), Attachment{9, 1}).ok());

  // Auto-increment position follows the processing order.
  auto r = exchange(segment, Command::aprd,
                    wire::physical_address(wire::position_adp(1), reg::kType), {0});
  EXPECT_EQ(r.wkc, 1);
  exchange(segment, Command::apwr,
           wire::physical_address(wire::position_adp(1), reg::kStationAddress), le16(0x77));
  EXPECT_EQ(segment.esc(2).station_address(), 0x77);

  auto dl = wire::DlStatus::decode(segment.esc(0).read_u16(reg::kDlStatus));
  EXPECT_TRUE(dl.ports[0].physical_link);
  EXPECT_TRUE(dl.ports[1].physical_link);
  EXPECT_FALSE(dl.ports[2].physical_link);
  EXPECT_TRUE(dl.ports[2].loop_closed);
  EXPECT_TRUE(dl.ports[3].communication);
}

TEST(Topology, LinkDownCutsOffTheRestAndClosesTheLoop) {
  Segment segment;
  for (int i = 0; i < 4; ++i)
    ASSERT_TRUE(segment.add_slave("s" + std::to_string(i), make_esc(1)).ok());
  EXPECT_EQ(exchange(segment, Command::brd, 0, {0}).wkc, 4);
  segment.set_link(2, 0, false);
  EXPECT_EQ(exchange(segment, Command::brd, 0, {0}).wkc, 2);
  auto dl = wire::DlStatus::decode(segment.esc(1).read_u16(reg::kDlStatus));
  EXPECT_FALSE(dl.ports[1].physical_link);
  EXPECT_TRUE(dl.ports[1].loop_closed);
  segment.set_link(2, 0, true);
  EXPECT_EQ(exchange(segment, Command::brd, 0, {0}).wkc, 4);
  // A port closed by the master through DL control (0x0101, port 1 = bits 2..3 = 0b11).
  exchange(segment, Command::apwr, wire::physical_address(0, reg::kDlPortControl), {0x0C});
  EXPECT_EQ(exchange(segment, Command::brd, 0, {0}).wkc, 1);
  segment.set_master_link(false);
  EXPECT_FALSE(exchange(segment, Command::brd, 0, {0}).returned);
}

// Loop control "auto close" (0x0101 bits 01): a port shut at link down stays shut when the link
// comes back (DL status: link up, loop closed) until the master writes 01 again; written while
// the port has no link it closes it too. Auto (00) opens with the link.
TEST(Topology, AutoCloseKeepsAPortClosedAfterLinkDownUntilTheMasterOpensIt) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("junction", make_esc(1)).ok());
  ASSERT_TRUE(segment.add_slave("group", make_esc(2), Attachment{0, 1}).ok());  // on port 1
  ASSERT_TRUE(segment.add_slave("far", make_esc(3), Attachment{0, 2}).ok());    // on port 2
  const auto port_control = [&](std::uint8_t value) {
    return exchange(segment, Command::apwr, wire::physical_address(0, reg::kDlPortControl),
                    {value});
  };
  const auto dl = [&] {
    exchange(segment, Command::brd, 0, {0});  // a frame: the route is planned again
    return wire::DlStatus::decode(segment.esc(0).read_u16(reg::kDlStatus));
  };
  const auto count = [&] { return exchange(segment, Command::brd, 0, {0}).wkc; };
  ASSERT_EQ(count(), 3);
  ASSERT_EQ(port_control(0x04).wkc, 1);  // port 1: auto close, with link: stays open
  EXPECT_EQ(count(), 3);
  EXPECT_FALSE(dl().ports[1].loop_closed);

  // Link down: closed; link up again: still closed, the group behind it unseen.
  segment.set_link(1, 0, false);
  EXPECT_EQ(count(), 2);
  segment.set_link(1, 0, true);
  EXPECT_EQ(count(), 2);
  auto status = dl();
  EXPECT_TRUE(status.ports[1].physical_link);
  EXPECT_TRUE(status.ports[1].loop_closed);
  EXPECT_FALSE(status.ports[2].loop_closed);
  // The frame's route: the far slave right after the junction (auto-increment position 1).
  auto far = exchange(segment, Command::aprd,
                      wire::physical_address(wire::position_adp(1), reg::kType), {0});
  EXPECT_EQ(far.wkc, 1);

  // The same value written again opens it: the group is in the ring, in front of `far`.
  ASSERT_EQ(port_control(0x04).wkc, 1);
  EXPECT_EQ(count(), 3);
  status = dl();
  EXPECT_TRUE(status.ports[1].physical_link);
  EXPECT_FALSE(status.ports[1].loop_closed);
  EXPECT_EQ(segment.processing_order(), (std::vector<std::size_t>{0, 1, 2}));

  // 01 written while the port has no link closes it: the link coming back leaves it closed.
  segment.set_link(1, 0, false);
  ASSERT_EQ(port_control(0x04).wkc, 1);
  segment.set_link(1, 0, true);
  EXPECT_EQ(count(), 2);
  // Auto (00) opens with the link; auto close written then keeps it open.
  ASSERT_EQ(port_control(0x00).wkc, 1);
  EXPECT_EQ(count(), 3);
  ASSERT_EQ(port_control(0x04).wkc, 1);
  EXPECT_EQ(count(), 3);
  EXPECT_FALSE(dl().ports[1].loop_closed);
  // Forced closed (11) and forced open (10) ignore the latch.
  segment.set_link(1, 0, false);
  segment.set_link(1, 0, true);
  ASSERT_EQ(port_control(0x08).wkc, 1);
  EXPECT_EQ(count(), 3);
  ASSERT_EQ(port_control(0x0C).wkc, 1);
  EXPECT_EQ(count(), 2);
}

// A frame through a port opened by the master takes the longer way: the slaves behind it latch
// their receive times later by the group's round trip.
TEST(Topology, OpeningAnAutoClosedPortDelaysTheSlavesBehindIt) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("junction", make_esc(1)).ok());
  ASSERT_TRUE(segment.add_slave("group", make_esc(2), Attachment{0, 1, 500}).ok());
  ASSERT_TRUE(segment.add_slave("far", make_esc(3), Attachment{0, 2}).ok());
  exchange(segment, Command::apwr, wire::physical_address(0, reg::kDlPortControl), {0x04});
  segment.set_link(1, 0, false);
  segment.set_link(1, 0, true);
  const auto far_arrival = [&] {
    exchange(segment, Command::bwr, wire::physical_address(0, reg::kDcReceiveTimePort0),
             {0, 0, 0, 0}, 1'000'000);
    return segment.esc(2).read_u32(reg::dc_receive_time(0));
  };
  const auto closed = far_arrival();
  exchange(segment, Command::apwr, wire::physical_address(0, reg::kDlPortControl), {0x04});
  const auto open = far_arrival();
  // Two 500 ns cables, the group's processing (100) and turnaround (50), the junction's
  // forwarding from port 1 (50).
  EXPECT_EQ(open - closed, 2 * 500u + 100u + 50u + 50u);
}

TEST(DistributedClocks, ReceiveTimesFollowTheTopology) {
  Segment segment;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(segment
                    .add_slave("s" + std::to_string(i), make_esc(1),
                               Attachment{std::nullopt, 1, 20}, HopTiming{100, 50})
                    .ok());
  }
  const std::int64_t t0 = 5'000'000;
  exchange(segment, Command::bwr, wire::physical_address(0, reg::kDcReceiveTimePort0), {0, 0, 0, 0},
           t0);
  auto& first = segment.esc(0);
  auto& last = segment.esc(2);
  const std::uint32_t p0 = first.read_u32(reg::dc_receive_time(0));
  const std::uint32_t p1 = first.read_u32(reg::dc_receive_time(1));
  // Behind slave 0's port 1: its own processing (100), four cable hops (4 x 20), slave 1 and
  // slave 2 processing (2 x 100), slave 2 turning round (50), slave 1 forwarding back from its
  // port 1 and out of port 0 (2 x 50).
  EXPECT_EQ(p0, static_cast<std::uint32_t>(t0 + 20));
  EXPECT_EQ(p1 - p0, 100u + 4 * 20u + 2 * 100u + 50u + 2 * 50u);
  EXPECT_EQ(last.read_u32(reg::dc_receive_time(1)), 0u) << "port 1 of the last slave saw nothing";
  EXPECT_EQ(last.read_u32(reg::dc_receive_time(0)), static_cast<std::uint32_t>(t0 + 20 + 2 * 120));
}

TEST(DistributedClocks, SystemTimeFollowsLocalClockAndOffset) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  segment.esc(0).dc()->set_clock({100.0, 1'000});
  exchange(segment, Command::apwr, wire::physical_address(0, reg::kDcSystemTimeOffset),
           {0x00, 0xCA, 0x9A, 0x3B, 0, 0, 0, 0});  // +1 s
  auto r = exchange(segment, Command::aprd, wire::physical_address(0, reg::kDcSystemTime),
                    std::vector<std::uint8_t>(8), 10'000'000);
  // An ECAT read latches the system time at the start of the frame (ESC register description,
  // System Time 0x0910): when the frame reaches port 0 at 10 ms + 5 ns cable.
  // local = 1000 + 10'000'005 * (1 + 100 ppm) = 1000 + 10'001'005
  EXPECT_EQ(wire::load_le64(r.data.data()), 1'000'000'000ull + 1'000 + 10'001'005);
}

TEST(Watchdog, ExpiresWithoutOutputsAndRetriggersOnWrite) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  const auto ap = [](std::uint16_t offset) { return wire::physical_address(0, offset); };
  exchange(segment, Command::apwr, ap(reg::sync_manager(2)),
           sm_config(0x1100, 2, wire::kOutputsControl, true), 0);
  exchange(segment, Command::apwr, ap(0x1100), {1, 2}, 1'000'000);
  segment.advance(50'000'000);
  EXPECT_EQ(segment.esc(0).read_u16(reg::kWatchdogStatus) & 1, 1);
  segment.advance(102'000'000);  // 100 ms default watchdog
  EXPECT_EQ(segment.esc(0).read_u16(reg::kWatchdogStatus) & 1, 0);
  EXPECT_EQ(segment.esc(0).read_u8(reg::kWatchdogCounterProcessData), 1);
  exchange(segment, Command::apwr, ap(0x1100), {1, 2}, 103'000'000);
  EXPECT_EQ(segment.esc(0).read_u16(reg::kWatchdogStatus) & 1, 1);
}

TEST(Segment, MalformedFramesAreIgnoredAndCounted) {
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", make_esc(1)).ok());
  std::vector<std::uint8_t> junk{0x05, 0x10, 0x01};
  EXPECT_FALSE(segment.process_frame(junk, 0));
  EXPECT_EQ(segment.stats().frames_malformed, 1u);
}

// Without slaves the master's frames go nowhere: soem-sdinfo-no-slaves.pcapng records only the
// master's own frames, never a reply.
TEST(Segment, EmptySegmentAnswersNothing) {
  Segment segment;
  auto r = exchange(segment, Command::brd, 0, {0});
  EXPECT_FALSE(r.returned);
  EXPECT_EQ(segment.stats().frames_lost, 1u);
}

}  // namespace
}  // namespace ecat::sim
