// Recording on the cycle path allocates nothing: RecordingLink::send/receive over a memory link,
// counted with the counting allocator on this thread (after the recorder was built: its rings are
// allocated once, at construction), while a reader snapshots on another thread.
#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/link/recording_link.hpp>

#include "support/counting_allocator.hpp"

namespace {

namespace allocs = ecat::test::allocations;
using namespace std::chrono_literals;

TEST(RecordingLinkAlloc, SendAndReceiveDoNotAllocate) {
  auto [a, b] = ecat::link::make_memory_link_pair();
  auto recorder = std::make_shared<ecat::link::FrameRecorder>(
      ecat::link::FrameRecorderOptions{.window = 10s, .byte_budget = 64 << 10});
  ecat::link::RecordingLink link(std::move(a), recorder);
  std::vector<std::uint8_t> frame(60, 0x11);
  std::atomic<bool> stop{false};
  std::thread reader([&] {
    while (!stop.load())
      (void)recorder->snapshot(1s);
  });
  allocs::counted.store(0);
  allocs::count_this_thread = true;
  for (int i = 0; i < 5000; ++i) {  // far more than the 64 KiB ring holds: it wraps many times
    frame[2] = static_cast<std::uint8_t>(i);
    ASSERT_TRUE(link.send(frame));
    ASSERT_TRUE(b->send(frame));
    auto got = link.receive(0ns);
    ASSERT_TRUE(got && got->has_value());
    auto echo = b->receive(0ns);
    ASSERT_TRUE(echo && echo->has_value());
  }
  allocs::count_this_thread = false;
  stop.store(true);
  reader.join();
  EXPECT_EQ(allocs::counted.load(), 0u);
  EXPECT_EQ(recorder->stats().recorded, 10000u);
}

}  // namespace
