// FoE through a running session: the reference ring plus the "mailbox" device (FoE file store,
// bootstrap mailbox) with its process data in domain "main", operational. Files are written and
// read through Slave::foe_write / foe_read (1 MiB with progress), the slave's errors (password,
// unknown file, an aborted transfer, a lost reply) come out as named errors and leave the session
// alone, and Slave::update_firmware takes the slave through INIT and BOOTSTRAP and back while the
// session is held off it, ending with the device running the new image and the session
// operational again.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/foe.hpp>
#include <ecat/master/master.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/foe_server.hpp>
#include <ecat/sim/server.hpp>
#include <ecat/sim/standard_application.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using Bytes = std::vector<std::uint8_t>;
constexpr std::size_t kMailboxPosition = 3;

Bytes pattern(std::size_t n, unsigned step = 7) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * step + (i >> 8)) & 0xFF);
  return out;
}

class Foe : public ::testing::Test {
 protected:
  // The mailbox slave's process data in domain "main" (a slave taken out of OP disturbs the
  // domain, so the session would pull it back unless it is held).
  virtual bool with_process_data() const { return true; }

  void SetUp() override {
    RingSpec spec;
    spec.kind = RingKind::segmented;
    spec.adjust = [pd = with_process_data()](master::MasterConfig& config) {
      for (auto& s : config.slaves) {
        if (s.name == "mailbox") {
          if (pd) s.process_data = master::ProcessDataRequest::all("main");
          s.startup_sdos.clear();
        }
      }
    };
    ring_ = ScenarioRing::operational(spec);
    ASSERT_TRUE(ring_);
  }

  master::Slave& mbx() { return ring_->slave("mailbox"); }

  template <class F>
  decltype(auto) with_foe(F&& f) {
    return ring_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      auto* foe = sim::foe_server_of(segment.esc(kMailboxPosition));
      EXPECT_NE(foe, nullptr);
      return f(*foe, segment.esc(kMailboxPosition));
    });
  }

  bool back_in_operation() {
    return eventually(
        [&] {
          return ring_->state() == MasterState::operational && mbx().state() == SlaveState::op &&
                 !ring_->any_slave_fault();
        },
        10s);
  }

  std::unique_ptr<ScenarioRing> ring_;
};

TEST_F(Foe, FilesAreWrittenAndReadBackWhileTheSessionRuns) {
  const Bytes notes = pattern(100);
  auto written = mbx().foe_write("notes.txt", notes);
  ASSERT_TRUE(written) << written.error().describe();
  auto read = mbx().foe_read("notes.txt");
  ASSERT_TRUE(read) << read.error().describe();
  EXPECT_EQ(*read, notes);
  EXPECT_EQ(with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.file("notes.txt")->data; }),
            notes);
  EXPECT_EQ(ring_->state(), MasterState::operational);
}

TEST_F(Foe, AOneMebibyteFileWithProgress) {
  const Bytes big = pattern(1024 * 1024, 13);
  std::vector<std::pair<std::size_t, std::optional<std::size_t>>> seen;
  master::FoeOptions options;
  options.progress = [&](std::size_t done, std::optional<std::size_t> total) {
    seen.emplace_back(done, total);
  };
  auto written = mbx().foe_write("big.bin", big, options);
  ASSERT_TRUE(written) << written.error().describe();
  // One call per packet of 52 bytes (64-byte mailbox): 20165 full packets and a short one.
  ASSERT_EQ(seen.size(), big.size() / 52 + 1);
  EXPECT_EQ(seen.front(), (std::pair<std::size_t, std::optional<std::size_t>>{52, big.size()}));
  EXPECT_EQ(seen.back(),
            (std::pair<std::size_t, std::optional<std::size_t>>{big.size(), big.size()}));
  seen.clear();
  auto read = mbx().foe_read("big.bin", options);
  ASSERT_TRUE(read) << read.error().describe();
  EXPECT_TRUE(*read == big);
  ASSERT_FALSE(seen.empty());
  EXPECT_EQ(seen.back().second, big.size());  // known at the end
  // A read larger than the caller allows stops early.
  master::FoeOptions small;
  small.max_read_size = 4096;
  auto bounded = mbx().foe_read("big.bin", small);
  ASSERT_FALSE(bounded);
  EXPECT_EQ(bounded.error().code(), Errc::out_of_range);
  EXPECT_EQ(ring_->state(), MasterState::operational);
  EXPECT_FALSE(ring_->any_slave_fault());
}

TEST_F(Foe, WrongPasswordsAndUnknownFilesAreTheSlavesErrors) {
  ASSERT_TRUE(with_foe([](sim::FoeServer& foe, sim::Esc&) {
    return foe.put_file("secret.cfg", {pattern(30), 0xC0DE, false}).ok();
  }));
  auto wrong = mbx().foe_read("secret.cfg", {.password = 1});
  ASSERT_FALSE(wrong);
  EXPECT_EQ(wrong.error().code(), Errc::permission_denied);
  EXPECT_EQ(master::foe_error_code(wrong.error()), 0x800Au);
  EXPECT_EQ(wrong.error().describe(),
            "FoE read of 'secret.cfg' from slave 0x1003: error 0x800A no access rights: wrong "
            "password");
  auto right = mbx().foe_read("secret.cfg", {.password = 0xC0DE});
  ASSERT_TRUE(right) << right.error().describe();
  EXPECT_EQ(*right, pattern(30));
  auto missing = mbx().foe_read("missing.bin");
  ASSERT_FALSE(missing);
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  // The firmware outside BOOTSTRAP.
  auto firmware = mbx().foe_write("firmware.efw", pattern(10));
  ASSERT_FALSE(firmware);
  EXPECT_EQ(firmware.error().code(), Errc::wrong_state);
  EXPECT_EQ(master::foe_error_code(firmware.error()), 0x8009u);
  // A slave without FoE.
  auto coupler = ring_->slave("coupler").foe_read("x");
  ASSERT_FALSE(coupler);
  EXPECT_EQ(coupler.error().code(), Errc::unsupported);
  EXPECT_EQ(ring_->state(), MasterState::operational);
}

TEST_F(Foe, AnAbortedTransferAndALostReplyFailClearlyAndTheNextTransferWorks) {
  with_foe([](sim::FoeServer& foe, sim::Esc&) {
    foe.add_fault({sim::FoeFaultKind::error, 3, 0x800B});
  });
  auto aborted = mbx().foe_write("a.bin", pattern(1000));
  ASSERT_FALSE(aborted);
  EXPECT_EQ(master::foe_error_code(aborted.error()), 0x800Bu);
  EXPECT_EQ(aborted.error().describe(),
            "FoE write of 'a.bin' to slave 0x1003: error 0x800B program error: injected fault");

  // The ACK of packet 5 never comes: the mailbox's repeat request finds only the ACK before it
  // (a duplicate), the transfer times out and the slave is told to drop it.
  with_foe([](sim::FoeServer& foe, sim::Esc&) {
    foe.add_fault({sim::FoeFaultKind::drop_reply, 4, 0});
  });
  master::FoeOptions quick;
  quick.timeout = 100ms;
  auto lost = mbx().foe_write("b.bin", pattern(1000), quick);
  ASSERT_FALSE(lost);
  EXPECT_EQ(lost.error().code(), Errc::timeout);
  EXPECT_NE(lost.error().describe().find("FoE write of 'b.bin' to slave 0x1003: DATA packet 5"),
            std::string::npos)
      << lost.error().describe();
  EXPECT_FALSE(with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.transfer_in_progress(); }));

  // Started again from the beginning, it goes through.
  ASSERT_TRUE(mbx().foe_write("b.bin", pattern(1000)));
  auto back = mbx().foe_read("b.bin");
  ASSERT_TRUE(back) << back.error().describe();
  EXPECT_EQ(*back, pattern(1000));
  EXPECT_EQ(ring_->state(), MasterState::operational);
}

TEST_F(Foe, FirmwareUpdateThroughBootstrapEndsWithTheNewImageRunningAndTheSessionOperational) {
  const std::string before =
      with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.firmware().version; });
  auto image = sim::make_firmware_image("2.0.0", pattern(20000, 3));
  ASSERT_TRUE(image);
  std::size_t progress_calls = 0;
  master::FoeOptions options;
  options.progress = [&](std::size_t, std::optional<std::size_t>) { ++progress_calls; };
  // A device that flashes slowly: two BUSY answers before each ACK.
  with_foe([](sim::FoeServer& foe, sim::Esc&) { foe.set_busy_per_packet(2); });
  auto updated = mbx().update_firmware("firmware.efw", *image, options);
  ASSERT_TRUE(updated) << updated.error().describe();
  // The bootstrap mailbox (256 bytes) carries 244 bytes per packet.
  EXPECT_EQ(progress_calls, image->size() / 244 + 1);
  const auto stats = with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.stats(); });
  EXPECT_EQ(stats.firmware_updates, 1u);
  EXPECT_EQ(stats.busy_sent, 2 * (image->size() / 244 + 1));
  EXPECT_EQ(with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.firmware().version; }),
            "2.0.0");
  EXPECT_NE(before, "2.0.0");
  ASSERT_TRUE(back_in_operation()) << ring_->describe();
  // The device reports its new version through CoE.
  auto version = mbx().upload_sdo(0x100A, 0);
  ASSERT_TRUE(version) << version.error().describe();
  EXPECT_EQ(std::string(version->begin(), version->end()), "2.0.0");
  // The way it went: OP -> INIT -> BOOT -> INIT -> PREOP (and back up by the session).
  EXPECT_EQ(mbx().info().fault, std::nullopt);
}

TEST_F(Foe, ACorruptImageIsRefusedAndTheSlaveReturnsWithItsOldImage) {
  auto image = sim::make_firmware_image("6.6.6", pattern(3000));
  ASSERT_TRUE(image);
  (*image)[sim::kFirmwareHeaderSize + 100] ^= 0x40;
  auto updated = mbx().update_firmware("firmware.efw", *image);
  ASSERT_FALSE(updated);
  EXPECT_EQ(master::foe_error_code(updated.error()), 0x800Cu);
  EXPECT_NE(updated.error().describe().find("error 0x800C checksum error"), std::string::npos)
      << updated.error().describe();
  ASSERT_TRUE(back_in_operation()) << ring_->describe();
  EXPECT_NE(with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.firmware().version; }),
            "6.6.6");
}

// Without process data, so that nothing pulls the slave out of BOOTSTRAP while the test is there.
class FoeWithoutProcessData : public Foe {
 protected:
  bool with_process_data() const override { return false; }
};

TEST_F(FoeWithoutProcessData, BootstrapThroughRequestUsesTheBootstrapMailbox) {
  ASSERT_TRUE(mbx().request(wire::AlState::bootstrap)) << ring_->describe();
  EXPECT_EQ(mbx().state(), SlaveState::bootstrap);
  // FoE in BOOTSTRAP goes through the bootstrap mailbox (244-byte packets).
  std::size_t calls = 0;
  master::FoeOptions options;
  options.progress = [&](std::size_t, std::optional<std::size_t>) { ++calls; };
  ASSERT_TRUE(mbx().foe_write("boot.log", pattern(500), options));
  EXPECT_EQ(calls, 3u);  // 244 + 244 + 12
  // SDOs are not available in BOOTSTRAP.
  EXPECT_FALSE(mbx().upload_sdo(0x1000, 0));
  ASSERT_TRUE(mbx().request(wire::AlState::preop)) << ring_->describe();
  auto read = mbx().foe_read("boot.log");
  ASSERT_TRUE(read) << read.error().describe();
  EXPECT_EQ(*read, pattern(500));
}

// The same faults through the fault language: one in the ring file (injected when the simulator
// starts), the others through the control channel, as `ecat sim fault inject` sends them.
class FoeRingFaults : public Foe {
 protected:
  void SetUp() override {
    RingSpec spec;
    spec.kind = RingKind::segmented;
    spec.ring_yaml = ring_yaml(RingKind::segmented) +
                     "  faults:\n"
                     "    - {kind: foe_fault, slave: mailbox, mode: error, packet: 3, "
                     "value: 0x800B}\n";
    spec.adjust = [](master::MasterConfig& config) {
      for (auto& s : config.slaves) {
        if (s.name == "mailbox") s.startup_sdos.clear();
      }
    };
    ring_ = ScenarioRing::operational(spec);
    ASSERT_TRUE(ring_);
  }
  void control(const std::string& fault) {
    const std::string reply = sim::handle_control_request(
        *ring_->server, R"({"op":"fault.inject","fault":)" + fault + "}");
    ASSERT_EQ(reply.rfind(R"({"ok":true)", 0), 0u) << reply;
  }
};

TEST_F(FoeRingFaults, RingAndControlChannelFaultsFailTransfersClearlyAndTheNextOneWorks) {
  auto aborted = mbx().foe_write("a.bin", pattern(1000));
  ASSERT_FALSE(aborted);
  EXPECT_EQ(master::foe_error_code(aborted.error()), 0x800Bu);
  EXPECT_EQ(aborted.error().describe(),
            "FoE write of 'a.bin' to slave 0x1003: error 0x800B program error: injected fault");

  control(R"({"kind":"foe_fault","slave":"mailbox","mode":"wrong_password"})");
  auto refused = mbx().foe_write("b.bin", pattern(100));
  ASSERT_FALSE(refused);
  EXPECT_EQ(master::foe_error_code(refused.error()), 0x800Au);

  // BUSY three times at the third DATA packet: the master sends it again and the file arrives.
  control(R"({"kind":"foe_fault","slave":"mailbox","mode":"busy","packet":2,"value":3})");
  ASSERT_TRUE(mbx().foe_write("c.bin", pattern(1000)));
  EXPECT_EQ(with_foe([](sim::FoeServer& foe, sim::Esc&) { return foe.stats().busy_sent; }), 3u);

  // A lost ACK: the transfer times out naming the packet, and the slave drops it.
  control(R"({"kind":"foe_fault","slave":"mailbox","mode":"drop_reply","packet":4})");
  master::FoeOptions quick;
  quick.timeout = 100ms;
  auto lost = mbx().foe_write("d.bin", pattern(1000), quick);
  ASSERT_FALSE(lost);
  EXPECT_EQ(lost.error().code(), Errc::timeout);

  auto back = mbx().foe_read("c.bin");
  ASSERT_TRUE(back) << back.error().describe();
  EXPECT_EQ(*back, pattern(1000));
  EXPECT_EQ(ring_->state(), MasterState::operational);
}

}  // namespace
}  // namespace ecat::scenarios
