// Realtime (cyclic) exchanges: built once, resubmitted every cycle, allocation-free.
//
// A RealtimeTransaction fixes its datagram layout at construction and owns its output and input
// storage. Each cycle the owner writes outputs in place (output(slot)), calls
// Bus::submit_realtime(rt, stale_after), and later reads inputs, working counters and status.
// Nothing in that cycle allocates: not the submission, not the bus thread's send, receive and
// matching, not the completion, not wait().
//
// Life cycle: idle -> queued -> in flight -> done -> (resubmitted) queued -> ...
// Outputs may be written and results read only while the transaction is not pending (idle or
// done). The object must outlive its pending exchange: destroy it only when !pending() (Bus::stop()
// completes every pending exchange with RealtimeStatus::closed).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string_view>
#include <vector>

#include <ecat/bus/transaction.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::bus {

enum class RealtimeStatus : std::uint8_t {
  not_run,       // never submitted
  ok,            // replied, and every expected working counter matched
  wkc_mismatch,  // replied (data is valid), but a working counter differs from its expectation
  expired,       // could not be sent before its staleness deadline; nothing was sent
  timeout,       // sent, but no valid reply within the bus's frame timeout
  link_error,    // the link failed to send; result() carries the link's error
  closed,        // the bus stopped before the exchange completed
};
std::string_view to_string(RealtimeStatus status) noexcept;

class RealtimeTransaction {
 public:
  // `layout` fixes the datagrams; its data becomes the initial outputs. A layout that has an
  // error() is kept, and Bus::submit_realtime refuses it with that error.
  explicit RealtimeTransaction(Transaction layout);
  ~RealtimeTransaction() = default;
  RealtimeTransaction(const RealtimeTransaction&) = delete;
  RealtimeTransaction& operator=(const RealtimeTransaction&) = delete;

  const Transaction& layout() const noexcept { return layout_; }
  std::size_t size() const noexcept { return layout_.size(); }

  // Data sent by the next submission (write it while !pending()).
  wire::MutableBytes output(std::size_t slot) noexcept { return layout_.mutable_data(slot); }
  // Reply of the last completed exchange (valid when status() is ok or wkc_mismatch).
  wire::Bytes input(std::size_t slot) const noexcept;
  std::uint16_t wkc(std::size_t slot) const noexcept;
  bool circulating(std::size_t slot) const noexcept;
  std::uint16_t irq(std::size_t slot) const noexcept;
  // Link receive timestamp (CLOCK_MONOTONIC ns) of the last reply frame, 0 when none.
  std::int64_t reply_timestamp_ns() const noexcept { return reply_timestamp_ns_; }
  // When the bus started sending the last exchange (CLOCK_MONOTONIC ns), 0 before the first.
  std::int64_t sent_timestamp_ns() const noexcept { return sent_timestamp_ns_; }
  // Completed exchanges, whatever their status.
  std::uint64_t completions() const noexcept {
    return completions_.load(std::memory_order_acquire);
  }

  // True from submission until completion.
  bool pending() const noexcept;
  RealtimeStatus status() const noexcept { return status_.load(std::memory_order_acquire); }
  // ok() for RealtimeStatus::ok, otherwise an Error naming what failed (allocates only then).
  Result<void> result() const;

  // Blocks until the exchange in progress (if any) completes. Allocation-free. The bus always
  // completes a submitted exchange (by reply, timeout, expiry or stop), so wait() cannot hang
  // while the bus runs.
  void wait() const;
  // Same, giving up at `deadline`; returns true when the transaction is no longer pending.
  bool wait_until(std::chrono::steady_clock::time_point deadline) const;
  bool wait_for(std::chrono::nanoseconds timeout) const {
    return wait_until(std::chrono::steady_clock::now() + timeout);
  }

  // Called on the bus thread at each completion, after the results are in place and before
  // waiters wake. Set it before the first submission; it must not block. The exchange still
  // counts as pending while it runs: resubmit from the next cycle, not from here.
  void set_completion(std::function<void(RealtimeTransaction&)> completion) {
    completion_ = std::move(completion);
  }

 private:
  friend class Bus;
  enum class Stage : std::uint8_t { idle, queued, in_flight, done };
  struct Reply {
    std::uint16_t wkc = 0;
    std::uint16_t irq = 0;
    bool circulating = false;
  };

  bool pending_locked() const noexcept;

  Transaction layout_;
  std::vector<std::uint8_t> input_;
  std::vector<Reply> replies_;
  std::function<void(RealtimeTransaction&)> completion_;

  std::atomic<Stage> stage_{Stage::idle};
  std::atomic<RealtimeStatus> status_{RealtimeStatus::not_run};
  std::atomic<std::uint64_t> completions_{0};
  mutable std::mutex wait_mutex_;
  mutable std::condition_variable wait_cv_;

  // Owned by the bus thread while pending; read by the owner after completion.
  std::chrono::steady_clock::time_point stale_at_{};
  std::chrono::nanoseconds stale_after_{};
  std::chrono::nanoseconds frame_timeout_{};
  std::size_t next_to_send_ = 0;
  std::size_t outstanding_ = 0;
  bool lost_ = false;
  std::size_t failed_slot_ = 0;
  std::uint8_t failed_index_ = 0;
  std::uint16_t failed_wkc_ = 0;
  std::optional<Error> link_error_;  // only set on a link failure (not a realtime-path event)
  std::int64_t reply_timestamp_ns_ = 0;
  std::int64_t sent_timestamp_ns_ = 0;
  std::vector<std::uint8_t> sent_index_;  // datagram index used per slot in the last exchange
  std::size_t frames_needed_ = 0;
  const Bus* validated_for_ = nullptr;  // submit_realtime's layout check is done once per bus
  RealtimeTransaction* next_active_ = nullptr;  // bus thread's list of unsent exchanges
};

}  // namespace ecat::bus
