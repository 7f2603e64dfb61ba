// Fault scenarios 12, 21, 22 and 24-37 (docs/scenarios/): a slave's PREOP
// configuration (its startup SDOs) fails at startup or when it is rebuilt after a reconnect. The
// failure is retained (the slave stays in PREOP, the failure visible with its named cause), the
// master blocks or recovers only where the reference does, and the failure heals through the
// master's retry loops, without a session restart.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <ecat/master/coe_client.hpp>
#include <ecat/sim/faults.hpp>

#include "scenarios/mailbox_support.hpp"

namespace ecat::scenarios {
namespace {

using sim::MailboxStage;
using sim::ProtocolFaultKind;

// The segmented ring (target OP) with `start_faults` already active when the master starts.
std::unique_ptr<ScenarioRing> segmented_with_start_faults(const std::vector<sim::Fault>& faults,
                                                          RingSpec spec = segmented_spec(false)) {
  std::string yaml = ring_yaml(RingKind::segmented) + "  faults:\n";
  for (const auto& f : faults)
    yaml += "    - " + sim::to_json(f) + "\n";
  spec.ring_yaml = yaml;
  return ScenarioRing::create(spec);
}

// The activation failure recorded for `slave`, if any.
std::optional<master::ActivationFailure> activation_failure(ScenarioRing& ring,
                                                            const std::string& slave) {
  for (const auto& f : ring.master->status().activation_failures) {
    if (f.slave == slave) return f;
  }
  return std::nullopt;
}

// Startup: the retained failure blocks activation, names its cause, and heals once cleared.
void expect_blocked_then_healed(ScenarioRing& ring, SdoFailure failure, const std::string& names) {
  ASSERT_TRUE(eventually([&] { return ring.state() == MasterState::activation_blocked; }, 10s))
      << ring.describe();
  auto f = activation_failure(ring, "mailbox");
  ASSERT_TRUE(f) << ring.describe();
  EXPECT_EQ(master::sdo_failure(f->error), failure) << f->error.describe();
  EXPECT_EQ(f->error.code(), Errc::wrong_state);
  EXPECT_THAT(f->error.describe(), ::testing::HasSubstr(names));
  EXPECT_EQ(ring.slave_state("mailbox"), SlaveState::preop);
  auto retained = configuration_error(ring, "mailbox");
  ASSERT_TRUE(retained);
  EXPECT_THAT(*retained, ::testing::HasSubstr(names));
  // The retained failure is the slave's fault in the session's summary.
  bool listed = false;
  for (const auto& s : ring.master->slaves())
    listed = listed || (s.name == "mailbox" && s.fault == retained);
  EXPECT_TRUE(listed) << ring.describe();
  // The other slaves reached OP.
  EXPECT_EQ(ring.slave_state("outputs"), SlaveState::op);

  ring.server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring.state() == MasterState::operational; }, 10s))
      << ring.describe();
  EXPECT_EQ(ring.slave_state("mailbox"), SlaveState::op);
  EXPECT_FALSE(configuration_error(ring, "mailbox"));
  EXPECT_TRUE(ring.master->status().activation_failures.empty());
  auto blob = ring.slave("mailbox").upload_sdo(0x2003, 1);
  ASSERT_TRUE(blob) << blob.error().describe();
  EXPECT_EQ(*blob, startup_blob());
  EXPECT_TRUE(ring.loopback(true));
  EXPECT_EQ(ring.master->status().illegal_transitions, 0u);
}

TEST(RetainedConfig, Scenario12_StartupSdoAbortBlocksActivationUntilCleared) {
  auto spec = segmented_spec(false);
  auto base = spec.adjust;
  spec.adjust = [base](master::MasterConfig& config) {
    base(config);
    for (auto& s : config.slaves) {
      if (s.name == "mailbox") s.startup_sdos.insert(s.startup_sdos.begin(), {0x2000, 0x02, {1}});
    }
  };
  auto ring = segmented_with_start_faults(
      {sim::fault::mailbox_abort("mailbox", 0x2000, 0x02, 0x06010002)}, spec);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::activation_blocked; }, 10s))
      << ring->describe();
  auto f = activation_failure(*ring, "mailbox");
  ASSERT_TRUE(f);
  EXPECT_EQ(master::sdo_abort_code(f->error), 0x06010002u) << f->error.describe();
  expect_blocked_then_healed(*ring, SdoFailure::aborted, "startup SDO 0x2000:02");
  auto flag = ring->slave("mailbox").upload_sdo(0x2000, 2);
  ASSERT_TRUE(flag);
  EXPECT_EQ(*flag, (Bytes{1}));
}

TEST(RetainedConfig, Scenario21_StartupSegmentedDownloadInvalidPayload) {
  // After the first segment of the startup download, every segment response of 0x2003:01 is
  // broken (sticky: each retry fails the same way until cleared).
  auto ring = segmented_with_start_faults({sim::fault::after_milestone(
      sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                         {ProtocolFaultKind::invalid_coe_payload, 0}),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 1))});
  ASSERT_TRUE(ring);
  expect_blocked_then_healed(*ring, SdoFailure::invalid_response, "startup SDO 0x2003:01");
}

TEST(RetainedConfig, Scenario22_StartupSegmentedDownloadResponseDropped) {
  auto ring = segmented_with_start_faults({sim::fault::after_milestone(
      sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                         {ProtocolFaultKind::drop_response, 0}),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 1))});
  ASSERT_TRUE(ring);
  expect_blocked_then_healed(*ring, SdoFailure::response_timeout, "startup SDO 0x2003:01");
}

// Reconnect scenarios: the mailbox-only slave (no process data) is cut off long enough for its
// health poll to find it down; when it is back, its rebuild's startup download fails on `rule`.
// The session stays operational with a healthy domain while the failure is retained; clearing the
// fault lets the master's slave retry re-run the PREOP configuration and bring the slave to OP.
void reconnect_with_retained_failure(const sim::Fault& rule, SdoFailure failure) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(rule));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("mailbox"), 60)));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }, 5s))
      << ring->describe();
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::preop);
  // Slave-local: the session stays operational, its domain cycles and process data flows.
  EXPECT_TRUE(stays([&] { return ring->state() == MasterState::operational; }, 200ms))
      << ring->describe();
  EXPECT_TRUE(ring->master->status().runtime_faults.empty()) << ring->describe();
  EXPECT_TRUE(ring->loopback(true));
  EXPECT_TRUE(configuration_error(*ring, "mailbox").has_value()) << "healed before the clear";
  // The failure is the slave's and keeps its named cause (a retry's refusal carries it).
  auto refused = ring->slave("mailbox").request(wire::AlState::op);
  ASSERT_FALSE(refused);
  EXPECT_EQ(master::sdo_failure(refused.error()), failure) << refused.error().describe();
  EXPECT_THAT(refused.error().describe(), ::testing::HasSubstr("startup SDO 0x2003:01"));

  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
  EXPECT_EQ(ring->state(), MasterState::operational);
  auto blob = ring->slave("mailbox").upload_sdo(0x2003, 1);
  ASSERT_TRUE(blob) << blob.error().describe();
  EXPECT_EQ(*blob, startup_blob());
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

TEST(RetainedConfig, Scenario24_ReconnectRebuildAbortRetainedThenRetried) {
  reconnect_with_retained_failure(
      sim::fault::mailbox_abort("mailbox", 0x2003, 0x01, 0x08000000, MailboxStage::request),
      SdoFailure::aborted);
}

TEST(RetainedConfig, Scenario25_ReconnectRebuildDownloadTimeout) {
  reconnect_with_retained_failure(
      sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                         {ProtocolFaultKind::drop_response, 0}),
      SdoFailure::response_timeout);
}

TEST(RetainedConfig, Scenario26_ReconnectRebuildMalformedSegmentAck) {
  reconnect_with_retained_failure(
      sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                         {ProtocolFaultKind::segment_command, 0x60}),
      SdoFailure::unexpected_segment_command);
}

TEST(RetainedConfig, Scenario28_ScriptedOneShotRebuildFaultSelfHeals) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  auto window = sim::fault::disconnect("mailbox");
  window.exchanges = 60;
  ASSERT_TRUE(ring->server->inject(sim::fault::script(
      {window,
       sim::fault::wait_for(sim::fault::mailbox_step("mailbox", MailboxStage::download_init, 1)),
       sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                          {ProtocolFaultKind::invalid_coe_payload, 0})})));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }, 5s))
      << ring->describe();
  // The rebuild's download fails once: retained, while the script has already run out.
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  EXPECT_THAT(*configuration_error(*ring, "mailbox"), ::testing::HasSubstr("0x2003:01"));
  EXPECT_TRUE(ring->fault_queue_drained());
  EXPECT_EQ(ring->state(), MasterState::operational);
  // No clear: the master's retry heals it.
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
  auto blob = ring->slave("mailbox").upload_sdo(0x2003, 1);
  ASSERT_TRUE(blob) << blob.error().describe();
  EXPECT_EQ(*blob, startup_blob());
  EXPECT_FALSE(ring->saw(MasterState::recovering));
}

TEST(RetainedConfig, Scenario33_ProcessDataMailboxSlaveRebuildFailureKeepsRecovering) {
  // The mailbox slave carries process data here: its loss is critical.
  auto spec = segmented_spec(false);
  auto base = spec.adjust;
  spec.adjust = [base](master::MasterConfig& config) {
    base(config);
    for (auto& s : config.slaves) {
      if (s.name == "mailbox") {
        s.process_data = master::ProcessDataRequest::all("main");
      }
    }
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  ring->forget_states();
  auto window = sim::fault::disconnect("mailbox");
  window.exchanges = 60;
  ASSERT_TRUE(ring->server->inject(sim::fault::script(
      {window,
       sim::fault::wait_for(sim::fault::mailbox_step("mailbox", MailboxStage::download_init, 1)),
       sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                          {ProtocolFaultKind::drop_response, 0})})));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }, 5s))
      << ring->describe();
  // The first rebuild fails (timeout) and is retained; the session keeps recovering meanwhile.
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->state(), MasterState::recovering);
  EXPECT_FALSE(ring->master->status().runtime_faults.empty());
  // A later retry heals the slave, its runtime fault, and the session.
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::op);
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
  EXPECT_TRUE(ring->master->status().runtime_faults.empty());
  EXPECT_TRUE(ring->loopback(true));
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

TEST(RetainedConfig, Scenario37_SplitDomainRtdRebuildTimeoutLeavesMainHealthy) {
  auto ring = ScenarioRing::operational(hardware_spec(/*split=*/true));
  ASSERT_TRUE(ring);
  auto rtd = ring->slave("rtd").read_input("channel_1.temperature");
  ASSERT_TRUE(eventually([&] {
    return ring->slave("rtd").read_input("channel_1.temperature").ok();
  })) << (rtd ? "" : rtd.error().describe());
  ASSERT_TRUE(ring->server->inject(sim::fault::mailbox_protocol_fault(
      "rtd", 0x8010, 0x19, MailboxStage::download_init, {ProtocolFaultKind::drop_response, 0})));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("rtd"), 60)));
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "rtd").has_value(); }, 10s))
      << ring->describe();
  EXPECT_THAT(*configuration_error(*ring, "rtd"), ::testing::HasSubstr("0x8010:19"));
  EXPECT_EQ(ring->slave_state("rtd"), SlaveState::preop);
  // The digital I/O's domain keeps cycling validly and carries the loopback.
  const auto before = ring->domain_stats("main");
  EXPECT_TRUE(ring->loopback(true));
  EXPECT_TRUE(ring->loopback(false));
  EXPECT_TRUE(
      eventually([&] { return ring->domain_stats("main").valid_count > before.valid_count + 10; }));
  EXPECT_EQ(ring->slave_state("outputs"), SlaveState::op);
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("rtd") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_FALSE(configuration_error(*ring, "rtd"));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 10s))
      << ring->describe();
  EXPECT_TRUE(
      eventually([&] { return ring->slave("rtd").read_input("channel_1.temperature").ok(); }));
}

// A disconnect window of the mailbox slave long enough for its health poll to find it down.
sim::Fault mailbox_window() {
  auto window = sim::fault::disconnect("mailbox");
  window.exchanges = 60;
  return window;
}

sim::Fault sticky(sim::Fault fault) {
  fault.effect.once = false;
  return fault;
}

bool retained_contains(ScenarioRing& ring, const std::string& slave, const std::string& text) {
  auto retained = configuration_error(ring, slave);
  return retained && retained->find(text) != std::string::npos;
}

TEST(RetainedConfig, Scenario27_ReconnectRebuildMalformedFinalAckAfterCommit) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  // Another value first, so that the rebuild's write can be seen to have been committed.
  ASSERT_TRUE(ring->slave("mailbox").download_sdo(0x2003, 1, default_0x2003()));
  ASSERT_TRUE(ring->server->inject(sim::fault::script(
      {mailbox_window(),
       sim::fault::wait_for(sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 2)),
       sticky(sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01,
                                                 MailboxStage::download_segment,
                                                 {ProtocolFaultKind::segment_command, 0x60}))})));
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  auto refused = ring->slave("mailbox").request(wire::AlState::op);
  ASSERT_FALSE(refused);
  EXPECT_EQ(master::sdo_failure(refused.error()), SdoFailure::unexpected_segment_command)
      << refused.error().describe();
  // The slave committed the rebuild's write before its broken final acknowledgement.
  auto blob = ring->slave("mailbox").upload_sdo(0x2003, 1);
  ASSERT_TRUE(blob) << blob.error().describe();
  EXPECT_EQ(*blob, startup_blob());
  EXPECT_EQ(ring->state(), MasterState::operational);
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
}

TEST(RetainedConfig, Scenario29_SuccessiveOneShotRebuildFaultsReplaceEachOther) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  const auto init_read = sim::fault::mailbox_step("mailbox", MailboxStage::download_init, 1);
  ASSERT_TRUE(ring->server->inject(sim::fault::script(
      {mailbox_window(), sim::fault::wait_for(init_read),
       sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                          {ProtocolFaultKind::drop_response, 0}),
       sim::fault::wait_for(init_read),
       sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                          {ProtocolFaultKind::invalid_coe_payload, 0})})));
  // First: the timeout is retained while the second fault still waits in the script.
  ASSERT_TRUE(eventually([&] { return retained_contains(*ring, "mailbox", "no reply"); }, 10s))
      << ring->describe();
  EXPECT_FALSE(ring->fault_queue_drained());
  // Then the retry's failure replaces it.
  ASSERT_TRUE(eventually(
      [&] { return retained_contains(*ring, "mailbox", "no complete CoE header"); }, 10s))
      << ring->describe();
  EXPECT_FALSE(retained_contains(*ring, "mailbox", "no reply"));
  // A later retry heals without a clear.
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_TRUE(ring->fault_queue_drained());
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
  auto blob = ring->slave("mailbox").upload_sdo(0x2003, 1);
  ASSERT_TRUE(blob) << blob.error().describe();
  EXPECT_EQ(*blob, startup_blob());
  EXPECT_EQ(ring->state(), MasterState::operational);
}

// A retained mailbox failure (sticky abort on its rebuild download), then `follow_up` once it is
// visible: the outputs' loss is critical and heals first; the mailbox heals after the clear.
void retained_mailbox_then_outputs_disconnect(bool armed_on_the_failure) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(
      sim::fault::mailbox_abort("mailbox", 0x2003, 0x01, 0x08000000, MailboxStage::request)));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("mailbox"), 60)));
  if (armed_on_the_failure) {
    ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
        << ring->describe();
  } else {
    ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::down; }, 5s))
        << ring->describe();
    ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
        << ring->describe();
    std::this_thread::sleep_for(100ms);  // "later": the retained failure has stood a while
  }
  ring->forget_states();
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("outputs"), 30)));
  // Seen in the state history, not by sampling: on a loaded machine the session may be back
  // in operational before a poll looks.
  ASSERT_TRUE(eventually([&] { return ring->saw(MasterState::recovering); }, 5s))
      << ring->describe();
  // Outputs heal first: operational again while the mailbox failure is still retained.
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->slave_state("outputs"), SlaveState::op);
  EXPECT_TRUE(configuration_error(*ring, "mailbox").has_value());
  EXPECT_EQ(ring->slave_state("mailbox"), SlaveState::preop);
  EXPECT_TRUE(ring->loopback(true));
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_FALSE(configuration_error(*ring, "mailbox"));
  EXPECT_EQ(ring->state(), MasterState::operational);
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

TEST(RetainedConfig, Scenario31_OutputsHealFirstWhileMailboxFailureIsRetained) {
  retained_mailbox_then_outputs_disconnect(false);
}

TEST(RetainedConfig, Scenario34_RetainedFailureArmsOutputsDisconnect) {
  retained_mailbox_then_outputs_disconnect(true);
}

TEST(RetainedConfig, Scenario30_RetainedMailboxTimeoutAndOutputsRetreatCoexist) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->server->inject(
      sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                                         {ProtocolFaultKind::drop_response, 0})));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("mailbox"), 60)));
  // Armed on the mailbox's fault becoming visible: the outputs retreat to SAFEOP.
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  ASSERT_TRUE(ring->server->inject(sim::fault::retreat_to_safeop("outputs")));
  // Two slave-local faults side by side; the session stays operational.
  EXPECT_TRUE(stays([&] { return ring->state() == MasterState::operational; }, 300ms))
      << ring->describe();
  EXPECT_TRUE(configuration_error(*ring, "mailbox").has_value());
  // The outputs' retry brings them back while the mailbox failure stands.
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_TRUE(ring->loopback(true));
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->state(), MasterState::operational);
  EXPECT_FALSE(ring->saw(MasterState::recovering));
}

// Scenarios 32 and 35: the inputs' retreat to SAFEOP, injected while the session recovers, must
// be seen. The inputs are input-only: in SAFEOP they still answer their share of the LRW, so the
// domain stays valid, and the recovery's re-activation walks every slave to OP anyway (it reads
// SAFEOP on the way, a state the monitor may or may not sample): a master whose health poll
// missed the retreat would pass the other checks. Seen: the inputs' poll reported that they left
// OP (their fault names the state it found; it stands until the slave retry brings them back).
// Then the device is in OP again, as the master says.
void expect_inputs_retreat_seen(ScenarioRing& ring, const Monitor& monitor) {
  EXPECT_TRUE(eventually([&] {
    return !monitor.matching("fault:inputs:left OP (AL status SAFEOP").empty();
  })) << "the inputs' retreat never showed in the API: "
      << monitor.seen();
  EXPECT_TRUE(eventually([&] { return ring.device_state("inputs") == wire::AlState::op; }))
      << "the simulated inputs stayed in "
      << wire::to_string(ring.device_state("inputs").value_or(wire::AlState::init))
      << " while the master reports " << ring.describe();
}

TEST(RetainedConfig, Scenario32_RetreatArmedOnRecoveringLandsDuringRecovery) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("outputs"), 30)));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }, 5s))
      << ring->describe();
  ASSERT_TRUE(ring->server->inject(sim::fault::retreat_to_safeop("inputs")));
  ASSERT_TRUE(eventually(
      [&] {
        return ring->state() == MasterState::operational &&
               ring->slave_state("inputs") == SlaveState::op &&
               ring->slave_state("outputs") == SlaveState::op;
      },
      10s))
      << ring->describe();
  expect_inputs_retreat_seen(*ring, monitor);
  EXPECT_TRUE(ring->loopback(true));
  EXPECT_TRUE(ring->loopback(false));
  EXPECT_EQ(ring->master->status().illegal_transitions, 0u);
}

TEST(RetainedConfig, Scenario35_ChainedFaultsOutputsHealFirst) {
  auto ring = start_segmented(/*held_in_preop=*/false);
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->inject(
      sim::fault::mailbox_abort("mailbox", 0x2003, 0x01, 0x08000000, MailboxStage::request)));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("mailbox"), 60)));
  // Mailbox PREOP failure -> outputs disconnect -> recovering -> inputs retreat.
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "mailbox").has_value(); }, 10s))
      << ring->describe();
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("outputs"), 30)));
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::recovering; }, 5s))
      << ring->describe();
  ASSERT_TRUE(ring->server->inject(sim::fault::retreat_to_safeop("inputs")));
  ASSERT_TRUE(eventually(
      [&] {
        return ring->state() == MasterState::operational &&
               ring->slave_state("outputs") == SlaveState::op &&
               ring->slave_state("inputs") == SlaveState::op;
      },
      10s))
      << ring->describe();
  expect_inputs_retreat_seen(*ring, monitor);
  EXPECT_TRUE(configuration_error(*ring, "mailbox").has_value());
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("mailbox") == SlaveState::op; }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->state(), MasterState::operational);
  EXPECT_TRUE(ring->loopback(true));
}

TEST(RetainedConfig, Scenario36_SharedDomainRtdKeepsTheSessionRecovering) {
  auto ring = ScenarioRing::operational(hardware_spec(/*split=*/false));
  ASSERT_TRUE(ring);
  ASSERT_TRUE(
      eventually([&] { return ring->slave("rtd").read_input("channel_1.temperature").ok(); }));
  // The rebuild's second startup SDO (0x8010:19) gets no reply: retained.
  ASSERT_TRUE(ring->server->inject(sim::fault::mailbox_protocol_fault(
      "rtd", 0x8010, 0x19, MailboxStage::download_init, {ProtocolFaultKind::drop_response, 0})));
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("rtd"), 60)));
  ASSERT_TRUE(eventually([&] { return configuration_error(*ring, "rtd").has_value(); }, 10s))
      << ring->describe();
  EXPECT_THAT(*configuration_error(*ring, "rtd"), ::testing::HasSubstr("0x8010:19"));
  // Armed on it: the outputs are cut off for a while (long enough for two failed polls).
  ASSERT_TRUE(ring->server->inject(sim::fault::next(sim::fault::disconnect("outputs"), 150)));
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::down; }, 5s))
      << ring->describe();
  ASSERT_TRUE(eventually([&] { return ring->slave_state("outputs") == SlaveState::op; }, 10s))
      << ring->describe();
  // Outputs are back, but the RTD shares the domain: the session keeps recovering.
  EXPECT_TRUE(stays([&] { return ring->state() == MasterState::recovering; }, 200ms))
      << ring->describe();
  ring->server->clear_faults();
  ASSERT_TRUE(eventually([&] { return ring->state() == MasterState::operational; }, 10s))
      << ring->describe();
  EXPECT_EQ(ring->slave_state("rtd"), SlaveState::op);
  EXPECT_TRUE(ring->loopback(true));
  EXPECT_TRUE(
      eventually([&] { return ring->slave("rtd").read_input("channel_1.temperature").ok(); }));
}

}  // namespace
}  // namespace ecat::scenarios
