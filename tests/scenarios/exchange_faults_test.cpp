// Fault scenarios on the bus: exchange faults (lost replies, working-counter skews, a slave cut
// off for a window) and transport-edge faults, injected into a running ring (docs/scenarios/).
#include <chrono>
#include <string>

#include <gtest/gtest.h>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using master::InvalidReason;
namespace fault = sim::fault;

// The reference reports the first invalid cycle to the master.
RingSpec eager_spec() {
  RingSpec spec;
  spec.recovery_threshold = 1;
  return spec;
}

// After a fault window: back to operational, every slave in OP without a fault, process data
// round the ring, and no transition the seed does not draw.
void expect_healed(ScenarioRing& ring) {
  ASSERT_TRUE(ring.master->await_operational(10s)) << ring.describe();
  EXPECT_TRUE(eventually([&] {
    return ring.all_slaves_in(SlaveState::op) && !ring.any_slave_fault();
  })) << ring.describe();
  EXPECT_TRUE(ring.loopback(true)) << ring.describe();
  EXPECT_TRUE(ring.loopback(false)) << ring.describe();
  EXPECT_TRUE(ring.master->status().runtime_faults.empty()) << ring.describe();
  EXPECT_EQ(ring.master->status().illegal_transitions, 0u);
}

// ---- 00: healthy ring on every transport -------------------------------------------------------

void expect_healthy_ring(Transport transport) {
  RingSpec spec;
  spec.transport = transport;
  std::string skip;
  auto ring = ScenarioRing::create(spec, &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  auto op = ring->master->await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe() << "; " << ring->describe();
  EXPECT_TRUE(ring->all_slaves_in(SlaveState::op)) << ring->describe();
  EXPECT_FALSE(ring->any_slave_fault()) << ring->describe();
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  const auto stats = ring->domain_stats();
  EXPECT_EQ(stats.state, master::DomainState::cycling);
  EXPECT_GT(stats.valid_count, 0u);
  EXPECT_TRUE(ring->master->status().runtime_faults.empty());
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_FALSE(ring->saw(MasterState::activation_blocked));
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
  // The stations the master assigned are the ones the simulated ESCs hold.
  const auto sim = ring->server->status();
  ASSERT_EQ(sim.slaves.size(), 3u);
  for (std::size_t i = 0; i < sim.slaves.size(); ++i) {
    EXPECT_EQ(sim.slaves[i].station, 0x1000 + i) << sim.slaves[i].name;
    EXPECT_EQ(sim.slaves[i].al_state, wire::AlState::op) << sim.slaves[i].name;
  }
}

TEST(Scenario00, HealthyRingOverMemoryReachesOperational) {
  expect_healthy_ring(Transport::memory);
}

TEST(Scenario00, HealthyRingOverUdpReachesOperational) {
  expect_healthy_ring(Transport::udp);
}

TEST(Scenario00, HealthyRingOverRawVethReachesOperational) {
  expect_healthy_ring(Transport::raw);
}

// ---- 01: no replies for 10 exchanges ------------------------------------------------------------

TEST(Scenario01, DroppedResponsesRecoverWithoutBlamingSlaves) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  const auto before = ring->domain_stats();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::next(fault::drop_responses(), 10)));
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  monitor.stop();
  // The domain saw transport misses, reported as timeouts (not as WKC mismatches).
  EXPECT_TRUE(monitor.saw("invalid:main:timeout")) << monitor.seen();
  EXPECT_TRUE(monitor.matching("wkc:main").empty()) << monitor.seen();
  const auto after = ring->domain_stats();
  EXPECT_GT(after.timeout_count, before.timeout_count);
  ASSERT_TRUE(after.last_invalid);
  EXPECT_EQ(after.last_invalid->reason, InvalidReason::timeout);
  // A bus that loses frames is not the slaves' fault: none was marked down or faulted.
  EXPECT_TRUE(monitor.matching("fault:").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:inputs:down").empty()) << monitor.seen();
  expect_healed(*ring);
}

// ---- 02: every working counter one short for 6 exchanges ---------------------------------------

TEST(Scenario02, WkcSkewIsAMismatchAndRecovers) {
  auto spec = eager_spec();
  // A 2 ms cycle keeps the 6 skewed exchanges well inside one 20 ms health-poll period: a poll
  // that falls into the window fails once, and one failed poll is not a lost slave.
  spec.domain_period = 2ms;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::next(fault::wkc_offset(-1), 6)));
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  monitor.stop();
  // The replies came back: the domain keeps cycling with a mismatch of 3 expected, 2 seen.
  EXPECT_TRUE(monitor.saw("wkc:main:3/2")) << monitor.seen();
  EXPECT_FALSE(monitor.saw("invalid:main:timeout")) << monitor.seen();
  EXPECT_EQ(ring->domain_stats().state, master::DomainState::cycling);
  EXPECT_GT(ring->domain_stats().wkc_mismatch_count, 0u);
  EXPECT_TRUE(monitor.matching("fault:").empty()) << monitor.seen();
  expect_healed(*ring);
}

// ---- 04: replies damaged on the transport edge (UDP) -------------------------------------------

std::uint64_t dropped_replies(const bus::BusStats& s) {
  return s.unmatched_replies + s.mismatched_replies + s.late_replies + s.duplicate_replies +
         s.decode_errors;
}

TEST(Scenario04, DamagedUdpRepliesAreDroppedAndTheRingRecovers) {
  RingSpec spec;
  spec.transport = Transport::udp;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& bus = *ring->master->bus();

  struct Case {
    const char* name;
    sim::Fault fault;
    bool decode_error;  // else: a foreign index (mismatched / unmatched / duplicate)
    // Exchanges that must end lost. A replayed reply is the one of the exchange before: the
    // second replay hands over the reply of the first damaged exchange, which may still be in
    // flight and then rightly completes it (late, but its own).
    std::uint64_t lost;
  };
  const std::vector<Case> cases = {
      {"truncate", fault::truncate_reply(1), true, 2},
      {"unsupported_type", fault::unsupported_type(0), true, 2},
      {"wrong_index", fault::wrong_index(), false, 2},
      {"replay_previous", fault::replay_previous(), false, 1},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const auto before = bus.stats();
    ASSERT_TRUE(ring->server->inject(fault::next(c.fault, 2)));
    ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
    // The damaged replies were thrown away, so their exchanges ended as lost frames.
    EXPECT_TRUE(eventually([&] {
      const auto now = bus.stats();
      return now.frames_lost >= before.frames_lost + c.lost &&
             (c.decode_error ? now.decode_errors >= before.decode_errors + 2
                             : dropped_replies(now) >= dropped_replies(before) + c.lost);
    })) << "lost "
        << bus.stats().frames_lost - before.frames_lost << ", decode errors "
        << bus.stats().decode_errors - before.decode_errors;
    ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  }

  // A scripted window: one of each, in order.
  const auto before = bus.stats();
  ASSERT_TRUE(
      ring->server->inject(fault::script({fault::truncate_reply(1), fault::wrong_index(),
                                          fault::unsupported_type(0), fault::replay_previous()})));
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  EXPECT_TRUE(eventually([&] {
    const auto now = bus.stats();
    return now.frames_lost >= before.frames_lost + 3 &&
           now.decode_errors >= before.decode_errors + 2;
  }));
  expect_healed(*ring);
}

// ---- 07: a script of drops, WKC skews and a cut-off slave ---------------------------------------

std::vector<sim::Fault> drops_and_skews() {
  return {fault::next(fault::drop_responses(), 6), fault::next(fault::wkc_offset(-1), 4)};
}

TEST(Scenario07, ScriptedExchangeFaultsRecover) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  const auto before = ring->domain_stats();
  auto steps = drops_and_skews();
  steps.push_back(fault::next(fault::disconnect("outputs"), 30));
  ASSERT_TRUE(ring->server->inject(fault::script(steps)));
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  // The script runs out by itself; nothing is cleared by hand.
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  // The outputs were cut off long enough for their health poll to find them down.
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:outputs:down"); })) << monitor.seen();
  expect_healed(*ring);
  monitor.stop();
  // The dropped replies were transport misses. Counted, not sampled: the skews that follow
  // replace the last invalid reason within a cycle or two, faster than a loaded sampler looks.
  const auto after = ring->domain_stats();
  EXPECT_GT(after.timeout_count + after.expired_count, before.timeout_count + before.expired_count)
      << monitor.seen();
  EXPECT_TRUE(monitor.saw("fault:outputs")) << monitor.seen();
  EXPECT_EQ(ring->slave("outputs").station(), 0x1002);
}

// ---- 08: the same, then a retreat to SAFEOP 600 ms later ----------------------------------------

TEST(Scenario08, DelayedSlaveRetreatAfterExchangeFaults) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(fault::script(drops_and_skews())));
  ASSERT_TRUE(ring->server->inject(fault::after(fault::retreat_to_safeop("outputs"), 600ms)));
  // The delayed fault is visible while it waits.
  const auto info = ring->server->fault_info();
  bool scheduled = false;
  for (const auto& s : info.scheduled) {
    if (s.due_in_ns && s.description.find("retreat") != std::string::npos) scheduled = true;
  }
  EXPECT_TRUE(scheduled) << "no scheduled retreat with a due time";
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  ASSERT_FALSE(ring->fault_queue_drained()) << "the retreat fired before the ring recovered";
  ring->forget_states();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  // The retreat is slave-local: the outputs are seen below OP with a fault, then sent back.
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:outputs"); })) << monitor.seen();
  expect_healed(*ring);
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:outputs:safeop")) << monitor.seen();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << monitor.seen();
}

// ---- 09: a retreat after 12 healthy polls of the outputs ---------------------------------------

TEST(Scenario09, MilestoneRetreatAfterExchangeFaults) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(fault::script(drops_and_skews())));
  ASSERT_TRUE(ring->server->inject(fault::after_milestone(fault::retreat_to_safeop("outputs"),
                                                          fault::healthy_polls("outputs", 12))));
  {
    const auto info = ring->server->fault_info();
    bool waiting = false;
    for (const auto& s : info.scheduled) {
      if (!s.waiting_on.empty() && s.remaining > 0 &&
          s.description.find("retreat") != std::string::npos) {
        waiting = true;
      }
    }
    EXPECT_TRUE(waiting) << "no scheduled retreat waiting on a milestone";
  }
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:outputs"); })) << monitor.seen();
  expect_healed(*ring);
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:outputs:safeop")) << monitor.seen();
}

// ---- 11: one script: faults, wait for 12 healthy polls, retreat ---------------------------------

TEST(Scenario11, ScriptWaitsForHealthyPollsThenRetreats) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  auto steps = drops_and_skews();
  steps.push_back(fault::wait_for(fault::healthy_polls("outputs", 12)));
  steps.push_back(fault::retreat_to_safeop("outputs"));
  ASSERT_TRUE(ring->server->inject(fault::script(steps)));
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  // While it waits, the rest of the script is visible: the step it is at and what it waits on.
  ASSERT_TRUE(eventually([&] {
    const auto info = ring->server->fault_info();
    for (const auto& s : info.scheduled) {
      if (s.step == 2 && !s.waiting_on.empty()) return true;
    }
    return ring->fault_queue_drained();
  }));
  Monitor monitor(*ring->master);
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:outputs"); })) << monitor.seen();
  expect_healed(*ring);
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:outputs:safeop")) << monitor.seen();
}

// ---- 13: only the outputs' share of the logical WKC is short -----------------------------------

TEST(Scenario13, LogicalWkcFaultIsNotBlamedOnTheSlave) {
  auto ring = ScenarioRing::operational(eager_spec());
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::next(fault::logical_wkc_offset("outputs", -1), 6)));
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  monitor.stop();
  EXPECT_TRUE(monitor.saw("wkc:main:3/2")) << monitor.seen();
  // The register polls stayed healthy: the outputs were never down.
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("fault:").empty()) << monitor.seen();
  expect_healed(*ring);
}

// ---- 42: the master's cable replugged, one direction slow to come up ---------------------------

// The reference saw this on hardware only: after a cable replug one PHY direction came up later
// than the other, so the first frames got through but their replies were lost or late. Here the
// master's link goes down, comes back, and the next replies are held back beyond the frame
// timeout (asymmetric: requests arrive at once, replies late).
TEST(Scenario42, AsymmetricLinkRecoveryAfterReplug) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  auto& bus = *ring->master->bus();
  Monitor monitor(*ring->master);
  const auto before = bus.stats();
  ASSERT_TRUE(ring->server->inject(fault::master_link_down()));
  ASSERT_TRUE(eventually([&] { return ring->domain_stats().miss_count >= 5; })) << ring->describe();
  const auto frame_timeout = bus.info().frame_timeout;
  ASSERT_TRUE(ring->server->inject(fault::script(
      {fault::master_link_up(), fault::next(fault::delay_replies(frame_timeout + 5ms), 5)})));
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  // The held-back replies came after their frames were given up: counted late, never taken for
  // the replies of newer frames.
  EXPECT_TRUE(eventually([&] { return bus.stats().late_replies > before.late_replies; }))
      << "late replies: " << bus.stats().late_replies - before.late_replies;
  expect_healed(*ring);
  monitor.stop();
  EXPECT_TRUE(monitor.saw("invalid:main:timeout")) << monitor.seen();
  EXPECT_TRUE(ring->saw(MasterState::recovering));
  // A link that loses every frame is not the slaves' fault.
  EXPECT_TRUE(monitor.matching("fault:").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
}

}  // namespace
}  // namespace ecat::scenarios
