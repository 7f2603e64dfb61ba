// Reliable transactions over the fake segment: round trips, addressing of every command,
// packing, spanning, index management under load, concurrency, validation and errors.

#include <array>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <functional>
#include <future>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/link/forwarding_link.hpp>

#include "bus/bus_test_support.hpp"

namespace ecat::bus::test {
namespace {

using wire::Command;

constexpr std::array<std::uint8_t, 2> kTwo{0x34, 0x12};

TEST(Transaction, BuilderRecordsCommandsAddressesAndSlots) {
  Transaction tx;
  const std::array<std::uint8_t, 3> data{1, 2, 3};
  EXPECT_EQ(tx.aprd(3, 0x0130, 2), 0u);
  EXPECT_EQ(tx.fpwr(0x1001, 0x0120, data, 1), 1u);
  EXPECT_EQ(tx.brd(0x0000, 1), 2u);
  EXPECT_EQ(tx.lrw(0x00010000, data), 3u);
  EXPECT_EQ(tx.nop(4), 4u);
  ASSERT_EQ(tx.size(), 5u);
  const auto d = tx.datagrams();
  EXPECT_EQ(d[0].command, Command::aprd);
  EXPECT_EQ(d[0].adp(), 0xFFFD);  // -3
  EXPECT_EQ(d[0].ado(), 0x0130);
  EXPECT_EQ(d[1].address, 0x01201001u);
  EXPECT_EQ(d[1].expected_wkc, std::optional<std::uint16_t>(1));
  EXPECT_EQ(bytes_of(tx.data(1)), (std::vector<std::uint8_t>{1, 2, 3}));
  EXPECT_EQ(bytes_of(tx.data(0)), (std::vector<std::uint8_t>{0, 0}));
  EXPECT_EQ(d[3].address, 0x00010000u);
  EXPECT_EQ(d[4].length, 4);
  EXPECT_EQ(tx.payload_size(), 2u + 3u + 1u + 3u + 4u);
  EXPECT_EQ(tx.wire_size(), tx.payload_size() + 5 * wire::kDatagramOverhead);
  EXPECT_FALSE(tx.error());
  EXPECT_EQ(describe(d[0]), "APRD position 3 offset 0x0130 (2 bytes)");
  EXPECT_EQ(describe(d[1]), "FPWR station 0x1001 offset 0x0120 (3 bytes)");
  EXPECT_EQ(describe(d[2]), "BRD offset 0x0000 (1 byte)");
  EXPECT_EQ(describe(d[3]), "LRW logical 0x00010000 (3 bytes)");
  EXPECT_EQ(describe(d[4]), "NOP (4 bytes)");
}

TEST(Transaction, BuilderMistakesAreReportedBySubmit) {
  auto segment = make_segment();
  auto bus = start_bus(segment);

  Transaction too_long;
  too_long.fprd(0x1001, 0x1000, 2);
  too_long.lrd(0x10000, 3000);
  ASSERT_TRUE(too_long.error());
  EXPECT_NE(too_long.error()->message().find("datagram 1"), std::string::npos);
  EXPECT_NE(too_long.error()->message().find("3000"), std::string::npos);
  auto r1 = bus->transact(too_long);
  ASSERT_FALSE(r1);
  EXPECT_EQ(r1.error().code(), Errc::invalid_argument);

  Transaction bad_slot;
  bad_slot.fprd(0x1001, 0x1000, 2);
  bad_slot.expect_wkc(5, 1);
  auto r2 = bus->transact(bad_slot);
  ASSERT_FALSE(r2);
  EXPECT_NE(r2.error().message().find("slot 5"), std::string::npos);

  auto r3 = bus->transact(Transaction{});
  ASSERT_FALSE(r3);
  EXPECT_EQ(r3.error().code(), Errc::invalid_argument);

  // 1600 bytes is a valid datagram, but not on a 1500-byte link.
  Transaction too_big;
  too_big.lrd(0x10000, 1600);
  EXPECT_FALSE(too_big.error());
  auto r4 = bus->transact(too_big);
  ASSERT_FALSE(r4);
  EXPECT_EQ(r4.error().code(), Errc::invalid_argument);
  EXPECT_NE(r4.error().message().find("LRD logical 0x00010000 (1600 bytes)"), std::string::npos)
      << r4.error().message();

  TransactOptions zero_timeout;
  zero_timeout.timeout = 0ns;
  Transaction ok_tx;
  ok_tx.fprd(0x1001, 0x1000, 2);
  auto r5 = bus->transact(ok_tx, zero_timeout);
  ASSERT_FALSE(r5);
  EXPECT_EQ(r5.error().code(), Errc::invalid_argument);
  EXPECT_EQ(segment->frames_sent(), 0u);
}

// A link that records the frame budget the bus tells it (Link::set_frame_budget).
class BudgetLink final : public link::ForwardingLink {
 public:
  BudgetLink(std::unique_ptr<link::Link> inner, std::shared_ptr<std::atomic<std::int64_t>> budget)
      : ForwardingLink(std::move(inner)), budget_(std::move(budget)) {}
  void set_frame_budget(std::chrono::nanoseconds budget) override {
    budget_->store(budget.count());
  }

 private:
  std::shared_ptr<std::atomic<std::int64_t>> budget_;
};

// A bus with a 25 ms frame timeout over a BudgetLink: told() is the budget the link was told last.
struct BudgetBus {
  std::shared_ptr<FakeSegment> segment = make_segment();
  std::shared_ptr<std::atomic<std::int64_t>> budget =
      std::make_shared<std::atomic<std::int64_t>>(-1);
  Bus bus{std::make_unique<BudgetLink>(FakeSegment::make_link(segment), budget), [] {
            BusOptions options;
            options.frame_timeout = 25ms;
            return options;
          }()};
  std::chrono::nanoseconds told() const { return std::chrono::nanoseconds(budget->load()); }
};

// The link is told the frame timeout, bounded by three cycle periods while a cycle runs (a
// redundant link waits for a late side of the ring up to half of it).
TEST(Bus, TellsTheLinkItsFrameBudgetBoundedByThreeCyclePeriods) {
  BudgetBus b;
  auto& bus = b.bus;
  const auto told = [&] { return b.told(); };
  EXPECT_EQ(told(), 25ms);
  ASSERT_TRUE(bus.start());
  ASSERT_TRUE(bus.set_frame_timeout(8ms));
  EXPECT_EQ(told(), 8ms);
  ASSERT_TRUE(bus.set_cycle(1ms, [](const CycleTick&) {}));
  EXPECT_EQ(told(), 3ms);
  ASSERT_TRUE(bus.set_frame_timeout(1500us));
  EXPECT_EQ(told(), 1500us);
  ASSERT_TRUE(bus.set_frame_timeout(20ms));
  EXPECT_EQ(told(), 3ms);
  ASSERT_TRUE(bus.set_cycle(4ms, [](const CycleTick&) {}));
  EXPECT_EQ(told(), 12ms);
  bus.clear_cycle();
  EXPECT_EQ(told(), 20ms);
  bus.stop();
}

// Several domains: the cycle ticks at their common base (2 ms and 3 ms tick at 1 ms), the cap is
// three periods of the fastest domain (Bus::set_fastest_work_period), never of the base tick, and
// the frame timeout still bounds it.
TEST(Bus, FrameBudgetFollowsTheFastestWorkNotTheBaseTick) {
  BudgetBus b;
  auto& bus = b.bus;
  const auto told = [&] { return b.told(); };
  ASSERT_TRUE(bus.start());
  // Told before the cycle is set: no cycle runs, the frame timeout alone.
  ASSERT_TRUE(bus.set_fastest_work_period(2ms));
  EXPECT_EQ(told(), 25ms);
  ASSERT_TRUE(bus.set_cycle(1ms, [](const CycleTick&) {}));
  EXPECT_EQ(told(), 6ms);
  // A faster domain joins (1 ms and 10 ms: the base is the fastest).
  ASSERT_TRUE(bus.set_fastest_work_period(1ms));
  EXPECT_EQ(told(), 3ms);
  // Slow domains only: the frame timeout bounds the cap.
  ASSERT_TRUE(bus.set_fastest_work_period(10ms));
  EXPECT_EQ(told(), 25ms);
  ASSERT_TRUE(bus.set_frame_timeout(12ms));
  EXPECT_EQ(told(), 12ms);
  EXPECT_FALSE(bus.set_fastest_work_period(-1ms));
  EXPECT_EQ(told(), 12ms);
  // 0: the cycle's own period again; clear_cycle forgets it too.
  ASSERT_TRUE(bus.set_fastest_work_period(0ns));
  EXPECT_EQ(told(), 3ms);
  ASSERT_TRUE(bus.set_fastest_work_period(3ms));
  bus.clear_cycle();
  EXPECT_EQ(told(), 12ms);
  ASSERT_TRUE(bus.set_cycle(2ms, [](const CycleTick&) {}));
  EXPECT_EQ(told(), 6ms);
  bus.stop();
}

// The bus thread carries BusOptions::thread_name (ps, top and perf show it), read back from
// /proc/self/task/*/comm.
TEST(Bus, ThreadIsNamed) {
  const auto count_named = [](const std::string& name) {
    std::size_t n = 0;
    for (const auto& task : std::filesystem::directory_iterator("/proc/self/task")) {
      std::ifstream comm(task.path() / "comm");
      std::string line;
      std::getline(comm, line);
      if (line == name) ++n;
    }
    return n;
  };
  auto segment = make_segment();
  BusOptions options;
  options.thread_name = "bus-name-test-long";  // cut to the kernel's 15 characters
  Bus bus(FakeSegment::make_link(segment), options);
  EXPECT_EQ(count_named("bus-name-test-l"), 0u);
  ASSERT_TRUE(bus.start());
  EXPECT_EQ(count_named("bus-name-test-l"), 1u);
  bus.stop();
  EXPECT_EQ(count_named("bus-name-test-l"), 0u);
}

TEST(Bus, SingleTransactionRoundTrip) {
  auto segment = make_segment();
  segment->write(1, 0x0130, kTwo);
  auto bus = start_bus(segment);

  Transaction tx;
  const auto slot = tx.fprd(0x1002, 0x0130, 2, 1);
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  ASSERT_EQ(result->size(), 1u);
  EXPECT_EQ(bytes_of(result->data(slot)), (std::vector<std::uint8_t>{0x34, 0x12}));
  EXPECT_EQ(result->wkc(slot), 1);
  EXPECT_FALSE(result->circulating(slot));
  EXPECT_EQ(result->irq(slot), 0);

  const auto sent = segment->sent();
  ASSERT_EQ(sent.size(), 1u);
  const auto datagrams = datagrams_of(sent[0].bytes);
  ASSERT_EQ(datagrams.size(), 1u);
  EXPECT_EQ(datagrams[0].command, Command::fprd);
  EXPECT_EQ(datagrams[0].address, 0x01301002u);
  EXPECT_EQ(datagrams[0].length, 2);

  const auto stats = bus->stats();
  EXPECT_EQ(stats.frames_sent, 1u);
  EXPECT_EQ(stats.frames_received, 1u);
  EXPECT_EQ(stats.datagrams_sent, 1u);
  EXPECT_EQ(stats.transactions_completed, 1u);
  EXPECT_EQ(stats.frames_lost, 0u);
  const auto info = bus->info();
  EXPECT_EQ(info.link_name, "fake:segment");
  EXPECT_TRUE(info.running);
  EXPECT_EQ(info.frame_timeout, 25ms);
  EXPECT_EQ(info.link_stats.frames_sent, 1u);
}

// Finished transactions are freed by the next thread that submits, never by the bus thread...
// unless only completions on the bus thread submit: then the bus thread frees them itself
// beyond a bound, so the memory stays bounded.
TEST(Bus, FinishedTransactionsAreFreedByTheNextSubmitterAndStayBounded) {
  auto segment = make_segment();
  auto bus = start_bus(segment);
  std::atomic<int> left{3000};
  std::promise<void> done;
  std::function<void(Result<TransactionResult>)> again = [&](Result<TransactionResult> r) {
    EXPECT_TRUE(r);
    if (--left == 0) {
      done.set_value();
      return;
    }
    Transaction tx;
    tx.fprd(0x1001, 0x0130, 2, 1);
    EXPECT_TRUE(bus->submit(std::move(tx), again));  // on the bus thread
  };
  Transaction first;
  first.fprd(0x1001, 0x0130, 2, 1);
  ASSERT_TRUE(bus->submit(std::move(first), again));
  ASSERT_EQ(done.get_future().wait_for(30s), std::future_status::ready);
  EXPECT_GT(bus->stats().finished_awaiting_free, 0u);
  EXPECT_LE(bus->stats().finished_awaiting_free, 1024u);
  // A submission from another thread frees them: what waits after it is at most itself and the
  // chain's last, which joins the list after its completion said done.
  Transaction other;
  other.fprd(0x1001, 0x0130, 2, 1);
  ASSERT_TRUE(bus->transact(std::move(other)));
  EXPECT_LE(bus->stats().finished_awaiting_free, 2u);
}

TEST(Bus, PositionAddressingReachesTheSlaveAtThatPosition) {
  auto segment = make_segment();
  auto bus = start_bus(segment);
  const std::array<std::uint8_t, 2> station{0x34, 0x12};

  Transaction tx;
  const auto write = tx.apwr(2, 0x0010, station, 1);
  const auto read = tx.aprd(2, 0x0010, 2, 1);
  const auto read0 = tx.aprd(0, 0x0010, 2, 1);
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(result->wkc(write), 1);
  EXPECT_EQ(bytes_of(result->data(read)), (std::vector<std::uint8_t>{0x34, 0x12}));
  EXPECT_EQ(bytes_of(result->data(read0)), (std::vector<std::uint8_t>{0x01, 0x10}));
  EXPECT_EQ(segment->read(2, 0x0010, 2), (std::vector<std::uint8_t>{0x34, 0x12}));
  EXPECT_EQ(segment->read(1, 0x0010, 2), (std::vector<std::uint8_t>{0x02, 0x10}));

  const auto datagrams = datagrams_of(segment->sent().at(0).bytes);
  ASSERT_EQ(datagrams.size(), 3u);
  EXPECT_EQ(datagrams[0].address, wire::physical_address(0xFFFE, 0x0010));
  EXPECT_EQ(datagrams[2].address, wire::physical_address(0x0000, 0x0010));

  // A position past the end of the ring reaches nobody.
  Transaction missing;
  missing.aprd(7, 0x0010, 2);
  auto none = bus->transact(std::move(missing));
  ASSERT_TRUE(none);
  EXPECT_EQ(none->wkc(0), 0);
}

TEST(Bus, ReadWriteAndReadMultipleWriteCommands) {
  auto segment = make_segment();
  for (std::size_t s = 0; s < 3; ++s) {
    const std::array<std::uint8_t, 2> v{static_cast<std::uint8_t>(0x10 + s), 0xAB};
    segment->write(s, 0x0900, v);
  }
  auto bus = start_bus(segment);
  const std::array<std::uint8_t, 2> value{0x55, 0x66};

  Transaction tx;
  const auto aprw = tx.aprw(1, 0x0900, value);
  const auto fprw = tx.fprw(0x1003, 0x0900, value);
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(result->wkc(aprw), 3);
  EXPECT_EQ(bytes_of(result->data(aprw)), (std::vector<std::uint8_t>{0x11, 0xAB}));
  EXPECT_EQ(result->wkc(fprw), 3);
  EXPECT_EQ(bytes_of(result->data(fprw)), (std::vector<std::uint8_t>{0x12, 0xAB}));
  EXPECT_EQ(segment->read(1, 0x0900, 2), (std::vector<std::uint8_t>{0x55, 0x66}));
  EXPECT_EQ(segment->read(2, 0x0900, 2), (std::vector<std::uint8_t>{0x55, 0x66}));
  EXPECT_EQ(segment->read(0, 0x0900, 2), (std::vector<std::uint8_t>{0x10, 0xAB}));

  // ARMW/FRMW: the addressed slave is read, every other slave written with that value.
  Transaction rmw;
  const auto frmw = rmw.frmw(0x1001, 0x0900, 2);
  auto r2 = bus->transact(std::move(rmw));
  ASSERT_TRUE(r2);
  EXPECT_EQ(r2->wkc(frmw), 3);
  EXPECT_EQ(bytes_of(r2->data(frmw)), (std::vector<std::uint8_t>{0x10, 0xAB}));
  for (std::size_t s = 0; s < 3; ++s) {
    EXPECT_EQ(segment->read(s, 0x0900, 2), (std::vector<std::uint8_t>{0x10, 0xAB})) << s;
  }
  const std::array<std::uint8_t, 2> marker{0x77, 0x01};
  segment->write(2, 0x0910, marker);
  Transaction armw_tx;
  const auto armw = armw_tx.armw(2, 0x0910, 2);
  auto r3 = bus->transact(std::move(armw_tx));
  ASSERT_TRUE(r3);
  EXPECT_EQ(r3->wkc(armw), 3);
  // Slaves 0 and 1 come before the addressed slave: they wrote the incoming zeros.
  EXPECT_EQ(bytes_of(r3->data(armw)), (std::vector<std::uint8_t>{0x77, 0x01}));
  EXPECT_EQ(segment->read(0, 0x0910, 2), (std::vector<std::uint8_t>{0x00, 0x00}));
}

TEST(Bus, BroadcastCommandsReachEverySlave) {
  auto segment = make_segment();
  for (std::size_t s = 0; s < 3; ++s) {
    const std::array<std::uint8_t, 1> bit{static_cast<std::uint8_t>(1u << s)};
    segment->write(s, 0x0200, bit);
  }
  auto bus = start_bus(segment);
  const std::array<std::uint8_t, 2> init{0x01, 0x00};

  Transaction tx;
  const auto count = tx.brd(0x0000, 1, 3);
  const auto bits = tx.brd(0x0200, 1);
  const auto reset = tx.bwr(0x0120, init, 3);
  const auto rw = tx.brw(0x0300, init);
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(result->wkc(count), 3);
  EXPECT_EQ(result->data(bits)[0], 0x07);
  EXPECT_EQ(result->wkc(reset), 3);
  EXPECT_EQ(result->wkc(rw), 9);
  for (std::size_t s = 0; s < 3; ++s) {
    EXPECT_EQ(segment->read(s, 0x0120, 2), (std::vector<std::uint8_t>{0x01, 0x00}));
  }
  // The bus accepts the broadcast reply although each slave incremented ADP on the way.
  const auto datagrams = datagrams_of(segment->sent().at(0).bytes);
  EXPECT_EQ(datagrams.at(0).address, 0u);
}

TEST(Bus, LogicalCommandsUseTheMappings) {
  auto segment = make_segment();
  segment->map_logical(0, {0x00010000, 0x1000, 2, false, true});  // outputs
  segment->map_logical(1, {0x00010002, 0x1100, 2, true, false});  // inputs
  const std::array<std::uint8_t, 2> inputs{0xC1, 0xC2};
  segment->write(1, 0x1100, inputs);
  auto bus = start_bus(segment);

  const std::array<std::uint8_t, 4> image{0xA1, 0xA2, 0x00, 0x00};
  Transaction tx;
  const auto lrw = tx.lrw(0x00010000, image, 3);
  const auto lrd = tx.lrd(0x00010002, 2, 1);
  const std::array<std::uint8_t, 2> out2{0xB1, 0xB2};
  const auto lwr = tx.lwr(0x00010000, out2, 1);
  const auto nop = tx.nop(2);
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(result->wkc(lrw), 3);
  EXPECT_EQ(bytes_of(result->data(lrw)), (std::vector<std::uint8_t>{0xA1, 0xA2, 0xC1, 0xC2}));
  EXPECT_EQ(result->wkc(lrd), 1);
  EXPECT_EQ(bytes_of(result->data(lrd)), (std::vector<std::uint8_t>{0xC1, 0xC2}));
  EXPECT_EQ(result->wkc(lwr), 1);
  EXPECT_EQ(result->wkc(nop), 0);
  EXPECT_EQ(segment->read(0, 0x1000, 2), (std::vector<std::uint8_t>{0xB1, 0xB2}));
}

TEST(Bus, WkcExpectationFailureNamesTheDatagram) {
  auto segment = make_segment();
  auto bus = start_bus(segment);
  Transaction tx;
  tx.fprd(0x1001, 0x0130, 2, 1);
  tx.fprd(0x7777, 0x0130, 2);
  tx.expect_wkc(1, 1);
  auto result = bus->transact(std::move(tx));
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::wkc_mismatch);
  const auto& message = result.error().message();
  EXPECT_NE(message.find("FPRD station 0x7777 offset 0x0130 (2 bytes)"), std::string::npos)
      << message;
  EXPECT_NE(message.find("datagram 1"), std::string::npos) << message;
  EXPECT_NE(message.find("index 0x"), std::string::npos) << message;
  EXPECT_NE(message.find("working counter 0, expected 1"), std::string::npos) << message;
  EXPECT_EQ(bus->stats().wkc_mismatches, 1u);
  EXPECT_EQ(bus->stats().transactions_failed, 1u);
}

TEST(Bus, SmallTransactionsSubmittedTogetherArePackedIntoFewFrames) {
  auto segment = make_segment();
  for (std::size_t s = 0; s < 3; ++s) {
    std::vector<std::uint8_t> pattern(256);
    for (std::size_t i = 0; i < pattern.size(); ++i) {
      pattern[i] = static_cast<std::uint8_t>(i * 7 + s);
    }
    segment->write(s, 0x1000, pattern);
  }
  // Replies take a while, so submissions pile up behind the first frame, as on a busy bus.
  segment->set_reply_delay(5ms);
  BusOptions options;
  options.max_reliable_frames_in_flight = 1;
  auto bus = start_bus(segment, options);

  constexpr std::size_t kCount = 200;
  Completions done;
  for (std::size_t i = 0; i < kCount; ++i) {
    Transaction tx;
    tx.fprd(static_cast<std::uint16_t>(0x1001 + i % 3),
            static_cast<std::uint16_t>(0x1000 + i % 200), 2, 1);
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(i)));
  }
  ASSERT_TRUE(done.wait_for(kCount));
  for (std::size_t i = 0; i < kCount; ++i) {
    const auto& r = done.at(i);
    ASSERT_TRUE(r) << r.error().describe();
    const auto o = i % 200;
    EXPECT_EQ(bytes_of(r->data(0)),
              (std::vector<std::uint8_t>{static_cast<std::uint8_t>(o * 7 + i % 3),
                                         static_cast<std::uint8_t>((o + 1) * 7 + i % 3)}))
        << i;
  }
  const auto stats = bus->stats();
  EXPECT_EQ(stats.datagrams_sent, kCount);
  // 14 bytes per datagram: 107 fit one 1500-byte frame, so 200 need at least 2 frames; the first
  // may go out nearly alone before the others are queued.
  EXPECT_LE(stats.frames_sent, 5u) << "frames: " << stats.frames_sent;
  EXPECT_GE(stats.frames_sent, 2u);
  for (const auto& frame : segment->sent())
    EXPECT_LE(frame.bytes.size(), wire::kMaxFrameSize);
}

TEST(Bus, TransactionLargerThanAFrameSpansSeveralFrames) {
  FakeSegment::Options seg;
  seg.max_frame_size = 600;
  auto segment = make_segment(seg);
  auto bus = start_bus(segment);
  EXPECT_EQ(bus->max_frame_size(), 600u);

  Transaction write;
  std::vector<std::vector<std::uint8_t>> blocks;
  for (std::size_t i = 0; i < 10; ++i) {
    std::vector<std::uint8_t> block(400);
    for (std::size_t j = 0; j < block.size(); ++j)
      block[j] = static_cast<std::uint8_t>(i * 31 + j);
    write.fpwr(0x1001, static_cast<std::uint16_t>(0x1000 + i * 400), block, 1);
    blocks.push_back(block);
  }
  ASSERT_TRUE(bus->transact(std::move(write)));
  EXPECT_EQ(segment->frames_sent(), 10u);  // one 412-byte datagram per 600-byte frame

  Transaction read;
  for (std::size_t i = 0; i < 10; ++i) {
    read.fprd(0x1001, static_cast<std::uint16_t>(0x1000 + i * 400), 400, 1);
  }
  auto result = bus->transact(std::move(read));
  ASSERT_TRUE(result) << result.error().describe();
  for (std::size_t i = 0; i < 10; ++i)
    EXPECT_EQ(bytes_of(result->data(i)), blocks[i]) << i;

  // Small datagrams: 100 x 14 bytes = 1400 bytes need 3 frames of 600.
  Transaction many;
  for (std::size_t i = 0; i < 100; ++i)
    many.fprd(0x1002, static_cast<std::uint16_t>(0x1000 + i), 2);
  const auto before = segment->frames_sent();
  ASSERT_TRUE(bus->transact(std::move(many)));
  EXPECT_EQ(segment->frames_sent() - before, 3u);
  for (const auto& frame : segment->sent())
    EXPECT_LE(frame.bytes.size(), 600u);
}

TEST(Bus, MoreThan256DatagramsQueuedAtOnceCompleteWithoutIndexReuse) {
  auto segment = make_segment();
  std::vector<std::uint8_t> pattern(0x1000);
  for (std::size_t i = 0; i < pattern.size(); ++i)
    pattern[i] = static_cast<std::uint8_t>(i ^ (i >> 8));
  for (std::size_t s = 0; s < 3; ++s)
    segment->write(s, 0x1000, pattern);
  segment->set_reply_delay(1ms);  // keep several frames in flight at once
  auto bus = start_bus(segment);

  Completions done;
  // One transaction of 600 datagrams (more than all indices) plus 20 of 50.
  Transaction big;
  for (std::size_t i = 0; i < 600; ++i) {
    big.fprd(0x1001, static_cast<std::uint16_t>(0x1000 + i), 1, 1);
  }
  ASSERT_TRUE(bus->submit(std::move(big), done.make(0)));
  for (std::size_t t = 1; t <= 20; ++t) {
    Transaction tx;
    for (std::size_t i = 0; i < 50; ++i) {
      tx.fprd(static_cast<std::uint16_t>(0x1001 + t % 3),
              static_cast<std::uint16_t>(0x1000 + t * 50 + i), 1, 1);
    }
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(t)));
  }
  ASSERT_TRUE(done.wait_for(21));
  const auto& r0 = done.at(0);
  ASSERT_TRUE(r0) << r0.error().describe();
  ASSERT_EQ(r0->size(), 600u);
  for (std::size_t i = 0; i < 600; ++i)
    ASSERT_EQ(r0->data(i)[0], pattern[i]) << i;
  for (std::size_t t = 1; t <= 20; ++t) {
    const auto& r = done.at(t);
    ASSERT_TRUE(r) << r.error().describe();
    for (std::size_t i = 0; i < 50; ++i)
      ASSERT_EQ(r->data(i)[0], pattern[t * 50 + i]);
  }
  EXPECT_EQ(bus->stats().datagrams_sent, 1600u);
  EXPECT_EQ(segment->index_reuse_violations(), 0u);
  EXPECT_EQ(bus->stats().unmatched_replies + bus->stats().mismatched_replies, 0u);
}

TEST(Bus, EightThreadsOfConcurrentTransactionsKeepTheirData) {
  FakeSegment::Options seg;
  seg.record = false;
  auto segment = make_segment(seg);
  auto bus = start_bus(segment);

  constexpr int kThreads = 8;
  constexpr int kPerThread = 1000;
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      const auto station = static_cast<std::uint16_t>(0x1001 + t % 3);
      const auto offset = static_cast<std::uint16_t>(0x1000 + t * 8);
      for (int i = 0; i < kPerThread; ++i) {
        const std::uint32_t value =
            (static_cast<std::uint32_t>(t) << 24) | static_cast<std::uint32_t>(i);
        std::array<std::uint8_t, 4> bytes{};
        wire::store_le32(bytes.data(), value);
        Transaction tx;
        tx.fpwr(station, offset, bytes, 1);
        const auto read = tx.fprd(station, offset, 4, 1);
        auto result = bus->transact(std::move(tx));
        if (!result || wire::load_le32(result->data(read).data()) != value) {
          failures.fetch_add(1);
        }
      }
    });
  }
  for (auto& thread : threads)
    thread.join();
  EXPECT_EQ(failures.load(), 0);
  const auto stats = bus->stats();
  EXPECT_EQ(stats.transactions_completed, static_cast<std::uint64_t>(kThreads * kPerThread));
  EXPECT_EQ(stats.datagrams_sent, static_cast<std::uint64_t>(2 * kThreads * kPerThread));
  EXPECT_LE(stats.frames_sent, stats.datagrams_sent / 2);  // pairs never split; often packed
  EXPECT_EQ(stats.unmatched_replies + stats.mismatched_replies + stats.late_replies, 0u);
}

TEST(Bus, CompletionRunsOnTheBusThreadWhereTransactIsRefused) {
  auto segment = make_segment();
  auto bus = start_bus(segment);
  std::mutex mutex;
  std::condition_variable cv;
  bool done = false;
  bool on_bus_thread = false;
  std::optional<Errc> nested;
  Transaction tx;
  tx.brd(0, 1);
  ASSERT_TRUE(bus->submit(std::move(tx), [&](Result<TransactionResult> result) {
    EXPECT_TRUE(result);
    Transaction inner;
    inner.brd(0, 1);
    auto r = bus->transact(std::move(inner));
    std::lock_guard lock(mutex);
    on_bus_thread = bus->on_bus_thread();
    if (!r) nested = r.error().code();
    done = true;
    cv.notify_all();
  }));
  std::unique_lock lock(mutex);
  ASSERT_TRUE(cv.wait_for(lock, 5s, [&] { return done; }));
  EXPECT_TRUE(on_bus_thread);
  EXPECT_EQ(nested, Errc::wrong_state);
  EXPECT_FALSE(bus->on_bus_thread());
}

TEST(Bus, FrameTimeoutIsSettableAndRejectsNonPositiveValues) {
  auto segment = make_segment();
  auto bus = start_bus(segment);
  EXPECT_EQ(bus->frame_timeout(), 25ms);
  ASSERT_TRUE(bus->set_frame_timeout(7ms));
  EXPECT_EQ(bus->frame_timeout(), 7ms);
  auto zero = bus->set_frame_timeout(0ns);
  ASSERT_FALSE(zero);
  EXPECT_EQ(zero.error().code(), Errc::invalid_argument);
  EXPECT_FALSE(bus->set_frame_timeout(-1ms));
  EXPECT_EQ(bus->frame_timeout(), 7ms);
  EXPECT_EQ(bus->info().frame_timeout, 7ms);
}

TEST(Bus, StartAndStopRules) {
  auto segment = make_segment();
  Bus bus(FakeSegment::make_link(segment));
  Transaction tx;
  tx.brd(0, 1);
  auto before = bus.transact(tx);
  ASSERT_FALSE(before);
  EXPECT_EQ(before.error().code(), Errc::wrong_state);
  ASSERT_TRUE(bus.start());
  EXPECT_FALSE(bus.start());
  EXPECT_TRUE(bus.transact(tx));
  bus.stop();
  bus.stop();
  EXPECT_FALSE(bus.running());
  auto after = bus.transact(tx);
  ASSERT_FALSE(after);
  EXPECT_EQ(after.error().code(), Errc::closed);
  EXPECT_FALSE(bus.start());

  BusOptions bad;
  bad.realtime_reserved_indices = 256;
  Bus bad_bus(FakeSegment::make_link(segment), bad);
  auto started = bad_bus.start();
  ASSERT_FALSE(started);
  EXPECT_EQ(started.error().code(), Errc::invalid_argument);

  Bus no_link(nullptr);
  EXPECT_FALSE(no_link.start());
  EXPECT_FALSE(no_link.transact(tx));
}

TEST(Bus, InfoReportsQueueDepthsAndFramesInFlight) {
  auto segment = make_segment();
  segment->hold(true);
  BusOptions options;
  options.max_reliable_frames_in_flight = 1;
  options.frame_timeout = 5s;
  auto bus = start_bus(segment, options);
  Completions done;
  // Each transaction needs a frame of its own (1000 bytes of data).
  for (std::size_t i = 0; i < 5; ++i) {
    Transaction tx;
    tx.fprd(0x1001, 0x1000, 1000);
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(i)));
  }
  ASSERT_TRUE(eventually([&] { return bus->info().frames_in_flight == 1; }));
  ASSERT_TRUE(eventually([&] { return bus->info().reliable_queued == 4; }));
  const auto info = bus->info();
  EXPECT_EQ(info.reliable_pending, 5u);
  EXPECT_EQ(info.datagrams_in_flight, 1u);
  EXPECT_EQ(info.realtime_queued, 0u);
  EXPECT_EQ(info.realtime_frames_in_flight, 0u);
  segment->hold(false);
  ASSERT_TRUE(done.wait_for(5));
  ASSERT_TRUE(eventually([&] { return bus->info().reliable_pending == 0; }));
  EXPECT_EQ(bus->info().frames_in_flight, 0u);
}

}  // namespace
// A reply that arrived while the bus thread was off the processor is not lost: two frames in
// flight, their replies both queued, and the thread stalls after taking the first one for longer
// than the frame timeout. The second reply is still taken, not counted as a loss and retried.
TEST(Bus, RepliesWaitingAfterAStallAreNotLost) {
  auto segment = make_segment();
  segment->hold(true);
  BusOptions options;
  options.frame_timeout = 200ms;
  auto bus = start_bus(segment, options);
  Completions done;
  for (std::size_t i = 0; i < 2; ++i) {
    Transaction tx;
    tx.fprd(0x1001, 0x1000, 1000);  // a frame each
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(i)));
  }
  ASSERT_TRUE(eventually([&] { return bus->info().frames_in_flight == 2; }));
  segment->stall_after_next_receive(600ms);
  segment->hold(false);
  ASSERT_TRUE(done.wait_for(2));
  EXPECT_TRUE(done.at(0).ok());
  EXPECT_TRUE(done.at(1).ok());
  const auto stats = bus->stats();
  EXPECT_EQ(stats.frames_lost, 0u);
  EXPECT_EQ(stats.retries, 0u);
}

}  // namespace ecat::bus::test
