#include <algorithm>
#include <cstdio>
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

  CLI11_PARSE(app, argc, argv);

  for (auto& command : commands) {
    if (command.app != nullptr && command.app->parsed()) return command.run();
  }
  std::fprintf(stderr, "ecat: no subcommand given (see ecat --help)\n");
  return 2;
}
