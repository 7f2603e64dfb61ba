// How the `ecat` subcommands that run a master session (run, slaves, demo) show it.
#pragma once

#include <nlohmann/json.hpp>

#include <ecat/master/master.hpp>

namespace ecat::tool {

// One line per slave (position, station, name, state, driver, identity, device name), with its
// retained configuration error and, when asked, its signal names.
void print_slaves(master::Master& master, bool with_signals);
void print_domains(master::Master& master);
// One line on the distributed clocks (reference, lock, differences), or why they do not run.
void print_dc(master::Master& master);
// The whole session as a JSON document: state, slaves, domains.
nlohmann::json status_json(master::Master& master);
// A slave as `ecat slaves --json` lists it: position, station, name, state, identity {vendor_id,
// product_code, revision, serial}, ports.
nlohmann::json slave_json(const master::SlaveInfo& info);
// Prints why the session did not get running (activation failures, last failure); returns 1.
int report_failure(master::Master& master, const Error& error);

}  // namespace ecat::tool
