#include <fmt/format.h>

#include <ecat/wire/mailbox_gateway.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {

namespace {
constexpr std::string_view kWhat = "mailbox gateway message";
}  // namespace

Result<GatewayMessage> decode_gateway_message(Bytes datagram) {
  if (datagram.size() < kMailboxGatewayHeaderSize) {
    return Error(Errc::truncated,
                 fmt::format("{}: {} byte{} cannot hold the 2-byte EtherCAT header", kWhat,
                             datagram.size(), datagram.size() == 1 ? "" : "s"));
  }
  const std::uint16_t word = load_le16(datagram.data());
  const std::size_t length = word & 0x07FF;
  const unsigned type = word >> 12;
  if (type != kEtherCatTypeMailbox) {
    return Error(Errc::unsupported,
                 fmt::format("{}: EtherCAT header type is {}, expected 5 (mailbox)", kWhat, type));
  }
  const Bytes body = datagram.subspan(kMailboxGatewayHeaderSize);
  if (length > body.size()) {
    return Error(Errc::truncated,
                 fmt::format("{}: EtherCAT header length is {}, only {} bytes follow it", kWhat,
                             length, body.size()));
  }
  if (length < kMailboxHeaderSize) {
    return detail::malformed(
        kWhat,
        fmt::format("EtherCAT header length is {}, less than the 6-byte mailbox header", length));
  }
  auto header = decode_mailbox_header(body);
  if (!header) return std::move(header).error();
  const std::size_t size = kMailboxHeaderSize + header->length;
  if (size > length) {
    return detail::malformed(
        kWhat, fmt::format("mailbox length field says {} bytes of data, the EtherCAT header's "
                           "length {} leaves room for {}",
                           header->length, length, length - kMailboxHeaderSize));
  }
  return GatewayMessage{*header, body.first(size),
                        body.subspan(kMailboxHeaderSize, header->length)};
}

Result<std::size_t> encode_gateway_message(MailboxHeader header, Bytes data, MutableBytes out) {
  const std::size_t mailbox = kMailboxHeaderSize + data.size();
  if (mailbox > kMaxGatewayMailboxSize) {
    return detail::invalid_argument(
        kWhat,
        fmt::format("a mailbox of {} bytes exceeds the 11-bit EtherCAT length (2047)", mailbox));
  }
  const std::size_t size = kMailboxGatewayHeaderSize + mailbox;
  if (out.size() < size) return detail::no_room(kWhat, size, out.size());
  header.length = static_cast<std::uint16_t>(data.size());
  ByteWriter w(out.first(size));
  w.u16(static_cast<std::uint16_t>(mailbox | (kEtherCatTypeMailbox << 12)));
  if (auto r = encode_mailbox_header(header, w); !r) return std::move(r).error();
  w.bytes(data);
  return size;
}

Result<std::vector<std::uint8_t>> encode_gateway_message(MailboxHeader header, Bytes data) {
  std::vector<std::uint8_t> out(kMailboxGatewayHeaderSize + kMailboxHeaderSize + data.size());
  auto r = encode_gateway_message(header, data, MutableBytes{out});
  if (!r) return std::move(r).error();
  return out;
}

}  // namespace ecat::wire
