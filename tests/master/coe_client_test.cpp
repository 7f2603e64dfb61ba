// The CoE client against the simulator's servo, mailbox and EL3202 devices: every SDO transfer
// kind in both directions (checked against the slave's object dictionary), complete access, SDO
// information, aborts with their exact codes and texts, injected mailbox faults, concurrent
// transfers on one and on eight slaves, and emergencies collected on the way.
#include <cstdint>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/coe_client.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/sim/coe_server.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/object_dictionary.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/sdo_abort.hpp>
#include <ecat/wire/sdo_info.hpp>

#include "master/master_test_support.hpp"

namespace ecat::master {
namespace {

using namespace std::chrono_literals;
using test::SimBench;
using Bytes = std::vector<std::uint8_t>;

constexpr const char* kRing = R"(version: 1
simulator:
  slaves:
    - {name: drive, profile: servo}
    - {name: mbx, profile: mailbox}
    - {name: temp, profile: EL3202}
)";

Bytes pattern(std::size_t n, unsigned step, unsigned offset = 0) {
  Bytes out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>((i * step + offset) & 0xFF);
  return out;
}

class CoeClientTest : public ::testing::Test {
 protected:
  void SetUp() override {
    bench_ = SimBench::make(kRing);
    ASSERT_TRUE(bench_);
    auto configs = bench_->run(test::bring_all_to_preop(bench_->loop, *bench_->bus, 3));
    ASSERT_TRUE(configs.ok()) << configs.error().describe();
    for (std::size_t i = 0; i < 3; ++i) {
      mailboxes_.push_back(std::make_unique<Mailbox>(bench_->loop, *bench_->bus,
                                                     test::station_at(i), (*configs)[i]));
    }
  }

  Mailbox& drive() { return *mailboxes_[0]; }
  Mailbox& mbx() { return *mailboxes_[1]; }
  Mailbox& temp() { return *mailboxes_[2]; }

  template <class T>
  T run(exec::Task<T> task) {
    return bench_->run(std::move(task));
  }

  // The stored bytes of an entry in a slave's object dictionary (read under the server's lock).
  Bytes od_value(std::size_t position, std::uint16_t index, std::uint8_t subindex) {
    return bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      auto* coe = sim::coe_server_of(segment.esc(position));
      auto value = coe->dictionary().value(index, subindex);
      return value ? Bytes(value->begin(), value->end()) : Bytes{};
    });
  }
  sim::CoeServerStats coe_stats(std::size_t position) {
    return bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      return sim::coe_server_of(segment.esc(position))->stats();
    });
  }
  void inject(const sim::Fault& fault) {
    auto injected = bench_->server->inject(fault);
    ASSERT_TRUE(injected.ok()) << injected.error().describe();
  }

  std::unique_ptr<SimBench> bench_;
  std::vector<std::unique_ptr<Mailbox>> mailboxes_;
};

// ---- transfer kinds ------------------------------------------------------------------------

TEST_F(CoeClientTest, ExpeditedUploadAndDownload) {
  auto value = run(upload<std::uint16_t>(mbx(), 0x2000, 1));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, 0x1234);
  ASSERT_TRUE(run(download<std::uint16_t>(mbx(), 0x2000, 1, 0xBEEF)).ok());
  EXPECT_EQ(od_value(1, 0x2000, 1), (Bytes{0xEF, 0xBE}));
  auto back = run(upload_sdo(mbx(), 0x2000, 1));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, (Bytes{0xEF, 0xBE}));
  ASSERT_TRUE(run(download<std::uint8_t>(mbx(), 0x2000, 2, 0x5A)).ok());
  EXPECT_EQ(od_value(1, 0x2000, 2), (Bytes{0x5A}));
  // 32-bit values from the servo and the EL3202 (identity object).
  auto vendor = run(upload<std::uint32_t>(drive(), 0x1018, 1));
  ASSERT_TRUE(vendor.ok()) << vendor.error().describe();
  EXPECT_EQ(*vendor, 0x00000ACEu);
  auto product = run(upload<std::uint32_t>(temp(), 0x1018, 2));
  ASSERT_TRUE(product.ok()) << product.error().describe();
  EXPECT_EQ(*product, 0x0C823052u);
  ASSERT_TRUE(run(download<std::int32_t>(drive(), 0x607A, 0, -123456)).ok());
  auto target = run(upload<std::int32_t>(drive(), 0x607A, 0));
  ASSERT_TRUE(target.ok());
  EXPECT_EQ(*target, -123456);
  EXPECT_EQ(od_value(0, 0x607A, 0), sim::to_le_bytes<std::int32_t>(-123456));
  // The typed helper insists on the exact size.
  auto wrong = run(upload<std::uint32_t>(mbx(), 0x2000, 1));
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(wrong.error().message(),
            "SDO upload 0x2000:01 of slave 0x1002: the slave sent 2 bytes, expected 4");
}

TEST_F(CoeClientTest, NormalTransfersThatFitOneMailbox) {
  // 12 bytes: more than expedited, less than the 48 a 64-byte mailbox carries in one message.
  Bytes hello{'h', 'e', 'l', 'l', 'o', '-', 's', 'i', 'm', 0, 0, 0};
  const auto before = coe_stats(1).requests_served;
  auto value = run(upload_sdo(mbx(), 0x2001, 1));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, hello);
  Bytes fresh = pattern(12, 3, 1);
  ASSERT_TRUE(run(download_sdo(mbx(), 0x2001, 1, fresh)).ok());
  EXPECT_EQ(od_value(1, 0x2001, 1), fresh);
  auto back = run(upload_sdo(mbx(), 0x2001, 1));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(*back, fresh);
  EXPECT_EQ(coe_stats(1).requests_served - before, 3u);  // one message each: no segments
}

TEST_F(CoeClientTest, SegmentedTransfersBothWays) {
  for (const auto& [index, size, step] :
       std::vector<std::tuple<std::uint16_t, std::size_t, unsigned>>{
           {0x2002, 80, 1}, {0x2003, 192, 1}, {0x2004, 4096, 7}}) {
    SCOPED_TRACE(fmt::format("0x{:04X}", index));
    auto value = run(upload_sdo(mbx(), index, 1));
    ASSERT_TRUE(value.ok()) << value.error().describe();
    EXPECT_EQ(*value, pattern(size, step));
    const Bytes fresh = pattern(size, 5, 3);
    const auto before = coe_stats(1).requests_served;
    ASSERT_TRUE(run(download_sdo(mbx(), index, 1, fresh)).ok());
    // 48 bytes in the initiate request, then 55 per segment (64-byte mailbox).
    const std::size_t segments = (size - 48 + 54) / 55;
    EXPECT_EQ(coe_stats(1).requests_served - before, 1 + segments);
    EXPECT_EQ(od_value(1, index, 1), fresh);
    auto back = run(upload_sdo(mbx(), index, 1));
    ASSERT_TRUE(back.ok()) << back.error().describe();
    EXPECT_EQ(*back, fresh);
  }
}

TEST_F(CoeClientTest, CompleteAccessBothWays) {
  // 0x1C12 (RxPDO assignment of the servo) with subindex 0 padded to 16 bits: one PDO, 0x1600.
  SdoOptions whole;
  whole.complete_access = true;
  auto assign = run(upload_sdo(drive(), 0x1C12, 0, whole));
  ASSERT_TRUE(assign.ok()) << assign.error().describe();
  EXPECT_EQ(*assign, (Bytes{0x01, 0x00, 0x00, 0x16}));
  // 0x1A00: six 32-bit mapping entries.
  auto mapping = run(upload_sdo(drive(), 0x1A00, 0, whole));
  ASSERT_TRUE(mapping.ok()) << mapping.error().describe();
  auto entries = wire::complete_access_u32_entries(*mapping);
  ASSERT_TRUE(entries.ok());
  EXPECT_EQ(*entries, (std::vector<std::uint32_t>{0x60410010, 0x60640020, 0x606C0020, 0x60770010,
                                                  0x60610008, 0x603F0010}));
  // From subindex 1: the entries only.
  auto from_one = run(upload_sdo(drive(), 0x1C12, 1, whole));
  ASSERT_TRUE(from_one.ok()) << from_one.error().describe();
  EXPECT_EQ(*from_one, (Bytes{0x00, 0x16}));

  // Download: assign 0x1601 instead (never expedited with complete access, even for 4 bytes).
  const auto before = coe_stats(0).requests_served;
  ASSERT_TRUE(
      run(download_sdo(drive(), 0x1C12, 0, wire::join_complete_access(1, Bytes{0x01, 0x16}), whole))
          .ok());
  EXPECT_EQ(coe_stats(0).requests_served - before, 1u);
  EXPECT_EQ(od_value(0, 0x1C12, 0), (Bytes{0x01}));
  EXPECT_EQ(od_value(0, 0x1C12, 1), (Bytes{0x01, 0x16}));
  auto reread = run(upload<std::uint16_t>(drive(), 0x1C12, 1));
  ASSERT_TRUE(reread.ok());
  EXPECT_EQ(*reread, 0x1601);
  // A new mapping for 0x1A01 written whole, read back through single entries.
  const Bytes new_map =
      wire::join_complete_access(2, Bytes{0x10, 0x00, 0x41, 0x60, 0x20, 0x00, 0x64, 0x60});
  ASSERT_TRUE(run(download_sdo(drive(), 0x1A01, 0, new_map, whole)).ok());
  auto entry2 = run(upload<std::uint32_t>(drive(), 0x1A01, 2));
  ASSERT_TRUE(entry2.ok()) << entry2.error().describe();
  EXPECT_EQ(*entry2, 0x60640020u);

  auto bad = run(upload_sdo(drive(), 0x1C12, 2, whole));
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().code(), Errc::invalid_argument);
  EXPECT_EQ(bad.error().message(),
            "SDO upload 0x1C12:02 of slave 0x1001 (complete access): complete access starts at "
            "subindex 0 or 1, not 2");
}

// ---- SDO information ---------------------------------------------------------------------------

TEST_F(CoeClientTest, SdoInformationListsAndDescribesTheObjects) {
  const auto expected =
      bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
        auto& od = sim::coe_server_of(segment.esc(0))->dictionary();
        return std::make_pair(od.od_list(wire::OdListType::all),
                              od.od_list(wire::OdListType::number_of_objects));
      });
  auto all = run(od_list(drive(), wire::OdListType::all));
  ASSERT_TRUE(all.ok()) << all.error().describe();
  EXPECT_EQ(*all, expected.first);
  auto counts = run(od_list(drive(), wire::OdListType::number_of_objects));
  ASSERT_TRUE(counts.ok()) << counts.error().describe();
  EXPECT_EQ(*counts, expected.second);
  EXPECT_EQ(counts->at(0), expected.first.size());

  // The mailbox device's 64-byte mailbox fragments even a short list.
  const auto mbx_list =
      bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
        return sim::coe_server_of(segment.esc(1))->dictionary().od_list(wire::OdListType::all);
      });
  const auto replies_before = mbx().stats().replies;
  auto mbx_all = run(od_list(mbx(), wire::OdListType::all));
  ASSERT_TRUE(mbx_all.ok()) << mbx_all.error().describe();
  EXPECT_EQ(*mbx_all, mbx_list);
  EXPECT_EQ(mbx().stats().replies - replies_before, (2 + 2 * mbx_list.size() + 51) / 52);

  auto object = run(object_description(mbx(), 0x2000));
  ASSERT_TRUE(object.ok()) << object.error().describe();
  EXPECT_EQ(object->index, 0x2000);
  EXPECT_EQ(object->name, "Settings");
  EXPECT_EQ(object->max_subindex, 2);
  EXPECT_EQ(object->object_code, wire::ObjectCode::record);

  auto entry = run(entry_description(mbx(), 0x2000, 1, wire::kValueInfoDefaultValue));
  ASSERT_TRUE(entry.ok()) << entry.error().describe();
  EXPECT_EQ(entry->index, 0x2000);
  EXPECT_EQ(entry->subindex, 1);
  EXPECT_EQ(entry->data_type, static_cast<std::uint16_t>(sim::DataType::unsigned16));
  EXPECT_EQ(entry->bit_length, 16);
  EXPECT_EQ(entry->object_access & sim::kAccessReadWrite, sim::kAccessReadWrite);
  EXPECT_EQ(entry->default_value, (Bytes{0x34, 0x12}));
  EXPECT_EQ(entry->description, "vendor_word");

  auto missing = run(object_description(mbx(), 0x6041));
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::sdo_abort);
  EXPECT_EQ(sdo_abort_code(missing.error()), 0x06020000u);
  EXPECT_EQ(missing.error().message(),
            "SDO information: object description 0x6041 of slave 0x1002 aborted: 0x06020000 "
            "object does not exist in the object dictionary");
}

// ---- aborts ------------------------------------------------------------------------------------

void expect_abort(const Result<Bytes>& result, std::uint32_t code, const std::string& what) {
  ASSERT_FALSE(result.ok()) << what;
  EXPECT_EQ(result.error().code(), Errc::sdo_abort);
  EXPECT_EQ(sdo_abort_code(result.error()), code);
  EXPECT_EQ(result.error().message(),
            fmt::format("{} aborted: 0x{:08X} {}", what, code, wire::sdo_abort_text(code)));
}
void expect_abort(const Result<void>& result, std::uint32_t code, const std::string& what) {
  ASSERT_FALSE(result.ok()) << what;
  EXPECT_EQ(result.error().code(), Errc::sdo_abort);
  EXPECT_EQ(sdo_abort_code(result.error()), code);
  EXPECT_EQ(result.error().message(),
            fmt::format("{} aborted: 0x{:08X} {}", what, code, wire::sdo_abort_text(code)));
}

TEST_F(CoeClientTest, AbortsCarryTheirExactCodes) {
  auto missing = run(upload_sdo(mbx(), 0x6041, 0));
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().message(),
            "SDO upload 0x6041:00 of slave 0x1002 aborted: 0x06020000 object does not exist in "
            "the object dictionary");
  EXPECT_EQ(sdo_abort_code(missing.error()), 0x06020000u);
  // The code survives being wrapped as a cause.
  EXPECT_EQ(sdo_abort_code(missing.error().context(Errc::wrong_state, "configuring")), 0x06020000u);
  EXPECT_EQ(sdo_abort_code(Error(Errc::timeout, "no abort")), std::nullopt);

  expect_abort(run(upload_sdo(mbx(), 0x2000, 7)), 0x06090011,
               "SDO upload 0x2000:07 of slave 0x1002");
  expect_abort(run(download<std::uint32_t>(mbx(), 0x1018, 1, 5)), 0x06010002,
               "SDO download 0x1018:01 of slave 0x1002");
  expect_abort(run(download<std::uint32_t>(mbx(), 0x2000, 1, 5)), 0x06070012,
               "SDO download 0x2000:01 of slave 0x1002");
  expect_abort(run(download<std::uint8_t>(mbx(), 0x2000, 1, 5)), 0x06070013,
               "SDO download 0x2000:01 of slave 0x1002");
  // Nothing was stored by the refused writes.
  EXPECT_EQ(od_value(1, 0x2000, 1), (Bytes{0x34, 0x12}));
}

// ---- injected faults ---------------------------------------------------------------------------

// A refusal in the bytes real slave stacks send (SOES, KickCAT's slaves, Beckhoff terminals):
// CoE service 2 and command 0x80. The master must report the slave's own code and must not answer
// with an abort of its own. The non-standard service-3 form some stacks send is taken the same
// way. The bytes are put into SM1 directly, ahead of the simulator's own answer, so the test does
// not depend on how ecat's simulator encodes aborts.
TEST_F(CoeClientTest, AbortsInTheBytesRealStacksSendKeepTheirCode) {
  struct Form {
    const char* name;
    std::uint8_t service_byte;  // the high byte of the CoE header: service << 4
  };
  for (const Form form : {Form{"service 2 (standard)", 0x20}, Form{"service 3", 0x30}}) {
    SCOPED_TRACE(form.name);
    // A mailbox of our own, so the slave's counter sequence starts fresh; drain SM1 first (the
    // simulator's answer to the previous round's request is still in it).
    Mailbox mailbox(bench_->loop, *bench_->bus, test::station_at(1), mbx().config());
    (void)run(mailbox.poll());
    const Bytes real = {0x0A, 0x00,
                        0x00, 0x00,
                        0x00, 0x23,               // length 10, CoE, counter 2
                        0x00, form.service_byte,  // CoE header
                        0x80, 0x00,
                        0x20, 0x01,  // abort 0x2000:01
                        0x02, 0x00,
                        0x01, 0x06};  // 0x06010002 read-only
    const bool placed =
        bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
          return segment.esc(1).pdi_mailbox_send(1, real);
        });
    ASSERT_TRUE(placed);
    const auto before = coe_stats(1).mailboxes_received;
    auto result = run(download<std::uint32_t>(mailbox, 0x2000, 1, 5));
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.error().code(), Errc::sdo_abort) << result.error().describe();
    EXPECT_EQ(sdo_abort_code(result.error()), 0x06010002u);
    EXPECT_EQ(sdo_failure(result.error()), SdoFailure::aborted);
    EXPECT_EQ(result.error().message(),
              "SDO download 0x2000:01 of slave 0x1002 aborted: 0x06010002 attempt to write a "
              "read-only object");
    // Only the download request reached the slave: no abort of the master's own followed it.
    EXPECT_EQ(coe_stats(1).mailboxes_received - before, 1u);
  }
}

TEST_F(CoeClientTest, InjectedAbortsAtEachStage) {
  inject(
      sim::fault::mailbox_abort("mbx", 0x2003, 1, 0x08000020, sim::MailboxStage::upload_segment));
  expect_abort(run(upload_sdo(mbx(), 0x2003, 1)), 0x08000020,
               "SDO upload 0x2003:01 of slave 0x1002");
  inject(
      sim::fault::mailbox_abort("mbx", 0x2003, 1, 0x06060000, sim::MailboxStage::download_segment));
  expect_abort(run(download_sdo(mbx(), 0x2003, 1, pattern(192, 2))), 0x06060000,
               "SDO download 0x2003:01 of slave 0x1002");
  // A code the abort table does not know still comes through, with a text saying so.
  inject(sim::fault::mailbox_abort("mbx", 0x2000, 1, 0x0BADC0DE));
  expect_abort(run(upload_sdo(mbx(), 0x2000, 1)), 0x0BADC0DE,
               "SDO upload 0x2000:01 of slave 0x1002");
  bench_->server->clear_faults();
  auto fine = run(upload<std::uint16_t>(mbx(), 0x2000, 1));
  ASSERT_TRUE(fine.ok()) << fine.error().describe();
  EXPECT_EQ(*fine, 0x1234);
}

sim::Fault protocol_fault(std::uint16_t index, std::uint8_t subindex, sim::MailboxStage stage,
                          sim::ProtocolFaultKind kind, std::uint8_t value = 0) {
  auto fault = sim::fault::mailbox_protocol_fault("mbx", index, subindex, stage, {kind, value});
  fault.effect.once = true;
  return fault;
}

TEST_F(CoeClientTest, CorruptRepliesFailWithWhatWasWrong) {
  struct Case {
    sim::Fault fault;
    Errc code;
    std::string message;
  };
  using K = sim::ProtocolFaultKind;
  using S = sim::MailboxStage;
  const std::vector<Case> cases{
      {protocol_fault(0x2002, 1, S::upload_init, K::sdo_command, 0x60), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: the slave answered with an SDO initiate download "
       "response instead of an initiate upload response"},
      {protocol_fault(0x2002, 1, S::upload_init, K::invalid_coe_payload), Errc::malformed,
       "SDO upload 0x2002:01 of slave 0x1002: the reply of slave 0x1002 has no complete CoE "
       "header (1 bytes of mailbox data)"},
      {protocol_fault(0x2002, 1, S::upload_init, K::mailbox_type, 5), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: slave 0x1002 answered with a SoE mailbox (type 5) "
       "instead of CoE"},
      {protocol_fault(0x2002, 1, S::upload_init, K::coe_service, 4), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: slave 0x1002 answered with CoE service 4 (TxPDO), "
       "expected 3 (SDO response) or an abort"},
      {protocol_fault(0x2002, 1, S::upload_segment, K::toggle_mismatch), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: upload segment 1 carries toggle bit 1, expected 0"},
      // One command byte and no data, of another kind: named by its command (SdoFailure).
      {protocol_fault(0x2002, 1, S::upload_segment, K::segment_command, 0x20), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: slave 0x1002 answered with SDO command 0x20 "
       "(download segment response) instead of the expected upload segment response (3 bytes: "
       "00 30 20)"},
      // A segment where the initiate response belongs.
      {protocol_fault(0x2002, 1, S::upload_init, K::sdo_command, 0x00), Errc::mailbox_error,
       "SDO upload 0x2002:01 of slave 0x1002: the slave answered with an SDO upload segment "
       "response instead of an initiate upload response"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(sim::describe(c.fault));
    inject(c.fault);
    auto result = run(upload_sdo(mbx(), 0x2002, 1));
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.error().code(), c.code);
    EXPECT_EQ(result.error().message(), c.message);
    // The master aborted the transfer on the slave's side: the next one starts clean.
    auto next = run(upload_sdo(mbx(), 0x2002, 1));
    ASSERT_TRUE(next.ok()) << next.error().describe();
    EXPECT_EQ(*next, pattern(80, 1));
  }
  // Download side: a segment response with the wrong toggle.
  inject(protocol_fault(0x2002, 1, S::download_segment, K::toggle_mismatch));
  auto down = run(download_sdo(mbx(), 0x2002, 1, pattern(80, 9)));
  ASSERT_FALSE(down.ok());
  EXPECT_EQ(down.error().message(),
            "SDO download 0x2002:01 of slave 0x1002: download segment response 1 carries toggle "
            "bit 1, expected 0");
}

TEST_F(CoeClientTest, ADroppedReplyTimesOutNamingTheObject) {
  // The slave swallows its reply: the repeat request only brings back the previous (already
  // received) reply, which is dropped as a duplicate; the transfer times out.
  ASSERT_TRUE(run(upload<std::uint8_t>(mbx(), 0x2000, 2)).ok());
  inject(protocol_fault(0x2000, 1, sim::MailboxStage::upload_init,
                        sim::ProtocolFaultKind::drop_response));
  SdoOptions quick;
  quick.timeout = 30ms;
  const auto start = exec::Clock::now();
  auto lost = run(upload_sdo(mbx(), 0x2000, 1, quick));
  ASSERT_FALSE(lost.ok());
  EXPECT_GE(exec::Clock::now() - start, 30ms);
  EXPECT_EQ(lost.error().code(), Errc::timeout);
  EXPECT_EQ(lost.error().message(),
            "SDO upload 0x2000:01 of slave 0x1002: no reply from slave 0x1002 within 30 ms, nor "
            "after a mailbox repeat request");
  EXPECT_EQ(mbx().stats().repeat_requests, 1u);
  EXPECT_EQ(mbx().stats().duplicates, 1u);
  // The rule fired once; the next transfer is answered.
  auto again = run(upload<std::uint16_t>(mbx(), 0x2000, 1));
  ASSERT_TRUE(again.ok()) << again.error().describe();
  EXPECT_EQ(*again, 0x1234);
}

TEST_F(CoeClientTest, AReplyWithAnUnexpectedCounterIsAccepted) {
  inject(protocol_fault(0x2000, 1, sim::MailboxStage::upload_init,
                        sim::ProtocolFaultKind::counter_mismatch));
  auto value = run(upload<std::uint16_t>(mbx(), 0x2000, 1));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, 0x1234);
  // The slave's next reply repeats that counter with new content: not mistaken for a repeat.
  auto next = run(upload<std::uint8_t>(mbx(), 0x2000, 2));
  ASSERT_TRUE(next.ok()) << next.error().describe();
  EXPECT_EQ(*next, 0);
  EXPECT_EQ(mbx().stats().duplicates, 0u);
}

TEST_F(CoeClientTest, ADelayedReplyFrameIsRetriedWithoutRunningTheRequestTwice) {
  // The frame carrying the request (and the read of SM1) comes back after the bus gave up on it:
  // the bus sends it again, the slave recognises the repeated request by its counter and offers
  // the reply again instead of executing the request twice.
  const auto served = coe_stats(1).requests_served;
  inject(sim::fault::next(sim::fault::delay_replies(60ms), 1));
  auto value = run(upload_sdo(mbx(), 0x2003, 1));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(*value, pattern(192, 1));
  EXPECT_GE(bench_->bus->stats().retries, 1u);
  EXPECT_EQ(coe_stats(1).duplicates, 1u);
  // 192 bytes from a 64-byte mailbox: the initiate response carries 48, then 3 segments.
  EXPECT_EQ(coe_stats(1).requests_served - served, 4u);
}

// ---- concurrency and emergencies --------------------------------------------------------------

TEST_F(CoeClientTest, TransfersToOneSlaveFromSeveralTasksQueue) {
  auto all = [&]() -> exec::Task<std::vector<Result<Bytes>>> {
    std::vector<exec::Task<Result<Bytes>>> tasks;
    for (int i = 0; i < 4; ++i)
      tasks.push_back(upload_sdo(mbx(), i % 2 == 0 ? 0x2003 : 0x2002, 1));
    co_return co_await exec::when_all(bench_->loop, std::move(tasks));
  };
  auto results = run(all());
  ASSERT_EQ(results.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    ASSERT_TRUE(results[i].ok()) << results[i].error().describe();
    EXPECT_EQ(*results[i], i % 2 == 0 ? pattern(192, 1) : pattern(80, 1));
  }
}

TEST_F(CoeClientTest, EmergenciesFromTheDeviceAreCollected) {
  std::vector<wire::Emergency> seen;
  const wire::Emergency following_error{0x8611, 0x81, {0, 0, 0, 0, 0}};
  bench_->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    auto& esc = segment.esc(0);
    sim::coe_server_of(esc)->queue_emergency(esc, following_error);
    return 0;
  });
  auto value = run(upload<std::uint16_t>(drive(), 0x6041, 0));
  ASSERT_TRUE(value.ok()) << value.error().describe();
  EXPECT_EQ(drive().emergencies(), (std::vector<wire::Emergency>{following_error}));
  EXPECT_TRUE(drive().emergencies().empty());
}

TEST(CoeClient, EightSlavesTransferConcurrentlyAndShareFrames) {
  std::string ring = "version: 1\nsimulator:\n  slaves:\n";
  for (int i = 0; i < 8; ++i)
    ring += fmt::format("    - {{name: m{}, profile: mailbox}}\n", i);
  // One frame in flight: what the tasks submit meanwhile waits and leaves packed in the next frame.
  bus::BusOptions options;
  options.max_reliable_frames_in_flight = 1;
  auto bench = SimBench::make(ring, options);
  ASSERT_TRUE(bench);
  auto configs = bench->run(test::bring_all_to_preop(bench->loop, *bench->bus, 8));
  ASSERT_TRUE(configs.ok()) << configs.error().describe();
  // A wire-like round trip: without it the in-process simulator answers faster than the loop
  // thread resumes the next task (notably under sanitizers), and every frame leaves alone.
  ASSERT_TRUE(bench->server->inject(sim::fault::delay_replies(1ms)).ok());
  std::vector<std::unique_ptr<Mailbox>> mailboxes;
  for (std::size_t i = 0; i < 8; ++i) {
    mailboxes.push_back(
        std::make_unique<Mailbox>(bench->loop, *bench->bus, test::station_at(i), (*configs)[i]));
  }
  // Per slave: a segmented download of its own data, then the upload that reads it back.
  auto one = [&](std::size_t i) -> exec::Task<Result<Bytes>> {
    auto down =
        co_await download_sdo(*mailboxes[i], 0x2003, 1, pattern(192, 3, static_cast<unsigned>(i)));
    if (!down) co_return down.error();
    co_return co_await upload_sdo(*mailboxes[i], 0x2003, 1);
  };
  auto sequential = [&]() -> exec::Task<std::vector<Result<Bytes>>> {
    std::vector<Result<Bytes>> out;
    for (std::size_t i = 0; i < 8; ++i)
      out.push_back(co_await one(i));
    co_return out;
  };
  auto concurrent = [&]() -> exec::Task<std::vector<Result<Bytes>>> {
    std::vector<exec::Task<Result<Bytes>>> tasks;
    for (std::size_t i = 0; i < 8; ++i)
      tasks.push_back(one(i));
    co_return co_await exec::when_all(bench->loop, std::move(tasks));
  };
  auto start = bench->bus->stats().frames_sent;
  auto one_by_one = bench->run(sequential());
  const auto sequential_frames = bench->bus->stats().frames_sent - start;
  start = bench->bus->stats().frames_sent;
  auto together = bench->run(concurrent());
  const auto concurrent_frames = bench->bus->stats().frames_sent - start;
  for (std::size_t i = 0; i < 8; ++i) {
    ASSERT_TRUE(one_by_one[i].ok()) << one_by_one[i].error().describe();
    ASSERT_TRUE(together[i].ok()) << together[i].error().describe();
    EXPECT_EQ(*together[i], pattern(192, 3, static_cast<unsigned>(i)));
  }
  // Sequential: 8 exchanges x 8 slaves, one frame each. Concurrent: each round of 8 exchanges
  // leaves in about two frames (the first alone, the rest packed behind it); a loaded machine
  // splits some rounds further.
  EXPECT_LT(concurrent_frames * 2, sequential_frames)
      << "sequential " << sequential_frames << " frames, concurrent " << concurrent_frames;
}

}  // namespace
}  // namespace ecat::master
