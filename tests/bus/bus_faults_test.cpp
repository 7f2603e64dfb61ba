// Reliable transactions against a misbehaving segment: lost, late, duplicated, corrupted and
// mismatching replies, a dying link, and stopping with work pending.

#include <array>
#include <thread>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>

#include "bus/bus_test_support.hpp"

namespace ecat::bus::test {
namespace {

constexpr std::array<std::uint8_t, 2> kValue{0xEF, 0xBE};

Transaction read_register(std::uint16_t station = 0x1001) {
  Transaction tx;
  tx.fprd(station, 0x0130, 2, 1);
  return tx;
}

std::shared_ptr<FakeSegment> segment_with_value() {
  auto segment = make_segment();
  segment->write(0, 0x0130, kValue);
  return segment;
}

BusOptions fast_timeouts() {
  BusOptions options;
  options.frame_timeout = 10ms;
  return options;
}

TEST(BusFaults, LostReplyIsRetried) {
  auto segment = segment_with_value();
  segment->inject(Fault::drop);
  auto bus = start_bus(segment, fast_timeouts());
  auto result = bus->transact(read_register());
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(bytes_of(result->data(0)), (std::vector<std::uint8_t>{0xEF, 0xBE}));
  const auto stats = bus->stats();
  EXPECT_EQ(stats.frames_lost, 1u);
  EXPECT_EQ(stats.retries, 1u);
  EXPECT_EQ(stats.frames_sent, 2u);
  EXPECT_EQ(stats.transactions_completed, 1u);
  // The retry used a fresh index.
  const auto sent = segment->sent();
  ASSERT_EQ(sent.size(), 2u);
  EXPECT_NE(datagrams_of(sent[0].bytes).at(0).index, datagrams_of(sent[1].bytes).at(0).index);
}

TEST(BusFaults, RetriesResendTheWholeTransactionInOrder) {
  FakeSegment::Options seg;
  seg.max_frame_size = 100;
  auto segment = make_segment(seg);
  auto bus = start_bus(segment, fast_timeouts());
  // Three datagrams of 40 bytes: one frame each on a 100-byte link. Lose the second frame.
  segment->inject(Fault::none);
  segment->inject(Fault::drop);
  Transaction tx;
  std::array<std::uint8_t, 40> block{};
  for (std::size_t i = 0; i < 3; ++i) {
    block.fill(static_cast<std::uint8_t>(i + 1));
    tx.fpwr(0x1001, static_cast<std::uint16_t>(0x1000 + 40 * i), block, 1);
  }
  auto result = bus->transact(std::move(tx));
  ASSERT_TRUE(result) << result.error().describe();
  const auto sent = segment->sent();
  ASSERT_EQ(sent.size(), 6u);
  for (std::size_t i = 0; i < 6; ++i) {
    const auto d = datagrams_of(sent[i].bytes);
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0].address >> 16, 0x1000u + 40 * (i % 3)) << i;
  }
  EXPECT_EQ(bus->stats().retries, 1u);
}

TEST(BusFaults, GivingUpAfterRetriesNamesTheDatagram) {
  auto segment = segment_with_value();
  for (int i = 0; i < 3; ++i)
    segment->inject(Fault::drop);
  auto bus = start_bus(segment, fast_timeouts());
  TransactOptions options;
  options.retries = 2;
  auto result = bus->transact(read_register(), options);
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::timeout);
  const auto& message = result.error().message();
  EXPECT_NE(message.find("FPRD station 0x1001 offset 0x0130 (2 bytes)"), std::string::npos)
      << message;
  EXPECT_NE(message.find("index 0x"), std::string::npos) << message;
  EXPECT_NE(message.find("10 ms"), std::string::npos) << message;
  EXPECT_NE(message.find("after 2 retries"), std::string::npos) << message;
  const auto stats = bus->stats();
  EXPECT_EQ(stats.frames_lost, 3u);
  EXPECT_EQ(stats.retries, 2u);
  EXPECT_EQ(stats.transaction_timeouts, 1u);

  // retries = 0: a single loss fails the transaction.
  segment->inject(Fault::drop);
  options.retries = 0;
  auto once = bus->transact(read_register(), options);
  ASSERT_FALSE(once);
  EXPECT_EQ(once.error().code(), Errc::timeout);
  EXPECT_EQ(bus->stats().frames_lost, 4u);
  EXPECT_EQ(bus->stats().retries, 2u);
}

TEST(BusFaults, TransactionTimeoutCoversQueueingAndRetries) {
  auto segment = segment_with_value();
  segment->hold(true);
  BusOptions options;
  options.frame_timeout = 5s;
  auto bus = start_bus(segment, options);
  TransactOptions tx_options;
  tx_options.timeout = 30ms;
  const auto start = std::chrono::steady_clock::now();
  auto result = bus->transact(read_register(), tx_options);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::timeout);
  EXPECT_NE(result.error().message().find("timed out after 30 ms"), std::string::npos)
      << result.error().message();
  EXPECT_GE(elapsed, 30ms);
  EXPECT_LT(elapsed, 2s);
  EXPECT_EQ(bus->stats().transaction_timeouts, 1u);
  // The reply still comes later: it belongs to nobody any more.
  segment->hold(false);
  ASSERT_TRUE(eventually([&] { return bus->stats().late_replies == 1; }));
  auto next = bus->transact(read_register());
  ASSERT_TRUE(next) << next.error().describe();
}

TEST(BusFaults, LateReplyIsCountedAndNotDeliveredToTheNextCaller) {
  auto segment = make_segment();
  const std::array<std::uint8_t, 2> first{0x11, 0x11};
  const std::array<std::uint8_t, 2> second{0x22, 0x22};
  segment->write(0, 0x0130, first);
  BusOptions options;
  options.frame_timeout = 100ms;
  auto bus = start_bus(segment, options);

  // A's reply arrives at +150 ms, after A's frame timed out (100 ms) and while B is in flight.
  segment->inject(Fault::delay, 150ms);
  TransactOptions no_retry;
  no_retry.retries = 0;
  auto a = bus->transact(read_register(), no_retry);
  ASSERT_FALSE(a);
  EXPECT_EQ(a.error().code(), Errc::timeout);

  segment->write(0, 0x0130, second);
  segment->inject(Fault::delay, 80ms);
  auto b = bus->transact(read_register(), no_retry);
  ASSERT_TRUE(b) << b.error().describe();
  // Same command, station, register and length: only the index tells them apart.
  EXPECT_EQ(bytes_of(b->data(0)), (std::vector<std::uint8_t>{0x22, 0x22}));
  const auto stats = bus->stats();
  EXPECT_EQ(stats.late_replies, 1u);
  EXPECT_EQ(stats.frames_lost, 1u);
  EXPECT_EQ(stats.unmatched_replies + stats.mismatched_replies, 0u);
}

// With an adaptive ceiling, a late reply doubles the time reliable frames get (never past the
// ceiling), so a reply as slow again is waited for instead of being given up; without one the
// timeout stays fixed. set_frame_timeout() starts over from its value.
TEST(BusFaults, LateRepliesLetReliableFramesWaitLongerUpToTheCeiling) {
  auto segment = segment_with_value();
  BusOptions options;
  options.frame_timeout = 40ms;
  options.adaptive_frame_timeout_limit = 100ms;
  auto bus = start_bus(segment, options);
  TransactOptions no_retry;
  no_retry.retries = 0;
  segment->inject(Fault::delay, 60ms);
  auto first = bus->transact(read_register(), no_retry);
  ASSERT_FALSE(first);
  EXPECT_EQ(first.error().code(), Errc::timeout);
  ASSERT_TRUE(eventually([&] { return bus->stats().late_replies == 1; }));
  EXPECT_EQ(bus->info().reliable_frame_timeout, 80ms);
  EXPECT_EQ(bus->info().frame_timeout, 40ms);
  // As slow again: now within the reliable frames' time.
  segment->inject(Fault::delay, 60ms);
  auto second = bus->transact(read_register(), no_retry);
  ASSERT_TRUE(second) << second.error().describe();
  EXPECT_EQ(bus->stats().frames_lost, 1u);
  // Slower than that: lost, late, and raised to the ceiling only.
  segment->inject(Fault::delay, 120ms);
  EXPECT_FALSE(bus->transact(read_register(), no_retry));
  ASSERT_TRUE(eventually([&] { return bus->stats().late_replies == 2; }));
  EXPECT_EQ(bus->info().reliable_frame_timeout, 100ms);
  ASSERT_TRUE(bus->set_frame_timeout(30ms));
  EXPECT_EQ(bus->info().reliable_frame_timeout, 30ms);
}

TEST(BusFaults, WithoutACeilingLateRepliesLeaveTheTimeoutAlone) {
  auto segment = segment_with_value();
  BusOptions options;
  options.frame_timeout = 40ms;
  auto bus = start_bus(segment, options);
  TransactOptions no_retry;
  no_retry.retries = 0;
  segment->inject(Fault::delay, 60ms);
  EXPECT_FALSE(bus->transact(read_register(), no_retry));
  ASSERT_TRUE(eventually([&] { return bus->stats().late_replies == 1; }));
  EXPECT_EQ(bus->info().reliable_frame_timeout, 40ms);
  BusOptions negative;
  negative.adaptive_frame_timeout_limit = -1ms;
  auto refused = std::make_unique<Bus>(FakeSegment::make_link(make_segment()), negative);
  auto started = refused->start();
  ASSERT_FALSE(started);
  EXPECT_EQ(started.error().code(), Errc::invalid_argument);
}

TEST(BusFaults, DuplicateReplyIsCounted) {
  auto segment = segment_with_value();
  segment->inject(Fault::duplicate);
  auto bus = start_bus(segment);
  auto result = bus->transact(read_register());
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(bytes_of(result->data(0)), (std::vector<std::uint8_t>{0xEF, 0xBE}));
  ASSERT_TRUE(eventually([&] { return bus->stats().duplicate_replies == 1; }));
  auto next = bus->transact(read_register());
  ASSERT_TRUE(next);
  const auto stats = bus->stats();
  EXPECT_EQ(stats.frames_received, 3u);
  EXPECT_EQ(stats.transactions_completed, 2u);
  EXPECT_EQ(stats.frames_lost, 0u);
}

struct MismatchCase {
  Fault fault;
  bool unmatched;  // counted as unmatched (index not in flight) rather than mismatched
};

class BusMismatch : public ::testing::TestWithParam<MismatchCase> {};

TEST_P(BusMismatch, WrongReplyIsCountedIgnoredAndTheTransactionRetried) {
  auto segment = segment_with_value();
  segment->inject(GetParam().fault);
  auto bus = start_bus(segment, fast_timeouts());
  auto result = bus->transact(read_register());
  ASSERT_TRUE(result) << result.error().describe();
  EXPECT_EQ(bytes_of(result->data(0)), (std::vector<std::uint8_t>{0xEF, 0xBE}));
  EXPECT_EQ(result->wkc(0), 1);
  const auto stats = bus->stats();
  EXPECT_EQ(stats.unmatched_replies, GetParam().unmatched ? 1u : 0u);
  EXPECT_EQ(stats.mismatched_replies, GetParam().unmatched ? 0u : 1u);
  EXPECT_EQ(stats.frames_lost, 1u);
  EXPECT_EQ(stats.retries, 1u);
  EXPECT_EQ(stats.frames_received, 2u);
}

INSTANTIATE_TEST_SUITE_P(Faults, BusMismatch,
                         ::testing::Values(MismatchCase{Fault::wrong_index, true},
                                           MismatchCase{Fault::wrong_command, false},
                                           MismatchCase{Fault::wrong_length, false},
                                           MismatchCase{Fault::wrong_address, false}));

TEST(BusFaults, MismatchInTheMiddleOfAFrameRejectsTheWholeFrame) {
  auto segment = segment_with_value();
  // Long enough that the bus does not retry before the hand-made reply is in (with 10 ms, a
  // loaded machine saw the retry first, and frames_sent() was 2 before the test looked).
  BusOptions options;
  options.frame_timeout = 300ms;
  auto bus = start_bus(segment, options);
  // Reply whose second datagram's length differs: build it by hand from what the bus sends.
  segment->inject(Fault::drop);
  Transaction tx;
  tx.fprd(0x1001, 0x0130, 2, 1);
  tx.fprd(0x1002, 0x0130, 2, 1);
  Completions done;
  ASSERT_TRUE(bus->submit(std::move(tx), done.make(0)));
  ASSERT_TRUE(eventually([&] { return segment->frames_sent() == 1; }));
  auto request = segment->sent().at(0).bytes;
  // Same frame, second datagram with a different command: must not be accepted.
  request[2 + 12 + 2] = static_cast<std::uint8_t>(wire::Command::fpwr);
  segment->inject_frame(request);
  ASSERT_TRUE(done.wait_for(1));
  ASSERT_TRUE(done.at(0)) << done.at(0).error().describe();
  EXPECT_EQ(done.at(0)->wkc(0), 1);
  EXPECT_EQ(bus->stats().mismatched_replies, 1u);
  EXPECT_EQ(bus->stats().retries, 1u);
}

TEST(BusFaults, CorruptFrameIsADecodeError) {
  auto segment = segment_with_value();
  segment->inject(Fault::corrupt);
  auto bus = start_bus(segment, fast_timeouts());
  auto result = bus->transact(read_register());
  ASSERT_TRUE(result) << result.error().describe();
  const auto stats = bus->stats();
  EXPECT_EQ(stats.decode_errors, 1u);
  EXPECT_EQ(stats.frames_lost, 1u);
  EXPECT_EQ(stats.retries, 1u);
}

TEST(BusFaults, StrayFramesAreCountedAsUnmatched) {
  auto segment = segment_with_value();
  auto bus = start_bus(segment);
  Transaction tx;
  tx.fprd(0x1001, 0x0130, 2);
  auto first = bus->transact(tx);
  ASSERT_TRUE(first);
  // A frame with an index the bus never used.
  std::array<std::uint8_t, 64> buffer{};
  wire::FrameBuilder builder(buffer);
  ASSERT_TRUE(builder.add(wire::DatagramHeader{wire::Command::brd, 0xC3, 0, 1, false, false, 0}));
  segment->inject_frame(builder.finish());
  ASSERT_TRUE(eventually([&] { return bus->stats().unmatched_replies == 1; }));
  EXPECT_TRUE(bus->transact(tx));
  EXPECT_EQ(bus->stats().duplicate_replies + bus->stats().late_replies, 0u);
}

TEST(BusFaults, ReorderedRepliesAreMatchedByIndex) {
  auto segment = make_segment();
  for (std::size_t s = 0; s < 3; ++s) {
    const std::array<std::uint8_t, 2> v{static_cast<std::uint8_t>(s), 0x5A};
    segment->write(s, 0x0130, v);
  }
  segment->inject(Fault::reorder);
  BusOptions options;
  options.max_reliable_frames_in_flight = 4;
  auto bus = start_bus(segment, options);
  Completions done;
  // Each transaction alone in a frame (1200 bytes), so the held reply is overtaken.
  for (std::size_t i = 0; i < 3; ++i) {
    Transaction tx;
    tx.fprd(static_cast<std::uint16_t>(0x1001 + i), 0x0130, 2, 1);
    tx.fprd(static_cast<std::uint16_t>(0x1001 + i), 0x1000, 1200);
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(i)));
  }
  ASSERT_TRUE(done.wait_for(3));
  for (std::size_t i = 0; i < 3; ++i) {
    ASSERT_TRUE(done.at(i)) << done.at(i).error().describe();
    EXPECT_EQ(bytes_of(done.at(i)->data(0)),
              (std::vector<std::uint8_t>{static_cast<std::uint8_t>(i), 0x5A}));
  }
  EXPECT_EQ(bus->stats().frames_lost, 0u);
}

TEST(BusFaults, StopCompletesPendingWorkWithClosed) {
  auto segment = segment_with_value();
  segment->hold(true);
  BusOptions options;
  options.frame_timeout = 5s;
  auto bus = start_bus(segment, options);
  Completions done;
  for (std::size_t i = 0; i < 50; ++i)
    ASSERT_TRUE(bus->submit(read_register(), done.make(i)));
  std::optional<Result<TransactionResult>> blocking;
  std::thread waiter([&] { blocking.emplace(bus->transact(read_register())); });
  Transaction layout;
  const std::array<std::uint8_t, 4> image{};
  layout.lrw(0x10000, image);
  RealtimeTransaction rt(std::move(layout));
  ASSERT_TRUE(bus->submit_realtime(rt, 1s));
  ASSERT_TRUE(eventually([&] { return bus->info().reliable_pending == 51; }));

  bus->stop();
  waiter.join();
  EXPECT_EQ(done.done(), 50u);
  for (std::size_t i = 0; i < 50; ++i) {
    ASSERT_FALSE(done.at(i));
    EXPECT_EQ(done.at(i).error().code(), Errc::closed);
    EXPECT_NE(done.at(i).error().message().find("stopped"), std::string::npos);
  }
  ASSERT_TRUE(blocking.has_value());
  ASSERT_FALSE(*blocking);
  EXPECT_EQ(blocking->error().code(), Errc::closed);
  EXPECT_FALSE(rt.pending());
  EXPECT_EQ(rt.status(), RealtimeStatus::closed);
  EXPECT_EQ(rt.result().error().code(), Errc::closed);

  bool called = false;
  auto refused = bus->submit(read_register(), [&](Result<TransactionResult>) { called = true; });
  ASSERT_FALSE(refused);
  EXPECT_EQ(refused.error().code(), Errc::closed);
  EXPECT_FALSE(called);
  EXPECT_FALSE(bus->submit_realtime(rt, 1s));
  bus.reset();  // destruction after stop is clean
}

TEST(BusFaults, DestructionWithPendingWorkIsClean) {
  auto segment = segment_with_value();
  segment->hold(true);
  Completions done;
  {
    auto bus = start_bus(segment);
    for (std::size_t i = 0; i < 10; ++i)
      ASSERT_TRUE(bus->submit(read_register(), done.make(i)));
  }
  EXPECT_EQ(done.done(), 10u);
  EXPECT_EQ(done.at(9).error().code(), Errc::closed);
}

TEST(BusFaults, DeadLinkFailsEverythingWithTheLinkErrorAsCause) {
  auto segment = segment_with_value();
  segment->hold(true);
  BusOptions options;
  options.frame_timeout = 5s;
  auto bus = start_bus(segment, options);
  std::optional<Result<TransactionResult>> pending;
  std::thread waiter([&] { pending.emplace(bus->transact(read_register())); });
  ASSERT_TRUE(eventually([&] { return bus->info().frames_in_flight == 1; }));
  segment->kill(Errc::io_error);
  waiter.join();
  ASSERT_TRUE(pending.has_value());
  ASSERT_FALSE(*pending);
  const Error& error = pending->error();
  EXPECT_EQ(error.code(), Errc::io_error);
  EXPECT_NE(error.message().find("FPRD station 0x1001"), std::string::npos) << error.describe();
  ASSERT_NE(error.cause(), nullptr);
  EXPECT_NE(error.describe().find("fake segment: link is down"), std::string::npos)
      << error.describe();

  // Later requests fail at once, naming the same cause.
  const auto start = std::chrono::steady_clock::now();
  auto later = bus->transact(read_register());
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
  ASSERT_FALSE(later);
  EXPECT_NE(later.error().describe().find("link is down"), std::string::npos);
  const auto info = bus->info();
  ASSERT_TRUE(info.link_failure.has_value());
  EXPECT_GE(bus->stats().receive_errors, 1u);
}

TEST(BusFaults, AFailedLinkIsReopenedWithABoundedBackoffAndWorkFlowsAgain) {
  auto segment = segment_with_value();
  segment->allow_reopen(true);
  BusOptions options;
  options.reopen_backoff_min = 10ms;
  options.reopen_backoff_max = 1s;
  auto bus = start_bus(segment, options);
  ASSERT_TRUE(bus->transact(read_register()));
  segment->kill(Errc::io_error);
  // The failure shows in the next request (it fails, naming the cause) and in info().
  auto failed = bus->transact(read_register());
  ASSERT_FALSE(failed);
  EXPECT_NE(failed.error().describe().find("link is down"), std::string::npos)
      << failed.error().describe();
  ASSERT_TRUE(eventually([&] { return bus->info().reopen_attempts >= 2; }));
  auto down = bus->info();
  EXPECT_TRUE(down.link_failure.has_value());
  EXPECT_EQ(down.link_failures, 1u);
  EXPECT_EQ(down.link_reopens, 0u);
  EXPECT_TRUE(down.link_reopenable);
  ASSERT_TRUE(down.last_reopen_error.has_value());
  EXPECT_NE(down.last_reopen_error->describe().find("still down"), std::string::npos);
  // Bounded: one attempt at once, then waits doubling from 10 ms, so any 300 ms after the first
  // two attempts hold at most 4 (at 30, 70, 150 and 310 ms after the failure) however fast the
  // machine is.
  const auto attempts_before = bus->info().reopen_attempts;
  std::this_thread::sleep_for(300ms);
  EXPECT_LE(bus->info().reopen_attempts - attempts_before, 5u);

  segment->revive();
  ASSERT_TRUE(eventually([&] { return bus->info().link_reopens == 1; }, 5s));
  const auto up = bus->info();
  EXPECT_FALSE(up.link_failure.has_value());
  EXPECT_FALSE(up.last_reopen_error.has_value());
  auto again = bus->transact(read_register());
  ASSERT_TRUE(again) << again.error().describe();

  // A second failure is counted and healed the same way.
  segment->kill(Errc::io_error);
  ASSERT_FALSE(bus->transact(read_register()));
  ASSERT_TRUE(eventually([&] { return bus->info().link_failures == 2; }));
  segment->revive();
  ASSERT_TRUE(eventually([&] { return bus->info().link_reopens == 2; }, 5s));
  EXPECT_TRUE(bus->transact(read_register()));
}

TEST(BusFaults, ALinkThatCannotBeReopenedStaysFailed) {
  auto segment = segment_with_value();  // reopen not allowed: Errc::unsupported
  auto bus = start_bus(segment);
  segment->kill(Errc::io_error);
  ASSERT_FALSE(bus->transact(read_register()));
  ASSERT_TRUE(eventually([&] { return !bus->info().link_reopenable; }));
  segment->revive();
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(segment->reopen_calls(), 1);  // asked once; the answer is final
  const auto info = bus->info();
  EXPECT_TRUE(info.link_failure.has_value());
  EXPECT_EQ(info.link_reopens, 0u);
  ASSERT_TRUE(info.last_reopen_error.has_value());
  EXPECT_EQ(info.last_reopen_error->code(), Errc::unsupported);
  EXPECT_FALSE(bus->transact(read_register()));
}

TEST(BusFaults, ReopenBackoffMustBePositiveAndOrdered) {
  auto segment = segment_with_value();
  for (auto [min, max] : {std::pair{0ms, 1000ms}, std::pair{50ms, 10ms}}) {
    BusOptions options;
    options.reopen_backoff_min = min;
    options.reopen_backoff_max = max;
    Bus bus(FakeSegment::make_link(segment), options);
    auto started = bus.start();
    ASSERT_FALSE(started);
    EXPECT_NE(started.error().describe().find("reopen backoff"), std::string::npos);
  }
}

TEST(BusFaults, SendFailureFailsTheTransactionsOfThatFrame) {
  auto segment = segment_with_value();
  auto bus = start_bus(segment);
  segment->kill(Errc::closed);
  Transaction tx;
  tx.brd(0, 1);
  auto result = bus->transact(std::move(tx));
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::closed);
  ASSERT_NE(result.error().cause(), nullptr);
  EXPECT_NE(result.error().describe().find("link is down"), std::string::npos)
      << result.error().describe();
}

}  // namespace
}  // namespace ecat::bus::test
