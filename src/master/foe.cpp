#include <algorithm>
#include <string>
#include <utility>
#include <variant>

#include <fmt/format.h>

#include <ecat/master/foe.hpp>
#include <ecat/wire/foe.hpp>

namespace ecat::master {

namespace {

// The value of the outer error of an FoE ERROR from the slave; its cause holds the code. A tag
// rather than the code itself, so that foe_error_code() never mistakes another error's value
// (a mailbox error detail, an SDO failure) for an FoE code.
constexpr std::uint32_t kFoeSlaveErrorTag = 0x0002'0000;

// How a slave's FoE error code reads to callers that branch on Errc.
Errc errc_for(std::uint32_t code) {
  switch (static_cast<wire::FoeErrorCode>(code)) {
    case wire::FoeErrorCode::not_found:
      return Errc::not_found;
    case wire::FoeErrorCode::access_denied:
    case wire::FoeErrorCode::no_user:
    case wire::FoeErrorCode::no_rights:
      return Errc::permission_denied;
    case wire::FoeErrorCode::disk_full:
      return Errc::out_of_range;
    case wire::FoeErrorCode::bootstrap_only:
    case wire::FoeErrorCode::not_in_bootstrap:
      return Errc::wrong_state;
    default:
      return Errc::mailbox_error;
  }
}

// Names are quoted as given; a name with control characters is shown escaped.
std::string quoted(std::string_view name) {
  std::string out = "'";
  for (const char c : name) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7F) {
      out += fmt::format("\\x{:02x}", u);
    } else {
      out += c;
    }
  }
  out += '\'';
  return out;
}

// FoE replies and whatever else is not recognisably someone else's traffic: CoE (late SDO
// replies; emergencies never get here) and EoE (the slave's network stack) are queued as
// unsolicited, everything else is taken and checked, so that a slave answering with the wrong
// protocol fails the transfer at once instead of timing it out.
bool foe_filter(const MailboxMessage& message) {
  return message.header.type != wire::MailboxType::coe &&
         message.header.type != wire::MailboxType::eoe;
}

class Transfer {
 public:
  Transfer(Mailbox& mailbox, const Mailbox::Guard& guard, std::string what,
           const FoeOptions& options)
      : mailbox_(mailbox), guard_(guard), what_(std::move(what)), options_(options) {}

  const std::string& what() const noexcept { return what_; }

  // Sends `packet` and returns the slave's reply. BUSY sends the packet again (bounded by
  // busy_timeout); an FoE ERROR becomes the slave's error; a reply that is not FoE or does not
  // decode fails the transfer.
  exec::Task<Result<wire::FoeMessage>> exchange(wire::FoeMessage packet, std::string step) {
    auto data = wire::encode_foe(packet);
    if (!data) co_return data.error().context(Errc::invalid_argument, what_);
    std::optional<exec::Clock::time_point> busy_since;
    for (;;) {
      auto reply = co_await mailbox_.exchange(guard_, wire::MailboxType::foe, *data,
                                              options_.timeout, foe_filter, what_ + ": " + step);
      if (!reply) {
        // The slave may still be inside the transfer: tell it to give up (best effort).
        if (reply.error().code() == Errc::timeout) {
          co_await tell_slave(wire::FoeErrorCode::not_defined, "no reply, transfer abandoned");
        }
        co_return reply.error();
      }
      if (reply->header.type != wire::MailboxType::foe) {
        co_return co_await violation(
            Errc::mailbox_error,
            fmt::format("the slave answered the {} with a {} mailbox (type {}) instead of FoE",
                        step, wire::to_string(reply->header.type),
                        static_cast<unsigned>(reply->header.type)),
            wire::FoeErrorCode::illegal);
      }
      auto message = wire::decode_foe(reply->data);
      if (!message) {
        co_await tell_slave(wire::FoeErrorCode::illegal, "malformed FoE reply");
        co_return message.error().context(
            Errc::malformed,
            fmt::format("{}: the slave's reply to the {} does not decode", what_, step));
      }
      if (const auto* busy = std::get_if<wire::FoeBusy>(&*message)) {
        const auto now = exec::Clock::now();
        if (!busy_since) busy_since = now;
        ++busy_replies_;
        if (now - *busy_since >= options_.busy_timeout) {
          co_return co_await violation(
              Errc::timeout,
              fmt::format(
                  "the slave answered the {} with BUSY for {} ms (progress {}/{}), longer "
                  "than FoeOptions::busy_timeout",
                  step,
                  std::chrono::duration_cast<std::chrono::milliseconds>(now - *busy_since).count(),
                  busy->done, busy->entire),
              wire::FoeErrorCode::not_defined);
        }
        co_await exec::sleep_for(mailbox_.loop(), options_.busy_interval);
        continue;
      }
      if (const auto* error = std::get_if<wire::FoeError>(&*message)) {
        co_return slave_error(*error);
      }
      co_return std::move(*message);
    }
  }

  // Sends `packet` without waiting for a reply (the last ACK of a read).
  exec::Task<Result<void>> send(wire::FoeMessage packet, std::string step) {
    auto data = wire::encode_foe(packet);
    if (!data) co_return data.error().context(Errc::invalid_argument, what_);
    co_return co_await mailbox_.send(guard_, wire::MailboxType::foe, std::move(*data),
                                     options_.timeout, what_ + ": " + step);
  }

  // A protocol violation by the slave (or our own limit): the slave is told with an FoE ERROR so
  // that it drops the transfer too.
  exec::Task<Error> violation(Errc code, std::string problem, wire::FoeErrorCode tell) {
    co_await tell_slave(tell, problem);
    co_return Error(code, fmt::format("{}: {}", what_, problem));
  }

  // A write's reply must be the ACK of the packet just sent (0 for the write request).
  exec::Task<Result<void>> expect_ack(const Result<wire::FoeMessage>& reply, std::uint32_t number,
                                      std::string step) {
    if (!reply) co_return reply.error();
    const auto* ack = std::get_if<wire::FoeAck>(&*reply);
    if (ack == nullptr) {
      co_return co_await violation(
          Errc::mailbox_error,
          fmt::format("the slave answered the {} with {} instead of ACK {}", step,
                      wire::to_string(wire::opcode_of(*reply)), number),
          wire::FoeErrorCode::illegal);
    }
    if (ack->packet_number != number) {
      co_return co_await violation(
          Errc::mailbox_error,
          fmt::format("the slave answered the {} with ACK {}, expected ACK {}", step,
                      ack->packet_number, number),
          wire::FoeErrorCode::packet_number_wrong);
    }
    co_return ok();
  }

  std::uint64_t busy_replies() const noexcept { return busy_replies_; }

 private:
  Error slave_error(const wire::FoeError& error) const {
    const Errc code = errc_for(error.code);
    std::string detail =
        fmt::format("error 0x{:04X} {}", error.code, wire::foe_error_text(error.code));
    if (!error.text.empty()) detail += ": " + error.text;
    return Error(code, std::move(detail))
        .with_value(error.code)
        .context(code, what_)
        .with_value(kFoeSlaveErrorTag);
  }

  exec::Task<void> tell_slave(wire::FoeErrorCode code, std::string text) {
    // The text is the slave's to show; keep it short and free of NULs.
    std::string short_text = text.substr(0, 64);
    std::replace(short_text.begin(), short_text.end(), '\0', ' ');
    auto data = wire::encode_foe(wire::FoeError{static_cast<std::uint32_t>(code), short_text});
    if (!data) co_return;
    if (data->size() > mailbox_.max_request_data()) data->resize(mailbox_.max_request_data());
    (void)co_await mailbox_.send(guard_, wire::MailboxType::foe, std::move(*data), options_.timeout,
                                 what_ + ": aborting the transfer");
  }

  Mailbox& mailbox_;
  const Mailbox::Guard& guard_;
  std::string what_;
  const FoeOptions& options_;
  std::uint64_t busy_replies_ = 0;
};

std::string opcode_name(const wire::FoeMessage& message) {
  return std::string(wire::to_string(wire::opcode_of(message)));
}

}  // namespace

std::size_t foe_write_packet_size(const Mailbox& mailbox) noexcept {
  const std::size_t room = mailbox.max_request_data();
  return room > wire::kFoeHeaderSize ? room - wire::kFoeHeaderSize : 0;
}

std::size_t foe_read_packet_size(const Mailbox& mailbox) noexcept {
  const std::size_t room = mailbox.max_reply_data();
  return room > wire::kFoeHeaderSize ? room - wire::kFoeHeaderSize : 0;
}

std::optional<std::uint32_t> foe_error_code(const Error& error) noexcept {
  for (const Error* e = &error; e != nullptr; e = e->cause()) {
    if (e->value() == kFoeSlaveErrorTag && e->cause() != nullptr && e->cause()->value()) {
      return e->cause()->value();
    }
  }
  return std::nullopt;
}

exec::Task<Result<std::vector<std::uint8_t>>> foe_read(Mailbox& mailbox, std::string_view file_name,
                                                       FoeOptions options) {
  const std::string what =
      fmt::format("FoE read of {} from slave {:#06x}", quoted(file_name), mailbox.station());
  const std::size_t packet_size = foe_read_packet_size(mailbox);
  if (packet_size == 0) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: the slave's mailbox ({} bytes) has no room for FoE data", what,
                                mailbox.config().in_size));
  }
  auto guard = co_await mailbox.lock();
  Transfer transfer(mailbox, guard, what, options);
  std::vector<std::uint8_t> file;
  // Packets are named locals: a temporary inside a co_await expression is not safe with GCC 12.
  wire::FoeMessage request = wire::FoeReadRequest{options.password, std::string(file_name)};
  auto reply = co_await transfer.exchange(std::move(request), "read request");
  for (std::uint32_t expected = 1;; ++expected) {
    if (!reply) co_return reply.error();
    const auto* data = std::get_if<wire::FoeData>(&*reply);
    const std::string step =
        expected == 1 ? std::string("read request") : fmt::format("ACK of packet {}", expected - 1);
    if (data == nullptr) {
      co_return co_await transfer.violation(
          Errc::mailbox_error,
          fmt::format("the slave answered the {} with {} instead of DATA packet {}", step,
                      opcode_name(*reply), expected),
          wire::FoeErrorCode::illegal);
    }
    if (data->packet_number != expected) {
      co_return co_await transfer.violation(
          Errc::mailbox_error,
          fmt::format("the slave answered the {} with DATA packet {}, expected packet {}", step,
                      data->packet_number, expected),
          wire::FoeErrorCode::packet_number_wrong);
    }
    if (data->data.size() > options.max_read_size - std::min(file.size(), options.max_read_size)) {
      co_return co_await transfer.violation(
          Errc::out_of_range,
          fmt::format("the file grows beyond FoeOptions::max_read_size ({} bytes) with packet {}",
                      options.max_read_size, expected),
          wire::FoeErrorCode::disk_full);
    }
    file.insert(file.end(), data->data.begin(), data->data.end());
    // A packet shorter than the slave's mailbox allows is the last one; it is acknowledged too.
    const bool last = data->data.size() < packet_size;
    if (last) {
      wire::FoeMessage last_ack = wire::FoeAck{expected};
      auto acked =
          co_await transfer.send(std::move(last_ack), fmt::format("ACK of packet {}", expected));
      if (!acked) co_return acked.error();
      if (options.progress) options.progress(file.size(), file.size());
      co_return file;
    }
    if (options.progress) options.progress(file.size(), std::nullopt);
    wire::FoeMessage ack = wire::FoeAck{expected};
    reply = co_await transfer.exchange(std::move(ack), fmt::format("ACK of packet {}", expected));
  }
}

exec::Task<Result<void>> foe_write(Mailbox& mailbox, std::string_view file_name,
                                   std::vector<std::uint8_t> data, FoeOptions options) {
  const std::string what =
      fmt::format("FoE write of {} to slave {:#06x}", quoted(file_name), mailbox.station());
  const std::size_t packet_size = foe_write_packet_size(mailbox);
  if (packet_size == 0) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: the slave's mailbox ({} bytes) has no room for FoE data", what,
                                mailbox.config().out_size));
  }
  auto guard = co_await mailbox.lock();
  Transfer transfer(mailbox, guard, what, options);

  // Packets are named locals: a temporary inside a co_await expression is not safe with GCC 12.
  wire::FoeMessage request = wire::FoeWriteRequest{options.password, std::string(file_name)};
  auto reply = co_await transfer.exchange(std::move(request), "write request");
  if (auto acked = co_await transfer.expect_ack(reply, 0, "write request"); !acked) {
    co_return acked.error();
  }
  std::size_t offset = 0;
  for (std::uint32_t packet = 1;; ++packet) {
    const std::size_t n = std::min(packet_size, data.size() - offset);
    wire::FoeData chunk{packet, {}};
    chunk.data.assign(data.begin() + static_cast<std::ptrdiff_t>(offset),
                      data.begin() + static_cast<std::ptrdiff_t>(offset + n));
    wire::FoeMessage message = std::move(chunk);
    const std::string step = fmt::format("DATA packet {}", packet);
    reply = co_await transfer.exchange(std::move(message), step);
    if (auto acked = co_await transfer.expect_ack(reply, packet, step); !acked)
      co_return acked.error();
    offset += n;
    if (options.progress) options.progress(offset, data.size());
    // A full packet says "more follows": after the last full one comes an empty packet.
    if (n < packet_size) co_return ok();
  }
}

}  // namespace ecat::master
