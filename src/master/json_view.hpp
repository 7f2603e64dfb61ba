// A master as JSON: what the control endpoint answers and what `ecat ... --json` prints, built
// in one place so that a standalone command and an attached one print the same document.
#pragma once

#include <nlohmann/json.hpp>

#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>

namespace ecat::master::detail {

using Json = nlohmann::ordered_json;

std::string hex(std::span<const std::uint8_t> bytes);

// A slave: position, station, name, state, target, driver, device, identity, ports; with
// `verbose` also the ESC (type, revision, build, FMMUs, SMs, RAM, features), the DL status of
// every port, the mailbox, the SyncManager attachments and the signals with their types.
Json slave_json(const SlaveInfo& info, bool verbose = false);
Json domain_json(const DomainSummary& summary);
// Error when DC does not run: {"error": why}.
Json dc_json(Master& master);
Json counters_json(const MasterCounters& counters);
// A redundant link's ports and ring, and where the ring is open ("break": null when whole or not
// located).
Json redundancy_json(const link::RedundancyStatus& redundancy);
// state, desired target, link, slaves (summaries), domains, activation failures, runtime faults,
// last failure, illegal transition counts; "redundancy" on a redundant link.
Json status_json(Master& master);

}  // namespace ecat::master::detail
