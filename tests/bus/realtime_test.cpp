// Realtime exchanges: round trips, own frames, priority over reliable backlog, expiry, timeouts,
// working-counter checks, and the cycle function on the bus thread.

#include <algorithm>
#include <array>
#include <atomic>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>

#include "bus/bus_test_support.hpp"

namespace ecat::bus::test {
namespace {

using wire::Command;

// Slave 0 takes 2 output bytes at 0x10000, slave 1 gives 2 input bytes at 0x10002.
std::shared_ptr<FakeSegment> segment_with_process_image(FakeSegment::Options options = {}) {
  auto segment = make_segment(options);
  segment->map_logical(0, {0x00010000, 0x1000, 2, false, true});
  segment->map_logical(1, {0x00010002, 0x1100, 2, true, false});
  const std::array<std::uint8_t, 2> inputs{0xC1, 0xC2};
  segment->write(1, 0x1100, inputs);
  return segment;
}

Transaction lrw_layout(std::uint16_t expected_wkc = 3) {
  Transaction layout;
  const std::array<std::uint8_t, 4> image{};
  layout.lrw(0x00010000, image, expected_wkc);
  return layout;
}

TEST(Realtime, CyclicLrwRoundTrips) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  EXPECT_EQ(rt.status(), RealtimeStatus::not_run);
  EXPECT_FALSE(rt.pending());
  for (int cycle = 0; cycle < 100; ++cycle) {
    auto out = rt.output(0);
    out[0] = static_cast<std::uint8_t>(cycle);
    out[1] = 0x5A;
    ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
    rt.wait();
    ASSERT_EQ(rt.status(), RealtimeStatus::ok) << rt.result().error().describe();
    EXPECT_EQ(rt.wkc(0), 3);
    EXPECT_EQ(bytes_of(rt.input(0)),
              (std::vector<std::uint8_t>{static_cast<std::uint8_t>(cycle), 0x5A, 0xC1, 0xC2}));
    EXPECT_EQ(segment->read(0, 0x1000, 2),
              (std::vector<std::uint8_t>{static_cast<std::uint8_t>(cycle), 0x5A}));
  }
  EXPECT_EQ(rt.completions(), 100u);
  EXPECT_GT(rt.reply_timestamp_ns(), 0);
  // Sent before its reply came back, after it was submitted.
  EXPECT_GT(rt.sent_timestamp_ns(), 0);
  EXPECT_LE(rt.sent_timestamp_ns(), rt.reply_timestamp_ns());
  const auto before = std::chrono::duration_cast<std::chrono::nanoseconds>(
                          std::chrono::steady_clock::now().time_since_epoch())
                          .count();
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  rt.wait();
  EXPECT_GE(rt.sent_timestamp_ns(), before);
  EXPECT_TRUE(rt.result());
  const auto stats = bus->stats();
  EXPECT_EQ(stats.realtime_completed, 101u);
  EXPECT_EQ(stats.realtime_frames_sent, 101u);
  EXPECT_EQ(stats.frames_sent, 101u);
}

TEST(Realtime, ResubmittingWhilePendingIsBusy) {
  auto segment = segment_with_process_image();
  segment->hold(true);
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  ASSERT_TRUE(bus->submit_realtime(rt, 1s));
  EXPECT_TRUE(rt.pending());
  auto again = bus->submit_realtime(rt, 1s);
  ASSERT_FALSE(again);
  EXPECT_EQ(again.error().code(), Errc::busy);
  segment->hold(false);
  ASSERT_TRUE(rt.wait_for(5s));
  EXPECT_EQ(rt.status(), RealtimeStatus::ok);
}

TEST(Realtime, InvalidSubmissionsAreRefused) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  auto zero = bus->submit_realtime(rt, 0ns);
  ASSERT_FALSE(zero);
  EXPECT_EQ(zero.error().code(), Errc::invalid_argument);
  RealtimeTransaction empty{Transaction{}};
  EXPECT_FALSE(bus->submit_realtime(empty, 1ms));
  Transaction broken;
  broken.lrd(0, 4000);
  RealtimeTransaction too_long(std::move(broken));
  auto r = bus->submit_realtime(too_long, 1ms);
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_FALSE(rt.pending());
  EXPECT_EQ(segment->frames_sent(), 0u);
}

TEST(Realtime, WkcMismatchKeepsTheData) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout(5));
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  rt.wait();
  EXPECT_EQ(rt.status(), RealtimeStatus::wkc_mismatch);
  EXPECT_EQ(rt.wkc(0), 3);
  EXPECT_EQ(rt.input(0)[2], 0xC1);
  const auto result = rt.result();
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::wkc_mismatch);
  EXPECT_NE(result.error().message().find("LRW logical 0x00010000 (4 bytes)"), std::string::npos)
      << result.error().message();
  EXPECT_NE(result.error().message().find("working counter 3, expected 5"), std::string::npos);
  EXPECT_EQ(bus->stats().wkc_mismatches, 1u);
}

TEST(Realtime, LostFrameTimesOutWithoutRetry) {
  auto segment = segment_with_process_image();
  segment->inject(Fault::drop, {}, Command::lrw);
  BusOptions options;
  options.frame_timeout = 10ms;
  auto bus = start_bus(segment, options);
  RealtimeTransaction rt(lrw_layout());
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  ASSERT_TRUE(rt.wait_for(5s));
  EXPECT_EQ(rt.status(), RealtimeStatus::timeout);
  const auto result = rt.result();
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::timeout);
  EXPECT_NE(result.error().message().find("LRW logical 0x00010000"), std::string::npos)
      << result.error().message();
  const auto stats = bus->stats();
  EXPECT_EQ(stats.realtime_timeouts, 1u);
  EXPECT_EQ(stats.frames_lost, 1u);
  EXPECT_EQ(stats.retries, 0u);
  EXPECT_EQ(segment->frames_sent(), 1u);
  // The next cycle works again.
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  rt.wait();
  EXPECT_EQ(rt.status(), RealtimeStatus::ok);
}

TEST(Realtime, ExpiresWhenItCannotBeSentBeforeItsDeadline) {
  auto segment = segment_with_process_image();
  // The first LRW's reply takes 100 ms; with one realtime frame slot the second cannot go out.
  segment->inject(Fault::delay, 100ms, Command::lrw);
  BusOptions options;
  options.max_realtime_frames_in_flight = 1;
  options.frame_timeout = 1s;
  auto bus = start_bus(segment, options);
  RealtimeTransaction first(lrw_layout());
  RealtimeTransaction second(lrw_layout());
  ASSERT_TRUE(bus->submit_realtime(first, 1s));
  ASSERT_TRUE(eventually([&] { return bus->info().realtime_frames_in_flight == 1; }));
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE(bus->submit_realtime(second, 5ms));
  ASSERT_TRUE(second.wait_for(5s));
  const auto waited = std::chrono::steady_clock::now() - start;
  EXPECT_EQ(second.status(), RealtimeStatus::expired);
  EXPECT_GE(waited, 5ms);
  EXPECT_LT(waited, 90ms);  // well before the first one's reply frees the slot
  const auto result = second.result();
  ASSERT_FALSE(result);
  EXPECT_EQ(result.error().code(), Errc::expired);
  EXPECT_NE(result.error().message().find("5000 us staleness budget"), std::string::npos)
      << result.error().message();
  EXPECT_TRUE(first.pending());
  ASSERT_TRUE(first.wait_for(5s));
  EXPECT_EQ(first.status(), RealtimeStatus::ok);
  EXPECT_EQ(bus->stats().realtime_expired, 1u);
  EXPECT_EQ(segment->frames_sent(), 1u);  // the expired exchange sent nothing
}

TEST(Realtime, GoesOutInTheVeryNextFrameDespiteADeepReliableBacklog) {
  auto segment = segment_with_process_image();
  segment->set_reply_delay(1ms);
  auto bus = start_bus(segment);

  // 3000 reads of 64 bytes: 19 per frame, about 160 frames of backlog. Replies are held while
  // submitting so that the backlog is deep however slow submission is; then traffic flows.
  Completions done;
  constexpr std::size_t kBacklog = 3000;
  segment->hold(true);
  for (std::size_t i = 0; i < kBacklog; ++i) {
    Transaction tx;
    tx.fprd(0x1001, static_cast<std::uint16_t>(0x1000 + i % 64), 64);
    ASSERT_TRUE(bus->submit(std::move(tx), done.make(i)));
  }
  ASSERT_TRUE(eventually([&] { return bus->info().reliable_queued > 2500; }));
  segment->hold(false);
  ASSERT_TRUE(eventually([&] { return segment->frames_sent() >= 8; }));
  const auto queued = bus->info().reliable_queued;
  EXPECT_GT(queued, 1000u);

  RealtimeTransaction rt(lrw_layout());
  segment->set_marker(1);
  ASSERT_TRUE(bus->submit_realtime(rt, 1s));
  ASSERT_TRUE(rt.wait_for(5s));
  EXPECT_EQ(rt.status(), RealtimeStatus::ok);
  ASSERT_TRUE(done.wait_for(kBacklog, 30s));

  const auto sent = segment->sent();
  std::optional<std::size_t> first_marked;
  std::optional<std::size_t> realtime_frame;
  for (std::size_t i = 0; i < sent.size(); ++i) {
    if (!first_marked && sent[i].marker == 1) first_marked = i;
    const auto datagrams = datagrams_of(sent[i].bytes);
    const bool has_lrw = std::any_of(datagrams.begin(), datagrams.end(), [](const SentDatagram& d) {
      return d.command == Command::lrw;
    });
    if (has_lrw) {
      EXPECT_FALSE(realtime_frame) << "LRW sent twice";
      realtime_frame = i;
      // Its own frame: nothing reliable mixed in.
      EXPECT_EQ(datagrams.size(), 1u);
    }
  }
  ASSERT_TRUE(first_marked);
  ASSERT_TRUE(realtime_frame);
  // At most one reliable frame (already being built when the request arrived) went first.
  EXPECT_LE(*realtime_frame, *first_marked + 1);
  EXPECT_GT(sent.size() - *realtime_frame, 50u) << "the backlog was not deep any more";
}

TEST(Realtime, LargeImageSpansSeveralFramesOfItsOwn) {
  FakeSegment::Options options;
  auto segment = make_segment(options);
  segment->map_logical(2, {0x00020000, 0x1000, 3000, true, true});
  auto bus = start_bus(segment);
  Transaction layout;
  std::vector<std::uint8_t> chunk(1000, 0);
  for (std::size_t i = 0; i < 3; ++i) {
    layout.lrw(static_cast<std::uint32_t>(0x00020000 + 1000 * i), chunk, 3);
  }
  RealtimeTransaction rt(std::move(layout));
  for (std::size_t i = 0; i < 3; ++i) {
    auto out = rt.output(i);
    for (std::size_t j = 0; j < out.size(); ++j)
      out[j] = static_cast<std::uint8_t>(i + j);
  }
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  rt.wait();
  ASSERT_EQ(rt.status(), RealtimeStatus::ok) << rt.result().error().describe();
  EXPECT_EQ(segment->frames_sent(), 3u);
  // The slave read then wrote each byte: inputs echo the outputs.
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(rt.input(i)[10], static_cast<std::uint8_t>(i + 10));
    EXPECT_EQ(rt.wkc(i), 3);
  }
  EXPECT_EQ(bus->stats().realtime_frames_sent, 3u);
}

TEST(Realtime, CycleFunctionRunsOnAbsoluteDeadlinesOnTheBusThread) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  std::mutex mutex;
  std::vector<CycleTick> ticks;
  std::atomic<int> on_bus{0};
  std::atomic<int> submitted{0};
  constexpr auto kPeriod = 2ms;
  ASSERT_TRUE(bus->set_cycle(kPeriod, [&](const CycleTick& tick) {
    if (bus->on_bus_thread()) on_bus.fetch_add(1);
    // The previous exchange completed long ago (same thread, 2 ms period).
    if (!rt.pending() && bus->submit_realtime(rt, 1ms)) submitted.fetch_add(1);
    std::lock_guard lock(mutex);
    ticks.push_back(tick);
  }));
  ASSERT_TRUE(eventually([&] {
    std::lock_guard lock(mutex);
    return ticks.size() >= 30;
  }));
  bus->clear_cycle();
  std::vector<CycleTick> seen;
  {
    std::lock_guard lock(mutex);
    seen = ticks;
  }
  std::this_thread::sleep_for(10ms);
  {
    std::lock_guard lock(mutex);
    EXPECT_EQ(ticks.size(), seen.size()) << "cycle function ran after clear_cycle()";
  }
  ASSERT_GE(seen.size(), 30u);
  for (std::size_t i = 1; i < seen.size(); ++i) {
    const auto step = seen[i].deadline - seen[i - 1].deadline;
    EXPECT_EQ(step, kPeriod * (1 + seen[i].missed)) << i;
    EXPECT_EQ(seen[i].cycle, seen[i - 1].cycle + 1);
    EXPECT_GE(seen[i].woke_at, seen[i].deadline);
  }
  EXPECT_EQ(seen[0].deadline.time_since_epoch() % kPeriod, std::chrono::nanoseconds(0));
  EXPECT_EQ(on_bus.load(), static_cast<int>(seen.size()));
  EXPECT_GE(submitted.load(), static_cast<int>(seen.size()) - 2);
  EXPECT_GE(bus->stats().cycles, seen.size());
  ASSERT_TRUE(rt.wait_for(1s));
  EXPECT_FALSE(bus->set_cycle(0ns, [](const CycleTick&) {}));
  EXPECT_FALSE(bus->set_cycle(1ms, CycleFunction{}));
}

TEST(Realtime, CycleTraceRecordsEveryTicksStepsInOrder) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  constexpr auto kPeriod = 2ms;
  std::atomic<int> refused_on_bus{0};
  ASSERT_TRUE(bus->set_cycle(kPeriod, [&](const CycleTick&) {
    CycleTrace none(1);
    const auto r = bus->set_cycle_trace(&none);
    if (!r && r.error().code() == Errc::wrong_state) refused_on_bus.fetch_add(1);
    if (!rt.pending()) (void)bus->submit_realtime(rt, 1ms);
  }));
  CycleTrace trace(12);
  EXPECT_EQ(trace.size(), 0u);
  ASSERT_TRUE(bus->set_cycle_trace(&trace));
  ASSERT_TRUE(eventually([&] { return trace.full(); }));
  ASSERT_TRUE(bus->set_cycle_trace(nullptr));
  EXPECT_EQ(trace.size(), trace.capacity());
  std::size_t exchanged = 0;
  for (std::size_t i = 0; i < trace.size(); ++i) {
    const CycleTraceRecord& r = trace[i];
    if (i > 0) {
      EXPECT_EQ(r.cycle, trace[i - 1].cycle + 1) << i;
    }
    EXPECT_EQ(r.due_ns % std::chrono::nanoseconds(kPeriod).count(), 0) << i;
    EXPECT_LE(r.due_ns, r.woke_ns) << i;
    EXPECT_LE(r.woke_ns, r.participants_ns) << i;
    EXPECT_GE(r.turns, 1u) << i;
    if (i > 0) {
      // The wait before the tick never asked to sleep past its deadline.
      EXPECT_GT(r.wait_entered_ns, 0) << i;
      EXPECT_LE(r.wait_entered_ns, r.wait_returned_ns) << i;
      EXPECT_LE(r.wait_returned_ns, r.woke_ns) << i;
      EXPECT_LE(r.wait_until_ns, r.due_ns) << i;
    }
    if (r.sent_ns != 0) {
      ++exchanged;
      EXPECT_LE(r.participants_ns, r.sent_ns) << i;
      EXPECT_LE(r.sent_ns, r.reply_ns) << i;
      EXPECT_LE(r.reply_ns, r.completed_ns) << i;
    }
  }
  EXPECT_GE(exchanged, trace.size() - 2);
  EXPECT_GT(refused_on_bus.load(), 0);
  // Detached: nothing more is written, and a trace can be swapped while the cycle runs.
  CycleTrace second(1000);
  ASSERT_TRUE(bus->set_cycle_trace(&second));
  ASSERT_TRUE(eventually([&] { return second.size() >= 2; }));
  ASSERT_TRUE(bus->set_cycle_trace(nullptr));
  const std::size_t kept = second.size();
  std::this_thread::sleep_for(4 * kPeriod);
  EXPECT_EQ(second.size(), kept);
  bus->clear_cycle();
  ASSERT_TRUE(rt.wait_for(1s));
}

TEST(Realtime, SteeredCycleMovesItsDeadlinesNotItsGrid) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  std::mutex mutex;
  std::vector<CycleTick> ticks;
  constexpr auto kPeriod = 2ms;
  // Rate: every period 1000 ppm longer (2 us); a phase step of 1.1 ms, spread over ticks of at
  // most a quarter period (500 us).
  bus->set_cycle_rate(1000.0);
  ASSERT_TRUE(bus->set_cycle(kPeriod, [&](const CycleTick& tick) {
    std::lock_guard lock(mutex);
    ticks.push_back(tick);
    if (ticks.size() == 5) bus->shift_cycle(1100us);  // from the bus thread: allowed
  }));
  ASSERT_TRUE(eventually([&] {
    std::lock_guard lock(mutex);
    return ticks.size() >= 20;
  }));
  bus->clear_cycle();
  std::vector<CycleTick> seen;
  {
    std::lock_guard lock(mutex);
    seen = ticks;
  }
  const auto steering = bus->cycle_steering();
  EXPECT_DOUBLE_EQ(steering.rate_ppm, 1000.0);
  EXPECT_EQ(steering.steps, 3u);  // 500 + 500 + 100 us
  EXPECT_EQ(steering.pending, 0ns);
  for (std::size_t i = 1; i < seen.size(); ++i) {
    if (seen[i].missed != 0) continue;  // a late bus thread: the grid skipped ahead
    // The grid the Cycler schedules by never moves.
    EXPECT_EQ(seen[i].nominal - seen[i - 1].nominal, kPeriod) << i;
    EXPECT_EQ(seen[i].nominal.time_since_epoch() % kPeriod, 0ns) << i;
    // The deadlines: the period stretched by 2 us, plus the phase step's share.
    const auto step = seen[i].deadline - seen[i - 1].deadline;
    std::chrono::nanoseconds expected = kPeriod + 2us;
    if (i == 5 || i == 6) expected += 500us;
    if (i == 7) expected += 100us;
    EXPECT_NEAR(static_cast<double>(step.count()), static_cast<double>(expected.count()), 2.0)
        << "tick " << i;
    EXPECT_GE(seen[i].woke_at, seen[i].deadline);
  }
  // Steering persists across set_cycle(): the new cycle's first deadline is a steered grid
  // point still ahead, not a pause of the accumulated offset's length.
  const auto offset = bus->cycle_steering().offset;
  EXPECT_GT(offset, 1100us);
  std::atomic<int> after{0};
  std::atomic<std::int64_t> first_offset{-1};
  ASSERT_TRUE(bus->set_cycle(kPeriod, [&](const CycleTick& tick) {
    if (after.fetch_add(1) == 0) first_offset.store((tick.deadline - tick.nominal).count());
  }));
  ASSERT_TRUE(eventually([&] { return after.load() >= 2; }));
  EXPECT_NEAR(static_cast<double>(first_offset.load()), static_cast<double>(offset.count()), 4.0);
  bus->reset_cycle_steering();
  ASSERT_TRUE(eventually([&] { return bus->cycle_steering().offset == 0ns; }));
  bus->clear_cycle();
  // Nonsense rates are not followed.
  bus->set_cycle_rate(std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(bus->cycle_steering().rate_ppm, 0.0);
  bus->set_cycle_rate(1e9);
  EXPECT_EQ(bus->cycle_steering().rate_ppm, 1000.0);
}

TEST(Realtime, CompletionCallbackRunsOnTheBusThread) {
  auto segment = segment_with_process_image();
  auto bus = start_bus(segment);
  RealtimeTransaction rt(lrw_layout());
  std::atomic<bool> on_bus{false};
  std::atomic<int> calls{0};
  rt.set_completion([&](RealtimeTransaction& done) {
    on_bus.store(bus->on_bus_thread());
    EXPECT_EQ(done.status(), RealtimeStatus::ok);
    calls.fetch_add(1);
  });
  ASSERT_TRUE(bus->submit_realtime(rt, 100ms));
  rt.wait();
  EXPECT_EQ(calls.load(), 1);
  EXPECT_TRUE(on_bus.load());
}

}  // namespace
}  // namespace ecat::bus::test
