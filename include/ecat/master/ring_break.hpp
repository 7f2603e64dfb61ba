// Where a redundant ring is open, from the DL status (0x0110) of its slaves: the pure part of the
// master's break report (MasterStatus::redundancy->break_location, link.redundancy events).
//
// On a ring of slaves in a line from the primary port (port 0 towards the master, port 1 onwards)
// whose last slave's port 1 is cabled to the secondary port, a lost cable shows as a port without
// link: between slaves n-1 and n, slave n-1's port 1 and slave n's port 0 (either is enough: one
// end may still report a link while the other does not); at a master port, slave 0's port 0 or
// the last slave's port 1.
//
// On a ring through junctions (EK1122: a frame leaves by ports 3, 1, 2 in turn), the ring's
// shape comes from the slaves' DL status read while it was whole (ring_tree, the tree DC
// planning builds): the ring runs from slave 0 to the last slave in frame order, whose free port
// goes back to the secondary; the slaves on the way are the ring's, the rest hang on branches
// (a junction port whose subtree ends there). A break on the ring shows at a cable between a
// slave and the one hanging on it (the parent's port and the child's port 0); a branch's lost
// cable leaves the ring whole (the slaves behind it are lost to both ports) and is not the
// ring's break.
#pragma once

#include <cstdint>
#include <optional>
#include <span>

#include <ecat/link/link.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/result.hpp>
#include <ecat/wire/registers.hpp>

namespace ecat::master {

struct RingPortReading {
  std::uint16_t station = 0;
  std::optional<wire::DlStatus> dl_status;  // none: the read was not answered
};

// The first lost link in ring order (slave 0's port 0, then each cable between slaves, then the
// last slave's port 1); none when every link is up, for no slaves, or when a slave before the
// first lost link did not answer (the break cannot be told from a silent slave).
std::optional<link::RingBreak> locate_ring_break(std::span<const RingPortReading> slaves);

// The same over the ring's shape (`shape`: ring_tree of the whole ring, one node per reading,
// with its return_port): slave 0's port 0, then each cable on the way to the last slave in ring
// order (the parent's port and the child's port 0), then the last slave's return port. A slave
// off the ring (on a branch) neither breaks the ring nor hides a break when silent. A shape of
// another size than `slaves`: none (it is not this ring's).
std::optional<link::RingBreak> locate_ring_break(std::span<const RingPortReading> slaves,
                                                 const RingTree& shape);

// The shape of a redundant ring that was broken when it was read (never seen whole), from what
// the start-up reads: every slave's DL status (0x0110, raw, by ring position: stations are
// assigned side by side, so the primary's side comes first in its frame order and then the
// secondary's from the first slave behind the break), the number of slaves the primary's frame
// processes (`primary_side`, RingSides::primary: 0 with the primary's cable cut, all of them
// with the secondary's) and each slave's port descriptor (0x0007; none where unknown).
//
// Each side is a tree of its own (ring_tree): the primary's from slave 0 by port 0, the
// secondary's from the first slave behind the break, whose port 0 is the broken cable's far end,
// back to the secondary port through the last slave's free port. The break's near end is a port
// without link on the primary's side that the first slave behind it can hang on in frame order
// (0 -> 3 -> 1 -> 2): on slave primary_side - 1 or an ancestor of it, after the ports its
// children use. A port the ESC does not have carries no cable (port descriptors are taken into
// account only when no slave shows a link on a port its descriptor says it lacks). With the
// secondary's cable cut, the return port is the last slave's free port.
//
// Errors (no shape: the line rule applies): Errc::malformed when the picture is not a ring
// broken after `primary_side` slaves (a port 0 with or without link where the break says
// otherwise, an open port with nothing behind it, no way back to the secondary port); Errc::
// not_found when it fits more than one tree (several ports the break may be at: the DL status
// cannot tell a broken cable from a port never cabled) or none.
Result<RingTree> broken_ring_tree(std::span<const std::uint16_t> dl_status,
                                  std::span<const std::optional<wire::PortDescriptor>> ports,
                                  std::span<const std::uint16_t> stations,
                                  std::size_t primary_side);

}  // namespace ecat::master
