// Bus costs over the in-process fake segment (tests/bus/fake_segment.hpp): what the bus itself
// adds per exchange, without a network. Figures only; nothing here asserts a timing.
//
//   BM_TransactSingleDatagram   blocking transact() of one FPRD, caller thread <-> bus thread
//   BM_TransactTenDatagrams     one transaction of 10 FPRDs (one frame)
//   BM_SubmitTenTransactions    10 one-datagram transactions submitted together, then awaited
//   BM_RealtimeLrwCycle         submit_realtime() + wait() of a 64-byte LRW
//   BM_PackingRatio             frames per transaction when 1000 small transactions queue up
//                               behind a 200 us reply delay (counter frames_per_transaction)

#include <array>
#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>

#include <benchmark/benchmark.h>

#include <ecat/bus/bus.hpp>

#include "../tests/bus/fake_segment.hpp"
#include "benchmark_main.hpp"

namespace {

using namespace std::chrono_literals;
using ecat::bus::Bus;
using ecat::bus::BusOptions;
using ecat::bus::RealtimeStatus;
using ecat::bus::RealtimeTransaction;
using ecat::bus::Transaction;
using ecat::bus::TransactionResult;
using ecat::bus::test::FakeSegment;

struct Rig {
  std::shared_ptr<FakeSegment> segment;
  std::unique_ptr<Bus> bus;

  explicit Rig(std::chrono::nanoseconds reply_delay = 0ns) {
    FakeSegment::Options options;
    options.record = false;
    options.reply_delay = reply_delay;
    segment = std::make_shared<FakeSegment>(options);
    segment->map_logical(0, {0x00010000, 0x1000, 32, false, true});
    segment->map_logical(1, {0x00010020, 0x1100, 32, true, false});
    bus = std::make_unique<Bus>(FakeSegment::make_link(segment), BusOptions{});
    if (!bus->start()) std::abort();
  }
};

// Waits for a known number of submit() completions.
struct Latch {
  std::mutex mutex;
  std::condition_variable cv;
  std::size_t done = 0;
  std::size_t failed = 0;
  void arrive(bool ok) {
    std::lock_guard lock(mutex);
    ++done;
    if (!ok) ++failed;
    cv.notify_all();
  }
  void wait(std::size_t count) {
    std::unique_lock lock(mutex);
    cv.wait(lock, [&] { return done >= count; });
  }
};

void BM_TransactSingleDatagram(benchmark::State& state) {
  Rig rig;
  for (auto _ : state) {
    Transaction tx;
    tx.fprd(0x1001, 0x0130, 2, 1);
    auto result = rig.bus->transact(std::move(tx));
    if (!result) state.SkipWithError(result.error().describe().c_str());
    benchmark::DoNotOptimize(result);
  }
  state.counters["frames"] = static_cast<double>(rig.bus->stats().frames_sent);
}
BENCHMARK(BM_TransactSingleDatagram)->UseRealTime();

void BM_TransactTenDatagrams(benchmark::State& state) {
  Rig rig;
  for (auto _ : state) {
    Transaction tx;
    for (std::uint16_t i = 0; i < 10; ++i)
      tx.fprd(0x1001 + i % 3, 0x1000 + 8 * i, 8, 1);
    auto result = rig.bus->transact(std::move(tx));
    if (!result) state.SkipWithError(result.error().describe().c_str());
    benchmark::DoNotOptimize(result);
  }
  const auto stats = rig.bus->stats();
  state.counters["datagrams_per_frame"] =
      static_cast<double>(stats.datagrams_sent) / static_cast<double>(stats.frames_sent);
}
BENCHMARK(BM_TransactTenDatagrams)->UseRealTime();

void BM_SubmitTenTransactions(benchmark::State& state) {
  Rig rig;
  for (auto _ : state) {
    Latch latch;
    for (std::uint16_t i = 0; i < 10; ++i) {
      Transaction tx;
      tx.fprd(0x1001 + i % 3, 0x1000 + 8 * i, 8, 1);
      auto submitted = rig.bus->submit(
          std::move(tx), [&latch](ecat::Result<TransactionResult> r) { latch.arrive(r.ok()); });
      if (!submitted) state.SkipWithError(submitted.error().describe().c_str());
    }
    latch.wait(10);
  }
  const auto stats = rig.bus->stats();
  state.counters["datagrams_per_frame"] =
      static_cast<double>(stats.datagrams_sent) / static_cast<double>(stats.frames_sent);
}
BENCHMARK(BM_SubmitTenTransactions)->UseRealTime();

void BM_RealtimeLrwCycle(benchmark::State& state) {
  Rig rig;
  Transaction layout;
  std::array<std::uint8_t, 64> image{};
  layout.lrw(0x00010000, image, 3);
  RealtimeTransaction rt(std::move(layout));
  std::uint8_t counter = 0;
  for (auto _ : state) {
    rt.output(0)[0] = counter++;
    if (!rig.bus->submit_realtime(rt, 1s)) state.SkipWithError("submit_realtime failed");
    rt.wait();
    if (rt.status() != RealtimeStatus::ok) state.SkipWithError("realtime exchange failed");
    benchmark::DoNotOptimize(rt.input(0)[0]);
  }
  state.counters["expired"] = static_cast<double>(rig.bus->stats().realtime_expired);
}
BENCHMARK(BM_RealtimeLrwCycle)->UseRealTime();

void BM_PackingRatio(benchmark::State& state) {
  Rig rig(200us);
  constexpr std::size_t kTransactions = 1000;
  std::uint64_t transactions = 0;
  for (auto _ : state) {
    Latch latch;
    for (std::size_t i = 0; i < kTransactions; ++i) {
      Transaction tx;
      tx.fprd(static_cast<std::uint16_t>(0x1001 + i % 3),
              static_cast<std::uint16_t>(0x1000 + i % 512), 2, 1);
      (void)rig.bus->submit(std::move(tx),
                            [&latch](ecat::Result<TransactionResult> r) { latch.arrive(r.ok()); });
    }
    latch.wait(kTransactions);
    transactions += kTransactions;
  }
  const auto stats = rig.bus->stats();
  state.counters["frames_per_transaction"] =
      static_cast<double>(stats.frames_sent) / static_cast<double>(transactions);
  state.counters["datagrams_per_frame"] =
      static_cast<double>(stats.datagrams_sent) / static_cast<double>(stats.frames_sent);
}
BENCHMARK(BM_PackingRatio)->UseRealTime()->Unit(benchmark::kMillisecond);

}  // namespace

int main(int argc, char** argv) {
  return ecat::bench::benchmark_main(argc, argv);
}
