#include <fmt/format.h>

#include <ecat/exec/quiesce.hpp>

namespace ecat::exec {

bool reliable_idle(const bus::BusInfo& info) noexcept {
  return info.reliable_queued == 0 && info.reliable_pending == 0 &&
         info.frames_in_flight <= info.realtime_frames_in_flight;
}

Task<Result<void>> settle(EventLoop& loop, bus::Bus& bus, SettleOptions options) {
  const auto deadline = Clock::now() + options.timeout;
  // Idle twice, one poll apart: the bus publishes its counts between taking new submissions and
  // counting them as live, so a single look could fall into that gap.
  bool idle_before = false;
  while (true) {
    const auto info = bus.info();
    if (!info.running) {
      co_return Error(Errc::closed, fmt::format("bus on link {} is not running: it cannot settle",
                                                info.link_name));
    }
    const bool idle = reliable_idle(info);
    if (idle && idle_before) co_return ok();
    idle_before = idle;
    if (!idle && Clock::now() >= deadline) {
      co_return Error(
          Errc::timeout,
          fmt::format(
              "bus on link {} did not settle within {} ms: {} reliable transaction(s) "
              "pending ({} queued), {} frame(s) in flight ({} realtime)",
              info.link_name,
              std::chrono::duration_cast<std::chrono::milliseconds>(options.timeout).count(),
              info.reliable_pending, info.reliable_queued, info.frames_in_flight,
              info.realtime_frames_in_flight));
    }
    co_await sleep_for(loop, options.poll);
  }
}

Task<Result<void>> quiesce(EventLoop& loop, bus::Bus& bus, std::chrono::nanoseconds quiet,
                           SettleOptions options) {
  if (auto r = co_await settle(loop, bus, options); !r) co_return r;
  if (quiet.count() > 0) co_await sleep_for(loop, quiet);
  co_return co_await settle(loop, bus, options);
}

}  // namespace ecat::exec
