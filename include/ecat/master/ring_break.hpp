// Where a redundant ring is open, from the DL status (0x0110) of its slaves: the pure part of the
// master's break report (MasterStatus::redundancy->break_location, link.redundancy events).
//
// On a ring of slaves in a line from the primary port (port 0 towards the master, port 1 onwards)
// whose last slave's port 1 is cabled to the secondary port, a lost cable shows as a port without
// link: between slaves n-1 and n, slave n-1's port 1 and slave n's port 0 (either is enough: one
// end may still report a link while the other does not); at a master port, slave 0's port 0 or
// the last slave's port 1.
#pragma once

#include <cstdint>
#include <optional>
#include <span>

#include <ecat/link/link.hpp>
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

}  // namespace ecat::master
