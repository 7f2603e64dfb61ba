#include <algorithm>
#include <utility>

#include <fmt/format.h>

#include <ecat/master/eoe.hpp>

namespace ecat::master {

namespace {

// The value of an Errc::mailbox_error that carries an EoE result code: the code in the low 16
// bits under a tag, so that eoe_result_code() never mistakes a mailbox error detail for it.
constexpr std::uint32_t kEoeResultTag = 0x00E0'0000;

bool is_eoe(const MailboxMessage& message) {
  return message.header.type == wire::MailboxType::eoe;
}

bool is_set_ip_response(const MailboxMessage& message) {
  if (!is_eoe(message)) return false;
  auto header = wire::decode_eoe_header(message.data);
  return header && header->type == wire::EoeFrameType::set_ip_response;
}

}  // namespace

Result<std::vector<std::vector<std::uint8_t>>> eoe_fragments(std::span<const std::uint8_t> frame,
                                                             std::size_t max_data,
                                                             std::uint8_t frame_number,
                                                             std::uint8_t port) {
  if (frame.size() < kEoeMinFrameSize || frame.size() > kEoeMaxFrameSize) {
    return Error(Errc::invalid_argument,
                 fmt::format("EoE: an Ethernet frame of {} bytes (must be {}..{} bytes)",
                             frame.size(), kEoeMinFrameSize, kEoeMaxFrameSize));
  }
  if (frame_number > 0x0F || port > 0x0F) {
    return Error(Errc::invalid_argument,
                 fmt::format("EoE: frame number {} / port {} beyond 15", frame_number, port));
  }
  // Every fragment but the last carries whole 32-byte blocks.
  const std::size_t room = max_data > wire::kEoeHeaderSize ? max_data - wire::kEoeHeaderSize : 0;
  const std::size_t block_room = room / wire::kEoeBlockSize * wire::kEoeBlockSize;
  if (block_room == 0) {
    return Error(Errc::unsupported,
                 fmt::format("EoE: a mailbox of {} data bytes cannot carry the EoE header and one "
                             "32-byte block",
                             max_data));
  }
  std::vector<std::vector<std::uint8_t>> out;
  std::size_t offset = 0;
  std::uint8_t number = 0;
  while (offset < frame.size()) {
    const std::size_t left = frame.size() - offset;
    // The last fragment may use the whole room; a fragment 0 .. 63 limit follows from the
    // frame size limit (1518 bytes are 48 blocks).
    const bool last = left <= room;
    const std::size_t size = last ? left : block_room;
    wire::EoeFragment fragment;
    fragment.header.type = wire::EoeFrameType::fragment;
    fragment.header.port = port;
    fragment.header.last_fragment = last;
    fragment.header.fragment_number = number;
    fragment.header.offset_blocks = static_cast<std::uint8_t>(
        number == 0 ? (frame.size() + wire::kEoeBlockSize - 1) / wire::kEoeBlockSize
                    : offset / wire::kEoeBlockSize);
    fragment.header.frame_number = frame_number;
    fragment.data.assign(frame.begin() + static_cast<std::ptrdiff_t>(offset),
                         frame.begin() + static_cast<std::ptrdiff_t>(offset + size));
    auto bytes = wire::encode_eoe(wire::EoeMessage{std::move(fragment)});
    if (!bytes) return bytes.error();
    out.push_back(std::move(*bytes));
    offset += size;
    ++number;
  }
  return out;
}

exec::Task<Result<void>> EoeClient::send(Mailbox& mailbox, std::vector<std::uint8_t> frame,
                                         std::optional<std::chrono::nanoseconds> timeout) {
  const auto per_fragment = timeout.value_or(options_.timeout);
  const std::string what =
      fmt::format("EoE send of a {}-byte frame to slave 0x{:04x}", frame.size(), mailbox.station());
  const std::uint8_t number = tx_frame_number_;
  auto fragments = eoe_fragments(frame, mailbox.max_request_data(), number, options_.port);
  if (!fragments) co_return fragments.error().context(what);
  tx_frame_number_ = static_cast<std::uint8_t>((tx_frame_number_ + 1) & 0x0F);
  auto guard = co_await mailbox.lock();
  for (auto& fragment : *fragments) {
    auto sent = co_await mailbox.send(guard, wire::MailboxType::eoe, std::move(fragment),
                                      per_fragment, what);
    if (!sent) co_return sent.error();
    ++stats_.fragments_sent;
  }
  ++stats_.frames_sent;
  co_return ok();
}

void EoeClient::drop_frame() noexcept {
  if (open_) ++stats_.frames_dropped;
  open_ = false;
  rx_.clear();
}

void EoeClient::reset() noexcept {
  open_ = false;
  rx_.clear();
}

std::optional<std::vector<std::uint8_t>> EoeClient::accept(const wire::EoeFragment& fragment) {
  ++stats_.fragments_received;
  const auto& h = fragment.header;
  const std::size_t bytes = fragment.data.size();
  if (h.fragment_number == 0) {
    drop_frame();  // a new frame while one is open: the open one lost its end
    open_ = true;
    rx_frame_number_ = h.frame_number;
    next_fragment_ = 0;
    announced_ = static_cast<std::size_t>(h.offset_blocks) * wire::kEoeBlockSize;
  } else if (!open_) {
    ++stats_.fragments_dropped;  // its frame's start was lost (or dropped already)
    return std::nullopt;
  } else if (h.fragment_number != next_fragment_ || h.frame_number != rx_frame_number_ ||
             static_cast<std::size_t>(h.offset_blocks) * wire::kEoeBlockSize != rx_.size()) {
    drop_frame();  // lost or out of order
    ++stats_.fragments_dropped;
    return std::nullopt;
  }
  // Bounded: never beyond what fragment 0 announced nor beyond an Ethernet frame.
  if (rx_.size() + bytes > std::min(announced_, kEoeMaxFrameSize)) {
    drop_frame();
    return std::nullopt;
  }
  // A fragment before the last must end on a block boundary, or the next offset cannot match.
  rx_.insert(rx_.end(), fragment.data.begin(), fragment.data.end());
  ++next_fragment_;
  if (!h.last_fragment) {
    if (rx_.size() % wire::kEoeBlockSize != 0 || next_fragment_ > 0x3F) drop_frame();
    return std::nullopt;
  }
  if (rx_.size() < kEoeMinFrameSize) {
    drop_frame();
    return std::nullopt;
  }
  open_ = false;
  ++stats_.frames_received;
  return std::exchange(rx_, {});
}

std::optional<std::vector<std::uint8_t>> EoeClient::accept(wire::Bytes mailbox_data) {
  auto message = wire::decode_eoe(mailbox_data);
  if (!message) {
    ++stats_.fragments_dropped;
    return std::nullopt;
  }
  if (auto* fragment = std::get_if<wire::EoeFragment>(&*message)) return accept(*fragment);
  ++stats_.other_dropped;
  return std::nullopt;
}

void EoeClient::drain(Mailbox& mailbox, std::vector<std::vector<std::uint8_t>>& frames) {
  while (auto message = mailbox.take_unsolicited(is_eoe)) {
    if (auto frame = accept(message->data)) frames.push_back(std::move(*frame));
  }
}

exec::Task<Result<std::vector<std::vector<std::uint8_t>>>> EoeClient::receive(
    Mailbox& mailbox, std::chrono::nanoseconds timeout) {
  std::vector<std::vector<std::uint8_t>> frames;
  const auto deadline = exec::Clock::now() + timeout;
  for (;;) {
    drain(mailbox, frames);
    if (!frames.empty() || exec::Clock::now() >= deadline) co_return frames;
    // poll() reads SM1 once (it waits for a running exchange) and queues what came.
    auto polled = co_await mailbox.poll();
    if (!polled) co_return polled.error();
    if (*polled == 0) co_await exec::sleep_for(mailbox.loop(), options_.poll_interval);
  }
}

exec::Task<Result<void>> EoeClient::set_ip(Mailbox& mailbox, wire::EoeIpParameters parameters,
                                           std::chrono::nanoseconds timeout) {
  const std::string what = fmt::format("EoE set IP parameter of slave 0x{:04x}", mailbox.station());
  auto bytes = wire::encode_eoe(wire::EoeMessage{wire::EoeSetIpRequest{options_.port, parameters}});
  if (!bytes) co_return bytes.error().context(what);
  if (bytes->size() > mailbox.max_request_data()) {
    co_return Error(Errc::unsupported,
                    fmt::format("{}: the request's {} bytes do not fit the mailbox ({} bytes)",
                                what, bytes->size(), mailbox.max_request_data()));
  }
  auto reply = co_await mailbox.request(wire::MailboxType::eoe, std::move(*bytes), timeout,
                                        is_set_ip_response, what);
  if (!reply) co_return reply.error();
  auto response = wire::decode_eoe(reply->data);
  if (!response) co_return response.error().context(Errc::malformed, what);
  const auto* r = std::get_if<wire::EoeSetIpResponse>(&*response);
  if (r == nullptr) co_return Error(Errc::internal, fmt::format("{}: not a response", what));
  if (r->result != 0) {
    co_return Error(Errc::mailbox_error,
                    fmt::format("{}: refused with EoE result 0x{:04x} ({})", what, r->result,
                                wire::eoe_result_text(r->result)))
        .with_value(kEoeResultTag | r->result);
  }
  co_return ok();
}

std::optional<std::uint16_t> eoe_result_code(const Error& error) noexcept {
  for (const Error* e = &error; e != nullptr; e = e->cause()) {
    const auto value = e->value();
    if (e->code() == Errc::mailbox_error && value && (*value & 0xFFFF'0000u) == kEoeResultTag) {
      return static_cast<std::uint16_t>(*value & 0xFFFF);
    }
  }
  return std::nullopt;
}

}  // namespace ecat::master
