// The ring file: one YAML document that describes an EtherCAT ring for both the simulator
// (`ecat sim --ring FILE`, open_backend("sim:FILE")) and the master (`ecat run`). The simulator
// reads the `simulator:` section strictly (unknown keys are errors) and accepts the master's
// top-level sections without reading them. docs/RING-FILE.md is the reference.
//
//   simulator:
//     slaves:
//       - {name: coupler, profile: EK1100}
//       - {name: inputs, profile: EL1809}
//       - {name: outputs, profile: EL2809}
//     wiring:
//       - {from: outputs.channel_1, to: inputs.channel_1}
//     faults:
//       - {kind: wkc_offset, delta: -1, next: 3}
//
// Errors name the file, line and key: "ring.yaml:12: simulator.slaves[3].profile: unknown
// profile 'EL9999' (known: ...)".
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <ecat/result.hpp>
#include <ecat/sim/device.hpp>
#include <ecat/sim/faults.hpp>
#include <ecat/sim/segment.hpp>

namespace ecat::sim {

struct RingSlave {
  std::string name;
  DeviceConfig device;  // profile, file (resolved against the ring file's folder), options, clock
  std::optional<std::string> parent;  // attached to this slave's `port`; none = the previous one
  std::uint8_t port = 1;
  std::int64_t cable_delay_ns = 5;
  HopTiming timing{};
  // Hot connect: this slave is the first of a group that can be plugged and unplugged at runtime
  // (everything cabled behind its port 0); `plugged` is its state when the simulator starts.
  std::optional<std::string> hot_connect_group;
  bool plugged = true;
  // The device's explicit device ID (EscHardware::device_id), answered to an AL ID request.
  std::optional<std::uint16_t> device_id;
  int line = 0;  // where the entry starts in the ring file
};

struct RingWire {
  std::string from_slave;
  std::string from_signal;
  std::string to_slave;
  std::string to_signal;
  int line = 0;
};

struct RingFault {
  Fault fault;
  int line = 0;
};

struct Ring {
  std::string source;  // the file name messages use
  std::vector<RingSlave> slaves;
  std::vector<RingWire> wiring;
  std::vector<RingFault> faults;  // injected when the simulator starts
  // simulator.redundancy: the cabling when the ring is served with a second master port
  // (RedundantPortsOptions::topology and delays); none when the section is absent.
  std::optional<RedundantCabling> redundancy;
  // The master sections present in the file (not read by the simulator).
  std::vector<std::string> master_sections;

  const RingSlave* find(std::string_view name) const noexcept;
};

// Top-level sections that belong to the master (`ecat run`): the simulator accepts them without
// reading them; any other unknown top-level key is an error. "version" and "simulator" are the
// other known keys.
std::span<const std::string_view> ring_master_sections() noexcept;

// Reads and checks a ring file. Relative `file:` paths are resolved against the file's folder.
Result<Ring> load_ring(const std::string& path);
// The same from text; `source` names it in messages and `base_dir` resolves relative files.
Result<Ring> parse_ring(std::string_view text, std::string source = "ring.yaml",
                        std::string base_dir = "");

// Builds the slaves (make_device), attaches them as the ring says and installs the wiring (after
// every frame, each wired source value is copied to its target input, settling chains). Errors
// name the file, line and slave.
Result<std::unique_ptr<Segment>> build_segment(const Ring& ring);

}  // namespace ecat::sim
