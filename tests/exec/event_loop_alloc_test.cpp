// EventLoop::post(Work&): the allocation-free, lock-free way in (the bus thread completes
// co_awaited transactions through it). It keeps posting order with post(std::function), runs on
// the loop thread, allocates nothing on the posting thread, and a loop destroyed with work still
// queued hands every node back (run == false) instead of running or leaking it.
#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/exec/event_loop.hpp>

#include "support/counting_allocator.hpp"

namespace allocs = ecat::test::allocations;

namespace ecat::exec {
namespace {

using namespace std::chrono_literals;

struct Node final : EventLoop::Work {
  Node() noexcept : Work(&invoke) {}
  static void invoke(Work& self, bool run) {
    auto& node = static_cast<Node&>(self);
    if (run) {
      node.ran_on = std::this_thread::get_id();
      if (node.order != nullptr) node.order->push_back(node.id);
      node.runs.fetch_add(1);
    } else {
      node.discarded.fetch_add(1);
    }
  }
  int id = 0;
  std::vector<int>* order = nullptr;
  std::thread::id ran_on{};
  std::atomic<int> runs{0};
  std::atomic<int> discarded{0};
};

TEST(EventLoopWork, KeepsPostingOrderWithFunctions) {
  EventLoop loop;
  std::vector<int> order;
  Node two, four;
  two.id = 2;
  two.order = &order;
  four.id = 4;
  four.order = &order;
  loop.post([&] { order.push_back(1); });
  loop.post(two);
  loop.post([&] { order.push_back(3); });
  loop.post(four);
  loop.post([&] { loop.stop(); });
  loop.run();
  EXPECT_EQ(order, (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(two.runs.load(), 1);
  EXPECT_EQ(four.runs.load(), 1);
}

TEST(EventLoopWork, PostingFromAnotherThreadAllocatesNothingAndWakesTheLoop) {
  EventLoop loop;
  loop.start_thread("test-loop");
  constexpr int kNodes = 200;
  std::vector<Node> nodes(kNodes);
  std::thread poster([&] {
    allocs::count_this_thread = true;
    for (auto& n : nodes) {
      loop.post(n);
      std::this_thread::sleep_for(100us);  // the loop falls asleep between posts: wakes too
    }
    allocs::count_this_thread = false;
  });
  poster.join();
  const auto until = std::chrono::steady_clock::now() + 5s;
  auto all_ran = [&] {
    for (const auto& n : nodes)
      if (n.runs.load() != 1) return false;
    return true;
  };
  while (!all_ran() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(1ms);
  EXPECT_TRUE(all_ran());
  EXPECT_EQ(allocs::counted.load(), 0u) << "post(Work&) allocated on the posting thread";
  EXPECT_NE(nodes[0].ran_on, std::this_thread::get_id());
  EXPECT_NE(nodes[0].ran_on, std::thread::id{});
  loop.stop();
  loop.join();
}

TEST(EventLoopWork, DestroyedLoopDiscardsWhatItDidNotRun) {
  Node queued;
  std::atomic<bool> function_ran{false};
  {
    EventLoop loop;  // never run
    loop.post(queued);
    loop.post([&] { function_ran = true; });
    EXPECT_EQ(loop.pending(), 2u);
  }
  EXPECT_EQ(queued.runs.load(), 0);
  EXPECT_EQ(queued.discarded.load(), 1);
  EXPECT_FALSE(function_ran.load());
}

TEST(EventLoopWork, StopLeavesTheRestForTheNextRun) {
  EventLoop loop;
  std::vector<int> order;
  Node one, three;
  one.id = 1;
  one.order = &order;
  three.id = 3;
  three.order = &order;
  loop.post(one);
  loop.post([&] {
    order.push_back(2);
    loop.stop();
  });
  loop.post(three);
  loop.run();
  EXPECT_EQ(order, (std::vector<int>{1, 2}));
  loop.reset();
  loop.post([&] { loop.stop(); });
  loop.run();
  EXPECT_EQ(order, (std::vector<int>{1, 2, 3}));
}

}  // namespace
}  // namespace ecat::exec
