// Names for the slaves of a dynamic session (MasterConfig::slaves empty): a coupler is called
// `coupler` (`coupler_2`, `coupler_3`, ... for the next ones), every other slave
// `slave_<position>`, as the reference names them.
//
// Whether a slave is a coupler is decided from its SII, before its Slave object exists (the name
// is its identity from then on). A pure coupler such as the EK1100 describes itself in its SII
// with a standard mailbox of size 0 and no mailbox protocols (words 0x18..0x1C), and with only
// descriptive categories (STRINGS, GENERAL, vendor ones): no FMMU, SYNCM, FMMU_EX, SYNCUNIT,
// TXPDO, RXPDO or DC category. A terminal without a mailbox (EL2004) still has its SyncManager and
// PDO categories; a coupler with a mailbox or its own I/O (EK1914) is named as a slave. Reading
// that costs the mailbox words plus one category header per category up to the first one that
// rules the slave out (or END): a handful of small EEPROM reads, for all slaves at once. An SII
// that cannot be read, or that does not look like a real one (no GENERAL category, no END within
// bounds), keeps the positional name.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <ecat/bus/bus.hpp>
#include <ecat/exec/event_loop.hpp>
#include <ecat/exec/task.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {

// What the naming decision needs from an SII: the standard mailbox words, the mailbox protocols,
// the category types in image order (END last when the walk reached it).
struct SiiShape {
  wire::SiiMailbox standard_mailbox;
  std::uint16_t mailbox_protocols = 0;
  std::vector<std::uint16_t> category_types;
};

// True when the shape is that of a pure coupler (see above). Pure.
bool sii_shape_is_coupler(const SiiShape& shape) noexcept;

// The shape of a whole image (a decoded one, or bytes read from a file). Pure.
SiiShape sii_shape_of(const wire::SiiDecoded& decoded);

// Reads just enough of the SII of `station` to decide; nullopt when the SII cannot be read.
exec::Task<std::optional<bool>> probe_coupler(exec::EventLoop& loop, bus::Bus& bus,
                                              std::uint16_t station);

// Names by position: `coupler[i]` true names position i a coupler, false or unknown (nullopt)
// keeps slave_<i>. Pure.
std::vector<std::string> dynamic_slave_names(std::span<const std::optional<bool>> coupler);

}  // namespace ecat::master
