// Fault scenarios 06, 10, 15-20 and 23 (docs/scenarios/): a slave's mailbox misbehaves during
// public SDO transfers on a session held in PREOP. Every fault comes out of upload_sdo /
// download_sdo as its own named SdoFailure (with the exact abort code for aborts), the session
// stays preop_ready with no slave fault, objects are only changed by transfers the slave
// completed, and the next transfer after clear_faults() works without a restart.
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <ecat/master/coe_client.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/wire/sdo_abort.hpp>

#include "scenarios/mailbox_support.hpp"

namespace ecat::scenarios {
namespace {

using sim::MailboxStage;
using sim::ProtocolFaultKind;

class MailboxFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    ring_ = start_segmented(/*held_in_preop=*/true);
    ASSERT_TRUE(ring_);
    // The startup download went through: the blob is in 0x2003:01.
    auto blob = mbx().upload_sdo(0x2003, 1);
    ASSERT_TRUE(blob) << blob.error().describe();
    ASSERT_EQ(*blob, startup_blob());
  }

  master::Slave& mbx() { return ring_->slave("mailbox"); }

  void inject(const sim::Fault& fault) {
    auto injected = ring_->server->inject(fault);
    ASSERT_TRUE(injected) << injected.error().describe();
  }

  // The session did not degrade: still preop_ready, no slave fault, nothing retained.
  void expect_undisturbed() {
    EXPECT_EQ(ring_->state(), MasterState::preop_ready) << ring_->describe();
    EXPECT_FALSE(ring_->any_slave_fault()) << ring_->describe();
    EXPECT_EQ(mbx().state(), SlaveState::preop);
    EXPECT_FALSE(configuration_error(*ring_, "mailbox"));
    EXPECT_TRUE(ring_->master->status().runtime_faults.empty());
  }

  Bytes upload(std::uint16_t index, std::uint8_t subindex) {
    auto value = mbx().upload_sdo(index, subindex);
    EXPECT_TRUE(value) << value.error().describe();
    return value ? *value : Bytes{};
  }

  std::unique_ptr<ScenarioRing> ring_;
};

void expect_abort(const Result<void>& result, std::uint32_t code, const std::string& what) {
  ASSERT_FALSE(result);
  EXPECT_EQ(master::sdo_failure(result.error()), SdoFailure::aborted);
  EXPECT_EQ(result.error().code(), Errc::sdo_abort);
  EXPECT_EQ(master::sdo_abort_code(result.error()), code);
  EXPECT_EQ(result.error().message(),
            fmt::format("{} aborted: 0x{:08X} {}", what, code, wire::sdo_abort_text(code)));
}

void expect_abort(const Result<Bytes>& result, std::uint32_t code, const std::string& what) {
  ASSERT_FALSE(result);
  expect_abort(Result<void>(result.error()), code, what);
}

TEST_F(MailboxFaults, Scenario06_PublicUploadAbortKeepsPreopReady) {
  inject(sim::fault::mailbox_abort("mailbox", 0x2000, 0x01, 0x06010002));
  expect_abort(mbx().upload_sdo(0x2000, 1), 0x06010002, "SDO upload 0x2000:01 of slave 0x1003");
  // Sticky until cleared: the same abort again, nothing restarted.
  expect_abort(mbx().upload_sdo(0x2000, 1), 0x06010002, "SDO upload 0x2000:01 of slave 0x1003");
  expect_undisturbed();
  ring_->server->clear_faults();
  EXPECT_EQ(upload(0x2000, 1), (Bytes{0x34, 0x12}));
  expect_undisturbed();
}

TEST_F(MailboxFaults, Scenario10_SegmentedTransferAbortsLeaveTheObject) {
  inject(
      sim::fault::mailbox_abort("mailbox", 0x2002, 0x01, 0x08000000, MailboxStage::upload_segment));
  expect_abort(mbx().upload_sdo(0x2002, 1), 0x08000000, "SDO upload 0x2002:01 of slave 0x1003");
  ring_->server->clear_faults();
  inject(sim::fault::mailbox_abort("mailbox", 0x2002, 0x01, 0x08000000,
                                   MailboxStage::download_segment));
  expect_abort(mbx().download_sdo(0x2002, 1, pattern(80, 3)), 0x08000000,
               "SDO download 0x2002:01 of slave 0x1003");
  expect_undisturbed();
  ring_->server->clear_faults();
  // The aborted download changed nothing; after the clear both directions work.
  EXPECT_EQ(upload(0x2002, 1), default_0x2002());
  ASSERT_TRUE(mbx().download_sdo(0x2002, 1, pattern(80, 3)));
  EXPECT_EQ(upload(0x2002, 1), pattern(80, 3));
  expect_undisturbed();
}

TEST_F(MailboxFaults, Scenario15_MilestoneArmedAbortHitsTheThirdSegment) {
  // Upload of 0x2003:01 (192 bytes): initiate + 3 segments. Armed after two segment responses
  // were read, the abort answers the third segment request.
  const auto before = coe_stats(*ring_->server, "mailbox");
  inject(sim::fault::after_milestone(
      sim::fault::mailbox_abort("mailbox", 0x2003, 0x01, 0x08000000, MailboxStage::upload_segment),
      sim::fault::mailbox_step("mailbox", MailboxStage::upload_segment, 2)));
  EXPECT_EQ(ring_->server->fault_info().scheduled.size(), 1u);
  expect_abort(mbx().upload_sdo(0x2003, 1), 0x08000000, "SDO upload 0x2003:01 of slave 0x1003");
  const auto after = coe_stats(*ring_->server, "mailbox");
  const auto slot = stage_slot(MailboxStage::upload_segment);
  EXPECT_EQ(after.stage_responses_read[slot] - before.stage_responses_read[slot], 2u);
  EXPECT_EQ(after.aborts_sent - before.aborts_sent, 1u);
  EXPECT_TRUE(ring_->fault_queue_drained());
  ring_->server->clear_faults();
  EXPECT_EQ(upload(0x2003, 1), startup_blob());

  // Download variant: the third segment is refused, the object keeps its value.
  inject(sim::fault::after_milestone(
      sim::fault::mailbox_abort("mailbox", 0x2003, 0x01, 0x08000000,
                                MailboxStage::download_segment),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 2)));
  const auto before_down = coe_stats(*ring_->server, "mailbox");
  expect_abort(mbx().download_sdo(0x2003, 1, default_0x2003()), 0x08000000,
               "SDO download 0x2003:01 of slave 0x1003");
  const auto after_down = coe_stats(*ring_->server, "mailbox");
  const auto down = stage_slot(MailboxStage::download_segment);
  EXPECT_EQ(after_down.stage_responses_read[down] - before_down.stage_responses_read[down], 2u);
  expect_undisturbed();
  ring_->server->clear_faults();
  EXPECT_EQ(upload(0x2003, 1), startup_blob());
  ASSERT_TRUE(mbx().download_sdo(0x2003, 1, default_0x2003()));
  EXPECT_EQ(upload(0x2003, 1), default_0x2003());
}

TEST_F(MailboxFaults, Scenario16_CounterAndToggleMismatch) {
  inject(sim::fault::mailbox_protocol_fault("mailbox", 0x2001, 0x01, MailboxStage::upload_init,
                                            {ProtocolFaultKind::counter_mismatch, 0}));
  auto counter = mbx().upload_sdo(0x2001, 1);
  ASSERT_FALSE(counter);
  EXPECT_EQ(failure_of(counter), SdoFailure::counter_mismatch) << counter.error().describe();
  EXPECT_EQ(counter.error().code(), Errc::mailbox_error);
  EXPECT_THAT(counter.error().message(),
              ::testing::MatchesRegex("SDO upload 0x2001:01 of slave 0x1003: the reply of slave "
                                      "0x1003 carries mailbox counter [1-7], expected [1-7] .*"));
  expect_undisturbed();

  inject(sim::fault::mailbox_protocol_fault("mailbox", 0x2003, 0x01, MailboxStage::upload_segment,
                                            {ProtocolFaultKind::toggle_mismatch, 0}));
  auto toggle = mbx().upload_sdo(0x2003, 1);
  ASSERT_FALSE(toggle);
  EXPECT_EQ(failure_of(toggle), SdoFailure::toggle_mismatch) << toggle.error().describe();
  EXPECT_EQ(toggle.error().message(),
            "SDO upload 0x2003:01 of slave 0x1003: upload segment 1 carries toggle bit 1, "
            "expected 0");
  expect_undisturbed();

  ring_->server->clear_faults();
  const std::string hello = "hello-sim";
  Bytes expected(hello.begin(), hello.end());
  expected.resize(12, 0);
  EXPECT_EQ(upload(0x2001, 1), expected);
  EXPECT_EQ(upload(0x2003, 1), startup_blob());
}

TEST_F(MailboxFaults, Scenario17_WrongMailboxTypeAndCoeService) {
  inject(protocol_fault_once("mailbox", 0x2001, 0x01, MailboxStage::upload_init,
                             ProtocolFaultKind::mailbox_type, 0x04));
  auto type = mbx().upload_sdo(0x2001, 1);
  EXPECT_EQ(failure_of(type), SdoFailure::unexpected_mailbox_type);
  ASSERT_FALSE(type);
  EXPECT_EQ(type.error().message(),
            "SDO upload 0x2001:01 of slave 0x1003: slave 0x1003 answered with a FoE mailbox (type "
            "4) instead of CoE");

  inject(protocol_fault_once("mailbox", 0x2001, 0x01, MailboxStage::upload_init,
                             ProtocolFaultKind::coe_service, 0x02));
  auto service = mbx().upload_sdo(0x2001, 1);
  EXPECT_EQ(failure_of(service), SdoFailure::unexpected_coe_service);
  ASSERT_FALSE(service);
  EXPECT_EQ(service.error().message(),
            "SDO upload 0x2001:01 of slave 0x1003: slave 0x1003 answered with CoE service 2 (SDO "
            "request), expected 3 (SDO response) or an abort");
  expect_undisturbed();
  EXPECT_EQ(upload(0x2001, 1).size(), 12u);
}

TEST_F(MailboxFaults, Scenario18_InvalidCoePayloadAndUnexpectedSdoCommand) {
  inject(protocol_fault_once("mailbox", 0x2001, 0x01, MailboxStage::upload_init,
                             ProtocolFaultKind::invalid_coe_payload));
  auto payload = mbx().upload_sdo(0x2001, 1);
  EXPECT_EQ(failure_of(payload), SdoFailure::invalid_response);
  ASSERT_FALSE(payload);
  EXPECT_EQ(payload.error().message(),
            "SDO upload 0x2001:01 of slave 0x1003: the reply of slave 0x1003 has no complete CoE "
            "header (1 bytes of mailbox data)");

  inject(protocol_fault_once("mailbox", 0x2001, 0x01, MailboxStage::upload_init,
                             ProtocolFaultKind::sdo_command, 0x60));
  auto command = mbx().upload_sdo(0x2001, 1);
  EXPECT_EQ(failure_of(command), SdoFailure::unexpected_sdo_command);
  ASSERT_FALSE(command);
  EXPECT_EQ(command.error().message(),
            "SDO upload 0x2001:01 of slave 0x1003: the slave answered with an SDO initiate "
            "download response instead of an initiate upload response");
  expect_undisturbed();
  EXPECT_EQ(upload(0x2001, 1).size(), 12u);
}

TEST_F(MailboxFaults, Scenario19_InvalidSegmentPaddingAndSegmentCommand) {
  inject(protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::upload_segment,
                             ProtocolFaultKind::invalid_segment_padding));
  auto padding = mbx().upload_sdo(0x2003, 1);
  EXPECT_EQ(failure_of(padding), SdoFailure::invalid_segment_padding);
  ASSERT_FALSE(padding);
  EXPECT_EQ(padding.error().message(),
            "SDO upload 0x2003:01 of slave 0x1003: upload segment 1 declares 7 unused bytes: it "
            "carries no data");

  inject(protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::upload_segment,
                             ProtocolFaultKind::segment_command, 0x20));
  auto command = mbx().upload_sdo(0x2003, 1);
  EXPECT_EQ(failure_of(command), SdoFailure::unexpected_segment_command);
  ASSERT_FALSE(command);
  EXPECT_EQ(command.error().message(),
            "SDO upload 0x2003:01 of slave 0x1003: slave 0x1003 answered with SDO command 0x20 "
            "(download segment response) instead of the expected upload segment response (3 "
            "bytes: 00 30 20)");
  expect_undisturbed();
  EXPECT_EQ(upload(0x2003, 1), startup_blob());
}

TEST_F(MailboxFaults, Scenario20_DownloadSegmentFaultsMidTransferAndOnTheFinalAck) {
  // Mid-transfer: the second segment's response is broken; the master aborts, the slave drops
  // the transfer, the object keeps its value.
  inject(sim::fault::after_milestone(
      protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                          ProtocolFaultKind::invalid_coe_payload),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 1)));
  auto mid = mbx().download_sdo(0x2003, 1, default_0x2003());
  EXPECT_EQ(failure_of(mid), SdoFailure::invalid_response);
  EXPECT_EQ(upload(0x2003, 1), startup_blob());
  expect_undisturbed();

  // Final acknowledgement: the slave committed the value before its broken last response; the
  // master reports the broken response all the same (it cannot know).
  inject(sim::fault::after_milestone(
      protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                          ProtocolFaultKind::segment_command, 0x60),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 2)));
  auto last = mbx().download_sdo(0x2003, 1, default_0x2003());
  EXPECT_EQ(failure_of(last), SdoFailure::unexpected_segment_command);
  ASSERT_FALSE(last);
  EXPECT_THAT(last.error().message(),
              ::testing::HasSubstr("answered with SDO command 0x60 (initiate download response) "
                                   "instead of the expected download segment response"));
  EXPECT_EQ(upload(0x2003, 1), default_0x2003());
  expect_undisturbed();
  EXPECT_TRUE(ring_->fault_queue_drained());
}

TEST_F(MailboxFaults, Scenario23_DroppedResponsesTimeOut) {
  inject(sim::fault::after_milestone(
      protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::upload_segment,
                          ProtocolFaultKind::drop_response),
      sim::fault::mailbox_step("mailbox", MailboxStage::upload_segment, 2)));
  auto up = mbx().upload_sdo(0x2003, 1, quick_sdo());
  EXPECT_EQ(failure_of(up), SdoFailure::response_timeout);
  ASSERT_FALSE(up);
  EXPECT_EQ(up.error().code(), Errc::timeout);

  inject(sim::fault::after_milestone(
      protocol_fault_once("mailbox", 0x2003, 0x01, MailboxStage::download_segment,
                          ProtocolFaultKind::drop_response),
      sim::fault::mailbox_step("mailbox", MailboxStage::download_segment, 1)));
  auto down = mbx().download_sdo(0x2003, 1, default_0x2003(), quick_sdo());
  EXPECT_EQ(failure_of(down), SdoFailure::response_timeout);
  ASSERT_FALSE(down);
  EXPECT_EQ(down.error().code(), Errc::timeout);
  expect_undisturbed();
  ring_->server->clear_faults();
  EXPECT_EQ(upload(0x2003, 1), startup_blob());
  ASSERT_TRUE(mbx().download_sdo(0x2003, 1, default_0x2003()));
  EXPECT_EQ(upload(0x2003, 1), default_0x2003());
}

}  // namespace
}  // namespace ecat::scenarios
