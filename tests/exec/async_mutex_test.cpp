// The coroutine mutex: exclusion across suspension points, FIFO hand-over, resumption through the
// loop (never inline from unlock), try_lock, and guards that move and unlock early.
#include <chrono>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/exec/async_mutex.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>

namespace ecat::exec {
namespace {

using namespace std::chrono_literals;

Task<int> critical(EventLoop& loop, AsyncMutex& mutex, std::vector<std::string>& log, int id,
                   int& inside, int& max_inside) {
  auto guard = co_await mutex.lock();
  ++inside;
  max_inside = std::max(max_inside, inside);
  log.push_back("enter " + std::to_string(id));
  co_await sleep_for(loop, 1ms);  // other tasks run meanwhile, but must not get in
  log.push_back("leave " + std::to_string(id));
  --inside;
  co_return id;
}

TEST(AsyncMutex, ExcludesAcrossSuspensionAndHandsOverInFifoOrder) {
  EventLoop loop;
  AsyncMutex mutex(loop);
  std::vector<std::string> log;
  int inside = 0;
  int max_inside = 0;
  std::vector<int> results;
  auto all = [&]() -> Task<void> {
    std::vector<Task<int>> tasks;
    for (int i = 0; i < 5; ++i)
      tasks.push_back(critical(loop, mutex, log, i, inside, max_inside));
    results = co_await when_all(loop, std::move(tasks));
    loop.stop();
  };
  spawn(loop, all());
  loop.run();
  EXPECT_EQ(max_inside, 1);
  EXPECT_EQ(results, (std::vector<int>{0, 1, 2, 3, 4}));
  EXPECT_EQ(log, (std::vector<std::string>{"enter 0", "leave 0", "enter 1", "leave 1", "enter 2",
                                           "leave 2", "enter 3", "leave 3", "enter 4", "leave 4"}));
  EXPECT_FALSE(mutex.locked());
  EXPECT_EQ(mutex.waiters(), 0u);
}

TEST(AsyncMutex, UnlockResumesTheWaiterThroughTheLoopNotInline) {
  EventLoop loop;
  AsyncMutex mutex(loop);
  std::vector<std::string> log;
  auto first = mutex.try_lock();
  ASSERT_TRUE(first.has_value());
  EXPECT_FALSE(mutex.try_lock().has_value());
  auto waiter = [&]() -> Task<void> {
    auto guard = co_await mutex.lock();
    log.push_back("waiter got it");
  };
  spawn(loop, waiter());
  loop.post([&] {
    EXPECT_EQ(mutex.waiters(), 1u);
    first->unlock();
    log.push_back("unlocked");    // before the waiter runs: it was posted, not resumed here
    EXPECT_TRUE(mutex.locked());  // already handed over: nobody can barge in
    EXPECT_FALSE(mutex.try_lock().has_value());
  });
  loop.call_after(5ms, [&] { loop.stop(); });
  loop.run();
  EXPECT_EQ(log, (std::vector<std::string>{"unlocked", "waiter got it"}));
  EXPECT_FALSE(mutex.locked());
}

TEST(AsyncMutex, GuardsMoveAndUnlockOnce) {
  EventLoop loop;
  AsyncMutex mutex(loop);
  auto guard = mutex.try_lock();
  ASSERT_TRUE(guard);
  EXPECT_TRUE(guard->owns(mutex));
  AsyncMutex::Guard moved = std::move(*guard);
  EXPECT_FALSE(static_cast<bool>(*guard));
  EXPECT_TRUE(moved.owns(mutex));
  EXPECT_TRUE(mutex.locked());
  moved.unlock();
  EXPECT_FALSE(mutex.locked());
  moved.unlock();  // a second unlock does nothing
  EXPECT_FALSE(mutex.locked());
  {
    auto scoped = mutex.try_lock();
    EXPECT_TRUE(mutex.locked());
  }
  EXPECT_FALSE(mutex.locked());
}

TEST(AsyncMutex, LongWaiterChainsDoNotGrowTheStack) {
  EventLoop loop;
  AsyncMutex mutex(loop);
  int done = 0;
  auto holder = mutex.try_lock();
  auto one = [&]() -> Task<void> {
    auto guard = co_await mutex.lock();
    ++done;
  };
  for (int i = 0; i < 20'000; ++i)
    spawn(loop, one());
  loop.post([&] { holder->unlock(); });
  loop.call_after(2s, [&] { loop.stop(); });
  auto check = [&]() -> Task<void> {
    while (done < 20'000)
      co_await sleep_for(loop, 1ms);
    loop.stop();
  };
  spawn(loop, check());
  loop.run();
  EXPECT_EQ(done, 20'000);
  EXPECT_FALSE(mutex.locked());
}

}  // namespace
}  // namespace ecat::exec
