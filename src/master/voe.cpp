#include <utility>

#include <fmt/format.h>

#include <ecat/master/voe.hpp>

namespace ecat::master {

namespace {

bool is_voe(const MailboxMessage& message) {
  return message.header.type == wire::MailboxType::voe;
}

Result<wire::VoeMessage> decode(const MailboxMessage& message, const std::string& what) {
  auto voe = wire::decode_voe(message.data);
  if (!voe) return voe.error().context(Errc::malformed, what);
  return voe;
}

}  // namespace

exec::Task<Result<void>> voe_send(Mailbox& mailbox, std::uint32_t vendor_id,
                                  std::uint16_t vendor_type, std::vector<std::uint8_t> data,
                                  std::chrono::nanoseconds timeout) {
  const std::string what =
      fmt::format("VoE send (vendor 0x{:08x}, type 0x{:04x}) to slave 0x{:04x}", vendor_id,
                  vendor_type, mailbox.station());
  const std::size_t room = mailbox.max_request_data();
  if (room < wire::kVoeHeaderSize || data.size() > room - wire::kVoeHeaderSize) {
    co_return Error(Errc::invalid_argument,
                    fmt::format("{}: {} bytes do not fit the mailbox ({} bytes after the VoE "
                                "header)",
                                what, data.size(), room < wire::kVoeHeaderSize ? 0 : room - 6));
  }
  auto bytes = wire::encode_voe({{vendor_id, vendor_type}, std::move(data)});
  if (!bytes) co_return bytes.error().context(what);
  auto guard = co_await mailbox.lock();
  co_return co_await mailbox.send(guard, wire::MailboxType::voe, std::move(*bytes), timeout, what);
}

exec::Task<Result<wire::VoeMessage>> voe_receive(Mailbox& mailbox,
                                                 std::chrono::nanoseconds timeout) {
  const std::string what = fmt::format("VoE receive from slave 0x{:04x}", mailbox.station());
  if (auto queued = mailbox.take_unsolicited(is_voe)) co_return decode(*queued, what);
  auto guard = co_await mailbox.lock();
  // Another exchange may have queued one while this task waited for the mailbox.
  if (auto queued = mailbox.take_unsolicited(is_voe)) co_return decode(*queued, what);
  auto message = co_await mailbox.receive(guard, timeout, is_voe, what);
  if (!message) co_return message.error();
  co_return decode(*message, what);
}

}  // namespace ecat::master
