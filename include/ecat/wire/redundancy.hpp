// Cable redundancy, the pure part: where a frame that came back on one of a master's two ports
// had been sent, whether it is only the unprocessed copy of a request, and how two partial
// replies (each side of a broken ring processed part of the slaves) become one.
//
// A redundant master sends every frame on both ports. The ESCs process a frame only on its way
// from port 0 through the processing unit, so on a healthy ring the primary's frame is processed
// by every slave and leaves the last slave into the secondary port (a forward cross), while the
// secondary's frame travels the ring backwards through every slave unprocessed and reaches the
// primary port unchanged (a reverse cross, a passthrough copy). When the ring is broken, each
// frame turns round at the break: the primary's comes back to the primary port processed by the
// slaves before the break, the secondary's comes back to the secondary port processed by the
// slaves after it (two bounces), and the two are merged into the reply a whole ring would give.
//
// The sender is told apart by the Ethernet source address: each port sends with its own, and an
// ESC sets bit 1 of the first byte (the locally administered bit) of a frame it forwards, so the
// comparison ignores that bit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

#include <ecat/result.hpp>
#include <ecat/wire/bytes.hpp>
#include <ecat/wire/frame.hpp>

namespace ecat::wire {

enum class RedundantPort : std::uint8_t { primary, secondary };
std::string_view to_string(RedundantPort port) noexcept;

enum class ArrivalKind : std::uint8_t {
  forward_cross,     // sent by the primary, arrived on the secondary: the ring is whole
  reverse_cross,     // sent by the secondary, arrived on the primary
  primary_bounce,    // sent by the primary, came back to it: the ring is open somewhere
  secondary_bounce,  // sent by the secondary, came back to it
  unknown,           // a source address that is neither port's
};
std::string_view to_string(ArrivalKind kind) noexcept;

// Equal except for bit 1 of the first byte, which forwarding ESCs set.
bool same_station_mac(const MacAddress& a, const MacAddress& b) noexcept;

// What kind of arrival a frame with Ethernet source `source` is, arriving on `arrived_on`, when the
// primary port sends from `primary` and the secondary from `secondary` (the two must differ in
// more than bit 1 of the first byte; see same_station_mac).
ArrivalKind classify_arrival(RedundantPort arrived_on, const MacAddress& source,
                             const MacAddress& primary, const MacAddress& secondary) noexcept;

// Whether `reply` answers `request` datagram for datagram: the same number of datagrams, each
// with the same index, command and length. Both are EtherCAT frames (header + datagrams);
// anything that does not decode is not a reply.
bool same_shape(Bytes request, Bytes reply) noexcept;

// Whether `reply` is `request` come back untouched: the same shape, every working counter 0 and
// every datagram's data unchanged. Such a copy only passed through the ring (the secondary's frame
// on a healthy ring) and says nothing about the slaves: it is never a reply.
bool is_passthrough_copy(Bytes request, Bytes reply) noexcept;

// Whether any datagram of a decodable frame has a working counter above 0.
bool any_processed(Bytes frame) noexcept;

struct MergeStats {
  std::size_t datagrams = 0;
  std::size_t bytes_from_primary = 0;    // logical data bytes only the primary's side changed
  std::size_t bytes_from_secondary = 0;  // logical data bytes only the secondary's side changed
  std::size_t conflicting_bytes = 0;     // changed on both sides to different values
};

// Merges the two bounces of a broken ring into one reply written to `out` (at least
// request.size() bytes; the merged frame has the request's length). `primary` and `secondary`
// must have the request's shape (same_shape), else Errc::malformed naming which one. Per datagram:
//  - working counter: the sum of both sides' (saturating at 0xFFFF); circulating and IRQ bits:
//    the OR of both;
//  - LRD, LWR, LRW (whose bytes each slave fills only where its FMMUs map): byte by byte, a byte
//    changed from the request on one side only takes that side's value; changed on both sides,
//    the value of the side with the higher working counter (the primary's on a tie);
//  - FRMW and ARMW (one slave reads, every other writes what it read): the data and address of
//    the side whose data changed from the request (the reader's), whatever the working counters
//    say (the writers behind a break may outnumber the reader's side); when neither or both
//    changed, as for every other command;
//  - every other command: the data and address of the side with the higher working counter (the
//    primary's on a tie), since a physical read is answered by one slave, which is on one side.
// Returns the merged frame (a view into `out`). Never allocates.
Result<Bytes> merge_bounces(Bytes request, Bytes primary, Bytes secondary, MutableBytes out,
                            MergeStats* stats = nullptr);

}  // namespace ecat::wire
