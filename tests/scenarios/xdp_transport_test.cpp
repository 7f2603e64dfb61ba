// The master over an AF_XDP link (open_link("xdp:master")) against the simulator served raw
// (AF_PACKET, responder) on the other end of a veth pair in a private network namespace: the
// reference ring reaches OP and process data goes round it. Skips when the build has no AF_XDP
// link, or without the privileges for the namespace.
#include <chrono>
#include <string>

#include <gtest/gtest.h>

#include <ecat/link/open.hpp>
#include <ecat/link/xdp_link.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

TEST(XdpTransport, HealthyRingOverXdpVethReachesOperational) {
  if (!link::xdp_link_available()) {
    GTEST_SKIP() << "this build has no AF_XDP link (libxdp-dev and libbpf-dev were not found)";
  }
  RingSpec spec;
  spec.transport = Transport::raw;  // the namespace, and the simulator served raw on `segment`
  std::string xdp_error;
  std::string link_name;
  spec.wrap_link = [&](std::unique_ptr<link::Link> raw) -> std::unique_ptr<link::Link> {
    raw.reset();  // the master's end goes over AF_XDP instead
    auto xdp = link::open_link("xdp:master");
    if (!xdp) {
      xdp_error = xdp.error().describe();
      return nullptr;
    }
    link_name = (*xdp)->name();
    return std::move(*xdp);
  };
  std::string skip;
  auto ring = ScenarioRing::create(spec, &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(xdp_error.empty()) << xdp_error;
  ASSERT_TRUE(ring);
  EXPECT_EQ(link_name, "xdp:master");
  auto op = ring->master->await_operational(10s);
  ASSERT_TRUE(op) << op.error().describe() << "; " << ring->describe();
  EXPECT_TRUE(ring->all_slaves_in(SlaveState::op)) << ring->describe();
  EXPECT_FALSE(ring->any_slave_fault()) << ring->describe();
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  const auto stats = ring->domain_stats();
  EXPECT_EQ(stats.state, master::DomainState::cycling);
  EXPECT_GT(stats.valid_count, 0u);
  EXPECT_TRUE(ring->master->status().runtime_faults.empty());
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  const auto sim = ring->server->status();
  ASSERT_EQ(sim.slaves.size(), 3u);
  for (const auto& slave : sim.slaves)
    EXPECT_EQ(slave.al_state, wire::AlState::op) << slave.name;
}

}  // namespace
}  // namespace ecat::scenarios
