// The built-in device profiles through real datagrams: identities and SII images, the EK1100,
// EL2809 -> EL1809 wiring through LRW, EL3202 temperatures, range bits and settings, EL4102
// outputs and their safe state, the mailbox device's large objects, and devices rebuilt from the
// real EEPROM images in the shared data.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <tuple>

#include <gtest/gtest.h>

#include <ecat/sim/standard_application.hpp>
#include <ecat/sim/wiring.hpp>

#include "sim/sim_master.hpp"
#include "support/shared_data.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;
using test::SimMaster;
using wire::AlState;

wire::SiiImage sii_of(const Esc& esc) {
  auto decoded = wire::decode_sii(esc.eeprom());
  EXPECT_TRUE(decoded.ok());
  EXPECT_TRUE(decoded.ok() && decoded->checksum_ok);
  return decoded.ok() ? decoded->image : wire::SiiImage{};
}

std::unique_ptr<Esc> make(const std::string& profile,
                          std::map<std::string, std::string> options = {}) {
  auto esc = make_device(test::profile(profile, std::move(options)));
  EXPECT_TRUE(esc.ok()) << (esc.ok() ? "" : esc.error().describe());
  return esc.ok() ? std::move(*esc) : nullptr;
}

void to_op(SimMaster& m, std::size_t position) {
  m.bring_to_preop(position);
  m.configure_process_data(position);
  auto r = m.request(position, AlState::safeop);
  ASSERT_EQ(r.state, AlState::safeop) << "AL status code 0x" << std::hex << r.code;
  r = m.request(position, AlState::op);
  ASSERT_EQ(r.state, AlState::op) << "AL status code 0x" << std::hex << r.code;
}

// ---- the factory ----------------------------------------------------------------------------

TEST(Factory, ListsEveryProfileAndRefusesUnknownOnes) {
  std::vector<std::string> names;
  for (const auto& p : device_profiles()) {
    names.push_back(p.name);
    EXPECT_FALSE(p.description.empty());
  }
  EXPECT_EQ(names, (std::vector<std::string>{"generic", "EK1100", "EK1122", "EL1809", "EL2809",
                                             "EL3202", "EL4102", "servo", "mailbox", "soe_drive",
                                             "eoe_device", "eeprom", "esi"}));
  auto unknown = make_device(test::profile("EL9999"));
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().code(), Errc::not_found);
  EXPECT_NE(unknown.error().message().find("EL9999"), std::string::npos);
  EXPECT_NE(unknown.error().message().find("EL3202"), std::string::npos);
  auto bad_option = make_device(test::profile("EL1809", {{"channels", "8"}}));
  ASSERT_FALSE(bad_option.ok());
  EXPECT_NE(bad_option.error().message().find("'channels'"), std::string::npos);
  auto bad_serial = make_device(test::profile("EL1809", {{"serial", "12x"}}));
  ASSERT_FALSE(bad_serial.ok());
  EXPECT_NE(bad_serial.error().message().find("serial"), std::string::npos);
  auto no_file = make_device(test::profile("eeprom"));
  ASSERT_FALSE(no_file.ok());
  EXPECT_NE(no_file.error().message().find("file="), std::string::npos);
  DeviceConfig missing = test::profile("eeprom");
  missing.file = "/nonexistent/image.bin";
  auto missing_file = make_device(missing);
  ASSERT_FALSE(missing_file.ok());
  EXPECT_NE(missing_file.error().message().find("/nonexistent/image.bin"), std::string::npos);
}

TEST(Factory, BeckhoffIdentities) {
  struct Expected {
    const char* profile;
    std::uint32_t product;
    std::uint32_t revision;
    const char* order;
  };
  for (const auto& e : {Expected{"EK1100", 0x044C2C52, 0x00120000, "EK1100"},
                        Expected{"EL1809", 0x07113052, 0x00120000, "EL1809"},
                        Expected{"EL2809", 0x0AF93052, 0x00120000, "EL2809"},
                        Expected{"EL3202", 0x0C823052, 0x00150000, "EL3202"},
                        Expected{"EL4102", 0x10063052, 0x00130000, "EL4102"}}) {
    SCOPED_TRACE(e.profile);
    auto esc = make(e.profile, {{"serial", "0x1234"}});
    ASSERT_NE(esc, nullptr);
    const auto sii = sii_of(*esc);
    EXPECT_EQ(sii.identity, (wire::SiiIdentity{0x00000002, e.product, e.revision, 0x1234}));
    ASSERT_TRUE(sii.general);
    EXPECT_EQ(sii.string(sii.general->order_index), e.order);
    EXPECT_EQ(sii.device_name().substr(0, 6), e.order);
  }
}

TEST(Factory, DcClockComesFromTheConfig) {
  DeviceConfig c = test::profile("EL1809");
  c.clock.drift_ppm = 50;
  c.clock.start_offset_ns = 123456;
  auto esc = make_device(c);
  ASSERT_TRUE(esc.ok());
  ASSERT_NE((*esc)->dc(), nullptr);
  EXPECT_EQ((*esc)->dc()->clock().drift_ppm, 50);
  EXPECT_EQ((*esc)->dc()->clock().start_offset_ns, 123456);
}

// ---- EK1100, EL1809, EL2809 ------------------------------------------------------------------

TEST(Ek1100, NoMailboxNoProcessDataReachesOp) {
  Segment segment;
  test::add_device(segment, "coupler", test::profile("EK1100"));
  SimMaster m(segment);
  m.assign_stations();
  const auto sii = sii_of(segment.esc(0));
  EXPECT_FALSE(sii.standard_mailbox.present());
  EXPECT_TRUE(sii.sync_managers.empty());
  ASSERT_TRUE(sii.general);
  EXPECT_EQ(sii.general->current_on_ebus_ma, -2000);
  EXPECT_EQ(sii.general->port(0), wire::sii_port::kMii);
  EXPECT_EQ(sii.general->port(1), wire::sii_port::kEbus);
  EXPECT_EQ(segment.esc(0).hardware().ports.ports[1], wire::PortType::ebus);
  to_op(m, 0);
  EXPECT_TRUE(device_application(segment.esc(0))->signals().empty());
}

TEST(DigitalTerminals, SiiMatchesTheRealTerminals) {
  auto in = make("EL1809");
  const auto in_sii = sii_of(*in);
  ASSERT_EQ(in_sii.sync_managers.size(), 1u);
  EXPECT_EQ(in_sii.sync_managers[0],
            (wire::SiiSyncManager{0x1000, 2, 0x00, 0, 0x01, wire::sii_sm_type::kInputs}));
  ASSERT_EQ(in_sii.txpdos.size(), 16u);
  EXPECT_EQ(in_sii.txpdos[15].index, 0x1A0F);
  EXPECT_EQ(in_sii.txpdos[15].entries[0].index, 0x60F0);
  EXPECT_EQ(in_sii.string(in_sii.txpdos[15].name_index), "Channel 16");
  EXPECT_FALSE(in_sii.standard_mailbox.present());

  auto out = make("EL2809");
  const auto out_sii = sii_of(*out);
  ASSERT_EQ(out_sii.sync_managers.size(), 2u);
  EXPECT_EQ(out_sii.sync_managers[1],
            (wire::SiiSyncManager{0x0F01, 1, 0x44, 0, 0x09, wire::sii_sm_type::kOutputs}));
  ASSERT_EQ(out_sii.rxpdos.size(), 16u);
  EXPECT_EQ(out_sii.rxpdos[7].sync_manager, 0);
  EXPECT_EQ(out_sii.rxpdos[8].sync_manager, 1);
  EXPECT_EQ(out_sii.rxpdos[8].entries[0].index, 0x7080);
  auto signals = device_application(*out)->signals();
  ASSERT_EQ(signals.size(), 16u);
  EXPECT_EQ(signals[15].name, "channel_16");
  EXPECT_EQ(signals[15].direction, SignalDirection::output);
  EXPECT_EQ(signals[15].type, "bool");
}

TEST(DigitalTerminals, El2809DrivesEl1809ThroughWiring) {
  Segment segment;
  test::add_device(segment, "coupler", test::profile("EK1100"));
  test::add_device(segment, "inputs", test::profile("EL1809"));
  test::add_device(segment, "outputs", test::profile("EL2809"));
  ASSERT_TRUE(wire_signals(segment, "outputs", "channel_1", "inputs", "channel_1").ok());
  ASSERT_TRUE(wire_signals(segment, "outputs", "channel_16", "inputs", "channel_16").ok());
  SimMaster m(segment);
  m.assign_stations();
  to_op(m, 0);
  to_op(m, 1);
  to_op(m, 2);
  // Image: inputs (2 bytes) at 0, outputs SM0 at 2, SM1 at 3.
  ASSERT_EQ(m.slot(1, 0).offset, 0u);
  ASSERT_EQ(m.slot(2, 0).offset, 2u);
  ASSERT_EQ(m.slot(2, 1).offset, 3u);
  EXPECT_EQ(m.lrw(), 3);  // EL1809 reads (1), EL2809 writes (2)
  EXPECT_EQ(m.image()[0], 0);
  m.image()[2] = 0x01;  // channel 1
  m.image()[3] = 0x80;  // channel 16
  m.lrw();              // outputs reach the EL2809; wiring copies them after the frame
  EXPECT_EQ(m.lrw(), 3);
  EXPECT_EQ(m.image()[0], 0x01);
  EXPECT_EQ(m.image()[1], 0x80);
  auto* inputs = device_application(segment.esc(1));
  EXPECT_EQ(inputs->signal("channel_1"), 1.0);
  EXPECT_EQ(inputs->signal("channel_16"), 1.0);
  EXPECT_EQ(inputs->signal("channel_2"), 0.0);
  // Unwired channels follow set_input; clear_input releases them.
  EXPECT_TRUE(inputs->set_input("channel_9", 1));
  m.lrw();
  EXPECT_EQ(m.image()[1], 0x81);
  inputs->clear_input("channel_9");
  EXPECT_EQ(inputs->signal("channel_9"), 1.0);     // the entry keeps its last value ...
  EXPECT_TRUE(inputs->set_input("channel_9", 0));  // ... until something drives it
  m.image()[2] = 0x00;
  m.lrw();
  m.lrw();
  EXPECT_EQ(m.image()[0], 0x00);
  EXPECT_EQ(m.image()[1], 0x80);
  // Outputs are not inputs.
  EXPECT_FALSE(device_application(segment.esc(2))->set_input("channel_1", 1));
  EXPECT_FALSE(inputs->set_input("channel_17", 1));
}

TEST(Wiring, RefusesWhatCannotBeWired) {
  Segment segment;
  test::add_device(segment, "inputs", test::profile("EL1809"));
  test::add_device(segment, "outputs", test::profile("EL2809"));
  test::add_device(segment, "plain", test::profile("generic"));
  auto missing = wire_signals(segment, "nope", "channel_1", "inputs", "channel_1");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  auto wrong_way = wire_signals(segment, "inputs", "channel_1", "outputs", "channel_1");
  ASSERT_FALSE(wrong_way.ok());
  EXPECT_NE(wrong_way.error().message().find("is an input, not an output"), std::string::npos);
  auto no_signal = wire_signals(segment, "outputs", "channel_99", "inputs", "channel_1");
  ASSERT_FALSE(no_signal.ok());
  EXPECT_NE(no_signal.error().message().find("channel_99"), std::string::npos);
  EXPECT_FALSE(wire_signals(segment, "outputs", "channel_1", "plain", "x").ok());
}

// Generic slaves have the DC system time unit (SII word 0 enables SYNC out and latch in), so DC
// tests can use them: the system time answers, runs with segment time and takes a write.
TEST(Generic, HasTheDcSystemTimeUnit) {
  Segment segment;
  test::add_device(segment, "a", test::profile("generic"));
  test::add_device(segment, "b", test::profile("generic"));
  SimMaster m(segment);
  m.assign_stations();
  EXPECT_EQ(sii_of(segment.esc(0)).pdi_control, 0x0C08);
  EXPECT_EQ(segment.esc(0).read_u8(wire::reg::kEscConfiguration) & 0x0C, 0x0C);
  const auto fp = [&](std::size_t pos, std::uint16_t ado) { return test::fp(m.station(pos), ado); };
  auto t1 = m.exchange(wire::Command::fprd, fp(0, 0x0910), Bytes(8, 0));
  EXPECT_EQ(t1.wkc, 1);
  m.wait(1'000'000);
  auto t2 = m.exchange(wire::Command::fprd, fp(0, 0x0910), Bytes(8, 0));
  ASSERT_EQ(t2.wkc, 1);
  const auto elapsed =
      static_cast<std::int64_t>(wire::load_le64(t2.data.data()) - wire::load_le64(t1.data.data()));
  EXPECT_GE(elapsed, 1'000'000);
  EXPECT_LE(elapsed, 1'020'000);  // the frames' own 10 µs and the hop times
  // FRMW of the reference time: the first reads it, the second takes it.
  auto frmw = m.exchange(wire::Command::frmw, fp(0, 0x0910), Bytes(8, 0));
  EXPECT_EQ(frmw.wkc, 2);
  auto brd = m.exchange(wire::Command::brd, wire::physical_address(0, 0x0918), Bytes(4, 0));
  EXPECT_EQ(brd.wkc, 2);
}

// ---- EL3202 ---------------------------------------------------------------------------------

class El3202 : public ::testing::Test {
 protected:
  void SetUp() override {
    test::add_device(segment, "rtd", test::profile("EL3202"));
    m.assign_stations();
    m.bring_to_preop(0);
  }
  struct Channel {
    bool underrange;
    bool overrange;
    std::uint8_t limit1;
    std::uint8_t limit2;
    bool error;
    bool state;
    bool toggle;
    std::int16_t value;
  };
  Channel channel(int ch) {
    m.lrw();
    const std::uint8_t* p = &m.image()[m.slot(0, 3).offset + 4 * ch];
    const std::uint16_t status = wire::load_le16(p);
    return {(status & 0x01) != 0,
            (status & 0x02) != 0,
            static_cast<std::uint8_t>((status >> 2) & 3),
            static_cast<std::uint8_t>((status >> 4) & 3),
            (status & 0x40) != 0,
            (status & 0x4000) != 0,
            (status & 0x8000) != 0,
            static_cast<std::int16_t>(wire::load_le16(p + 2))};
  }
  DeviceApplication& dev() { return *device_application(segment.esc(0)); }
  Segment segment;
  SimMaster m{segment};
};

TEST_F(El3202, AcceptsTheStartupParametersMastersWrite) {
  // TwinCAT / IgH style: assignment rewritten, settings per channel, restore defaults.
  EXPECT_EQ(m.download(0, 0x1C12, 0, {0}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x1C13, 0, {0}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x1C13, 1, test::le16(0x1A00)).abort, 0u);
  EXPECT_EQ(m.download(0, 0x1C13, 2, test::le16(0x1A01)).abort, 0u);
  EXPECT_EQ(m.download(0, 0x1C13, 0, {2}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x08, 0x00}).abort, 0u);  // element: 1/16 ohm
  EXPECT_EQ(m.download(0, 0x8010, 0x19, {0x08, 0x00}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x1A, {0x01, 0x00}).abort, 0u);  // 3-wire
  EXPECT_EQ(m.download(0, 0x8000, 0x15, {0x00, 0x00}).abort, 0u);  // 50 Hz filter
  EXPECT_EQ(m.download(0, 0x8000, 0x06, {0x01}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x02, {0x00}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x1B, {0x00, 0x00}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x1C33, 1, {0x00, 0x00}).abort, 0u);
  // Out of range values are refused with the CoE codes.
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x10, 0x01}).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::value_too_high));
  // The mapping itself is fixed.
  EXPECT_EQ(m.download(0, 0x1A00, 0, {0}).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::write_of_read_only));
  // 0x1011:01 "load" restores the defaults; other values are refused.
  EXPECT_EQ(m.download(0, 0x1011, 1, test::le32(0x12345678)).abort,
            static_cast<std::uint32_t>(wire::SdoAbortCode::cannot_store));
  EXPECT_EQ(m.download(0, 0x1011, 1, test::le32(0x64616F6C)).abort, 0u);
  auto element = m.upload(0, 0x8000, 0x19);
  ASSERT_TRUE(element.value);
  EXPECT_EQ(*element.value, (Bytes{0x00, 0x00}));
  auto identity = m.upload(0, 0x1018, 2);
  ASSERT_TRUE(identity.value);
  EXPECT_EQ(*identity.value, test::le32(0x0C823052));
}

TEST_F(El3202, TemperaturesAndRangeBits) {
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  // Ambient by default: 25.0 °C in 1/10 °C.
  auto c = channel(0);
  EXPECT_EQ(c.value, 250);
  EXPECT_FALSE(c.error);
  EXPECT_EQ(dev().signal("temperature_1"), 25.0);
  const bool toggle = c.toggle;
  EXPECT_NE(channel(0).toggle, toggle);  // new data every update
  ASSERT_TRUE(dev().set_input("temperature_1", 21.34));
  ASSERT_TRUE(dev().set_input("temperature_2", -12.5));
  EXPECT_EQ(channel(0).value, 213);
  EXPECT_EQ(channel(1).value, -125);
  // Below the PT100 range (-200 °C): underrange + error, value at the limit.
  ASSERT_TRUE(dev().set_input("temperature_1", -250));
  c = channel(0);
  EXPECT_TRUE(c.underrange);
  EXPECT_FALSE(c.overrange);
  EXPECT_TRUE(c.error);
  EXPECT_TRUE(c.state);
  EXPECT_EQ(c.value, -2000);
  // Above (850 °C): overrange.
  ASSERT_TRUE(dev().set_input("temperature_1", 900));
  c = channel(0);
  EXPECT_FALSE(c.underrange);
  EXPECT_TRUE(c.overrange);
  EXPECT_TRUE(c.error);
  EXPECT_EQ(c.value, 8500);
  // A broken wire.
  ASSERT_TRUE(dev().set_input("temperature_1", std::numeric_limits<double>::quiet_NaN()));
  c = channel(0);
  EXPECT_TRUE(c.overrange);
  EXPECT_TRUE(c.error);
  EXPECT_EQ(c.value, 32767);
  // Released: back to ambient, no error.
  dev().clear_input("temperature_1");
  c = channel(0);
  EXPECT_EQ(c.value, 250);
  EXPECT_FALSE(c.error || c.underrange || c.overrange || c.state);
  // Settings in OP take effect: high resolution, limits, resistance output, Ni100 range.
  EXPECT_EQ(m.download(0, 0x8000, 0x02, {0x02}).abort, 0u);
  EXPECT_EQ(channel(0).value, 2500);
  EXPECT_EQ(m.download(0, 0x8000, 0x02, {0x00}).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x13, test::le16(300)).abort, 0u);
  EXPECT_EQ(m.download(0, 0x8000, 0x07, {0x01}).abort, 0u);
  EXPECT_EQ(channel(0).limit1, 2);  // 250 < 300
  EXPECT_EQ(m.download(0, 0x8000, 0x13, test::le16(250)).abort, 0u);
  EXPECT_EQ(channel(0).limit1, 3);
  ASSERT_TRUE(dev().set_input("temperature_1", 0.0));
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x08, 0x00}).abort, 0u);
  EXPECT_EQ(static_cast<std::uint16_t>(channel(0).value), 1600);  // 100 ohm * 16
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x09, 0x00}).abort, 0u);
  ASSERT_TRUE(dev().set_input("temperature_1", 100.0));  // 138.5055 ohm * 64
  EXPECT_EQ(static_cast<std::uint16_t>(channel(0).value), 8864);
  EXPECT_EQ(m.download(0, 0x8000, 0x19, {0x01, 0x00}).abort, 0u);  // Ni100: -60..250 °C
  ASSERT_TRUE(dev().set_input("temperature_1", 260.0));
  c = channel(0);
  EXPECT_TRUE(c.overrange);
  EXPECT_EQ(c.value, 2500);
  // The status bits can be read over SDO too.
  auto over = m.upload(0, 0x6000, 0x02);
  ASSERT_TRUE(over.value);
  EXPECT_EQ(*over.value, Bytes{0x01});
  EXPECT_FALSE(dev().set_input("temperature_3", 1));
}

// ---- EL4102 ---------------------------------------------------------------------------------

TEST(El4102, OutputsAndTheirSafeState) {
  Segment segment;
  test::add_device(segment, "ao", test::profile("EL4102"));
  SimMaster m(segment);
  m.assign_stations();
  m.bring_to_preop(0);
  EXPECT_EQ(m.download(0, 0x8010, 0x13, test::le16(0x3FFF)).abort, 0u);  // ch2 default 5 V
  to_op(m, 0);
  auto& dev = *device_application(segment.esc(0));
  const auto signals = dev.signals();
  ASSERT_EQ(signals.size(), 2u);
  EXPECT_EQ(signals[0].name, "output_1");
  EXPECT_EQ(signals[0].unit, "V");
  std::uint8_t* out = &m.image()[m.slot(0, 2).offset];
  wire::store_le16(out, 0x7FFF);
  wire::store_le16(out + 2, 0x0CCD);  // 1 V
  EXPECT_EQ(m.lrw(), 2);
  EXPECT_NEAR(*dev.signal("output_1"), 10.0, 1e-9);
  EXPECT_NEAR(*dev.signal("output_2"), 1.0, 1e-3);
  wire::store_le16(out, 0x8000);  // negative: 0 V
  m.lrw();
  EXPECT_EQ(dev.signal("output_1"), 0.0);
  // Leaving OP: default outputs (ch1 0 V, ch2 the configured 5 V).
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  EXPECT_EQ(dev.signal("output_1"), 0.0);
  EXPECT_NEAR(*dev.signal("output_2"), 5.0, 1e-3);
  // SAFEOP does not apply outputs.
  wire::store_le16(out, 0x7FFF);
  m.lrw();
  EXPECT_EQ(dev.signal("output_1"), 0.0);
  EXPECT_FALSE(dev.set_input("output_1", 3.0));
}

// ---- mailbox device -------------------------------------------------------------------------

TEST(MailboxDevice, LargeObjectsTravelSegmented) {
  Segment segment;
  test::add_device(segment, "mbx", test::profile("mailbox"));
  SimMaster m(segment);
  m.assign_stations();
  m.bring_to_preop(0);
  auto word = m.upload(0, 0x2000, 1);
  ASSERT_TRUE(word.value);
  EXPECT_EQ(*word.value, test::le16(0x1234));
  auto blob = m.upload(0, 0x2001, 1);
  ASSERT_TRUE(blob.value);
  EXPECT_EQ(std::string(blob.value->begin(), blob.value->begin() + 9), "hello-sim");
  EXPECT_EQ(blob.value->size(), 12u);
  for (auto [index, size, step] :
       {std::tuple{0x2002, 80u, 1u}, std::tuple{0x2003, 192u, 1u}, std::tuple{0x2004, 4096u, 7u}}) {
    auto v = m.upload(0, static_cast<std::uint16_t>(index), 1);
    ASSERT_TRUE(v.value) << std::hex << index;
    ASSERT_EQ(v.value->size(), size);
    for (std::size_t i = 0; i < size; ++i) {
      ASSERT_EQ((*v.value)[i], static_cast<std::uint8_t>(i * step)) << i;
    }
  }
  Bytes big(4096);
  for (std::size_t i = 0; i < big.size(); ++i)
    big[i] = static_cast<std::uint8_t>(255 - i % 251);
  EXPECT_EQ(m.download(0, 0x2004, 1, big).abort, 0u);
  auto back = m.upload(0, 0x2004, 1);
  ASSERT_TRUE(back.value);
  EXPECT_EQ(*back.value, big);
  // Process data: button1 mirrors led0.
  m.configure_process_data(0);
  ASSERT_EQ(m.request(0, AlState::safeop).state, AlState::safeop);
  ASSERT_EQ(m.request(0, AlState::op).state, AlState::op);
  m.image()[m.slot(0, 2).offset] = 0x5A;
  m.image()[m.slot(0, 2).offset + 1] = 0x0F;
  m.lrw();
  m.lrw();
  EXPECT_EQ(m.image()[m.slot(0, 3).offset], 0x5A);
  auto* dev = device_application(segment.esc(0));
  EXPECT_EQ(dev->signal("led_1"), 15.0);
  EXPECT_EQ(dev->signal("button_1"), 90.0);
}

// ---- devices from real EEPROM images ----------------------------------------------------------

void eeprom_device_reaches_op(const std::filesystem::path& file, std::uint32_t product,
                              std::map<std::size_t, std::uint16_t> expected_lengths) {
  DeviceConfig c = test::profile("eeprom");
  c.file = file.string();
  Segment segment;
  test::add_device(segment, "dut", c);
  SimMaster m(segment);
  m.assign_stations();
  // The ESC serves the image as it is, byte for byte, through its EEPROM interface.
  const auto bytes = ::ecat::test::read_file(file);
  EXPECT_EQ(m.read_sii(0, 128), Bytes(bytes.begin(), bytes.begin() + 128));
  EXPECT_EQ(m.sii(0).identity.product_code, product);
  to_op(m, 0);
  for (const auto& [sm, length] : expected_lengths) {
    EXPECT_EQ(m.slot(0, sm).length, length) << "SM" << sm;
    EXPECT_EQ(segment.esc(0).sync_manager(sm).config.length, length);
  }
  EXPECT_EQ(m.lrw(), m.image_size() == 0 ? 0 : 2);
  m.wait(50'000'000);
  m.lrw();
  EXPECT_EQ(m.al_status(0).state, AlState::op);
}

TEST(EepromProfile, Ek1100) {
  ECAT_SHARED_DATA_OR_SKIP(file, "eeprom/ek1100.bin");
  eeprom_device_reaches_op(file, 0x044C2C52, {});
}

TEST(EepromProfile, El2004OutputsFromFourOneBitPdos) {
  ECAT_SHARED_DATA_OR_SKIP(file, "eeprom/el2004.bin");
  eeprom_device_reaches_op(file, 0x07D43052, {{0, 1}});
  DeviceConfig c = test::profile("eeprom");
  c.file = file.string();
  Segment segment;
  test::add_device(segment, "el2004", c);
  SimMaster m(segment);
  m.assign_stations();
  to_op(m, 0);
  auto& dev = *device_application(segment.esc(0));
  const auto signals = dev.signals();
  ASSERT_EQ(signals.size(), 4u);
  EXPECT_EQ(signals[0].name, "channel_1");
  EXPECT_EQ(signals[3].name, "channel_4");
  EXPECT_EQ(signals[0].direction, SignalDirection::output);
  m.image()[0] = 0x05;
  m.lrw();
  EXPECT_EQ(dev.signal("channel_1"), 1.0);
  EXPECT_EQ(dev.signal("channel_2"), 0.0);
  EXPECT_EQ(dev.signal("channel_3"), 1.0);
  EXPECT_EQ(dev.signal("channel_4"), 0.0);
  // The SyncManager sits on the digital output register.
  EXPECT_EQ(segment.esc(0).read_u8(0x0F00), 0x05);
}

TEST(EepromProfile, El2828) {
  ECAT_SHARED_DATA_OR_SKIP(file, "eeprom/el2828.bin");
  eeprom_device_reaches_op(file, 0x0B0C3052, {{0, 1}});
}

TEST(EepromProfile, El2262WithAVirtualSyncManager) {
  ECAT_SHARED_DATA_OR_SKIP(file, "eeprom/el2262.bin");
  // 16 + 1 + 8 + (1 + 2 + ... + 7) bits per output SyncManager: 53 bits, 7 bytes.
  eeprom_device_reaches_op(file, 0x08D63052, {{0, 7}, {1, 7}});
}

TEST(EepromProfile, RefusesImagesThatAreNotSii) {
  const auto path = std::filesystem::temp_directory_path() / "ecat_blank_sii.bin";
  {
    std::ofstream out(path, std::ios::binary);
    const std::string blank(256, '\xFF');
    out << blank;
  }
  DeviceConfig c = test::profile("eeprom");
  c.file = path.string();
  auto esc = make_device(c);
  ASSERT_FALSE(esc.ok());
  EXPECT_NE(esc.error().describe().find(path.string()), std::string::npos);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace ecat::sim
