// Ctrl-C for the long-running subcommands (run, demo): the first SIGINT/SIGTERM asks the command
// to wind down cleanly (slaves back to INIT, bus closed); a second one ends the process at once.
#pragma once

#include <chrono>

namespace ecat::tool {

// Installs the handlers (idempotent).
void catch_interrupts();
bool interrupted() noexcept;
// Sleeps up to `duration`, returning early (false) when interrupted.
bool sleep_unless_interrupted(std::chrono::nanoseconds duration);

}  // namespace ecat::tool
