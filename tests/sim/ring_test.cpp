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
#include <ecat/sim/standard_application.hpp>

#include "ecat_test_paths.hpp"  // ECAT_SOURCE_DIR, ECAT_BINARY_DIR, ECAT_SHARED_DATA_DIR

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

TEST(RingParse, EscPresetsAndStartStateShapeTheEsc) {
  auto ring = parse_ring(R"(simulator:
  slaves:
    - name: a
      profile: generic
      esc: {type: 0x14, revision: 0x03, build: 0x0102, fmmus: 3, sync_managers: 4, ram_kib: 1,
            ports: 0x0F, features: 0x0180, sii_busy_ns: 700000, sii_read_bytes: 4}
      start: {station: 0x1001, al_status: 0x0008}
    - {name: b, profile: generic}
)",
                         "ring.yaml");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  const EscPreset& preset = ring->slaves[0].device.esc;
  EXPECT_EQ(preset.type, 0x14);
  EXPECT_EQ(preset.sii_busy_ns, 700000);
  EXPECT_EQ(preset.sii_read_bytes, 4);
  EXPECT_EQ(ring->slaves[0].device.start.station, 0x1001);
  EXPECT_TRUE(ring->slaves[1].device.esc.empty());
  auto segment = build_segment(*ring);
  ASSERT_TRUE(segment.ok()) << segment.error().describe();
  const Esc& a = (*segment)->esc(0);
  EXPECT_EQ(a.read_u8(0x0000), 0x14);
  EXPECT_EQ(a.read_u8(0x0001), 0x03);
  EXPECT_EQ(a.read_u16(0x0002), 0x0102);
  EXPECT_EQ(a.read_u8(0x0004), 3);
  EXPECT_EQ(a.read_u8(0x0005), 4);
  EXPECT_EQ(a.read_u8(0x0006), 1);
  EXPECT_EQ(a.read_u8(0x0007), 0x0F);
  // Bit 2 clear: no DC unit at all (and bit 3, 64-bit DC, goes with it).
  EXPECT_EQ(a.read_u16(0x0008), 0x0180);
  EXPECT_EQ((*segment)->esc(0).dc(), nullptr);
  EXPECT_EQ(a.read_u16(0x0502) & 0x0040, 0);  // 4-byte SII reads
  EXPECT_EQ(a.hardware().sii_busy_ns, 700000);
  EXPECT_EQ(a.station_address(), 0x1001);
  EXPECT_EQ(a.al_state(), wire::AlState::op);
  EXPECT_EQ(a.read_u16(0x0120), 0x0008);
  // Without presets the profile's own ESC: 8 FMMUs, DC, 8-byte reads, station 0, INIT.
  const Esc& b = (*segment)->esc(1);
  EXPECT_EQ(b.read_u8(0x0004), 8);
  EXPECT_NE((*segment)->esc(1).dc(), nullptr);
  EXPECT_EQ(b.read_u16(0x0502) & 0x0040, 0x0040);
  EXPECT_EQ(b.station_address(), 0);
  EXPECT_EQ(b.al_state(), wire::AlState::init);
}

// The register facts a capture or an EEPROM shows (`ecat sim profile` writes them): the SII
// control bits, DL control at power-up, enhanced link detection and refused AL states.
TEST(RingParse, EscRegisterFactsReachTheRegisters) {
  auto ring = parse_ring(R"(simulator:
  slaves:
    - name: a
      profile: generic
      esc: {type: 0x02, sii_address_bytes: 2, sii_emulation: true, dl_control: 0x00070003,
            enhanced_link_detection: true, al_refusals: [{state: op, code: 0x001D}]}
    - {name: b, profile: generic, esc: {type: 0x12}}
)",
                         "ring.yaml");
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  const EscPreset& preset = ring->slaves[0].device.esc;
  EXPECT_EQ(preset.sii_address_bytes, 2);
  EXPECT_EQ(preset.dl_control, 0x00070003u);
  ASSERT_EQ(preset.al_refusals.size(), 1u);
  EXPECT_EQ(preset.al_refusals[0].first, wire::AlState::op);
  auto segment = build_segment(*ring);
  ASSERT_TRUE(segment.ok()) << segment.error().describe();
  Esc& a = (*segment)->esc(0);
  // ESC20 (type 0x02): 4-byte SII reads unless a key says otherwise; bits 5 and 7 as given.
  EXPECT_EQ(a.read_u16(0x0502) & 0x00E0, 0x00A0);
  EXPECT_EQ(a.read_u32(0x0100), 0x00070003u);
  EXPECT_NE(a.read_u8(0x0110) & 0x04, 0);
  EXPECT_NE(a.read_u8(0x0141) & 0x02, 0);
  EXPECT_EQ(a.al_refusal(wire::AlState::op), std::optional<std::uint16_t>(0x001D));
  // ET1200 defaults: 8-byte reads, DL control 0x00070001.
  const Esc& b = (*segment)->esc(1);
  EXPECT_EQ(b.read_u16(0x0502) & 0x0040, 0x0040);
  EXPECT_EQ(b.read_u32(0x0100), 0x00070001u);
}

TEST(RingParse, EepromObjectsAndFirmwareNone) {
  if (!has_profile("EL3202")) GTEST_SKIP() << "no EL3202 profile";
  const fs::path dir = fs::temp_directory_path() / fmt::format("ecat-ring-obj-{}", ::getpid());
  fs::create_directories(dir);
  {
    DeviceConfig config;
    config.profile = "EL3202";
    auto device = make_device(config);
    ASSERT_TRUE(device.ok());
    const auto image = (*device)->eeprom();
    std::ofstream(dir / "rtd.bin", std::ios::binary)
        .write(reinterpret_cast<const char*>(image.data()),
               static_cast<std::streamsize>(image.size()));
  }
  std::ofstream(dir / "r.yaml") << R"(simulator:
  slaves:
    - name: rtd
      profile: eeprom
      file: rtd.bin
      objects:
        - {index: 0x1018, subindex: 4, value: "78563412"}
        - {index: 0x2000, value: "34 12", writable: true}
        - {index: 0x2001, subindex: 1, abort: 0x06010000}
        - {index: 0x2001, subindex: 2, value: "01"}
    - {name: bare, profile: eeprom, file: rtd.bin, options: {firmware: none}}
)";
  auto ring = load_ring((dir / "r.yaml").string());
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  ASSERT_EQ(ring->slaves[0].device.objects.size(), 4u);
  EXPECT_EQ(ring->slaves[0].device.objects[1].value, (std::vector<std::uint8_t>{0x34, 0x12}));
  EXPECT_EQ(ring->slaves[0].device.objects[2].abort_code, 0x06010000u);
  auto segment = build_segment(*ring);
  ASSERT_TRUE(segment.ok()) << segment.error().describe();
  auto* app = dynamic_cast<StandardApplication*>(&(*segment)->esc(0).application());
  ASSERT_NE(app, nullptr);
  const ObjectDictionary& od = app->dictionary();
  ASSERT_NE(od.find(0x1018, 4), nullptr);
  EXPECT_EQ(od.find(0x1018, 4)->value, (std::vector<std::uint8_t>{0x78, 0x56, 0x34, 0x12}));
  ASSERT_NE(od.find(0x2000, 0), nullptr);
  EXPECT_EQ(od.find(0x2000, 0)->value, (std::vector<std::uint8_t>{0x34, 0x12}));
  EXPECT_EQ(od.find(0x2000, 0)->access & kAccessReadWrite, kAccessReadWrite);
  ASSERT_NE(od.find(0x2001, 1), nullptr);
  ASSERT_NE(od.find(0x2001, 2), nullptr);
  EXPECT_EQ(od.find(0x2001, 2)->access & kAccessReadWrite, kAccessRead);
  // firmware=none: the ESC alone, no StandardApplication.
  EXPECT_EQ(dynamic_cast<StandardApplication*>(&(*segment)->esc(1).application()), nullptr);
  DeviceConfig bad;
  bad.profile = "eeprom";
  bad.file = (dir / "rtd.bin").string();
  bad.options["firmware"] = "custom";
  auto refused = make_device(bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().message(),
            "profile 'eeprom': firmware 'custom' is not 'standard' or 'none'");
  fs::remove_all(dir);
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
            "master: master, link, slaves, domains, dc, targets, hot_connect)");
  EXPECT_EQ(error_of("version: 2\nsimulator: {slaves: [{name: a, profile: generic}]}\n"),
            "ring.yaml:1: version: 2 is out of range (1 to 1)");
  EXPECT_EQ(error_of("simulator:\n  slaves: [{name: a, profile: generic}]\n  slaves: []\n"),
            "ring.yaml:3: slaves: duplicate key");
  EXPECT_EQ(error_of("simulator:\n  slaves: []\n"),
            "ring.yaml:2: simulator.slaves: expected a non-empty list of slaves");
  EXPECT_EQ(
      error_of("simulator:\n  slaves: [{name: a, profile: generic}]\n  wires: []\n"),
      "ring.yaml:3: simulator.wires: unknown key (known: slaves, wiring, faults, redundancy)");
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
            "options, clock, esc, start, objects, parent, port, cable_delay_ns, timing, count, "
            "hot_connect, device_id)");
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

TEST(RingErrors, EscStartAndObjects) {
  EXPECT_EQ(
      error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: {fmmus: 17}}\n"),
      "ring.yaml:3: simulator.slaves[0].esc.fmmus: 17 is out of range (1 to 16)");
  EXPECT_EQ(
      error_of(
          "simulator:\n  slaves:\n    - {name: a, profile: generic, esc: {sii_read_bytes: 6}}\n"),
      "ring.yaml:3: simulator.slaves[0].esc.sii_read_bytes: 6 bytes: an SII interface reads 4 or "
      "8");
  EXPECT_EQ(
      error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: {colour: 1}}\n"),
      "ring.yaml:3: simulator.slaves[0].esc.colour: unknown key (known: type, revision, "
      "build, fmmus, sync_managers, ram_kib, ports, features, sii_busy_ns, sii_read_bytes, "
      "sii_address_bytes, sii_emulation, dl_control, enhanced_link_detection, al_refusals)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{sii_address_bytes: 3}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.sii_address_bytes: 3 is out of range (1 to 2)");
  EXPECT_EQ(
      error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
               "{sii_emulation: maybe}}\n"),
      "ring.yaml:3: simulator.slaves[0].esc.sii_emulation: expected true or false, found 'maybe'");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{dl_control: 0x100000000}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.dl_control: 0x100000000 is out of range (0 to "
            "4294967295)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{al_refusals: {state: op}}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.al_refusals: expected a list of {state, code}, "
            "found a mapping");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{al_refusals: [{state: running, code: 0x1D}]}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.al_refusals[0].state: 'running' is not an AL "
            "state (init, preop, bootstrap, safeop, op)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{al_refusals: [{state: op, code: 0}]}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.al_refusals[0].code: 0 is out of range (1 to "
            "65535)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, esc: "
                     "{al_refusals: [{state: op}]}}\n"),
            "ring.yaml:3: simulator.slaves[0].esc.al_refusals[0]: missing key 'code'");
  EXPECT_EQ(
      error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, start: {al_status: 5}}\n"),
      "ring.yaml:3: simulator.slaves[0].start.al_status: 0x0005 holds no AL state (INIT 1, PREOP "
      "2, BOOT 3, SAFEOP 4, OP 8; + 0x10 for the error flag)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: generic, objects: []}\n"),
            "ring.yaml:3: simulator.slaves[0].objects: profile 'generic' takes no objects (only "
            "'eeprom' does)");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: eeprom, file: a.bin, "
                     "objects: [{index: 0x2000, value: \"12 3\"}]}\n"),
            "ring.yaml:3: simulator.slaves[0].objects[0].value: an odd number of hex digits");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: eeprom, file: a.bin, "
                     "objects: [{index: 0x2000, value: \"0g\"}]}\n"),
            "ring.yaml:3: simulator.slaves[0].objects[0].value: 'g' at offset 1 is not a hex digit "
            "(bytes as hex: \"02000000\")");
  EXPECT_EQ(error_of("simulator:\n  slaves:\n    - {name: a, profile: eeprom, file: a.bin, "
                     "objects: [{index: 0x2000}]}\n"),
            "ring.yaml:3: simulator.slaves[0].objects[0]: an object needs a 'value' or an 'abort' "
            "code");
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
  EXPECT_EQ(error_of(head + "  faults:\n    - {after_ms: 5, fault: {kind: hot_plug, group: q}}\n"),
            "ring.yaml:6: simulator.faults[0]: unknown hot-connect group 'q' (known: none)");
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
  EXPECT_EQ(missing.error().message(), "/nonexistent/ring.yaml: no such ring file");

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
