// A scripted EtherCAT segment behind a Link, for testing the bus without real links.
//
// send() runs the frame through N simulated slaves in the caller's thread (working counters per
// command, auto-increment, station and logical addressing over a small register memory), applies
// the next scripted fault, and queues the reply for receive() at now + delay. Everything after
// construction is allocation-free unless frames are recorded (Options::record) or faults are
// scripted, so the realtime allocation test can run through it.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::bus::test {

enum class Fault : std::uint8_t {
  none,
  drop,           // no reply
  delay,          // reply after FaultRule::delay
  duplicate,      // reply twice
  corrupt,        // reply with an invalid frame type (does not decode)
  reorder,        // hold this reply and deliver it after the next one
  wrong_index,    // first datagram's index changed
  wrong_command,  // first datagram's command changed
  wrong_length,   // first datagram one byte shorter (or longer when empty), frame re-encoded
  wrong_address,  // first datagram's ADO (or logical address) + 2
  unprocessed,    // the request comes back untouched (as if no slave saw it)
};

struct FaultRule {
  Fault fault = Fault::none;
  std::chrono::nanoseconds delay{0};
  // Apply only to the next frame whose first datagram has this command (frames that do not
  // match pass through normally and leave the rule in place).
  std::optional<wire::Command> first_command;
};

class FakeSegment {
 public:
  using Clock = std::chrono::steady_clock;

  struct Options {
    std::size_t slaves = 3;
    // Station address of slave i is first_station + i (stored in register 0x0010); 0 leaves every
    // slave unassigned.
    std::uint16_t first_station = 0x1001;
    std::size_t memory_size = 0x2000;
    std::size_t max_frame_size = wire::kMaxFrameSize;
    std::chrono::nanoseconds reply_delay{0};
    bool record = true;  // keep a copy of every frame sent (allocates)
  };

  struct SentFrame {
    std::vector<std::uint8_t> bytes;
    Clock::time_point at;
    int marker = 0;  // the value of marker() when the frame was sent
  };

  struct LogicalMapping {
    std::uint32_t logical = 0;
    std::uint16_t physical = 0;
    std::uint16_t length = 0;
    bool inputs = false;   // slave -> master (LRD, LRW read)
    bool outputs = false;  // master -> slave (LWR, LRW write)
  };

  explicit FakeSegment(Options options) : options_(options), slaves_(options.slaves) {
    for (std::size_t i = 0; i < slaves_.size(); ++i) {
      slaves_[i].memory.assign(options_.memory_size, 0);
      if (options_.first_station != 0 && options_.memory_size >= 0x12) {
        wire::store_le16(&slaves_[i].memory[0x10],
                         static_cast<std::uint16_t>(options_.first_station + i));
      }
      slaves_[i].mappings.reserve(8);
    }
  }

  // ---- the segment's contents

  std::vector<std::uint8_t> read(std::size_t slave, std::uint16_t offset, std::size_t length) {
    std::lock_guard lock(mutex_);
    const auto& m = slaves_.at(slave).memory;
    return std::vector<std::uint8_t>(m.begin() + offset, m.begin() + offset + length);
  }
  void write(std::size_t slave, std::uint16_t offset, wire::Bytes data) {
    std::lock_guard lock(mutex_);
    std::copy(data.begin(), data.end(), slaves_.at(slave).memory.begin() + offset);
  }
  void map_logical(std::size_t slave, LogicalMapping mapping) {
    std::lock_guard lock(mutex_);
    slaves_.at(slave).mappings.push_back(mapping);
  }
  std::size_t slave_count() const { return slaves_.size(); }

  // ---- faults and timing

  void inject(Fault fault, std::chrono::nanoseconds delay = {},
              std::optional<wire::Command> first_command = std::nullopt) {
    std::lock_guard lock(mutex_);
    script_.push_back(FaultRule{fault, delay, first_command});
  }
  void set_reply_delay(std::chrono::nanoseconds delay) {
    std::lock_guard lock(mutex_);
    options_.reply_delay = delay;
  }
  // The next receive() that returns a frame sleeps `stall` before it returns, as a thread that
  // is descheduled between two receives under load.
  void stall_after_next_receive(std::chrono::nanoseconds stall) {
    std::lock_guard lock(mutex_);
    stall_ = stall;
  }
  // While held, replies are computed but not delivered; release delivers them in order.
  void hold(bool on) {
    std::lock_guard lock(mutex_);
    held_ = on;
    cv_.notify_all();
  }
  // Delivers arbitrary bytes as if they had arrived from the wire.
  void inject_frame(wire::Bytes bytes) {
    std::lock_guard lock(mutex_);
    enqueue(bytes, Clock::now());
  }
  // From now on send() and receive() fail as a dead link would.
  void kill(Errc code = Errc::closed) {
    std::lock_guard lock(mutex_);
    dead_ = code;
    cv_.notify_all();
  }
  // The link works again; reopen() succeeds from now on (when reopening is allowed).
  void revive() {
    std::lock_guard lock(mutex_);
    dead_.reset();
    cv_.notify_all();
  }
  // Whether the link can be reopened at all (off: reopen() answers Errc::unsupported, as
  // in-process links do).
  void allow_reopen(bool allowed) { reopen_allowed_.store(allowed); }
  // Link::reopen(): fails while the link is dead.
  Result<void> reopen() {
    reopen_calls_.fetch_add(1);
    if (!reopen_allowed_.load()) return Error(Errc::unsupported, "fake link cannot be reopened");
    std::lock_guard lock(mutex_);
    if (dead_) return Error(Errc::io_error, "fake segment: still down");
    return ok();
  }
  int reopen_calls() const { return reopen_calls_.load(); }
  void set_marker(int marker) { marker_.store(marker); }

  // ---- inspection

  std::vector<SentFrame> sent() const {
    std::lock_guard lock(mutex_);
    return log_;
  }
  std::size_t frames_sent() const {
    std::lock_guard lock(mutex_);
    return frames_sent_;
  }
  // Frames sent while a reply carrying one of their datagram indices was still undelivered.
  std::size_t index_reuse_violations() const {
    std::lock_guard lock(mutex_);
    return index_reuse_violations_;
  }
  std::size_t replies_queued() const {
    std::lock_guard lock(mutex_);
    return std::count_if(queue_.begin(), queue_.end(), [](const Slot& s) { return s.used; });
  }

  // ---- the Link side

  Result<void> send(wire::Bytes frame) {
    std::lock_guard lock(mutex_);
    if (dead_) return Error(*dead_, "fake segment: link is down");
    if (frame.size() > options_.max_frame_size) {
      return Error(Errc::invalid_argument, "fake segment: frame too large");
    }
    ++frames_sent_;
    bytes_sent_ += frame.size();
    if (options_.record)
      log_.push_back(SentFrame{{frame.begin(), frame.end()}, Clock::now(), marker_.load()});
    std::copy(frame.begin(), frame.end(), work_.begin());
    std::size_t length = frame.size();
    for_each_index(work_.data(), length, [this](std::uint8_t index) {
      if (undelivered_[index] > 0) ++index_reuse_violations_;
    });

    FaultRule rule;
    if (!script_.empty()) {
      const FaultRule& next = script_.front();
      const bool applies =
          !next.first_command ||
          (length > 2 && work_[2] == static_cast<std::uint8_t>(*next.first_command));
      if (applies) {
        rule = next;
        script_.pop_front();
      }
    }
    if (rule.fault != Fault::unprocessed) process(length);

    auto at = Clock::now() + options_.reply_delay;
    switch (rule.fault) {
      case Fault::drop:
        return ok();
      case Fault::delay:
        at = Clock::now() + rule.delay;
        break;
      case Fault::corrupt:
        work_[1] = static_cast<std::uint8_t>(work_[1] | 0xF0);
        break;
      case Fault::wrong_index:
        work_[3] = static_cast<std::uint8_t>(work_[3] ^ 0x55);
        break;
      case Fault::wrong_command:
        work_[2] = work_[2] == static_cast<std::uint8_t>(wire::Command::fprd)
                       ? static_cast<std::uint8_t>(wire::Command::fpwr)
                       : static_cast<std::uint8_t>(wire::Command::fprd);
        break;
      case Fault::wrong_address:
        wire::store_le16(&work_[6], static_cast<std::uint16_t>(wire::load_le16(&work_[6]) + 2));
        break;
      case Fault::wrong_length:
        length = reencode_first_length(length);
        break;
      default:
        break;
    }
    const wire::Bytes reply{work_.data(), length};
    if (rule.fault == Fault::reorder) {
      std::copy(reply.begin(), reply.end(), stash_.begin());
      stash_length_ = length;
      return ok();
    }
    enqueue(reply, at);
    if (rule.fault == Fault::duplicate) enqueue(reply, at);
    if (stash_length_ > 0) {
      enqueue(wire::Bytes{stash_.data(), stash_length_}, at);
      stash_length_ = 0;
    }
    return ok();
  }

  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) {
    std::unique_lock lock(mutex_);
    const auto deadline = Clock::now() + timeout;
    for (;;) {
      if (dead_) return Error(*dead_, "fake segment: link is down");
      const auto now = Clock::now();
      Slot* ready = nullptr;
      auto next_at = Clock::time_point::max();
      if (!held_) {
        for (auto& s : queue_) {
          if (!s.used) continue;
          if (s.at <= now && (!ready || s.seq < ready->seq)) ready = &s;
          next_at = std::min(next_at, s.at);
        }
      }
      if (ready) {
        std::copy(ready->bytes.begin(), ready->bytes.begin() + ready->length, rx_.begin());
        link::ReceivedFrame frame;
        frame.frame = wire::Bytes{rx_.data(), ready->length};
        frame.timestamp_ns =
            std::chrono::duration_cast<std::chrono::nanoseconds>(now.time_since_epoch()).count();
        ready->used = false;
        for_each_index(rx_.data(), ready->length, [this](std::uint8_t index) {
          if (undelivered_[index] > 0) --undelivered_[index];
        });
        ++frames_received_;
        bytes_received_ += frame.frame.size();
        if (stall_ > std::chrono::nanoseconds(0)) {
          // The receiving thread loses the processor right after it took this frame.
          const auto stall = std::exchange(stall_, std::chrono::nanoseconds(0));
          lock.unlock();
          std::this_thread::sleep_for(stall);
        }
        return std::optional<link::ReceivedFrame>(frame);
      }
      if (interrupted_) {
        interrupted_ = false;
        return std::optional<link::ReceivedFrame>();
      }
      if (now >= deadline) return std::optional<link::ReceivedFrame>();
      cv_.wait_until(lock, std::min(deadline, next_at));
    }
  }

  void interrupt() {
    std::lock_guard lock(mutex_);
    interrupted_ = true;
    cv_.notify_all();
  }

  link::LinkStats link_stats() const {
    std::lock_guard lock(mutex_);
    link::LinkStats s;
    s.frames_sent = frames_sent_;
    s.frames_received = frames_received_;
    s.bytes_sent = bytes_sent_;
    s.bytes_received = bytes_received_;
    return s;
  }

  std::size_t max_frame_size() const { return options_.max_frame_size; }

  static std::unique_ptr<link::Link> make_link(std::shared_ptr<FakeSegment> segment);

 private:
  static constexpr std::size_t kBuffer = 2 * wire::kFrameHeaderSize + wire::kMaxDatagramLength + 64;
  static constexpr std::size_t kQueueSlots = 256;

  std::chrono::nanoseconds stall_{0};
  struct Slave {
    std::vector<std::uint8_t> memory;
    std::vector<LogicalMapping> mappings;
  };
  struct Slot {
    bool used = false;
    Clock::time_point at{};
    std::uint64_t seq = 0;
    std::size_t length = 0;
    std::array<std::uint8_t, kBuffer> bytes{};
  };

  void enqueue(wire::Bytes bytes, Clock::time_point at) {
    for (auto& s : queue_) {
      if (s.used) continue;
      s.used = true;
      s.at = at;
      s.seq = next_seq_++;
      s.length = std::min(bytes.size(), s.bytes.size());
      std::copy(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(s.length),
                s.bytes.begin());
      for_each_index(s.bytes.data(), s.length,
                     [this](std::uint8_t index) { ++undelivered_[index]; });
      cv_.notify_all();
      return;
    }
    // Queue full: the reply is lost, as on a congested wire.
  }

  // Calls fn(index) for each datagram of a well-formed frame.
  template <class Fn>
  static void for_each_index(const std::uint8_t* frame, std::size_t size, Fn fn) {
    if (size < wire::kFrameHeaderSize || (frame[1] >> 4) != wire::kFrameTypeDatagrams) return;
    const std::size_t end =
        std::min(size, wire::kFrameHeaderSize + (wire::load_le16(frame) & 0x7FFu));
    std::size_t pos = wire::kFrameHeaderSize;
    while (pos + wire::kDatagramHeaderSize <= end) {
      const std::uint16_t length_field = wire::load_le16(frame + pos + 6);
      const std::size_t length = length_field & 0x7FFu;
      if (pos + wire::kDatagramOverhead + length > end) return;
      fn(frame[pos + 1]);
      pos += wire::kDatagramOverhead + length;
      if ((length_field & 0x8000u) == 0) return;
    }
  }

  // Runs every datagram of the frame in work_ through the slaves, in ring order.
  void process(std::size_t size) {
    if (size < wire::kFrameHeaderSize) return;
    const std::size_t end =
        std::min(size, wire::kFrameHeaderSize + (wire::load_le16(&work_[0]) & 0x7FFu));
    std::size_t pos = wire::kFrameHeaderSize;
    while (pos + wire::kDatagramHeaderSize <= end) {
      std::uint8_t* p = &work_[pos];
      const std::uint16_t length_field = wire::load_le16(p + 6);
      const std::size_t length = length_field & 0x7FFu;
      if (pos + wire::kDatagramOverhead + length > end) return;
      std::uint8_t* data = p + wire::kDatagramHeaderSize;
      std::uint16_t wkc = wire::load_le16(data + length);
      std::uint32_t address = wire::load_le32(p + 2);
      execute(p[0], address, data, length, wkc);
      wire::store_le32(p + 2, address);
      wire::store_le16(data + length, wkc);
      pos += wire::kDatagramOverhead + length;
      if ((length_field & 0x8000u) == 0) return;
    }
  }

  void execute(std::uint8_t command_byte, std::uint32_t& address, std::uint8_t* data,
               std::size_t length, std::uint16_t& wkc) {
    const auto command = wire::command_from_byte(command_byte);
    if (!command) return;
    using wire::Command;
    const auto addressing = wire::addressing_of(*command);
    for (auto& slave : slaves_) {
      auto adp = static_cast<std::uint16_t>(address);
      const std::uint16_t ado = static_cast<std::uint16_t>(address >> 16);
      auto& memory = slave.memory;
      const bool in_memory = static_cast<std::size_t>(ado) + length <= memory.size();
      std::uint8_t* reg = in_memory ? memory.data() + ado : nullptr;
      bool addressed = false;
      switch (addressing) {
        case wire::Addressing::position:
          addressed = adp == 0;
          ++adp;
          break;
        case wire::Addressing::station:
          addressed = memory.size() >= 0x12 && wire::load_le16(&memory[0x10]) == adp;
          break;
        case wire::Addressing::broadcast:
          addressed = true;
          ++adp;
          break;
        case wire::Addressing::logical:
          execute_logical(slave, *command, address, data, length, wkc);
          continue;
        case wire::Addressing::none:
          return;
      }
      if (addressing != wire::Addressing::station) {
        address = (address & 0xFFFF0000u) | adp;
      }
      const bool rmw = *command == Command::armw || *command == Command::frmw;
      if (!reg || (!addressed && !rmw)) continue;
      switch (*command) {
        case Command::aprd:
        case Command::fprd:
          std::copy(reg, reg + length, data);
          wkc += 1;
          break;
        case Command::brd:
          for (std::size_t i = 0; i < length; ++i)
            data[i] |= reg[i];
          wkc += 1;
          break;
        case Command::apwr:
        case Command::fpwr:
        case Command::bwr:
          std::copy(data, data + length, reg);
          wkc += 1;
          break;
        case Command::aprw:
        case Command::fprw:
          for (std::size_t i = 0; i < length; ++i)
            std::swap(data[i], reg[i]);
          wkc += 3;
          break;
        case Command::brw:
          for (std::size_t i = 0; i < length; ++i) {
            const std::uint8_t old = reg[i];
            reg[i] = data[i];
            data[i] |= old;
          }
          wkc += 3;
          break;
        case Command::armw:
        case Command::frmw:
          if (addressed) {
            std::copy(reg, reg + length, data);
          } else {
            std::copy(data, data + length, reg);
          }
          wkc += 1;
          break;
        default:
          break;
      }
    }
  }

  static void execute_logical(Slave& slave, wire::Command command, std::uint32_t logical,
                              std::uint8_t* data, std::size_t length, std::uint16_t& wkc) {
    bool read = false;
    bool wrote = false;
    for (const auto& m : slave.mappings) {
      const std::uint64_t begin = std::max<std::uint64_t>(logical, m.logical);
      const std::uint64_t end = std::min<std::uint64_t>(std::uint64_t{logical} + length,
                                                        std::uint64_t{m.logical} + m.length);
      if (begin >= end) continue;
      for (std::uint64_t la = begin; la < end; ++la) {
        std::uint8_t& d = data[la - logical];
        const std::size_t at = m.physical + (la - m.logical);
        if (at >= slave.memory.size()) continue;
        std::uint8_t& r = slave.memory[at];
        if (m.outputs && command != wire::Command::lrd) {
          r = d;
          wrote = true;
        }
        if (m.inputs && command != wire::Command::lwr) {
          d = r;
          read = true;
        }
      }
    }
    if (read) wkc += 1;
    if (wrote) wkc += command == wire::Command::lrw ? 2 : 1;
  }

  // Rewrites the frame in work_ with the first datagram's data one byte shorter (or one longer
  // when empty), keeping the frame well-formed. Returns the new size.
  std::size_t reencode_first_length(std::size_t size) {
    if (size < wire::kFrameHeaderSize + wire::kDatagramOverhead) return size;
    std::array<std::uint8_t, kBuffer> out{};
    const std::uint8_t* p = &work_[2];
    const std::uint16_t length_field = wire::load_le16(p + 6);
    const std::size_t length = length_field & 0x7FFu;
    const std::size_t new_length = length > 0 ? length - 1 : 1;
    std::copy(p, p + wire::kDatagramHeaderSize, &out[2]);
    wire::store_le16(&out[2 + 6],
                     static_cast<std::uint16_t>((length_field & ~0x7FFu) | new_length));
    std::copy(p + wire::kDatagramHeaderSize,
              p + wire::kDatagramHeaderSize + std::min(length, new_length),
              &out[2 + wire::kDatagramHeaderSize]);
    std::size_t o = 2 + wire::kDatagramHeaderSize + new_length;
    std::copy(p + wire::kDatagramHeaderSize + length, p + wire::kDatagramHeaderSize + length + 2,
              &out[o]);  // wkc
    o += 2;
    const std::size_t rest_begin = 2 + wire::kDatagramOverhead + length;
    std::copy(work_.begin() + static_cast<std::ptrdiff_t>(rest_begin),
              work_.begin() + static_cast<std::ptrdiff_t>(size),
              out.begin() + static_cast<std::ptrdiff_t>(o));
    o += size - rest_begin;
    wire::store_le16(&out[0], static_cast<std::uint16_t>(((o - 2) & 0x7FFu) |
                                                         (wire::load_le16(&work_[0]) & 0xF000u)));
    std::copy(out.begin(), out.begin() + static_cast<std::ptrdiff_t>(o), work_.begin());
    return o;
  }

  mutable std::mutex mutex_;
  std::condition_variable cv_;
  Options options_;
  std::vector<Slave> slaves_;
  std::deque<FaultRule> script_;
  std::vector<SentFrame> log_;
  std::vector<Slot> queue_ = std::vector<Slot>(kQueueSlots);
  std::array<std::uint8_t, kBuffer> work_{};
  std::array<std::uint8_t, kBuffer> rx_{};
  std::array<std::uint8_t, kBuffer> stash_{};
  std::size_t stash_length_ = 0;
  std::uint64_t next_seq_ = 0;
  bool held_ = false;
  bool interrupted_ = false;
  std::optional<Errc> dead_;
  std::atomic<bool> reopen_allowed_{false};
  std::atomic<int> reopen_calls_{0};
  std::atomic<int> marker_{0};
  std::array<int, 256> undelivered_{};
  std::size_t index_reuse_violations_ = 0;
  std::uint64_t frames_sent_ = 0;
  std::uint64_t frames_received_ = 0;
  std::uint64_t bytes_sent_ = 0;
  std::uint64_t bytes_received_ = 0;
};

class FakeLink final : public link::Link {
 public:
  explicit FakeLink(std::shared_ptr<FakeSegment> segment) : segment_(std::move(segment)) {}
  Result<void> send(wire::Bytes frame) override {
    if (closed_.load()) return Error(Errc::closed, "fake link closed");
    return segment_->send(frame);
  }
  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    if (closed_.load()) return Error(Errc::closed, "fake link closed");
    return segment_->receive(timeout);
  }
  void interrupt() override { segment_->interrupt(); }
  void close() override { closed_.store(true); }
  Result<void> reopen() override {
    if (closed_.load()) return Error(Errc::closed, "fake link closed");
    return segment_->reopen();
  }
  std::string name() const override { return "fake:segment"; }
  link::LinkStats stats() const override { return segment_->link_stats(); }
  std::size_t max_frame_size() const override { return segment_->max_frame_size(); }

 private:
  std::shared_ptr<FakeSegment> segment_;
  std::atomic<bool> closed_{false};
};

inline std::unique_ptr<link::Link> FakeSegment::make_link(std::shared_ptr<FakeSegment> segment) {
  return std::make_unique<FakeLink>(std::move(segment));
}

// Decoded view of a recorded frame's datagrams (for assertions).
struct SentDatagram {
  wire::Command command;
  std::uint8_t index;
  std::uint32_t address;
  std::uint16_t length;
};
inline std::vector<SentDatagram> datagrams_of(const std::vector<std::uint8_t>& frame) {
  std::vector<SentDatagram> out;
  const auto decoded = wire::decode_frame(frame);
  if (!decoded) return out;
  for (const auto d : *decoded.frame) {
    out.push_back({d.header.command, d.header.index, d.header.address, d.header.length});
  }
  return out;
}

}  // namespace ecat::bus::test
