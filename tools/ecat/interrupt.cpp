#include "interrupt.hpp"

#include <atomic>
#include <csignal>
#include <cstdlib>
#include <thread>

namespace ecat::tool {
namespace {

std::atomic<int> g_interrupts{0};

extern "C" void on_interrupt(int /*signal*/) {
  if (g_interrupts.fetch_add(1) > 0) std::_Exit(130);
}

}  // namespace

void catch_interrupts() {
  struct sigaction action {};
  action.sa_handler = on_interrupt;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

bool interrupted() noexcept {
  return g_interrupts.load() > 0;
}

bool sleep_unless_interrupted(std::chrono::nanoseconds duration) {
  using namespace std::chrono_literals;
  const auto end = std::chrono::steady_clock::now() + duration;
  while (!interrupted()) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= end) return true;
    std::this_thread::sleep_for(std::min<std::chrono::nanoseconds>(end - now, 20ms));
  }
  return false;
}

}  // namespace ecat::tool
