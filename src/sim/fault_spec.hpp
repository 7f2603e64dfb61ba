// Reading and writing faults in the document tree shared by ring files and control requests.
#pragma once

#include <string>
#include <string_view>

#include <ecat/sim/faults.hpp>

#include "sim/spec_tree.hpp"

namespace ecat::sim::detail {

// A fault at `path` ("fault", "simulator.faults[2]"). Checks keys and value ranges, and the
// structure (validate()); slave names are checked later, against the segment.
Result<Fault> parse_fault_node(const SpecContext& context, const SpecNode& node,
                               const std::string& path);
Result<Milestone> parse_milestone_node(const SpecContext& context, const SpecNode& node,
                                       const std::string& path);
void append_fault_json(std::string& out, const Fault& fault);

}  // namespace ecat::sim::detail
