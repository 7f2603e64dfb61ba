#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>
#include <memory>
#include <vector>

#include <fmt/format.h>
#include <spdlog/logger.h>
#include <spdlog/sinks/stdout_color_sinks.h>

#include <ecat/log.hpp>
#include <ecat/version.hpp>

#include "command.hpp"

namespace ecat::tool {
namespace {
std::vector<SetupFn>& registry() {
  static std::vector<SetupFn> setups;
  return setups;
}
}  // namespace

bool register_command(SetupFn setup) {
  registry().push_back(setup);
  return true;
}

namespace {

// The library's log level for the global -v (repeatable) and -q options: warnings by default.
LogLevel log_level_for(int verbosity, bool quiet) {
  if (quiet) return LogLevel::error;
  switch (verbosity) {
    case 0:
      return LogLevel::warn;
    case 1:
      return LogLevel::info;
    case 2:
      return LogLevel::debug;
    default:
      return LogLevel::trace;
  }
}

spdlog::level::level_enum spdlog_level(LogLevel level) {
  switch (level) {
    case LogLevel::trace:
      return spdlog::level::trace;
    case LogLevel::debug:
      return spdlog::level::debug;
    case LogLevel::info:
      return spdlog::level::info;
    case LogLevel::warn:
      return spdlog::level::warn;
    case LogLevel::error:
      return spdlog::level::err;
    case LogLevel::off:
      break;
  }
  return spdlog::level::off;
}

// The library's log on stderr through spdlog (colored when stderr is a terminal), each line with
// the record's own time and subsystem: "[12:00:01.234] [info] master: master.state ...". The
// sink is removed when the tool ends, before anything it uses goes away.
class LogToStderr {
 public:
  explicit LogToStderr(LogLevel level) {
    auto logger = std::make_shared<spdlog::logger>(
        "ecat", std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    logger->set_pattern("[%H:%M:%S.%e] [%^%l%$] %v");
    logger->set_level(spdlog::level::trace);  // the library filters before formatting
    logger->flush_on(spdlog::level::trace);   // stderr: every line as it comes
    set_log_sink(
        [logger](const LogRecord& record) {
          const spdlog::log_clock::time_point time{
              std::chrono::duration_cast<spdlog::log_clock::duration>(
                  std::chrono::nanoseconds(record.time_ns))};
          logger->log(time, spdlog::source_loc{}, spdlog_level(record.level),
                      fmt::format("{}: {}", record.subsystem, record.message));
        },
        level);
  }
  ~LogToStderr() { clear_log_sink(); }
  LogToStderr(const LogToStderr&) = delete;
  LogToStderr& operator=(const LogToStderr&) = delete;
};

}  // namespace
}  // namespace ecat::tool

int main(int argc, char** argv) {
  CLI::App app{"ecat: EtherCAT master, simulator and tools"};
  app.set_version_flag("--version", ecat::kVersion);
  app.require_subcommand(1);
  // Global options, accepted before the subcommand or after it (fallthrough).
  int verbosity = 0;
  bool quiet = false;
  auto* verbose = app.add_flag("-v,--verbose", verbosity,
                               "Show the library's log on stderr: -v info, -vv debug, -vvv trace "
                               "(default: warnings and errors)");
  app.add_flag("-q,--quiet", quiet, "Log errors only")->excludes(verbose);
  app.fallthrough();

  std::vector<ecat::tool::Command> commands;
  for (auto setup : ecat::tool::registry())
    commands.push_back(setup(app));

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every refused argument exits 2, the tool's code for bad usage
    // (CLI11's own codes, 105 and so on, mean nothing to a script).
    return app.exit(e) == 0 ? 0 : 2;
  }

  const ecat::tool::LogToStderr log(ecat::tool::log_level_for(verbosity, quiet));

  // No exception leaves the tool: one that escapes a command is a bug, reported as such. Unwinding
  // first runs the command's destructors, so a running master still takes its slaves to INIT.
  try {
    for (auto& command : commands) {
      if (command.app != nullptr && command.app->parsed()) return command.run();
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "ecat: internal error (please report it): %s\n", e.what());
    return 70;
  } catch (...) {
    std::fprintf(stderr, "ecat: internal error (please report it): an unknown exception\n");
    return 70;
  }
  std::fprintf(stderr, "ecat: no subcommand given (see ecat --help)\n");
  return 2;
}
