// Subcommands of the `ecat` tool register themselves here, one file per subcommand:
//
//   namespace {
//   ecat::tool::Command setup(CLI::App& parent) {
//     auto* app = parent.add_subcommand("sii", "Decode an SII EEPROM image");
//     auto options = std::make_shared<Options>();
//     app->add_option("FILE", options->file)->required();
//     return {app, [options] { return run(*options); }};
//   }
//   const bool registered = ecat::tool::register_command(&setup);
//   }  // namespace
#pragma once

#include <functional>

#include <CLI/CLI.hpp>

namespace ecat::tool {

struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;  // exit code of the process
};

using SetupFn = Command (*)(CLI::App& parent);

// Call from a namespace-scope initializer; returns true so the result can initialise a constant.
bool register_command(SetupFn setup);

}  // namespace ecat::tool

namespace ecat::tool {

// Validators for numeric options: a finite decimal number within [min, max] (above `min` when
// `min_exclusive`), refused otherwise with the range in words ("--timeout: 'nan' is not a number
// of seconds from above 0 to 86400"). CLI11's own PositiveNumber takes nan, inf and 1e300.
CLI::Validator number_in(double min, double max, std::string unit, bool min_exclusive = false);

// Common ranges: a duration in seconds to keep running (0 to a year), and a time-out in seconds
// (above 0, at most a day).
CLI::Validator run_seconds();
CLI::Validator timeout_seconds();

}  // namespace ecat::tool
