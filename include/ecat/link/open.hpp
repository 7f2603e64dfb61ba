// Opens a link from a one-line spec, as the `ecat` command and configuration files name them.
#pragma once

#include <memory>
#include <string_view>

#include <ecat/link/link.hpp>
#include <ecat/result.hpp>

namespace ecat::link {

// Accepted specs:
//   raw:IFACE          EtherCAT on Ethernet through network interface IFACE (needs CAP_NET_RAW),
//                      RawLink; options after commas: busy_poll=US (SO_BUSY_POLL), spin (receive
//                      never sleeps), e.g. raw:eth0,busy_poll=50,spin
//   xdp:IFACE          the same through an AF_XDP socket (XdpLink; needs CAP_NET_ADMIN, CAP_NET_RAW
//                      and CAP_BPF, and ecat built with libxdp); options: queue=N, busy_poll=US,
//                      spin, native or generic (XDP attach mode), copy or zero_copy
//   raw:PRI,SEC        a redundant ring on two interfaces (RedundantLink): the second item after
//                      'raw:' that is not an option names the secondary port; UDP cannot be
//                      redundant. The latency options apply to single-port raw links only.
//   udp:HOST:PORT      EtherCAT over UDP to HOST (IPv4 address or name) at PORT
//   udp:[IPV6]:PORT    the same with an IPv6 address
//   udp:HOST           port 34980 (0x88A4); HOST may also be a bare IPv6 address
// "sim:RING.yaml" is reserved for the built-in simulator, which the link layer cannot reach (a
// lower layer never includes a higher one): ecat::sim::open_backend (<ecat/sim/backend.hpp>)
// accepts it along with every spec here.
// A malformed spec is Errc::invalid_argument naming the spec and these forms.
Result<std::unique_ptr<Link>> open_link(std::string_view spec);

}  // namespace ecat::link
