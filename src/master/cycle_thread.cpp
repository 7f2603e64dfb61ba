#include "cycle_thread.hpp"

#include <cstring>

#include <fmt/format.h>
#include <pthread.h>
#include <sched.h>

namespace ecat::master {

std::string apply_cycle_thread(const CycleThreadOptions& options) {
  std::string out;
  auto note = [&out](std::string text) {
    if (!out.empty()) out += "; ";
    out += text;
  };
  if (options.fifo_priority) {
    sched_param param{};
    param.sched_priority = *options.fifo_priority;
    const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    note(rc == 0 ? fmt::format("SCHED_FIFO {}: applied", *options.fifo_priority)
                 : fmt::format("SCHED_FIFO {}: refused ({})", *options.fifo_priority,
                               std::strerror(rc)));
  }
  if (options.cpu) {
    const int cpu = *options.cpu;
    int rc = EINVAL;
    if (cpu >= 0 && cpu < CPU_SETSIZE) {
      cpu_set_t set;
      CPU_ZERO(&set);
      CPU_SET(static_cast<std::size_t>(cpu), &set);
      rc = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
    }
    note(rc == 0 ? fmt::format("CPU {}: pinned", cpu)
                 : fmt::format("CPU {}: refused ({})", cpu, std::strerror(rc)));
  }
  return out;
}

}  // namespace ecat::master
