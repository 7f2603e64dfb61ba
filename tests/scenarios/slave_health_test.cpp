// Fault scenarios of slave health: a slave cut off, power-cycled, retreating or latching an AL
// error; health polling while slaves are held in PREOP; a drive under the CiA 402 driver
// (docs/scenarios/).
#include <chrono>
#include <cstdlib>
#include <string>
#include <variant>

#include <gtest/gtest.h>

#include <ecat/wire/frame.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using master::InvalidReason;
namespace fault = sim::fault;

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

// ---- 03: the outputs cut off for 30 exchanges; inputs read while stale -------------------------

TEST(Scenario03, DisconnectedSlaveIsDownThenReconnected) {
  RingSpec spec;
  spec.recovery_threshold = 1;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::next(fault::disconnect("outputs"), 30)));
  // The domain sees the outputs' share missing first: 3 expected, 1 (the inputs) seen.
  ASSERT_TRUE(eventually([&] { return monitor.saw("wkc:main:3/1"); })) << monitor.seen();
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  // Its health poll finds the outputs down; after the window they are rebuilt through PREOP and
  // brought back to OP by the master.
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:outputs:down"); })) << monitor.seen();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  expect_healed(*ring);
  monitor.stop();
  EXPECT_TRUE(monitor.saw("fault:outputs")) << monitor.seen();
  // Rebuilt while DOWN, straight to PREOP (the seed's down -> preop), then requested to OP.
  EXPECT_TRUE(monitor.saw("state:outputs:preop")) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:inputs:down").empty()) << monitor.seen();
}

TEST(Scenario03, InputsReadWhileCutOffAreStale) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  auto& inputs = ring->slave("inputs");
  ASSERT_TRUE(ring->loopback(true));
  ASSERT_TRUE(ring->server->inject(fault::next(fault::disconnect("outputs"), 120)));
  // No valid cycle while the outputs are missing: the last inputs age past the window.
  Result<master::Value> read = master::Value(false);
  ASSERT_TRUE(eventually([&] {
    read = inputs.read_input("channel_1");
    return !read && read.error().code() == Errc::stale;
  })) << (read ? "still fresh" : read.error().describe());
  EXPECT_NE(read.error().message().find("channel_1"), std::string::npos) << read.error().describe();
  auto domain = ring->master->domain("main");
  ASSERT_TRUE(domain);
  const auto freshness = (*domain)->freshness();
  EXPECT_EQ(freshness.state, master::Freshness::stale);
  ASSERT_TRUE(freshness.age && freshness.refreshed_at);
  EXPECT_GT(*freshness.age, freshness.stale_after);
  EXPECT_EQ(freshness.stale_after, 3 * 5ms);
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  expect_healed(*ring);
  auto fresh = inputs.read_input("channel_1");
  ASSERT_TRUE(fresh) << fresh.error().describe();
}

// ---- 05: a retreat to SAFEOP is slave-local -----------------------------------------------------

TEST(Scenario05, RetreatToSafeopIsRetriedWhileTheMasterStaysOperational) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  ring->forget_states();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::retreat_to_safeop("outputs")));
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:outputs"); })) << monitor.seen();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("outputs") == SlaveState::op && !ring->slave_fault("outputs");
  })) << ring->describe();
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:outputs:safeop")) << monitor.seen();
  // The fault names what the poll saw: AL state SAFEOP, no error.
  const auto faults = monitor.matching("fault:outputs:");
  ASSERT_FALSE(faults.empty());
  EXPECT_NE(faults.front().find("SAFEOP"), std::string::npos) << faults.front();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << monitor.seen();
  EXPECT_TRUE(monitor.matching("invalid:main").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
  expect_healed(*ring);
}

TEST(Scenario05, DisconnectWhileHeldInSafeopBecomesDown) {
  RingSpec spec;
  spec.retry_interval = 400ms;  // keeps the outputs in SAFEOP long enough to cut them off
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::retreat_to_safeop("outputs")));
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("outputs") == SlaveState::safeop && ring->slave_fault("outputs");
  })) << ring->describe();
  const auto retreat = *ring->slave_fault("outputs");
  ASSERT_TRUE(ring->server->inject(fault::disconnect("outputs")));
  // The tracked fault changes from the retreat to down.
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::down; }))
      << ring->describe();
  auto down = ring->slave_fault("outputs");
  ASSERT_TRUE(down);
  EXPECT_NE(*down, retreat);
  EXPECT_EQ(down->rfind("down", 0), 0u) << *down;
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }))
      << ring->describe();
  ring->server->clear_faults();
  expect_healed(*ring);
}

// ---- 14: only FPRD working counters short (health polls fail, process data fine) ---------------

TEST(Scenario14, FailedHealthPollsMarkThePdoSlaveDown) {
  RingSpec spec;
  // Only the outputs poll at 20 ms (as in the reference); the others at the default period.
  spec.health_polls["coupler"] = 250ms;
  spec.health_polls["inputs"] = 250ms;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(
      ring->server->inject(fault::next(fault::command_wkc_offset(wire::Command::fprd, -1), 100)));
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:outputs:down"); })) << monitor.seen();
  // Critical: the outputs carry process data.
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); })) << ring->describe();
  // The logical exchange was not affected: the domain was still valid when the poll found the
  // slave down (the rebuild that follows takes the slave out of OP, which the domain then sees).
  const auto down_at = monitor.first("state:outputs:down");
  const auto invalid_at = monitor.first_matching("invalid:main");
  EXPECT_TRUE(!invalid_at || *invalid_at >= *down_at) << monitor.seen();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  expect_healed(*ring);
}

// ---- 43: silent PDO failure, bounded disconnect, power cycles ----------------------------------

TEST(Scenario43, SilentPdoFailureRecoversWhilePollsStayGreen) {
  RingSpec spec;
  spec.recovery_threshold = 1;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::logical_wkc_offset("outputs", -1)));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }))
      << ring->describe();
  EXPECT_TRUE(stays([&] { return ring->state() == MasterState::recovering; }, 200ms));
  EXPECT_TRUE(eventually([&] { return monitor.saw("wkc:main:3/2"); })) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
  EXPECT_FALSE(ring->slave_fault("outputs"));
  ring->server->clear_faults();
  expect_healed(*ring);
}

TEST(Scenario43, BoundedDisconnectIsDetectedAndReconnected) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::next(fault::disconnect("outputs"), 60)));
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:outputs:down"); })) << monitor.seen();
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  expect_healed(*ring);
  EXPECT_TRUE(ring->saw(MasterState::recovering));
}

// The outputs power-cycle while cut off: they come back at station 0 and are reclaimed at their
// position (identity checked) and rebuilt.
TEST(Scenario43, PowerCycleWhileDisconnectedReclaimsTheStation) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->loopback(true));
  ASSERT_TRUE(ring->server->inject(fault::disconnect("outputs")));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::down; }))
      << ring->describe();
  ASSERT_TRUE(ring->server->power_cycle("outputs"));
  auto station = ring->server->read_memory("outputs", 0x0010, 2);
  ASSERT_TRUE(station);
  EXPECT_EQ((*station)[0] | ((*station)[1] << 8), 0);
  ring->server->clear_faults();
  // The output staged before the loss is applied again once the slave is back.
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  EXPECT_TRUE(eventually([&] {
    auto v = ring->slave("inputs").read_input("channel_1");
    return v && master::as_bool(*v) == true;
  }));
  expect_healed(*ring);
  station = ring->server->read_memory("outputs", 0x0010, 2);
  ASSERT_TRUE(station);
  EXPECT_EQ((*station)[0] | ((*station)[1] << 8), 0x1002);
}

TEST(Scenario43, PowerCycleWhilePresentReclaimsTheStation) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->power_cycle("outputs"));
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:outputs:down"); })) << monitor.seen();
  expect_healed(*ring);
  auto station = ring->server->read_memory("outputs", 0x0010, 2);
  ASSERT_TRUE(station);
  EXPECT_EQ((*station)[0] | ((*station)[1] << 8), 0x1002);
}

TEST(Scenario43, PdoFaultDuringReconnectStillConverges) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(fault::disconnect("outputs")));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::down; }))
      << ring->describe();
  ring->server->clear_faults();
  ASSERT_TRUE(ring->server->inject(fault::next(fault::logical_wkc_offset("outputs", -1), 5)));
  expect_healed(*ring);
}

// ---- 44: reply delays on a raw link -------------------------------------------------------------

TEST(Scenario44, ConfiguredAndTransientReplyDelaysOnRaw) {
  RingSpec spec;
  spec.transport = Transport::raw;
  // The segment's configured delay: a start fault of the ring file.
  spec.ring_yaml = ring_yaml(RingKind::basic) + "  faults:\n    - {kind: delay_replies, ms: 1}\n";
  std::string skip;
  auto ring = ScenarioRing::create(spec, &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  auto active = ring->server->fault_info().active;
  ASSERT_EQ(active.size(), 1u);
  const auto configured = active.front();
  EXPECT_NE(configured.find("delay"), std::string::npos) << configured;
  auto& domain = **ring->master->domain("main");
  EXPECT_TRUE(eventually([&] { return domain.stats().last_latency >= 1ms; }));
  // A transient overlay: 3 ms more for the next 40 exchanges (well within the 20 ms frame timeout).
  ASSERT_TRUE(ring->server->inject(fault::next(fault::delay_replies(3ms), 40)));
  const auto queued = ring->server->fault_info().queued;
  ASSERT_EQ(queued.size(), 1u);
  EXPECT_NE(queued.front().description.find("delay"), std::string::npos);
  EXPECT_TRUE(eventually([&] { return domain.stats().last_latency >= 3ms; }));
  ASSERT_TRUE(eventually([&] { return ring->fault_queue_drained(); }));
  // The overlay ran out; the configured delay is still there.
  EXPECT_EQ(ring->server->fault_info().active, std::vector<std::string>{configured});
  EXPECT_TRUE(eventually([&] {
    const auto l = domain.stats().last_latency;
    return l >= 1ms && l < 3ms;
  }));
  ring->server->clear_faults();
  EXPECT_TRUE(ring->server->fault_info().active.empty());
  EXPECT_TRUE(eventually([&] { return domain.stats().last_latency < 1ms; }));
  EXPECT_TRUE(ring->server->fault_info().queued.empty());
  expect_healed(*ring);
}

// ---- 46: an AL error latched in OP ------------------------------------------------------------

TEST(Scenario46, LatchedAlErrorIsAcknowledgedAndRetried) {
  auto ring = ScenarioRing::operational(RingSpec{});
  ASSERT_TRUE(ring);
  ring->forget_states();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::latch_al_error("outputs", 0x001D)));
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:outputs"); })) << monitor.seen();
  EXPECT_TRUE(eventually([&] { return ring->slave("outputs").error() == 0x001D; }));
  const auto faults = monitor.matching("fault:outputs:");
  ASSERT_FALSE(faults.empty());
  EXPECT_NE(faults.front().find("0x001d"), std::string::npos) << faults.front();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("outputs") == SlaveState::op && !ring->slave_fault("outputs");
  })) << ring->describe();
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:outputs:safeop")) << monitor.seen();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << monitor.seen();
  // The error was acknowledged: the simulated ESC no longer shows the error flag.
  EXPECT_TRUE(eventually([&] {
    for (const auto& s : ring->server->status().slaves) {
      if (s.name == "outputs") return !s.al_error && s.al_state == wire::AlState::op;
    }
    return false;
  }));
  expect_healed(*ring);
}

// ---- 47-51: health polling while slaves are held in PREOP ---------------------------------------

RingSpec held_spec(RingKind kind = RingKind::basic) {
  RingSpec spec;
  spec.kind = kind;
  for (const char* name : {"coupler", "inputs", "outputs", "mailbox"})
    spec.targets[name] = TargetState::preop;
  return spec;
}

std::unique_ptr<ScenarioRing> running(const RingSpec& spec, MasterState expected) {
  auto ring = ScenarioRing::create(spec);
  if (!ring) return nullptr;
  auto up = ring->master->await_running(10s);
  if (!up) {
    ADD_FAILURE() << up.error().describe();
    return nullptr;
  }
  EXPECT_EQ(ring->state(), expected) << ring->describe();
  return ring;
}

TEST(Scenario47, StartupHeldPreopDoesNotPoll) {
  auto ring = running(held_spec(), MasterState::preop_ready);
  ASSERT_TRUE(ring);
  // A frame of our own, past the master, reaches the outputs before the cut ...
  ASSERT_EQ(ring->probe_wkc("outputs"), 1);
  ASSERT_TRUE(ring->server->inject(fault::disconnect("outputs")));
  // ... and not once it is in effect: a poll would have found them gone.
  EXPECT_EQ(ring->probe_wkc("outputs"), 0) << "the disconnect did not take effect";
  EXPECT_TRUE(stays(
      [&] {
        return ring->state() == MasterState::preop_ready && !ring->slave_fault("outputs") &&
               ring->slave_state("outputs") == SlaveState::preop;
      },
      300ms))
      << ring->describe();
  // Still cut off at the end of the window (the fault is sticky until cleared).
  EXPECT_EQ(ring->probe_wkc("outputs"), 0) << "the disconnect did not last the window";
  ring->server->clear_faults();
  EXPECT_EQ(ring->probe_wkc("outputs"), 1);
  EXPECT_TRUE(ring->all_slaves_in(SlaveState::preop));
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

TEST(Scenario48, HeldPreopSlaveReturnsToPreopNotOp) {
  RingSpec spec;
  spec.kind = RingKind::segmented;
  spec.targets["mailbox"] = TargetState::preop;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::preop);
  ring->forget_states();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::disconnect("mailbox")));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }))
      << ring->describe();
  EXPECT_TRUE(ring->slave_fault("mailbox"));
  // No process data: slave-local, the session stays operational.
  EXPECT_TRUE(stays([&] { return ring->state() == MasterState::operational; }, 100ms));
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("mailbox") == SlaveState::preop && !ring->slave_fault("mailbox");
  })) << ring->describe();
  // Its runtime target is min(session target OP, configured PREOP): it stays there.
  EXPECT_TRUE(stays([&] { return ring->slave_state("mailbox") == SlaveState::preop; }, 200ms));
  monitor.stop();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:mailbox:op").empty()) << monitor.seen();
  EXPECT_TRUE(ring->loopback(true));
}

// PREOP-first: every slave held, then reconfigured and activated.
master::SlaveConfig reconfigured(const std::string& name, TargetState target) {
  auto config = ring_config(held_spec(RingKind::segmented));
  for (auto& s : config.slaves) {
    if (s.name == name) {
      s.target = target;
      return s;
    }
  }
  ADD_FAILURE() << "no slave " << name;
  return {};
}

TEST(Scenario49, ActivationRestoresPollingOfAnOpTarget) {
  auto ring = running(held_spec(RingKind::segmented), MasterState::preop_ready);
  ASSERT_TRUE(ring);
  for (const char* name : {"inputs", "outputs", "mailbox"}) {
    auto done = ring->master->configure_slave(name, reconfigured(name, TargetState::op));
    ASSERT_TRUE(done) << name << ": " << done.error().describe();
  }
  auto active = ring->master->activate();
  ASSERT_TRUE(active) << active.error().describe();
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  EXPECT_EQ(ring->master->status().desired_target, TargetState::op);
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::op);
  ASSERT_TRUE(ring->server->inject(fault::disconnect("mailbox")));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }))
      << ring->describe();
  auto down = ring->slave_fault("mailbox");
  ASSERT_TRUE(down);
  EXPECT_EQ(down->rfind("down", 0), 0u) << *down;
  EXPECT_EQ(ring->state(), MasterState::operational);
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("mailbox") == SlaveState::op && !ring->slave_fault("mailbox");
  })) << ring->describe();
  EXPECT_FALSE(ring->saw(MasterState::recovering));
}

TEST(Scenario50, ActivationRestoresPollingOfHeldPreopSlaves) {
  auto ring = running(held_spec(RingKind::segmented), MasterState::preop_ready);
  ASSERT_TRUE(ring);
  for (const char* name : {"inputs", "outputs"}) {
    auto done = ring->master->configure_slave(name, reconfigured(name, TargetState::op));
    ASSERT_TRUE(done) << name << ": " << done.error().describe();
  }
  ASSERT_TRUE(ring->master->activate());
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::preop);
  ASSERT_TRUE(ring->server->inject(fault::disconnect("mailbox")));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }))
      << ring->describe();
  EXPECT_TRUE(ring->slave_fault("mailbox"));
  EXPECT_EQ(ring->state(), MasterState::operational);
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("mailbox") == SlaveState::preop && !ring->slave_fault("mailbox");
  })) << ring->describe();
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_TRUE(ring->loopback(true));
}

TEST(Scenario51, PollStaysSuppressedUntilActivation) {
  auto spec = held_spec(RingKind::segmented);
  spec.health_polls["mailbox"] = std::nullopt;
  auto ring = running(spec, MasterState::preop_ready);
  ASSERT_TRUE(ring);
  auto config = reconfigured("mailbox", TargetState::preop);
  config.health_poll = 20ms;
  ASSERT_TRUE(ring->master->configure_slave("mailbox", config));
  ASSERT_TRUE(ring->server->inject(fault::disconnect("mailbox")));
  EXPECT_TRUE(stays(
      [&] {
        return ring->state() == MasterState::preop_ready && !ring->slave_fault("mailbox") &&
               ring->slave_state("mailbox") == SlaveState::preop;
      },
      300ms))
      << ring->describe();
  ring->server->clear_faults();
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

// ---- 52: a CiA 402 drive; its SAFEOP retreat is slave-local -------------------------------------

std::string drive_state(master::Slave& drive) {
  const auto info = drive.info();
  const auto* v = info.device_state.find("state");
  if (!v) return "?";
  const auto* s = std::get_if<std::string>(v);
  return s ? *s : "?";
}

bool enable_drive(ScenarioRing& ring, master::Slave& drive, std::int64_t velocity) {
  using master::Value;
  if (!drive.command("set_mode", {{"mode", Value(std::string("csv"))}})) return false;
  for (const char* step : {"shutdown", "switch_on", "enable_operation"}) {
    if (!drive.command(step)) return false;
    const std::string want = std::string(step) == "shutdown"    ? "ready_to_switch_on"
                             : std::string(step) == "switch_on" ? "switched_on"
                                                                : "operation_enabled";
    if (!eventually([&] { return drive_state(drive) == want; }, 5s)) {
      ADD_FAILURE() << step << ": drive is " << drive_state(drive) << "; " << ring.describe();
      return false;
    }
  }
  return bool(drive.command("set_target", {{"velocity", Value(velocity)}}));
}

bool velocity_follows(master::Slave& drive, std::int64_t velocity) {
  return eventually([&] {
    auto v = drive.read_input("velocity_actual");
    auto n = v ? master::as_int64(*v) : std::nullopt;
    return n && std::abs(*n - velocity) <= std::abs(velocity) / 100 + 1;
  });
}

TEST(Scenario52, DriveRetreatIsSlaveLocalAndCommandsResume) {
  RingSpec spec;
  spec.kind = RingKind::servo;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& drive = ring->slave("drive");
  EXPECT_TRUE(eventually([&] { return drive_state(drive) == "switch_on_disabled"; }))
      << drive_state(drive);
  ASSERT_TRUE(enable_drive(*ring, drive, 1000));
  EXPECT_TRUE(velocity_follows(drive, 1000));

  ring->forget_states();
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(fault::retreat_to_safeop("drive")));
  ASSERT_TRUE(eventually([&] { return monitor.saw("fault:drive"); })) << monitor.seen();
  ASSERT_TRUE(eventually([&] {
    return ring->slave_state("drive") == SlaveState::op && !ring->slave_fault("drive");
  })) << ring->describe();
  monitor.stop();
  EXPECT_TRUE(monitor.saw("state:drive:safeop")) << monitor.seen();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << monitor.seen();
  // Back in OP the command flow and the feedback resume (the drive may have dropped out of
  // operation_enabled while its outputs were not applied: walk it up again when it did).
  if (drive_state(drive) != "operation_enabled") {
    if (drive_state(drive) == "fault") {
      ASSERT_TRUE(drive.command("fault_reset"));
    }
    ASSERT_TRUE(enable_drive(*ring, drive, -500));
  } else {
    ASSERT_TRUE(drive.command("set_target", {{"velocity", master::Value(std::int64_t{-500})}}));
  }
  EXPECT_TRUE(velocity_follows(drive, -500));
  EXPECT_EQ(ring->state(), MasterState::operational);
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

// ---- outputs routed nowhere --------------------------------------------------------------------

// The mailbox device has a 2-byte output SyncManager with the watchdog trigger on in its SII; the
// ring file routes none of its process data, so nothing ever writes it. It stays in OP past
// several watchdog times (100 ms): the master configures that SyncManager without the trigger.
TEST(SlaveHealth, SlaveWithOutputsRoutedNowhereStaysInOpPastItsWatchdogTime) {
  RingSpec spec;
  spec.kind = RingKind::segmented;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  std::this_thread::sleep_for(350ms);
  monitor.stop();
  EXPECT_FALSE(monitor.saw("state:mailbox:safeop")) << monitor.seen();
  EXPECT_TRUE(ring->all_slaves_in(SlaveState::op)) << ring->describe();
  EXPECT_FALSE(ring->any_slave_fault()) << ring->describe();
  ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    for (std::size_t i = 0; i < segment.size(); ++i) {
      EXPECT_EQ(segment.esc(i).read_u8(wire::reg::kWatchdogCounterProcessData), 0)
          << segment.name(i);
    }
  });
}

// A domain slower than a third of the ESC's 100 ms watchdog: the master raises the outputs
// terminal's watchdog to three periods, so it stays in OP between the domain's writes; set to 0
// in the configuration, the watchdog is off.
TEST(SlaveHealth, SlowDomainGetsAWatchdogOfThreePeriods) {
  for (const std::optional<std::chrono::nanoseconds> configured :
       {std::optional<std::chrono::nanoseconds>{}, std::optional<std::chrono::nanoseconds>{0}}) {
    SCOPED_TRACE(configured ? "watchdog off" : "watchdog from the period");
    RingSpec spec;
    spec.domain_period = 150ms;
    spec.adjust = [&](master::MasterConfig& config) {
      for (auto& slave : config.slaves)
        slave.watchdog = configured;
    };
    auto ring = ScenarioRing::operational(spec);
    ASSERT_TRUE(ring);
    Monitor monitor(*ring->master);
    std::this_thread::sleep_for(600ms);
    monitor.stop();
    EXPECT_FALSE(monitor.saw("state:outputs:safeop")) << monitor.seen();
    EXPECT_TRUE(ring->all_slaves_in(SlaveState::op)) << ring->describe();
    ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      for (std::size_t i = 0; i < segment.size(); ++i) {
        if (segment.name(i) != "outputs") continue;
        EXPECT_EQ(segment.esc(i).read_u16(wire::reg::kWatchdogTimeProcessData),
                  configured ? 0 : 4500);
        EXPECT_EQ(segment.esc(i).read_u8(wire::reg::kWatchdogCounterProcessData), 0);
      }
    });
  }
}

}  // namespace
}  // namespace ecat::scenarios
