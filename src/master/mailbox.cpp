#include <algorithm>
#include <array>
#include <utility>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/mailbox.hpp>
#include <ecat/wire/coe.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

namespace {

constexpr std::uint8_t kRepeatRequestBit = 0x02;  // SM activate (offset 6) bit 1
constexpr std::uint8_t kRepeatAckBit = 0x02;      // SM PDI control (offset 7) bit 1
constexpr std::uint8_t kMailboxFullBit = 0x08;    // SM status (offset 5) bit 3

std::string ms_text(std::chrono::nanoseconds d) {
  return fmt::format("{} ms", std::chrono::duration<double, std::milli>(d).count());
}

bool is_emergency(const MailboxMessage& message) {
  if (message.header.type != wire::MailboxType::coe) return false;
  auto coe = wire::decode_coe_header(message.data);
  return coe && coe->service == wire::CoeService::emergency;
}

}  // namespace

Mailbox::Mailbox(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t station, MailboxConfig config,
                 MailboxOptions options)
    : loop_(loop),
      bus_(bus),
      station_(station),
      config_(config),
      options_(std::move(options)),
      mutex_(loop) {}

std::size_t Mailbox::max_request_data() const noexcept {
  return config_.out_size > wire::kMailboxHeaderSize ? config_.out_size - wire::kMailboxHeaderSize
                                                     : 0;
}

std::size_t Mailbox::max_reply_data() const noexcept {
  return config_.in_size > wire::kMailboxHeaderSize ? config_.in_size - wire::kMailboxHeaderSize
                                                    : 0;
}

std::string Mailbox::describe_exchange(const std::string& what) const {
  return what.empty() ? fmt::format("mailbox exchange with slave {:#06x}", station_) : what;
}

Result<void> Mailbox::check_guard(const Guard& guard, const std::string& what) const {
  if (!guard.owns(mutex_)) {
    return Error(Errc::wrong_state,
                 fmt::format("{}: the mailbox of slave {:#06x} is used without holding its lock",
                             describe_exchange(what), station_));
  }
  return ok();
}

exec::Task<Result<bus::TransactionResult>> Mailbox::transact(bus::Transaction tx) {
  co_return co_await exec::transact(loop_, bus_, std::move(tx), options_.transact);
}

void Mailbox::queue_unsolicited(MailboxMessage message) {
  ++stats_.unsolicited;
  unsolicited_.push_back(std::move(message));
  while (unsolicited_.size() > options_.max_unsolicited) {
    unsolicited_.pop_front();
    ++stats_.dropped;
  }
}

Mailbox::StatusView Mailbox::status_view() const noexcept {
  StatusView view;
  if (!status_source_ || status_source_->domain == nullptr) return view;
  const Domain& domain = *status_source_->domain;
  if (domain.state() != DomainState::cycling) return view;
  const auto period = domain.cycle_period();
  if (period > options_.status_max_period) return view;
  std::uint8_t status = 0;
  auto sample = domain.sample(status_source_->handle, wire::MutableBytes(&status, 1));
  if (!sample || !sample->freshness || sample->freshness->state != Freshness::fresh ||
      !sample->updated_at) {
    return view;
  }
  // A cycle published before the last read may still show the message that read took.
  if (*sample->updated_at > last_sm1_read_ && (status & kMailboxFullBit) != 0) {
    view.kind = StatusView::Kind::full;
    return view;
  }
  view.kind = StatusView::Kind::empty;
  // The next cycle's inputs are due a period after this one's, give or take the round trip's
  // jitter; a cycle later than that is looked for again a quarter period on.
  const auto now = exec::Clock::now();
  view.next_check = std::max(*sample->updated_at + period + period / 4, now + period / 4);
  return view;
}

void Mailbox::note_sm1_read(bool found) noexcept {
  ++stats_.sm1_reads;
  if (!found) ++stats_.empty_reads;
  last_sm1_read_ = exec::Clock::now();
}

Result<Mailbox::Arrival> Mailbox::take(wire::Bytes raw, const ReplyFilter& is_reply,
                                       MailboxMessage* reply, const std::string& what) {
  ++stats_.messages;
  auto decoded = wire::decode_mailbox(raw);
  if (!decoded) {
    return decoded.error().context(
        Errc::malformed,
        fmt::format("{}: slave {:#06x} sent a malformed mailbox ({} bytes read "
                    "from SM1 at {:#06x})",
                    describe_exchange(what), station_, raw.size(), config_.in_offset));
  }
  const std::size_t size = wire::kMailboxHeaderSize + decoded->header.length;
  const wire::Bytes bytes = raw.first(size);
  // A repeat (after a repeat request, or a read whose reply frame was lost and retried) is the same
  // message with the same counter. A new message with a repeated counter but other content is a
  // slave miscounting, not a repeat: it is kept.
  if (decoded->header.counter != 0 &&
      std::equal(bytes.begin(), bytes.end(), last_message_.begin(), last_message_.end())) {
    ++stats_.duplicates;
    return Arrival::none;
  }
  last_message_.assign(bytes.begin(), bytes.end());

  MailboxMessage message;
  message.header = decoded->header;
  message.data.assign(decoded->data.begin(), decoded->data.end());
  // The slave numbers its messages 1..7 (0: it does not count). The same counter again is
  // tolerated (a slave repeating with new content); any other jump is reported with the message.
  if (const std::uint8_t counter = decoded->header.counter; counter != 0) {
    if (reply_counter_ != 0 && counter != reply_counter_ &&
        counter != wire::next_mailbox_counter(reply_counter_)) {
      message.expected_counter = wire::next_mailbox_counter(reply_counter_);
      reply_counter_ = 0;
    } else {
      reply_counter_ = counter;
    }
  }

  if (is_emergency(message)) {
    auto emergency = wire::decode_emergency(message.data);
    if (emergency) {
      ++stats_.emergencies;
      emergencies_.push_back(*emergency);
      while (emergencies_.size() > options_.max_emergencies) {
        emergencies_.pop_front();
        ++stats_.dropped;
      }
      if (options_.on_emergency) options_.on_emergency(station_, *emergency);
      return Arrival::queued;
    }
    queue_unsolicited(std::move(message));  // a broken emergency is nobody's reply either
    return Arrival::queued;
  }
  if (reply == nullptr) {
    queue_unsolicited(std::move(message));
    return Arrival::queued;
  }
  if (message.header.type == wire::MailboxType::error) {
    ++stats_.replies;
    auto error = wire::decode_mailbox_error(message.data);
    if (!error) {
      return error.error().context(
          Errc::mailbox_error,
          fmt::format("{}: slave {:#06x} answered with a malformed mailbox error reply",
                      describe_exchange(what), station_));
    }
    return Error(Errc::mailbox_error,
                 fmt::format("{}: slave {:#06x} answered with mailbox error {:#06x}: {}",
                             describe_exchange(what), station_, error->detail,
                             wire::mailbox_error_text(error->detail)))
        .with_value(error->detail);
  }
  if (is_reply && !is_reply(message)) {
    queue_unsolicited(std::move(message));
    return Arrival::queued;
  }
  ++stats_.replies;
  *reply = std::move(message);
  return Arrival::reply;
}

exec::Task<Result<void>> Mailbox::send(const Guard& guard, wire::MailboxType type,
                                       std::vector<std::uint8_t> data,
                                       std::chrono::nanoseconds timeout, std::string what) {
  if (auto held = check_guard(guard, what); !held) co_return held.error();
  what = describe_exchange(what);
  if (data.size() > max_request_data()) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: {} bytes of mailbox data do not fit the mailbox of slave "
                                "{:#06x} (SM0 of {} bytes holds at most {})",
                                what, data.size(), station_, config_.out_size, max_request_data()));
  }
  // Whatever was read before this request cannot be its reply.
  while (!inbox_.empty()) {
    auto raw = std::move(inbox_.front());
    inbox_.pop_front();
    (void)take(raw, {}, nullptr, what);
  }

  counter_ = wire::next_mailbox_counter(counter_);
  wire::MailboxHeader header;
  header.type = type;
  header.counter = counter_;
  std::vector<std::uint8_t> buffer(config_.out_size, 0);
  if (auto encoded = wire::encode_mailbox(header, data, buffer); !encoded) {
    co_return encoded.error().context(Errc::invalid_argument,
                                      fmt::format("{}: encoding the mailbox request", what));
  }

  const auto deadline = exec::Clock::now() + timeout;
  for (;;) {
    bus::Transaction tx;
    tx.fpwr(station_, config_.out_offset, buffer);
    if (options_.read_with_request) tx.fprd(station_, config_.in_offset, config_.in_size);
    auto reply = co_await transact(std::move(tx));
    if (!reply) {
      co_return reply.error().context(
          fmt::format("{}: writing the request into the mailbox of "
                      "slave {:#06x} (SM0 at {:#06x})",
                      what, station_, config_.out_offset));
    }
    if (options_.read_with_request) note_sm1_read(reply->wkc(1) == 1);
    if (options_.read_with_request && reply->wkc(1) == 1) {
      const auto read = reply->data(1);
      inbox_.emplace_back(read.begin(), read.end());
    }
    const std::uint16_t wkc = reply->wkc(0);
    if (wkc == 1) {
      ++stats_.requests;
      co_return ok();
    }
    if (wkc != 0) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("{}: the mailbox write to slave {:#06x} came back with WKC {} "
                                  "(expected 1)",
                                  what, station_, wkc));
    }
    if (exec::Clock::now() >= deadline) {
      ++stats_.timeouts;
      co_return Error(Errc::timeout,
                      fmt::format("{}: slave {:#06x} did not take the request within {}: its "
                                  "mailbox SM0 at {:#06x} stayed full (WKC 0)",
                                  what, station_, ms_text(timeout), config_.out_offset));
    }
    ++stats_.write_retries;
    co_await exec::sleep_for(loop_, options_.poll_interval);
  }
}

exec::Task<Result<MailboxMessage>> Mailbox::receive(const Guard& guard,
                                                    std::chrono::nanoseconds timeout,
                                                    ReplyFilter is_reply, std::string what) {
  co_return co_await receive_until(guard, exec::Clock::now() + timeout, timeout,
                                   std::move(is_reply), std::move(what));
}

exec::Task<Result<MailboxMessage>> Mailbox::receive_until(const Guard& guard,
                                                          exec::Clock::time_point deadline,
                                                          std::chrono::nanoseconds timeout,
                                                          ReplyFilter is_reply, std::string what) {
  if (auto held = check_guard(guard, what); !held) co_return held.error();
  what = describe_exchange(what);
  MailboxMessage message;
  while (!inbox_.empty()) {
    auto raw = std::move(inbox_.front());
    inbox_.pop_front();
    auto arrival = take(raw, is_reply, &message, what);
    if (!arrival) co_return arrival.error();
    if (*arrival == Arrival::reply) co_return message;
  }
  for (;;) {
    const StatusView view = status_view();
    if (view.kind == StatusView::Kind::empty) {
      // Nothing in SM1 as of the last cycle: no frame, wait for the next one.
      const auto now = exec::Clock::now();
      if (now >= deadline) break;
      ++stats_.status_waits;
      co_await exec::sleep_for(loop_, std::min(view.next_check, deadline) - now);
      continue;
    }
    if (view.kind == StatusView::Kind::unknown && status_source_) ++stats_.status_fallbacks;
    bus::Transaction tx;
    tx.fprd(station_, config_.in_offset, config_.in_size);
    auto reply = co_await transact(std::move(tx));
    if (!reply) {
      co_return reply.error().context(
          fmt::format("{}: reading the mailbox of slave {:#06x} (SM1 "
                      "at {:#06x})",
                      what, station_, config_.in_offset));
    }
    const std::uint16_t wkc = reply->wkc(0);
    note_sm1_read(wkc == 1);
    if (wkc > 1) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("{}: the mailbox read from slave {:#06x} came back with WKC {} "
                                  "(expected 0 or 1)",
                                  what, station_, wkc));
    }
    if (wkc == 1) {
      auto arrival = take(reply->data(0), is_reply, &message, what);
      if (!arrival) co_return arrival.error();
      if (*arrival == Arrival::reply) co_return message;
      // SM1 may hold the next message already: read again at once (within the deadline; with
      // the mapped status, once a cycle shows it).
      if (exec::Clock::now() < deadline) continue;
      break;
    }
    if (exec::Clock::now() >= deadline) break;
    // The status said full but a cycle older than the read: the loop waits for a newer one.
    if (view.kind == StatusView::Kind::full) continue;
    co_await exec::sleep_for(loop_, options_.poll_interval);
  }

  std::string after_repeat;
  if (options_.repeat_request) {
    auto outcome = co_await repeat(is_reply, message, what);
    if (!outcome) co_return outcome.error();
    if (outcome->replied) co_return message;
    after_repeat = outcome->acknowledged
                       ? ", nor after a mailbox repeat request"
                       : ", and the slave did not acknowledge a mailbox repeat request";
  }
  ++stats_.timeouts;
  co_return Error(Errc::timeout, fmt::format("{}: no reply from slave {:#06x} within {}{}", what,
                                             station_, ms_text(timeout), after_repeat));
}

exec::Task<Result<Mailbox::RepeatOutcome>> Mailbox::repeat(const ReplyFilter& is_reply,
                                                           MailboxMessage& message,
                                                           const std::string& what) {
  ++stats_.repeat_requests;
  const auto sm = wire::reg::sync_manager(config_.in_sync_manager);
  const auto activate_at = static_cast<std::uint16_t>(sm + wire::reg::kSyncManagerActivateOffset);
  const auto pdi_at = static_cast<std::uint16_t>(sm + wire::reg::kSyncManagerPdiControlOffset);
  auto context = [&](const Error& e) {
    return e.context(fmt::format("{}: mailbox repeat request to slave {:#06x} (SM{})", what,
                                 station_, config_.in_sync_manager));
  };
  bus::Transaction read_tx;
  read_tx.fprd(station_, activate_at, 1, 1);
  auto current = co_await transact(std::move(read_tx));
  if (!current) co_return context(current.error());
  const std::uint8_t activate = static_cast<std::uint8_t>(current->data(0)[0] ^ kRepeatRequestBit);
  const bool want_ack = (activate & kRepeatRequestBit) != 0;
  bus::Transaction write_tx;
  write_tx.fpwr(station_, activate_at, wire::Bytes(&activate, 1), 1);
  auto written = co_await transact(std::move(write_tx));
  if (!written) co_return context(written.error());

  RepeatOutcome outcome;
  const auto deadline = exec::Clock::now() + options_.repeat_timeout;
  for (;;) {
    bus::Transaction tx;
    tx.fprd(station_, pdi_at, 1);
    tx.fprd(station_, config_.in_offset, config_.in_size);
    auto reply = co_await transact(std::move(tx));
    if (!reply) co_return context(reply.error());
    note_sm1_read(reply->wkc(1) == 1);
    if (reply->wkc(0) == 1 && ((reply->data(0)[0] & kRepeatAckBit) != 0) == want_ack) {
      outcome.acknowledged = true;
    }
    if (reply->wkc(1) == 1) {
      auto arrival = take(reply->data(1), is_reply, &message, what);
      if (!arrival) co_return arrival.error();
      if (*arrival == Arrival::reply) {
        outcome.replied = true;
        co_return outcome;
      }
      continue;
    }
    if (exec::Clock::now() >= deadline) co_return outcome;
    co_await exec::sleep_for(loop_, options_.poll_interval);
  }
}

exec::Task<Result<MailboxMessage>> Mailbox::exchange(const Guard& guard, wire::MailboxType type,
                                                     std::vector<std::uint8_t> data,
                                                     std::chrono::nanoseconds timeout,
                                                     ReplyFilter is_reply, std::string what) {
  // One deadline for both halves: a slave slow to take the request leaves less time to answer.
  const auto deadline = exec::Clock::now() + timeout;
  auto sent = co_await send(guard, type, std::move(data), timeout, what);
  if (!sent) co_return sent.error();
  co_return co_await receive_until(guard, deadline, timeout, std::move(is_reply), std::move(what));
}

exec::Task<Result<MailboxMessage>> Mailbox::request(wire::MailboxType type,
                                                    std::vector<std::uint8_t> data,
                                                    std::chrono::nanoseconds timeout,
                                                    ReplyFilter is_reply, std::string what) {
  auto guard = co_await lock();
  co_return co_await exchange(guard, type, std::move(data), timeout, std::move(is_reply),
                              std::move(what));
}

exec::Task<Result<std::size_t>> Mailbox::poll() {
  auto guard = co_await lock();
  std::size_t count = 0;
  const std::string what = fmt::format("polling the mailbox of slave {:#06x}", station_);
  while (!inbox_.empty()) {
    auto raw = std::move(inbox_.front());
    inbox_.pop_front();
    ++count;
    if (auto taken = take(raw, {}, nullptr, what); !taken) co_return taken.error();
  }
  // SM1 holds one message at a time; a slave with more queued refills it after each read. With
  // the mapped status, SM1 is read while a cycle after the last read shows it full (at most once
  // per cycle), and not at all while it shows it empty.
  for (int reads = 0; reads < 16; ++reads) {
    const StatusView view = status_view();
    if (view.kind == StatusView::Kind::empty) {
      ++stats_.status_waits;
      break;
    }
    if (view.kind == StatusView::Kind::unknown && status_source_) ++stats_.status_fallbacks;
    bus::Transaction tx;
    tx.fprd(station_, config_.in_offset, config_.in_size);
    auto reply = co_await transact(std::move(tx));
    if (!reply) co_return reply.error().context(what);
    note_sm1_read(reply->wkc(0) == 1);
    if (reply->wkc(0) != 1) break;
    ++count;
    if (auto taken = take(reply->data(0), {}, nullptr, what); !taken) co_return taken.error();
  }
  co_return count;
}

std::vector<wire::Emergency> Mailbox::emergencies() {
  std::vector<wire::Emergency> out(emergencies_.begin(), emergencies_.end());
  emergencies_.clear();
  return out;
}

std::vector<MailboxMessage> Mailbox::unsolicited() {
  std::vector<MailboxMessage> out(std::make_move_iterator(unsolicited_.begin()),
                                  std::make_move_iterator(unsolicited_.end()));
  unsolicited_.clear();
  return out;
}

std::optional<MailboxMessage> Mailbox::take_unsolicited(const ReplyFilter& which) {
  for (auto it = unsolicited_.begin(); it != unsolicited_.end(); ++it) {
    if (!which(*it)) continue;
    MailboxMessage out = std::move(*it);
    unsolicited_.erase(it);
    return out;
  }
  return std::nullopt;
}

void Mailbox::reset() noexcept {
  counter_ = 0;
  reply_counter_ = 0;
  last_message_.clear();
  inbox_.clear();
}

}  // namespace ecat::master
