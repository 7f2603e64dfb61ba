// Cable redundancy (docs/scenarios/00, 39, 45): the default ring served with a second master port
// (sim::RedundantPorts, in process) and the master on a link::RedundantLink over both ports.
// The cable is broken between slaves or cut at a master port while the domain cycles.
#include <chrono>
#include <string>
#include <thread>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include <ecat/link/redundant_link.hpp>
#include <ecat/master/ring_break.hpp>
#include <ecat/sim/control.hpp>
#include <ecat/sim/redundant_ring.hpp>
#include <ecat/sim/segment.hpp>

#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using link::RedundancyTopology;
using link::RingState;
using sim::RedundantTopology;
using wire::RedundantPort;

RingSpec redundant_spec(std::chrono::nanoseconds period = 5ms,
                        Transport transport = Transport::redundant) {
  RingSpec spec;
  spec.transport = transport;
  spec.domain_period = period;
  return spec;
}

// Cycles that did not come back valid since `before`.
std::uint64_t invalid_since(const master::DomainStats& before, const master::DomainStats& now) {
  const auto invalid = [](const master::DomainStats& s) {
    return s.wkc_mismatch_count + s.timeout_count + s.expired_count + s.overrun_count +
           s.link_error_count;
  };
  return invalid(now) - invalid(before);
}

std::string debug_status(ScenarioRing& ring) {
  const auto s = ring.redundant_link->status();
  const auto d = ring.domain_stats();
  return fmt::format(
      "; link: ring {} fwd {} rev {} copies {} merged {} lone {} window {} unknown {} stale {}; "
      "domain last_wkc {} expected {} actual {}",
      link::to_string(s.ring), s.forward_crosses, s.reverse_crosses, s.passthrough_copies, s.merged,
      s.lone_bounces, s.merge_timeouts, s.unknown_sources, s.stale, d.last_wkc,
      d.last_invalid ? d.last_invalid->expected_wkc : 0,
      d.last_invalid ? d.last_invalid->actual_wkc : 0);
}

// Waits for `n` more valid cycles.
bool cycles_pass(ScenarioRing& ring, std::uint64_t n) {
  const auto start = ring.domain_stats().valid_count;
  return eventually([&] { return ring.domain_stats().valid_count >= start + n; });
}

// Process data keeps flowing through `topology` with the whole ring's working counter, losing
// no cycle but possibly the one in flight at the moment of the change.
void expect_flows_through(ScenarioRing& ring, const RedundantTopology& topology,
                          const std::function<void()>& change = {}) {
  SCOPED_TRACE(sim::describe(topology));
  ASSERT_TRUE(cycles_pass(ring, 5));
  const auto before = ring.domain_stats();
  if (change) {
    change();
    ASSERT_EQ(sim::describe(ring.redundant_ports->topology()), sim::describe(topology));
  } else {
    ASSERT_TRUE(ring.redundant_ports->set_topology(topology));
  }
  ASSERT_TRUE(cycles_pass(ring, 20)) << ring.describe();
  const auto after = ring.domain_stats();
  EXPECT_LE(invalid_since(before, after), 1u) << ring.describe() << debug_status(ring);
  EXPECT_EQ(after.last_wkc, before.last_wkc);
  EXPECT_LE(after.wkc_mismatch_count - before.wkc_mismatch_count, 1u);
  EXPECT_TRUE(ring.loopback(true)) << ring.describe();
  EXPECT_TRUE(ring.loopback(false)) << ring.describe();
  EXPECT_EQ(ring.state(), MasterState::operational);
  EXPECT_TRUE(ring.master->status().runtime_faults.empty()) << ring.describe();
}

void expect_never_recovered(ScenarioRing& ring) {
  EXPECT_FALSE(ring.saw(MasterState::recovering)) << ring.describe();
  EXPECT_FALSE(ring.saw(MasterState::activation_blocked)) << ring.describe();
  EXPECT_TRUE(ring.all_slaves_in(SlaveState::op)) << ring.describe();
  EXPECT_FALSE(ring.any_slave_fault()) << ring.describe();
}

// ---- 00 (redundant part): a whole redundant ring, one cable break, heal ----------------------

TEST(Scenario00, RedundantRingThroughABreakAndBack) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  ASSERT_NE(ring->redundant_link, nullptr);
  Monitor monitor(*ring->master);
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  auto status = ring->redundant_link->status();
  EXPECT_EQ(status.topology, RedundancyTopology::redundant);
  EXPECT_EQ(status.ring, RingState::whole);
  EXPECT_GT(status.forward_crosses, 0u);
  EXPECT_GT(status.passthrough_copies, 0u);
  EXPECT_EQ(status.merged, 0u);

  expect_flows_through(*ring, RedundantTopology::broken_after(1));
  status = ring->redundant_link->status();
  EXPECT_EQ(status.ring, RingState::broken);
  EXPECT_EQ(status.topology, RedundancyTopology::redundant);  // both ports work
  // The coupler alone before the break maps no process data: the primary's half of the LRW comes
  // back untouched and the secondary's bounce is the reply.
  EXPECT_GT(status.lone_bounces, 0u);
  EXPECT_EQ(status.ring_breaks, 1u);
  // The master reports it, in its status and in the event stream, naming the break from the
  // slaves' DL status: between the coupler (slave 0) and the inputs terminal (slave 1).
  const auto slaves = ring->master->status().slaves;
  ASSERT_EQ(slaves.size(), 3u);
  const auto between = [&](std::size_t before) {
    return fmt::format(
        "redundancy:redundant, ring broken between slave {} (station 0x{:04X}) and "
        "slave {} (station 0x{:04X})",
        before, slaves[before].station, before + 1, slaves[before + 1].station);
  };
  EXPECT_TRUE(eventually([&] { return monitor.saw(between(0)); })) << monitor.seen();
  auto master_status = ring->master->status();
  ASSERT_TRUE(master_status.redundancy);
  EXPECT_EQ(master_status.redundancy->ring, RingState::broken);
  ASSERT_TRUE(master_status.redundancy->break_location);
  link::RingBreak expected{link::RingBreak::Where::between_slaves, 0, slaves[0].station, 1,
                           slaves[1].station};
  EXPECT_EQ(*master_status.redundancy->break_location, expected);

  // The break moves: between the inputs and the outputs terminal. Both halves carry process
  // data now and are merged.
  const auto merged_before = ring->redundant_link->status().merged;
  expect_flows_through(*ring, RedundantTopology::broken_after(2));
  EXPECT_GT(ring->redundant_link->status().merged, merged_before + 20);
  // The ring stayed broken, so the link says nothing new: the master finds the moved break by
  // reading the DL status again while the ring is broken.
  EXPECT_TRUE(eventually([&] { return monitor.saw(between(1)); })) << monitor.seen();
  master_status = ring->master->status();
  ASSERT_TRUE(master_status.redundancy && master_status.redundancy->break_location);
  EXPECT_EQ(master_status.redundancy->break_location->before_position, 1u);
  EXPECT_EQ(master_status.redundancy->break_location->after_station, slaves[2].station);
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  status = ring->redundant_link->status();
  EXPECT_EQ(status.ring, RingState::whole);
  EXPECT_EQ(status.ring_heals, 1u);
  EXPECT_EQ(status.merge_timeouts, 0u);  // both halves always came back
  EXPECT_TRUE(eventually([&] { return monitor.saw("redundancy:redundant, ring whole"); }))
      << monitor.seen();
  EXPECT_FALSE(ring->master->status().redundancy->break_location);
  expect_never_recovered(*ring);
  const auto sim = ring->redundant_ports->stats();
  EXPECT_GT(sim.crosses, 0u);
  EXPECT_GT(sim.bounces, 0u);
}

// ---- 00 (redundant part) on a ring through a junction ------------------------------------------

// The ring file's slaves after the basic three, configured in that order: process data in
// `main` where asked, health polled every 20 ms.
void configure_after_basic(RingSpec& spec, std::vector<std::pair<const char*, bool>> extra) {
  spec.adjust = [extra = std::move(extra)](master::MasterConfig& c) {
    for (const auto& [name, process_data] : extra) {
      master::SlaveConfig s;
      s.name = name;
      if (process_data) s.process_data = master::ProcessDataRequest::all("main");
      s.health_poll = 20ms;
      c.slaves.push_back(std::move(s));
    }
  };
}

// coupler -> inputs -> outputs -> junction (EK1122); on the junction's port 1 a branch that ends
// there (branch_coupler -> branch_in), on its port 2 the ring goes on (far_coupler -> far_in ->
// far_out, whose port 1 is cabled to the secondary port). A frame leaves the junction by port 1
// before port 2: ring positions 0..3, the branch 4..5, the far slaves 6..8.
RingSpec junction_redundant_spec() {
  RingSpec spec = redundant_spec();
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: junction, profile: EK1122}
    - {name: branch_coupler, profile: EK1100, parent: junction, port: 1}
    - {name: branch_in, profile: EL1809}
    - {name: far_coupler, profile: EK1100, parent: junction, port: 2}
    - {name: far_in, profile: EL1809}
    - {name: far_out, profile: EL2809}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_16, to: inputs.channel_16}
)";
  configure_after_basic(spec, {{"junction", false},
                               {"branch_coupler", false},
                               {"branch_in", true},
                               {"far_coupler", false},
                               {"far_in", true},
                               {"far_out", true}});
  return spec;
}

// The break is located on the ring's shape (the tree DC planning builds): a cable leaving the
// junction's port 2 is named with its ports, one between two slaves behind it as on a line, and
// the branch's end (branch_in's port 1 and the junction's unused port 3, without link) is never
// taken for one. A cable inside the branch is not the ring's: the simulator refuses to break the
// ring there.
TEST(Scenario00, RedundantRingThroughAJunctionLocatesTheBreak) {
  auto ring = ScenarioRing::operational(junction_redundant_spec());
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  const auto slaves = ring->master->status().slaves;
  ASSERT_EQ(slaves.size(), 9u);
  const auto station = [&](std::string_view name) -> std::uint16_t {
    for (const auto& s : slaves)
      if (s.name == name) return s.station;
    ADD_FAILURE() << name;
    return 0;
  };
  const auto located_as = [&](const link::RingBreak& expected) {
    return eventually([&] {
      const auto r = ring->master->status().redundancy;
      return r && r->break_location == expected;
    });
  };

  // Behind the junction's port 2: between the junction (3) and far_coupler (6).
  expect_flows_through(*ring, RedundantTopology::broken_after(6));
  const link::RingBreak at_junction{link::RingBreak::Where::between_slaves,
                                    3,
                                    station("junction"),
                                    6,
                                    station("far_coupler"),
                                    2,
                                    0};
  EXPECT_TRUE(located_as(at_junction)) << ring->describe();
  EXPECT_TRUE(eventually([&] {
    return monitor.saw(fmt::format(
        "redundancy:redundant, ring broken between slave 3 (station 0x{:04X}, port 2) and slave 6 "
        "(station 0x{:04X}, port 0)",
        station("junction"), station("far_coupler")));
  })) << monitor.seen();
  EXPECT_TRUE(ring->master->status().slaves.size() == 9u);

  // The break moves behind it: between far_in (7) and far_out (8).
  expect_flows_through(*ring, RedundantTopology::broken_after(8));
  EXPECT_TRUE(located_as(link::RingBreak{link::RingBreak::Where::between_slaves, 7,
                                         station("far_in"), 8, station("far_out")}))
      << ring->describe();

  // The secondary's cable: far_out's port 1.
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::secondary));
  EXPECT_TRUE(eventually([&] {
    const auto b = ring->master->status().redundancy->break_location;
    return b && b->where == link::RingBreak::Where::secondary_cable && b->before_position == 8 &&
           b->before_port == 1;
  })) << ring->describe();

  // In front of the junction, between inputs (1) and outputs (2).
  expect_flows_through(*ring, RedundantTopology::broken_after(2));
  EXPECT_TRUE(located_as(link::RingBreak{link::RingBreak::Where::between_slaves, 1,
                                         station("inputs"), 2, station("outputs")}))
      << ring->describe();

  // Inside the branch: not a ring cable.
  auto refused = ring->redundant_ports->set_topology(RedundantTopology::broken_after(5));
  ASSERT_FALSE(refused);
  EXPECT_NE(refused.error().message().find("leads into 'branch_in' on port 1 of "
                                           "'branch_coupler', a branch off the ring"),
            std::string::npos)
      << refused.error().describe();

  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_TRUE(eventually([&] { return !ring->master->status().redundancy->break_location; }));
  expect_never_recovered(*ring);
}

// A ring through a junction served broken before the master starts, never whole until healed:
// its shape comes from the two sides the start-up read (master::broken_ring_tree). coupler: on
// its E-bus (port 1) inputs -> outputs, which ends there; on its X2 (port 2) the junction; on the
// junction's port 1 a branch that ends there (branch_coupler -> branch_in), on its port 2 the
// ring goes on (far_in -> far_out, whose port 1 is cabled to the secondary port). Ring positions:
// 0 coupler, 1 inputs, 2 outputs, 3 junction, 4 branch_coupler, 5 branch_in, 6 far_in, 7 far_out.
RingSpec junction_on_x2_spec() {
  RingSpec spec = redundant_spec();
  spec.ring_yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: junction, profile: EK1122, parent: coupler, port: 2}
    - {name: branch_coupler, profile: EK1100, parent: junction, port: 1}
    - {name: branch_in, profile: EL1809}
    - {name: far_in, profile: EL1809, parent: junction, port: 2}
    - {name: far_out, profile: EL2809}
  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: outputs.channel_16, to: inputs.channel_16}
)";
  configure_after_basic(spec, {{"junction", false},
                               {"branch_coupler", false},
                               {"branch_in", true},
                               {"far_in", true},
                               {"far_out", true}});
  return spec;
}

// Broken between far_in and far_out from the start: the line rule would take the E-bus's end
// (outputs' free port 1) for the break; the two sides' shape names far_in's port 1 (its only
// free port, the junction's and the coupler's all used by then). Healed, the whole ring's shape
// replaces it, and breaks at the junction's ring port and at the coupler's X2 are named with
// their ports.
TEST(Scenario00, RedundantRingThroughAJunctionStartsBrokenBehindIt) {
  auto spec = junction_on_x2_spec();
  spec.redundant_cabling = RedundantTopology::broken_after(7);
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  ASSERT_NE(ring->redundant_link, nullptr);
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::broken);
  const auto slaves = ring->master->status().slaves;
  ASSERT_EQ(slaves.size(), 8u);
  const auto station = [&](std::string_view name) -> std::uint16_t {
    for (const auto& s : slaves)
      if (s.name == name) return s.station;
    ADD_FAILURE() << name;
    return 0;
  };
  for (std::size_t i = 0; i < slaves.size(); ++i)
    EXPECT_EQ(slaves[i].station, 0x1000 + i) << slaves[i].name;
  const auto located_as = [&](const link::RingBreak& expected) {
    return eventually([&] {
      const auto r = ring->master->status().redundancy;
      return r && r->break_location == expected;
    });
  };
  const link::RingBreak behind{
      link::RingBreak::Where::between_slaves, 6, station("far_in"), 7, station("far_out"), 1, 0};
  EXPECT_TRUE(located_as(behind)) << ring->describe();
  // As a line (the DL status the start-up read), the E-bus's end would be the break.
  std::vector<master::RingPortReading> start;
  for (const auto& s : slaves) {
    auto slave = ring->master->slave(s.name);
    ASSERT_TRUE(slave);
    start.push_back({s.station, (*slave)->info().dl_status});
  }
  const auto line = master::locate_ring_break(start);
  ASSERT_TRUE(line);
  EXPECT_EQ(line->before_position, 2u);
  EXPECT_EQ(line->after_position, 3u);
  ASSERT_TRUE(cycles_pass(*ring, 20));
  EXPECT_EQ(ring->master->status().redundancy->break_location, behind);  // and stays

  Monitor monitor(*ring->master);
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_TRUE(eventually([&] { return !ring->master->status().redundancy->break_location; }));

  // At the junction's ring port: right behind the branch's end.
  expect_flows_through(*ring, RedundantTopology::broken_after(6));
  EXPECT_TRUE(located_as(link::RingBreak{link::RingBreak::Where::between_slaves, 3,
                                         station("junction"), 6, station("far_in"), 2, 0}))
      << ring->describe();
  EXPECT_TRUE(eventually([&] {
    return monitor.saw(fmt::format(
        "redundancy:redundant, ring broken between slave 3 (station 0x{:04X}, port 2) and slave 6 "
        "(station 0x{:04X}, port 0)",
        station("junction"), station("far_in")));
  })) << monitor.seen();
  // At the coupler's X2, in front of the junction: right behind the E-bus's end.
  expect_flows_through(*ring, RedundantTopology::broken_after(3));
  EXPECT_TRUE(located_as(link::RingBreak{link::RingBreak::Where::between_slaves, 0,
                                         station("coupler"), 3, station("junction"), 2, 0}))
      << ring->describe();
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_TRUE(eventually([&] { return !ring->master->status().redundancy->break_location; }));
  expect_never_recovered(*ring);
}

// ---- 39: the primary's cable cut at the master, then restored --------------------------------

TEST(Scenario39, RedundantPrimaryCutKeepsOperational) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  Monitor monitor(*ring->master);
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::primary));
  // Slave 0's port 0 lost its link: the primary's cable.
  const auto station0 = ring->master->status().slaves.at(0).station;
  EXPECT_TRUE(eventually([&] {
    return monitor.saw(
        fmt::format("redundancy:redundant, ring broken at the primary port's cable "
                    "(slave 0, station 0x{:04X}, port 0)",
                    station0));
  })) << monitor.seen();
  const auto located = ring->master->status().redundancy->break_location;
  ASSERT_TRUE(located);
  EXPECT_EQ(located->where, link::RingBreak::Where::primary_cable);
  auto status = ring->redundant_link->status();
  EXPECT_EQ(status.ring, RingState::broken);
  EXPECT_GT(status.lone_bounces, 0u);
  EXPECT_GT(status.merge_timeouts, 0u);
  // Only the frames in flight when the cable was cut waited for the primary's side (together,
  // for one patience): the silent side is remembered, later lone bounces are handed on at once.
  ASSERT_TRUE(cycles_pass(*ring, 20));
  EXPECT_EQ(ring->redundant_link->status().merge_timeouts, status.merge_timeouts);
  EXPECT_GT(ring->redundant_link->status().lone_bounces, status.lone_bounces + 19);
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::whole);
  expect_never_recovered(*ring);
}

// ---- 45: the secondary's cable cut, at a 10 ms and at a 1 ms cycle ---------------------------

void secondary_cut(std::chrono::nanoseconds period) {
  auto ring = ScenarioRing::operational(redundant_spec(period));
  ASSERT_TRUE(ring);
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::secondary));
  EXPECT_GT(ring->redundant_link->status().lone_bounces, 0u);
  EXPECT_TRUE(eventually([&] {
    const auto b = ring->master->status().redundancy->break_location;
    return b && b->where == link::RingBreak::Where::secondary_cable && b->before_position == 2;
  })) << ring->describe();
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  expect_never_recovered(*ring);
}

TEST(Scenario45, RedundantSecondaryCutAt10ms) {
  secondary_cut(10ms);
}
TEST(Scenario45, RedundantSecondaryCutAt1ms) {
  secondary_cut(1ms);
}

// ---- over two veth pairs: the simulator serving both ends of the ring on raw interfaces --------

TEST(Scenario45, RedundantSecondaryCutOverTwoVethPairs) {
  std::string skip;
  auto ring = ScenarioRing::operational(redundant_spec(5ms, Transport::redundant_raw), &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  EXPECT_TRUE(ring->redundant_ports->serving());
  EXPECT_EQ(ring->redundant_ports->served(), "segment,segment2");
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::secondary));
  EXPECT_GT(ring->redundant_link->status().lone_bounces, 0u);
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::whole);
  expect_never_recovered(*ring);
}

// The control channel of `ecat sim` on a socket of its own, as a test harness drives it.
class ControlChannel {
 public:
  explicit ControlChannel(sim::SimServer& server)
      : path_(fmt::format("{}ecat-sim-redundant-{}.sock", ::testing::TempDir(), ::getpid())) {
    auto started = sim::ControlServer::start(server, path_);
    EXPECT_TRUE(started) << started.error().describe();
    if (started) server_ = std::move(*started);
  }
  nlohmann::json call(const std::string& request) {
    auto reply = sim::control_call(path_, request);
    EXPECT_TRUE(reply) << reply.error().describe();
    if (!reply) return {};
    return nlohmann::json::parse(*reply);
  }

 private:
  std::string path_;
  std::unique_ptr<sim::ControlServer> server_;
};

TEST(Scenario00, RedundantRingOverTwoVethPairsBreaksAndHealsByTheControlChannel) {
  std::string skip;
  auto ring = ScenarioRing::operational(redundant_spec(5ms, Transport::redundant_raw), &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  ControlChannel control(*ring->server);
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  auto status = ring->redundant_link->status();
  EXPECT_EQ(status.topology, RedundancyTopology::redundant);
  EXPECT_EQ(status.ring, RingState::whole);
  EXPECT_GT(status.forward_crosses, 0u);
  EXPECT_GT(status.passthrough_copies, 0u);
  EXPECT_EQ(control.call(R"({"op":"ring"})").value("ring", ""), "whole");

  // A break in the middle: both halves carry process data, merged by the master's link.
  expect_flows_through(*ring, RedundantTopology::broken_after(2), [&] {
    const auto reply = control.call(R"({"op":"ring","break_after":2})");
    EXPECT_TRUE(reply.value("ok", false)) << reply.dump();
    EXPECT_EQ(reply.value("ring", ""), "break after 2");
  });
  status = ring->redundant_link->status();
  EXPECT_EQ(status.ring, RingState::broken);
  EXPECT_GT(status.merged, 20u);
  const auto sim_status = control.call(R"({"op":"status"})");
  EXPECT_EQ(sim_status["faults"].value("ring", ""), "break after 2") << sim_status.dump();
  const auto master_status = ring->master->status();
  ASSERT_TRUE(master_status.redundancy);
  EXPECT_EQ(master_status.redundancy->ring, RingState::broken);
  // The control channel's break shows in the slaves' DL status: the master names it.
  const auto slaves = master_status.slaves;
  ASSERT_EQ(slaves.size(), 3u);
  const auto located = [&]() -> std::optional<link::RingBreak> {
    const auto r = ring->master->status().redundancy;
    return r ? r->break_location : std::nullopt;
  };
  const link::RingBreak between{link::RingBreak::Where::between_slaves, 1, slaves[1].station, 2,
                                slaves[2].station};
  EXPECT_TRUE(eventually([&] { return located() == between; }))
      << (located() ? link::describe(*located()) : std::string("none"));

  // Healed: redundant again, the primary's frames cross the whole ring.
  expect_flows_through(*ring, RedundantTopology::whole_ring(), [&] {
    EXPECT_TRUE(control.call(R"({"op":"ring","heal":true})").value("ok", false));
  });
  status = ring->redundant_link->status();
  EXPECT_EQ(status.ring, RingState::whole);
  EXPECT_EQ(status.ring_heals, 1u);
  EXPECT_TRUE(eventually([&] { return !located(); }));

  // The same as a fault (what `ecat sim fault inject ring_cut primary` sends), and back.
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::primary), [&] {
    const auto reply =
        control.call(R"({"op":"fault.inject","fault":{"kind":"ring_cut","port":"primary"}})");
    EXPECT_TRUE(reply.value("ok", false)) << reply.dump();
  });
  // Slave 0's port 0 lost the link (before_port 0).
  const link::RingBreak primary{
      link::RingBreak::Where::primary_cable, 0, slaves[0].station, 0, slaves[0].station, 0, 0};
  EXPECT_TRUE(eventually([&] { return located() == primary; }))
      << (located() ? link::describe(*located()) : std::string("none"));
  expect_flows_through(*ring, RedundantTopology::whole_ring(), [&] {
    EXPECT_TRUE(control.call(R"({"op":"fault.clear"})").value("ok", false));
  });
  EXPECT_TRUE(eventually([&] { return !located(); }));

  // Bad values are named.
  auto refused = control.call(R"({"op":"ring","break_after":3})");
  EXPECT_FALSE(refused.value("ok", true));
  EXPECT_NE(refused.value("error", "").find("cannot break after slave 3 (1..2)"), std::string::npos)
      << refused.dump();
  refused = control.call(R"({"op":"ring","cut":"tertiary"})");
  EXPECT_NE(refused.value("error", "").find("unknown master port 'tertiary'"), std::string::npos)
      << refused.dump();
  refused = control.call(R"({"op":"fault.inject","fault":{"kind":"ring_break","after":0}})");
  EXPECT_FALSE(refused.value("ok", true)) << refused.dump();
  expect_never_recovered(*ring);
  EXPECT_EQ(ring->redundant_ports->stats().send_errors, 0u);
}

// ---- 42 (the redundant part): the primary cable pulled and replugged, one direction slow ------

TEST(Scenario42, RedundantReplugWithAsymmetricDelayLosesNoCycle) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  // Pulled: the secondary carries the ring alone (the cycle in flight may be lost).
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::primary));
  Monitor monitor(*ring->master);
  // Replugged with the link's two directions out of step: what leaves the ring into the primary
  // port comes a frame timeout and more late (the PHY of the reference's NIC), what the primary
  // sends goes in at once.
  ASSERT_TRUE(cycles_pass(*ring, 5));
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->inject(sim::fault::script(
      {sim::fault::port_delay(RedundantPort::primary, 25ms), sim::fault::ring_heal()})));
  EXPECT_EQ(ring->redundant_ports->topology().kind, RedundantTopology::Kind::whole);
  ASSERT_TRUE(cycles_pass(*ring, 40)) << ring->describe();
  // The link settles: the delay goes.
  ASSERT_TRUE(ring->server->inject(sim::fault::port_delay(RedundantPort::primary, 0ms)));
  ASSERT_TRUE(cycles_pass(*ring, 20)) << ring->describe();
  const auto after = ring->domain_stats();
  EXPECT_EQ(invalid_since(before, after), 0u) << ring->describe() << debug_status(*ring);
  EXPECT_EQ(after.last_wkc, before.last_wkc);
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::whole);
  expect_never_recovered(*ring);
  EXPECT_FALSE(monitor.first_matching("invalid:")) << monitor.seen();
}

// A ring that starts with one port cut comes up through the other alone: every slave is on one
// side, so position addressing (station assignment) counts as on a whole ring.
TEST(Scenario39, RedundantRingStartsWithThePrimaryCut) {
  auto spec = redundant_spec();
  RingSpec copy = spec;
  auto ring = ScenarioRing::create(copy);
  ASSERT_TRUE(ring);
  // The master is already starting; cut before it gets far (a race that only decides whether the
  // first frames cross or bounce: either way it must come up).
  ASSERT_TRUE(
      ring->redundant_ports->set_topology(RedundantTopology::cut_at(RedundantPort::primary)));
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::broken);
}

// ---- Faults on the redundant ports' replies, with the master's link on top ----------------------

// Injects `fault` (a `next N` one) and checks the session copes while it lasts and after: the
// master stays operational with the whole ring's working counter, losing at most `lost` cycles.
void expect_copes_with(ScenarioRing& ring, const sim::Fault& fault, std::uint64_t lost) {
  SCOPED_TRACE(sim::describe(fault));
  ASSERT_TRUE(cycles_pass(ring, 5));
  const auto before = ring.domain_stats();
  ASSERT_TRUE(ring.server->inject(fault));
  ASSERT_TRUE(eventually([&] { return ring.server->fault_info().queued.empty(); }))
      << ring.describe();
  ASSERT_TRUE(cycles_pass(ring, 20)) << ring.describe();
  const auto after = ring.domain_stats();
  EXPECT_LE(invalid_since(before, after), lost) << ring.describe() << debug_status(ring);
  EXPECT_EQ(after.last_wkc, before.last_wkc);
  EXPECT_TRUE(ring.loopback(true)) << ring.describe();
  EXPECT_TRUE(ring.loopback(false)) << ring.describe();
  EXPECT_EQ(ring.state(), MasterState::operational);
  EXPECT_TRUE(ring.master->status().runtime_faults.empty()) << ring.describe();
}

TEST(RedundantReplyFaults, DuplicatesAreNotCountedTwice) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  // Whole: the forward cross comes twice; broken in the middle: both bounces do.
  expect_copes_with(*ring, sim::fault::next(sim::fault::duplicate_reply(), 60), 0);
  ASSERT_TRUE(ring->redundant_ports->set_topology(RedundantTopology::broken_after(2)));
  ASSERT_TRUE(cycles_pass(*ring, 5));
  const auto merged = ring->redundant_link->status().merged;
  expect_copes_with(*ring, sim::fault::next(sim::fault::duplicate_reply(), 60), 1);
  EXPECT_GT(ring->redundant_link->status().merged, merged + 20);
  EXPECT_GT(ring->redundant_ports->stats().duplicated, 20u);
  expect_never_recovered(*ring);
}

TEST(RedundantReplyFaults, ReorderedAndDelayedRepliesOnABrokenRing) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  ASSERT_TRUE(ring->redundant_ports->set_topology(RedundantTopology::broken_after(2)));
  ASSERT_TRUE(cycles_pass(*ring, 5));
  const auto delayed = ring->redundant_ports->stats().delayed;
  // The secondary's half of one frame held back behind the next: its cycle is short by that half
  // at most (the primary's half waits out the merge window alone), the late half is dropped.
  expect_copes_with(
      *ring,
      sim::fault::next(sim::fault::at_port(sim::fault::reorder_replies(), RedundantPort::secondary),
                       1),
      2);
  EXPECT_EQ(ring->redundant_ports->stats().delayed, delayed + 1);
  // Within the merge window: merged as if on time.
  auto status = ring->redundant_link->status();
  expect_copes_with(
      *ring,
      sim::fault::next(
          sim::fault::at_port(sim::fault::delay_replies(100us), RedundantPort::secondary), 30),
      1);
  EXPECT_GT(ring->redundant_link->status().merged, status.merged + 40) << debug_status(*ring);
  EXPECT_LE(ring->redundant_link->status().merge_timeouts, status.merge_timeouts + 1)
      << debug_status(*ring);
  // Late by more than the merge window but within the patience (half the budget the bus tells
  // the link: three 5 ms periods, so 7.5 ms from the oldest frame that side owes): still merged
  // (on a loaded host the bus thread may come to the reply late for one of the two).
  status = ring->redundant_link->status();
  expect_copes_with(
      *ring,
      sim::fault::next(
          sim::fault::at_port(sim::fault::delay_replies(3ms), RedundantPort::secondary), 2),
      1);
  EXPECT_LE(ring->redundant_link->status().merge_timeouts, status.merge_timeouts + 1)
      << debug_status(*ring);
  // Beyond it: the lone bounce is handed on after the patience (that cycle short), a frame sent
  // while the side still owes that one waits no longer, the late halves are no second reply.
  status = ring->redundant_link->status();
  expect_copes_with(
      *ring,
      sim::fault::next(
          sim::fault::at_port(sim::fault::delay_replies(8ms), RedundantPort::secondary), 2),
      2);
  EXPECT_GT(ring->redundant_link->status().merge_timeouts, status.merge_timeouts)
      << debug_status(*ring);
  expect_never_recovered(*ring);
}

// The master's link alone over the ports: replies that arrive out of order are each matched to
// their own frame, and a duplicate is no second reply.
TEST(RedundantReplyFaults, LinkMatchesReorderedReplies) {
  auto made = sim::make_server(*sim::parse_ring(ring_yaml(RingKind::basic)));
  ASSERT_TRUE(made);
  sim::RedundantPortsOptions options;
  auto ports = sim::RedundantPorts::create(**made, options);
  ASSERT_TRUE(ports);
  link::RedundantLinkOptions link_options;
  link_options.primary_mac = options.primary_mac;
  link_options.secondary_mac = options.secondary_mac;
  auto opened =
      link::RedundantLink::open((*ports)->take_link(RedundantPort::primary),
                                (*ports)->take_link(RedundantPort::secondary), link_options);
  ASSERT_TRUE(opened);
  link::RedundantLink& link = **opened;
  const auto frame = [](std::uint8_t index) {
    std::array<std::uint8_t, wire::kMaxFrameSize> buffer{};
    wire::FrameBuilder builder(buffer);
    wire::DatagramHeader header;
    header.command = wire::Command::brd;
    header.index = index;
    header.length = 1;
    EXPECT_TRUE(builder.add(header, std::array<std::uint8_t, 1>{}).has_value());
    const auto bytes = builder.finish();
    return std::vector<std::uint8_t>(bytes.begin(), bytes.end());
  };
  const auto receive = [&]() -> std::optional<std::pair<std::uint8_t, std::uint16_t>> {
    auto r = link.receive(20ms);
    EXPECT_TRUE(r);
    if (!r || !*r) return std::nullopt;
    const auto decoded = wire::decode_frame((*r)->frame);
    EXPECT_TRUE(decoded);
    if (!decoded) return std::nullopt;
    const auto d = *decoded.frame->begin();
    return std::make_pair(d.header.index, d.wkc);
  };
  for (const RedundantTopology& topology :
       {RedundantTopology::whole_ring(), RedundantTopology::broken_after(1)}) {
    SCOPED_TRACE(sim::describe(topology));
    ASSERT_TRUE((*ports)->set_topology(topology));
    // Whole, the replies arrive at the secondary; broken, the reorder is the secondary's half.
    ASSERT_TRUE((*made)->inject(sim::fault::next(
        sim::fault::at_port(sim::fault::reorder_replies(), RedundantPort::secondary), 1)));
    ASSERT_TRUE(link.send(frame(0x10)));
    ASSERT_TRUE(link.send(frame(0x11)));
    const auto first = receive();
    const auto second = receive();
    ASSERT_TRUE(first && second);
    EXPECT_EQ(first->second, 3);
    EXPECT_EQ(second->second, 3);
    EXPECT_NE(first->first, second->first);
    EXPECT_FALSE(receive());
    // Duplicated at both ports: one reply.
    ASSERT_TRUE((*made)->inject(sim::fault::next(sim::fault::duplicate_reply(), 2)));
    ASSERT_TRUE(link.send(frame(0x12)));
    const auto one = receive();
    ASSERT_TRUE(one);
    EXPECT_EQ(*one, std::make_pair(std::uint8_t{0x12}, std::uint16_t{3}));
    EXPECT_FALSE(receive());
  }
  EXPECT_GT((*ports)->stats().delayed, 0u);
}

// ---- Link faults on a redundant ring: the ring turns round at the port
// ---------------------------

TEST(RedundantLinkFaults, LinkDownIsABreakTheMasterLocates) {
  auto ring = ScenarioRing::operational(redundant_spec());
  ASSERT_TRUE(ring);
  const auto slaves = ring->master->status().slaves;
  ASSERT_EQ(slaves.size(), 3u);
  const auto located = [&]() -> std::optional<link::RingBreak> {
    const auto r = ring->master->status().redundancy;
    return r ? r->break_location : std::nullopt;
  };
  const auto inject = [&](const sim::Fault& f) {
    return [&ring, f] { ASSERT_TRUE(ring->server->inject(f)); };
  };
  // The inputs terminal's port 0 loses its link: a break between the coupler and it.
  expect_flows_through(*ring, RedundantTopology::broken_after(1),
                       inject(sim::fault::link_down("inputs", 0)));
  const link::RingBreak between{link::RingBreak::Where::between_slaves, 0, slaves[0].station, 1,
                                slaves[1].station};
  EXPECT_TRUE(eventually([&] { return located() == between; }))
      << (located() ? link::describe(*located()) : std::string("none"));
  expect_flows_through(*ring, RedundantTopology::whole_ring(),
                       inject(sim::fault::link_up("inputs", 0)));
  EXPECT_TRUE(eventually([&] { return !located(); }));
  // The last slave's port 1: the secondary's cable.
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::secondary),
                       inject(sim::fault::link_down("outputs", 1)));
  EXPECT_TRUE(eventually([&] {
    const auto b = located();
    return b && b->where == link::RingBreak::Where::secondary_cable && b->before_position == 2;
  })) << ring->describe();
  expect_flows_through(*ring, RedundantTopology::whole_ring(),
                       inject(sim::fault::link_up("outputs", 1)));
  // The master's own cable: the primary's.
  expect_flows_through(*ring, RedundantTopology::cut_at(RedundantPort::primary),
                       inject(sim::fault::master_link_down()));
  // Slave 0's port 0 lost the link (before_port 0).
  const link::RingBreak primary{
      link::RingBreak::Where::primary_cable, 0, slaves[0].station, 0, slaves[0].station, 0, 0};
  EXPECT_TRUE(eventually([&] { return located() == primary; }))
      << (located() ? link::describe(*located()) : std::string("none"));
  expect_flows_through(*ring, RedundantTopology::whole_ring(),
                       inject(sim::fault::master_link_up()));
  EXPECT_TRUE(eventually([&] { return !located(); }));
  expect_never_recovered(*ring);
}

// The same faults act on the ports served on two raw interfaces (one code path carries both).
TEST(RedundantLinkFaults, LinkDownAndReplyFaultsOverTwoVethPairs) {
  std::string skip;
  auto ring = ScenarioRing::operational(redundant_spec(5ms, Transport::redundant_raw), &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  expect_flows_through(*ring, RedundantTopology::broken_after(2), [&] {
    ASSERT_TRUE(ring->server->inject(sim::fault::link_down("outputs", 0)));
  });
  expect_copes_with(*ring, sim::fault::next(sim::fault::duplicate_reply(), 60), 1);
  EXPECT_GT(ring->redundant_ports->stats().duplicated, 20u);
  expect_copes_with(
      *ring,
      sim::fault::next(
          sim::fault::at_port(sim::fault::delay_replies(100us), RedundantPort::primary), 30),
      1);
  expect_flows_through(*ring, RedundantTopology::whole_ring(), [&] {
    ASSERT_TRUE(ring->server->inject(sim::fault::link_up("outputs", 0)));
  });
  expect_never_recovered(*ring);
  EXPECT_EQ(ring->redundant_ports->stats().send_errors, 0u);
}

// ---- a start on a ring already broken ----------------------------------------------------------

// The ring is served broken (`cabling`) before the master starts. Position addressing behind a
// break counts from the first slave after it, so a position reaches a slave on each side: the
// stations are assigned side by side, through one port at a time. Every slave gets its ring
// position's station (the configured slave at its configured position), the session reaches OP
// with the whole ring's working counter and the break is located; healed, the same process data
// flows through the whole ring and nothing is assigned again.
void starts_broken(const RedundantTopology& cabling, const link::RingBreak& expected_break,
                   RingKind kind = RingKind::basic, Transport transport = Transport::redundant) {
  SCOPED_TRACE(sim::describe(cabling));
  auto spec = redundant_spec(5ms, transport);
  spec.kind = kind;
  spec.redundant_cabling = cabling;
  std::string skip;
  auto ring = ScenarioRing::operational(spec, &skip);
  if (!skip.empty()) GTEST_SKIP() << skip;
  ASSERT_TRUE(ring);
  ASSERT_NE(ring->redundant_link, nullptr);
  EXPECT_EQ(sim::describe(ring->redundant_ports->topology()), sim::describe(cabling));
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::broken);
  const auto slaves = ring->master->status().slaves;
  std::vector<std::string> names;
  std::size_t esc_count = 0;
  ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    esc_count = segment.size();
    for (std::size_t i = 0; i < segment.size(); ++i)
      names.push_back(segment.name(i));
  });
  ASSERT_EQ(slaves.size(), esc_count);
  for (std::size_t i = 0; i < slaves.size(); ++i) {
    EXPECT_EQ(slaves[i].position, i);
    EXPECT_EQ(slaves[i].station, 0x1000 + i) << slaves[i].name;
    EXPECT_EQ(slaves[i].name, names[i]);
  }
  // Each ESC holds its ring position's station (the simulator's own view).
  const auto stations_are_positions = [&] {
    ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      for (std::size_t i = 0; i < segment.size(); ++i)
        EXPECT_EQ(segment.esc(i).station_address(), 0x1000 + i) << "slave " << i;
    });
  };
  stations_are_positions();
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  EXPECT_TRUE(eventually([&] {
    const auto r = ring->master->status().redundancy;
    return r && r->break_location && *r->break_location == expected_break;
  })) << ring->describe();
  expect_flows_through(*ring, RedundantTopology::whole_ring());
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::whole);
  EXPECT_TRUE(eventually([&] {
    const auto r = ring->master->status().redundancy;
    return r && !r->break_location;
  })) << ring->describe();
  stations_are_positions();
  expect_never_recovered(*ring);
}

using Where = link::RingBreak::Where;

TEST(Scenario00, RedundantRingStartsBrokenBetweenSlaves) {
  // After the first slave, and before the last.
  starts_broken(RedundantTopology::broken_after(1), {Where::between_slaves, 0, 0x1000, 1, 0x1001});
  starts_broken(RedundantTopology::broken_after(2), {Where::between_slaves, 1, 0x1001, 2, 0x1002});
}

TEST(Scenario00, RedundantRingStartsBrokenInALongerRing) {
  // Four slaves (the mailbox one last): a break in the middle, and before the last.
  starts_broken(RedundantTopology::broken_after(2), {Where::between_slaves, 1, 0x1001, 2, 0x1002},
                RingKind::segmented);
  starts_broken(RedundantTopology::broken_after(3), {Where::between_slaves, 2, 0x1002, 3, 0x1003},
                RingKind::segmented);
}

TEST(Scenario00, RedundantRingStartsWithAMasterCableCut) {
  starts_broken(RedundantTopology::cut_at(RedundantPort::primary),
                {Where::primary_cable, 0, 0x1000, 0, 0x1000, 0, 0});
  starts_broken(RedundantTopology::cut_at(RedundantPort::secondary),
                {Where::secondary_cable, 2, 0x1002, 2, 0x1002});
}

TEST(Scenario00, RedundantRingStartsBrokenOverTwoVethPairs) {
  starts_broken(RedundantTopology::broken_after(1), {Where::between_slaves, 0, 0x1000, 1, 0x1001},
                RingKind::basic, Transport::redundant_raw);
}

// ---- position addressing behind a break -------------------------------------------------------

// A slave power-cycled while the ring is broken comes back at station 0 and is found by its
// position: behind the break that position is reached through the secondary's frame (counted
// from the first slave after the break), and a position on the primary's side must not also
// reach the slave at that count behind the break. It is recovered to OP with its own station;
// no other slave is touched.
void power_cycle_behind_break(RingKind kind, const RedundantTopology& cabling,
                              const std::string& cycled) {
  SCOPED_TRACE(sim::describe(cabling) + ", " + cycled + " power-cycled");
  auto spec = redundant_spec();
  spec.kind = kind;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  expect_flows_through(*ring, cabling);
  ASSERT_TRUE(eventually([&] {
    const auto r = ring->master->status().redundancy;
    return r && r->break_location;
  })) << ring->describe();
  const auto slaves = ring->master->status().slaves;
  Monitor monitor(*ring->master);
  ASSERT_TRUE(ring->server->power_cycle(cycled));
  ASSERT_TRUE(eventually([&] { return monitor.saw("state:" + cycled + ":down"); }))
      << monitor.seen();
  ASSERT_TRUE(ring->master->await_operational(10s)) << ring->describe();
  EXPECT_TRUE(eventually([&] {
    return ring->all_slaves_in(SlaveState::op) && !ring->any_slave_fault();
  })) << ring->describe();
  EXPECT_TRUE(ring->loopback(true)) << ring->describe();
  EXPECT_TRUE(ring->loopback(false)) << ring->describe();
  for (const auto& slave : slaves) {
    if (slave.name == cycled) continue;
    EXPECT_FALSE(monitor.saw("state:" + slave.name + ":down")) << monitor.seen();
  }
  ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    for (std::size_t i = 0; i < segment.size(); ++i)
      EXPECT_EQ(segment.esc(i).station_address(), 0x1000 + i) << segment.name(i);
  });
  EXPECT_EQ(sim::describe(ring->redundant_ports->topology()), sim::describe(cabling));
  EXPECT_EQ(ring->redundant_link->status().ring, RingState::broken);
}

TEST(RedundantPositionAddressing, PowerCycledSlaveBehindABreakIsRecoveredAtItsStation) {
  // Ring position 1 is the secondary side's position 0: position 1 from there is the outputs.
  power_cycle_behind_break(RingKind::basic, RedundantTopology::broken_after(1), "inputs");
  // Ring position 2: no position 2 on either side without the translation.
  power_cycle_behind_break(RingKind::basic, RedundantTopology::broken_after(1), "outputs");
  power_cycle_behind_break(RingKind::segmented, RedundantTopology::broken_after(2), "outputs");
}

TEST(RedundantPositionAddressing, PowerCycledSlaveBeforeABreakDoesNotReachOneBehindIt) {
  // Four slaves broken after two: ring position 1 (the inputs) is also position 1 from the
  // secondary's side (the mailbox), which must keep its station.
  power_cycle_behind_break(RingKind::segmented, RedundantTopology::broken_after(2), "inputs");
}

// Master::scan_wire (the control endpoint's rescan) behind a break: every ring position reached
// through the frame that reaches it. Sent through both ports as is, position 1 of a ring broken
// after its first slave would answer from the secondary's side, one slave too far.
TEST(RedundantPositionAddressing, ScanWireReadsEveryPositionBehindABreak) {
  for (const auto& cabling :
       {RedundantTopology::whole_ring(), RedundantTopology::broken_after(1),
        RedundantTopology::broken_after(2), RedundantTopology::cut_at(RedundantPort::primary)}) {
    SCOPED_TRACE(sim::describe(cabling));
    auto spec = redundant_spec();
    spec.kind = RingKind::segmented;
    auto ring = ScenarioRing::operational(spec);
    ASSERT_TRUE(ring);
    expect_flows_through(*ring, cabling);
    const auto slaves = ring->master->status().slaves;
    auto scanned = ring->master->scan_wire();
    ASSERT_TRUE(scanned) << scanned.error().describe();
    ASSERT_EQ(scanned->size(), slaves.size());
    // What each simulated ESC holds, position by position.
    std::vector<std::pair<std::uint16_t, wire::AlState>> escs;
    ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
      for (std::size_t i = 0; i < segment.size(); ++i)
        escs.emplace_back(segment.esc(i).station_address(), segment.esc(i).al_state());
    });
    ASSERT_EQ(escs.size(), slaves.size());
    for (std::size_t i = 0; i < slaves.size(); ++i) {
      const auto& at = (*scanned)[i];
      EXPECT_EQ(at.position, i);
      ASSERT_TRUE(at.station && at.al_status) << "position " << i;
      EXPECT_EQ(*at.station, slaves[i].station) << "position " << i;
      EXPECT_EQ(*at.station, escs[i].first) << "position " << i;
      EXPECT_EQ(*at.al_status & 0x1F, static_cast<unsigned>(escs[i].second)) << "position " << i;
    }
  }
}

// ---- 38, 40, 41: the bus alone on a redundant ring ---------------------------------------------

// The default ring served with two master ports and a bus on a RedundantLink, no master.
struct RedundantBus {
  std::unique_ptr<RawNamespace> ns;  // raw: two veth pairs
  std::unique_ptr<sim::SimServer> server;
  std::unique_ptr<sim::RedundantPorts> ports;
  link::RedundantLink* link = nullptr;
  std::unique_ptr<bus::Bus> bus;
  std::string skip;

  explicit RedundantBus(std::chrono::nanoseconds frame_timeout, bool raw = false) {
    if (raw) {
      ns = std::make_unique<RawNamespace>(2);
      if (!ns->why_not().empty()) {
        skip = ns->why_not();
        return;
      }
    }
    auto parsed = sim::parse_ring(ring_yaml(RingKind::basic));
    EXPECT_TRUE(parsed) << parsed.error().describe();
    if (!parsed) return;
    auto made = sim::make_server(*parsed);
    EXPECT_TRUE(made);
    if (!made) return;
    server = std::move(*made);
    sim::RedundantPortsOptions options;
    auto created = sim::RedundantPorts::create(*server, options);
    EXPECT_TRUE(created);
    if (!created) return;
    ports = std::move(*created);
    link::RedundantLinkOptions link_options;
    link_options.primary_mac = options.primary_mac;
    link_options.secondary_mac = options.secondary_mac;
    Result<std::unique_ptr<link::RedundantLink>> opened = Error(Errc::internal, "not opened");
    if (raw) {
      link::RawLinkOptions a;
      a.interface = "segment";
      link::RawLinkOptions b;
      b.interface = "segment2";
      auto served_a = link::RawLink::open(a);
      auto served_b = link::RawLink::open(b);
      EXPECT_TRUE(served_a && served_b);
      if (!served_a || !served_b) return;
      EXPECT_TRUE(ports->serve(std::move(*served_a), std::move(*served_b)));
      opened = link::RedundantLink::open_raw("master", "master2");
    } else {
      opened = link::RedundantLink::open(ports->take_link(RedundantPort::primary),
                                         ports->take_link(RedundantPort::secondary), link_options);
    }
    EXPECT_TRUE(opened);
    if (!opened) return;
    link = opened->get();
    bus::BusOptions bus_options;
    bus_options.frame_timeout = frame_timeout;
    bus = std::make_unique<bus::Bus>(std::move(*opened), bus_options);
    EXPECT_TRUE(bus->start());
    // Stations 0x1000 + position, as a master assigns them (the ring is whole).
    bus::Transaction assign;
    for (std::uint16_t i = 0; i < 3; ++i) {
      const std::array<std::uint8_t, 2> station{static_cast<std::uint8_t>(i), 0x10};
      assign.apwr(i, wire::reg::kStationAddress, station, 1);
    }
    EXPECT_TRUE(bus->transact(std::move(assign)));
  }
  ~RedundantBus() {
    if (bus) bus->stop();
    bus.reset();
    if (ports) ports->stop();
    ports.reset();
    server.reset();
    ns.reset();
  }
};

bus::TransactOptions once(std::chrono::nanoseconds timeout = 1s) {
  bus::TransactOptions options;
  options.retries = 0;
  options.timeout = timeout;
  return options;
}

void passthrough_copy_is_no_reply(bool raw) {
  RedundantBus ring(40ms, raw);
  if (!ring.skip.empty()) GTEST_SKIP() << ring.skip;
  ASSERT_TRUE(ring.bus);
  // Whatever leaves by the secondary (the primary's processed frame) comes 200 ms late; the
  // secondary's copy, unprocessed, reaches the primary at once.
  ring.ports->set_delay(RedundantPort::secondary, 200ms);
  bus::Transaction tx;
  tx.fprd(0x1002, 0x0010, 2);
  auto reply = ring.bus->transact(std::move(tx), once());
  ASSERT_FALSE(reply);
  EXPECT_EQ(reply.error().code(), Errc::timeout) << reply.error().describe();
  EXPECT_GT(ring.link->status().passthrough_copies, 0u);
}

TEST(Scenario38, RedundantPassthroughCopyIsNoReply) {
  passthrough_copy_is_no_reply(false);
}
TEST(Scenario38, RedundantPassthroughCopyIsNoReplyOverTwoVethPairs) {
  passthrough_copy_is_no_reply(true);
}

TEST(Scenario40, RedundantDelayedCopyDoesNotHoldTheReply) {
  RedundantBus ring(40ms);
  ASSERT_TRUE(ring.bus);
  // The primary holds back replies to frames that entered by the secondary (the passthrough
  // copy); the processed reply is taken as it comes.
  ring.ports->set_delay(RedundantPort::primary, 200ms, RedundantPort::secondary);
  for (int i = 0; i < 3; ++i) {
    bus::Transaction tx;
    tx.brd(0x0000, 1);
    auto reply = ring.bus->transact(std::move(tx), once(100ms));
    ASSERT_TRUE(reply) << reply.error().describe();
    EXPECT_EQ(reply->wkc(0), 3);
  }
  const auto status = ring.link->status();
  EXPECT_EQ(status.topology, RedundancyTopology::redundant);
  EXPECT_EQ(status.ring, RingState::whole);
}

TEST(Scenario41, RedundantResetBlockCountsEverySlave) {
  RedundantBus ring(40ms);
  ASSERT_TRUE(ring.bus);
  // The startup's broadcast reset block: 13 BWRs in one frame, once and then ten times.
  const auto reset = [] {
    bus::Transaction tx;
    tx.bwr(wire::reg::kDlPortControl, std::array<std::uint8_t, 1>{0x00});
    tx.bwr(wire::reg::kEcatEventMask, std::array<std::uint8_t, 2>{0x04, 0x00});
    tx.bwr(wire::reg::kRxErrorCounter, std::array<std::uint8_t, 8>{});
    tx.bwr(wire::reg::kFmmuBase, std::array<std::uint8_t, 3 * wire::reg::kFmmuSize>{});
    tx.bwr(wire::reg::kSyncManagerBase,
           std::array<std::uint8_t, 4 * wire::reg::kSyncManagerSize>{});
    tx.bwr(wire::reg::kDcActivation, std::array<std::uint8_t, 1>{});
    tx.bwr(wire::reg::kDcSystemTime, std::array<std::uint8_t, 4>{});
    tx.bwr(wire::reg::kDcSpeedCounterStart, std::array<std::uint8_t, 2>{0x00, 0x10});
    tx.bwr(wire::reg::kDcSystemTimeFilterDepth, std::array<std::uint8_t, 2>{0x00, 0x0C});
    tx.bwr(wire::reg::kDlAliasControl, std::array<std::uint8_t, 1>{});
    tx.bwr(wire::reg::kAlControl, std::array<std::uint8_t, 2>{0x11, 0x00});
    tx.bwr(wire::reg::kSiiAccess, std::array<std::uint8_t, 1>{0x02});
    tx.bwr(wire::reg::kSiiAccess, std::array<std::uint8_t, 1>{0x00});
    return tx;
  };
  for (int round = 0; round < 11; ++round) {
    auto reply = ring.bus->transact(reset(), once());
    ASSERT_TRUE(reply) << reply.error().describe();
    for (std::size_t i = 0; i < 13; ++i)
      EXPECT_GT(reply->wkc(i), 0) << round << " " << i;
  }
  bus::Transaction count;
  count.brd(0x0000, 1);
  auto counted = ring.bus->transact(std::move(count), once());
  ASSERT_TRUE(counted);
  EXPECT_EQ(counted->wkc(0), 3);
  const auto status = ring.link->status();
  EXPECT_GE(status.passthrough_copies, 12u);  // every copy came round and was dropped
  EXPECT_EQ(status.stale, 0u);
}

// DL status 0x0110 of each slave of the default three-slave ring served by RedundantPorts:
// (port 0 link, port 0 loop closed, port 1 link, port 1 loop closed).
std::vector<std::array<bool, 4>> ports_of(sim::SimServer& server) {
  return server.with_segment([](sim::Segment& segment, sim::FaultInjector&) {
    std::vector<std::array<bool, 4>> out;
    for (std::size_t i = 0; i < segment.size(); ++i) {
      const auto dl = wire::DlStatus::decode(segment.esc(i).read_u16(wire::reg::kDlStatus));
      // Communication follows the link on every port.
      EXPECT_EQ(dl.ports[0].communication, dl.ports[0].physical_link);
      EXPECT_EQ(dl.ports[1].communication, dl.ports[1].physical_link);
      out.push_back({dl.ports[0].physical_link, dl.ports[0].loop_closed, dl.ports[1].physical_link,
                     dl.ports[1].loop_closed});
    }
    return out;
  });
}

TEST(RedundantSegment, DlStatusShowsTheBreak) {
  RedundantBus ring(40ms);
  ASSERT_TRUE(ring.ports);
  using P = std::array<bool, 4>;
  const P through{true, false, true, false};  // link on both sides, both loops open
  // Whole: the last slave's port 1 is cabled to the secondary port.
  EXPECT_EQ(ports_of(*ring.server), (std::vector<P>{through, through, through}));
  ASSERT_TRUE(ring.ports->set_topology(RedundantTopology::broken_after(2)));
  EXPECT_EQ(ports_of(*ring.server),
            (std::vector<P>{through, P{true, false, false, true}, P{false, true, true, false}}));
  ASSERT_TRUE(ring.ports->set_topology(RedundantTopology::cut_at(RedundantPort::primary)));
  EXPECT_EQ(ports_of(*ring.server),
            (std::vector<P>{P{false, true, true, false}, through, through}));
  ASSERT_TRUE(ring.ports->set_topology(RedundantTopology::cut_at(RedundantPort::secondary)));
  EXPECT_EQ(ports_of(*ring.server),
            (std::vector<P>{through, through, P{true, false, false, true}}));
  ASSERT_TRUE(ring.ports->set_topology(RedundantTopology::whole_ring()));
  EXPECT_EQ(ports_of(*ring.server), (std::vector<P>{through, through, through}));
  // The ring faults change it too, and fault.clear returns to the start cabling's.
  ASSERT_TRUE(ring.server->inject(sim::fault::ring_break(1)));
  EXPECT_EQ(ports_of(*ring.server),
            (std::vector<P>{P{true, false, false, true}, P{false, true, true, false}, through}));
  ASSERT_TRUE(ring.server->inject(sim::fault::ring_cut(RedundantPort::secondary)));
  EXPECT_EQ(ports_of(*ring.server),
            (std::vector<P>{through, through, P{true, false, false, true}}));
  ring.server->clear_faults();
  EXPECT_EQ(ports_of(*ring.server), (std::vector<P>{through, through, through}));
  // The master reads the same through the ports (the broken ring's two halves merged).
  ASSERT_TRUE(ring.ports->set_topology(RedundantTopology::broken_after(1)));
  bus::Transaction tx;
  for (std::uint16_t i = 0; i < 3; ++i)
    tx.fprd(static_cast<std::uint16_t>(0x1000 + i), wire::reg::kDlStatus, 2);
  auto reply = ring.bus->transact(std::move(tx), once());
  ASSERT_TRUE(reply) << reply.error().describe();
  std::vector<master::RingPortReading> readings;
  for (std::uint16_t i = 0; i < 3; ++i) {
    ASSERT_EQ(reply->wkc(i), 1) << i;
    readings.push_back({static_cast<std::uint16_t>(0x1000 + i),
                        wire::DlStatus::decode(wire::load_le16(reply->data(i).data()))});
  }
  const auto found = master::locate_ring_break(readings);
  ASSERT_TRUE(found);
  EXPECT_EQ(link::describe(*found),
            "between slave 0 (station 0x1000) and slave 1 (station 0x1001)");
  // Gone, the ports leave the segment's own cables to speak: the last slave's port 1 is free.
  ring.bus->stop();
  ring.ports.reset();
  EXPECT_EQ(ports_of(*ring.server).back(), (P{true, false, false, true}));
}

TEST(RedundantSegment, RoutesFollowTheEscForwardingRules) {
  using K = RedundantTopology;
  auto r = sim::route_redundant(K::whole_ring(), 3, RedundantPort::primary);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->first, 0u);
  EXPECT_EQ(r->last, 3u);
  EXPECT_EQ(r->egress, RedundantPort::secondary);
  r = sim::route_redundant(K::whole_ring(), 3, RedundantPort::secondary);
  EXPECT_EQ(r->first, r->last);  // passes every slave unprocessed
  EXPECT_EQ(r->egress, RedundantPort::primary);
  r = sim::route_redundant(K::broken_after(1), 3, RedundantPort::secondary);
  EXPECT_EQ(r->first, 1u);
  EXPECT_EQ(r->last, 3u);
  EXPECT_EQ(r->egress, RedundantPort::secondary);
  r = sim::route_redundant(K::cut_at(RedundantPort::primary), 3, RedundantPort::primary);
  EXPECT_FALSE(r->egress);
  r = sim::route_redundant(K::cut_at(RedundantPort::primary), 3, RedundantPort::secondary);
  EXPECT_EQ(r->last, 3u);
  EXPECT_EQ(r->egress, RedundantPort::secondary);
  for (std::size_t bad : {0u, 3u, 7u}) {
    auto refused = sim::route_redundant(K::broken_after(bad), 3, RedundantPort::primary);
    ASSERT_FALSE(refused);
    EXPECT_EQ(refused.error().code(), Errc::invalid_argument);
    EXPECT_NE(refused.error().message().find("cannot break after slave"), std::string::npos);
  }
  EXPECT_EQ(sim::describe(K::broken_after(2)), "break after 2");
  EXPECT_EQ(sim::describe(K::cut_at(RedundantPort::secondary)), "master break secondary");
}

TEST(RedundantSegment, RingFaultsSpeakTheFaultLanguage) {
  const std::vector<std::string> words{"port_delay", "secondary", "0.2", "primary"};
  auto parsed = sim::parse_fault_words(words);
  ASSERT_TRUE(parsed) << parsed.error().describe();
  EXPECT_EQ(parsed->effect.kind, sim::FaultKind::port_delay);
  EXPECT_EQ(parsed->effect.master_port, RedundantPort::secondary);
  EXPECT_EQ(parsed->effect.ns, 200'000);
  EXPECT_EQ(parsed->effect.from, RedundantPort::primary);
  auto round = sim::parse_fault_json(sim::to_json(*parsed));
  ASSERT_TRUE(round) << round.error().describe();
  EXPECT_EQ(sim::describe(*round), sim::describe(*parsed));
  for (const auto& f : {sim::fault::ring_break(2), sim::fault::ring_cut(RedundantPort::primary),
                        sim::fault::ring_heal()}) {
    auto again = sim::parse_fault_json(sim::to_json(f));
    ASSERT_TRUE(again) << again.error().describe();
    EXPECT_EQ(sim::describe(*again), sim::describe(f));
  }
  const std::vector<std::string> cut{"ring_cut", "tertiary"};
  auto refused = sim::parse_fault_words(cut);
  ASSERT_FALSE(refused);
  EXPECT_NE(refused.error().message().find("unknown master port 'tertiary'"), std::string::npos)
      << refused.error().message();
  const std::vector<std::string> zero{"ring_break", "0"};
  EXPECT_FALSE(sim::parse_fault_words(zero));

  // A segment without a second master port refuses them; with one, a break outside 1..N-1 is
  // refused naming it, and fault.clear returns to the cabling the ports were made with.
  auto made = sim::make_server(*sim::parse_ring(ring_yaml(RingKind::basic)));
  ASSERT_TRUE(made);
  auto& server = **made;
  auto alone = server.inject(sim::fault::ring_break(1));
  ASSERT_FALSE(alone);
  EXPECT_NE(alone.error().message().find("no second master port"), std::string::npos);
  sim::RedundantPortsOptions options;
  options.topology = RedundantTopology::broken_after(1);
  auto ports = sim::RedundantPorts::create(server, options);
  ASSERT_TRUE(ports) << ports.error().describe();
  auto outside = server.inject(sim::fault::ring_break(3));
  ASSERT_FALSE(outside);
  EXPECT_NE(outside.error().message().find("cannot break after slave 3 (1..2)"), std::string::npos)
      << outside.error().message();
  ASSERT_TRUE(server.inject(sim::fault::ring_cut(RedundantPort::secondary)));
  ASSERT_TRUE(server.inject(sim::fault::port_delay(RedundantPort::primary, 1ms)));
  EXPECT_EQ(server.fault_info().ring, "master break secondary; primary +1000 us");
  server.clear_faults();
  EXPECT_EQ(server.fault_info().ring, "break after 1");
  EXPECT_FALSE(sim::RedundantPorts::create(server, {}));  // one second port per segment
  ports->reset();
  EXPECT_TRUE(server.fault_info().ring.empty());
}

TEST(RedundantSegment, RingFilesSetTheCabling) {
  const std::string base = ring_yaml(RingKind::basic);
  auto ring = sim::parse_ring(base + R"(  redundancy:
    break_after: 2
    delays:
      - {port: secondary, ms: 0.5, from: secondary}
)");
  ASSERT_TRUE(ring) << ring.error().describe();
  ASSERT_TRUE(ring->redundancy);
  EXPECT_EQ(sim::describe(*ring->redundancy), "break after 2; secondary +500 us (from secondary)");
  EXPECT_FALSE(sim::parse_ring(base)->redundancy);
  const auto error_of = [&](const std::string& section) {
    auto bad = sim::parse_ring(base + section);
    return bad ? std::string("accepted") : bad.error().message();
  };
  EXPECT_NE(error_of("  redundancy: {break_after: 3}\n").find("break_after"), std::string::npos);
  EXPECT_NE(error_of("  redundancy: {cut: left}\n").find("unknown master port 'left'"),
            std::string::npos);
  EXPECT_NE(error_of("  redundancy: {cut: primary, break_after: 1}\n").find("not both"),
            std::string::npos);
  EXPECT_NE(error_of("  redundancy: {delays: [{port: primary, ms: -1}]}\n").find("out of range"),
            std::string::npos);
}

}  // namespace
}  // namespace ecat::scenarios
