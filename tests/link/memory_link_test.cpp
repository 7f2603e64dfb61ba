#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <new>
#include <stdexcept>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <poll.h>

#include <ecat/link/memory_link.hpp>
#include <ecat/wire/frame.hpp>

#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::link {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

std::vector<std::uint8_t> frame_with(std::uint32_t seq, std::size_t size = 16) {
  std::vector<std::uint8_t> f(size);
  for (std::size_t i = 0; i < size; ++i)
    f[i] = static_cast<std::uint8_t>(seq + i * 7);
  if (size >= 4) wire::store_le32(f.data(), seq);
  return f;
}

std::vector<std::uint8_t> to_vector(wire::Bytes b) {
  return {b.begin(), b.end()};
}

std::vector<std::uint8_t> receive_now(Link& link) {
  auto r = link.receive(0ns);
  EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().describe());
  if (!r.ok() || !r->has_value()) return {};
  return to_vector((*r)->frame);
}

TEST(MemoryLinkTest, RoundTripBothWays) {
  auto [a, b] = make_memory_link_pair();
  EXPECT_EQ(a->name(), "memory:a");
  EXPECT_EQ(b->name(), "memory:b");
  const auto request = frame_with(1, 40);
  ASSERT_TRUE(a->send(request).ok());
  auto got = b->receive(100ms);
  ASSERT_TRUE(got.ok());
  ASSERT_TRUE(got->has_value());
  EXPECT_EQ(to_vector((*got)->frame), request);
  EXPECT_EQ((*got)->source, wire::MacAddress{});

  const auto reply = frame_with(2, 1500);
  ASSERT_TRUE(b->send(reply).ok());
  EXPECT_EQ(receive_now(*a), reply);

  EXPECT_EQ(a->stats().frames_sent, 1u);
  EXPECT_EQ(a->stats().bytes_sent, 40u);
  EXPECT_EQ(a->stats().frames_received, 1u);
  EXPECT_EQ(a->stats().bytes_received, 1500u);
  EXPECT_EQ(b->stats().frames_sent, 1u);
  EXPECT_EQ(b->stats().frames_received, 1u);
  EXPECT_EQ(b->stats().bytes_received, 40u);
}

// Whether poll() finds `fd` readable now.
bool readable(int fd) {
  pollfd p{fd, POLLIN, 0};
  return ::poll(&p, 1, 0) == 1 && (p.revents & POLLIN) != 0;
}

// Link::wait_fd: readable while a frame waits (also one queued before it was asked for), quiet
// once a receive found nothing; an interrupt and a close of the peer make it readable too.
TEST(MemoryLinkTest, WaitFdIsReadableWhileAFrameWaits) {
  auto [a, b] = make_memory_link_pair();
  ASSERT_TRUE(a->send(frame_with(1)).ok());
  const int fd = b->wait_fd();
  ASSERT_GE(fd, 0);
  EXPECT_EQ(b->wait_fd(), fd);
  EXPECT_TRUE(readable(fd));
  EXPECT_EQ(receive_now(*b), frame_with(1));
  EXPECT_TRUE(receive_now(*b).empty());
  EXPECT_FALSE(readable(fd));
  ASSERT_TRUE(a->send(frame_with(2)).ok());
  ASSERT_TRUE(a->send(frame_with(3)).ok());
  EXPECT_TRUE(readable(fd));
  EXPECT_EQ(receive_now(*b), frame_with(2));
  EXPECT_EQ(receive_now(*b), frame_with(3));
  EXPECT_TRUE(receive_now(*b).empty());
  EXPECT_FALSE(readable(fd));
  b->interrupt();
  EXPECT_TRUE(readable(fd));
  EXPECT_TRUE(receive_now(*b).empty());
  EXPECT_FALSE(readable(fd));
  a->close();
  EXPECT_TRUE(readable(fd));
  b->close();
  EXPECT_EQ(b->wait_fd(), -1);
}

TEST(FunctionLinkTest, WaitFdIsReadableWhileRepliesWait) {
  auto link = make_function_link(
      [](wire::Bytes request, ReplySink& replies) { EXPECT_TRUE(replies.reply(request)); });
  const int fd = link->wait_fd();
  ASSERT_GE(fd, 0);
  EXPECT_FALSE(readable(fd));
  ASSERT_TRUE(link->send(frame_with(7)).ok());
  EXPECT_TRUE(readable(fd));
  EXPECT_EQ(receive_now(*link), frame_with(7));
  EXPECT_TRUE(receive_now(*link).empty());
  EXPECT_FALSE(readable(fd));
}

TEST(MemoryLinkTest, EmptyFrameIsDeliveredAsEmpty) {
  auto [a, b] = make_memory_link_pair();
  ASSERT_TRUE(a->send({}).ok());
  auto got = b->receive(0ns);
  ASSERT_TRUE(got.ok());
  ASSERT_TRUE(got->has_value());
  EXPECT_EQ((*got)->frame.size(), 0u);
}

TEST(MemoryLinkTest, KeepsOrder) {
  auto [a, b] = make_memory_link_pair(64);
  for (std::uint32_t i = 0; i < 64; ++i)
    ASSERT_TRUE(a->send(frame_with(i, 8 + i)).ok());
  for (std::uint32_t i = 0; i < 64; ++i)
    EXPECT_EQ(receive_now(*b), frame_with(i, 8 + i)) << i;
  EXPECT_TRUE(receive_now(*b).empty());
  // The ring wraps: a second round through the same slots keeps the order too.
  for (std::uint32_t i = 100; i < 140; ++i)
    ASSERT_TRUE(a->send(frame_with(i)).ok());
  for (std::uint32_t i = 100; i < 140; ++i)
    EXPECT_EQ(receive_now(*b), frame_with(i)) << i;
}

TEST(MemoryLinkTest, FullQueueDropsAndCounts) {
  auto [a, b] = make_memory_link_pair(4);
  for (std::uint32_t i = 0; i < 7; ++i)
    ASSERT_TRUE(a->send(frame_with(i)).ok());
  EXPECT_EQ(a->stats().frames_sent, 4u);
  EXPECT_EQ(a->stats().frames_dropped, 3u);
  EXPECT_EQ(b->stats().frames_dropped, 0u);
  for (std::uint32_t i = 0; i < 4; ++i)
    EXPECT_EQ(receive_now(*b), frame_with(i));
  auto none = b->receive(1ms);
  ASSERT_TRUE(none.ok());
  EXPECT_FALSE(none->has_value());
  // Room again after draining.
  ASSERT_TRUE(a->send(frame_with(9)).ok());
  EXPECT_EQ(receive_now(*b), frame_with(9));
  EXPECT_EQ(a->stats().frames_dropped, 3u);
}

TEST(MemoryLinkTest, RejectsOversizedFrame) {
  auto [a, b] = make_memory_link_pair();
  std::vector<std::uint8_t> big(wire::kMaxFrameSize + 1);
  auto r = a->send(big);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::invalid_argument);
  EXPECT_EQ(r.error().message(), "memory:a: frame of 1501 bytes exceeds the 1500-byte maximum");
  EXPECT_EQ(a->stats().frames_sent, 0u);
  EXPECT_EQ(a->max_frame_size(), wire::kMaxFrameSize);
}

TEST(MemoryLinkTest, ReceiveTimesOut) {
  auto [a, b] = make_memory_link_pair();
  auto start = Clock::now();
  auto r = b->receive(30ms);
  const auto elapsed = Clock::now() - start;
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_GE(elapsed, 30ms);
  EXPECT_LT(elapsed, 2s);

  start = Clock::now();
  r = b->receive(0ns);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 50ms);

  r = b->receive(-5ms);  // negative: a poll, not an error
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(MemoryLinkTest, TimestampIsWhenTheFrameWasSent) {
  auto [a, b] = make_memory_link_pair();
  const auto before = Clock::now().time_since_epoch();
  ASSERT_TRUE(a->send(frame_with(1)).ok());
  const auto after = Clock::now().time_since_epoch();
  auto r = b->receive(0ns);
  ASSERT_TRUE(r.ok() && r->has_value());
  EXPECT_GE((*r)->timestamp_ns, std::chrono::nanoseconds(before).count());
  EXPECT_LE((*r)->timestamp_ns, std::chrono::nanoseconds(after).count());
}

TEST(MemoryLinkTest, InterruptWakesBlockedReceivePromptly) {
  auto [a, b] = make_memory_link_pair();
  std::atomic<bool> returned{false};
  Clock::time_point woke;
  bool had_value = true;
  bool ok = false;
  std::thread receiver([&, link = b.get()] {
    auto r = link->receive(10s);
    woke = Clock::now();
    ok = r.ok();
    had_value = ok && r->has_value();
    returned = true;
  });
  std::this_thread::sleep_for(30ms);
  EXPECT_FALSE(returned.load());
  const auto interrupted = Clock::now();
  b->interrupt();
  receiver.join();
  EXPECT_TRUE(ok);
  EXPECT_FALSE(had_value);
  EXPECT_LT(woke - interrupted, 200ms);
}

// An interrupt never hides a frame that has arrived: the frame comes first, then the interrupt
// wakes the next receive, once.
TEST(MemoryLinkTest, InterruptBeforeReceiveWakesTheNextOneOnly) {
  auto [a, b] = make_memory_link_pair();
  ASSERT_TRUE(a->send(frame_with(5)).ok());
  b->interrupt();
  EXPECT_EQ(receive_now(*b), frame_with(5));
  const auto start = Clock::now();
  auto r = b->receive(1s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 500ms) << "the pending interrupt did not end the wait";
  r = b->receive(20ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(MemoryLinkTest, WaitingReceiverWakesQuicklyOnSend) {
  auto [a, b] = make_memory_link_pair();
  std::vector<std::int64_t> latencies;
  for (int i = 0; i < 50; ++i) {
    std::int64_t sent_at = 0;
    std::thread sender([&, link = a.get()] {
      std::this_thread::sleep_for(2ms);
      sent_at = std::chrono::nanoseconds(Clock::now().time_since_epoch()).count();
      ASSERT_TRUE(link->send(frame_with(static_cast<std::uint32_t>(i))).ok());
    });
    auto r = b->receive(5s);
    const auto now = std::chrono::nanoseconds(Clock::now().time_since_epoch()).count();
    sender.join();
    ASSERT_TRUE(r.ok() && r->has_value());
    latencies.push_back(now - sent_at);
  }
  std::sort(latencies.begin(), latencies.end());
  // A futex wake takes microseconds; a sleep-polling receiver would show milliseconds.
  EXPECT_LT(latencies[latencies.size() / 2], 1'000'000) << "median wake-up latency in ns";
}

TEST(MemoryLinkTest, CloseDrainsThenReportsClosedToPeer) {
  auto [a, b] = make_memory_link_pair();
  ASSERT_TRUE(a->send(frame_with(1)).ok());
  ASSERT_TRUE(a->send(frame_with(2)).ok());
  a->close();
  EXPECT_EQ(receive_now(*b), frame_with(1));
  EXPECT_EQ(receive_now(*b), frame_with(2));
  auto r = b->receive(1s);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::closed);
  EXPECT_EQ(r.error().message(), "memory:b: the peer memory:a closed");

  auto sent = b->send(frame_with(3));
  ASSERT_FALSE(sent.ok());
  EXPECT_EQ(sent.error().code(), Errc::closed);
  EXPECT_EQ(sent.error().message(), "memory:b: the peer memory:a is closed");

  auto own_send = a->send(frame_with(4));
  ASSERT_FALSE(own_send.ok());
  EXPECT_EQ(own_send.error().code(), Errc::closed);
  EXPECT_EQ(own_send.error().message(), "memory:a: link is closed");
  auto own_receive = a->receive(0ns);
  ASSERT_FALSE(own_receive.ok());
  EXPECT_EQ(own_receive.error().code(), Errc::closed);
  a->close();  // twice is harmless
}

TEST(MemoryLinkTest, CloseWakesBlockedPeerAndOwnReceiver) {
  auto [a, b] = make_memory_link_pair();
  Errc peer_code{};
  Errc own_code{};
  std::thread peer([&, link = b.get()] {
    auto r = link->receive(10s);
    peer_code = r.ok() ? Errc::internal : r.error().code();
  });
  std::thread own([&, link = a.get()] {
    auto r = link->receive(10s);
    own_code = r.ok() ? Errc::internal : r.error().code();
  });
  std::this_thread::sleep_for(20ms);
  const auto start = Clock::now();
  a->close();
  peer.join();
  own.join();
  EXPECT_LT(Clock::now() - start, 1s);
  EXPECT_EQ(peer_code, Errc::closed);
  EXPECT_EQ(own_code, Errc::closed);
}

TEST(MemoryLinkTest, DestroyingAnEndClosesIt) {
  auto [a, b] = make_memory_link_pair();
  ASSERT_TRUE(a->send(frame_with(1)).ok());
  a.reset();
  EXPECT_EQ(receive_now(*b), frame_with(1));
  auto r = b->receive(0ns);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.error().code(), Errc::closed);
}

int* volatile g_escape = nullptr;

// The allocation tests below would pass vacuously if the replaced operator new were not the one
// in use (a sanitizer runtime could interpose its own).
TEST(MemoryLinkTest, AllocationCounterSeesAllocations) {
  const auto before = allocs::total.load();
  g_escape = new int(5);
  delete g_escape;
  g_escape = nullptr;
  EXPECT_EQ(allocs::total.load() - before, 1u);
}

TEST(MemoryLinkTest, SteadyStateSendAndReceiveDoNotAllocate) {
  // Clang 14 cannot capture structured bindings in a lambda.
  auto links = make_memory_link_pair(8);
  Link& a = *links.first;
  Link& b = *links.second;
  std::array<std::uint8_t, 64> request{};
  std::array<std::uint8_t, 64> reply{};
  for (std::size_t i = 0; i < request.size(); ++i)
    request[i] = static_cast<std::uint8_t>(i);
  std::uint64_t received = 0;
  std::uint64_t bad_results = 0;
  auto round = [&] {
    bad_results += a.send(request).ok() ? 0 : 1;
    auto r1 = b.receive(0ns);
    if (r1.ok() && r1->has_value()) {
      std::copy((*r1)->frame.begin(), (*r1)->frame.end(), reply.begin());
      ++reply[0];
      bad_results += b.send(reply).ok() ? 0 : 1;
    } else {
      ++bad_results;
    }
    auto r2 = a.receive(1ms);
    if (r2.ok() && r2->has_value()) {
      ++received;
    } else {
      ++bad_results;
    }
    auto r3 = a.receive(0ns);  // a timed-out poll allocates nothing either
    bad_results += (r3.ok() && !r3->has_value()) ? 0 : 1;
    a.interrupt();
    auto r4 = a.receive(1ms);
    bad_results += (r4.ok() && !r4->has_value()) ? 0 : 1;
  };
  for (int i = 0; i < 10; ++i)
    round();  // warm-up
  const auto before = allocs::total.load();
  for (int i = 0; i < 1000; ++i)
    round();
  const auto allocations = allocs::total.load() - before;
  EXPECT_EQ(allocations, 0u);
  EXPECT_EQ(bad_results, 0u);
  EXPECT_EQ(received, 1010u);
  (void)a.stats();
}

TEST(MemoryLinkTest, TwoThreadPingPong100k) {
  constexpr std::uint32_t kFrames = 100'000;
  auto [a, b] = make_memory_link_pair(4);
  std::atomic<std::uint64_t> echo_errors{0};
  std::thread echo([&, link = b.get()] {
    std::array<std::uint8_t, 32> out{};
    for (std::uint32_t i = 0; i < kFrames; ++i) {
      auto r = link->receive(5s);
      if (!r.ok() || !r->has_value() || (*r)->frame.size() != out.size()) {
        ++echo_errors;
        return;
      }
      std::copy((*r)->frame.begin(), (*r)->frame.end(), out.begin());
      wire::store_le32(out.data() + 4, wire::load_le32(out.data()) * 3u + 1u);
      if (!link->send(out).ok()) ++echo_errors;
    }
  });
  std::array<std::uint8_t, 32> request{};
  std::uint32_t mismatches = 0;
  std::uint32_t timeouts = 0;
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    wire::store_le32(request.data(), i);
    ASSERT_TRUE(a->send(request).ok());
    auto r = a->receive(5s);
    ASSERT_TRUE(r.ok());
    if (!r->has_value()) {
      ++timeouts;
      break;
    }
    const auto& f = (*r)->frame;
    if (f.size() != 32 || wire::load_le32(f.data()) != i ||
        wire::load_le32(f.data() + 4) != i * 3u + 1u) {
      ++mismatches;
    }
  }
  echo.join();
  EXPECT_EQ(timeouts, 0u);
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(echo_errors.load(), 0u);
  EXPECT_EQ(a->stats().frames_sent, kFrames);
  EXPECT_EQ(a->stats().frames_received, kFrames);
  EXPECT_EQ(b->stats().frames_dropped, 0u);
}

// ---- function link

TEST(FunctionLinkTest, HandlerRepliesAreReceivedInOrder) {
  std::vector<std::vector<std::uint8_t>> requests;
  auto link = make_function_link([&](wire::Bytes request, ReplySink& replies) {
    requests.push_back(to_vector(request));
    std::vector<std::uint8_t> reply = to_vector(request);
    reply[0] ^= 0xFF;
    EXPECT_TRUE(replies.reply(reply));
    reply[0] = 0x55;
    EXPECT_TRUE(replies.reply(reply));
  });
  EXPECT_EQ(link->name(), "function");
  const auto f = frame_with(0x10203040, 20);
  ASSERT_TRUE(link->send(f).ok());
  ASSERT_EQ(requests.size(), 1u);
  EXPECT_EQ(requests[0], f);
  auto first = f;
  first[0] ^= 0xFF;
  auto second = f;
  second[0] = 0x55;
  EXPECT_EQ(receive_now(*link), first);
  EXPECT_EQ(receive_now(*link), second);
  // Nothing else can come: an empty queue returns at once, without waiting out the timeout.
  const auto start = Clock::now();
  auto r = link->receive(5s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
  EXPECT_LT(Clock::now() - start, 1s);
  EXPECT_EQ(link->stats().frames_sent, 1u);
  EXPECT_EQ(link->stats().frames_received, 2u);
}

TEST(FunctionLinkTest, FullReplyQueueDropsAndCounts) {
  FunctionLinkOptions options;
  options.name = "sim";
  options.reply_queue_depth = 2;
  std::vector<bool> accepted;
  auto link = make_function_link(
      [&](wire::Bytes request, ReplySink& replies) {
        for (int i = 0; i < 3; ++i)
          accepted.push_back(replies.reply(request));
        std::vector<std::uint8_t> huge(wire::kMaxFrameSize + 1);
        accepted.push_back(replies.reply(huge));
      },
      options);
  EXPECT_EQ(link->name(), "sim");
  ASSERT_TRUE(link->send(frame_with(1)).ok());
  EXPECT_EQ(accepted, (std::vector<bool>{true, true, false, false}));
  EXPECT_EQ(link->stats().frames_dropped, 2u);
  EXPECT_EQ(receive_now(*link), frame_with(1));
  EXPECT_EQ(receive_now(*link), frame_with(1));
  EXPECT_TRUE(receive_now(*link).empty());
}

TEST(FunctionLinkTest, SilentHandlerLooksLikeALostFrame) {
  auto link = make_function_link([](wire::Bytes, ReplySink&) {});
  ASSERT_TRUE(link->send(frame_with(1)).ok());
  auto r = link->receive(10ms);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(FunctionLinkTest, InterruptCloseAndErrors) {
  auto link = make_function_link([](wire::Bytes request, ReplySink& replies) {
    if (!request.empty() && request[0] == 0xEE) throw std::runtime_error("boom");
    replies.reply(request);
  });
  ASSERT_TRUE(link->send(frame_with(1)).ok());
  link->interrupt();
  EXPECT_EQ(receive_now(*link), frame_with(1));  // the reply before the interrupt
  auto r = link->receive(1s);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());

  std::vector<std::uint8_t> bad{0xEE, 0, 0, 0};
  auto thrown = link->send(bad);
  ASSERT_FALSE(thrown.ok());
  EXPECT_EQ(thrown.error().code(), Errc::internal);
  EXPECT_EQ(thrown.error().message(), "function: the frame handler threw: boom");

  std::vector<std::uint8_t> big(wire::kMaxFrameSize + 1);
  auto too_big = link->send(big);
  ASSERT_FALSE(too_big.ok());
  EXPECT_EQ(too_big.error().code(), Errc::invalid_argument);

  ASSERT_TRUE(link->send(frame_with(2)).ok());
  link->close();
  auto after = link->receive(0ns);
  ASSERT_FALSE(after.ok());
  EXPECT_EQ(after.error().code(), Errc::closed);
  auto send_after = link->send(frame_with(3));
  ASSERT_FALSE(send_after.ok());
  EXPECT_EQ(send_after.error().code(), Errc::closed);
}

TEST(FunctionLinkTest, SteadyStateDoesNotAllocate) {
  auto link = make_function_link([](wire::Bytes request, ReplySink& replies) {
    std::array<std::uint8_t, 64> reply{};
    std::copy(request.begin(), request.end(), reply.begin());
    reply[1] = 0x77;
    replies.reply(wire::Bytes(reply.data(), request.size()));
  });
  std::array<std::uint8_t, 60> request{};
  std::uint64_t good = 0;
  auto round = [&] {
    if (!link->send(request).ok()) return;
    auto r = link->receive(1ms);
    if (r.ok() && r->has_value() && (*r)->frame.size() == 60 && (*r)->frame[1] == 0x77) ++good;
  };
  for (int i = 0; i < 10; ++i)
    round();
  const auto before = allocs::total.load();
  for (int i = 0; i < 1000; ++i)
    round();
  EXPECT_EQ(allocs::total.load() - before, 0u);
  EXPECT_EQ(good, 1010u);
}

}  // namespace
}  // namespace ecat::link
