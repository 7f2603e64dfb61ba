#include <algorithm>
#include <type_traits>

#include <fmt/format.h>

#include <ecat/wire/eoe.hpp>

#include "wire/mailbox_detail.hpp"

namespace ecat::wire {
namespace {

constexpr std::uint16_t kLastFragment = 0x0100;
constexpr std::uint16_t kTimeAppended = 0x0200;
constexpr std::uint16_t kTimeRequest = 0x0400;

// "Included" flags of the IP parameter services.
constexpr std::uint32_t kMacIncluded = 0x01;
constexpr std::uint32_t kIpIncluded = 0x02;
constexpr std::uint32_t kSubnetIncluded = 0x04;
constexpr std::uint32_t kGatewayIncluded = 0x08;
constexpr std::uint32_t kDnsServerIncluded = 0x10;
constexpr std::uint32_t kDnsNameIncluded = 0x20;

void append_header(std::vector<std::uint8_t>& out, const EoeHeader& h) {
  std::uint8_t header[kEoeHeaderSize];
  ByteWriter w(header);
  (void)encode_eoe_header(h, w);
  detail::append(out, Bytes{header});
}

Result<void> check_header(const EoeHeader& h) {
  if (static_cast<unsigned>(h.type) > 0x0F || h.port > 0x0F || h.fragment_number > 0x3F ||
      h.offset_blocks > 0x3F || h.frame_number > 0x0F) {
    return detail::invalid_argument(
        "EoE header",
        fmt::format("field out of range (type {} max 15, port {} max 15, fragment {} max 63, "
                    "offset {} max 63, frame {} max 15)",
                    static_cast<unsigned>(h.type), h.port, h.fragment_number, h.offset_blocks,
                    h.frame_number));
  }
  return ok();
}

Result<EoeIpParameters> decode_ip_parameters(detail::FieldReader& r) {
  const std::uint32_t flags = r.u32("included flags");
  EoeIpParameters p;
  if (flags & kMacIncluded) {
    Bytes mac = r.bytes("MAC address", 6);
    if (r.ok()) std::copy(mac.begin(), mac.end(), p.mac.emplace().begin());
  }
  if (flags & kIpIncluded) p.ip = r.u32("IP address");
  if (flags & kSubnetIncluded) p.subnet_mask = r.u32("subnet mask");
  if (flags & kGatewayIncluded) p.default_gateway = r.u32("default gateway");
  if (flags & kDnsServerIncluded) p.dns_server = r.u32("DNS server");
  if (flags & kDnsNameIncluded)
    p.dns_name = detail::text_field(r.bytes("DNS name", kEoeDnsNameSize));
  if (!r.ok()) return r.error();
  return p;
}

Result<void> append_ip_parameters(std::vector<std::uint8_t>& out, const EoeIpParameters& p) {
  if (p.dns_name && (p.dns_name->size() > kEoeDnsNameSize || detail::holds_nul(*p.dns_name))) {
    return detail::invalid_argument(
        "EoE IP parameters", fmt::format("DNS name must be at most 32 bytes without NUL, is {} "
                                         "bytes",
                                         p.dns_name->size()));
  }
  std::uint32_t flags = 0;
  if (p.mac) flags |= kMacIncluded;
  if (p.ip) flags |= kIpIncluded;
  if (p.subnet_mask) flags |= kSubnetIncluded;
  if (p.default_gateway) flags |= kGatewayIncluded;
  if (p.dns_server) flags |= kDnsServerIncluded;
  if (p.dns_name) flags |= kDnsNameIncluded;
  detail::append_u32(out, flags);
  if (p.mac) detail::append(out, *p.mac);
  for (const auto* address : {&p.ip, &p.subnet_mask, &p.default_gateway, &p.dns_server}) {
    if (*address) detail::append_u32(out, **address);
  }
  if (p.dns_name) {
    detail::append(out, detail::as_bytes(*p.dns_name));
    out.insert(out.end(), kEoeDnsNameSize - p.dns_name->size(), 0);
  }
  return ok();
}

}  // namespace

std::string_view to_string(EoeFrameType type) noexcept {
  switch (type) {
    case EoeFrameType::fragment:
      return "fragment";
    case EoeFrameType::timestamp_response:
      return "timestamp response";
    case EoeFrameType::set_ip_request:
      return "set IP parameter request";
    case EoeFrameType::set_ip_response:
      return "set IP parameter response";
    case EoeFrameType::set_address_filter_request:
      return "set address filter request";
    case EoeFrameType::set_address_filter_response:
      return "set address filter response";
    case EoeFrameType::get_ip_request:
      return "get IP parameter request";
    case EoeFrameType::get_ip_response:
      return "get IP parameter response";
    case EoeFrameType::get_address_filter_request:
      return "get address filter request";
    case EoeFrameType::get_address_filter_response:
      return "get address filter response";
  }
  return "reserved";
}

std::string_view eoe_result_text(std::uint16_t result) noexcept {
  switch (static_cast<EoeResult>(result)) {
    case EoeResult::success:
      return "success";
    case EoeResult::unspecified_error:
      return "unspecified error";
    case EoeResult::unsupported_frame_type:
      return "unsupported frame type";
    case EoeResult::no_ip_support:
      return "no IP support";
    case EoeResult::dhcp_not_supported:
      return "DHCP not supported";
    case EoeResult::no_filter_support:
      return "no address filter support";
  }
  return "unknown EoE result";
}

Result<void> encode_eoe_header(const EoeHeader& h, ByteWriter& out) {
  if (auto valid = check_header(h); !valid) return valid;
  if (out.remaining() < kEoeHeaderSize) {
    return detail::no_room("EoE header", kEoeHeaderSize, out.remaining());
  }
  std::uint16_t word0 = static_cast<std::uint16_t>(static_cast<unsigned>(h.type) | (h.port << 4));
  if (h.last_fragment) word0 |= kLastFragment;
  if (h.time_appended) word0 |= kTimeAppended;
  if (h.time_request) word0 |= kTimeRequest;
  out.u16(word0);
  out.u16(eoe_result_of(h));
  return ok();
}

Result<EoeHeader> decode_eoe_header(Bytes data) {
  detail::FieldReader r(data, "EoE header");
  const std::uint16_t word0 = r.u16("frame info");
  const std::uint16_t word1 = r.u16("fragment info");
  if (!r.ok()) return r.error();
  EoeHeader h;
  h.type = static_cast<EoeFrameType>(word0 & 0x0F);
  h.port = (word0 >> 4) & 0x0F;
  h.last_fragment = (word0 & kLastFragment) != 0;
  h.time_appended = (word0 & kTimeAppended) != 0;
  h.time_request = (word0 & kTimeRequest) != 0;
  h.fragment_number = word1 & 0x3F;
  h.offset_blocks = (word1 >> 6) & 0x3F;
  h.frame_number = static_cast<std::uint8_t>(word1 >> 12);
  return h;
}

Result<EoeMessage> decode_eoe(Bytes data) {
  auto header = decode_eoe_header(data);
  if (!header) return std::move(header).error();
  detail::FieldReader r(
      data, header->type == EoeFrameType::set_ip_request ? "EoE set IP parameter request" : "EoE");
  (void)r.bytes("EoE header", kEoeHeaderSize);
  switch (header->type) {
    case EoeFrameType::fragment: {
      EoeFragment m;
      m.header = *header;
      Bytes payload = r.rest();
      if (header->time_appended) {
        if (payload.size() < 4) {
          detail::FieldReader t(data, "EoE fragment");
          (void)t.bytes("EoE header", kEoeHeaderSize);
          (void)t.bytes("appended timestamp", 4);
          return t.error();
        }
        m.timestamp = load_le32(&payload[payload.size() - 4]);
        payload = payload.first(payload.size() - 4);
      }
      m.data.assign(payload.begin(), payload.end());
      return EoeMessage{std::move(m)};
    }
    case EoeFrameType::set_ip_request: {
      auto parameters = decode_ip_parameters(r);
      if (!parameters) return std::move(parameters).error();
      return EoeMessage{EoeSetIpRequest{header->port, std::move(*parameters)}};
    }
    case EoeFrameType::set_ip_response:
      return EoeMessage{EoeSetIpResponse{header->port, eoe_result_of(*header)}};
    default:
      break;
  }
  Bytes rest = r.rest();
  return EoeMessage{EoeOther{*header, std::vector<std::uint8_t>(rest.begin(), rest.end())}};
}

Result<std::vector<std::uint8_t>> encode_eoe(const EoeMessage& message) {
  std::vector<std::uint8_t> out;
  auto body = std::visit(
      [&out](const auto& m) -> Result<void> {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, EoeFragment>) {
          if (m.header.type != EoeFrameType::fragment) {
            return detail::invalid_argument("EoE fragment", "header type is not fragment (0)");
          }
          if (m.header.time_appended != m.timestamp.has_value()) {
            return detail::invalid_argument(
                "EoE fragment", "a timestamp must be present exactly when time_appended is set");
          }
          if (auto valid = check_header(m.header); !valid) return valid;
          append_header(out, m.header);
          detail::append(out, m.data);
          if (m.timestamp) detail::append_u32(out, *m.timestamp);
        } else if constexpr (std::is_same_v<T, EoeSetIpRequest>) {
          EoeHeader h;
          h.type = EoeFrameType::set_ip_request;
          h.port = m.port;
          h.last_fragment = true;
          if (auto valid = check_header(h); !valid) return valid;
          append_header(out, h);
          return append_ip_parameters(out, m.parameters);
        } else if constexpr (std::is_same_v<T, EoeSetIpResponse>) {
          EoeHeader h;
          h.type = EoeFrameType::set_ip_response;
          h.port = m.port;
          h.last_fragment = true;
          h.fragment_number = m.result & 0x3F;
          h.offset_blocks = (m.result >> 6) & 0x3F;
          h.frame_number = static_cast<std::uint8_t>(m.result >> 12);
          if (auto valid = check_header(h); !valid) return valid;
          append_header(out, h);
        } else {
          static_assert(std::is_same_v<T, EoeOther>);
          if (m.header.type == EoeFrameType::fragment ||
              m.header.type == EoeFrameType::set_ip_request ||
              m.header.type == EoeFrameType::set_ip_response) {
            return detail::invalid_argument(
                "EoE", "EoeOther cannot carry a fragment or set IP parameter frame type");
          }
          if (auto valid = check_header(m.header); !valid) return valid;
          append_header(out, m.header);
          detail::append(out, m.data);
        }
        return ok();
      },
      message);
  if (!body) return std::move(body).error();
  if (out.size() > detail::kMaxMailboxData) {
    return detail::invalid_argument(
        "EoE", fmt::format("{} bytes exceed the mailbox length limit of 65535", out.size()));
  }
  return out;
}

std::string format_ipv4(std::uint32_t address) {
  return fmt::format("{}.{}.{}.{}", address >> 24, (address >> 16) & 0xFF, (address >> 8) & 0xFF,
                     address & 0xFF);
}

}  // namespace ecat::wire
