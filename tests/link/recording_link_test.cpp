// RecordingLink and FrameRecorder: every frame sent and received is recorded with its direction
// and times; snapshots see the last seconds; streaming hands every frame to the sink once; a ring
// too small for a slow sink drops and counts instead of waiting.
#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/recording_link.hpp>

namespace {

using namespace std::chrono_literals;
using namespace ecat::link;
using Bytes = std::vector<std::uint8_t>;

Bytes frame_of(std::size_t size, std::uint8_t seed) {
  Bytes f(size);
  for (std::size_t i = 0; i < size; ++i)
    f[i] = static_cast<std::uint8_t>(seed + i);
  return f;
}

TEST(RecordingLink, RecordsBothDirectionsAndForwards) {
  auto [a, b] = make_memory_link_pair();
  auto recorder = std::make_shared<FrameRecorder>();
  RecordingLink link(std::move(a), recorder);
  EXPECT_EQ(link.name(), "memory:a");
  const Bytes out = frame_of(40, 1);
  const Bytes in = frame_of(23, 9);
  ASSERT_TRUE(link.send(out));
  ASSERT_TRUE(b->send(in));
  auto received = link.receive(100ms);
  ASSERT_TRUE(received);
  ASSERT_TRUE(received->has_value());
  auto echoed = b->receive(100ms);
  ASSERT_TRUE(echoed && echoed->has_value());
  EXPECT_EQ(link.stats().frames_sent, 1u);

  const auto frames = recorder->snapshot();
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[0].direction, FrameDirection::outbound);
  EXPECT_EQ(frames[0].data, out);
  EXPECT_EQ(frames[1].direction, FrameDirection::inbound);
  EXPECT_EQ(Bytes(frames[1].data.begin(), frames[1].data.begin() + 23), in);
  EXPECT_LE(frames[0].steady_ns, frames[1].steady_ns);
  const auto now = std::chrono::system_clock::now().time_since_epoch().count();
  EXPECT_NEAR(static_cast<double>(frames[0].realtime_ns), static_cast<double>(now), 5e9);
  EXPECT_EQ(recorder->stats().recorded, 2u);
}

TEST(FrameRecorder, SnapshotKeepsTheWindowAndTheBudget) {
  FrameRecorder recorder({.window = 10s, .byte_budget = 64 << 10, .max_frame_bytes = 100});
  const std::int64_t now = std::chrono::steady_clock::now().time_since_epoch().count();
  // An old frame (20 s ago) and a recent one: the window keeps the recent one only.
  recorder.record(FrameDirection::outbound, frame_of(16, 0), now - 20'000'000'000);
  recorder.record(FrameDirection::outbound, frame_of(16, 1), now - 1'000'000);
  EXPECT_EQ(recorder.snapshot().size(), 1u);
  EXPECT_EQ(recorder.snapshot(30s).size(), 2u);
  // Longer than max_frame_bytes: kept cut, the original length told.
  recorder.record(FrameDirection::inbound, frame_of(300, 2), 0);
  auto frames = recorder.snapshot(1s);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(frames[1].data.size(), 100u);
  EXPECT_EQ(frames[1].original_length, 300u);
  EXPECT_EQ(recorder.stats().truncated, 1u);
  // Far more than the budget: the newest survive, intact.
  for (int i = 0; i < 10000; ++i)
    recorder.record(FrameDirection::outbound, frame_of(64, static_cast<std::uint8_t>(i)), 0);
  frames = recorder.snapshot(10s);
  ASSERT_FALSE(frames.empty());
  EXPECT_LT(frames.size(), 10000u);
  EXPECT_EQ(frames.back().data, frame_of(64, static_cast<std::uint8_t>(9999)));
  bool cut = false;
  EXPECT_EQ(recorder.snapshot(10s, 640, &cut).size(), 10u);
  EXPECT_TRUE(cut);
}

TEST(FrameRecorder, StreamsEveryFrameOnceInOrder) {
  FrameRecorder recorder;
  recorder.record(FrameDirection::outbound, frame_of(8, 0), 0);  // before streaming: not streamed
  std::vector<Bytes> seen;
  ASSERT_TRUE(recorder.start_streaming(
      [&](const RecordedFrameView& f) {
        seen.emplace_back(f.data.begin(), f.data.end());
        return ecat::ok();
      },
      1ms));
  EXPECT_FALSE(recorder.start_streaming([](const RecordedFrameView&) { return ecat::ok(); }));
  std::thread producer([&] {
    for (int i = 0; i < 2000; ++i) {
      recorder.record(i % 2 ? FrameDirection::inbound : FrameDirection::outbound,
                      frame_of(20, static_cast<std::uint8_t>(i)), 0);
      if (i % 100 == 0) std::this_thread::sleep_for(1ms);
    }
  });
  producer.join();
  ASSERT_TRUE(recorder.stop_streaming());
  EXPECT_EQ(seen.size(), 2000u);
  EXPECT_EQ(recorder.stats().stream_dropped, 0u);
  EXPECT_EQ(recorder.stats().streamed, 2000u);
}

TEST(FrameRecorder, SlowSinkDropsAndCountsNeverBlocks) {
  FrameRecorder recorder({.window = 10s, .byte_budget = 64 << 10, .max_frame_bytes = 1514});
  std::atomic<std::uint64_t> seen{0};
  ASSERT_TRUE(recorder.start_streaming(
      [&](const RecordedFrameView&) {
        std::this_thread::sleep_for(1ms);
        seen.fetch_add(1);
        return ecat::ok();
      },
      1ms));
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 20000; ++i)
    recorder.record(FrameDirection::outbound, frame_of(200, static_cast<std::uint8_t>(i)), 0);
  EXPECT_LT(std::chrono::steady_clock::now() - start, 2s);  // never waited for the sink
  ASSERT_TRUE(recorder.stop_streaming());
  const auto stats = recorder.stats();
  EXPECT_GT(stats.stream_dropped, 0u);
  EXPECT_EQ(stats.streamed + stats.stream_dropped, 20000u);
  EXPECT_EQ(stats.streamed, seen.load());
}

TEST(FrameRecorder, SinkErrorEndsStreamingAndIsReported) {
  FrameRecorder recorder;
  ASSERT_TRUE(recorder.start_streaming(
      [](const RecordedFrameView&) {
        return ecat::Result<void>(ecat::Error(ecat::Errc::io_error, "disk full"));
      },
      1ms));
  recorder.record(FrameDirection::outbound, frame_of(8, 0), 0);
  auto stopped = recorder.stop_streaming();
  ASSERT_FALSE(stopped);
  EXPECT_EQ(stopped.error().code(), ecat::Errc::io_error);
}

}  // namespace
