// `profile` and `verify`: rebuilding simulator profiles from captures and proving the simulator
// against them (tools/ecat/cmd_sim_verify.cpp). Each adds its subcommand under `parent` and
// returns it with the function that runs it; `ecat sim` (cmd_sim.cpp) carries them:
//
//   auto verify = add_sim_verify_command(*sim_app, "verify");
//   ... if (verify.app->parsed()) return verify.run();
#pragma once

#include <string>

#include "command.hpp"

namespace ecat::tool {

Command add_sim_profile_command(CLI::App& parent, const std::string& name);
Command add_sim_verify_command(CLI::App& parent, const std::string& name);

}  // namespace ecat::tool
