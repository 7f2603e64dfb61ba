// Shared helpers for the bus tests.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/bus/bus.hpp>

#include "bus/fake_segment.hpp"

namespace ecat::bus::test {

using namespace std::chrono_literals;

inline std::unique_ptr<Bus> start_bus(const std::shared_ptr<FakeSegment>& segment,
                                      BusOptions options = {}) {
  auto bus = std::make_unique<Bus>(FakeSegment::make_link(segment), std::move(options));
  auto started = bus->start();
  EXPECT_TRUE(started.ok()) << (started ? "" : started.error().describe());
  return bus;
}

inline std::shared_ptr<FakeSegment> make_segment(FakeSegment::Options options = {}) {
  return std::make_shared<FakeSegment>(options);
}

inline std::vector<std::uint8_t> bytes_of(wire::Bytes b) {
  return {b.begin(), b.end()};
}

// Counts completions of submit() calls and keeps their results.
class Completions {
 public:
  Completion make(std::size_t id) {
    return [this, id](Result<TransactionResult> result) {
      std::lock_guard lock(mutex_);
      if (results_.size() <= id) results_.resize(id + 1);
      results_[id].emplace(std::move(result));
      ++done_;
      cv_.notify_all();
    };
  }
  bool wait_for(std::size_t count, std::chrono::nanoseconds timeout = 10s) {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, timeout, [&] { return done_ >= count; });
  }
  std::size_t done() {
    std::lock_guard lock(mutex_);
    return done_;
  }
  const Result<TransactionResult>& at(std::size_t id) {
    std::lock_guard lock(mutex_);
    return *results_.at(id);
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<std::optional<Result<TransactionResult>>> results_;
  std::size_t done_ = 0;
};

// Polls `predicate` until it holds or `timeout` passes.
template <class Predicate>
bool eventually(Predicate predicate, std::chrono::nanoseconds timeout = 5s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (predicate()) return true;
    std::this_thread::sleep_for(1ms);
  }
  return predicate();
}

}  // namespace ecat::bus::test
