// A link wrapper for tests of link failure: the master's end of a link with a cable that can be
// pulled (send and receive fail as a NIC without carrier does) and plugged back; reopen() fails
// while it is out, or always (`reopenable` off: Errc::unsupported, as in-process links answer).
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>

namespace ecat::test {

// The master's end of the link, with a cable that can be pulled: while pulled, send() and
// receive() fail as a NIC without carrier does, and reopen() fails until the cable is back.
class PullableLink final : public link::Link {
 public:
  struct Cable {
    std::atomic<bool> pulled{false};
    std::atomic<bool> reopenable{true};
    std::atomic<int> reopens{0};
  };

  PullableLink(std::unique_ptr<link::Link> inner, std::shared_ptr<Cable> cable)
      : inner_(std::move(inner)), cable_(std::move(cable)) {}

  Result<void> send(wire::Bytes frame) override {
    if (cable_->pulled.load()) return Error(Errc::io_error, "pullable: the cable is pulled");
    return inner_->send(frame);
  }
  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    if (cable_->pulled.load()) {
      // Replies that were on their way are lost with the cable.
      while (true) {
        auto stale = inner_->receive(std::chrono::nanoseconds(0));
        if (!stale || !*stale) break;
      }
      return Error(Errc::io_error, "pullable: no carrier");
    }
    return inner_->receive(timeout);
  }
  void interrupt() override { inner_->interrupt(); }
  void close() override { inner_->close(); }
  Result<void> reopen() override {
    cable_->reopens.fetch_add(1);
    if (!cable_->reopenable.load()) return Error(Errc::unsupported, "pullable: cannot reopen");
    if (cable_->pulled.load()) return Error(Errc::io_error, "pullable: still no carrier");
    return ok();
  }
  std::string name() const override { return "pullable:" + inner_->name(); }
  link::LinkStats stats() const override { return inner_->stats(); }
  std::size_t max_frame_size() const override { return inner_->max_frame_size(); }

 private:
  std::unique_ptr<link::Link> inner_;
  std::shared_ptr<Cable> cable_;
};

}  // namespace ecat::test
