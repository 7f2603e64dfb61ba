// How the `ecat` subcommands that run a master session (run, slaves, demo) show it.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include <ecat/link/link.hpp>
#include <ecat/master/master.hpp>

#include "live_capture.hpp"

namespace ecat::tool {

// The link and configuration a command's own session uses.
struct Setup {
  std::unique_ptr<ecat::link::Link> link;
  master::MasterConfig config;
  std::string link_name;
  // With --pcap: the file every frame of `link` goes to (link is wrapped to record into it).
  // finish() it once the master has stopped.
  std::unique_ptr<LiveCapture> capture;
};
// From a ring file (its master sections; its simulator section when it names no backend) and/or
// a backend spec (raw:IFACE, udp:HOST:PORT, sim:RING.yaml). `dynamic`: every slave found, held in
// PREOP, no process data (the file's slaves and domains are dropped). Prints why not and returns
// nullopt on a bad file or backend. `pcap`: a capture file to write (--pcap), empty for none.
std::optional<Setup> prepare(const std::string& ring, const std::string& backend, bool dynamic,
                             const std::string& pcap = {});

// One line per slave (position, station, name, state, driver, identity, device name), with its
// retained configuration error and, when asked, its signal names.
void print_slaves(master::Master& master, bool with_signals);
void print_domains(master::Master& master);
// One line on the distributed clocks (reference, lock, differences), or why they do not run.
void print_dc(master::Master& master);
// The whole session as a JSON document: state, slaves, domains.
nlohmann::ordered_json status_json(master::Master& master);
// A slave as `ecat slaves --json` lists it: position, station, name, state, identity {vendor_id,
// product_code, revision, serial}, ports.
nlohmann::ordered_json slave_json(const master::SlaveInfo& info);
// Decodes and prints an SII image as `ecat sii` does (`label` stands for the file name); the
// exit code `ecat sii` would give.
int print_sii(const std::vector<std::uint8_t>& image, const std::string& label, bool json);

// Prints why the session did not get running (activation failures, last failure); returns 1.
int report_failure(master::Master& master, const Error& error);

}  // namespace ecat::tool
