#include <vector>

#include <ecat/master/ring_break.hpp>

namespace ecat::master {

namespace {

bool link_up(const RingPortReading& r, std::uint8_t port) {
  return r.dl_status && r.dl_status->ports[port].physical_link;
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

}  // namespace ecat::master
