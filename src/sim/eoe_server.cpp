#include <algorithm>
#include <utility>

#include <ecat/sim/eoe_server.hpp>
#include <ecat/sim/esc.hpp>
#include <ecat/sim/standard_application.hpp>

namespace ecat::sim {

namespace {

constexpr std::size_t kMaxFrame = 1518;  // Ethernet without FCS, with a VLAN tag
constexpr std::size_t kMinFrame = 60;    // replies are padded to it
constexpr std::size_t kEthHeader = 14;
constexpr std::uint16_t kEtherArp = 0x0806;
constexpr std::uint16_t kEtherIpv4 = 0x0800;
constexpr std::size_t kArpSize = 28;
constexpr std::size_t kIpv4Header = 20;  // no options taken
constexpr std::size_t kIcmpHeader = 8;

std::uint16_t be16(std::span<const std::uint8_t> d, std::size_t at) {
  return static_cast<std::uint16_t>((d[at] << 8) | d[at + 1]);
}
std::uint32_t be32(std::span<const std::uint8_t> d, std::size_t at) {
  return (std::uint32_t{d[at]} << 24) | (std::uint32_t{d[at + 1]} << 16) |
         (std::uint32_t{d[at + 2]} << 8) | d[at + 3];
}
void put16(std::vector<std::uint8_t>& d, std::size_t at, std::uint16_t v) {
  d[at] = static_cast<std::uint8_t>(v >> 8);
  d[at + 1] = static_cast<std::uint8_t>(v);
}
void put32(std::vector<std::uint8_t>& d, std::size_t at, std::uint32_t v) {
  put16(d, at, static_cast<std::uint16_t>(v >> 16));
  put16(d, at + 2, static_cast<std::uint16_t>(v));
}

bool is_broadcast(std::span<const std::uint8_t> mac) {
  return std::all_of(mac.begin(), mac.end(), [](std::uint8_t b) { return b == 0xFF; });
}

// Ethernet header of a reply: to the requester, from us.
std::vector<std::uint8_t> reply_header(std::span<const std::uint8_t> request,
                                       const std::array<std::uint8_t, 6>& mac,
                                       std::uint16_t ether_type, std::size_t size) {
  std::vector<std::uint8_t> out(std::max(size, kMinFrame), 0);
  std::copy(request.begin() + 6, request.begin() + 12, out.begin());
  std::copy(mac.begin(), mac.end(), out.begin() + 6);
  put16(out, 12, ether_type);
  return out;
}

}  // namespace

std::string_view to_string(EoeFaultKind kind) noexcept {
  switch (kind) {
    case EoeFaultKind::drop_reply_fragment:
      return "drop_reply_fragment";
    case EoeFaultKind::drop_request_fragment:
      return "drop_request_fragment";
    case EoeFaultKind::drop_reply:
      return "drop_reply";
    case EoeFaultKind::corrupt_fragment_offset:
      return "corrupt_fragment_offset";
  }
  return "unknown";
}

std::uint16_t internet_checksum(std::span<const std::uint8_t> data) noexcept {
  std::uint32_t sum = 0;
  for (std::size_t i = 0; i + 1 < data.size(); i += 2)
    sum += static_cast<std::uint32_t>((data[i] << 8) | data[i + 1]);
  if (data.size() % 2 != 0) sum += static_cast<std::uint32_t>(data.back() << 8);
  while (sum >> 16)
    sum = (sum & 0xFFFF) + (sum >> 16);
  return static_cast<std::uint16_t>(~sum);
}

EoeServer::EoeServer(CoeServer& mailbox, EoeServerConfig config)
    : mailbox_(mailbox), config_(config), mac_(config.mac), ip_(config.ip) {}

void EoeServer::power_up() {
  mac_ = config_.mac;
  ip_ = config_.ip;
  parameters_ = {};
  open_ = false;
  skip_fragment_.reset();
  rx_.clear();
  tx_frame_number_ = 0;
}

std::optional<EoeFaultRule> EoeServer::take_fault(EoeFaultKind kind) {
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->kind != kind) continue;
    const EoeFaultRule rule = *it;
    if (rule.once) faults_.erase(it);
    ++stats_.faults_applied;
    return rule;
  }
  return std::nullopt;
}

std::optional<std::vector<std::uint8_t>> EoeServer::take_fragment(
    const wire::EoeFragment& fragment) {
  ++stats_.fragments_received;
  const auto& h = fragment.header;
  auto drop = [this] {
    if (open_) ++stats_.frames_dropped;
    open_ = false;
    rx_.clear();
  };
  if (h.fragment_number == 0) {
    drop();  // a new frame while one is open: the open one lost its end
    open_ = true;
    rx_frame_number_ = h.frame_number;
    next_fragment_ = 0;
    announced_ = std::size_t{h.offset_blocks} * wire::kEoeBlockSize;
    skip_fragment_.reset();
    if (auto fault = take_fault(EoeFaultKind::drop_request_fragment)) {
      skip_fragment_ = fault->value;
    }
  } else if (!open_) {
    ++stats_.fragments_dropped;
    return std::nullopt;
  }
  if (skip_fragment_ && *skip_fragment_ == h.fragment_number) {
    skip_fragment_.reset();  // "lost": the next fragment finds a gap
    if (h.fragment_number == 0) open_ = false;
    return std::nullopt;
  }
  if (h.fragment_number != next_fragment_ || h.frame_number != rx_frame_number_ ||
      (h.fragment_number != 0 &&
       std::size_t{h.offset_blocks} * wire::kEoeBlockSize != rx_.size())) {
    drop();
    ++stats_.fragments_dropped;
    return std::nullopt;
  }
  if (rx_.size() + fragment.data.size() > std::min(announced_, kMaxFrame)) {
    drop();
    return std::nullopt;
  }
  rx_.insert(rx_.end(), fragment.data.begin(), fragment.data.end());
  ++next_fragment_;
  if (!h.last_fragment) {
    if (rx_.size() % wire::kEoeBlockSize != 0 || next_fragment_ > 0x3F) drop();
    return std::nullopt;
  }
  open_ = false;
  ++stats_.frames_received;
  return std::exchange(rx_, {});
}

std::vector<std::vector<std::uint8_t>> EoeServer::fragments(std::span<const std::uint8_t> frame,
                                                            std::size_t max_data) {
  std::vector<std::vector<std::uint8_t>> out;
  const std::size_t room = max_data > wire::kEoeHeaderSize ? max_data - wire::kEoeHeaderSize : 0;
  const std::size_t block_room = room / wire::kEoeBlockSize * wire::kEoeBlockSize;
  if (block_room == 0 || frame.empty() || frame.size() > kMaxFrame) return out;
  const std::uint8_t number = tx_frame_number_;
  tx_frame_number_ = static_cast<std::uint8_t>((tx_frame_number_ + 1) & 0x0F);
  std::size_t offset = 0;
  std::uint8_t fragment_number = 0;
  while (offset < frame.size()) {
    const std::size_t left = frame.size() - offset;
    const bool last = left <= room;
    const std::size_t size = last ? left : block_room;
    wire::EoeFragment f;
    f.header.last_fragment = last;
    f.header.fragment_number = fragment_number;
    f.header.offset_blocks = static_cast<std::uint8_t>(
        fragment_number == 0 ? (frame.size() + wire::kEoeBlockSize - 1) / wire::kEoeBlockSize
                             : offset / wire::kEoeBlockSize);
    f.header.frame_number = number;
    f.data.assign(frame.begin() + static_cast<std::ptrdiff_t>(offset),
                  frame.begin() + static_cast<std::ptrdiff_t>(offset + size));
    auto bytes = wire::encode_eoe(wire::EoeMessage{std::move(f)});
    if (!bytes) return {};
    out.push_back(std::move(*bytes));
    offset += size;
    ++fragment_number;
  }
  return out;
}

std::vector<MailboxReply> EoeServer::reply_frame(Esc& esc, std::span<const std::uint8_t> frame) {
  std::vector<MailboxReply> out;
  if (take_fault(EoeFaultKind::drop_reply)) return out;
  const std::size_t sm = mailbox_.config().reply_sm;
  const std::size_t capacity =
      sm < esc.hardware().sync_manager_count ? esc.sync_manager(sm).config.length : 0;
  const std::size_t max_data =
      capacity > wire::kMailboxHeaderSize ? capacity - wire::kMailboxHeaderSize : 0;
  auto parts = fragments(frame, max_data);
  if (parts.empty()) return out;
  // Only a frame that has the fragment loses it (an ARP reply in one fragment passes untouched).
  std::optional<EoeFaultRule> lost;
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->kind != EoeFaultKind::drop_reply_fragment || it->value >= parts.size()) continue;
    lost = *it;
    if (it->once) faults_.erase(it);
    ++stats_.faults_applied;
    break;
  }
  // A wrong offset in fragment `value` (fragment 0's offset field holds the frame size instead).
  for (auto it = faults_.begin(); it != faults_.end(); ++it) {
    if (it->kind != EoeFaultKind::corrupt_fragment_offset || it->value == 0 ||
        it->value >= parts.size()) {
      continue;
    }
    auto& part = parts[it->value];
    auto message = wire::decode_eoe(part);
    auto* fragment = message ? std::get_if<wire::EoeFragment>(&*message) : nullptr;
    if (fragment == nullptr) break;
    fragment->header.offset_blocks =
        static_cast<std::uint8_t>((fragment->header.offset_blocks + 1) & 0x3F);
    auto bytes = wire::encode_eoe(wire::EoeMessage{std::move(*fragment)});
    if (!bytes) break;
    part = std::move(*bytes);
    if (it->once) faults_.erase(it);
    ++stats_.faults_applied;
    break;
  }
  for (std::size_t i = 0; i < parts.size(); ++i) {
    if (lost && lost->value == i) continue;
    out.push_back({wire::MailboxType::eoe, std::move(parts[i])});
    ++stats_.fragments_sent;
  }
  ++stats_.frames_sent;
  return out;
}

void EoeServer::send_frame(Esc& esc, std::span<const std::uint8_t> frame) {
  for (auto& reply : reply_frame(esc, frame))
    mailbox_.queue_reply(esc, reply.type, reply.data);
}

std::optional<std::vector<std::uint8_t>> EoeServer::answer_arp(
    std::span<const std::uint8_t> frame) {
  if (frame.size() < kEthHeader + kArpSize) {
    ++stats_.malformed;
    return std::nullopt;
  }
  auto arp = frame.subspan(kEthHeader, kArpSize);
  // Ethernet / IPv4, 6 / 4 byte addresses, a request.
  if (be16(arp, 0) != 1 || be16(arp, 2) != kEtherIpv4 || arp[4] != 6 || arp[5] != 4 ||
      be16(arp, 6) != 1) {
    ++stats_.unsupported;
    return std::nullopt;
  }
  if (!ip_ || be32(arp, 24) != *ip_) {
    ++stats_.not_for_us;
    return std::nullopt;
  }
  auto out = reply_header(frame, mac_, kEtherArp, kEthHeader + kArpSize);
  put16(out, 14, 1);
  put16(out, 16, kEtherIpv4);
  out[18] = 6;
  out[19] = 4;
  put16(out, 20, 2);  // reply
  std::copy(mac_.begin(), mac_.end(), out.begin() + 22);
  put32(out, 28, *ip_);
  std::copy(arp.begin() + 8, arp.begin() + 18, out.begin() + 32);  // the requester's MAC and IP
  ++stats_.arp_replies;
  return out;
}

std::optional<std::vector<std::uint8_t>> EoeServer::answer_ipv4(
    std::span<const std::uint8_t> frame) {
  if (frame.size() < kEthHeader + kIpv4Header) {
    ++stats_.malformed;
    return std::nullopt;
  }
  auto ip = frame.subspan(kEthHeader);
  if ((ip[0] >> 4) != 4 || (ip[0] & 0x0F) < 5) {
    ++stats_.malformed;
    return std::nullopt;
  }
  if ((ip[0] & 0x0F) != 5) {  // options: not taken
    ++stats_.unsupported;
    return std::nullopt;
  }
  const std::size_t total = be16(ip, 2);
  if (total < kIpv4Header || total > ip.size() || internet_checksum(ip.first(kIpv4Header)) != 0) {
    ++stats_.malformed;
    return std::nullopt;
  }
  if (!ip_ || be32(ip, 16) != *ip_) {
    ++stats_.not_for_us;
    return std::nullopt;
  }
  // Not a fragment (MF clear, offset 0), ICMP.
  if ((be16(ip, 6) & 0x3FFF) != 0 || ip[9] != 1) {
    ++stats_.unsupported;
    return std::nullopt;
  }
  auto icmp = ip.subspan(kIpv4Header, total - kIpv4Header);
  if (icmp.size() < kIcmpHeader || internet_checksum(icmp) != 0) {
    ++stats_.malformed;
    return std::nullopt;
  }
  if (icmp[0] != 8 || icmp[1] != 0) {  // echo request only
    ++stats_.unsupported;
    return std::nullopt;
  }
  auto out = reply_header(frame, mac_, kEtherIpv4, kEthHeader + total);
  // IPv4: the request's header with the addresses swapped, a fresh TTL, the checksum again.
  std::copy(ip.begin(), ip.begin() + kIpv4Header, out.begin() + 14);
  out[14 + 1] = 0;  // DSCP/ECN
  out[14 + 6] = 0;  // flags / fragment offset
  out[14 + 7] = 0;
  out[14 + 8] = 64;  // TTL
  put16(out, 14 + 10, 0);
  put32(out, 14 + 12, *ip_);
  std::copy(ip.begin() + 12, ip.begin() + 16, out.begin() + 14 + 16);
  put16(out, 14 + 10,
        internet_checksum(std::span<const std::uint8_t>(out).subspan(14, kIpv4Header)));
  // ICMP: type 0 (echo reply), same identifier, sequence and data.
  const std::size_t at = 14 + kIpv4Header;
  std::copy(icmp.begin(), icmp.end(), out.begin() + static_cast<std::ptrdiff_t>(at));
  out[at] = 0;
  put16(out, at + 2, 0);
  put16(out, at + 2,
        internet_checksum(std::span<const std::uint8_t>(out).subspan(at, icmp.size())));
  ++stats_.icmp_replies;
  return out;
}

std::optional<std::vector<std::uint8_t>> EoeServer::respond(std::span<const std::uint8_t> frame) {
  if (frame.size() < kEthHeader || frame.size() > kMaxFrame) {
    ++stats_.malformed;
    return std::nullopt;
  }
  auto destination = frame.first(6);
  if (!is_broadcast(destination) &&
      !std::equal(destination.begin(), destination.end(), mac_.begin())) {
    ++stats_.not_for_us;
    return std::nullopt;
  }
  switch (be16(frame, 12)) {
    case kEtherArp:
      return answer_arp(frame);
    case kEtherIpv4:
      if (is_broadcast(destination)) break;  // no broadcast pings
      return answer_ipv4(frame);
    default:
      break;
  }
  ++stats_.unsupported;
  return std::nullopt;
}

std::vector<MailboxReply> EoeServer::handle(Esc& esc, const wire::MailboxHeader& header,
                                            wire::Bytes data) {
  (void)header;
  auto message = wire::decode_eoe(data);
  if (!message) {
    ++stats_.fragments_dropped;
    return {};
  }
  if (auto* fragment = std::get_if<wire::EoeFragment>(&*message)) {
    auto frame = take_fragment(*fragment);
    if (!frame) return {};
    auto answer = respond(*frame);
    if (!answer) return {};
    return reply_frame(esc, *answer);
  }
  auto respond_with = [](wire::EoeMessage m) -> std::vector<MailboxReply> {
    auto bytes = wire::encode_eoe(m);
    if (!bytes) return {};
    return {MailboxReply{wire::MailboxType::eoe, std::move(*bytes)}};
  };
  if (auto* set = std::get_if<wire::EoeSetIpRequest>(&*message)) {
    ++stats_.set_ip_requests;
    if (!config_.ip_support) {
      return respond_with(wire::EoeSetIpResponse{
          set->port, static_cast<std::uint16_t>(wire::EoeResult::no_ip_support)});
    }
    const auto& p = set->parameters;
    if (p.mac) mac_ = *p.mac;
    if (p.ip) ip_ = *p.ip;
    // Each service only names the parameters it changes: merge them.
    if (p.mac) parameters_.mac = p.mac;
    if (p.ip) parameters_.ip = p.ip;
    if (p.subnet_mask) parameters_.subnet_mask = p.subnet_mask;
    if (p.default_gateway) parameters_.default_gateway = p.default_gateway;
    if (p.dns_server) parameters_.dns_server = p.dns_server;
    if (p.dns_name) parameters_.dns_name = p.dns_name;
    return respond_with(
        wire::EoeSetIpResponse{set->port, static_cast<std::uint16_t>(wire::EoeResult::success)});
  }
  if (auto* other = std::get_if<wire::EoeOther>(&*message)) {
    // Requests (even types from 4 on) get their response type with "unsupported frame type";
    // responses and time stamps from the master make no sense and are dropped.
    const auto type = static_cast<unsigned>(other->header.type);
    if (type >= 4 && type <= 8 && type % 2 == 0) {
      ++stats_.other_requests;
      wire::EoeHeader h;
      h.type = static_cast<wire::EoeFrameType>(type + 1);
      h.port = other->header.port;
      h.last_fragment = true;
      const auto result = static_cast<std::uint16_t>(wire::EoeResult::unsupported_frame_type);
      h.fragment_number = result & 0x3F;
      h.offset_blocks = (result >> 6) & 0x3F;
      h.frame_number = static_cast<std::uint8_t>(result >> 12);
      return respond_with(wire::EoeOther{h, {}});
    }
  }
  ++stats_.fragments_dropped;
  return {};
}

EoeServer* eoe_server_of(Esc& esc) noexcept {
  auto* app = dynamic_cast<StandardApplication*>(&esc.application());
  return app != nullptr ? app->eoe_server() : nullptr;
}

}  // namespace ecat::sim
