// A link wrapper for tests that count what the master sends: every reply frame it receives is
// decoded and each datagram recorded (command, address, length, working counter), frame by frame,
// into a shared log a test reads while the master runs. Replies rather than requests: they carry
// the working counter, so a test can tell a mailbox read that found SM1 full from one that found
// it empty.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::test {

struct CountedDatagram {
  wire::Command command = wire::Command::nop;
  std::uint32_t address = 0;
  std::uint16_t length = 0;
  std::uint16_t wkc = 0;

  std::uint16_t adp() const noexcept { return static_cast<std::uint16_t>(address); }
  std::uint16_t ado() const noexcept { return static_cast<std::uint16_t>(address >> 16); }
};

// The reply frames seen, oldest first.
class FrameLog {
 public:
  void add(std::vector<CountedDatagram> frame) {
    std::lock_guard lock(mutex_);
    frames_.push_back(std::move(frame));
  }
  std::size_t size() const {
    std::lock_guard lock(mutex_);
    return frames_.size();
  }
  // The frames from index `from` on.
  std::vector<std::vector<CountedDatagram>> since(std::size_t from) const {
    std::lock_guard lock(mutex_);
    if (from >= frames_.size()) return {};
    return {frames_.begin() + static_cast<std::ptrdiff_t>(from), frames_.end()};
  }

 private:
  mutable std::mutex mutex_;
  std::vector<std::vector<CountedDatagram>> frames_;
};

// Frames carrying at least one datagram `which` accepts.
inline std::size_t count_frames(const std::vector<std::vector<CountedDatagram>>& frames,
                                const std::function<bool(const CountedDatagram&)>& which) {
  std::size_t n = 0;
  for (const auto& frame : frames) {
    for (const auto& d : frame) {
      if (which(d)) {
        ++n;
        break;
      }
    }
  }
  return n;
}

// Datagrams `which` accepts.
inline std::size_t count_datagrams(const std::vector<std::vector<CountedDatagram>>& frames,
                                   const std::function<bool(const CountedDatagram&)>& which) {
  std::size_t n = 0;
  for (const auto& frame : frames) {
    for (const auto& d : frame)
      n += which(d) ? 1 : 0;
  }
  return n;
}

class CountingLink final : public link::Link {
 public:
  CountingLink(std::unique_ptr<link::Link> inner, std::shared_ptr<FrameLog> log)
      : inner_(std::move(inner)), log_(std::move(log)) {}

  Result<void> send(wire::Bytes frame) override { return inner_->send(frame); }
  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    auto got = inner_->receive(timeout);
    if (got && *got) {
      if (auto decoded = wire::decode_frame((*got)->frame)) {
        std::vector<CountedDatagram> datagrams;
        for (const auto& d : *decoded.frame) {
          datagrams.push_back({d.header.command, d.header.address, d.header.length, d.wkc});
        }
        log_->add(std::move(datagrams));
      }
    }
    return got;
  }
  void interrupt() override { inner_->interrupt(); }
  void close() override { inner_->close(); }
  Result<void> reopen() override { return inner_->reopen(); }
  std::string name() const override { return "counting:" + inner_->name(); }
  link::LinkStats stats() const override { return inner_->stats(); }
  std::size_t max_frame_size() const override { return inner_->max_frame_size(); }

 private:
  std::unique_ptr<link::Link> inner_;
  std::shared_ptr<FrameLog> log_;
};

}  // namespace ecat::test
