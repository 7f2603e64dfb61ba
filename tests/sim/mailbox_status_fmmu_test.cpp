// What the master's mailbox status in the cyclic frame relies on, on the simulated ESC: an FMMU
// mapping SM1's status register (0x080D) is read by LRD/LRW like any input (bit 3 "mailbox full",
// one WKC increment), the read takes nothing out of the mailbox, and a firmware with a reply
// delay (mailbox_reply_us) fills SM1 only once that time has passed.
#include <gtest/gtest.h>

#include <ecat/sim/standard_application.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using test::Bytes;
using test::SimMaster;
namespace reg = wire::reg;

constexpr std::uint32_t kStatusLogical = 0x00020000;
constexpr std::uint8_t kMailboxFull = 0x08;

struct Rig {
  explicit Rig(std::map<std::string, std::string> options = {}) : master(segment) {
    test::add_device(segment, "dut", test::profile("mailbox", std::move(options)));
    master.assign_stations();
    master.bring_to_preop(0);
    // FMMU 2: one byte at SM1's status register, read direction.
    master.write_fmmu(0, 2, kStatusLogical, 1, 0x080D, false);
  }
  // The status byte as an LRD of the logical address reads it, and the datagram's WKC.
  std::pair<std::uint8_t, std::uint16_t> status() {
    auto r = master.exchange(wire::Command::lrd, kStatusLogical, Bytes(1, 0));
    return {r.data.at(0), r.wkc};
  }
  Segment segment;
  SimMaster master;
};

// An SDO upload request of 0x1018:01.
Bytes upload_request() {
  wire::SdoMessage request = wire::SdoInitiateUploadRequest{0x1018, 1, false};
  auto encoded = wire::encode_sdo(request);
  EXPECT_TRUE(encoded.ok());
  return encoded.ok() ? *encoded : Bytes{};
}

TEST(MailboxStatusFmmu, StatusRegisterReadThroughAnFmmuWithoutSideEffects) {
  Rig rig;
  auto [empty, wkc] = rig.status();
  EXPECT_EQ(empty & kMailboxFull, 0);
  EXPECT_EQ(wkc, 1);
  ASSERT_TRUE(rig.master.write_mailbox(0, wire::MailboxType::coe, upload_request()));
  // The firmware answers at once: SM1 is full, seen through the FMMU as often as it is read.
  for (int i = 0; i < 3; ++i) {
    auto [full, read_wkc] = rig.status();
    EXPECT_NE(full & kMailboxFull, 0) << i;
    EXPECT_EQ(read_wkc, 1);
  }
  // The status reads took nothing: the reply is still there, and SM1 is empty after it.
  auto reply = rig.master.read_mailbox(0);
  ASSERT_TRUE(reply);
  EXPECT_EQ(reply->first.type, wire::MailboxType::coe);
  EXPECT_EQ(rig.status().first & kMailboxFull, 0);
  EXPECT_FALSE(rig.master.read_mailbox(0));
}

TEST(MailboxStatusFmmu, ReplyDelayFillsSm1OnlyWhenItsTimeHasCome) {
  Rig rig(std::map<std::string, std::string>{{"mailbox_reply_us", "2000"}});
  ASSERT_TRUE(rig.master.write_mailbox(0, wire::MailboxType::coe, upload_request()));
  EXPECT_EQ(rig.status().first & kMailboxFull, 0);
  EXPECT_FALSE(rig.master.read_mailbox(0));
  rig.master.wait(1'000'000);
  EXPECT_EQ(rig.status().first & kMailboxFull, 0);
  rig.master.wait(1'100'000);
  EXPECT_NE(rig.status().first & kMailboxFull, 0);
  EXPECT_TRUE(rig.master.read_mailbox(0));
}

TEST(MailboxStatusFmmu, ReplyDelayOptionIsChecked) {
  DeviceConfig config;
  config.profile = "mailbox";
  config.options = {{"mailbox_reply_us", "soon"}};
  auto made = make_device(config);
  ASSERT_FALSE(made);
  EXPECT_NE(made.error().describe().find("mailbox_reply_us"), std::string::npos);
  config.options = {{"mailbox_reply_us", "20000000"}};
  EXPECT_FALSE(make_device(config));
}

}  // namespace
}  // namespace ecat::sim
