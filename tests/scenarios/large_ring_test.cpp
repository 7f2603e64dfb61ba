// Rings of hundreds of terminals in one domain (issue #17): `operational` means every slave is at
// its target, and a ring's size needs no limit raised by hand.
#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <ecat/master/master.hpp>
#include <ecat/master/slave.hpp>
#include <ecat/sim/ring.hpp>
#include <ecat/sim/server.hpp>

namespace ecat::master {
namespace {

using namespace std::chrono_literals;

// An EK1100 followed by `terminals` terminals, EL1809 and EL2809 alternating.
std::string ring_yaml(std::size_t terminals) {
  std::string yaml = "version: 1\nsimulator:\n  slaves:\n    - {name: coupler, profile: EK1100}\n";
  for (std::size_t i = 0; i < terminals; ++i)
    yaml += fmt::format("    - {{name: t{}, profile: {}}}\n", i, i % 2 == 0 ? "EL1809" : "EL2809");
  return yaml;
}

MasterConfig config_for(std::size_t terminals) {
  MasterConfig config;
  config.scan = {.poll = 10ms, .stable = 50ms, .timeout = 10s};
  config.dc.reset();
  DomainConfig domain;
  domain.id = "main";
  domain.period = 2ms;
  config.domains.push_back(std::move(domain));
  SlaveConfig coupler;
  coupler.name = "coupler";
  config.slaves.push_back(std::move(coupler));
  for (std::size_t i = 0; i < terminals; ++i) {
    SlaveConfig terminal;
    terminal.name = fmt::format("t{}", i);
    terminal.process_data = ProcessDataRequest::all("main");
    config.slaves.push_back(std::move(terminal));
  }
  return config;
}

TEST(LargeRing, OperationalMeansEverySlaveInOp) {
  // Well beyond the 170 terminals the old fixed limit of 256 registrations took (scale figures up
  // to 1,024 terminals are the bench's: bench/master_bench.cpp).
  constexpr std::size_t kTerminals = 300;
  auto ring = sim::parse_ring(ring_yaml(kTerminals));
  ASSERT_TRUE(ring.ok()) << ring.error().describe();
  auto server = sim::make_server(*ring);
  ASSERT_TRUE(server.ok()) << server.error().describe();
  // The simulator answers inside the bus's send: 300 slaves under a sanitizer must not lose
  // frames to a starved simulator thread (this test is about sizes and states, not timing).
  std::unique_ptr<link::Link> link = (*server)->function_link();
  Master master(config_for(kTerminals));
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
  (void)master.stop();
}

}  // namespace
}  // namespace ecat::master
