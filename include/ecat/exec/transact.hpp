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
  TransactAwaiter(const TransactAwaiter&) = delete;
  TransactAwaiter& operator=(const TransactAwaiter&) = delete;

  bool await_ready() const noexcept { return false; }
  void await_suspend(std::coroutine_handle<> h) {
    resume_.handle = h;
    // The completion runs on the bus thread. It moves the result into this awaiter (which lives
    // in the suspended coroutine's frame: nobody else touches it until the coroutine resumes)
    // and queues the resumption on the control thread with a node that lives here too: the
    // hand-over allocates nothing and takes no lock. The lambda holds one pointer, within
    // std::function's inline storage.
    auto submitted = bus_.submit(
        std::move(transaction_),
        [this](Result<bus::TransactionResult> result) {
          result_.emplace(std::move(result));
          loop_.post(resume_);
        },
        options_);
    if (!submitted) {
      result_.emplace(std::move(submitted).error());
      loop_.post(resume_);
    }
  }
  Result<bus::TransactionResult> await_resume() { return std::move(*result_); }

 private:
  struct Resume final : EventLoop::Work {
    Resume() noexcept : Work(&invoke) {}
    static void invoke(Work& self, bool run) {
      if (run) static_cast<Resume&>(self).handle.resume();
    }
    std::coroutine_handle<> handle;
  };

  EventLoop& loop_;
  bus::Bus& bus_;
  bus::Transaction transaction_;
  bus::TransactOptions options_;
  std::optional<Result<bus::TransactionResult>> result_;
  Resume resume_;
};

inline TransactAwaiter transact(EventLoop& loop, bus::Bus& bus, bus::Transaction transaction,
                                bus::TransactOptions options = {}) {
  return TransactAwaiter(loop, bus, std::move(transaction), options);
}

}  // namespace ecat::exec
