#include <chrono>

#include <fmt/format.h>

#include <ecat/bus/realtime.hpp>

namespace ecat::bus {

std::string_view to_string(RealtimeStatus status) noexcept {
  switch (status) {
    case RealtimeStatus::not_run:
      return "not run";
    case RealtimeStatus::ok:
      return "ok";
    case RealtimeStatus::wkc_mismatch:
      return "working counter mismatch";
    case RealtimeStatus::expired:
      return "expired";
    case RealtimeStatus::timeout:
      return "timeout";
    case RealtimeStatus::link_error:
      return "link error";
    case RealtimeStatus::closed:
      return "closed";
  }
  return "unknown";
}

RealtimeTransaction::RealtimeTransaction(Transaction layout)
    : layout_(std::move(layout)),
      input_(layout_.payload_size(), 0),
      replies_(layout_.size()),
      sent_index_(layout_.size(), 0) {}

wire::Bytes RealtimeTransaction::input(std::size_t slot) const noexcept {
  if (slot >= layout_.size()) return {};
  const auto& d = layout_.datagrams()[slot];
  return wire::Bytes{input_.data() + d.data_offset, d.length};
}

std::uint16_t RealtimeTransaction::wkc(std::size_t slot) const noexcept {
  return slot < replies_.size() ? replies_[slot].wkc : 0;
}

bool RealtimeTransaction::circulating(std::size_t slot) const noexcept {
  return slot < replies_.size() && replies_[slot].circulating;
}

std::uint16_t RealtimeTransaction::irq(std::size_t slot) const noexcept {
  return slot < replies_.size() ? replies_[slot].irq : 0;
}

// Completion is published under wait_mutex_ and the bus never touches the object after releasing
// it, so observing "not pending" under the same mutex makes destroying the object safe.
bool RealtimeTransaction::pending_locked() const noexcept {
  const Stage stage = stage_.load(std::memory_order_acquire);
  return stage == Stage::queued || stage == Stage::in_flight;
}

bool RealtimeTransaction::pending() const noexcept {
  std::lock_guard lock(wait_mutex_);
  return pending_locked();
}

Result<void> RealtimeTransaction::result() const {
  const auto what = [this]() -> std::string {
    if (layout_.empty()) return "realtime exchange (no datagrams)";
    const auto first = describe(layout_.datagrams()[0]);
    if (layout_.size() == 1) return fmt::format("realtime {}", first);
    return fmt::format("realtime exchange of {} datagrams (first {})", layout_.size(), first);
  };
  const auto datagram = [this](std::size_t slot) {
    return slot < layout_.size() ? describe(layout_.datagrams()[slot]) : std::string("?");
  };
  using std::chrono::duration_cast;
  using std::chrono::microseconds;
  switch (status()) {
    case RealtimeStatus::ok:
      return ok();
    case RealtimeStatus::not_run:
      return Error(Errc::wrong_state, what() + " has not been submitted");
    case RealtimeStatus::wkc_mismatch: {
      const auto& d = layout_.datagrams()[failed_slot_];
      return Error(Errc::wkc_mismatch,
                   fmt::format("{} (datagram {}, index 0x{:02x}): working counter {}, expected {}",
                               datagram(failed_slot_), failed_slot_, failed_index_, failed_wkc_,
                               d.expected_wkc.value_or(0)));
    }
    case RealtimeStatus::expired:
      return Error(Errc::expired,
                   fmt::format("{} expired: not sent within its {} us staleness budget", what(),
                               duration_cast<microseconds>(stale_after_).count()));
    case RealtimeStatus::timeout:
      return Error(Errc::timeout,
                   fmt::format("{}: no reply to the frame with {} (datagram {}, index 0x{:02x}) "
                               "within {} us",
                               what(), datagram(failed_slot_), failed_slot_, failed_index_,
                               duration_cast<microseconds>(frame_timeout_).count()));
    case RealtimeStatus::link_error:
      if (link_error_) {
        return link_error_->context(fmt::format("{}: sending failed", what()));
      }
      return Error(Errc::io_error, what() + ": sending failed");
    case RealtimeStatus::closed:
      return Error(Errc::closed, what() + ": the bus stopped before it completed");
  }
  return Error(Errc::internal, what() + ": unknown status");
}

void RealtimeTransaction::wait() const {
  std::unique_lock lock(wait_mutex_);
  wait_cv_.wait(lock, [this] { return !pending_locked(); });
}

bool RealtimeTransaction::wait_until(std::chrono::steady_clock::time_point deadline) const {
  std::unique_lock lock(wait_mutex_);
  return wait_cv_.wait_until(lock, deadline, [this] { return !pending_locked(); });
}

}  // namespace ecat::bus
