#include "cycle_thread.hpp"

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <mutex>

#include <fcntl.h>
#include <fmt/format.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <unistd.h>

namespace ecat::master {

namespace {

// mlockall is process-wide: the first session that asks locks, the last one that leaves unlocks.
std::mutex lock_mutex;
int lock_holders = 0;

// Touches `kPrefaultedStack` bytes below the caller's frame, so those stack pages are mapped (and,
// with mlockall's MCL_FUTURE or MCL_CURRENT, locked) before the first cycle needs them.
[[gnu::noinline]] void prefault_stack() {
  std::uint8_t area[kPrefaultedStack];
  std::memset(area, 0, sizeof area);
  // The compiler may not drop the writes: the array escapes into this (empty) assembly.
  asm volatile("" : : "r"(area) : "memory");
}

}  // namespace

void CycleThreadHolds::release() noexcept {
  if (dma_latency_fd >= 0) ::close(dma_latency_fd);
  dma_latency_fd = -1;
  if (memory_locked) {
    std::lock_guard lock(lock_mutex);
    if (--lock_holders == 0) (void)::munlockall();
  }
  memory_locked = false;
}

bool asks_anything(const CycleThreadOptions& options) noexcept {
  return options.fifo_priority || options.cpu || options.cpu_dma_latency_us || options.lock_memory;
}

std::string apply_cycle_thread(const CycleThreadOptions& options, CycleThreadHolds& holds,
                               const char* dma_latency_path) {
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
  if (options.cpu_dma_latency_us && holds.dma_latency_fd < 0) {
    // As cyclictest does: the PM QoS request lasts while the file stays open.
    const std::int32_t value = *options.cpu_dma_latency_us;
    const int fd = ::open(dma_latency_path, O_WRONLY | O_CLOEXEC);
    int err = fd < 0 ? errno : 0;
    if (fd >= 0 && ::write(fd, &value, sizeof value) != static_cast<ssize_t>(sizeof value)) {
      err = errno == 0 ? EIO : errno;
      ::close(fd);
    } else if (fd >= 0) {
      holds.dma_latency_fd = fd;
    }
    note(err == 0 ? fmt::format("cpu_dma_latency {} us: held", value)
                  : fmt::format("cpu_dma_latency {} us: refused ({}: {})", value, dma_latency_path,
                                std::strerror(err)));
  }
  if (options.lock_memory) {
    std::string locked;
    if (holds.memory_locked) {
      locked = "locked";
    } else {
      std::lock_guard lock(lock_mutex);
      if (lock_holders > 0 || ::mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
        ++lock_holders;
        holds.memory_locked = true;
        locked = "locked";
      } else {
        locked = fmt::format("not locked (mlockall: {})", std::strerror(errno));
      }
    }
    prefault_stack();
    note(fmt::format("memory: {}, {} KiB of stack pre-faulted", locked, kPrefaultedStack / 1024));
  }
  return out;
}

}  // namespace ecat::master
