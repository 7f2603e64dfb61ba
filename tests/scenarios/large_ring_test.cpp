// Rings of hundreds of terminals in one domain (issue #17): `operational` means every slave is at
// its target, and a ring's size needs no limit raised by hand.
#include <chrono>
#include <cstddef>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <ecat/master/config.hpp>
#include <ecat/master/domain.hpp>
#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

// A ring file (docs/RING-FILE.md) of an EK1100 followed by `terminals` terminals (EL1809 and
// EL2809 alternating, every terminal's process data in the one domain "main"): the simulator's
// section and the master's, as `ecat run` and `ecat sim --ring` read them. Nothing in it sizes
// the domain: registrations, image and frames per cycle follow from the ring.
std::string ring_file(std::size_t terminals) {
  std::string yaml = "version: 1\nsimulator:\n  slaves:\n    - {name: coupler, profile: EK1100}\n";
  for (std::size_t i = 0; i < terminals; ++i)
    yaml += fmt::format("    - {{name: t{}, profile: {}}}\n", i, i % 2 == 0 ? "EL1809" : "EL2809");
  yaml +=
      "master: {scan_poll_ms: 10, scan_stable_ms: 50}\n"
      "dc: false\n"
      "domains:\n  - {id: main, period_us: 2000}\n"
      "slaves:\n  - {name: coupler}\n";
  for (std::size_t i = 0; i < terminals; ++i)
    yaml += fmt::format("  - {{name: t{}, process_data: main}}\n", i);
  return yaml;
}

TEST(LargeRing, OperationalMeansEverySlaveInOp) {
  // Well beyond the 170 terminals the old fixed limit of 256 registrations took (scale figures up
  // to 1,024 terminals are the bench's: bench/master_bench.cpp).
  // A ring file of 1,024 terminals reaches OP the same way (bench/master_bench.cpp --startup
  // --full writes and runs one); here a size that stays quick under the sanitizers.
  constexpr std::size_t kTerminals = 300;
  const auto dir = std::filesystem::temp_directory_path() /
                   fmt::format("ecat-large-ring-{}", static_cast<long>(::getpid()));
  std::filesystem::create_directories(dir);
  const auto path = (dir / "ring.yaml").string();
  {
    std::ofstream out(path);
    out << ring_file(kTerminals);
    ASSERT_TRUE(out.good()) << "cannot write " << path;
  }
  auto ring = sim::load_ring(path);
  auto config = load_master_config(path);
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  ASSERT_TRUE(config.ok()) << config.error().describe();
  ASSERT_EQ(config->slaves.size(), kTerminals + 1);
  ASSERT_EQ(config->domains.size(), 1u);
  EXPECT_EQ(config->domains[0].max_image_size, 0u) << "the domain sizes itself";
  auto server = sim::make_server(*ring);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  // The simulator answers inside the bus's send: 300 slaves under a sanitizer must not lose
  // frames to a starved simulator thread (this test is about sizes and states, not timing).
  std::unique_ptr<link::Link> link = (*server)->function_link();
  Master master(std::move(*config));
  ASSERT_TRUE(master.start(std::move(link)).ok());
  auto up = master.await_operational(60s);
  if (!up) {
    const auto status = master.status();
    std::string why;
    for (const auto& f : status.runtime_faults)
      why += "\n  runtime fault: " + f;
    for (const auto& f : status.activation_failures)
      why += "\n  activation failure: " + f.slave + ": " + f.error.describe();
    std::size_t listed = 0;
    for (const auto& slave : status.slaves) {
      if (slave.state == SlaveState::op || ++listed > 8) continue;
      why += fmt::format("\n  {} {} {}", slave.name, to_string(slave.state),
                         slave.fault.value_or(slave.startup_error.value_or("")));
    }
    FAIL() << up.error().describe() << why;
  }
  std::size_t in_op = 0;
  std::string behind;
  for (const auto& slave : master.slaves()) {
    if (slave.state == SlaveState::op) {
      ++in_op;
    } else if (behind.size() < 200) {
      behind += fmt::format(" {}={}", slave.name, to_string(slave.state));
    }
  }
  EXPECT_EQ(in_op, kTerminals + 1) << "not in OP:" << behind;
  // Every terminal's process data registered in the one domain, its image as large as theirs
  // together (EL1809: 2 input bytes, EL2809: 2 output bytes).
  auto domain = master.domain("main");
  ASSERT_TRUE(domain.ok());
  const DomainInfo info = (*domain)->info();
  EXPECT_GE(info.registrations.size(), kTerminals);  // at least one per terminal
  EXPECT_EQ(info.image_size, 2 * kTerminals);
  EXPECT_FALSE(info.datagrams.empty());
  (void)master.stop();
}

}  // namespace
}  // namespace ecat::master
