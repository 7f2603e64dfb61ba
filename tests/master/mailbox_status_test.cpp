// Mailbox status in the cyclic frame: SM1's status byte mapped by an FMMU into the slave's domain,
// the mailbox waiting for "mailbox full" there instead of polling SM1 with frames of its own, and
// every way back to polling.
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/registers.hpp>

#include "master_test_support.hpp"
#include "support/counting_link.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using ecat::test::CountedDatagram;

// A mailbox device (mailbox, 2 output and 1 input byte, 3 FMMUs) whose firmware takes 3 ms to
// answer: long enough for polling to show, and for several cycles to pass.
constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: io, profile: mailbox, options: {mailbox_reply_us: 3000}}
)";

// The same device with only two FMMUs: both taken by its process data.
constexpr const char* kTwoFmmuRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: io, profile: mailbox, options: {mailbox_reply_us: 3000}, esc: {fmmus: 2}}
)";

constexpr std::uint16_t kIoStation = 0x1001;
constexpr std::uint16_t kSm1Offset = 0x1040;  // the mailbox profile's SM1

MasterConfig config(std::chrono::nanoseconds period, TargetState target = TargetState::op) {
  MasterConfig c = test::quick_config(period, target);
  c.slaves = {test::quick_slave("coupler", false, target), test::quick_slave("io", true, target)};
  for (auto& s : c.slaves)
    s.health_poll.reset();  // no acyclic traffic but the mailbox's
  return c;
}

struct Running {
  std::unique_ptr<sim::SimServer> server;
  std::shared_ptr<ecat::test::FrameLog> log = std::make_shared<ecat::test::FrameLog>();
  std::unique_ptr<Master> master;

  Running(std::string_view ring, MasterConfig c) {
    server = test::make_sim_server(ring);
    if (!server) return;
    auto link = server->serve_memory();
    if (!link) {
      ADD_FAILURE() << link.error().describe();
      return;
    }
    master = std::make_unique<Master>(std::move(c));
    auto started = master->start(std::make_unique<ecat::test::CountingLink>(std::move(*link), log));
    EXPECT_TRUE(started) << started.error().describe();
  }
  ~Running() {
    if (master) (void)master->stop();
  }
  SlaveInfo io() { return (*master->slave("io"))->info(); }
  Domain& domain() { return **master->domain("main"); }
};

bool is_sm1_read(const CountedDatagram& d) {
  return d.command == wire::Command::fprd && d.adp() == kIoStation && d.ado() == kSm1Offset;
}
bool is_cyclic(const CountedDatagram& d) {
  return d.command == wire::Command::lrw;
}

// What one SDO upload costs in frames: those that are not the domain's.
struct Cost {
  std::size_t acyclic_frames = 0;
  std::size_t sm1_reads = 0;
  std::size_t empty_sm1_reads = 0;
};

Cost upload_cost(Running& run, std::vector<std::uint8_t>* value = nullptr) {
  auto* io = *run.master->slave("io");
  const std::size_t from = run.log->size();
  auto got = io->upload_sdo(0x1018, 1);
  EXPECT_TRUE(got) << got.error().describe();
  if (got && value) *value = *got;
  const auto frames = run.log->since(from);
  Cost cost;
  cost.acyclic_frames =
      ecat::test::count_frames(frames, [](const CountedDatagram& d) { return !is_cyclic(d); });
  cost.sm1_reads = ecat::test::count_datagrams(frames, is_sm1_read);
  cost.empty_sm1_reads = ecat::test::count_datagrams(
      frames, [](const CountedDatagram& d) { return is_sm1_read(d) && d.wkc == 0; });
  return cost;
}

// The status is mapped (FMMU 2, the one the process data leaves), the domain's LRW reads it, and
// an SDO reply is found through it: one frame for the request (SM1 read alongside, still empty)
// and one for the reply, no SM1 polls while the firmware works.
TEST(MailboxStatus, ReplySeenInTheCycleWithoutPolls) {
  Running run(kRing, config(1ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  const auto io = run.io();
  EXPECT_EQ(io.mailbox_status_domain, "main");
  EXPECT_EQ(io.mailbox_status_fmmu, 2);
  auto status = run.domain().registration(PdoKey{kIoStation, 1, RegistrationKind::sm_status});
  ASSERT_TRUE(status) << status.error().describe();
  EXPECT_EQ(status->size, 1);
  EXPECT_EQ(status->direction, PdoDirection::input);

  // Polling reads SM1 every 200 us (plus a round trip) for the 3 ms the firmware takes: 5 to 7
  // frames per upload. A cycle that comes late on a loaded machine may make the status stale for
  // a moment (polls then): slack of two frames per upload over the exact 2 frames and 1 empty
  // read (a run beside the sanitizer suite needed it), still well under what polling costs.
  Cost total;
  constexpr std::size_t kUploads = 5;
  for (std::size_t i = 0; i < kUploads; ++i) {
    std::vector<std::uint8_t> value;
    const Cost cost = upload_cost(run, &value);
    EXPECT_EQ(value.size(), 4u);
    EXPECT_GE(cost.sm1_reads, 2u) << "upload " << i;  // the request's, the reply's
    total.acyclic_frames += cost.acyclic_frames;
    total.sm1_reads += cost.sm1_reads;
    total.empty_sm1_reads += cost.empty_sm1_reads;
  }
  EXPECT_LE(total.acyclic_frames, 4 * kUploads);
  EXPECT_LE(total.empty_sm1_reads, 3 * kUploads);  // the requests' own, and stale cycles' polls
  // The cycle stayed valid with the status byte in it.
  EXPECT_TRUE(run.master->domains().at(0).healthy);
  EXPECT_EQ(run.domain().stats().wkc_mismatch_count, 0u);
}

// The same with the option off: the mailbox polls SM1 every 200 us while the firmware works.
TEST(MailboxStatus, OffPollsAsBefore) {
  auto c = config(1ms);
  c.mailbox_status = false;
  Running run(kRing, c);
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.io().mailbox_status_domain, "");
  EXPECT_FALSE(run.domain().registration(PdoKey{kIoStation, 1, RegistrationKind::sm_status}));
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.empty_sm1_reads, 2u);  // polls beyond the request's own read
  EXPECT_GE(cost.acyclic_frames, 3u);
}

// Per slave: SlaveConfig::mailbox_status off wins over the master's on.
TEST(MailboxStatus, SlaveOptionWins) {
  auto c = config(1ms);
  c.slaves[1].mailbox_status = false;
  Running run(kRing, c);
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.io().mailbox_status_domain, "");
}

// An ESC whose FMMUs are all taken by process data keeps polling, and its domain's WKC is the
// plain one.
TEST(MailboxStatus, NoSpareFmmuPolls) {
  Running run(kTwoFmmuRing, config(1ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.io().mailbox_status_domain, "");
  EXPECT_EQ(run.domain().info().expected_wkc, 3u);  // outputs (2) + inputs (1)
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.empty_sm1_reads, 2u);  // polls beyond the request's own read
}

// The status byte counts in the working counter as the ESC counts it: once per slave and datagram
// with a read FMMU, so a slave that already has inputs in the datagram adds nothing; the cycles
// stay valid in OP, and the LRW's WKC is what the domain expects.
TEST(MailboxStatus, WorkingCounterInOp) {
  Running run(kRing, config(1ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.domain().info().expected_wkc, 3u);
  const auto before = run.domain().stats();
  std::this_thread::sleep_for(50ms);
  const auto after = run.domain().stats();
  EXPECT_GT(after.valid_count, before.valid_count + 10);
  EXPECT_EQ(after.wkc_mismatch_count, 0u);
  EXPECT_EQ(after.last_wkc, 3u);
  EXPECT_GT(ecat::test::count_datagrams(run.log->since(0), is_cyclic), 10u);
  // The LRWs on the wire in OP: every one came back with the expected count.
  const std::size_t mark = run.log->size();
  std::this_thread::sleep_for(30ms);
  const auto in_op = run.log->since(mark);
  EXPECT_EQ(ecat::test::count_datagrams(
                in_op, [](const CountedDatagram& d) { return is_cyclic(d) && d.wkc != 3; }),
            0u);
}

// A slave with only outputs gains a read FMMU: its share becomes 3 (write 2 + read 1), and the
// simulated ESC counts exactly that.
TEST(MailboxStatus, WorkingCounterOfAnOutputOnlySlave) {
  auto c = config(1ms);
  c.slaves[1].process_data = ProcessDataRequest{};
  c.slaves[1].process_data.kind = ProcessDataRequest::Kind::signals;
  c.slaves[1].process_data.routes = {{"outputs.led0", "main"}};
  Running run(kRing, c);
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.io().mailbox_status_domain, "main");
  EXPECT_EQ(run.domain().info().expected_wkc, 3u);
  const std::size_t mark = run.log->size();
  std::this_thread::sleep_for(30ms);
  EXPECT_EQ(run.domain().stats().wkc_mismatch_count, 0u);
  const auto frames = run.log->since(mark);
  EXPECT_GT(ecat::test::count_datagrams(frames, is_cyclic), 5u);
  EXPECT_EQ(ecat::test::count_datagrams(
                frames, [](const CountedDatagram& d) { return is_cyclic(d) && d.wkc != 3; }),
            0u);
  const Cost cost = upload_cost(run);
  EXPECT_EQ(cost.empty_sm1_reads, 1u);
}

// In PREOP the domain is not cycling (nothing to exchange): the mailbox polls.
TEST(MailboxStatus, PreopBeforeCyclingPolls) {
  Running run(kRing, config(1ms, TargetState::preop));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_running(15s));
  EXPECT_EQ(run.master->state(), MasterState::preop_ready);
  EXPECT_EQ(run.io().mailbox_status_domain, "main");  // mapped, but not cycling
  EXPECT_NE(run.domain().state(), DomainState::cycling);
  // The reply comes by polling (a wait for cycles that never come would time out). Polls beyond
  // the request's own read are the rule; a loaded machine may find the reply at the first one.
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.sm1_reads, 2u);
}

// A stopped domain publishes nothing: the mailbox polls.
TEST(MailboxStatus, StoppedDomainPolls) {
  Running run(kRing, config(1ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  ASSERT_TRUE(run.domain().stop_cycling());
  // As above: the reply by polling, never a wait for a cycle.
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.sm1_reads, 2u);
}

// A domain whose cycles stop being valid (every LRW's WKC off by one: nothing published) makes
// the status stale: the mailbox falls back to polling and still gets its reply.
TEST(MailboxStatus, StaleStatusFallsBackToPolling) {
  Running run(kRing, config(1ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  auto injected = run.server->inject(sim::fault::command_wkc_offset(wire::Command::lrw, 1));
  ASSERT_TRUE(injected) << injected.error().describe();
  std::this_thread::sleep_for(10ms);  // older than stale_after (3 ms)
  ASSERT_NE(run.domain().freshness().state, Freshness::fresh);
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.empty_sm1_reads, 2u);  // polls beyond the request's own read
}

// A domain slower than MailboxOptions::status_max_period (10 ms): polling, as waiting a cycle per
// message would cost more time than the frames it saves.
TEST(MailboxStatus, SlowDomainPolls) {
  Running run(kRing, config(20ms));
  ASSERT_TRUE(run.master);
  ASSERT_TRUE(run.master->await_operational(15s));
  EXPECT_EQ(run.io().mailbox_status_domain, "main");
  const Cost cost = upload_cost(run);
  EXPECT_GE(cost.empty_sm1_reads, 2u);  // polls beyond the request's own read
}

// SDOs while cycling at several periods: correct values, segmented transfers included, and no
// SM1 read that finds it empty but the one riding each request.
TEST(MailboxStatus, SdosWhileCyclingAtSeveralPeriods) {
  for (const auto period : {500us, 1000us, 4000us}) {
    SCOPED_TRACE(std::chrono::duration_cast<std::chrono::microseconds>(period).count());
    Running run(kRing, config(period));
    ASSERT_TRUE(run.master);
    ASSERT_TRUE(run.master->await_operational(15s));
    auto* io = *run.master->slave("io");
    const std::size_t from = run.log->size();
    std::size_t requests = 0;
    for (int i = 0; i < 3; ++i) {
      auto vendor = io->upload_sdo(0x1018, 1);
      ASSERT_TRUE(vendor) << vendor.error().describe();
      ++requests;
      const std::vector<std::uint8_t> led{static_cast<std::uint8_t>(i + 1)};
      ASSERT_TRUE(io->download_sdo(0x2000, 2, led));
      ++requests;
      auto back = io->upload_sdo(0x2000, 2);
      ASSERT_TRUE(back) << back.error().describe();
      EXPECT_EQ(*back, led);
      ++requests;
    }
    // The device name (0x1008) is longer than an expedited transfer: a normal upload.
    auto name = io->upload_sdo(0x1008, 0);
    ASSERT_TRUE(name) << name.error().describe();
    EXPECT_GT(name->size(), 4u);
    ++requests;
    // Polling: an empty read every 200 us (plus a round trip) for 3 ms, about 15 per request;
    // with the status, the one riding each request, and polls while late cycles on a loaded
    // machine make the status stale (a run beside the sanitizer suite saw 23 for 10 requests).
    const auto frames = run.log->since(from);
    EXPECT_LT(ecat::test::count_datagrams(
                  frames, [](const CountedDatagram& d) { return is_sm1_read(d) && d.wkc == 0; }),
              5 * requests);
    EXPECT_EQ(run.domain().stats().wkc_mismatch_count, 0u);
  }
}

}  // namespace
}  // namespace ecat::master
