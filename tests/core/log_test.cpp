// The library's log (include/ecat/log.hpp): silent without a sink, filtered by level before the
// message is built, safe to replace while other threads log.
#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/log.hpp>

namespace ecat {
namespace {

struct Seen {
  LogLevel level;
  std::string subsystem;
  std::string message;
  std::int64_t time_ns;
};

// Collects records; clears the process-wide sink when the test ends, whatever happens.
class LogTest : public ::testing::Test {
 protected:
  void TearDown() override { clear_log_sink(); }

  void collect(LogLevel level) {
    set_log_sink(
        [this](const LogRecord& r) {
          std::lock_guard lock(mutex_);
          seen_.push_back({r.level, std::string(r.subsystem), std::string(r.message), r.time_ns});
        },
        level);
  }
  std::vector<Seen> seen() {
    std::lock_guard lock(mutex_);
    return seen_;
  }

  std::mutex mutex_;
  std::vector<Seen> seen_;
};

TEST_F(LogTest, NoSinkMeansNothingIsEnabledOrBuilt) {
  clear_log_sink();
  for (auto level :
       {LogLevel::trace, LogLevel::debug, LogLevel::info, LogLevel::warn, LogLevel::error})
    EXPECT_FALSE(log_enabled(level));
  int built = 0;
  auto message = [&] {
    ++built;
    return std::string("never");
  };
  ECAT_LOG(LogLevel::error, "test", message());
  EXPECT_EQ(built, 0);
  log(LogLevel::error, "test", "dropped");  // no sink: nothing happens
  set_log_level(LogLevel::trace);           // no sink: stays silent
  EXPECT_FALSE(log_enabled(LogLevel::error));
}

TEST_F(LogTest, SinkReceivesRecordsAtOrAboveItsLevel) {
  collect(LogLevel::info);
  EXPECT_FALSE(log_enabled(LogLevel::debug));
  EXPECT_TRUE(log_enabled(LogLevel::info));
  EXPECT_FALSE(log_enabled(LogLevel::off));
  int built = 0;
  auto message = [&](const char* text) {
    ++built;
    return std::string(text);
  };
  const auto before = std::chrono::system_clock::now().time_since_epoch();
  ECAT_LOG(LogLevel::debug, "master", message("hidden"));
  ECAT_LOG(LogLevel::info, "master", message("shown"));
  ECAT_LOG(LogLevel::error, "link", message("broken"));
  log(LogLevel::trace, "link", "hidden too");
  log(LogLevel::off, "link", "never a record level");
  const auto after = std::chrono::system_clock::now().time_since_epoch();
  EXPECT_EQ(built, 2);  // the filtered message was never built
  const auto records = seen();
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].level, LogLevel::info);
  EXPECT_EQ(records[0].subsystem, "master");
  EXPECT_EQ(records[0].message, "shown");
  EXPECT_EQ(records[1].level, LogLevel::error);
  EXPECT_EQ(records[1].subsystem, "link");
  EXPECT_EQ(records[1].message, "broken");
  // CLOCK_REALTIME nanoseconds.
  EXPECT_GE(records[0].time_ns,
            std::chrono::duration_cast<std::chrono::nanoseconds>(before).count());
  EXPECT_LE(records[1].time_ns,
            std::chrono::duration_cast<std::chrono::nanoseconds>(after).count());

  set_log_level(LogLevel::trace);
  log(LogLevel::trace, "sim", "now shown");
  EXPECT_EQ(seen().size(), 3u);
  clear_log_sink();
  log(LogLevel::error, "sim", "after clear");
  EXPECT_EQ(seen().size(), 3u);
  EXPECT_FALSE(log_enabled(LogLevel::error));
}

TEST_F(LogTest, LevelsHaveNames) {
  EXPECT_EQ(to_string(LogLevel::warn), "warn");
  EXPECT_EQ(log_level_from_string("debug"), LogLevel::debug);
  EXPECT_EQ(log_level_from_string("warning"), LogLevel::warn);
  EXPECT_EQ(log_level_from_string("loud"), std::nullopt);
}

TEST_F(LogTest, ASinkThatThrowsDoesNotReachTheCaller) {
  set_log_sink([](const LogRecord&) { throw std::runtime_error("sink failed"); }, LogLevel::info);
  EXPECT_NO_THROW(log(LogLevel::error, "test", "x"));
  set_log_sink(LogSink{}, LogLevel::info);  // empty: the same as clear
  EXPECT_FALSE(log_enabled(LogLevel::error));
}

TEST_F(LogTest, ASinkMayLogAndReplaceTheSinkFromInsideACall) {
  std::atomic<int> inner{0};
  set_log_sink(
      [&](const LogRecord& r) {
        if (r.subsystem == "outer") {
          set_log_sink([&](const LogRecord&) { ++inner; }, LogLevel::info);
          log(LogLevel::info, "inner", "from inside");
        }
      },
      LogLevel::info);
  log(LogLevel::info, "outer", "first");
  EXPECT_EQ(inner.load(), 1);
}

// Sinks replaced and cleared while four threads log: no crash and no call into a destroyed sink
// (each holds the only other reference to its counter: under AddressSanitizer a call after its
// destruction is a use after free), and every record goes to one sink or none.
TEST_F(LogTest, ReplacingTheSinkWhileOtherThreadsLogIsSafe) {
  struct Counter {
    std::atomic<std::uint64_t> count{0};
  };
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> sent{0};
  std::vector<std::thread> loggers;
  for (int t = 0; t < 4; ++t) {
    loggers.emplace_back([&] {
      while (!stop.load()) {
        ECAT_LOG(LogLevel::info, "test", std::string("a message long enough to allocate ...."));
        ++sent;
      }
    });
  }
  std::uint64_t delivered = 0;
  for (int round = 0; round < 300; ++round) {
    auto counter = std::make_shared<Counter>();
    set_log_sink(
        [counter](const LogRecord& r) {
          if (r.message.size() > 10) ++counter->count;
        },
        round % 2 == 0 ? LogLevel::info : LogLevel::trace);
    std::this_thread::sleep_for(std::chrono::microseconds(100));
    if (round % 3 == 0) clear_log_sink();
    if (round % 5 == 0) set_log_level(LogLevel::error);  // filters everything for a while
    delivered += counter->count.load();
  }
  stop = true;
  for (auto& t : loggers)
    t.join();
  clear_log_sink();
  EXPECT_GT(sent.load(), 0u);
  EXPECT_GT(delivered, 0u);
  EXPECT_LE(delivered, sent.load());
}

}  // namespace
}  // namespace ecat
