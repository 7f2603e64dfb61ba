// co_await a bus transaction from a task on the control thread:
//
//   auto reply = co_await exec::transact(loop, bus, std::move(tx), {.timeout = 50ms});
//
// The transaction is submitted to the bus at once; the task resumes on the loop thread when it
// completes, so everything a task does stays on the control thread.
#pragma once

#include <coroutine>
#include <optional>
#include <utility>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>

namespace ecat::exec {

class TransactAwaiter {
 public:
  TransactAwaiter(EventLoop& loop, bus::Bus& bus, bus::Transaction transaction,
                  bus::TransactOptions options)
      : loop_(loop), bus_(bus), transaction_(std::move(transaction)), options_(options) {}

  bool await_ready() const noexcept { return false; }
  void await_suspend(std::coroutine_handle<> h) {
    auto submitted = bus_.submit(
        std::move(transaction_),
        [this, h](Result<bus::TransactionResult> result) {
          // Runs on the bus thread: hand the result to the control thread.
          loop_.post([this, h, result = std::move(result)]() mutable {
            result_.emplace(std::move(result));
            h.resume();
          });
        },
        options_);
    if (!submitted) {
      result_.emplace(std::move(submitted).error());
      loop_.post([h] { h.resume(); });
    }
  }
  Result<bus::TransactionResult> await_resume() { return std::move(*result_); }

 private:
  EventLoop& loop_;
  bus::Bus& bus_;
  bus::Transaction transaction_;
  bus::TransactOptions options_;
  std::optional<Result<bus::TransactionResult>> result_;
};

inline TransactAwaiter transact(EventLoop& loop, bus::Bus& bus, bus::Transaction transaction,
                                bus::TransactOptions options = {}) {
  return TransactAwaiter(loop, bus, std::move(transaction), options);
}

}  // namespace ecat::exec
