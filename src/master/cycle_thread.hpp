// Applies CycleThreadOptions to the calling thread (the bus thread, from
// BusOptions::on_thread_start): SCHED_FIFO, CPU affinity, and a realtime user's setup when asked
// (cpu_dma_latency held, memory locked, the stack pre-faulted).
#pragma once

#include <cstddef>
#include <string>

#include <ecat/master/config.hpp>

namespace ecat::master {

// What the session holds for its cycle thread; released when destroyed (the session ends).
class CycleThreadHolds {
 public:
  CycleThreadHolds() = default;
  ~CycleThreadHolds() { release(); }
  CycleThreadHolds(const CycleThreadHolds&) = delete;
  CycleThreadHolds& operator=(const CycleThreadHolds&) = delete;

  // Closes cpu_dma_latency and leaves the memory lock (idempotent).
  void release() noexcept;

  // The open /dev/cpu_dma_latency (the kernel keeps the request while it is open), or -1.
  int dma_latency_fd = -1;
  // This session counts in the process's memory lock (mlockall); the last one out unlocks.
  bool memory_locked = false;
};

// How much of the cycle thread's stack is touched at its start, so that its first deep call does
// not fault.
inline constexpr std::size_t kPrefaultedStack = 256 * 1024;

// Sets SCHED_FIFO and the CPU affinity as asked, holds cpu_dma_latency (through `holds`, from
// `dma_latency_path`) and locks memory when asked; returns what was done or refused, e.g.
// "SCHED_FIFO 80: applied; CPU 1: pinned; cpu_dma_latency 0 us: held; memory: locked, 256 KiB of
// stack pre-faulted"; "" when nothing was asked.
std::string apply_cycle_thread(const CycleThreadOptions& options, CycleThreadHolds& holds,
                               const char* dma_latency_path = "/dev/cpu_dma_latency");

// True when any option asks for something (the bus thread then runs apply_cycle_thread).
bool asks_anything(const CycleThreadOptions& options) noexcept;

}  // namespace ecat::master
