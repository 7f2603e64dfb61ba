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
