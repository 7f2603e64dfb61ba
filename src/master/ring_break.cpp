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

}  // namespace ecat::master
