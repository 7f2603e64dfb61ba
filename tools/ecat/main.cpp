#include <algorithm>
#include <cstdio>
#include <exception>
#include <vector>

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
}  // namespace ecat::tool

int main(int argc, char** argv) {
  CLI::App app{"ecat: EtherCAT master, simulator and tools"};
  app.set_version_flag("--version", ecat::kVersion);
  app.require_subcommand(1);

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
