// Waiting for the bus to fall quiet, from a task on the control thread (the reference design's
// Bus.settle / Bus.quiesce):
//
//   if (auto r = co_await exec::quiesce(loop, bus, 2ms); !r) ...  // settle, quiet window, settle
//
// "Idle" is about reliable (acyclic) work only: no reliable transaction accepted and not yet
// completed, and no frame in flight but realtime ones. Cyclic exchange (domains, DC) may go on:
// it never shares a frame with reliable work, so it cannot carry a late startup reply.
#pragma once

#include <chrono>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/result.hpp>

namespace ecat::exec {

struct SettleOptions {
  // Give up (Errc::timeout, naming what was still pending) after this long.
  std::chrono::nanoseconds timeout = std::chrono::seconds(1);
  // How often the bus is looked at while it is busy.
  std::chrono::nanoseconds poll = std::chrono::microseconds(200);
};

// True when the bus has no reliable work queued, pending or in flight.
bool reliable_idle(const bus::BusInfo& info) noexcept;

// Waits until reliable_idle(). Errc::closed when the bus is not running.
Task<Result<void>> settle(EventLoop& loop, bus::Bus& bus, SettleOptions options = {});

// settle, then `quiet` of nothing, then settle again: a reply that was late for the first settle
// has landed (or timed out) by the second.
Task<Result<void>> quiesce(EventLoop& loop, bus::Bus& bus, std::chrono::nanoseconds quiet,
                           SettleOptions options = {});

}  // namespace ecat::exec
