#include <fmt/format.h>

#include <ecat/wire/voe.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {

Result<void> encode_voe_header(const VoeHeader& header, ByteWriter& out) {
  if (out.remaining() < kVoeHeaderSize) {
    return detail::no_room("VoE header", kVoeHeaderSize, out.remaining());
  }
  out.u32(header.vendor_id);
  out.u16(header.vendor_type);
  return ok();
}

Result<VoeHeader> decode_voe_header(Bytes data) {
  detail::FieldReader r(data, "VoE header");
  VoeHeader h;
  h.vendor_id = r.u32("vendor id");
  h.vendor_type = r.u16("vendor type");
  if (!r.ok()) return r.error();
  return h;
}

Result<VoeMessage> decode_voe(Bytes data) {
  auto header = decode_voe_header(data);
  if (!header) return std::move(header).error();
  VoeMessage m;
  m.header = *header;
  const Bytes rest = data.subspan(kVoeHeaderSize);
  m.data.assign(rest.begin(), rest.end());
  return m;
}

Result<std::vector<std::uint8_t>> encode_voe(const VoeMessage& message) {
  if (message.data.size() > detail::kMaxMailboxData - kVoeHeaderSize) {
    return detail::invalid_argument(
        "VoE", fmt::format("{} bytes of data exceed the mailbox length limit of 65535",
                           message.data.size() + kVoeHeaderSize));
  }
  std::vector<std::uint8_t> out(kVoeHeaderSize);
  ByteWriter w(MutableBytes{out});
  if (auto r = encode_voe_header(message.header, w); !r) return std::move(r).error();
  detail::append(out, message.data);
  return out;
}

}  // namespace ecat::wire
