#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include <ecat/wire/mailbox.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {

std::string_view to_string(MailboxType type) noexcept {
  switch (type) {
    case MailboxType::error:
      return "error";
    case MailboxType::aoe:
      return "AoE";
    case MailboxType::eoe:
      return "EoE";
    case MailboxType::coe:
      return "CoE";
    case MailboxType::foe:
      return "FoE";
    case MailboxType::soe:
      return "SoE";
    case MailboxType::voe:
      return "VoE";
  }
  return "reserved";
}

Result<void> encode_mailbox_header(const MailboxHeader& header, ByteWriter& out) {
  constexpr std::string_view what = "mailbox header";
  if (header.channel > kMailboxMaxChannel) {
    return detail::invalid_argument(what, fmt::format("channel {} exceeds 63", header.channel));
  }
  if (header.priority > kMailboxMaxPriority) {
    return detail::invalid_argument(what, fmt::format("priority {} exceeds 3", header.priority));
  }
  if (header.counter > kMailboxMaxCounter) {
    return detail::invalid_argument(what, fmt::format("counter {} exceeds 7", header.counter));
  }
  const auto type = static_cast<std::uint8_t>(header.type);
  if (type > 0x0F) {
    return detail::invalid_argument(what, fmt::format("type {} exceeds 15", type));
  }
  if (out.remaining() < kMailboxHeaderSize) {
    return detail::no_room(what, kMailboxHeaderSize, out.remaining());
  }
  out.u16(header.length);
  out.u16(header.address);
  out.u8(static_cast<std::uint8_t>(header.channel | (header.priority << 6)));
  out.u8(static_cast<std::uint8_t>(type | (header.counter << 4)));
  return ok();
}

Result<MailboxHeader> decode_mailbox_header(Bytes bytes) {
  detail::FieldReader r(bytes, "mailbox header");
  MailboxHeader h;
  h.length = r.u16("length");
  h.address = r.u16("address");
  const std::uint8_t channel_priority = r.u8("channel/priority");
  const std::uint8_t type_counter = r.u8("type/counter");
  if (!r.ok()) return r.error();
  h.channel = channel_priority & 0x3F;
  h.priority = static_cast<std::uint8_t>(channel_priority >> 6);
  h.type = static_cast<MailboxType>(type_counter & 0x0F);
  h.counter = (type_counter >> 4) & 0x07;
  return h;
}

Result<Mailbox> decode_mailbox(Bytes buffer) {
  auto header = decode_mailbox_header(buffer);
  if (!header) return std::move(header).error();
  const std::size_t available = buffer.size() - kMailboxHeaderSize;
  if (header->length > available) {
    return Error(Errc::truncated,
                 fmt::format("mailbox: length field says {} bytes of data, only {} follow the "
                             "header",
                             header->length, available));
  }
  return Mailbox{*header, buffer.subspan(kMailboxHeaderSize, header->length)};
}

Result<std::size_t> encode_mailbox(MailboxHeader header, Bytes data, MutableBytes out) {
  if (data.size() > detail::kMaxMailboxData) {
    return detail::invalid_argument(
        "mailbox", fmt::format("{} bytes of data exceed the 16-bit length field", data.size()));
  }
  const std::size_t size = kMailboxHeaderSize + data.size();
  if (out.size() < size) return detail::no_room("mailbox", size, out.size());
  header.length = static_cast<std::uint16_t>(data.size());
  ByteWriter w(out);
  if (auto r = encode_mailbox_header(header, w); !r) return std::move(r).error();
  w.bytes(data);
  w.zeros(w.remaining());
  return size;
}

Result<std::vector<std::uint8_t>> encode_mailbox(MailboxHeader header, Bytes data) {
  std::vector<std::uint8_t> out(kMailboxHeaderSize + data.size());
  auto r = encode_mailbox(header, data, MutableBytes{out});
  if (!r) return std::move(r).error();
  return out;
}

std::string mailbox_error_text(std::uint16_t detail) {
  switch (static_cast<MailboxErrorCode>(detail)) {
    case MailboxErrorCode::syntax:
      return "syntax error";
    case MailboxErrorCode::unsupported_protocol:
      return "unsupported protocol";
    case MailboxErrorCode::invalid_channel:
      return "invalid channel";
    case MailboxErrorCode::service_not_supported:
      return "service not supported";
    case MailboxErrorCode::invalid_header:
      return "invalid header";
    case MailboxErrorCode::size_too_short:
      return "size too short";
    case MailboxErrorCode::no_more_memory:
      return "no more memory";
    case MailboxErrorCode::invalid_size:
      return "invalid size";
    case MailboxErrorCode::service_in_work:
      return "service in work";
  }
  return fmt::format("unknown mailbox error 0x{:04x}", detail);
}

Result<MailboxErrorReply> decode_mailbox_error(Bytes data) {
  detail::FieldReader r(data, "mailbox error reply");
  const std::uint16_t service = r.u16("service type");
  MailboxErrorReply reply;
  reply.detail = r.u16("detail");
  if (!r.ok()) return r.error();
  if (service != kMailboxErrorService) {
    return detail::malformed(
        "mailbox error reply",
        fmt::format("service type at offset 0 is 0x{:04x}, expected 0x0001", service));
  }
  return reply;
}

Result<void> encode_mailbox_error(const MailboxErrorReply& reply, ByteWriter& out) {
  if (out.remaining() < kMailboxErrorReplySize) {
    return detail::no_room("mailbox error reply", kMailboxErrorReplySize, out.remaining());
  }
  out.u16(kMailboxErrorService);
  out.u16(reply.detail);
  return ok();
}

}  // namespace ecat::wire
