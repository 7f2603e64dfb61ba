#include <charconv>
#include <string>

#include <arpa/inet.h>
#include <fmt/format.h>

#include <ecat/link/open.hpp>
#include <ecat/link/raw_link.hpp>
#include <ecat/link/udp_link.hpp>
#include <ecat/log.hpp>

namespace ecat::link {

namespace {

constexpr std::string_view kAcceptedForms =
    "accepted forms: raw:IFACE, udp:HOST:PORT, udp:[IPV6]:PORT, udp:HOST";

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

Result<std::unique_ptr<Link>> open_spec(std::string_view spec) {
  const auto colon = spec.find(':');
  if (colon == std::string_view::npos) return bad_spec(spec, "no kind prefix");
  const std::string_view kind = spec.substr(0, colon);
  const std::string_view rest = spec.substr(colon + 1);
  if (kind == "raw") {
    if (rest.empty()) return bad_spec(spec, "no interface after 'raw:'");
    RawLinkOptions options;
    options.interface = std::string(rest);
    ECAT_LOG(LogLevel::debug, "link", fmt::format("opening raw Ethernet link on {}", rest));
    auto link = RawLink::open(std::move(options));
    if (!link) return std::move(link).error();
    ECAT_LOG(LogLevel::info, "link", fmt::format("opened raw Ethernet link on {}", rest));
    return std::unique_ptr<Link>(std::move(*link));
  }
  if (kind == "udp") return open_udp(spec, rest);
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
