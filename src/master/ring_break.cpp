#include <array>
#include <string>
#include <vector>

#include <fmt/format.h>

#include <ecat/master/ring_break.hpp>

namespace ecat::master {

namespace {

bool link_up(const RingPortReading& r, std::uint8_t port) {
  return r.dl_status && r.dl_status->ports[port].physical_link;
}

// Frame order through an ESC: port 0 in, then the downstream ports in this order.
constexpr std::array<std::uint8_t, 3> kDownstreamOrder{3, 1, 2};

// Where in kDownstreamOrder a port is (port 0: before all of them).
std::size_t order_of(std::uint8_t port) {
  for (std::size_t i = 0; i < kDownstreamOrder.size(); ++i)
    if (kDownstreamOrder[i] == port) return i + 1;
  return 0;
}

}  // namespace

std::optional<link::RingBreak> locate_ring_break(std::span<const RingPortReading> slaves) {
  if (slaves.empty()) return std::nullopt;
  const auto at = [&](link::RingBreak::Where where, std::size_t i) {
    link::RingBreak b;
    b.where = where;
    b.before_position = b.after_position = i;
    b.before_station = b.after_station = slaves[i].station;
    b.before_port = where == link::RingBreak::Where::primary_cable ? 0 : 1;
    return b;
  };
  if (!slaves[0].dl_status) return std::nullopt;
  if (!link_up(slaves[0], 0)) return at(link::RingBreak::Where::primary_cable, 0);
  for (std::size_t i = 0; i + 1 < slaves.size(); ++i) {
    if (!slaves[i].dl_status || !slaves[i + 1].dl_status) return std::nullopt;
    if (!link_up(slaves[i], 1) || !link_up(slaves[i + 1], 0)) {
      link::RingBreak b;
      b.where = link::RingBreak::Where::between_slaves;
      b.before_position = i;
      b.before_station = slaves[i].station;
      b.after_position = i + 1;
      b.after_station = slaves[i + 1].station;
      return b;
    }
  }
  const std::size_t last = slaves.size() - 1;
  if (!link_up(slaves[last], 1)) return at(link::RingBreak::Where::secondary_cable, last);
  return std::nullopt;
}

std::optional<link::RingBreak> locate_ring_break(std::span<const RingPortReading> slaves,
                                                 const RingTree& shape) {
  const std::size_t n = slaves.size();
  if (n == 0 || shape.slaves.size() != n) return std::nullopt;
  // The ring: the last slave and its ancestors, in ring order.
  std::vector<bool> ring(n, false);
  std::optional<std::size_t> k = n - 1;
  while (k && !ring[*k]) {
    ring[*k] = true;
    k = shape.slaves[*k].parent;
  }
  if (!slaves[0].dl_status) return std::nullopt;
  if (!link_up(slaves[0], 0)) {
    link::RingBreak b;
    b.where = link::RingBreak::Where::primary_cable;
    b.before_station = b.after_station = slaves[0].station;
    b.before_port = 0;
    return b;
  }
  for (std::size_t c = 1; c < n; ++c) {
    if (!ring[c] || !shape.slaves[c].parent) continue;
    const std::size_t p = *shape.slaves[c].parent;
    const std::uint8_t port = shape.slaves[c].parent_port;
    if (!slaves[p].dl_status || !slaves[c].dl_status) return std::nullopt;
    if (!link_up(slaves[p], port) || !link_up(slaves[c], 0)) {
      link::RingBreak b;
      b.where = link::RingBreak::Where::between_slaves;
      b.before_position = p;
      b.before_station = slaves[p].station;
      b.before_port = port;
      b.after_position = c;
      b.after_station = slaves[c].station;
      return b;
    }
  }
  const std::size_t last = n - 1;
  const std::uint8_t back = shape.return_port.value_or(1);
  if (!slaves[last].dl_status) return std::nullopt;
  if (!link_up(slaves[last], back)) {
    link::RingBreak b;
    b.where = link::RingBreak::Where::secondary_cable;
    b.before_position = b.after_position = last;
    b.before_station = b.after_station = slaves[last].station;
    b.before_port = back;
    return b;
  }
  return std::nullopt;
}

Result<RingTree> broken_ring_tree(std::span<const std::uint16_t> dl_status,
                                  std::span<const std::optional<wire::PortDescriptor>> ports,
                                  std::span<const std::uint16_t> stations,
                                  std::size_t primary_side) {
  const std::size_t n = dl_status.size();
  const std::size_t k = primary_side;
  if (n == 0) return Error(Errc::invalid_argument, "broken ring's shape: no slaves");
  if (k > n) {
    return Error(Errc::invalid_argument,
                 fmt::format("broken ring's shape: {} slaves on the primary's side of {}", k, n));
  }
  const auto who = [&](std::size_t i) {
    return fmt::format("slave {} (station 0x{:04X})", i, i < stations.size() ? stations[i] : 0);
  };
  std::vector<wire::DlStatus> dl(n);
  for (std::size_t i = 0; i < n; ++i)
    dl[i] = wire::DlStatus::decode(dl_status[i]);
  const auto link = [&](std::size_t i, std::uint8_t port) {
    return dl[i].ports[port].physical_link;
  };
  // The port descriptors, when every one was read and none says a port with a link is missing
  // (a simulated ring may cable any port).
  bool trusted = ports.size() == n;
  for (std::size_t i = 0; trusted && i < n; ++i) {
    if (!ports[i]) continue;
    for (std::uint8_t p = 0; p < 4; ++p)
      if (link(i, p) && ports[i]->ports[p] == wire::PortType::not_implemented) trusted = false;
  }
  const auto has_port = [&](std::size_t i, std::uint8_t port) {
    return !trusted || !ports[i] || ports[i]->ports[port] != wire::PortType::not_implemented;
  };
  // Port 0: the cable towards the master. Only the first slave behind the break (slave 0 with
  // the primary's cable cut) has none; with the secondary's cut, every one has it.
  for (std::size_t i = 0; i < n; ++i) {
    if (link(i, 0) != (i != k)) {
      return Error(Errc::malformed,
                   fmt::format("broken ring's shape: {} has {} link on port 0, which does not "
                               "fit a ring broken after {} slave(s) on the primary's side",
                               who(i), link(i, 0) ? "a" : "no", k));
    }
  }

  RingTree tree;
  tree.slaves.resize(n);
  // The pieces, each a tree of its own over its slaves' open ports.
  const auto piece = [&](std::size_t first, std::size_t last,
                         bool returns) -> Result<std::optional<std::uint8_t>> {
    auto sub = ring_tree(dl_status.subspan(first, last - first),
                         stations.size() >= last ? stations.subspan(first, last - first)
                                                 : std::span<const std::uint16_t>{},
                         returns);
    if (!sub) {
      return Error(sub.error().code(),
                   fmt::format("broken ring's shape: the {} side (positions {}..{}): {}",
                               first == 0 ? "primary's" : "secondary's", first, last - 1,
                               sub.error().message()));
    }
    for (std::size_t i = 0; i < sub->slaves.size(); ++i) {
      const auto& from = sub->slaves[i];
      auto& to = tree.slaves[first + i];
      if (from.parent) to.parent = first + *from.parent;
      to.parent_port = from.parent_port;
      for (std::size_t p = 0; p < 4; ++p)
        if (from.children[p]) to.children[p] = first + *from.children[p];
    }
    return sub->return_port;
  };
  if (k > 0) {
    auto r = piece(0, k, false);
    if (!r) return r.error();
  }
  if (k < n) {
    auto back = piece(k, n, true);
    if (!back) return back.error();
    if (!*back) {
      return Error(Errc::malformed,
                   fmt::format("broken ring's shape: the secondary's side has no open port left "
                               "for the cable back to the secondary port (on {})",
                               who(n - 1)));
    }
    tree.return_port = *back;
  }

  // The ports a cable may have left from without link: on `from` and its ancestors, after the
  // ports their children use in frame order.
  struct Candidate {
    std::size_t slave;
    std::uint8_t port;
  };
  const auto free_ports = [&](std::size_t from) {
    std::vector<Candidate> out;
    std::optional<std::size_t> s = from;
    while (s) {
      std::size_t used = 0;
      for (std::uint8_t p = 1; p < 4; ++p)
        if (tree.slaves[*s].children[p]) used = std::max(used, order_of(p));
      for (std::size_t o = used; o < kDownstreamOrder.size(); ++o) {
        const std::uint8_t p = kDownstreamOrder[o];
        if (!link(*s, p) && has_port(*s, p)) out.push_back({*s, p});
      }
      s = tree.slaves[*s].parent;
    }
    return out;
  };
  const auto one_of = [&](const std::vector<Candidate>& c,
                          std::string_view what) -> Result<Candidate> {
    if (c.size() == 1) return c.front();
    if (c.empty()) {
      return Error(Errc::not_found,
                   fmt::format("broken ring's shape: no port without link for {}", what));
    }
    std::string list;
    for (const auto& x : c)
      list += fmt::format("{}{}'s port {}", list.empty() ? "" : ", ", who(x.slave), x.port);
    return Error(Errc::not_found,
                 fmt::format("broken ring's shape: {} may be at any of {}: the DL status does "
                             "not tell a broken cable from a port never cabled",
                             what, list));
  };
  if (k == n) {
    // The secondary's cable cut: it left the last slave (a leaf, the last in frame order).
    std::vector<Candidate> c;
    for (const auto p : kDownstreamOrder)
      if (!link(n - 1, p) && has_port(n - 1, p)) c.push_back({n - 1, p});
    auto back = one_of(c, "the secondary's cable");
    if (!back) return back.error();
    tree.return_port = back->port;
  } else if (k > 0) {
    auto at = one_of(free_ports(k - 1), fmt::format("the cable into {}", who(k)));
    if (!at) return at.error();
    tree.slaves[k].parent = at->slave;
    tree.slaves[k].parent_port = at->port;
    tree.slaves[at->slave].children[at->port] = k;
  }
  return tree;
}

}  // namespace ecat::master
