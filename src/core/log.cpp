#include <chrono>
#include <memory>
#include <mutex>
#include <utility>

#include <ecat/log.hpp>

namespace ecat {

namespace detail {
std::atomic<std::uint8_t> log_threshold{static_cast<std::uint8_t>(LogLevel::off)};
}  // namespace detail

namespace {

// The installed sink. Callers copy the shared_ptr under the mutex and call the sink outside it,
// so a sink that is replaced while another thread is inside it stays alive until that call
// returns, and a sink may itself log or replace the sink without deadlocking.
struct SinkSlot {
  std::mutex mutex;
  std::shared_ptr<const LogSink> sink;
  LogLevel level = LogLevel::off;
};

SinkSlot& slot() {
  // Never destroyed: threads may still log while static destructors run at exit.
  static auto* s = new SinkSlot;
  return *s;
}

std::int64_t realtime_ns() noexcept {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace

std::string_view to_string(LogLevel level) noexcept {
  switch (level) {
    case LogLevel::trace:
      return "trace";
    case LogLevel::debug:
      return "debug";
    case LogLevel::info:
      return "info";
    case LogLevel::warn:
      return "warn";
    case LogLevel::error:
      return "error";
    case LogLevel::off:
      return "off";
  }
  return "unknown";
}

std::optional<LogLevel> log_level_from_string(std::string_view name) noexcept {
  for (auto level : {LogLevel::trace, LogLevel::debug, LogLevel::info, LogLevel::warn,
                     LogLevel::error, LogLevel::off}) {
    if (name == to_string(level)) return level;
  }
  if (name == "warning") return LogLevel::warn;
  return std::nullopt;
}

void set_log_sink(LogSink sink, LogLevel min_level) {
  if (!sink) {
    clear_log_sink();
    return;
  }
  auto installed = std::make_shared<const LogSink>(std::move(sink));
  std::shared_ptr<const LogSink> previous;  // destroyed after the lock is released
  auto& s = slot();
  std::lock_guard lock(s.mutex);
  previous = std::exchange(s.sink, std::move(installed));
  s.level = min_level;
  detail::log_threshold.store(static_cast<std::uint8_t>(min_level), std::memory_order_relaxed);
}

void clear_log_sink() {
  std::shared_ptr<const LogSink> previous;
  auto& s = slot();
  std::lock_guard lock(s.mutex);
  previous = std::move(s.sink);
  s.sink.reset();
  s.level = LogLevel::off;
  detail::log_threshold.store(static_cast<std::uint8_t>(LogLevel::off), std::memory_order_relaxed);
}

void set_log_level(LogLevel min_level) {
  auto& s = slot();
  std::lock_guard lock(s.mutex);
  if (!s.sink) return;
  s.level = min_level;
  detail::log_threshold.store(static_cast<std::uint8_t>(min_level), std::memory_order_relaxed);
}

void log(LogLevel level, std::string_view subsystem, std::string_view message) noexcept {
  if (!log_enabled(level)) return;
  std::shared_ptr<const LogSink> sink;
  auto& s = slot();
  {
    std::lock_guard lock(s.mutex);
    // The level is checked again under the lock: the atomic may be a moment behind a change.
    if (!s.sink || level < s.level) return;
    sink = s.sink;
  }
  try {
    (*sink)(LogRecord{level, subsystem, message, realtime_ns()});
  } catch (...) {
    // The sink's failure is not the caller's: logging never throws.
  }
}

}  // namespace ecat
