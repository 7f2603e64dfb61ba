#include <charconv>
#include <string>
#include <utility>
#include <vector>

#include <arpa/inet.h>
#include <fmt/format.h>

#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/redundant_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/link/xdp_link.hpp>
#include <ecat/log.hpp>

namespace ecat::link {

namespace {

constexpr std::string_view kAcceptedForms =
    "accepted forms: raw:IFACE[,busy_poll=US][,spin], raw:PRIMARY,SECONDARY, "
    "xdp:IFACE[,queue=N][,busy_poll=US][,spin][,native|,generic][,copy|,zero_copy], "
    "udp:HOST:PORT, udp:[IPV6]:PORT, udp:HOST";

Error bad_spec(std::string_view spec, std::string_view why) {
  return Error(Errc::invalid_argument,
               fmt::format("invalid link '{}': {} ({})", spec, why, kAcceptedForms));
}

bool is_ipv6_literal(std::string_view text) {
  if (text.size() >= INET6_ADDRSTRLEN) return false;
  const std::string copy(text);
  unsigned char buffer[16];
  return ::inet_pton(AF_INET6, copy.c_str(), buffer) == 1;
}

Result<std::uint16_t> parse_port(std::string_view spec, std::string_view text) {
  unsigned value = 0;
  const auto* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end || value == 0 || value > 65535) {
    return bad_spec(spec, fmt::format("port '{}' is not a number from 1 to 65535", text));
  }
  return static_cast<std::uint16_t>(value);
}

Result<std::unique_ptr<Link>> open_udp(std::string_view spec, std::string_view rest) {
  std::string_view host = rest;
  std::uint16_t port = wire::kEtherCatUdpPort;
  if (rest.empty()) return bad_spec(spec, "no host after 'udp:'");
  if (rest.front() == '[') {
    const auto close = rest.find(']');
    if (close == std::string_view::npos) return bad_spec(spec, "'[' without a closing ']'");
    host = rest.substr(1, close - 1);
    const std::string_view after = rest.substr(close + 1);
    if (!after.empty()) {
      if (after.front() != ':') return bad_spec(spec, "expected ':PORT' after ']'");
      auto parsed = parse_port(spec, after.substr(1));
      if (!parsed) return std::move(parsed).error();
      port = *parsed;
    }
    if (!is_ipv6_literal(host)) {
      return bad_spec(spec, fmt::format("'{}' inside brackets is not an IPv6 address", host));
    }
  } else if (rest.find(':') != rest.rfind(':')) {
    // Several colons without brackets: only a bare IPv6 address makes sense.
    if (!is_ipv6_literal(rest)) {
      return bad_spec(spec, "an IPv6 address with a port must be written in brackets");
    }
  } else if (const auto colon = rest.find(':'); colon != std::string_view::npos) {
    host = rest.substr(0, colon);
    auto parsed = parse_port(spec, rest.substr(colon + 1));
    if (!parsed) return std::move(parsed).error();
    port = *parsed;
  }
  if (host.empty()) return bad_spec(spec, "the host is empty");
  ECAT_LOG(LogLevel::debug, "link",
           fmt::format("opening EtherCAT-over-UDP link to {} port {}", host, port));
  auto link = UdpLink::connect(std::string(host), port);
  if (!link) return std::move(link).error();
  ECAT_LOG(LogLevel::info, "link",
           fmt::format("opened EtherCAT-over-UDP link to {} port {}", host, port));
  return std::unique_ptr<Link>(std::move(*link));
}

// "IFACE,option,key=value,..." of raw: and xdp: specs.
struct InterfaceSpec {
  std::string interface;
  std::vector<std::pair<std::string_view, std::string_view>> options;  // key, value ("" if none)
};

InterfaceSpec split_interface_spec(std::string_view rest) {
  InterfaceSpec out;
  std::size_t comma = rest.find(',');
  out.interface = std::string(rest.substr(0, comma));
  while (comma != std::string_view::npos) {
    rest = rest.substr(comma + 1);
    comma = rest.find(',');
    const std::string_view item = rest.substr(0, comma);
    const auto equals = item.find('=');
    if (equals == std::string_view::npos) {
      out.options.emplace_back(item, std::string_view());
    } else {
      out.options.emplace_back(item.substr(0, equals), item.substr(equals + 1));
    }
  }
  return out;
}

Result<int> parse_number(std::string_view spec, std::string_view key, std::string_view text,
                         int max) {
  int value = 0;
  const auto* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end || value < 0 || value > max) {
    return bad_spec(spec, fmt::format("{}='{}' is not a number from 0 to {}", key, text, max));
  }
  return value;
}

Result<std::unique_ptr<Link>> open_raw(std::string_view spec, std::string_view rest) {
  const InterfaceSpec parts = split_interface_spec(rest);
  if (parts.interface.empty()) return bad_spec(spec, "no interface after 'raw:'");
  RawLinkOptions options;
  options.interface = parts.interface;
  // raw:PRIMARY,SECONDARY: an item that is neither a known option nor KEY=VALUE names the
  // redundant ring's secondary port.
  std::string secondary;
  bool latency_options = false;
  for (const auto& [key, value] : parts.options) {
    if (key == "busy_poll") {
      auto us = parse_number(spec, key, value, 1'000'000);
      if (!us) return std::move(us).error();
      options.busy_poll_us = *us;
      latency_options = true;
    } else if (key == "spin" && value.empty()) {
      options.spin = true;
      latency_options = true;
    } else if (value.empty() && !key.empty() && secondary.empty()) {
      secondary = std::string(key);
    } else if (value.empty()) {
      return bad_spec(spec, "a redundant ring is raw:PRIMARY,SECONDARY, two interfaces");
    } else {
      return bad_spec(spec, fmt::format("unknown raw link option '{}'", key));
    }
  }
  if (!secondary.empty()) {
    if (latency_options) {
      return bad_spec(spec, "busy_poll and spin apply to a single raw port, not a redundant ring");
    }
    ECAT_LOG(LogLevel::debug, "link",
             fmt::format("opening redundant raw Ethernet link on {} and {}", options.interface,
                         secondary));
    auto link = RedundantLink::open_raw(options.interface, secondary);
    if (!link) return std::move(link).error();
    ECAT_LOG(LogLevel::info, "link",
             fmt::format("opened redundant raw Ethernet link on {} and {}", options.interface,
                         secondary));
    return std::unique_ptr<Link>(std::move(*link));
  }
  ECAT_LOG(LogLevel::debug, "link", fmt::format("opening raw Ethernet link on {}", rest));
  auto link = RawLink::open(std::move(options));
  if (!link) return std::move(link).error();
  ECAT_LOG(LogLevel::info, "link", fmt::format("opened raw Ethernet link on {}", rest));
  return std::unique_ptr<Link>(std::move(*link));
}

Result<std::unique_ptr<Link>> open_xdp(std::string_view spec, std::string_view rest) {
  const InterfaceSpec parts = split_interface_spec(rest);
  if (parts.interface.empty()) return bad_spec(spec, "no interface after 'xdp:'");
  XdpLinkOptions options;
  options.interface = parts.interface;
  for (const auto& [key, value] : parts.options) {
    if (key == "queue") {
      auto queue = parse_number(spec, key, value, 4095);
      if (!queue) return std::move(queue).error();
      options.queue_id = static_cast<std::uint32_t>(*queue);
    } else if (key == "busy_poll") {
      auto us = parse_number(spec, key, value, 1'000'000);
      if (!us) return std::move(us).error();
      options.busy_poll_us = *us;
    } else if (key == "spin" && value.empty()) {
      options.spin = true;
    } else if (key == "native" && value.empty()) {
      options.attach = XdpAttachMode::native;
    } else if (key == "generic" && value.empty()) {
      options.attach = XdpAttachMode::generic;
    } else if (key == "copy" && value.empty()) {
      options.copy = XdpCopyMode::copy;
    } else if (key == "zero_copy" && value.empty()) {
      options.copy = XdpCopyMode::zero_copy;
    } else {
      return bad_spec(spec, fmt::format("unknown xdp link option '{}'", key));
    }
  }
  ECAT_LOG(LogLevel::debug, "link", fmt::format("opening AF_XDP link on {}", rest));
  auto link = XdpLink::open(std::move(options));
  if (!link) return std::move(link).error();
  const XdpLinkInfo info = (*link)->info();
  ECAT_LOG(
      LogLevel::info, "link",
      fmt::format("opened AF_XDP link on {} (queue {}, {} XDP, {} mode{})", rest, info.queue_id,
                  info.native ? "native" : "generic", info.zero_copy ? "zero-copy" : "copy",
                  info.busy_poll ? ", busy polling" : ""));
  return std::unique_ptr<Link>(std::move(*link));
}

Result<std::unique_ptr<Link>> open_spec(std::string_view spec) {
  const auto colon = spec.find(':');
  if (colon == std::string_view::npos) return bad_spec(spec, "no kind prefix");
  const std::string_view kind = spec.substr(0, colon);
  const std::string_view rest = spec.substr(colon + 1);
  if (kind == "raw") return open_raw(spec, rest);
  if (kind == "xdp") return open_xdp(spec, rest);
  if (kind == "udp") {
    if (rest.find(',') != std::string_view::npos) {
      return Error(Errc::unsupported,
                   fmt::format("link '{}': cable redundancy needs two raw Ethernet ports "
                               "(raw:PRIMARY,SECONDARY); EtherCAT over UDP cannot close a ring",
                               spec));
    }
    return open_udp(spec, rest);
  }
  if (kind == "sim") {
    return Error(Errc::unsupported,
                 fmt::format("link '{}': the built-in simulator is not available yet at the "
                             "link layer, which cannot depend on it: open it with "
                             "ecat::sim::open_backend (<ecat/sim/backend.hpp>), or serve the ring "
                             "with `ecat sim --ring RING.yaml --udp ADDR:PORT` and use "
                             "udp:ADDR:PORT",
                             spec));
  }
  return bad_spec(spec, fmt::format("unknown kind '{}'", kind));
}

}  // namespace

Result<std::unique_ptr<Link>> open_link(std::string_view spec) {
  auto link = open_spec(spec);
  if (!link) ECAT_LOG(LogLevel::warn, "link", link.error().describe());
  return link;
}

}  // namespace ecat::link
