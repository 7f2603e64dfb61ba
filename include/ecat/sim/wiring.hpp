// Wiring between simulated devices: an output signal of one device drives an input signal of
// another, as a cable between an output terminal and an input terminal would. The copy happens
// after every frame the segment processes, so a value a master writes with one LRW shows up in
// the inputs the next LRW reads.
#pragma once

#include <string_view>

#include <ecat/result.hpp>
#include <ecat/sim/segment.hpp>

namespace ecat::sim {

// Copies `from_slave`'s signal `from_signal` (an output) into `to_slave`'s input `to_signal`
// after every frame (Segment::add_after_frame). Fails when a slave does not exist or is not a
// device with signals, when the source is not an output or the target not an input of those
// devices.
Result<void> wire_signals(Segment& segment, std::string_view from_slave,
                          std::string_view from_signal, std::string_view to_slave,
                          std::string_view to_signal);

}  // namespace ecat::sim
