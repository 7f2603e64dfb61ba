// Runs a control-loop task from an application thread and waits for it: what every blocking
// Slave call (SDO, FoE, SoE, SII writes ...) does. Refused on the control thread itself, which
// would wait for itself.
#pragma once

#include <chrono>
#include <string_view>

#include <fmt/format.h>

#include <ecat/exec/task.hpp>
#include <ecat/result.hpp>

#include "session.hpp"

namespace ecat::master::detail {

template <class T>
Result<T> blocking(Session& session, exec::Task<Result<T>> task, std::chrono::nanoseconds timeout,
                   std::string_view what) {
  if (session.loop.in_loop_thread()) {
    return Error(Errc::wrong_state,
                 fmt::format("{}: called on the control thread (it would wait for itself)", what));
  }
  auto result = exec::run_blocking(session.loop, std::move(task), timeout);
  if (!result) {
    return Error(
        Errc::timeout,
        fmt::format("{}: no answer within {} ms", what,
                    std::chrono::duration_cast<std::chrono::milliseconds>(timeout).count()));
  }
  return std::move(*result);
}

}  // namespace ecat::master::detail
