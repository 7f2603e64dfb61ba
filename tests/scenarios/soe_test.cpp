// SoE and VoE through a whole master session on the in-process simulator: a coupler, a
// "soe_drive" (SoE only, no CoE, held in SAFEOP) and a "mailbox" device (CoE + VoE). The drive's
// elements are read and split, a value is written and read back, a write is refused in SAFEOP
// with 0x7005, the 122-byte IDN list comes in two fragments, a procedure command's notification
// is collected, a VoE message makes the round trip, and injected faults (a lost fragment, an
// error response, a dropped response) fail the transfers naming what went wrong. Then the drive
// goes to OP with its SII process data.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/master/soe.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/sim/soe_server.hpp>
#include <ecat/wire/soe.hpp>
#include <ecat/wire/voe.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

RingSpec soe_spec() {
  RingSpec spec;
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: drive, profile: soe_drive}
    - {name: mbx, profile: mailbox}
)";
  spec.targets["drive"] = TargetState::safeop;
  spec.adjust = [](master::MasterConfig& config) {
    const auto health = config.slaves.front().health_poll;
    config.slaves.clear();
    for (const char* name : {"coupler", "drive", "mbx"}) {
      master::SlaveConfig s;
      s.name = name;
      s.health_poll = health;
      if (std::string(name) != "coupler") s.process_data = master::ProcessDataRequest::all("main");
      if (std::string(name) == "drive") s.target = TargetState::safeop;
      config.slaves.push_back(std::move(s));
    }
  };
  return spec;
}

class SoeScenario : public ::testing::Test {
 protected:
  void SetUp() override {
    ring_ = ScenarioRing::create(soe_spec());
    ASSERT_TRUE(ring_);
    ASSERT_TRUE(eventually(
        [&] {
          auto s = ring_->master->slave("drive");
          return s && (*s)->state() == SlaveState::safeop;
        },
        10s));
  }

  master::Slave& drive() { return ring_->slave("drive"); }
  master::Slave& mbx() { return ring_->slave("mbx"); }
  void fault(const sim::SoeFaultRule& rule) {
    ring_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      sim::soe_server_of(segment.esc(*segment.find("drive")))->add_fault(rule);
      return 0;
    });
  }

  std::unique_ptr<ScenarioRing> ring_;
};

TEST_F(SoeScenario, ReadElementsWriteAValueAndAWriteRefusedInSafeop) {
  auto all = drive().soe_read(0, 0x0001, 0xFE);
  ASSERT_TRUE(all.ok()) << all.error().describe();
  auto split = master::split_soe_elements(0xFE, *all);
  ASSERT_TRUE(split.ok()) << split.error().describe();
  EXPECT_EQ(split->name, "NC cycle time (TNcyc)");
  EXPECT_EQ(split->unit, "us");
  ASSERT_TRUE(split->attribute.has_value());
  EXPECT_EQ(split->attribute->item_size(), 2u);
  EXPECT_EQ(split->attribute->format, master::SoeDisplayFormat::unsigned_decimal);
  EXPECT_FALSE(split->attribute->write_protected_preop);
  EXPECT_TRUE(split->attribute->write_protected_safeop);
  EXPECT_EQ(split->minimum, (Bytes{125, 0}));
  EXPECT_EQ(split->value, (Bytes{0xE8, 0x03}));

  // The velocity command may be written in SAFEOP; the cycle time may not.
  ASSERT_TRUE(drive().soe_write(0, 0x0024, wire::kSoeElementValue, {0x2C, 0x01, 0, 0}).ok());
  auto back = drive().soe_read(0, 0x0024);
  ASSERT_TRUE(back.ok()) << back.error().describe();
  EXPECT_EQ(*back, (Bytes{0x2C, 0x01, 0, 0}));
  auto refused = drive().soe_write(0, 0x0001, wire::kSoeElementValue, {0xF4, 0x01});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().code(), Errc::mailbox_error);
  EXPECT_EQ(master::soe_error_code(refused.error()), 0x7005);
  EXPECT_NE(refused.error().message().find(
                "SoE error 0x7005 (operation data is write protected at this time)"),
            std::string::npos)
      << refused.error().message();
  auto missing = drive().soe_read(0, 0x0123);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(master::soe_error_code(missing.error()), 0x1001);
}

TEST_F(SoeScenario, TheIdnListComesInFragments) {
  auto list = drive().soe_read(0, 0x0011);
  ASSERT_TRUE(list.ok()) << list.error().describe();
  EXPECT_EQ(list->size(), 4u + 122u);  // two fragments of a 128-byte mailbox
  auto idns = master::decode_soe_idn_list(*list);
  ASSERT_TRUE(idns.ok()) << idns.error().describe();
  EXPECT_EQ(idns->size(), 61u);
  for (std::uint16_t idn : {1, 17, 32, 36, 40, 47, 51, 99, 127, 128}) {
    EXPECT_NE(std::find(idns->begin(), idns->end(), idn), idns->end()) << wire::format_idn(idn);
  }
  // Every IDN the list names can be read by name.
  auto name = drive().soe_read(0, 0x8065, wire::kSoeElementName);  // P-0-0101
  ASSERT_TRUE(name.ok()) << name.error().describe();
  EXPECT_EQ(*master::decode_soe_string(*name), "Manufacturer parameter 1");
}

TEST_F(SoeScenario, AProcedureCommandSendsANotification) {
  ASSERT_TRUE(drive().soe_write(0, 0x0063, wire::kSoeElementValue, {0x03, 0x00}).ok());
  std::vector<master::SoeNotification> got;
  ASSERT_TRUE(eventually(
      [&] {
        auto n = drive().soe_notifications();
        if (n) got.insert(got.end(), n->begin(), n->end());
        return !got.empty();
      },
      2s));
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].opcode, wire::SoeOpcode::notification);
  EXPECT_EQ(got[0].idn, 0x0063);
  EXPECT_EQ(got[0].elements, wire::kSoeElementDataState);
  EXPECT_EQ(got[0].data, (Bytes{0x03, 0x00}));
  // CP4 transition check runs in SAFEOP (phase 3).
  EXPECT_TRUE(drive().soe_write(0, 0x0080, wire::kSoeElementValue, {0x03, 0x00}).ok());
}

TEST_F(SoeScenario, VoeRoundTripAndProtocolsTheSiiDoesNotDeclare) {
  ASSERT_TRUE(mbx().voe_send(0x00000ACE, 0x0010, {1, 2, 3}).ok());
  auto echo = mbx().voe_receive();
  ASSERT_TRUE(echo.ok()) << echo.error().describe();
  EXPECT_EQ(echo->header.vendor_id, 0x00000ACEu);
  EXPECT_EQ(echo->header.vendor_type, 0x0011);
  EXPECT_EQ(echo->data, (Bytes{1, 2, 3}));
  auto none = mbx().voe_receive(100ms);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.error().code(), Errc::timeout);

  auto voe = drive().voe_send(0x00000ACE, 1, {});
  ASSERT_FALSE(voe.ok());
  EXPECT_EQ(voe.error().code(), Errc::unsupported);
  auto soe = mbx().soe_read(0, 0x0001);
  ASSERT_FALSE(soe.ok());
  EXPECT_EQ(soe.error().code(), Errc::unsupported);
  EXPECT_NE(soe.error().message().find("does not declare SoE"), std::string::npos);
  EXPECT_EQ(ring_->slave("coupler").soe_read(0, 0x0001).error().code(), Errc::unsupported);
}

TEST_F(SoeScenario, InjectedFaultsFailNamingWhatWentWrong) {
  // P-0-0010 (260 bytes) comes in three fragments; the second one is lost.
  fault({0, 0x800A, false, sim::SoeFaultKind::drop_fragment, 2, true});
  auto lost = drive().soe_read(0, 0x800A);
  ASSERT_FALSE(lost.ok());
  EXPECT_NE(lost.error().message().find("(a fragment was lost)"), std::string::npos)
      << lost.error().message();
  auto whole = drive().soe_read(0, 0x800A);
  ASSERT_TRUE(whole.ok()) << whole.error().describe();
  EXPECT_EQ(whole->size(), 260u);

  fault({0, 0x0001, false, sim::SoeFaultKind::error_response, 0x800B, true});
  auto general = drive().soe_read(0, 0x0001);
  ASSERT_FALSE(general.ok());
  EXPECT_EQ(master::soe_error_code(general.error()), 0x800B);
  EXPECT_NE(general.error().message().find("general error"), std::string::npos);

  fault({0, 0x0001, false, sim::SoeFaultKind::drop_response, 0, true});
  auto silent = drive().soe_read(0, 0x0001, wire::kSoeElementValue, 200ms);
  ASSERT_FALSE(silent.ok());
  EXPECT_EQ(silent.error().code(), Errc::timeout);
  auto again = drive().soe_read(0, 0x0001);
  ASSERT_TRUE(again.ok()) << again.error().describe();
  EXPECT_EQ(*again, (Bytes{0xE8, 0x03}));
}

TEST_F(SoeScenario, TheDriveGoesToOpWithItsSiiProcessData) {
  ASSERT_TRUE(drive().request(wire::AlState::op).ok());
  EXPECT_EQ(drive().state(), SlaveState::op);
  auto info = drive().info();
  EXPECT_FALSE(info.coe);
  EXPECT_TRUE(info.has_mailbox);
  EXPECT_EQ(drive().signals().size(), 6u);
  // S-0-0032 is write protected in OP.
  auto refused = drive().soe_write(0, 0x0020, wire::kSoeElementValue, {0x02, 0x00});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(master::soe_error_code(refused.error()), 0x7005);
}

// The SoE and VoE faults through the fault language: a lost fragment from the ring file, the
// others through the control channel.
class SoeRingFaults : public SoeScenario {
 protected:
  void SetUp() override {
    RingSpec spec = soe_spec();
    spec.ring_yaml +=
        "  faults:\n"
        "    - {kind: soe_fault, slave: drive, mode: drop_fragment, idn: 0x800A, value: 2}\n";
    ring_ = ScenarioRing::create(spec);
    ASSERT_TRUE(ring_);
    ASSERT_TRUE(eventually(
        [&] {
          auto s = ring_->master->slave("drive");
          return s && (*s)->state() == SlaveState::safeop;
        },
        10s));
  }
  void control(const std::string& fault) {
    const std::string reply = sim::handle_control_request(
        *ring_->server, R"({"op":"fault.inject","fault":)" + fault + "}");
    ASSERT_EQ(reply.rfind(R"({"ok":true)", 0), 0u) << reply;
  }
};

TEST_F(SoeRingFaults, LostFragmentErrorCodeAndVoeFaultsFailCleanly) {
  auto lost = drive().soe_read(0, 0x800A);
  ASSERT_FALSE(lost.ok());
  EXPECT_NE(lost.error().message().find("(a fragment was lost)"), std::string::npos)
      << lost.error().message();
  auto whole = drive().soe_read(0, 0x800A);
  ASSERT_TRUE(whole.ok()) << whole.error().describe();
  EXPECT_EQ(whole->size(), 260u);

  control(R"({"kind":"soe_fault","slave":"drive","mode":"error_response","idn":1,)"
          R"("value":"0x800B"})");
  auto general = drive().soe_read(0, 0x0001);
  ASSERT_FALSE(general.ok());
  EXPECT_EQ(master::soe_error_code(general.error()), 0x800B);

  // VoE: a garbled reply is a malformed message, a dropped one a timeout; then the echo works.
  control(R"({"kind":"voe_fault","slave":"mbx","mode":"garble_reply"})");
  ASSERT_TRUE(mbx().voe_send(0x00000ACE, 0x0010, {1, 2, 3}).ok());
  auto garbled = mbx().voe_receive();
  ASSERT_FALSE(garbled.ok());
  EXPECT_EQ(garbled.error().code(), Errc::malformed) << garbled.error().describe();
  control(R"({"kind":"voe_fault","slave":"mbx","mode":"drop_reply"})");
  ASSERT_TRUE(mbx().voe_send(0x00000ACE, 0x0010, {4}).ok());
  auto dropped = mbx().voe_receive(200ms);
  ASSERT_FALSE(dropped.ok());
  EXPECT_EQ(dropped.error().code(), Errc::timeout);
  ASSERT_TRUE(mbx().voe_send(0x00000ACE, 0x0010, {5}).ok());
  auto echo = mbx().voe_receive();
  ASSERT_TRUE(echo.ok()) << echo.error().describe();
  EXPECT_EQ(echo->data, (Bytes{5}));
  EXPECT_FALSE(ring_->any_slave_fault());
}

}  // namespace
}  // namespace ecat::scenarios
