// Fault injection against a segment of generic slaves: every fault kind and every scheduling form
// with its exact effect on replies and working counters, the descriptions, the JSON and
// command-line forms, and clear(). Mailbox faults need a device with a CoE server: those cases
// sit at the end and skip until such a profile exists.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <ecat/sim/dc_unit.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/registers.hpp>

#include "sim/sim_master.hpp"

namespace ecat::sim {
namespace {

using namespace std::chrono_literals;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using wire::Command;
namespace reg = wire::reg;

constexpr std::int64_t kMs = 1'000'000;

struct Datagram {
  Command command = Command::nop;
  std::uint32_t address = 0;
  std::vector<std::uint8_t> data;
};

struct Reply {
  bool returned = false;
  std::vector<std::uint8_t> frame;  // as it came back (after after_frame hooks)
  std::vector<std::uint16_t> wkc;
  std::vector<std::vector<std::uint8_t>> data;
  std::vector<std::uint16_t> adp;
};

std::vector<std::uint8_t> le16(std::uint16_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8)};
}

std::uint32_t fp(std::uint16_t station, std::uint16_t offset) {
  return wire::physical_address(station, offset);
}

std::vector<std::uint8_t> build(const std::vector<Datagram>& datagrams, std::uint8_t index = 0x40) {
  std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
  wire::FrameBuilder builder(buffer);
  for (const auto& d : datagrams) {
    wire::DatagramHeader header;
    header.command = d.command;
    header.index = index++;
    header.address = d.address;
    header.length = static_cast<std::uint16_t>(d.data.size());
    EXPECT_TRUE(builder.add(header, d.data).has_value());
  }
  const auto frame = builder.finish();
  return {frame.begin(), frame.end()};
}

Reply decode(bool returned, std::vector<std::uint8_t> bytes) {
  Reply r;
  r.returned = returned;
  r.frame = bytes;
  if (!returned) return r;
  auto decoded = wire::decode_frame(bytes);
  EXPECT_TRUE(decoded) << decoded.error.describe();
  if (!decoded) return r;
  for (const auto& d : *decoded.frame) {
    r.wkc.push_back(d.wkc);
    r.data.emplace_back(d.data.begin(), d.data.end());
    r.adp.push_back(d.header.adp());
  }
  return r;
}

// Three generic slaves a, b, c at stations 0x1001..0x1003, each with an FMMU mapping logical byte
// 0x10000 + i onto its RAM at 0x1000 for reading and writing.
class FaultsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    for (const char* name : {"a", "b", "c"}) {
      auto esc = make_device(DeviceConfig{});
      ASSERT_TRUE(esc.ok()) << esc.error().describe();
      ASSERT_TRUE(segment.add_slave(name, std::move(*esc)).ok());
    }
    for (std::uint16_t pos = 0; pos < 3; ++pos) {
      auto r = send(
          {{Command::apwr, wire::physical_address(wire::position_adp(pos), reg::kStationAddress),
            le16(static_cast<std::uint16_t>(0x1001 + pos))}});
      ASSERT_EQ(r.wkc, std::vector<std::uint16_t>{1});
      wire::FmmuConfig fmmu;
      fmmu.logical_start = 0x10000u + pos;
      fmmu.length = 1;
      fmmu.physical_start = 0x1000;
      fmmu.type = wire::FmmuType::read_write;
      fmmu.active = true;
      const auto bytes = fmmu.encode();
      r = send({{Command::fpwr,
                 fp(static_cast<std::uint16_t>(0x1001 + pos), reg::kFmmuBase),
                 {bytes.begin(), bytes.end()}}});
      ASSERT_EQ(r.wkc, std::vector<std::uint16_t>{1});
    }
    injector = std::make_unique<FaultInjector>(segment);
  }

  Reply send(const std::vector<Datagram>& datagrams) {
    auto bytes = build(datagrams);
    now += kMs;
    const bool returned = segment.process_frame(bytes, now);
    return decode(returned, std::move(bytes));
  }

  std::uint16_t brd_wkc() {
    auto r = send({{Command::brd, fp(0, reg::kType), {0}}});
    return r.returned ? r.wkc.at(0) : 0xFFFF;
  }

  Reply lrw() { return send({{Command::lrw, 0x10000, {1, 2, 3}}}); }

  void inject(const Fault& f) {
    auto r = injector->inject(f, now);
    ASSERT_TRUE(r.ok()) << r.error().describe();
  }

  void request_state(std::uint16_t station, wire::AlState state) {
    auto r =
        send({{Command::fpwr, fp(station, reg::kAlControl), le16(wire::encode_al_control(state))}});
    ASSERT_EQ(r.wkc.at(0), 1);
  }

  void to_op(std::uint16_t station) {
    for (auto s : {wire::AlState::preop, wire::AlState::safeop, wire::AlState::op}) {
      request_state(station, s);
    }
    ASSERT_EQ(segment.esc(station - 0x1001u).al_state(), wire::AlState::op);
  }

  Reply poll_al_status(std::uint16_t station) {
    return send({{Command::fprd, fp(station, reg::kAlStatus), {0, 0}}});
  }

  Segment segment;
  std::unique_ptr<FaultInjector> injector;
  std::int64_t now = 1'000 * kMs;
};

// ---- A. Exchange faults ---------------------------------------------------------------------

TEST_F(FaultsTest, DropResponsesIsStickyUntilCleared) {
  inject(fault::drop_responses());
  EXPECT_FALSE(lrw().returned);
  EXPECT_FALSE(lrw().returned);
  EXPECT_TRUE(injector->info(now).drop_responses);
  EXPECT_THAT(injector->info(now).active, ElementsAre("drop responses"));
  EXPECT_EQ(injector->stats().responses_dropped, 2u);
  EXPECT_EQ(segment.stats().frames_lost, 2u);
  injector->clear();
  EXPECT_EQ(lrw().wkc, std::vector<std::uint16_t>{9});
  EXPECT_TRUE(injector->info(now).active.empty());
}

TEST_F(FaultsTest, NextExchangesCountDown) {
  inject(fault::next(fault::drop_responses(), 2));
  auto info = injector->info(now);
  ASSERT_EQ(info.queued.size(), 1u);
  EXPECT_EQ(info.queued[0].description, "drop responses");
  EXPECT_EQ(info.queued[0].remaining, 2u);
  EXPECT_FALSE(lrw().returned);
  EXPECT_EQ(injector->info(now).queued.at(0).remaining, 1u);
  EXPECT_FALSE(lrw().returned);
  EXPECT_TRUE(injector->info(now).queued.empty());
  EXPECT_TRUE(lrw().returned);
}

TEST_F(FaultsTest, OverlappingNextFaultsApplyTogether) {
  inject(fault::next(fault::wkc_offset(-1), 2));
  inject(fault::next(fault::wkc_offset(-2), 1));
  EXPECT_EQ(brd_wkc(), 0);  // 3 - 1 - 2
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_EQ(brd_wkc(), 3);
}

TEST_F(FaultsTest, WkcOffsetAppliesToEveryDatagramAndClamps) {
  inject(fault::wkc_offset(-1));
  auto r = send({{Command::brd, fp(0, reg::kType), {0}},
                 {Command::aprd, wire::physical_address(0, reg::kType), {0}},
                 {Command::lrw, 0x10000, {0, 0, 0}}});
  EXPECT_EQ(r.wkc, (std::vector<std::uint16_t>{2, 0, 8}));
  injector->clear();
  inject(fault::wkc_offset(+2));
  EXPECT_EQ(brd_wkc(), 5);
  injector->clear();
  inject(fault::wkc_offset(-100));
  EXPECT_EQ(brd_wkc(), 0);
}

TEST_F(FaultsTest, CommandWkcOffsetTouchesOnlyThatCommand) {
  inject(fault::command_wkc_offset(Command::lrw, -3));
  auto r = send({{Command::brd, fp(0, reg::kType), {0}}, {Command::lrw, 0x10000, {0, 0, 0}}});
  EXPECT_EQ(r.wkc, (std::vector<std::uint16_t>{3, 6}));
  EXPECT_EQ(injector->info(now).command_wkc_offsets.at("LRW"), -3);
}

TEST_F(FaultsTest, LogicalWkcOffsetChangesOneSlavesShareOnly) {
  inject(fault::logical_wkc_offset("b", -1));
  // LRW: each read-write FMMU adds 3; b's 3 becomes 2. Register access stays healthy.
  auto r = send({{Command::lrw, 0x10000, {0, 0, 0}},
                 {Command::fprd, fp(0x1002, reg::kAlStatus), {0, 0}},
                 {Command::lrw, 0x10000, {0}}});  // covers only a's byte
  EXPECT_EQ(r.wkc, (std::vector<std::uint16_t>{8, 1, 3}));
  injector->clear();
  inject(fault::logical_wkc_offset("b", -10));  // b's share cannot go below 0
  EXPECT_EQ(lrw().wkc.at(0), 6);
  EXPECT_EQ(injector->info(now).logical_wkc_offsets.at("b"), -10);
}

TEST_F(FaultsTest, DisconnectCutsTheSlaveOffAndOutOfAutoIncrement) {
  inject(fault::disconnect("b"));
  auto r = send({{Command::brd, fp(0, reg::kType), {0}},
                 {Command::fprd, fp(0x1002, reg::kStationAddress), {0, 0}},
                 {Command::aprd,
                  wire::physical_address(wire::position_adp(1), reg::kStationAddress),
                  {0, 0}}});
  EXPECT_EQ(r.wkc, (std::vector<std::uint16_t>{2, 0, 1}));
  EXPECT_EQ(r.adp.at(0), 2);  // BRD counts the reachable slaves
  // Position 1 is now c: b no longer increments the address.
  EXPECT_EQ(r.data.at(2), le16(0x1003));
  EXPECT_THAT(injector->info(now).disconnected, ElementsAre("b"));
  EXPECT_EQ(describe(fault::next(fault::disconnect("outputs"), 30)),
            "next 30 exchanges disconnect outputs");
}

// ---- Reply faults ---------------------------------------------------------------------------

TEST_F(FaultsTest, ReplyFaultsAlterTheReplyAtTheTransportEdge) {
  auto original = lrw();
  auto reply = original.frame;
  EXPECT_EQ(injector->shape_reply(reply).copies, 1u);

  inject(fault::next(fault::truncate_reply(3), 1));
  auto r = lrw();
  reply = r.frame;
  injector->shape_reply(reply);
  EXPECT_EQ(reply.size(), r.frame.size() - 3);
  EXPECT_FALSE(wire::decode_frame(reply));

  inject(fault::next(fault::unsupported_type(), 1));
  r = lrw();
  reply = r.frame;
  injector->shape_reply(reply);
  auto decoded = wire::decode_frame(reply);
  ASSERT_FALSE(decoded);
  EXPECT_EQ(decoded.error.code, wire::DecodeErrc::unsupported_frame_type);

  inject(fault::next(fault::wrong_index(), 1));
  r = lrw();
  reply = r.frame;
  injector->shape_reply(reply);
  EXPECT_EQ(reply[3], static_cast<std::uint8_t>(r.frame[3] + 1));

  inject(fault::next(fault::corrupt_byte(12, 0x0F), 1));
  r = lrw();
  reply = r.frame;
  injector->shape_reply(reply);
  EXPECT_EQ(reply[12], r.frame[12] ^ 0x0F);
  reply[12] ^= 0x0F;
  EXPECT_EQ(reply, r.frame);

  inject(fault::next(fault::duplicate_reply(), 1));
  r = lrw();
  reply = r.frame;
  EXPECT_EQ(injector->shape_reply(reply).copies, 2u);
  EXPECT_EQ(reply, r.frame);

  inject(fault::next(fault::reorder_replies(), 1));
  r = lrw();
  reply = r.frame;
  EXPECT_TRUE(injector->shape_reply(reply).hold);

  inject(fault::next(fault::delay_replies(5ms), 1));
  r = lrw();
  reply = r.frame;
  EXPECT_EQ(injector->shape_reply(reply).delay, 5ms);

  // Healthy again.
  r = lrw();
  reply = r.frame;
  const auto plan = injector->shape_reply(reply);
  EXPECT_EQ(plan.copies, 1u);
  EXPECT_FALSE(plan.hold);
  EXPECT_EQ(plan.delay, 0ns);
  EXPECT_EQ(injector->stats().replies_altered, 7u);
}

TEST_F(FaultsTest, ReplayPreviousSendsTheLastOriginalReply) {
  auto first = send({{Command::brd, fp(0, reg::kType), {0}}});
  auto reply = first.frame;
  injector->shape_reply(reply);
  inject(fault::next(fault::replay_previous(), 1));
  auto second = lrw();
  reply = second.frame;
  injector->shape_reply(reply);
  EXPECT_EQ(reply, first.frame);
  // The one after replays nothing: it gets its own reply, and the second's is remembered.
  auto third = lrw();
  reply = third.frame;
  injector->shape_reply(reply);
  EXPECT_EQ(reply, third.frame);
}

// ---- B. Slave faults ------------------------------------------------------------------------

TEST_F(FaultsTest, RetreatToSafeopLeavesOpWithoutError) {
  to_op(0x1002);
  inject(fault::retreat_to_safeop("b"));
  EXPECT_EQ(segment.esc(1).al_state(), wire::AlState::safeop);
  EXPECT_FALSE(segment.esc(1).al_error());
  // Below OP it changes nothing.
  inject(fault::retreat_to_safeop("a"));
  EXPECT_EQ(segment.esc(0).al_state(), wire::AlState::init);
}

TEST_F(FaultsTest, PowerCycleResetsStationAndState) {
  to_op(0x1003);
  inject(fault::power_cycle("c"));
  EXPECT_EQ(segment.esc(2).station_address(), 0);
  EXPECT_EQ(segment.esc(2).al_state(), wire::AlState::init);
  EXPECT_FALSE(segment.esc(2).fmmu(0).active);
  // The FMMU is gone: c no longer answers the LRW.
  EXPECT_EQ(lrw().wkc.at(0), 6);
}

TEST_F(FaultsTest, LatchedAlErrorKeepsStateUntilClear) {
  to_op(0x1001);
  inject(fault::latch_al_error("a", 0x001D));
  auto r = send({{Command::fprd, fp(0x1001, reg::kAlStatus), {0, 0, 0, 0, 0, 0}}});
  EXPECT_EQ(r.data.at(0)[0], 0x18);  // OP + error
  EXPECT_EQ(wire::load_le16(r.data.at(0).data() + 4), 0x001D);
  EXPECT_THAT(injector->info(now).active, ElementsAre("latch AL error 0x001D on a"));
  injector->clear();
  EXPECT_FALSE(segment.esc(0).al_error());
  EXPECT_EQ(segment.esc(0).al_status_code(), 0);
  EXPECT_EQ(segment.esc(0).al_state(), wire::AlState::op);
}

// A slave whose firmware refuses a state: the request leaves it where it was with the error bit
// and the code; other states are still taken; clear() lifts the refusal, a power cycle too.
TEST_F(FaultsTest, RefusedStateKeepsTheSlaveWhereItWasUntilClear) {
  request_state(0x1002, wire::AlState::preop);
  inject(fault::refuse_state("b", wire::AlState::safeop, 0x001D));
  EXPECT_THAT(injector->info(now).active, ElementsAre("refuse SAFEOP on b with AL status 0x001D"));
  request_state(0x1002, wire::AlState::safeop);
  auto r = send({{Command::fprd, fp(0x1002, reg::kAlStatus), {0, 0, 0, 0, 0, 0}}});
  EXPECT_EQ(r.data.at(0)[0], 0x12);  // PREOP + error
  EXPECT_EQ(wire::load_le16(r.data.at(0).data() + 4), 0x001D);
  // Acknowledged and asked again: refused again (the firmware still refuses).
  send({{Command::fpwr, fp(0x1002, reg::kAlControl),
         le16(wire::encode_al_control(wire::AlState::safeop, true))}});
  EXPECT_EQ(segment.esc(1).al_state(), wire::AlState::preop);
  EXPECT_TRUE(segment.esc(1).al_error());
  EXPECT_EQ(segment.esc(1).al_status_code(), 0x001D);
  // Other slaves and other states are not affected.
  to_op(0x1001);
  request_state(0x1002, wire::AlState::init);
  EXPECT_EQ(segment.esc(1).al_state(), wire::AlState::init);
  injector->clear();
  EXPECT_THAT(injector->info(now).active, ElementsAre());
  send({{Command::fpwr, fp(0x1002, reg::kAlControl),
         le16(wire::encode_al_control(wire::AlState::init, true))}});
  EXPECT_FALSE(segment.esc(1).al_error());
  to_op(0x1002);
  // Lifted by a power cycle as well (the firmware restarts).
  inject(fault::refuse_state("c", wire::AlState::preop, 0x0016));
  request_state(0x1003, wire::AlState::preop);
  EXPECT_EQ(segment.esc(2).al_state(), wire::AlState::init);
  inject(fault::power_cycle("c"));
  EXPECT_FALSE(segment.esc(2).al_refusal(wire::AlState::preop).has_value());
  EXPECT_THAT(injector->info(now).active, ElementsAre());
}

TEST_F(FaultsTest, DcJumpStepsTheLocalClock) {
  DcUnit* dc = segment.esc(0).dc();
  ASSERT_NE(dc, nullptr);
  segment.advance(now);
  const auto before = dc->local_time(now);
  inject(fault::dc_jump("a", 1500ns));
  EXPECT_EQ(dc->local_time(now) - before, 1500u);
}

TEST_F(FaultsTest, MailboxFaultsNeedACoeServer) {
  auto r = injector->inject(fault::mailbox_abort("a", 0x2000, 1, 0x06010002), now);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "mailbox_abort: slave 'a' has no CoE mailbox");
  r = injector->inject(
      fault::after_milestone(fault::drop_responses(),
                             fault::mailbox_step("a", MailboxStage::upload_init, 1)),
      now);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "mailbox_step: slave 'a' has no CoE mailbox");
}

// ---- Segment faults -------------------------------------------------------------------------

TEST_F(FaultsTest, LinkDownCutsTheSlavesBehindThePort) {
  inject(fault::link_down("a", 1));
  EXPECT_EQ(brd_wkc(), 1);
  EXPECT_FALSE(segment.link(1, 0));
  EXPECT_THAT(injector->info(now).links_down, ElementsAre("a:1"));
  inject(fault::link_up("a", 1));
  EXPECT_EQ(brd_wkc(), 3);
  inject(fault::link_down("b", 1));
  EXPECT_EQ(brd_wkc(), 2);
  injector->clear();  // brings the link back
  EXPECT_EQ(brd_wkc(), 3);
}

TEST_F(FaultsTest, MasterLinkDownLosesEveryFrame) {
  inject(fault::master_link_down());
  EXPECT_FALSE(lrw().returned);
  EXPECT_THAT(injector->info(now).links_down, ElementsAre("master"));
  inject(fault::master_link_up());
  EXPECT_TRUE(lrw().returned);
  inject(fault::master_link_down());
  injector->clear();
  EXPECT_TRUE(lrw().returned);
}

// ---- C. Scheduling --------------------------------------------------------------------------

TEST_F(FaultsTest, AfterDelayFiresAtSegmentTime) {
  const std::int64_t start = now;
  inject(fault::after(fault::next(fault::drop_responses(), 2), 5ms));
  auto info = injector->info(now);
  ASSERT_EQ(info.scheduled.size(), 1u);
  EXPECT_EQ(info.scheduled[0].description, "after 5 ms: next 2 exchanges drop responses");
  EXPECT_EQ(info.scheduled[0].due_in_ns, 5 * kMs);
  EXPECT_EQ(injector->next_due_ns(), start + 5 * kMs);
  EXPECT_TRUE(lrw().returned);  // +1 ms
  EXPECT_TRUE(lrw().returned);  // +2 ms
  EXPECT_EQ(injector->info(now).scheduled.at(0).due_in_ns, 3 * kMs);
  injector->advance(now + 3 * kMs);  // an idle server advances the injector
  EXPECT_TRUE(injector->info(now).scheduled.empty());
  now += 3 * kMs;
  EXPECT_FALSE(lrw().returned);
  EXPECT_FALSE(lrw().returned);
  EXPECT_TRUE(lrw().returned);
}

TEST_F(FaultsTest, AfterMilestoneCountsHealthyExchangesOnly) {
  inject(fault::after_milestone(fault::drop_responses(), fault::healthy_exchanges(3)));
  inject(fault::next(fault::wkc_offset(-1), 1));  // an exchange a fault touched: not healthy
  EXPECT_EQ(brd_wkc(), 2);
  auto info = injector->info(now);
  ASSERT_EQ(info.scheduled.size(), 1u);
  EXPECT_EQ(info.scheduled[0].waiting_on, "3 healthy exchanges");
  EXPECT_EQ(info.scheduled[0].remaining, 3u);
  // A datagram nobody answers makes the exchange unhealthy too.
  send({{Command::fprd, fp(0x7777, reg::kType), {0}}});
  EXPECT_EQ(injector->info(now).scheduled.at(0).remaining, 3u);
  EXPECT_TRUE(lrw().returned);
  EXPECT_TRUE(lrw().returned);
  EXPECT_EQ(injector->info(now).scheduled.at(0).remaining, 1u);
  EXPECT_TRUE(lrw().returned);  // the third: the drop is armed after it
  EXPECT_FALSE(lrw().returned);
  EXPECT_FALSE(lrw().returned);  // sticky
  EXPECT_EQ(injector->stats().healthy_exchanges, 3u);
}

TEST_F(FaultsTest, HealthyPollsMilestoneCountsOpStatusReadsOfThatSlave) {
  to_op(0x1002);
  inject(fault::after_milestone(fault::disconnect("c"), fault::healthy_polls("b", 2)));
  poll_al_status(0x1001);  // a is in INIT: not a healthy poll of b either
  EXPECT_EQ(injector->info(now).scheduled.at(0).remaining, 2u);
  poll_al_status(0x1002);
  EXPECT_EQ(injector->info(now).scheduled.at(0).remaining, 1u);
  EXPECT_EQ(brd_wkc(), 3);
  poll_al_status(0x1002);
  EXPECT_TRUE(injector->info(now).scheduled.empty());
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_EQ(describe(fault::healthy_polls("b", 2)), "2 healthy polls of b");
}

TEST_F(FaultsTest, ScriptRunsStepsInExchangeOrder) {
  inject(fault::script(
      {fault::drop_responses(), fault::wkc_offset(-1), fault::latch_al_error("a", 0x0011),
       fault::wait_for(fault::healthy_exchanges(2)), fault::next(fault::disconnect("b"), 2)}));
  EXPECT_FALSE(segment.esc(0).al_error());
  EXPECT_FALSE(lrw().returned);  // step 1: one exchange
  EXPECT_FALSE(segment.esc(0).al_error());
  EXPECT_EQ(brd_wkc(), 2);  // step 2: one exchange; then the latch applies
  EXPECT_TRUE(segment.esc(0).al_error());
  EXPECT_EQ(segment.esc(0).al_status_code(), 0x0011);
  auto info = injector->info(now);
  ASSERT_EQ(info.scheduled.size(), 1u);
  EXPECT_EQ(info.scheduled[0].waiting_on, "2 healthy exchanges");
  EXPECT_EQ(info.scheduled[0].step, 4u);
  EXPECT_EQ(brd_wkc(), 3);
  EXPECT_EQ(brd_wkc(), 3);  // second healthy exchange: disconnect armed
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_EQ(brd_wkc(), 3);
  EXPECT_TRUE(injector->info(now).scheduled.empty());
}

TEST_F(FaultsTest, ScriptWaitPausesForSegmentTime) {
  inject(fault::script({fault::wait(3ms), fault::drop_responses()}));
  EXPECT_TRUE(lrw().returned);   // +1 ms
  EXPECT_TRUE(lrw().returned);   // +2 ms
  EXPECT_FALSE(lrw().returned);  // +3 ms: due as this exchange starts
  EXPECT_TRUE(lrw().returned);   // a script step is one exchange, not sticky
}

TEST_F(FaultsTest, NestedSchedulingComposes) {
  // disconnect b for 2 exchanges, 2 ms after 1 healthy exchange.
  inject(fault::after_milestone(fault::after(fault::next(fault::disconnect("b"), 2), 2ms),
                                fault::healthy_exchanges(1)));
  EXPECT_EQ(
      describe(fault::after_milestone(fault::after(fault::next(fault::disconnect("b"), 2), 2ms),
                                      fault::healthy_exchanges(1))),
      "after 1 healthy exchange: after 2 ms: next 2 exchanges disconnect b");
  EXPECT_EQ(brd_wkc(), 3);  // healthy: the 2 ms start now
  EXPECT_EQ(injector->info(now).scheduled.at(0).due_in_ns, 2 * kMs);
  EXPECT_EQ(brd_wkc(), 3);  // +1 ms
  EXPECT_EQ(brd_wkc(), 2);  // +2 ms: due, fires before this exchange
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_EQ(brd_wkc(), 3);
}

TEST_F(FaultsTest, ClearRemovesEverythingScheduled) {
  inject(fault::after(fault::drop_responses(), 1ms));
  inject(fault::script({fault::wait_for(fault::healthy_exchanges(5)), fault::drop_responses()}));
  inject(fault::next(fault::wkc_offset(1), 10));
  inject(fault::disconnect("a"));
  EXPECT_EQ(injector->info(now).scheduled.size(), 2u);
  injector->clear();
  const auto info = injector->info(now);
  EXPECT_TRUE(info.scheduled.empty());
  EXPECT_TRUE(info.queued.empty());
  EXPECT_TRUE(info.active.empty());
  EXPECT_FALSE(injector->next_due_ns().has_value());
  for (int i = 0; i < 8; ++i)
    EXPECT_EQ(brd_wkc(), 3);
}

TEST_F(FaultsTest, InjectRejectsUnknownSlavesAndChangesNothing) {
  auto r = injector->inject(fault::script({fault::drop_responses(), fault::disconnect("zz")}), now);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
  EXPECT_EQ(r.error().message(), "unknown slave 'zz' (known: a, b, c)");
  EXPECT_TRUE(injector->info(now).scheduled.empty());
  EXPECT_TRUE(lrw().returned);
}

TEST_F(FaultsTest, HotPlugAndUnplugAGroupAndNameUnknownOnes) {
  auto r = injector->inject(fault::hot_unplug("tail"), now);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "hot_unplug: unknown hot-connect group 'tail' (known: none)");
  ASSERT_TRUE(segment.add_hot_connect_group("tail", 2).ok());
  r = injector->inject(fault::script({fault::drop_responses(), fault::hot_plug("nope")}), now);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::not_found);
  EXPECT_EQ(r.error().message(), "hot_plug: unknown hot-connect group 'nope' (known: tail)");
  EXPECT_TRUE(injector->info(now).scheduled.empty());
  EXPECT_EQ(brd_wkc(), 3);
  inject(fault::hot_unplug("tail"));
  EXPECT_EQ(brd_wkc(), 2);
  EXPECT_FALSE(segment.hot_connect_groups().at(0).plugged);
  inject(fault::hot_plug("tail"));
  EXPECT_EQ(brd_wkc(), 3);
  EXPECT_TRUE(segment.hot_connect_groups().at(0).plugged);
  // Plugged in afresh: the group's slave lost its station address.
  EXPECT_TRUE(send({{Command::fprd, fp(0x1003, reg::kStationAddress), {0, 0}}}).wkc ==
              std::vector<std::uint16_t>{0});
  EXPECT_TRUE(send({{Command::fprd, fp(0x1002, reg::kStationAddress), {0, 0}}}).wkc ==
              std::vector<std::uint16_t>{1});
}

// ---- Structure, descriptions and the text forms ------------------------------------------------

TEST(FaultForms, ValidateRejectsMisplacedForms) {
  auto r = validate(fault::next(fault::power_cycle("a"), 3));
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.error().message(), HasSubstr("'next' applies only to exchange and reply faults"));
  r = validate(fault::wait(1ms));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(), "wait and wait_for are only valid inside a script");
  r = validate(fault::mailbox_protocol_fault("m", 0x2000, 1, MailboxStage::upload_init,
                                             {ProtocolFaultKind::toggle_mismatch, 0}));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().message(),
            "mailbox_protocol_fault: toggle_mismatch cannot apply at stage upload_init");
  EXPECT_FALSE(validate(fault::unsupported_type(1)).ok());
  EXPECT_FALSE(validate(fault::script({})).ok());
  EXPECT_FALSE(
      validate(fault::after_milestone(fault::drop_responses(), fault::healthy_exchanges(0))).ok());
  EXPECT_TRUE(validate(fault::script({fault::wait(1ms), fault::power_cycle("a")})).ok());
}

TEST(FaultForms, Descriptions) {
  EXPECT_EQ(describe(fault::mailbox_abort("mbx", 0x2000, 1, 0x06010002)),
            "mailbox abort 0x06010002 on mbx 0x2000:01 at request");
  EXPECT_EQ(describe(fault::mailbox_protocol_fault("mbx", 0x2003, 1, MailboxStage::upload_init,
                                                   {ProtocolFaultKind::sdo_command, 0x60})),
            "mailbox protocol fault sdo_command=0x60 on mbx 0x2003:01 at upload_init");
  EXPECT_EQ(describe(fault::next(fault::drop_responses(), 1)), "next exchange drop responses");
  EXPECT_EQ(describe(fault::command_wkc_offset(Command::lrw, -1)), "LRW WKC offset -1");
  EXPECT_EQ(describe(fault::wkc_offset(2)), "WKC offset +2");
  EXPECT_EQ(describe(fault::logical_wkc_offset("io", -1)), "logical WKC offset -1 for io");
  EXPECT_EQ(describe(fault::truncate_reply()), "truncate replies by 1 byte");
  EXPECT_EQ(describe(fault::delay_replies(2500us)), "delay replies by 2500 us");
  EXPECT_EQ(describe(fault::dc_jump("d", -40ns)), "DC clock jump -40 ns on d");
  EXPECT_EQ(describe(fault::link_down("x", 2)), "link down on x port 2");
  EXPECT_EQ(describe(fault::script(
                {fault::drop_responses(),
                 fault::wait_for(fault::mailbox_step("m", MailboxStage::upload_segment, 2)),
                 fault::power_cycle("m")})),
            "script: drop responses; wait for 2 mailbox upload_segment steps of m; power cycle m");
}

std::vector<Fault> every_kind() {
  return {
      fault::drop_responses(),
      fault::wkc_offset(-3),
      fault::command_wkc_offset(Command::fprd, 2),
      fault::logical_wkc_offset("io", -1),
      fault::disconnect("io"),
      fault::truncate_reply(4),
      fault::unsupported_type(5),
      fault::wrong_index(),
      fault::replay_previous(),
      fault::corrupt_byte(20, 0x81),
      fault::duplicate_reply(),
      fault::reorder_replies(),
      fault::delay_replies(1500us),
      fault::retreat_to_safeop("io"),
      fault::power_cycle("io"),
      fault::latch_al_error("io", 0x001B),
      fault::refuse_state("io", wire::AlState::safeop, 0x001D),
      fault::mailbox_abort("m", 0x2002, 3, 0x06020000, MailboxStage::upload_segment),
      fault::mailbox_protocol_fault("m", 0x2000, 1, MailboxStage::download_segment,
                                    {ProtocolFaultKind::segment_command, 0x20}),
      fault::dc_jump("d", 123456ns),
      fault::foe_fault("fw", FoeFaultMode::error, 3, 0x800B),
      fault::soe_fault("drive", SoeFaultKind::drop_fragment, 17, 2),
      fault::eoe_fault("net", EoeFaultKind::corrupt_fragment_offset, 1),
      fault::voe_fault("mbx", HandlerFaultKind::garble_reply),
      fault::link_down("io", 1),
      fault::link_up("io", 2),
      fault::master_link_down(),
      fault::master_link_up(),
      fault::ring_break(2),
      fault::ring_cut(wire::RedundantPort::secondary),
      fault::ring_heal(),
      fault::port_delay(wire::RedundantPort::primary, 250us, wire::RedundantPort::secondary),
      fault::hot_plug("tail"),
      fault::hot_unplug("tail"),
  };
}

TEST(FaultForms, JsonRoundTripsEveryKindAndForm) {
  auto kinds = every_kind();
  ASSERT_EQ(kinds.size(), kFaultKindCount);
  std::vector<Fault> all = kinds;
  all.push_back(fault::next(fault::disconnect("io"), 30));
  all.push_back(fault::after(fault::next(fault::drop_responses(), 2), 250ms));
  all.push_back(fault::after_milestone(fault::power_cycle("io"), fault::healthy_polls("io", 4)));
  all.push_back(
      fault::script({fault::drop_responses(), fault::wait(2ms),
                     fault::wait_for(fault::mailbox_step("m", MailboxStage::download_init, 1)),
                     fault::after(fault::wkc_offset(1), 1ms)}));
  // Every mode of the mailbox protocol kinds, with and without their optional keys.
  for (auto mode : {FoeFaultMode::busy, FoeFaultMode::drop_reply, FoeFaultMode::wrong_packet,
                    FoeFaultMode::wrong_password}) {
    all.push_back(fault::foe_fault("fw", mode, 2, mode == FoeFaultMode::busy ? 4 : 0));
  }
  all.push_back(fault::soe_fault("drive", SoeFaultKind::error_response, 0x8001, 0x7004, 1, true));
  all.push_back(fault::soe_fault("drive", SoeFaultKind::drop_response, 32, 0));
  for (auto mode : {EoeFaultKind::drop_reply_fragment, EoeFaultKind::drop_request_fragment,
                    EoeFaultKind::drop_reply}) {
    auto f = fault::eoe_fault("net", mode, mode == EoeFaultKind::drop_reply ? 0 : 2);
    f.effect.once = false;
    all.push_back(f);
  }
  all.push_back(fault::after_milestone(fault::voe_fault("mbx", HandlerFaultKind::drop_reply),
                                       fault::healthy_exchanges(5)));
  for (const auto& f : all) {
    const std::string json = to_json(f);
    auto parsed = parse_fault_json(json);
    ASSERT_TRUE(parsed.ok()) << json << ": " << parsed.error().describe();
    EXPECT_EQ(to_json(*parsed), json);
    EXPECT_EQ(describe(*parsed), describe(f));
  }
  EXPECT_EQ(to_json(fault::next(fault::disconnect("outputs"), 30)),
            R"({"kind":"disconnect","slave":"outputs","next":30})");
  EXPECT_EQ(to_json(fault::mailbox_abort("mbx", 0x2000, 1, 0x06010002)),
            R"({"kind":"mailbox_abort","slave":"mbx","index":"0x2000","subindex":1,)"
            R"("stage":"request","code":"0x06010002"})");
  EXPECT_EQ(to_json(fault::refuse_state("outputs", wire::AlState::op, 0x001B)),
            R"({"kind":"refuse_state","slave":"outputs","state":"op","code":"0x001B"})");
  // Delays: whole milliseconds as integers, fractions exactly.
  EXPECT_EQ(to_json(fault::after(fault::delay_replies(1500us), 250ms)),
            R"({"after_ms":250,"fault":{"kind":"delay_replies","ms":1.5}})");
  EXPECT_EQ(to_json(fault::script({fault::wait(1234567ns), fault::power_cycle("a")})),
            R"({"script":[{"wait_ms":1.234567},{"kind":"power_cycle","slave":"a"}]})");
  EXPECT_EQ(to_json(fault::foe_fault("fw", FoeFaultMode::error, 3, 0x800B)),
            R"({"kind":"foe_fault","slave":"fw","mode":"error","packet":3,"value":"0x800B"})");
  EXPECT_EQ(to_json(fault::soe_fault("drive", SoeFaultKind::drop_fragment, 17, 2)),
            R"({"kind":"soe_fault","slave":"drive","mode":"drop_fragment","idn":17,"value":2,)"
            R"("drive":0,"write":false})");
  EXPECT_EQ(to_json(fault::port_delay(wire::RedundantPort::primary, 250us,
                                      wire::RedundantPort::secondary)),
            R"({"kind":"port_delay","port":"primary","ms":0.25,"from":"secondary"})");
  EXPECT_EQ(to_json(fault::ring_break(2)), R"({"kind":"ring_break","after":2})");
  EXPECT_EQ(to_json(fault::hot_unplug("tail")), R"({"kind":"hot_unplug","group":"tail"})");
  EXPECT_EQ(describe(fault::after(fault::hot_plug("tail"), 250ms)), "after 250 ms: hot plug tail");
  const std::vector<std::string> words{"hot_plug", "tail"};
  auto plug = parse_fault_words(words);
  ASSERT_TRUE(plug.ok()) << plug.error().describe();
  EXPECT_EQ(to_json(*plug), R"({"kind":"hot_plug","group":"tail"})");
  const std::vector<std::string> none{"hot_plug"};
  EXPECT_EQ(parse_fault_words(none).error().message(),
            "hot_plug: expected 1 argument, got 0 (usage: hot_plug GROUP)");
  EXPECT_THAT(parse_fault_json(R"({"kind":"hot_unplug"})").error().message(), HasSubstr("group"));
  EXPECT_THAT(parse_fault_json(R"({"kind":"hot_unplug","group":""})").error().message(),
              HasSubstr("empty group name"));
  EXPECT_EQ(describe(fault::ring_cut(wire::RedundantPort::secondary)),
            "ring cut at the master's secondary port");
  EXPECT_EQ(to_json(fault::voe_fault("mbx", HandlerFaultKind::garble_reply)),
            R"({"kind":"voe_fault","slave":"mbx","mode":"garble_reply"})");
  // Names are escaped (the control channel's clients parse this).
  EXPECT_EQ(to_json(fault::disconnect("a\"b")), R"({"kind":"disconnect","slave":"a\"b"})");
}

TEST(FaultForms, JsonErrorsNameTheKeyPath) {
  const auto message = [](std::string_view json) {
    auto r = parse_fault_json(json);
    EXPECT_FALSE(r.ok()) << json;
    return r.ok() ? std::string() : r.error().message();
  };
  EXPECT_THAT(message(R"({"kind":"explode"})"),
              HasSubstr("fault.kind: unknown fault kind 'explode' (known: drop_responses,"));
  EXPECT_EQ(message(R"({"kind":"disconnect"})"), "fault: missing key 'slave'");
  EXPECT_THAT(message(R"({"kind":"disconnect","slave":"a","colour":1})"),
              HasSubstr("fault.colour: unknown key (known: kind, next, slave)"));
  EXPECT_EQ(message(R"({"kind":"wkc_offset","delta":"x"})"),
            "fault.delta: 'x' is not an integer (decimal or 0x hex)");
  EXPECT_EQ(message(R"({"kind":"link_down","slave":"a","port":7})"),
            "fault.port: 7 is out of range (0 to 3)");
  EXPECT_EQ(message(R"({"kind":"power_cycle","slave":"a","next":2})"),
            "fault.next: unknown key (known: kind, slave)");
  EXPECT_EQ(message(R"({"script":[{"kind":"drop_responses"},{"wait_for":{"milestone":"x"}}]})"),
            "fault.script[1].wait_for.milestone: unknown milestone 'x' (known: "
            "healthy_exchanges, healthy_polls, mailbox_step)");
  EXPECT_EQ(message(R"({"wait_ms":5})"), "fault.wait_ms: only valid as a script step");
  EXPECT_EQ(message(R"({"after_ms":5,"script":[]})"),
            "fault: 'after_ms' and 'script' cannot be combined: one fault form per mapping");
  EXPECT_EQ(message(R"({"kind":"mailbox_protocol_fault","slave":"m","index":1,"subindex":0,)"
                    R"("stage":"upload_init","protocol":"invalid_segment_padding"})"),
            "fault.stage: invalid_segment_padding cannot apply at stage upload_init");
  EXPECT_THAT(message(R"({"kind":)"), HasSubstr("invalid JSON at byte 8"));
  // The mailbox protocol kinds name the key that is wrong.
  EXPECT_EQ(message(R"({"kind":"foe_fault","slave":"f","mode":"explode"})"),
            "fault.mode: unknown mode 'explode' (known: error, busy, drop_reply, wrong_packet, "
            "wrong_password)");
  EXPECT_EQ(message(R"({"kind":"foe_fault","slave":"f"})"), "fault: missing key 'mode'");
  EXPECT_EQ(message(R"({"kind":"foe_fault","slave":"f","mode":"busy","value":0})"),
            "fault.value: 0 is out of range (1 to 65535)");
  EXPECT_EQ(message(R"({"kind":"foe_fault","slave":"f","mode":"drop_reply","value":1})"),
            "fault.value: drop_reply takes no value");
  EXPECT_EQ(message(R"({"kind":"foe_fault","slave":"f","mode":"error","packet":-1})"),
            "fault.packet: -1 is out of range (0 to 4294967295)");
  EXPECT_EQ(message(R"({"kind":"soe_fault","slave":"d","mode":"error_response","value":1})"),
            "fault: missing key 'idn'");
  EXPECT_EQ(message(R"({"kind":"soe_fault","slave":"d","mode":"drop_fragment","idn":17,)"
                    R"("value":0})"),
            "fault.value: 0 is out of range (1 to 65535)");
  EXPECT_EQ(message(R"({"kind":"soe_fault","slave":"d","mode":"drop_response","idn":1,)"
                    R"("drive":8})"),
            "fault.drive: 8 is out of range (0 to 7)");
  EXPECT_EQ(message(R"({"kind":"soe_fault","slave":"d","mode":"drop_response","idn":1,)"
                    R"("write":"yes"})"),
            "fault.write: expected true or false, found 'yes'");
  EXPECT_EQ(message(R"({"kind":"eoe_fault","slave":"n","mode":"corrupt_fragment_offset"})"),
            "fault: missing key 'value'");
  EXPECT_EQ(message(R"({"kind":"eoe_fault","slave":"n","mode":"drop_reply_fragment",)"
                    R"("value":64})"),
            "fault.value: 64 is out of range (0 to 63)");
  EXPECT_EQ(message(R"({"kind":"voe_fault","slave":"m","mode":"garble_reply","value":1})"),
            "fault.value: unknown key (known: kind, slave, mode, once)");
  EXPECT_EQ(message(R"({"kind":"voe_fault","slave":"m","mode":"drop_reply","once":2})"),
            "fault.once: expected true or false, found '2'");
  EXPECT_EQ(message(R"(["drop_responses"])"), "fault: expected a fault (a mapping), found a list");
}

TEST(FaultForms, CommandLineWords) {
  const auto parse = [](std::vector<std::string> words) { return parse_fault_words(words); };
  auto f = parse({"disconnect", "outputs"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(describe(*f), "disconnect outputs");
  f = parse({"mailbox_abort", "mbx", "0x2000:1", "0x06010002", "upload_segment"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(describe(*f), "mailbox abort 0x06010002 on mbx 0x2000:01 at upload_segment");
  f = parse({"mailbox_protocol_fault", "mbx", "0x2003:1", "upload_init", "sdo_command=0x60"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(f->effect.protocol, (ProtocolFault{ProtocolFaultKind::sdo_command, 0x60}));
  f = parse({"corrupt_byte"});
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->effect.offset, 12u);
  f = parse({"delay_replies", "2.5"});
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->effect.ns, 2'500'000);
  f = parse({"command_wkc_offset", "lrw", "-1"});
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->effect.command, Command::lrw);

  f = parse({"disconnect"});
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.error().message(),
            "disconnect: expected 1 argument, got 0 (usage: disconnect SLAVE)");
  f = parse({"mailbox_abort", "m", "0x2000", "1"});
  ASSERT_FALSE(f.ok());
  EXPECT_THAT(f.error().message(), HasSubstr("'0x2000' is not INDEX:SUB"));
  f = parse({"refuse_state", "outputs", "SAFEOP", "0x001D"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(f->effect.state, wire::AlState::safeop);
  EXPECT_EQ(describe(*f), "refuse SAFEOP on outputs with AL status 0x001D");
  f = parse({"refuse_state", "outputs", "running", "0x001D"});
  ASSERT_FALSE(f.ok());
  EXPECT_THAT(f.error().message(), HasSubstr("refuse_state.state: unknown AL state 'running'"));
  f = parse({"refuse_state", "outputs", "op", "0"});
  ASSERT_FALSE(f.ok());
  EXPECT_THAT(f.error().message(), HasSubstr("refuse_state.code: 0 is out of range (1 to 65535)"));
  f = parse({"latch_al_error", "a", "0x10000"});
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.error().message(),
            "latch_al_error.code: 0x10000 is out of range (0 to 65535) (usage: latch_al_error "
            "SLAVE CODE)");
  f = parse({"foe_fault", "fw", "busy", "2", "3"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(describe(*f), "FoE busy x3 on fw after 2 packets");
  f = parse({"soe_fault", "drive", "error_response", "47", "0x7004"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(describe(*f), "SoE error 0x7004 on drive drive 0 IDN 47 (once)");
  f = parse({"eoe_fault", "net", "drop_reply"});
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(f->effect.eoe, EoeFaultKind::drop_reply);
  f = parse({"voe_fault", "mbx"});
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.error().message(),
            "voe_fault: expected 2 arguments, got 1 (usage: voe_fault SLAVE MODE)");
  f = parse({"nonsense"});
  ASSERT_FALSE(f.ok());
  EXPECT_THAT(f.error().message(), HasSubstr("unknown fault kind 'nonsense'"));
}

// The keys a JSON/YAML effect takes and the command-line arguments come from one table: every
// argument of `ecat sim fault kinds` is a key (INDEX:SUB two, KIND[=VALUE] two).
TEST(FaultForms, KeysAndWordsFollowTheArgumentTable) {
  const auto message = [](std::string_view json) {
    auto r = parse_fault_json(json);
    EXPECT_FALSE(r.ok()) << json;
    return r.ok() ? std::string() : r.error().message();
  };
  EXPECT_EQ(message(R"({"kind":"mailbox_abort","slave":"a","index":1,"code":1,"x":1})"),
            "fault.x: unknown key (known: kind, slave, index, subindex, code, stage, once)");
  EXPECT_EQ(message(R"({"kind":"mailbox_protocol_fault","slave":"a","x":1})"),
            "fault.x: unknown key (known: kind, slave, index, subindex, stage, protocol, value, "
            "once)");
  EXPECT_EQ(message(R"({"kind":"corrupt_byte","x":1})"),
            "fault.x: unknown key (known: kind, next, offset, mask, port)");
  EXPECT_EQ(message(R"({"kind":"mailbox_protocol_fault","slave":"a","index":1,"subindex":0,)"
                    R"("stage":"upload_init","protocol":"coe_service","value":16})"),
            "fault.value: 16 is out of range (0 to 15)");
  // Words: the same keys filled in order, optional tails left out.
  const std::vector<std::string> words{"mailbox_protocol_fault", "mbx", "0x2000:2", "upload_init",
                                       "sdo_command=0x61"};
  auto f = parse_fault_words(words);
  ASSERT_TRUE(f.ok()) << f.error().describe();
  EXPECT_EQ(f->effect.index, 0x2000);
  EXPECT_EQ(f->effect.subindex, 2);
  EXPECT_EQ(f->effect.protocol.kind, ProtocolFaultKind::sdo_command);
  EXPECT_EQ(f->effect.protocol.value, 0x61);
  const std::vector<std::string> partial{"corrupt_byte", "20"};
  auto c = parse_fault_words(partial);
  ASSERT_TRUE(c.ok()) << c.error().describe();
  EXPECT_EQ(c->effect.offset, 20u);
  EXPECT_EQ(c->effect.mask, 0xFF);
  const std::vector<std::string> no_colon{"mailbox_abort", "mbx", "0x2000", "0x06010002"};
  auto bad = parse_fault_words(no_colon);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message(),
            "mailbox_abort: '0x2000' is not INDEX:SUB (e.g. 0x2000:1) (usage: mailbox_abort SLAVE "
            "INDEX:SUB CODE [STAGE])");
  for (const auto& k : fault_kinds())
    EXPECT_EQ(k.name, to_string(k.kind));
}

TEST(FaultForms, KindTableIsComplete) {
  const auto& kinds = fault_kinds();
  for (std::size_t i = 0; i < kinds.size(); ++i) {
    EXPECT_EQ(static_cast<std::size_t>(kinds[i].kind), i);
    EXPECT_EQ(fault_kind_from_string(to_string(kinds[i].kind)), kinds[i].kind);
    EXPECT_FALSE(kinds[i].summary.empty());
  }
  EXPECT_EQ(fault_class(FaultKind::disconnect), FaultClass::exchange);
  EXPECT_EQ(fault_class(FaultKind::delay_replies), FaultClass::reply);
  EXPECT_EQ(fault_class(FaultKind::dc_jump), FaultClass::slave);
  EXPECT_EQ(fault_class(FaultKind::master_link_up), FaultClass::segment);
}

// ---- With device profiles: mailbox faults need a CoE server -------------------------------------

bool has_profile(const std::string& name) {
  const auto profiles = device_profiles();
  return std::any_of(profiles.begin(), profiles.end(),
                     [&](const DeviceProfileInfo& p) { return p.name == name; });
}

class MailboxFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!has_profile("mailbox")) GTEST_SKIP() << "the mailbox profile is not available yet";
    test::add_device(segment, "mbx", test::profile("mailbox"));
    master = std::make_unique<test::SimMaster>(segment);
    master->assign_stations();
    master->bring_to_preop(0);
    injector = std::make_unique<FaultInjector>(segment);
  }
  void inject(const Fault& f) {
    auto r = injector->inject(f, master->now());
    ASSERT_TRUE(r.ok()) << r.error().describe();
  }
  Segment segment;
  std::unique_ptr<test::SimMaster> master;
  std::unique_ptr<FaultInjector> injector;
};

TEST_F(MailboxFaults, AbortAtRequestHitsOnlyThatObject) {
  inject(fault::mailbox_abort("mbx", 0x2000, 1, 0x06010002));
  EXPECT_EQ(master->upload(0, 0x2000, 1).abort, 0x06010002u);
  EXPECT_EQ(master->upload(0, 0x2000, 2).value, test::Bytes{0});
  EXPECT_EQ(master->upload(0, 0x2000, 1).abort, 0x06010002u);  // sticky
  EXPECT_THAT(injector->info(master->now()).active,
              ElementsAre("mailbox abort 0x06010002 on mbx 0x2000:01 at request"));
  injector->clear();
  EXPECT_EQ(master->upload(0, 0x2000, 1).value, (test::Bytes{0x34, 0x12}));
}

TEST_F(MailboxFaults, AbortAtUploadSegment) {
  inject(fault::mailbox_abort("mbx", 0x2002, 1, 0x06020000, MailboxStage::upload_segment));
  const auto r = master->upload(0, 0x2002, 1);
  EXPECT_EQ(r.abort, 0x06020000u);
  EXPECT_FALSE(r.value.has_value());
  injector->clear();
  EXPECT_EQ(master->upload(0, 0x2002, 1).value->size(), 80u);
}

TEST_F(MailboxFaults, ProtocolFaultsCorruptTheResponse) {
  auto f = fault::mailbox_protocol_fault("mbx", 0x2000, 1, MailboxStage::upload_init,
                                         {ProtocolFaultKind::drop_response, 0});
  f.effect.once = true;
  inject(f);
  EXPECT_FALSE(master->upload(0, 0x2000, 1).value.has_value());              // no response at all
  EXPECT_EQ(master->upload(0, 0x2000, 1).value, (test::Bytes{0x34, 0x12}));  // once only

  inject(fault::mailbox_protocol_fault("mbx", 0x2000, 2, MailboxStage::upload_init,
                                       {ProtocolFaultKind::sdo_command, 0x60}));
  auto request = wire::encode_sdo(wire::SdoInitiateUploadRequest{0x2000, 2, false});
  ASSERT_TRUE(request.ok());
  ASSERT_TRUE(master->write_mailbox(0, wire::MailboxType::coe, *request));
  const auto reply = master->read_mailbox(0);
  ASSERT_TRUE(reply.has_value());
  ASSERT_GE(reply->second.size(), 3u);
  EXPECT_EQ(reply->second[2], 0x60);
}

TEST_F(MailboxFaults, MailboxStepMilestoneAndOnceOnlyScriptSteps) {
  inject(fault::after_milestone(fault::latch_al_error("mbx", 0x0011),
                                fault::mailbox_step("mbx", MailboxStage::upload_init, 2)));
  inject(fault::script({fault::mailbox_protocol_fault("mbx", 0x2001, 1, MailboxStage::request,
                                                      {ProtocolFaultKind::drop_response, 0})}));
  EXPECT_FALSE(master->upload(0, 0x2001, 1).value.has_value());  // the script's step, once
  EXPECT_EQ(master->upload(0, 0x2000, 1).value, (test::Bytes{0x34, 0x12}));
  EXPECT_FALSE(segment.esc(0).al_error());
  EXPECT_EQ(injector->info(master->now()).scheduled.at(0).remaining, 1u);
  EXPECT_EQ(master->upload(0, 0x2001, 1).value->size(), 12u);  // segmented: one upload_init
  EXPECT_TRUE(segment.esc(0).al_error());
  EXPECT_EQ(segment.esc(0).al_status_code(), 0x0011);
}

// The mailbox protocol kinds reach the servers of the devices that have them, and are refused
// for devices that do not.
TEST(ProtocolFaults, RulesReachTheServersAndClearRemovesThem) {
  for (const char* p : {"mailbox", "soe_drive", "eoe_device"}) {
    if (!has_profile(p)) GTEST_SKIP() << "profile " << p << " not available";
  }
  Segment segment;
  test::add_device(segment, "mbx", test::profile("mailbox"));
  test::add_device(segment, "drive", test::profile("soe_drive"));
  test::add_device(segment, "net", test::profile("eoe_device"));
  test::SimMaster master(segment);
  master.assign_stations();
  master.bring_to_preop(0);
  FaultInjector injector(segment);
  const auto inject = [&](const Fault& f) { return injector.inject(f, master.now()); };
  ASSERT_TRUE(inject(fault::foe_fault("mbx", FoeFaultMode::wrong_password)));
  ASSERT_TRUE(inject(fault::foe_fault("mbx", FoeFaultMode::busy, 2, 3)));
  ASSERT_TRUE(inject(fault::soe_fault("drive", SoeFaultKind::error_response, 47, 0x7004)));
  ASSERT_TRUE(inject(fault::eoe_fault("net", EoeFaultKind::corrupt_fragment_offset, 1)));
  ASSERT_TRUE(inject(fault::voe_fault("mbx", HandlerFaultKind::garble_reply)));
  const auto& foe = foe_server_of(segment.esc(0))->faults();
  ASSERT_EQ(foe.size(), 2u);
  EXPECT_EQ(foe[0].kind, FoeFaultKind::error);
  EXPECT_EQ(foe[0].code, 0x800Au) << "wrong_password: FoE error 'no rights'";
  EXPECT_EQ(foe[1].kind, FoeFaultKind::busy);
  EXPECT_EQ(foe[1].after_packets, 2u);
  EXPECT_EQ(foe[1].count, 3u);
  const auto& soe = soe_server_of(segment.esc(1))->faults();
  ASSERT_EQ(soe.size(), 1u);
  EXPECT_EQ(soe[0].idn, 47);
  EXPECT_EQ(soe[0].value, 0x7004);
  EXPECT_TRUE(soe[0].once);
  ASSERT_EQ(eoe_server_of(segment.esc(2))->faults().size(), 1u);
  EXPECT_THAT(injector.info(master.now()).active,
              ::testing::IsSupersetOf({"VoE garble_reply on mbx (once)",
                                       "SoE error 0x7004 on drive drive 0 IDN 47 (once)",
                                       "EoE corrupt_fragment_offset 1 on net (once)"}));

  // VoE: the echo comes back cut to 3 bytes (no VoE header), once; then whole again.
  const std::vector<std::uint8_t> voe{0x02, 0x00, 0x00, 0x00, 0x10, 0x00, 0xAB};
  ASSERT_TRUE(master.write_mailbox(0, wire::MailboxType::voe, voe));
  auto reply = master.read_mailbox(0);
  ASSERT_TRUE(reply.has_value());
  EXPECT_EQ(reply->second.size(), 3u);
  ASSERT_TRUE(master.write_mailbox(0, wire::MailboxType::voe, voe));
  reply = master.read_mailbox(0);
  ASSERT_TRUE(reply.has_value());
  EXPECT_EQ(reply->second.size(), voe.size());

  injector.clear();
  EXPECT_TRUE(foe_server_of(segment.esc(0))->faults().empty());
  EXPECT_TRUE(soe_server_of(segment.esc(1))->faults().empty());
  EXPECT_TRUE(eoe_server_of(segment.esc(2))->faults().empty());

  // A device without the protocol: refused, naming the slave and what it lacks.
  auto refused = inject(fault::foe_fault("drive", FoeFaultMode::drop_reply));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().message(), "foe_fault: slave 'drive' has no FoE");
  refused = inject(fault::soe_fault("mbx", SoeFaultKind::drop_response, 1, 0));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().message(), "soe_fault: slave 'mbx' has no SoE");
  refused = inject(fault::eoe_fault("drive", EoeFaultKind::drop_reply));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().message(), "eoe_fault: slave 'drive' has no EoE");
  refused = inject(fault::voe_fault("net", HandlerFaultKind::drop_reply));
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().message(), "voe_fault: slave 'net' has no VoE");
}

TEST(ProfileFaults, RetreatTakesADigitalOutputTerminalOutOfOp) {
  if (!has_profile("EL2809")) GTEST_SKIP() << "the EL2809 profile is not available yet";
  Segment segment;
  test::add_device(segment, "outputs", test::profile("EL2809"));
  test::SimMaster master(segment);
  master.assign_stations();
  master.bring_to_preop(0);
  master.configure_process_data(0);
  ASSERT_EQ(master.request(0, wire::AlState::safeop).state, wire::AlState::safeop);
  master.lrw();
  ASSERT_EQ(master.request(0, wire::AlState::op).state, wire::AlState::op);
  FaultInjector injector(segment);
  ASSERT_TRUE(injector.inject(fault::retreat_to_safeop("outputs"), master.now()).ok());
  const auto status = master.al_status(0);
  EXPECT_EQ(status.state, wire::AlState::safeop);
  EXPECT_FALSE(status.error);
  EXPECT_EQ(status.code, 0);
  ASSERT_TRUE(injector.inject(fault::latch_al_error("outputs", 0x001B), master.now()).ok());
  EXPECT_EQ(master.al_status(0).code, 0x001B);
  EXPECT_EQ(master.al_status(0).state, wire::AlState::safeop);
}

// A terminal whose ESC mirrors AL control into AL status (device emulation) refuses too: the
// refusal acts before the firmware and the mirror.
TEST(ProfileFaults, RefusedStateHoldsADigitalOutputTerminalInSafeop) {
  if (!has_profile("EL2809")) GTEST_SKIP() << "the EL2809 profile is not available yet";
  Segment segment;
  test::add_device(segment, "outputs", test::profile("EL2809"));
  test::SimMaster master(segment);
  master.assign_stations();
  master.bring_to_preop(0);
  master.configure_process_data(0);
  FaultInjector injector(segment);
  ASSERT_TRUE(
      injector.inject(fault::refuse_state("outputs", wire::AlState::op, 0x001B), master.now())
          .ok());
  ASSERT_EQ(master.request(0, wire::AlState::safeop).state, wire::AlState::safeop);
  master.lrw();
  const auto refused = master.request(0, wire::AlState::op);
  EXPECT_EQ(refused.state, wire::AlState::safeop);
  EXPECT_TRUE(refused.error);
  EXPECT_EQ(refused.code, 0x001B);
  injector.clear();
  master.lrw();
  EXPECT_EQ(master.request(0, wire::AlState::op, true).state, wire::AlState::op);
}

}  // namespace
}  // namespace ecat::sim
