// The library's log: where it says what it does (links opened, the master's events as they are
// dispatched, captures read). It prints nothing by default: an application that wants the log
// installs a sink, and the library hands it records at or above the level asked for.
//
//   ecat::set_log_sink([](const ecat::LogRecord& r) {
//     std::fprintf(stderr, "[%s] %.*s: %.*s\n", ecat::to_string(r.level).data(), ...);
//   }, ecat::LogLevel::info);
//
// A filtered or sinkless log costs one relaxed atomic load: the message is not even formatted
// (ECAT_LOG evaluates its message only when the level is enabled). The cycle (bus) thread never
// logs: only control-side code does (the control thread, the event dispatcher, API calls).
//
// The sink may be called from several threads at once and must be thread-safe itself. It may be
// replaced or cleared at any time from any thread; a call already running finishes with the sink
// it started with (kept alive until then), later calls see the new one.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <optional>
#include <string_view>

namespace ecat {

enum class LogLevel : std::uint8_t { trace, debug, info, warn, error, off };

// "trace", "debug", "info", "warn", "error", "off".
std::string_view to_string(LogLevel level) noexcept;
std::optional<LogLevel> log_level_from_string(std::string_view name) noexcept;

struct LogRecord {
  LogLevel level = LogLevel::info;
  std::string_view subsystem;  // "master", "slave", "domain", "dc", "link", "bus", "capture" ...
  std::string_view message;    // one line, no trailing newline
  std::int64_t time_ns = 0;    // CLOCK_REALTIME, since the Unix epoch
};

// Valid only during the call: copy what you keep.
using LogSink = std::function<void(const LogRecord& record)>;

// Installs `sink` for the whole process (replacing any other), passing it records at or above
// `min_level`. An empty sink is the same as clear_log_sink().
void set_log_sink(LogSink sink, LogLevel min_level = LogLevel::info);
// Removes the sink: the library is silent again.
void clear_log_sink();
// Changes the level of the installed sink (no effect without one).
void set_log_level(LogLevel min_level);

namespace detail {
// The lowest level delivered: LogLevel::off when no sink is installed.
extern std::atomic<std::uint8_t> log_threshold;
}  // namespace detail

// True when a record of `level` would reach a sink: check this before building a message.
inline bool log_enabled(LogLevel level) noexcept {
  return static_cast<std::uint8_t>(level) >=
             detail::log_threshold.load(std::memory_order_relaxed) &&
         level != LogLevel::off;
}

// Hands one record to the sink, if one is installed and the level is enabled. Never throws (a
// sink's exception is swallowed), never called on the cycle thread.
void log(LogLevel level, std::string_view subsystem, std::string_view message) noexcept;

}  // namespace ecat

// Evaluates `message` (anything convertible to std::string_view, e.g. a fmt::format(...) call)
// only when `level` is enabled.
#define ECAT_LOG(level, subsystem, message)                                       \
  do {                                                                            \
    if (::ecat::log_enabled(level)) ::ecat::log((level), (subsystem), (message)); \
  } while (false)
