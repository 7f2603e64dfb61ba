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

}  // namespace ecat::master
