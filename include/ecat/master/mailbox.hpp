// One slave's mailbox, used by tasks on the control thread: requests go into the slave's
// master->slave mailbox SyncManager (SM0), replies come out of its slave->master one (SM1).
//
// Sending writes the whole SM0 area with one FPWR (the 6-byte header, the data, zero padding).
// A working counter of 0 means the slave has not taken the previous request yet: the write is
// repeated (same counter) until it is accepted or the timeout passes. Receiving reads the whole
// SM1 area with one FPRD: the ESC only lets it through (WKC 1) while SM1 holds a message, so the
// read doubles as the poll. By default the first read rides in the request's frame, which saves a
// round trip with slaves that answer at once.
//
// Counters: requests carry 1..7, wrapping 7 -> 1 (wire::next_mailbox_counter). Replies are not
// matched against the request's counter (real slaves count their own messages), but a message
// identical to the previous one with the same counter is a repeat (after a lost read or a repeat
// request) and is dropped.
//
// What arrives: a mailbox error (type 0) fails the exchange with Errc::mailbox_error. CoE
// emergencies are never a reply: they are queued (emergencies()) and passed to the optional
// callback. Any other message is offered to the exchange's ReplyFilter; one it does not claim
// (a late reply to an earlier request, another protocol's traffic) is queued (unsolicited()).
//
// Mailbox status in the cyclic frame: with a status source (set_status_source: SM1's status byte
// mapped by an FMMU into a cycling domain, Domain::register_sm_status), receive() and poll() read
// SM1 only when a cycle published after the last SM1 read shows "mailbox full" (bit 3); while it
// shows SM1 empty they sleep until the domain's next cycle is due, sending nothing. They poll as
// above whenever the status cannot be trusted: the domain not cycling, its inputs not fresh (an
// invalid or stale cycle), or its period above MailboxOptions::status_max_period.
//
// Lost replies: when no reply comes within the timeout and MailboxOptions::repeat_request is set,
// the master toggles SM1's repeat request (0x080E bit 1); the slave copies its last reply into SM1
// again and acknowledges (0x080F bit 1). Only then does the exchange give up.
//
// Exchanges are serialized per mailbox: lock() returns a guard, and send / receive / exchange take
// it, so a multi-step transfer (a segmented SDO) holds the mailbox from its first to its last
// message. request() is lock + exchange for single-message protocols.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/async_mutex.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/master/config.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/emergency.hpp>
#include <ecat/wire/mailbox.hpp>

namespace ecat::master {

// Where the slave's mailbox SyncManagers are (the SII's standard mailbox).
struct MailboxConfig {
  std::uint16_t out_offset = 0;  // master -> slave (SM0)
  std::uint16_t out_size = 0;
  std::uint16_t in_offset = 0;  // slave -> master (SM1)
  std::uint16_t in_size = 0;
  // The SyncManager of the slave -> master mailbox (its repeat request bits).
  std::uint8_t in_sync_manager = 1;

  friend bool operator==(const MailboxConfig&, const MailboxConfig&) = default;
};

// A message as read from SM1: its header and data (exactly header.length bytes).
struct MailboxMessage {
  wire::MailboxHeader header{};
  std::vector<std::uint8_t> data;
  // Set when the message's counter breaks the slave's own sequence (neither the counter of the
  // slave's previous message nor the one after it): the counter the sequence called for. A
  // message was lost or the slave miscounts; the mailbox follows the slave again from the next
  // message on. Never set for the first message after reset() (nothing to compare with).
  std::optional<std::uint8_t> expected_counter;
};

class Domain;

// Where a cycling domain shows SM1's status byte (Domain::register_sm_status). The domain must
// outlive the mailbox's use of it (the session's domains outlive its slaves' mailboxes).
struct MailboxStatusSource {
  const Domain* domain = nullptr;
  PdoHandle handle{};
};

struct MailboxOptions {
  // Pause between two reads of an empty SM1 (and between writes into a full SM0). Zero polls back
  // to back.
  std::chrono::nanoseconds poll_interval = std::chrono::microseconds(200);
  // Read SM1 in the same frame as the request.
  bool read_with_request = true;
  // Recover a lost reply with SM1's repeat request before a timeout is reported.
  bool repeat_request = true;
  // The mapped status (set_status_source) is used while its domain cycles at least this often;
  // with a slower domain waiting a cycle per message costs more time than polling costs frames.
  std::chrono::nanoseconds status_max_period = std::chrono::milliseconds(10);
  // How long to wait for the repeated reply (on top of the exchange's timeout).
  std::chrono::nanoseconds repeat_timeout = std::chrono::milliseconds(100);
  // Bounds of the queues of messages nobody waited for; the oldest are dropped beyond them.
  std::size_t max_emergencies = 64;
  std::size_t max_unsolicited = 64;
  // Called on the loop thread for every emergency received (after it was queued).
  std::function<void(std::uint16_t station, const wire::Emergency&)> on_emergency{};
  // For every bus transaction. A frame lost on the way back is retried: the slave recognises a
  // repeated request by its counter, and a repeated read finds SM1 empty (WKC 0).
  bus::TransactOptions transact{std::chrono::milliseconds(200), 2};
};

struct MailboxStats {
  std::uint64_t requests = 0;          // messages written into SM0
  std::uint64_t write_retries = 0;     // writes refused because SM0 was still full
  std::uint64_t messages = 0;          // messages read from SM1 (duplicates included)
  std::uint64_t replies = 0;           // ... that were the reply to an exchange
  std::uint64_t duplicates = 0;        // repeated messages dropped
  std::uint64_t emergencies = 0;       // CoE emergencies received
  std::uint64_t unsolicited = 0;       // other messages nobody waited for
  std::uint64_t dropped = 0;           // queued messages dropped at a queue's bound
  std::uint64_t repeat_requests = 0;   // SM1 repeat requests issued
  std::uint64_t timeouts = 0;          // exchanges that got no reply
  std::uint64_t sm1_reads = 0;         // reads of SM1 (in a request's frame, waiting, polling)
  std::uint64_t empty_reads = 0;       // ... that found it empty (WKC 0)
  std::uint64_t status_waits = 0;      // sleeps until a cycle while the mapped status said empty
  std::uint64_t status_fallbacks = 0;  // SM1 polls made because the mapped status was not usable
};

class Mailbox {
 public:
  // Decides whether a message is the reply being waited for (true) or someone else's (false: it is
  // queued as unsolicited). Mailbox errors and emergencies never reach it.
  using ReplyFilter = std::function<bool(const MailboxMessage&)>;
  using Guard = exec::AsyncMutex::Guard;

  // `loop` and `bus` must outlive the mailbox; the mailbox must outlive its exchanges.
  Mailbox(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station, MailboxConfig config,
          MailboxOptions options = {});
  Mailbox(const Mailbox&) = delete;
  Mailbox& operator=(const Mailbox&) = delete;

  std::uint16_t station() const noexcept { return station_; }
  const MailboxConfig& config() const noexcept { return config_; }
  const MailboxOptions& options() const noexcept { return options_; }
  exec::EventLoop& loop() noexcept { return loop_; }
  // The most data one request can carry (out_size minus the mailbox header).
  std::size_t max_request_data() const noexcept;
  std::size_t max_reply_data() const noexcept;

  // Exclusive use of the mailbox until the guard goes.
  [[nodiscard]] exec::AsyncMutex::LockAwaiter lock() noexcept { return mutex_.lock(); }

  // Writes one message into SM0 (next counter), retrying while SM0 is full until `timeout`.
  // `what` names the request in errors ("SDO upload 0x6041:00"). Messages read in the same frame
  // are kept for receive().
  exec::Task<Result<void>> send(const Guard& guard, wire::MailboxType type,
                                std::vector<std::uint8_t> data, std::chrono::nanoseconds timeout,
                                std::string what);
  // Waits for the reply (see ReplyFilter) until `timeout`, then tries the repeat request.
  exec::Task<Result<MailboxMessage>> receive(const Guard& guard, std::chrono::nanoseconds timeout,
                                             ReplyFilter is_reply, std::string what);
  // send + receive.
  exec::Task<Result<MailboxMessage>> exchange(const Guard& guard, wire::MailboxType type,
                                              std::vector<std::uint8_t> data,
                                              std::chrono::nanoseconds timeout,
                                              ReplyFilter is_reply, std::string what);
  // lock + exchange.
  exec::Task<Result<MailboxMessage>> request(wire::MailboxType type, std::vector<std::uint8_t> data,
                                             std::chrono::nanoseconds timeout,
                                             ReplyFilter is_reply = {}, std::string what = {});

  // Reads SM1 once, if it holds a message, and queues what came (emergencies, unsolicited).
  // Returns how many messages were read. Takes the lock (waits for a running exchange).
  exec::Task<Result<std::size_t>> poll();

  // The emergencies received since the last call, oldest first; the queue is emptied.
  std::vector<wire::Emergency> emergencies();
  // The messages nobody waited for, oldest first; the queue is emptied.
  std::vector<MailboxMessage> unsolicited();
  // The oldest queued message `which` accepts, taken out of the queue; the others stay (a
  // protocol client takes its own messages without losing other protocols' ones).
  std::optional<MailboxMessage> take_unsolicited(const ReplyFilter& which);

  // Forgets counters and received messages: after the slave's mailbox SyncManagers were
  // reconfigured (the slave starts counting again).
  void reset() noexcept;

  const MailboxStats& stats() const noexcept { return stats_; }

  // Waits on the mapped SM1 status from now on (nullopt: polls again). Loop thread.
  void set_status_source(std::optional<MailboxStatusSource> source) noexcept {
    status_source_ = source;
  }
  const std::optional<MailboxStatusSource>& status_source() const noexcept {
    return status_source_;
  }

 private:
  // What the mapped status says about SM1 now: `unknown` (no source, or it cannot be trusted:
  // poll), `empty` (no message as of a cycle after the last read: sleep until `next_check`) or
  // `full` (read it).
  struct StatusView {
    enum class Kind : std::uint8_t { unknown, empty, full };
    Kind kind = Kind::unknown;
    exec::Clock::time_point next_check{};
  };
  StatusView status_view() const noexcept;
  void note_sm1_read(bool found) noexcept;

  enum class Arrival : std::uint8_t { none, queued, reply };

  Result<void> check_guard(const Guard& guard, const std::string& what) const;
  // receive() with an absolute deadline; `timeout` is what error messages report.
  exec::Task<Result<MailboxMessage>> receive_until(const Guard& guard,
                                                   exec::Clock::time_point deadline,
                                                   std::chrono::nanoseconds timeout,
                                                   ReplyFilter is_reply, std::string what);
  // Takes one SM1 read: decodes and sorts the message. A reply goes to `reply`.
  Result<Arrival> take(wire::Bytes raw, const ReplyFilter& is_reply, MailboxMessage* reply,
                       const std::string& what);
  exec::Task<Result<bus::TransactionResult>> transact(bus::Transaction tx);
  struct RepeatOutcome {
    bool replied = false;
    bool acknowledged = false;
  };
  exec::Task<Result<RepeatOutcome>> repeat(const ReplyFilter& is_reply, MailboxMessage& reply,
                                           const std::string& what);
  void queue_unsolicited(MailboxMessage message);
  std::string describe_exchange(const std::string& what) const;

  exec::EventLoop& loop_;
  bus::Bus& bus_;
  std::uint16_t station_;
  MailboxConfig config_;
  MailboxOptions options_;
  exec::AsyncMutex mutex_;
  std::uint8_t counter_ = 0;
  // The counter of the slave's last message (0: not known yet, or lost after a break).
  std::uint8_t reply_counter_ = 0;
  // The last message read (header + data), to recognise a repeat of it.
  std::vector<std::uint8_t> last_message_;
  // Messages read in a send's frame, not yet looked at.
  std::deque<std::vector<std::uint8_t>> inbox_;
  std::deque<wire::Emergency> emergencies_;
  std::deque<MailboxMessage> unsolicited_;
  MailboxStats stats_;
  std::optional<MailboxStatusSource> status_source_;
  // When the last SM1 read completed: a status published before it may show a message already
  // read.
  exec::Clock::time_point last_sm1_read_{};
};

}  // namespace ecat::master
