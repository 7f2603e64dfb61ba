// Applies CycleThreadOptions to the calling thread (the bus thread, from
// BusOptions::on_thread_start).
#pragma once

#include <string>

#include <ecat/master/config.hpp>

namespace ecat::master {

// Sets SCHED_FIFO and the CPU affinity as asked; returns what was done or refused, e.g.
// "SCHED_FIFO 80: applied; CPU 1: refused (Invalid argument)"; "" when nothing was asked.
std::string apply_cycle_thread(const CycleThreadOptions& options);

}  // namespace ecat::master
