// "eoe_device": a network node behind the ring over EoE, of the simulator's own make (vendor
// 0x00000ACE, product 0x00000E0E), shaped like an EtherCAT-to-Ethernet gateway terminal (an
// EL6601-class device): CoE + EoE in the SII, a 128-byte mailbox at 0x1000 / 0x1080 (118 bytes of
// frame per fragment, 96 in every fragment but the last: a default ping of 98 bytes goes whole,
// `ping -s 200` in three fragments), no process data.
// Its EoE server (sim/eoe_server.hpp) answers ARP and ICMP echo for its address.
//   options: ip=192.168.1.2 (none: only after Set IP Parameter), mac=02:00:0a:ce:00:01
#include <charconv>
#include <string>

#include <fmt/format.h>

#include "sim/devices/profiles.hpp"

namespace ecat::sim::devices {

namespace {

Result<std::uint32_t> parse_ipv4(const std::string& text) {
  std::uint32_t out = 0;
  const char* p = text.data();
  const char* end = text.data() + text.size();
  for (int i = 0; i < 4; ++i) {
    unsigned part = 0;
    auto [next, ec] = std::from_chars(p, end, part);
    if (ec != std::errc{} || next == p || part > 255 || (i < 3 && (next == end || *next != '.'))) {
      return Error(Errc::invalid_argument,
                   fmt::format("device option ip: '{}' is not an IPv4 address (a.b.c.d)", text));
    }
    out = (out << 8) | part;
    p = i < 3 ? next + 1 : next;
  }
  if (p != end) {
    return Error(Errc::invalid_argument,
                 fmt::format("device option ip: '{}' is not an IPv4 address (a.b.c.d)", text));
  }
  return out;
}

Result<std::array<std::uint8_t, 6>> parse_mac(const std::string& text) {
  std::array<std::uint8_t, 6> out{};
  const auto bad = [&] {
    return Error(Errc::invalid_argument,
                 fmt::format("device option mac: '{}' is not a unicast MAC address "
                             "(xx:xx:xx:xx:xx:xx)",
                             text));
  };
  if (text.size() != 17) return bad();
  for (std::size_t i = 0; i < 6; ++i) {
    if (i < 5 && text[i * 3 + 2] != ':') return bad();
    auto [next, ec] = std::from_chars(text.data() + i * 3, text.data() + i * 3 + 2, out[i], 16);
    if (ec != std::errc{} || next != text.data() + i * 3 + 2) return bad();
  }
  if ((out[0] & 0x01) != 0) return bad();  // a multicast address cannot be a device's
  return out;
}

}  // namespace

Result<std::unique_ptr<Esc>> make_eoe_device(const DeviceConfig& config) {
  if (auto ok = check_options(config, {"ip", "mac"}); !ok) return ok.error();
  StandardConfig cfg;
  if (auto it = config.options.find("ip"); it != config.options.end()) {
    auto ip = parse_ipv4(it->second);
    if (!ip) return ip.error();
    cfg.eoe.ip = *ip;
  }
  if (auto it = config.options.find("mac"); it != config.options.end()) {
    auto mac = parse_mac(it->second);
    if (!mac) return mac.error();
    cfg.eoe.mac = *mac;
  }
  wire::SiiImage sii;
  sii.identity = {kSimVendorId, 0x00000E0E, 0x00000001, 0x00000000};
  sii.standard_mailbox = {0x1000, 128, 0x1080, 128};
  sii.mailbox_protocols = wire::mailbox_protocol::kCoe | wire::mailbox_protocol::kEoe;
  SiiStrings strings(sii);
  wire::SiiGeneral general;
  general.order_index = strings.add("ECAT-EOE");
  general.group_index = strings.add("Test");
  general.name_index = strings.add("ecat sim EoE device");
  general.coe_details = wire::sii_coe_detail::kSdo | wire::sii_coe_detail::kSdoInfo;
  general.eoe_details = 0x01;  // EoE enabled
  general.physical_port = 0x0011;
  sii.general = general;
  sii.fmmus = {wire::sii_fmmu_usage::kMailboxState};
  sii.sync_managers = {{0x1000, 128, 0x26, 0, 0x01, wire::sii_sm_type::kMailboxOut},
                       {0x1080, 128, 0x22, 0, 0x01, wire::sii_sm_type::kMailboxIn}};

  add_sii_identity(cfg.dictionary, sii);
  cfg.sii = sii;
  if (auto ok = apply_common_options(config, cfg); !ok) return ok.error();
  const wire::SiiImage image = cfg.sii;
  EscHardware hw;
  hw.ports =
      wire::PortDescriptor{{wire::PortType::mii, wire::PortType::mii,
                            wire::PortType::not_implemented, wire::PortType::not_implemented}};
  return build_device(config, hw, image, std::make_unique<StandardApplication>(std::move(cfg)));
}

}  // namespace ecat::sim::devices
