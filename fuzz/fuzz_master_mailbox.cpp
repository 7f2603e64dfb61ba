// The master's stateful mailbox clients fed what a slave might put into its SM1: the Mailbox
// (counters, repeats, emergencies, the unsolicited queue), the FoE client (packet numbers, BUSY,
// errors), the SoE client (fragmented reads, error responses, notifications) and the EoE client
// (fragment reassembly, Set IP Parameter). A slave of our own on a fake link answers the master's
// datagrams: every read of SM1 takes the next scripted message, so the client's state carries
// from one message to the next; once the script is spent, SM1 holds one mailbox error (which ends
// an exchange still waiting at once) and then stays empty.
//
// Input: byte 0 chooses the operation (below), byte 1 the mailbox size and the transfer size,
// then messages, each a 2-byte little-endian length and that many bytes: the SM1 contents, mailbox
// header included (fuzz/seeds/master_mailbox is written by tests/master/mailbox_fuzz_seeds_test.cpp
// in this framing).
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/link/link.hpp>
#include <ecat/master/eoe.hpp>
#include <ecat/master/foe.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/master/soe.hpp>
#include <ecat/wire/frame.hpp>
#include <ecat/wire/mailbox.hpp>

namespace {

using namespace ecat;
using namespace std::chrono_literals;

constexpr std::uint16_t kStation = 0x1001;
constexpr std::uint16_t kOut = 0x1000;
constexpr std::uint16_t kIn = 0x1800;

void require(bool condition) {
  if (!condition) std::abort();
}

// The slave: takes every SM0 write, answers every SM1 read with the next scripted message.
class ScriptedSlaveLink final : public link::Link {
 public:
  void script(std::deque<std::vector<std::uint8_t>> messages) {
    std::lock_guard lock(mutex_);
    script_ = std::move(messages);
    spent_counter_ = 0;
    spent_ = false;
  }
  // The script and the mailbox error after it were read.
  bool spent() {
    std::lock_guard lock(mutex_);
    return spent_;
  }

  Result<void> send(wire::Bytes frame) override {
    std::lock_guard lock(mutex_);
    if (closed_) return Error(Errc::closed, "fuzz link closed");
    std::vector<std::uint8_t> bytes(frame.begin(), frame.end());
    auto view = wire::decode_frame(bytes);
    require(view.frame.has_value());  // the master never sends a frame that does not decode
    for (const auto& d : *view.frame) {
      const auto at = static_cast<std::size_t>(d.data.data() - bytes.data());
      std::uint8_t* data = bytes.data() + at;
      std::uint16_t wkc = d.wkc;
      if (d.header.command == wire::Command::fprd && d.header.adp() == kStation &&
          d.header.ado() == kIn) {
        if (!script_.empty()) {
          wkc = static_cast<std::uint16_t>(wkc + 1);
          std::fill(data, data + d.data.size(), 0);
          const auto& m = script_.front();
          std::copy_n(m.begin(), std::min(m.size(), d.data.size()), data);
          script_.pop_front();
        } else if (!spent_) {
          spent_ = true;
          wkc = static_cast<std::uint16_t>(wkc + 1);
          std::fill(data, data + d.data.size(), 0);
          // Mailbox error 0x0001 (syntax), a new counter each time so it is never a repeat.
          spent_counter_ = static_cast<std::uint8_t>(spent_counter_ % 7 + 1);
          const std::uint8_t error[] = {
              4, 0, 0, 0, 0, static_cast<std::uint8_t>(spent_counter_ << 4), 1, 0, 1, 0};
          std::copy_n(error, std::min(sizeof error, d.data.size()), data);
        }
      } else if (d.header.adp() == kStation) {
        wkc = static_cast<std::uint16_t>(wkc + 1);  // SM0 writes, status reads: taken
      }
      bytes[at + d.data.size()] = static_cast<std::uint8_t>(wkc);
      bytes[at + d.data.size() + 1] = static_cast<std::uint8_t>(wkc >> 8);
    }
    inbox_.push_back(std::move(bytes));
    ready_.notify_all();
    return {};
  }

  Result<std::optional<link::ReceivedFrame>> receive(std::chrono::nanoseconds timeout) override {
    std::unique_lock lock(mutex_);
    ready_.wait_for(lock, timeout, [&] { return !inbox_.empty() || interrupted_ || closed_; });
    if (closed_) return Error(Errc::closed, "fuzz link closed");
    if (inbox_.empty()) {
      interrupted_ = false;
      return std::optional<link::ReceivedFrame>{};
    }
    current_ = std::move(inbox_.front());
    inbox_.pop_front();
    link::ReceivedFrame frame;
    frame.frame = current_;
    frame.timestamp_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                             std::chrono::steady_clock::now().time_since_epoch())
                             .count();
    return std::optional<link::ReceivedFrame>{frame};
  }

  void interrupt() override {
    std::lock_guard lock(mutex_);
    interrupted_ = true;
    ready_.notify_all();
  }
  void close() override {
    std::lock_guard lock(mutex_);
    closed_ = true;
    ready_.notify_all();
  }
  std::string name() const override { return "fuzz"; }
  link::LinkStats stats() const override { return {}; }

 private:
  std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<std::vector<std::uint8_t>> script_;
  std::deque<std::vector<std::uint8_t>> inbox_;
  std::vector<std::uint8_t> current_;
  std::uint8_t spent_counter_ = 0;
  bool spent_ = false;
  bool interrupted_ = false;
  bool closed_ = false;
};

struct Bench {
  ScriptedSlaveLink* link = nullptr;
  std::unique_ptr<bus::Bus> bus;
  exec::EventLoop loop;

  Bench() {
    auto owned = std::make_unique<ScriptedSlaveLink>();
    link = owned.get();
    bus = std::make_unique<bus::Bus>(std::move(owned));
    require(bus->start().ok());
  }

  template <class T>
  T run(exec::Task<T> task) {
    std::optional<T> result;
    exec::spawn(loop, std::move(task), [&](T&& value) {
      result.emplace(std::move(value));
      loop.stop();
    });
    const auto watchdog = loop.call_after(20s, [this] { loop.stop(); });
    loop.run();
    loop.cancel(watchdog);
    loop.reset();
    require(result.has_value());  // a client that hangs on a finite script is a bug
    return std::move(*result);
  }
};

Bench& bench() {
  static Bench instance;
  return instance;
}

std::vector<std::uint8_t> pattern(std::size_t n) {
  std::vector<std::uint8_t> out(n);
  for (std::size_t i = 0; i < n; ++i)
    out[i] = static_cast<std::uint8_t>(i * 7);
  return out;
}

exec::Task<Result<void>> eoe_session(master::Mailbox& mailbox, ScriptedSlaveLink& link,
                                     bool set_ip) {
  master::EoeClient client;
  if (set_ip) {
    wire::EoeIpParameters parameters;
    parameters.ip = 0xC0A80102;
    auto done = co_await client.set_ip(mailbox, parameters, 10ms);
    (void)done;
  }
  // Frames until the script is spent, and once more for what the last poll queued.
  for (bool last = false; !last;) {
    last = link.spent();
    auto frames = co_await client.receive(mailbox, 1ms);
    if (!frames) continue;
    for (const auto& frame : *frames)
      require(frame.size() >= master::kEoeMinFrameSize && frame.size() <= master::kEoeMaxFrameSize);
  }
  const auto& stats = client.stats();
  require(stats.frames_received <= stats.fragments_received);
  co_return ok();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const std::uint8_t operation = data[0];
  const std::uint8_t shape = data[1];
  std::deque<std::vector<std::uint8_t>> script;
  for (std::size_t at = 2; at + 2 <= size && script.size() < 512;) {
    std::size_t length = static_cast<std::size_t>(data[at] | (data[at + 1] << 8));
    at += 2;
    length = std::min(length, size - at);
    script.emplace_back(data + at, data + at + length);
    at += length;
  }
  auto& b = bench();
  b.link->script(std::move(script));

  // Mailboxes of 32 .. 1024 bytes: small ones fragment everything.
  const std::uint16_t mailbox_size = static_cast<std::uint16_t>(32u << (shape % 6));
  master::MailboxConfig config{kOut, mailbox_size, kIn, mailbox_size, 1};
  master::MailboxOptions options;
  options.poll_interval = 0ns;
  options.repeat_request = false;
  options.max_emergencies = 8;
  options.max_unsolicited = 8;
  master::Mailbox mailbox(b.loop, *b.bus, kStation, config, options);
  const std::size_t transfer = static_cast<std::size_t>(shape >> 3) * 97;

  switch (operation % 6) {
    case 0: {
      master::FoeOptions foe;
      foe.timeout = 10ms;
      foe.busy_interval = 0ns;
      foe.max_read_size = 64 * 1024;
      auto file = b.run(master::foe_read(mailbox, "file.bin", foe));
      if (file) require(file->size() <= foe.max_read_size);
      break;
    }
    case 1: {
      master::FoeOptions foe;
      foe.timeout = 10ms;
      foe.busy_interval = 0ns;
      foe.password = 0x1234;
      (void)b.run(master::foe_write(mailbox, "firmware.efw", pattern(transfer), foe));
      break;
    }
    case 2: {
      master::SoeOptions soe;
      soe.timeout = 10ms;
      soe.max_size = 16 * 1024;
      auto value = b.run(master::soe_read(mailbox, operation >> 5, 0x0011, 0x40, soe));
      if (value) require(value->size() <= soe.max_size);
      break;
    }
    case 3: {
      master::SoeOptions soe;
      soe.timeout = 10ms;
      (void)b.run(master::soe_write(mailbox, operation >> 5, 0x8001, 0x40, pattern(transfer), soe));
      break;
    }
    case 4:
    case 5:
      (void)b.run(eoe_session(mailbox, *b.link, operation % 6 == 5));
      break;
  }
  // What the slave sent on its own: SoE notifications, emergencies, the rest.
  (void)master::soe_notifications(mailbox);
  require(mailbox.emergencies().size() <= options.max_emergencies);
  require(mailbox.unsolicited().size() <= options.max_unsolicited);
  return 0;
}
