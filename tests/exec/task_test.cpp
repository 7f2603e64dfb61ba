// The control-thread machinery: event loop, coroutine tasks, and tasks awaiting bus transactions
// against a simulated segment (their datagrams must share frames).
#include <atomic>
#include <chrono>
#include <future>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/exec/transact.hpp>
#include <ecat/link/memory_link.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/segment.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::exec {
namespace {

using namespace std::chrono_literals;

TEST(EventLoop, RunsPostedWorkInOrderAndTimersWhenDue) {
  EventLoop loop;
  std::vector<int> order;
  loop.call_after(20ms, [&] { order.push_back(3); });
  loop.call_after(5ms, [&] { order.push_back(2); });
  loop.post([&] { order.push_back(1); });
  const auto cancelled = loop.call_after(1ms, [&] { order.push_back(99); });
  EXPECT_TRUE(loop.cancel(cancelled));
  EXPECT_FALSE(loop.cancel(cancelled));
  loop.call_after(30ms, [&] { loop.stop(); });
  loop.run();
  EXPECT_EQ(order, (std::vector<int>{1, 2, 3}));
}

TEST(EventLoop, PostFromOtherThreadsWakesTheLoop) {
  EventLoop loop;
  loop.start_thread("test-loop");
  std::promise<std::thread::id> ran_on;
  loop.post([&] { ran_on.set_value(std::this_thread::get_id()); });
  auto id = ran_on.get_future();
  ASSERT_EQ(id.wait_for(2s), std::future_status::ready);
  EXPECT_NE(id.get(), std::this_thread::get_id());
  loop.stop();
  loop.join();
}

Task<int> add_later(EventLoop& loop, int a, int b) {
  co_await sleep_for(loop, 1ms);
  co_return a + b;
}

Task<int> chain(EventLoop& loop, int depth) {
  if (depth == 0) co_return 0;
  const int below = co_await chain(loop, depth - 1);
  co_return below + 1;
}

TEST(Task, AwaitsValuesAndSleeps) {
  EventLoop loop;
  int result = 0;
  spawn(loop, add_later(loop, 2, 3), [&](int v) {
    result = v;
    loop.stop();
  });
  loop.run();
  EXPECT_EQ(result, 5);
}

TEST(Task, DeepSynchronousChainsDoNotGrowTheStack) {
  EventLoop loop;
  int result = 0;
  spawn(loop, chain(loop, 100'000), [&](int v) {
    result = v;
    loop.stop();
  });
  loop.run();
  EXPECT_EQ(result, 100'000);
}

TEST(Task, WhenAllKeepsOrderAndRunsConcurrently) {
  EventLoop loop;
  std::vector<int> result;
  const auto start = Clock::now();
  auto all = [&]() -> Task<void> {
    std::vector<Task<int>> tasks;
    for (int i = 0; i < 50; ++i)
      tasks.push_back(add_later(loop, i, 100));
    result = co_await when_all(loop, std::move(tasks));
    std::vector<Task<int>> none;
    auto empty = co_await when_all(loop, std::move(none));
    EXPECT_TRUE(empty.empty());
    std::vector<Task<int>> immediate;
    immediate.push_back(chain(loop, 3));
    auto ready = co_await when_all(loop, std::move(immediate));
    EXPECT_EQ(ready, (std::vector<int>{3}));
    loop.stop();
  };
  spawn(loop, all());
  loop.run();
  ASSERT_EQ(result.size(), 50u);
  for (int i = 0; i < 50; ++i)
    EXPECT_EQ(result[static_cast<std::size_t>(i)], i + 100);
  // 50 sleeps of 1 ms ran side by side, not one after the other.
  EXPECT_LT(Clock::now() - start, 45ms);
}

// A bus over a function link into a simulated segment of plain ESCs.
struct SimulatedBus {
  explicit SimulatedBus(std::size_t slaves) {
    for (std::size_t i = 0; i < slaves; ++i) {
      wire::SiiImage image;
      image.identity = {0xACE, static_cast<std::uint32_t>(i), 1, 0};
      auto eeprom = wire::encode_sii(image);
      EXPECT_TRUE(eeprom.ok());
      EXPECT_TRUE(segment
                      .add_slave("s" + std::to_string(i),
                                 std::make_unique<sim::Esc>(sim::EscHardware{}, *eeprom, nullptr))
                      .ok());
    }
    auto link = link::make_function_link([this](wire::Bytes request, link::ReplySink& replies) {
      std::vector<std::uint8_t> frame(request.begin(), request.end());
      const auto now = Clock::now().time_since_epoch().count();
      if (segment.process_frame(frame, now)) replies.reply(frame);
    });
    bus = std::make_unique<bus::Bus>(std::move(link), bus::BusOptions{});
    EXPECT_TRUE(bus->start().ok());
  }
  ~SimulatedBus() { bus->stop(); }
  sim::Segment segment;
  std::unique_ptr<bus::Bus> bus;
};

Task<Result<std::uint16_t>> assign_and_read_back(EventLoop& loop, bus::Bus& bus,
                                                 std::uint16_t position) {
  const auto station = static_cast<std::uint16_t>(0x1000 + position);
  bus::Transaction assign;
  std::uint8_t bytes[2] = {static_cast<std::uint8_t>(station),
                           static_cast<std::uint8_t>(station >> 8)};
  assign.apwr(position, wire::reg::kStationAddress, wire::Bytes(bytes, 2), 1);
  auto assigned = co_await transact(loop, bus, std::move(assign));
  if (!assigned) co_return assigned.error();
  bus::Transaction read;
  read.fprd(station, wire::reg::kStationAddress, 2, 1);
  auto reply = co_await transact(loop, bus, std::move(read));
  if (!reply) co_return reply.error();
  co_return wire::load_le16(reply->data(0).data());
}

TEST(Transact, ConcurrentTasksShareFrames) {
  constexpr std::size_t kSlaves = 64;
  SimulatedBus sim(kSlaves);
  EventLoop loop;
  loop.start_thread();
  std::promise<std::vector<Result<std::uint16_t>>> done;
  auto all = [&]() -> Task<void> {
    std::vector<Task<Result<std::uint16_t>>> tasks;
    for (std::size_t i = 0; i < kSlaves; ++i) {
      tasks.push_back(assign_and_read_back(loop, *sim.bus, static_cast<std::uint16_t>(i)));
    }
    done.set_value(co_await when_all(loop, std::move(tasks)));
  };
  spawn(loop, all());
  auto future = done.get_future();
  ASSERT_EQ(future.wait_for(10s), std::future_status::ready);
  auto results = future.get();
  for (std::size_t i = 0; i < kSlaves; ++i) {
    ASSERT_TRUE(results[i].ok()) << results[i].error().describe();
    EXPECT_EQ(*results[i], 0x1000 + i);
    EXPECT_EQ(sim.segment.esc(i).station_address(), 0x1000 + i);
  }
  // 128 transactions, but tasks that run side by side have their datagrams packed together.
  EXPECT_LT(sim.bus->stats().frames_sent, 40u);
  loop.stop();
  loop.join();
}

TEST(Transact, ErrorsReachTheTask) {
  SimulatedBus sim(1);
  EventLoop loop;
  std::optional<Result<bus::TransactionResult>> outcome;
  auto task = [&]() -> Task<void> {
    bus::Transaction tx;
    tx.fprd(0x4242, wire::reg::kAlStatus, 2, 1);  // no such station: WKC 0, expected 1
    outcome.emplace(co_await transact(loop, *sim.bus, std::move(tx), {100ms, 0}));
    loop.stop();
  };
  spawn(loop, task());
  loop.run();
  ASSERT_TRUE(outcome.has_value());
  ASSERT_FALSE(outcome->ok());
  EXPECT_EQ(outcome->error().code(), Errc::wkc_mismatch);
}

}  // namespace
}  // namespace ecat::exec
