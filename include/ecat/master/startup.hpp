// The master's startup steps before any slave is configured (upstream-inventory §3.4): count the
// slaves until the count is stable, assign station addresses, read DL status, reset every ESC to
// a known state with broadcast writes, and bring them all to INIT. Each is a coroutine on the
// control loop; the Master runs them in order.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/async_mutex.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/link/link.hpp>
#include <ecat/master/config.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/al.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

// Slaves answering a broadcast read of 0x0000 (the working counter).
exec::Task<Result<std::uint16_t>> count_slaves(exec::EventLoop& loop, bus::Bus& bus,
                                               bus::TransactOptions options = {});

// The ports 1-3 of every slave as its DL status (0x0110) shows them, read by position: one entry
// per slave (bits 1-3 physical link, 5-7 communication, 9-11 loop closed, by port). `complete`
// when every port with a link carries frames and the links add up to a tree of exactly the
// counted slaves (count - 1 of them): no port leads to a device the count does not hold.
struct LinkPicture {
  std::vector<std::uint16_t> ports;
  bool complete = true;
};
// Nothing (no error) when a position does not answer or `count` is 0 or beyond auto-increment.
// On a redundant link the positions are read through transact_by_position (`addressing`: the
// session's position-access mutex; null: a private one), so a ring broken between two slaves
// gives its whole picture too, the break's missing link allowed for.
exec::Task<Result<std::optional<LinkPicture>>> read_link_picture(
    exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count,
    exec::AsyncMutex* addressing = nullptr);

// Polls count_slaves() until it is non-zero and unchanged for `stable`, or (link_check) unchanged
// at two consecutive polls with the same complete link picture at both (read_link_picture).
exec::Task<Result<std::uint16_t>> await_stable_count(exec::EventLoop& loop, bus::Bus& bus,
                                                     ScanOptions options = {},
                                                     exec::AsyncMutex* addressing = nullptr);

// Checks the limits of auto-increment addressing and of the station range (base + count - 1 must
// stay within 0xFFFF; station 0 is never assigned).
Result<void> check_addressing(std::uint16_t count, std::uint16_t base_station);

// On a redundant link: how the slaves divide between the two ports' frames now. Position
// addressing counts from the first slave a port's frame processes, so behind a break position p
// from the secondary's side is ring position primary + p.
struct RingSides {
  std::uint16_t primary = 0;  // processed by the primary's frame (0 with its cable cut)
  std::uint16_t total = 0;    // processed by either
};
// One frame: BRD 0x0000 with the secondary's copy a NOP (Link::set_port_nop) and BRD 0x0001
// through both. A whole ring is all on the primary's side.
exec::Task<Result<RingSides>> count_ring_sides(exec::EventLoop& loop, bus::Bus& bus);

// Where position addressing reaches ring position `position` (0 = the primary's first slave)
// when the ring divides into `sides`: through the primary's frame at the same position, or
// behind a break through the secondary's at position - sides.primary.
struct PositionRoute {
  link::Port port = link::Port::primary;
  std::uint16_t position = 0;  // counted from that port's first slave
  bool operator==(const PositionRoute&) const = default;
};
PositionRoute route_position(RingSides sides, std::uint16_t position) noexcept;

// The reply to one datagram of transact_by_position.
struct PositionReply {
  std::uint16_t wkc = 0;
  std::vector<std::uint8_t> data;
};
// Sends `tx`, whose datagrams are one position-addressed command (APRD, APWR or APRW) at one
// register, each to the slave at its ring position, also on a redundant ring that is broken:
// there each datagram goes through the port whose frame reaches that position (route_position,
// the other port's copy a NOP: Link::set_port_nop, NopSlot::addressing), the ring's sides
// counted before and after (a change between them is an error: Errc::wkc_mismatch, "the ring
// changed"). `addressing` keeps the session's position-addressed accesses one at a time (they
// share the slot). On one port the transaction goes out as it is. Replies in `tx`'s order;
// an expected working counter is checked as the bus checks it.
// `seen`, when given, receives the sides counted (on one port: left as it is).
exec::Task<Result<std::vector<PositionReply>>> transact_by_position(
    exec::EventLoop& loop, bus::Bus& bus, exec::AsyncMutex& addressing, bus::Transaction tx,
    bus::TransactOptions options = {}, RingSides* seen = nullptr);

// Writes station = base + position to every slave (one APWR each, in one transaction) and reads
// them back by station. Errors name the position and station. On a redundant link (a ring that
// may be broken already, where position addressing counts from each side's first slave) the
// primary's side is assigned through the primary port alone and the rest through the
// secondary's (Link::set_port_nop), so every slave gets its ring position's station.
// `sides`, when given, receives the sides counted on a redundant link (else left as it is).
exec::Task<Result<void>> assign_stations(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count,
                                         std::uint16_t base_station, RingSides* sides = nullptr);

// DL status (0x0110) of every station, in station order.
exec::Task<Result<std::vector<wire::DlStatus>>> read_dl_status(exec::EventLoop& loop, bus::Bus& bus,
                                                               std::uint16_t count,
                                                               std::uint16_t base_station);

// The port descriptor (0x0007) of every station, in station order (one frame); none where the
// read was not answered.
exec::Task<Result<std::vector<std::optional<wire::PortDescriptor>>>> read_port_descriptors(
    exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count, std::uint16_t base_station);

// The reset block (one frame of broadcast writes): loop control, event mask, error counters,
// FMMUs, SyncManagers, DC activation/system time/filters, alias control, AL control INIT with
// acknowledge, EEPROM to ECAT. Required writes must reach all `count` slaves.
exec::Task<Result<void>> reset_slaves(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count);

// Requests INIT (with error acknowledge) from every slave and waits until each station shows
// INIT, re-requesting from slaves that do not; names the blocking stations on failure.
exec::Task<Result<void>> init_all(exec::EventLoop& loop, bus::Bus& bus, std::uint16_t count,
                                  std::uint16_t base_station, InitOptions options = {});

// Auto-tuned frame timeout for `count` slaves: (200 + 40 * count) us, clamped to [5, 10] ms.
std::chrono::nanoseconds auto_frame_timeout(std::uint16_t count) noexcept;

}  // namespace ecat::master
