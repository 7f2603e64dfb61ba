#include <algorithm>
#include <array>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>

#include <ecat/exec/transact.hpp>
#include <ecat/master/al_control.hpp>
#include <ecat/master/startup.hpp>
#include <ecat/wire/bytes.hpp>

namespace ecat::master {
namespace {

namespace reg = wire::reg;
using Clock = exec::Clock;

// Auto-increment addressing reaches positions 0 .. 0x8000 (ADP = -position as a 16-bit value).
constexpr std::uint32_t kMaxAutoIncrementSlaves = 32769;

std::array<std::uint8_t, 2> le16(std::uint16_t v) {
  std::array<std::uint8_t, 2> out{};
  wire::store_le16(out.data(), v);
  return out;
}

}  // namespace

std::chrono::nanoseconds auto_frame_timeout(std::uint16_t count) noexcept {
  const auto us = 200 + 40 * static_cast<std::int64_t>(count);
  const auto ms = (us + 999) / 1000;
  return std::chrono::milliseconds(std::clamp<std::int64_t>(ms, 5, 10));
}

exec::Task<Result<std::uint16_t>> count_slaves(exec::EventLoop& loop, bus::Bus& bus,
                                               bus::TransactOptions options) {
  bus::Transaction tx;
  tx.brd(reg::kType, 1);
  auto reply = co_await exec::transact(loop, bus, std::move(tx), options);
  if (!reply) co_return reply.error().context("counting slaves (BRD 0x0000)");
  co_return reply->wkc(0);
}

exec::Task<Result<std::optional<LinkPicture>>> read_link_picture(exec::EventLoop& loop,
                                                                 bus::Bus& bus, std::uint16_t count,
                                                                 exec::AsyncMutex* addressing) {
  if (count == 0 || count > kMaxAutoIncrementSlaves) co_return std::nullopt;
  bus::Transaction tx;
  for (std::uint32_t pos = 0; pos < count; ++pos)
    tx.aprd(static_cast<std::uint16_t>(pos), reg::kDlStatus, 2);
  // By ring position also on a redundant ring that is broken (through the port whose frame
  // reaches each position), with the sides the ring divides into.
  exec::AsyncMutex own(loop);
  RingSides sides{count, count};
  auto reply = co_await transact_by_position(loop, bus, addressing ? *addressing : own,
                                             std::move(tx), {}, &sides);
  if (!reply) co_return reply.error().context("reading DL status by position");
  if (sides.total != count) co_return std::nullopt;  // the ring changed since the count
  LinkPicture picture;
  picture.ports.reserve(count);
  std::uint32_t links = 0;
  for (std::uint32_t pos = 0; pos < count; ++pos) {
    // A position that does not answer: the ring changed under the read.
    if ((*reply)[pos].wkc != 1) co_return std::nullopt;
    const auto dl = wire::DlStatus::decode(wire::load_le16((*reply)[pos].data.data()));
    std::uint16_t bits = 0;
    for (std::uint8_t port = 1; port < 4; ++port) {
      const auto& p = dl.ports[port];
      // A link not (yet) carrying frames: a partner coming up, or a port held closed.
      if (p.physical_link != p.communication || (p.physical_link && p.loop_closed)) {
        picture.complete = false;
      }
      if (p.physical_link) ++links;
      bits = static_cast<std::uint16_t>(bits | (p.physical_link ? 1u << port : 0u) |
                                        (p.communication ? 1u << (port + 4) : 0u) |
                                        (p.loop_closed ? 1u << (port + 8) : 0u));
    }
    picture.ports.push_back(bits);
  }
  // In a tree every slave but the first hangs from exactly one port 1-3 of another: a link more
  // leads to a device the count does not hold (booting, or the master's second port). On a
  // redundant link the last slave's port 1 is the cable back to the second port: not a slave;
  // and a break between two slaves leaves the first slave behind it hanging from the secondary
  // port instead of from a port 1-3 (a cut master cable leaves one side only: a plain line).
  if (bus.info().redundancy && (picture.ports.back() & (1u << 1)) != 0) --links;
  const bool broken_between = sides.primary > 0 && sides.primary < sides.total;
  if (links != count - 1u - (broken_between ? 1u : 0u)) picture.complete = false;
  co_return picture;
}

exec::Task<Result<std::uint16_t>> await_stable_count(exec::EventLoop& loop, bus::Bus& bus,
                                                     ScanOptions options,
                                                     exec::AsyncMutex* addressing) {
  const auto start = Clock::now();
  std::optional<std::uint16_t> current;
  Clock::time_point since{};
  unsigned samples = 0;
  std::optional<Error> last_error;
  std::optional<LinkPicture> last_picture;
  while (true) {
    auto count =
        co_await count_slaves(loop, bus, {options.poll + std::chrono::milliseconds(50), 0});
    const auto now = Clock::now();
    if (!count && count.error().code() == Errc::closed) {
      // The bus stopped (the session ended) or its link was closed: no later poll can answer.
      co_return count.error().context("discovering the ring");
    }
    if (!count) {
      last_error = count.error();
      current.reset();
      samples = 0;
      last_picture.reset();
    } else if (!current || *current != *count) {
      current = *count;
      since = now;
      samples = 1;
      last_picture.reset();
    } else {
      ++samples;
    }
    if (current && *current > 0 && samples >= 2 && now - since >= options.stable) {
      co_return *current;
    }
    if (current && *current > 0 && options.link_check) {
      // The early end: the same count at two polls, and both times the same complete link
      // picture (every open port leads to a counted slave, nothing half up).
      auto picture = co_await read_link_picture(loop, bus, *current, addressing);
      if (picture && *picture && (*picture)->complete) {
        if (samples >= 2 && last_picture && last_picture->ports == (*picture)->ports) {
          co_return *current;
        }
        last_picture = std::move(**picture);
      } else {
        last_picture.reset();
      }
    }
    if (now - start >= options.timeout) {
      std::string seen = current ? fmt::format("last count {}", *current) : "no reply";
      Error error(
          Errc::timeout,
          fmt::format(
              "no stable slave count within {} ms ({})",
              std::chrono::duration_cast<std::chrono::milliseconds>(options.timeout).count(),
              seen));
      if (last_error && !current) co_return last_error->context(error.message());
      co_return error;
    }
    co_await exec::sleep_for(loop, options.poll);
  }
}

Result<void> check_addressing(std::uint16_t count, std::uint16_t base_station) {
  if (count > kMaxAutoIncrementSlaves) {
    return Error(Errc::out_of_range,
                 fmt::format("{} slaves exceed the {} that auto-increment addressing reaches",
                             count, kMaxAutoIncrementSlaves));
  }
  if (base_station == 0) {
    return Error(Errc::invalid_argument, "base station 0 is not a valid station address");
  }
  if (count > 0 && static_cast<std::uint32_t>(base_station) + count - 1 > 0xFFFF) {
    return Error(Errc::out_of_range,
                 fmt::format("stations 0x{:04x} + {} slaves run past 0xffff", base_station, count));
  }
  return ok();
}

namespace {

// The datagrams a port's copy of every frame carries as NOP while it lives (Link::set_port_nop),
// so that they reach the slaves through the other port only; ended on every way out.
class PortMask {
 public:
  PortMask(bus::Bus& bus, link::Port port, link::DatagramSelector selector)
      : bus_(bus),
        port_(port),
        result_(bus.set_port_nop(port, link::NopSlot::addressing, selector)) {}
  ~PortMask() {
    if (result_) (void)bus_.set_port_nop(port_, link::NopSlot::addressing, std::nullopt);
  }
  PortMask(const PortMask&) = delete;
  PortMask& operator=(const PortMask&) = delete;
  const Result<void>& result() const { return result_; }

 private:
  bus::Bus& bus_;
  link::Port port_;
  Result<void> result_;
};

link::DatagramSelector every_station_write() {
  return {static_cast<std::uint8_t>(wire::Command::apwr), 0, reg::kStationAddress, true};
}

// Station base + first + k to the k-th slave from `port`'s side (position k), for k < count.
exec::Task<Result<void>> assign_from(exec::EventLoop& loop, bus::Bus& bus,
                                     std::optional<link::Port> port, std::uint16_t first,
                                     std::uint16_t count, std::uint16_t base_station) {
  if (count == 0) co_return ok();
  std::optional<PortMask> mask;
  if (port) {
    // The other port's copy carries the writes as NOPs.
    mask.emplace(bus, *port == link::Port::primary ? link::Port::secondary : link::Port::primary,
                 every_station_write());
    if (!mask->result()) co_return mask->result().error().context("assigning station addresses");
  }
  bus::Transaction write;
  for (std::uint16_t k = 0; k < count; ++k) {
    write.apwr(k, reg::kStationAddress, le16(static_cast<std::uint16_t>(base_station + first + k)));
  }
  auto written = co_await exec::transact(loop, bus, std::move(write));
  if (!written) co_return written.error().context("assigning station addresses");
  for (std::uint16_t k = 0; k < count; ++k) {
    if (written->wkc(k) != 1) {
      co_return Error(
          Errc::wkc_mismatch,
          fmt::format("assigning station 0x{:04x} to position {}{}: working counter {} "
                      "(expected 1)",
                      base_station + first + k, first + k,
                      port && *port == link::Port::secondary
                          ? fmt::format(" (position {} from the secondary port's side)", k)
                          : std::string(),
                      written->wkc(k)));
    }
  }
  co_return ok();
}

}  // namespace

exec::Task<Result<RingSides>> count_ring_sides(exec::EventLoop& loop, bus::Bus& bus) {
  // Two broadcast reads in one frame: the first (0x0000) a NOP in the secondary's copy, so only
  // the primary's side counts it; the second (0x0001) counted by both. The second also keeps
  // the secondary's copy a frame some slave may process, so that with the primary's cable cut
  // its bounce is a reply (a copy carrying nothing but NOPs comes back as it left: a
  // passthrough, never a reply).
  PortMask mask(bus, link::Port::secondary,
                {static_cast<std::uint8_t>(wire::Command::brd), 0, reg::kType, true});
  if (!mask.result()) co_return mask.result().error().context("counting the primary's side");
  bus::Transaction tx;
  tx.brd(reg::kType, 1);
  tx.brd(reg::kRevision, 1);
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error().context("counting the primary's side (BRD 0x0000)");
  RingSides sides{reply->wkc(0), reply->wkc(1)};
  if (sides.primary > sides.total) {
    co_return Error(Errc::wkc_mismatch,
                    fmt::format("counting the primary's side: {} slaves of {}: the ring changed",
                                sides.primary, sides.total));
  }
  co_return sides;
}

PositionRoute route_position(RingSides sides, std::uint16_t position) noexcept {
  if (position < sides.primary) return {link::Port::primary, position};
  return {link::Port::secondary, static_cast<std::uint16_t>(position - sides.primary)};
}

namespace {

bool position_addressed(wire::Command command) {
  return command == wire::Command::aprd || command == wire::Command::apwr ||
         command == wire::Command::aprw;
}

// Ring position of a position-addressed datagram (ADP = -position).
std::uint16_t ring_position(const bus::DatagramRequest& d) {
  return wire::position_adp(d.adp());  // the negation is its own inverse
}

Error changed_ring(RingSides before, RingSides after) {
  return Error(Errc::wkc_mismatch,
               fmt::format("position-addressed access: the ring changed under it ({} of {} "
                           "slaves on the primary port's side, then {} of {})",
                           before.primary, before.total, after.primary, after.total));
}

}  // namespace

exec::Task<Result<std::vector<PositionReply>>> transact_by_position(
    exec::EventLoop& loop, bus::Bus& bus, exec::AsyncMutex& addressing, bus::Transaction tx,
    bus::TransactOptions options, RingSides* seen) {
  if (tx.error()) co_return *tx.error();
  const auto datagrams = tx.datagrams();
  for (const auto& d : datagrams) {
    if (!position_addressed(d.command) || d.command != datagrams.front().command ||
        d.ado() != datagrams.front().ado()) {
      co_return Error(Errc::invalid_argument,
                      fmt::format("position-addressed access: {} in a transaction of {}: one "
                                  "position-addressed command at one register only",
                                  bus::describe(d), bus::describe(datagrams.front())));
    }
  }
  std::vector<PositionReply> out(datagrams.size());
  const auto take = [&](const bus::TransactionResult& reply, std::size_t from, std::size_t to) {
    const auto data = reply.data(from);
    out[to].wkc = reply.wkc(from);
    out[to].data.assign(data.begin(), data.end());
  };
  if (datagrams.empty()) co_return out;
  if (!bus.info().redundancy) {
    auto reply = co_await exec::transact(loop, bus, std::move(tx), options);
    if (!reply) co_return reply.error();
    for (std::size_t i = 0; i < out.size(); ++i)
      take(*reply, i, i);
    co_return out;
  }
  auto guard = co_await addressing.lock();
  auto sides = co_await count_ring_sides(loop, bus);
  if (!sides) co_return sides.error().context("position-addressed access");
  const link::DatagramSelector selector{static_cast<std::uint8_t>(datagrams.front().command), 0,
                                        datagrams.front().ado(), true};
  for (const auto port : {link::Port::primary, link::Port::secondary}) {
    bus::Transaction side;
    std::vector<std::size_t> slots;  // side's slot -> tx's
    for (std::size_t i = 0; i < datagrams.size(); ++i) {
      const auto& d = datagrams[i];
      const auto route = route_position(*sides, ring_position(d));
      if (route.port != port) continue;
      const auto address = static_cast<std::uint32_t>(wire::position_adp(route.position)) |
                           (static_cast<std::uint32_t>(d.ado()) << 16);
      side.add(d.command, address, d.length, tx.data(i), d.expected_wkc);
      slots.push_back(i);
    }
    if (slots.empty()) continue;
    PortMask mask(bus, port == link::Port::primary ? link::Port::secondary : link::Port::primary,
                  selector);
    if (!mask.result()) co_return mask.result().error().context("position-addressed access");
    auto reply = co_await exec::transact(loop, bus, std::move(side), options);
    if (!reply) co_return reply.error();
    for (std::size_t k = 0; k < slots.size(); ++k)
      take(*reply, k, slots[k]);
  }
  auto after = co_await count_ring_sides(loop, bus);
  if (!after) co_return after.error().context("position-addressed access");
  if (after->primary != sides->primary || after->total != sides->total) {
    co_return changed_ring(*sides, *after);
  }
  if (seen) *seen = *sides;
  co_return out;
}

exec::Task<Result<void>> assign_stations(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count,
                                         std::uint16_t base_station, RingSides* seen) {
  if (auto checked = check_addressing(count, base_station); !checked) co_return checked.error();
  if (!bus.info().redundancy) {
    auto assigned = co_await assign_from(loop, bus, std::nullopt, 0, count, base_station);
    if (!assigned) co_return assigned.error();
  } else {
    // A redundant ring may be broken already: each side's position 0 is the first slave its
    // port's frame processes, so a position reaches a slave on each side. The primary's side is
    // counted and assigned with the secondary's copy silenced, then the rest from the
    // secondary's side (in ring order: its frame processes them from the break on), with the
    // primary's silenced. A whole ring is all on the primary's side.
    auto sides = co_await count_ring_sides(loop, bus);
    if (!sides) co_return sides.error().context("assigning station addresses");
    if (sides->total != count) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("assigning station addresses: {} slaves answer, {} were "
                                  "counted: the ring changed",
                                  sides->total, count));
    }
    if (seen) *seen = *sides;
    auto assigned =
        co_await assign_from(loop, bus, link::Port::primary, 0, sides->primary, base_station);
    if (!assigned) co_return assigned.error();
    assigned =
        co_await assign_from(loop, bus, link::Port::secondary, sides->primary,
                             static_cast<std::uint16_t>(count - sides->primary), base_station);
    if (!assigned) co_return assigned.error();
  }
  bus::Transaction check;
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    check.fprd(static_cast<std::uint16_t>(base_station + pos), reg::kStationAddress, 2);
  }
  auto read = co_await exec::transact(loop, bus, std::move(check));
  if (!read) co_return read.error().context("reading back station addresses");
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    const auto station = static_cast<std::uint16_t>(base_station + pos);
    if (read->wkc(pos) != 1 || wire::load_le16(read->data(pos).data()) != station) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("station 0x{:04x} (position {}) does not answer after "
                                  "assignment (working counter {}): two slaves share it, or the "
                                  "ring changed",
                                  station, pos, read->wkc(pos)));
    }
  }
  co_return ok();
}

exec::Task<Result<std::vector<wire::DlStatus>>> read_dl_status(exec::EventLoop& loop, bus::Bus& bus,
                                                               std::uint16_t count,
                                                               std::uint16_t base_station) {
  bus::Transaction tx;
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    tx.fprd(static_cast<std::uint16_t>(base_station + pos), reg::kDlStatus, 2);
  }
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error().context("reading DL status");
  std::vector<wire::DlStatus> out;
  out.reserve(count);
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    if (reply->wkc(pos) != 1) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("DL status of station 0x{:04x}: working counter {}",
                                  base_station + pos, reply->wkc(pos)));
    }
    out.push_back(wire::DlStatus::decode(wire::load_le16(reply->data(pos).data())));
  }
  co_return out;
}

exec::Task<Result<std::vector<std::optional<wire::PortDescriptor>>>> read_port_descriptors(
    exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count, std::uint16_t base_station) {
  bus::Transaction tx;
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    tx.fprd(static_cast<std::uint16_t>(base_station + pos), reg::kPortDescriptor, 1);
  }
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error().context("reading the port descriptors");
  std::vector<std::optional<wire::PortDescriptor>> out(count);
  for (std::uint16_t pos = 0; pos < count; ++pos) {
    if (reply->wkc(pos) == 1) out[pos] = wire::PortDescriptor::decode(reply->data(pos)[0]);
  }
  co_return out;
}

exec::Task<Result<void>> reset_slaves(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count) {
  struct Step {
    std::uint16_t offset;
    std::vector<std::uint8_t> data;
    bool required;
    const char* what;
  };
  const std::vector<Step> steps{
      {reg::kDlPortControl, {0x00}, true, "DL port control"},
      {reg::kEcatEventMask, {0x04, 0x00}, true, "ECAT event mask"},
      {reg::kRxErrorCounter, std::vector<std::uint8_t>(8, 0), true, "RX error counters"},
      {reg::kFmmuBase, std::vector<std::uint8_t>(3 * reg::kFmmuSize, 0), true, "FMMU 0-2"},
      {reg::kSyncManagerBase, std::vector<std::uint8_t>(4 * reg::kSyncManagerSize, 0), true,
       "SyncManager 0-3"},
      {reg::kDcActivation, {0x00}, false, "DC activation"},
      {reg::kDcSystemTime, std::vector<std::uint8_t>(4, 0), false, "DC system time"},
      {reg::kDcSpeedCounterStart, {0x00, 0x10}, false, "DC speed counter start"},
      {reg::kDcSystemTimeFilterDepth, {0x00, 0x0C}, false, "DC time filter depths"},
      {reg::kDlAliasControl, {0x00}, true, "DL alias control"},
      {reg::kAlControl, {0x11, 0x00}, true, "AL control INIT + acknowledge"},
      {reg::kSiiAccess, {0x02}, true, "EEPROM access (force ECAT)"},
      {reg::kSiiAccess, {0x00}, true, "EEPROM access (ECAT)"},
  };
  bus::Transaction tx;
  for (const auto& step : steps)
    tx.bwr(step.offset, step.data);
  auto reply = co_await exec::transact(loop, bus, std::move(tx));
  if (!reply) co_return reply.error().context("resetting slaves (broadcast reset block)");
  for (std::size_t i = 0; i < steps.size(); ++i) {
    const auto wkc = reply->wkc(i);
    if (steps[i].required ? wkc != count : wkc > count) {
      co_return Error(Errc::wkc_mismatch,
                      fmt::format("reset block: {} (BWR 0x{:04x}) reached {} of {} slaves",
                                  steps[i].what, steps[i].offset, wkc, count));
    }
  }
  co_return ok();
}

exec::Task<Result<void>> init_all(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count,
                                  std::uint16_t base_station, InitOptions options) {
  {
    bus::Transaction tx;
    tx.bwr(reg::kAlControl, le16(wire::encode_al_control(wire::AlState::init, true)));
    auto reply = co_await exec::transact(loop, bus, std::move(tx));
    if (!reply) co_return reply.error().context("requesting INIT from all slaves");
    if (reply->wkc(0) == 0 || reply->wkc(0) > count) {
      co_return Error(
          Errc::wkc_mismatch,
          fmt::format("INIT request reached {} slaves (expected {})", reply->wkc(0), count));
    }
  }
  std::vector<std::uint16_t> blocking;
  std::string why;
  for (unsigned attempt = 0; attempt < std::max(1u, options.attempts); ++attempt) {
    bus::Transaction tx;
    for (std::uint16_t pos = 0; pos < count; ++pos) {
      tx.fprd(static_cast<std::uint16_t>(base_station + pos), reg::kAlStatus, 6);
    }
    auto reply = co_await exec::transact(loop, bus, std::move(tx));
    if (!reply) co_return reply.error().context("verifying INIT");
    blocking.clear();
    why.clear();
    bus::Transaction again;
    for (std::uint16_t pos = 0; pos < count; ++pos) {
      const auto station = static_cast<std::uint16_t>(base_station + pos);
      auto block = wire::decode_al_status_block(reply->data(pos));
      if (reply->wkc(pos) != 1 || !block) {
        blocking.push_back(station);
        why += fmt::format(" 0x{:04x}: no answer;", station);
        continue;
      }
      // A slave in INIT with an error still latched is accepted: its code is read later.
      if (block->status.state == wire::AlState::init) continue;
      blocking.push_back(station);
      why += fmt::format(" 0x{:04x}: {}{};", station, wire::to_string(block->status.state),
                         block->status.error ? fmt::format(" error 0x{:04x}", block->code) : "");
      if (block->status.error) {
        again.fpwr(station, reg::kAlControl,
                   le16(wire::encode_al_control(block->status.state, true)));
      }
      again.fpwr(station, reg::kAlControl, le16(wire::encode_al_control(wire::AlState::init)));
    }
    if (blocking.empty()) co_return ok();
    if (!again.empty()) {
      auto sent = co_await exec::transact(loop, bus, std::move(again));
      if (!sent) co_return sent.error().context("re-requesting INIT");
    }
    co_await exec::sleep_for(loop, options.interval);
  }
  if (!why.empty() && why.back() == ';') why.pop_back();
  co_return Error(Errc::timeout, fmt::format("{} slave(s) did not reach INIT after {} attempts:{}",
                                             blocking.size(), options.attempts, why));
}

}  // namespace ecat::master
