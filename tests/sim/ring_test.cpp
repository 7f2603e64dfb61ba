// Ring files: parsing, every class of error with its file:line: key message, building segments
// (topology, wiring, start faults) and the committed examples.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <ecat/sim/device.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::sim {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::StartsWith;

std::string error_of(std::string_view yaml) {
  auto r = parse_ring(yaml, "ring.yaml");
  EXPECT_FALSE(r.ok()) << "accepted:\n" << yaml;
  return r.ok() ? std::string() : r.error().message();
}

bool has_profile(const std::string& name) {
  const auto profiles = device_profiles();
  return std::any_of(profiles.begin(), profiles.end(),
                     [&](const DeviceProfileInfo& p) { return p.name == name; });
}

TEST(RingParse, ReadsEverySlaveKey) {
  auto ring = parse_ring(R"(version: 1
simulator:
  slaves:
    - name: coupler
      profile: generic
      options: {vendor_id: 0x2, product_code: 0x044c2c52}
    - name: io
      profile: generic
      parent: coupler
      port: 2
      cable_delay_ns: 40
      timing: {processing_delay_ns: 300, forwarding_delay_ns: 70}
      clock: {drift_ppm: -12.5, offset_ns: 1000000, jitter_ns: 20, jitter_seed: 7}
    - {name: rep, profile: generic, count: 3}
)",
                         "ring.yaml");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  ASSERT_EQ(ring->slaves.size(), 5u);
  const RingSlave& coupler = ring->slaves[0];
  EXPECT_EQ(coupler.name, "coupler");
  EXPECT_EQ(coupler.line, 4);
  EXPECT_EQ(coupler.device.options.at("vendor_id"), "0x2");
  EXPECT_EQ(coupler.device.options.at("product_code"), "0x044c2c52");
  const RingSlave& io = ring->slaves[1];
  EXPECT_EQ(io.parent, "coupler");
  EXPECT_EQ(io.port, 2);
  EXPECT_EQ(io.cable_delay_ns, 40);
  EXPECT_EQ(io.timing.processing_delay_ns, 300);
  EXPECT_EQ(io.timing.forwarding_delay_ns, 70);
  EXPECT_DOUBLE_EQ(io.device.clock.drift_ppm, -12.5);
  EXPECT_EQ(io.device.clock.start_offset_ns, 1000000);
  EXPECT_EQ(io.device.clock.jitter_ns, 20);
  EXPECT_EQ(io.device.clock.jitter_seed, 7u);
  EXPECT_EQ(ring->slaves[2].name, "rep_1");
  EXPECT_EQ(ring->slaves[3].name, "rep_2");
  EXPECT_EQ(ring->slaves[4].name, "rep_3");
  EXPECT_EQ(ring->slaves[4].line, 14);
  EXPECT_FALSE(ring->slaves[2].parent.has_value());
}

TEST(RingParse, ReadsWiringFaultsAndAcceptsMasterSections) {
  auto ring = parse_ring(R"(
master: {cycle_us: 1000, anything: [1, 2]}
domains:
  - {name: main}
simulator:
  slaves:
    - {name: a, profile: generic}
    - {name: b, profile: generic}
  wiring:
    - {from: a.out, to: b.in}
  faults:
    - {kind: wkc_offset, delta: -1, next: 3}
    - after_ms: 250
      fault: {kind: disconnect, slave: b}
    - script:
        - drop_responses
        - {wait_for: {milestone: healthy_polls, slave: a, count: 2}}
slaves: {whatever: the master wants}
)",
                         "ring.yaml");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  EXPECT_THAT(ring->master_sections, ElementsAre("master", "domains", "slaves"));
  ASSERT_EQ(ring->wiring.size(), 1u);
  EXPECT_EQ(ring->wiring[0].from_slave, "a");
  EXPECT_EQ(ring->wiring[0].from_signal, "out");
  EXPECT_EQ(ring->wiring[0].to_slave, "b");
  EXPECT_EQ(ring->wiring[0].to_signal, "in");
  EXPECT_EQ(ring->wiring[0].line, 10);
  ASSERT_EQ(ring->faults.size(), 3u);
  EXPECT_EQ(describe(ring->faults[0].fault), "next 3 exchanges WKC offset -1");
  EXPECT_EQ(describe(ring->faults[1].fault), "after 250 ms: disconnect b");
  EXPECT_EQ(describe(ring->faults[2].fault),
            "script: drop responses; wait for 2 healthy polls of a");
  EXPECT_EQ(ring->faults[1].line, 13);
  EXPECT_THAT(ring_master_sections(), ::testing::Contains("domains"));
}

TEST(RingErrors, SyntaxAndShape) {
  EXPECT_THAT(error_of("simulator:\n  slaves: [\n    - a\n"), StartsWith("ring.yaml:"));
  EXPECT_THAT(error_of("simulator:\n  slaves: [\n    - a\n"), HasSubstr("YAML syntax error"));
  EXPECT_EQ(error_of(""), "ring.yaml: the file is empty (expected a 'simulator:' section)");
  EXPECT_EQ(error_of("- 1\n- 2\n"), "ring.yaml:1: expected a mapping of sections, found a list");
  EXPECT_EQ(error_of("master: {}\n"),
            "ring.yaml:1: no 'simulator:' section (the simulator needs simulator.slaves)");
  EXPECT_EQ(error_of("simulator:\n  slaves: [{name: a, profile: generic}]\ncolour: red\n"),
            "ring.yaml:3: colour: unknown top-level section (known: version, simulator; for the "
            "master: master, link, slaves, domains, dc, targets)");
  EXPECT_EQ(error_of("version: 2\nsimulator: {slaves: [{name: a, profile: generic}]}\n"),
            "ring.yaml:1: version: 2 is out of range (1 to 1)");
  EXPECT_EQ(error_of("simulator:\n  slaves: [{name: a, profile: generic}]\n  slaves: []\n"),
            "ring.yaml:3: slaves: duplicate key");
  EXPECT_EQ(error_of("simulator:\n  slaves: []\n"),
            "ring.yaml:2: simulator.slaves: expected a non-empty list of slaves");
  EXPECT_EQ(error_of("simulator:\n  slaves: [{name: a, profile: generic}]\n  wires: []\n"),
            "ring.yaml:3: simulator.wires: unknown key (known: slaves, wiring, faults)");
  EXPECT_EQ(error_of("simulator: [1]\n"),
            "ring.yaml:1: simulator: expected a mapping, found a list");
}

TEST(RingErrors, Slaves) {
  EXPECT_EQ(
      error_of(R"(simulator:
  slaves:
    - name: a
      profile: generic
    - name: b
      profile: EL9999
)"),
      "ring.yaml:6: simulator.slaves[1].profile: unknown profile 'EL9999' (known: " +
          [] {
            std::string known;
            for (const auto& p : device_profiles()) {
              known += (known.empty() ? "" : ", ") + p.name;
            }
            bool eeprom = false;
            bool esi = false;
            for (const auto& p : device_profiles()) {
              eeprom = eeprom || p.name == "eeprom";
              esi = esi || p.name == "esi";
            }
            if (!eeprom) known += ", eeprom";
            if (!esi) known += ", esi";
            return known;
          }() +
          ")");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - profile: generic\n"),
            "ring.yaml:3: simulator.slaves[0]: missing key 'name'");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: 'a.b', profile: generic}\n"),
            "ring.yaml:3: simulator.slaves[0].name: 'a.b' is not a slave name (letters, digits, "
            "'_' and '-', starting with a letter or '_', at most 64)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic}\n"
                     "    - {name: a, profile: generic}\n"),
            "ring.yaml:4: simulator.slaves[1].name: a slave named 'a' already exists");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, colour: 1}\n"),
            "ring.yaml:3: simulator.slaves[0].colour: unknown key (known: name, profile, file, "
            "options, clock, parent, port, cable_delay_ns, timing, count)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, parent: a}\n"),
            "ring.yaml:3: simulator.slaves[0]: the first slave is cabled to the master: it has "
            "no parent or port");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic}\n"
                     "    - {name: b, profile: generic, parent: c}\n"),
            "ring.yaml:4: simulator.slaves[1].parent: unknown slave 'c': a parent must be listed "
            "before its children");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic}\n"
                     "    - {name: b, profile: generic, port: 4}\n"),
            "ring.yaml:4: simulator.slaves[1].port: 4 is out of range (1 to 3)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic}\n"
                     "    - {name: b, profile: generic}\n"
                     "    - name: c\n      profile: generic\n      parent: a\n      port: 1\n"),
            "ring.yaml:8: simulator.slaves[2]: port 1 of 'a' is already cabled to 'b'");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, options: [1]}\n"),
            "ring.yaml:3: simulator.slaves[0].options: expected a mapping of option: value, "
            "found a list");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - name: a\n      profile: generic\n"
                     "      options: {x: {y: 1}}\n"),
            "ring.yaml:5: simulator.slaves[0].options.x: expected a string, found a mapping");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - name: a\n      profile: generic\n"
                     "      clock: {drift_ppm: 5000}\n"),
            "ring.yaml:5: simulator.slaves[0].clock.drift_ppm: 5000 ppm is out of range (-1000 "
            "to 1000)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - name: a\n      profile: generic\n"
                     "      clock: {drift: 1}\n"),
            "ring.yaml:5: simulator.slaves[0].clock.drift: unknown key (known: drift_ppm, "
            "offset_ns, jitter_ns, jitter_seed)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: eeprom}\n"),
            "ring.yaml:3: simulator.slaves[0]: profile 'eeprom' needs 'file' (the SII image to "
            "build the device from)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, count: 0}\n"),
            "ring.yaml:3: simulator.slaves[0].count: 0 is out of range (1 to 1024)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, count: x}\n"),
            "ring.yaml:3: simulator.slaves[0].count: 'x' is not an integer (decimal or 0x hex)");
}

TEST(RingErrors, WiringAndFaults) {
  const std::string head =
      "simulator:\n  slaves:\n    - {name: a, profile: generic}\n"
      "    - {name: b, profile: generic}\n";
  EXPECT_EQ(error_of(head + "  wiring:\n    - {from: a, to: b.x}\n"),
            "ring.yaml:6: simulator.wiring[0].from: 'a' is not SLAVE.SIGNAL (e.g. "
            "outputs.channel_1)");
  EXPECT_EQ(error_of(head + "  wiring:\n    - {from: a.x, to: z.y}\n"),
            "ring.yaml:6: simulator.wiring[0].to: unknown slave 'z' (known: a, b)");
  EXPECT_EQ(error_of(head + "  wiring:\n    - {from: a.x, to: b.y}\n    - {from: a.z, to: b.y}\n"),
            "ring.yaml:7: simulator.wiring[1].to: b.y is already driven by a.x (line 6)");
  EXPECT_EQ(error_of(head + "  wiring:\n    - {from: a.x}\n"),
            "ring.yaml:6: simulator.wiring[0]: missing key 'to'");
  EXPECT_THAT(error_of(head + "  faults:\n    - {kind: boom}\n"),
              StartsWith("ring.yaml:6: simulator.faults[0].kind: unknown fault kind 'boom' "
                         "(known: drop_responses, "));
  EXPECT_EQ(error_of(head + "  faults:\n    - {kind: disconnect, slave: q}\n"),
            "ring.yaml:6: simulator.faults[0]: unknown slave 'q' (known: a, b)");
  EXPECT_EQ(error_of(head + "  faults:\n    - script:\n        - {kind: wkc_offset, delta: 1}\n"
                            "        - {wait_for: {milestone: healthy_polls, slave: x, count: "
                            "1}}\n"),
            "ring.yaml:6: simulator.faults[0]: unknown slave 'x' (known: a, b)");
  EXPECT_EQ(error_of(head + "  faults:\n    - kind: power_cycle\n      slave: a\n      next: 2\n"),
            "ring.yaml:8: simulator.faults[0].next: unknown key (known: kind, slave)");
  EXPECT_EQ(error_of(head + "  faults:\n    - {wait_ms: 3}\n"),
            "ring.yaml:6: simulator.faults[0].wait_ms: only valid as a script step");
}

TEST(RingLoad, FilesAndPaths) {
  auto missing = load_ring("/nonexistent/ring.yaml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code(), Errc::not_found);
  EXPECT_EQ(missing.error().message(), "/nonexistent/ring.yaml: cannot open the ring file");

  const fs::path dir = fs::temp_directory_path() / fmt::format("ecat-ring-test-{}", ::getpid());
  fs::create_directories(dir);
  const fs::path file = dir / "r.yaml";
  std::ofstream(file) << "simulator:\n  slaves:\n    - {name: a, profile: eeprom, file: "
                         "images/a.bin}\n    - {name: b, profile: generic, options: {x: 1}\n";
  auto bad = load_ring(file.string());
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.error().message(), StartsWith(file.string() + ":"));
  EXPECT_THAT(bad.error().message(), HasSubstr("YAML syntax error"));
  std::ofstream(file) << "simulator:\n  slaves:\n    - {name: a, profile: eeprom, file: "
                         "images/a.bin}\n";
  auto ring = load_ring(file.string());
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  EXPECT_EQ(ring->source, file.string());
  EXPECT_EQ(ring->slaves[0].device.file, (dir / "images/a.bin").string());
  fs::remove_all(dir);
}

TEST(RingBuild, TopologyFollowsParentsAndPorts) {
  auto ring = parse_ring(R"(simulator:
  slaves:
    - {name: root, profile: generic}
    - {name: left, profile: generic}
    - {name: left2, profile: generic}
    - {name: right, profile: generic, parent: root, port: 2}
    - {name: right2, profile: generic, cable_delay_ns: 100}
)");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  auto segment = build_segment(*ring);
  ASSERT_TRUE(segment.ok()) << segment.error().describe();
  ASSERT_EQ((*segment)->size(), 5u);
  // A frame leaves root by port 1 (forwarding order 3, 1, 2) before port 2.
  EXPECT_THAT((*segment)->processing_order(), ElementsAre(0, 1, 2, 3, 4));
  EXPECT_TRUE((*segment)->link(3, 0));
  EXPECT_EQ((*segment)->name(4), "right2");
}

TEST(RingBuild, ErrorsNameTheLineAndSlave) {
  auto ring = parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: generic}
    - {name: b, profile: generic, options: {vendor_id: banana}}
)");
  ASSERT_TRUE(ring.ok());
  auto segment = build_segment(*ring);
  ASSERT_FALSE(segment.ok());
  EXPECT_EQ(segment.error().message(),
            "ring.yaml:4: simulator.slaves[1] (b): device option vendor_id: 'banana' is not a "
            "32-bit number");

  ring = parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: generic}
    - {name: b, profile: generic}
  wiring:
    - {from: a.channel_1, to: b.channel_1}
)");
  ASSERT_TRUE(ring.ok());
  segment = build_segment(*ring);
  ASSERT_FALSE(segment.ok());
  EXPECT_THAT(segment.error().message(),
              StartsWith("ring.yaml:6: simulator.wiring[0] (a.channel_1 -> b.channel_1): "));
}

TEST(RingBuild, StartFaultsAreInjectedByMakeServer) {
  auto ring = parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: generic}
  faults:
    - {kind: disconnect, slave: a, next: 2}
    - {after_ms: 100, fault: drop_responses}
)");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  std::int64_t t = 5'000'000'000;
  SimServerOptions options;
  options.clock = [&t] { return t; };
  auto server = make_server(*ring, options);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  const auto info = (*server)->fault_info();
  ASSERT_EQ(info.queued.size(), 1u);
  EXPECT_EQ(info.queued[0].description, "disconnect a");
  EXPECT_EQ(info.queued[0].remaining, 2u);
  ASSERT_EQ(info.scheduled.size(), 1u);
  EXPECT_EQ(info.scheduled[0].due_in_ns, 100'000'000);
  const auto status = (*server)->status();
  EXPECT_EQ(status.slaves.at(0).profile, "generic");
}

TEST(RingExamples, AllLoadAndBuildWhenTheirProfilesExist) {
  const fs::path examples = fs::path(ECAT_SOURCE_DIR) / "examples";
  std::size_t seen = 0;
  for (const auto& entry : fs::directory_iterator(examples)) {
    if (entry.path().extension() != ".yaml") continue;
    ++seen;
    SCOPED_TRACE(entry.path().string());
    auto ring = load_ring(entry.path().string());
    bool profiles_exist = true;
    if (!ring.ok()) {
      // Only an example naming a profile the device layer does not have yet may fail to load.
      EXPECT_THAT(ring.error().message(), HasSubstr("unknown profile"));
      continue;
    }
    for (const auto& slave : ring->slaves) {
      profiles_exist = profiles_exist && (has_profile(slave.device.profile));
    }
    if (!profiles_exist) continue;
    auto segment = build_segment(*ring);
    EXPECT_TRUE(segment.ok()) << segment.error().describe();
    if (segment.ok()) {
      EXPECT_EQ((*segment)->size(), ring->slaves.size());
    }
  }
  EXPECT_GE(seen, 3u);
}

TEST(RingExamples, DefaultRingDescribesTheReferenceRing) {
  auto ring = load_ring(std::string(ECAT_SOURCE_DIR) + "/examples/default.yaml");
  if (!ring.ok() && ring.error().message().find("unknown profile") != std::string::npos) {
    GTEST_SKIP() << "profiles not available yet: " << ring.error().message();
  }
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  std::vector<std::string> profiles;
  for (const auto& s : ring->slaves)
    profiles.push_back(s.device.profile);
  EXPECT_THAT(profiles, ElementsAre("EK1100", "EL1809", "EL2809", "EL3202", "servo"));
  EXPECT_EQ(ring->wiring.size(), 16u);
}

}  // namespace
}  // namespace ecat::sim
