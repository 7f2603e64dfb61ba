// The emulated ESC's SII EEPROM interface bit for bit: 0x0502 read back after every step, like a
// logic-analyser trace of a real ESC (ESC datasheets, section II, 0x0500..0x050F; the capture
// facts are cited in src/sim/esc.cpp).
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/sim/esc.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::sim {
namespace {

using wire::Command;
namespace reg = wire::reg;
namespace sc = wire::sii_control;

std::vector<std::uint8_t> eeprom_image(std::uint16_t alias = 0) {
  wire::SiiImage image;
  image.pdi_control = 0x0C05;
  image.station_alias = alias;
  image.identity = {0x0000'0ACE, 0x42, 1, 7};
  image.strings = {"SiiTest"};
  auto bytes = wire::encode_sii(image);
  EXPECT_TRUE(bytes.ok());
  bytes->resize(2048, 0xFF);
  return *bytes;
}

struct Datagram {
  Command command = Command::nop;
  std::uint16_t offset = 0;
  std::vector<std::uint8_t> data;
};

struct Reply {
  std::vector<std::uint8_t> data;
  std::uint16_t wkc = 0;
};

// One frame with `datagrams` to position 0 at segment time `now_ns`.
std::vector<Reply> frame(Segment& segment, const std::vector<Datagram>& datagrams,
                         std::int64_t now_ns) {
  std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
  wire::FrameBuilder builder(buffer);
  std::uint8_t index = 0;
  for (const auto& d : datagrams) {
    wire::DatagramHeader header;
    header.command = d.command;
    header.index = index++;
    header.address = wire::physical_address(0, d.offset);
    header.length = static_cast<std::uint16_t>(d.data.size());
    EXPECT_TRUE(builder.add(header, d.data).has_value());
  }
  const auto built = builder.finish();
  std::vector<std::uint8_t> bytes(built.begin(), built.end());
  EXPECT_TRUE(segment.process_frame(bytes, now_ns));
  auto decoded = wire::decode_frame(bytes);
  EXPECT_TRUE(decoded) << decoded.error.describe();
  std::vector<Reply> out;
  for (const auto& d : *decoded.frame)
    out.push_back({std::vector<std::uint8_t>(d.data.begin(), d.data.end()), d.wkc});
  return out;
}

std::vector<std::uint8_t> le16(std::uint16_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8)};
}
std::vector<std::uint8_t> le32(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

class EscSii : public ::testing::Test {
 protected:
  void make(EscHardware hw, std::vector<std::uint8_t> eeprom) {
    ASSERT_TRUE(segment.add_slave("s", std::make_unique<Esc>(hw, std::move(eeprom), nullptr)).ok());
  }
  void SetUp() override {
    EscHardware hw;
    hw.sii_busy_ns = 100'000;          // 0.1 ms per read
    hw.sii_write_busy_ns = 3'000'000;  // 3 ms write cycle
    make(hw, eeprom_image());
  }
  Esc& esc() { return segment.esc(0); }
  // 0x0502 as a master reads it at `now`.
  std::uint16_t control(std::int64_t now) {
    return wire::load_le16(
        frame(segment, {{Command::aprd, reg::kSiiControl, {0, 0}}}, now)[0].data.data());
  }
  void write_control(std::uint16_t value, std::int64_t now) {
    frame(segment, {{Command::apwr, reg::kSiiControl, le16(value)}}, now);
  }
  // Data, address and 0x0201 in one frame, as the writer sends them.
  void write_word(std::uint32_t word, std::uint16_t value, std::int64_t now,
                  std::uint16_t command = sc::kCommandWrite | sc::kWriteEnable) {
    frame(segment,
          {{Command::apwr, reg::kSiiData, le16(value)},
           {Command::apwr, reg::kSiiAddress, le32(word)},
           {Command::apwr, reg::kSiiControl, le16(command)}},
          now);
  }
  std::uint16_t eeprom_word(std::size_t word) { return wire::load_le16(&esc().eeprom()[word * 2]); }
  Segment segment;
};

TEST_F(EscSii, WriteTraceBusyWithCommandThenIdleWithoutWriteEnable) {
  EXPECT_EQ(control(1'000'000), 0x0040) << "idle, 8-byte reads, one address byte";
  write_word(0x0040, 0xBEEF, 2'000'000);
  // While the write cycle runs: busy | write command, the write enable consumed.
  EXPECT_EQ(control(2'010'000), 0x8240);
  EXPECT_EQ(control(4'900'000), 0x8240);
  EXPECT_NE(eeprom_word(0x40), 0xBEEF) << "the word lands when the write cycle ends";
  EXPECT_EQ(control(5'000'001), 0x0040) << "busy and command clear, write enable gone";
  EXPECT_EQ(eeprom_word(0x40), 0xBEEF);
}

TEST_F(EscSii, CommandsWhileBusyAreIgnored) {
  write_word(0x0040, 0x1111, 1'000'000);
  // A second write (another word) and a read while busy change nothing.
  write_word(0x0041, 0x2222, 1'500'000);
  write_control(sc::kCommandRead, 1'600'000);
  EXPECT_EQ(control(1'700'000), 0x8240);
  EXPECT_EQ(control(4'100'000), 0x0040);
  EXPECT_EQ(eeprom_word(0x40), 0x1111);
  EXPECT_NE(eeprom_word(0x41), 0x2222);
}

TEST_F(EscSii, WriteWithoutWriteEnableSetsBit14AndNopClearsIt) {
  write_word(0x0040, 0x1234, 1'000'000, sc::kCommandWrite);
  EXPECT_EQ(control(1'010'000), 0x4040) << "write enable error, never busy";
  EXPECT_NE(eeprom_word(0x40), 0x1234);
  write_control(sc::kCommandNop, 1'100'000);
  EXPECT_EQ(control(1'110'000), 0x0040);
}

TEST_F(EscSii, WriteEnableIsSelfClearingAtTheNextFrame) {
  // Write enable alone (byte 0x0502), the write command (byte 0x0503) later in the same frame:
  // accepted.
  frame(segment,
        {{Command::apwr, reg::kSiiData, le16(0x5555)},
         {Command::apwr, reg::kSiiAddress, le32(0x40)},
         {Command::apwr, reg::kSiiControl, {0x01}},
         {Command::apwr, reg::kSiiControl + 1, {0x02}}},
        1'000'000);
  EXPECT_EQ(control(4'100'000), 0x0040);
  EXPECT_EQ(eeprom_word(0x40), 0x5555);
  // Write enable in one frame, the command in the next: the enable is gone by then.
  frame(segment, {{Command::apwr, reg::kSiiControl, {0x01}}}, 5'000'000);
  EXPECT_EQ(esc().read_u16(reg::kSiiControl), 0x0041) << "latched until the frame ends";
  frame(segment,
        {{Command::apwr, reg::kSiiData, le16(0x6666)},
         {Command::apwr, reg::kSiiAddress, le32(0x41)},
         {Command::apwr, reg::kSiiControl + 1, {0x02}}},
        5'100'000);
  EXPECT_EQ(control(5'200'000), 0x4040);
  EXPECT_NE(eeprom_word(0x41), 0x6666);
}

TEST_F(EscSii, AcknowledgeErrorBlocksCommandsUntilNop) {
  esc().inject_sii_acknowledge_errors(1);
  write_word(0x0040, 0x7777, 1'000'000);
  EXPECT_EQ(control(1'100'000), 0x8240);
  EXPECT_EQ(control(4'100'000), 0x2040) << "the EEPROM did not acknowledge";
  EXPECT_NE(eeprom_word(0x40), 0x7777);
  // Ignored while bit 13 is pending.
  write_word(0x0040, 0x7777, 4'200'000);
  EXPECT_EQ(control(4'300'000), 0x2040);
  write_control(sc::kCommandNop, 4'400'000);
  EXPECT_EQ(control(4'500'000), 0x0040);
  write_word(0x0040, 0x7777, 4'600'000);
  EXPECT_EQ(control(7'700'000), 0x0040);
  EXPECT_EQ(eeprom_word(0x40), 0x7777);
}

TEST_F(EscSii, InvalidCommandAndAddressPastTheEepromSetBit13) {
  write_control(0x0300, 1'000'000);  // bits 8 and 9: not a command the ESC knows
  EXPECT_EQ(control(1'010'000), 0x2040);
  write_control(sc::kCommandNop, 1'100'000);
  write_word(0x0400, 0x1234, 1'200'000);  // word 0x400 = byte 2048: past a 2 KiB EEPROM
  EXPECT_EQ(control(4'300'000), 0x2040);
}

TEST_F(EscSii, ReadTraceShowsBusyReadThenIdle) {
  frame(segment,
        {{Command::apwr, reg::kSiiAddress, le32(wire::sii_word::kVendorId)},
         {Command::apwr, reg::kSiiControl, le16(sc::kCommandRead)}},
        1'000'000);
  EXPECT_EQ(control(1'050'000), 0x8140);
  EXPECT_EQ(control(1'100'000), 0x0040);
  const auto data =
      frame(segment, {{Command::aprd, reg::kSiiData, std::vector<std::uint8_t>(8)}}, 1'200'000);
  EXPECT_EQ(wire::load_le32(data[0].data.data()), 0x0000'0ACEu);
}

TEST_F(EscSii, AliasLoadedAtPowerUpNotByReloadAndWritesSurvivePowerCycle) {
  EXPECT_EQ(esc().station_alias(), 0);
  // Word 4 = 0x1234 and the checksum of the new words 0..6 into word 7.
  std::vector<std::uint8_t> area(esc().eeprom().begin(), esc().eeprom().begin() + 14);
  area[8] = 0x34;
  area[9] = 0x12;
  write_word(wire::sii_word::kStationAlias, 0x1234, 1'000'000);
  write_word(wire::sii_word::kChecksum, wire::sii_crc8(area), 5'000'000);
  EXPECT_EQ(control(9'000'000), 0x0040);
  // A reload takes the configuration area again, but not the alias (ESC datasheet section I).
  write_control(sc::kCommandReload, 9'100'000);
  EXPECT_EQ(control(9'150'000), 0x8440);
  EXPECT_EQ(control(9'300'000), 0x0040);
  EXPECT_EQ(esc().station_alias(), 0);
  esc().power_cycle(20'000'000);
  EXPECT_EQ(eeprom_word(wire::sii_word::kStationAlias), 0x1234) << "the EEPROM is non-volatile";
  EXPECT_EQ(esc().station_alias(), 0x1234) << "0x0012 loaded from word 4 at power-up";
  EXPECT_EQ(esc().read_u16(reg::kSiiControl), 0x0040) << "checksum good";
}

TEST_F(EscSii, ChecksumErrorAfterPowerUpWhenWord7NoLongerMatches) {
  write_word(wire::sii_word::kStationAlias, 0x0BAD, 1'000'000);  // checksum not updated
  EXPECT_EQ(control(4'100'000), 0x0040);
  esc().power_cycle(10'000'000);
  EXPECT_EQ(esc().read_u16(reg::kSiiControl), 0x0840) << "bit 11: checksum error";
  EXPECT_EQ(esc().station_alias(), 0) << "a configuration area with a bad checksum is not loaded";
  EXPECT_EQ(esc().read_u8(reg::kDlStatus) & 0x01, 0) << "PDI not operational";
  // A NOP does not clear it; a reload after repairing word 7 does.
  write_control(sc::kCommandNop, 10'100'000);
  EXPECT_EQ(control(10'200'000), 0x0840);
  std::vector<std::uint8_t> area(esc().eeprom().begin(), esc().eeprom().begin() + 14);
  write_word(wire::sii_word::kChecksum, wire::sii_crc8(area), 10'300'000);
  EXPECT_EQ(control(13'400'000), 0x0840);
  write_control(sc::kCommandReload, 13'500'000);
  EXPECT_EQ(control(13'700'000), 0x0040);
}

TEST_F(EscSii, PdiHoldingTheEepromLocksEcatOut) {
  frame(segment, {{Command::apwr, reg::kSiiAccess, {0x01}}}, 1'000'000);  // offer to the PDI
  esc().pdi_take_eeprom(true);
  EXPECT_EQ(esc().read_u8(reg::kSiiPdiAccess), 0x01);
  write_word(0x0040, 0x4321, 1'100'000);
  EXPECT_EQ(control(1'200'000), 0x0040) << "ignored: the PDI holds the EEPROM";
  EXPECT_EQ(control(5'000'000), 0x0040);
  EXPECT_NE(eeprom_word(0x40), 0x4321);
  // Forcing ECAT access (bit 1) takes it from the PDI.
  frame(segment, {{Command::apwr, reg::kSiiAccess, {0x02}}}, 5'100'000);
  EXPECT_EQ(esc().read_u8(reg::kSiiPdiAccess), 0x00);
  frame(segment, {{Command::apwr, reg::kSiiAccess, {0x00}}}, 5'200'000);
  write_word(0x0040, 0x4321, 5'300'000);
  EXPECT_EQ(control(8'400'000), 0x0040);
  EXPECT_EQ(eeprom_word(0x40), 0x4321);
}

TEST(EscSiiHardware, AddressAlgorithmBitFollowsTheEepromSizeOrTheHardware) {
  Segment segment;
  EscHardware small;
  ASSERT_TRUE(segment.add_slave("a", std::make_unique<Esc>(small, eeprom_image(), nullptr)).ok());
  auto big_image = eeprom_image();
  big_image.resize(4096, 0xFF);
  ASSERT_TRUE(segment.add_slave("b", std::make_unique<Esc>(small, big_image, nullptr)).ok());
  EscHardware forced;
  forced.sii_two_address_bytes = false;  // a capture showed bit 7 clear
  forced.sii_reads_8_bytes = false;
  ASSERT_TRUE(segment.add_slave("c", std::make_unique<Esc>(forced, big_image, nullptr)).ok());
  EXPECT_EQ(segment.esc(0).read_u16(reg::kSiiControl), 0x0040);
  EXPECT_EQ(segment.esc(1).read_u16(reg::kSiiControl), 0x00C0);
  EXPECT_EQ(segment.esc(2).read_u16(reg::kSiiControl), 0x0000);
}

TEST(EscRegisterFacts, DatasheetDefaultsPerEscType) {
  EXPECT_EQ(esc_type_defaults(0x11).name, "ET1100");
  EXPECT_TRUE(esc_type_defaults(0x11).sii_reads_8_bytes);
  EXPECT_TRUE(esc_type_defaults(0x12).sii_reads_8_bytes);
  EXPECT_TRUE(esc_type_defaults(0x04).sii_reads_8_bytes);
  EXPECT_TRUE(esc_type_defaults(0xC0).sii_reads_8_bytes);
  EXPECT_FALSE(esc_type_defaults(0x02).sii_reads_8_bytes) << "ESC20 reads 4 bytes";
  EXPECT_EQ(esc_type_defaults(0x12).dl_control, 0x00070001u);
  EXPECT_EQ(esc_type_defaults(0x77).name, "unknown");
  // The reset value stands in 0x0100 until the master writes it, and comes back at power-up.
  Esc esc(EscHardware{}, eeprom_image(), nullptr);
  EXPECT_EQ(esc.read_u32(reg::kDlControl), 0x00070001u);
  esc.pdi_write(reg::kDlControl, std::vector<std::uint8_t>{0, 0, 0, 0});
  esc.power_cycle(0);
  EXPECT_EQ(esc.read_u32(reg::kDlControl), 0x00070001u);
}

TEST(EscRegisterFacts, EmulationBitAndEnhancedLinkDetectionFromTheHardware) {
  EscHardware hw;
  hw.sii_emulation = true;
  hw.enhanced_link_detection = true;  // the SII's word 0 says otherwise (0x0C05)
  Esc esc(hw, eeprom_image(), nullptr);
  EXPECT_EQ(esc.read_u16(reg::kSiiControl) & sc::kEmulation, sc::kEmulation);
  EXPECT_NE(esc.read_u8(reg::kDlStatus) & 0x04, 0);
  EXPECT_NE(esc.read_u8(reg::kEscConfiguration) & 0x02, 0);
  hw.enhanced_link_detection = false;
  Esc off(hw, eeprom_image(), nullptr);
  EXPECT_EQ(off.read_u8(reg::kDlStatus) & 0x04, 0);
}

// A device that refuses a state (EscHardware::al_refusals, from a capture) keeps refusing after
// a power cycle; an injected refusal lifted again leaves the device's own.
TEST(EscRegisterFacts, HardwareRefusalsSurvivePowerCyclesAndLiftedFaults) {
  EscHardware hw;
  hw.al_refusals = {{wire::AlState::preop, 0x0016}};
  Segment segment;
  ASSERT_TRUE(segment.add_slave("s", std::make_unique<Esc>(hw, eeprom_image(), nullptr)).ok());
  Esc& esc = segment.esc(0);
  auto request = [&](std::uint16_t control) {
    std::vector<std::uint8_t> data{static_cast<std::uint8_t>(control), 0};
    frame(segment, {{Command::apwr, reg::kAlControl, data}}, 0);
  };
  request(0x0002);
  EXPECT_EQ(esc.al_state(), wire::AlState::init);
  EXPECT_TRUE(esc.al_error());
  EXPECT_EQ(esc.al_status_code(), 0x0016);
  esc.set_al_refusal(wire::AlState::preop, 0x0011);
  EXPECT_EQ(esc.al_refusal(wire::AlState::preop), std::optional<std::uint16_t>(0x0011));
  esc.set_al_refusal(wire::AlState::preop, std::nullopt);
  EXPECT_EQ(esc.al_refusal(wire::AlState::preop), std::optional<std::uint16_t>(0x0016));
  esc.power_cycle(0);
  EXPECT_EQ(esc.al_refusal(wire::AlState::preop), std::optional<std::uint16_t>(0x0016));
  request(0x0012);
  EXPECT_EQ(esc.al_state(), wire::AlState::init);
  EXPECT_EQ(esc.al_status_code(), 0x0016);
}

TEST(EscSiiHardware, MissingEepromReportsDeviceInformationError) {
  Segment segment;
  ASSERT_TRUE(segment
                  .add_slave("s", std::make_unique<Esc>(EscHardware{}, std::vector<std::uint8_t>{},
                                                        nullptr))
                  .ok());
  EXPECT_EQ(segment.esc(0).read_u16(reg::kSiiControl), 0x1840);
}

TEST(EscSiiHardware, EnhancedLinkDetectionFromEscConfigurationShowsInDlStatus) {
  wire::SiiImage image;
  image.pdi_control = 0x0205;  // 0x0141 bit 1: enhanced link detection
  auto bytes = wire::encode_sii(image);
  ASSERT_TRUE(bytes.ok());
  Esc esc(EscHardware{}, *bytes, nullptr);
  EXPECT_NE(esc.read_u8(reg::kDlStatus) & 0x04, 0);
  wire::SiiImage plain;
  plain.pdi_control = 0x0C05;
  auto plain_bytes = wire::encode_sii(plain);
  ASSERT_TRUE(plain_bytes.ok());
  Esc other(EscHardware{}, *plain_bytes, nullptr);
  EXPECT_EQ(other.read_u8(reg::kDlStatus) & 0x04, 0);
}

}  // namespace
}  // namespace ecat::sim
