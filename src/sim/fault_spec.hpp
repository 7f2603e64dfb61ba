// Reading and writing faults in the document tree shared by ring files and control requests.
#pragma once

#include <string>
#include <string_view>

#include <ecat/sim/faults.hpp>

#include "config/spec_tree.hpp"

namespace ecat::sim::detail {

// The document tree lives in the config layer; the fault reader and writer use it by these names.
using config::detail::append_json_string;
using config::detail::check_keys;
using config::detail::index_path;
using config::detail::join_path;
using config::detail::parse_json;
using config::detail::require;
using config::detail::spec_error;
using config::detail::SpecContext;
using config::detail::SpecNode;
using config::detail::to_bool;
using config::detail::to_double;
using config::detail::to_int;
using config::detail::to_text;
using config::detail::type_name;

// A fault at `path` ("fault", "simulator.faults[2]"). Checks keys and value ranges, and the
// structure (validate()); slave names are checked later, against the segment.
Result<Fault> parse_fault_node(const SpecContext& context, const SpecNode& node,
                               const std::string& path);
Result<Milestone> parse_milestone_node(const SpecContext& context, const SpecNode& node,
                                       const std::string& path);
void append_fault_json(std::string& out, const Fault& fault);

}  // namespace ecat::sim::detail
