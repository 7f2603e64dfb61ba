#include <algorithm>
#include <cstring>

#include <fmt/format.h>

#include <ecat/wire/redundancy.hpp>

namespace ecat::wire {

namespace {

bool is_logical(Command command) noexcept {
  return command == Command::lrd || command == Command::lwr || command == Command::lrw;
}

// Offset of a decoded datagram's header within the frame it was decoded from.
std::size_t header_offset(Bytes frame, const DatagramView& d) noexcept {
  return static_cast<std::size_t>(d.data.data() - frame.data()) - kDatagramHeaderSize;
}

}  // namespace

std::string_view to_string(RedundantPort port) noexcept {
  return port == RedundantPort::primary ? "primary" : "secondary";
}

std::string_view to_string(ArrivalKind kind) noexcept {
  switch (kind) {
    case ArrivalKind::forward_cross:
      return "forward cross";
    case ArrivalKind::reverse_cross:
      return "reverse cross";
    case ArrivalKind::primary_bounce:
      return "primary bounce";
    case ArrivalKind::secondary_bounce:
      return "secondary bounce";
    case ArrivalKind::unknown:
      break;
  }
  return "unknown";
}

bool same_station_mac(const MacAddress& a, const MacAddress& b) noexcept {
  if ((a[0] | 0x02) != (b[0] | 0x02)) return false;
  return std::equal(a.begin() + 1, a.end(), b.begin() + 1);
}

ArrivalKind classify_arrival(RedundantPort arrived_on, const MacAddress& source,
                             const MacAddress& primary, const MacAddress& secondary) noexcept {
  const bool from_primary = same_station_mac(source, primary);
  const bool from_secondary = same_station_mac(source, secondary);
  if (from_primary == from_secondary) return ArrivalKind::unknown;
  if (arrived_on == RedundantPort::primary) {
    return from_primary ? ArrivalKind::primary_bounce : ArrivalKind::reverse_cross;
  }
  return from_primary ? ArrivalKind::forward_cross : ArrivalKind::secondary_bounce;
}

bool same_shape(Bytes request, Bytes reply) noexcept {
  const auto a = decode_frame(request);
  const auto b = decode_frame(reply);
  if (!a || !b || a.frame->datagram_count() != b.frame->datagram_count()) return false;
  auto j = b.frame->begin();
  for (const DatagramView d : *a.frame) {
    const DatagramView r = *j++;
    if (d.header.index != r.header.index || d.header.command != r.header.command ||
        d.header.length != r.header.length) {
      return false;
    }
  }
  return true;
}

bool is_passthrough_copy(Bytes request, Bytes reply) noexcept {
  if (!same_shape(request, reply)) return false;
  const auto a = decode_frame(request);
  const auto b = decode_frame(reply);
  auto j = b.frame->begin();
  for (const DatagramView d : *a.frame) {
    const DatagramView r = *j++;
    if (r.wkc != 0 || !std::equal(d.data.begin(), d.data.end(), r.data.begin())) return false;
  }
  return true;
}

bool any_processed(Bytes frame) noexcept {
  const auto decoded = decode_frame(frame);
  if (!decoded) return false;
  return std::any_of(decoded.frame->begin(), decoded.frame->end(),
                     [](const DatagramView& d) { return d.wkc > 0; });
}

Result<Bytes> merge_bounces(Bytes request, Bytes primary, Bytes secondary, MutableBytes out,
                            MergeStats* stats) {
  const auto req = decode_frame(request);
  if (!req) return req.error.to_error().context(Errc::malformed, "merging bounces: the request");
  if (!same_shape(request, primary)) {
    return Error(Errc::malformed,
                 "merging bounces: the primary's frame does not answer the request");
  }
  if (!same_shape(request, secondary)) {
    return Error(Errc::malformed,
                 "merging bounces: the secondary's frame does not answer the request");
  }
  if (out.size() < request.size()) {
    return Error(Errc::invalid_argument,
                 fmt::format("merging bounces: {} bytes of room for a {}-byte frame", out.size(),
                             request.size()));
  }
  const auto pri = decode_frame(primary);
  const auto sec = decode_frame(secondary);
  // The request's framing (header, padding) with every datagram then filled from the replies.
  std::memcpy(out.data(), request.data(), request.size());
  MergeStats local;
  auto p = pri.frame->begin();
  auto s = sec.frame->begin();
  for (const DatagramView r : *req.frame) {
    const DatagramView a = *p++;
    const DatagramView b = *s++;
    ++local.datagrams;
    const std::size_t at = header_offset(request, r);
    std::uint8_t* const dst = out.data() + at;
    bool primary_leads = a.wkc >= b.wkc;
    if (r.header.command == Command::frmw || r.header.command == Command::armw) {
      // One slave reads, the others write what it read: its side carries the read, the other
      // side's copy carries the request's data (written into its slaves) whatever its WKC.
      const bool a_read = !std::equal(a.data.begin(), a.data.end(), r.data.begin());
      const bool b_read = !std::equal(b.data.begin(), b.data.end(), r.data.begin());
      if (a_read != b_read) primary_leads = a_read;
    }
    const DatagramView& lead = primary_leads ? a : b;
    const Bytes lead_frame = primary_leads ? primary : secondary;
    // Header as the leading side returned it (its address carries the ADP it counted), with the
    // circulating bit and the IRQ of both.
    std::memcpy(dst, lead_frame.data() + header_offset(lead_frame, lead), kDatagramHeaderSize);
    const std::uint16_t length_field = load_le16(dst + 6);
    const bool circulating = a.header.circulating || b.header.circulating;
    store_le16(dst + 6, static_cast<std::uint16_t>((length_field & ~0x4000u) |
                                                   (circulating ? 0x4000u : 0u)));
    store_le16(dst + 8, static_cast<std::uint16_t>(a.header.irq | b.header.irq));
    std::uint8_t* const data = dst + kDatagramHeaderSize;
    if (is_logical(r.header.command)) {
      for (std::size_t i = 0; i < r.data.size(); ++i) {
        const std::uint8_t was = r.data[i];
        const bool a_changed = a.data[i] != was;
        const bool b_changed = b.data[i] != was;
        if (a_changed && b_changed) {
          if (a.data[i] != b.data[i]) ++local.conflicting_bytes;
          data[i] = lead.data[i];
        } else if (a_changed) {
          data[i] = a.data[i];
          ++local.bytes_from_primary;
        } else if (b_changed) {
          data[i] = b.data[i];
          ++local.bytes_from_secondary;
        } else {
          data[i] = was;
        }
      }
    } else {
      std::copy(lead.data.begin(), lead.data.end(), data);
    }
    const unsigned wkc = std::min<unsigned>(0xFFFFu, unsigned{a.wkc} + unsigned{b.wkc});
    store_le16(data + r.data.size(), static_cast<std::uint16_t>(wkc));
  }
  if (stats != nullptr) *stats = local;
  return Bytes(out.data(), request.size());
}

}  // namespace ecat::wire
