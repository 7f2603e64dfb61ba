// Hot connect (docs/ARCHITECTURE.md "Hot connect"): a group of slaves behind the fixed ones that
// is absent at start, plugged and unplugged at runtime in the simulator, and brought to the
// session's target by the master without disturbing the others' cycles.
#include <atomic>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <ecat/master/config.hpp>
#include <ecat/sim/dc_unit.hpp>

#include "master/json_view.hpp"
#include "scenarios/scenario_support.hpp"

namespace ecat::scenarios {
namespace {

using master::HotConnectState;

// coupler -> inputs -> outputs, then the group `tool`: tool_out (EL2809) -> tool_in (EL1809),
// tool_out's channel 1 wired to tool_in's channel 1 (so the group's own process data can be
// checked end to end).
std::string hot_connect_ring(bool plugged) {
  return fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
    - {{name: inputs, profile: EL1809}}
    - {{name: outputs, profile: EL2809}}
    - {{name: tool_out, profile: EL2809, hot_connect: {{group: tool, plugged: {}}}}}
    - {{name: tool_in, profile: EL1809}}
  wiring:
    - {{from: outputs.channel_1, to: inputs.channel_1}}
    - {{from: outputs.channel_16, to: inputs.channel_16}}
    - {{from: tool_out.channel_1, to: tool_in.channel_1}}
)",
                     plugged ? "true" : "false");
}

// The master's side of the group; identified by the first slave's identity (EL2809) unless
// `alias` is given.
master::HotConnectGroup tool_group(std::optional<std::uint16_t> alias = std::nullopt) {
  master::HotConnectGroup g;
  g.name = "tool";
  g.alias = alias;
  for (const char* name : {"tool_out", "tool_in"}) {
    master::SlaveConfig s;
    s.name = name;
    s.process_data = master::ProcessDataRequest::all("main");
    s.health_poll = 20ms;
    g.slaves.push_back(std::move(s));
  }
  g.slaves[0].vendor_id = 0x2;
  g.slaves[0].product_code = 0x0AF93052;
  g.slaves[1].vendor_id = 0x2;
  g.slaves[1].product_code = 0x07113052;
  return g;
}

RingSpec hot_connect_spec(bool plugged, std::optional<std::uint16_t> alias = std::nullopt) {
  RingSpec spec;
  spec.ring_yaml = hot_connect_ring(plugged);
  spec.adjust = [alias](master::MasterConfig& c) {
    c.hot_connect.push_back(tool_group(alias));
    c.hot_connect_poll = 10ms;
  };
  return spec;
}

master::HotConnectStatus group_status(master::Master& m) {
  auto st = m.status();
  if (st.hot_connect.empty()) return {};
  return st.hot_connect.front();
}

bool group_in(master::Master& m, HotConnectState state) {
  return group_status(m).state == state;
}

// Process data end to end through the simulator's wiring: `value` written to `out`'s channel 1
// is read back from `in`'s channel 1 within `limit`.
bool loop_follows(master::Master& m, const std::string& out_name, const std::string& in_name,
                  bool value, std::chrono::milliseconds limit = 10s) {
  auto out = m.slave(out_name);
  auto in = m.slave(in_name);
  if (!out || !in) return false;
  if (!(*out)->write_output("channel_1", master::Value(value))) return false;
  return eventually(
      [&] {
        auto v = (*in)->read_input("channel_1");
        return v && master::as_bool(*v) == value;
      },
      limit);
}

// The fixed slaves' process data: outputs.channel_1 -> inputs.
bool fixed_loop_follows(master::Master& m, bool value) {
  return loop_follows(m, "outputs", "inputs", value, 2s);
}

TEST(HotConnect, AbsentAtStartTheRestIsOperational) {
  auto ring = ScenarioRing::operational(hot_connect_spec(false));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  EXPECT_EQ(m.state(), MasterState::operational);
  const auto g = group_status(m);
  EXPECT_EQ(g.group, "tool");
  EXPECT_EQ(g.state, HotConnectState::absent);
  EXPECT_EQ(g.slaves, (std::vector<std::string>{"tool_out", "tool_in"}));
  EXPECT_TRUE(fixed_loop_follows(m, true));
  // The domain reserved room for the group: the fixed slaves' WKC only is expected.
  auto domain = m.domain("main");
  ASSERT_TRUE(domain);
  bool reserved = false;
  for (const auto& r : (*domain)->registrations())
    reserved |= r.key.kind == master::RegistrationKind::reserved;
  EXPECT_TRUE(reserved);
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 100ms));
}

TEST(HotConnect, PlugBringsTheGroupToOpWithoutDisturbingTheOthers) {
  auto ring = ScenarioRing::operational(hot_connect_spec(false));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  Monitor monitor(m);
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail << "\n"
      << ring->describe();
  for (const char* name : {"tool_out", "tool_in"}) {
    auto s = m.slave(name);
    ASSERT_TRUE(s);
    EXPECT_EQ((*s)->state(), SlaveState::op) << name;
  }
  const auto g = group_status(m);
  EXPECT_EQ(g.position, 3);
  EXPECT_EQ(g.appearances, 1u);
  ASSERT_TRUE(g.last_join);
  // The control endpoint's status says the same.
  const auto json = master::detail::status_json(m);
  ASSERT_TRUE(json.contains("hot_connect")) << json.dump();
  EXPECT_EQ(json["hot_connect"][0]["group"], "tool");
  EXPECT_EQ(json["hot_connect"][0]["state"], "present");
  EXPECT_EQ(json["hot_connect"][0]["position"], 3);
  EXPECT_EQ(json["hot_connect"][0]["slaves"][1], "tool_in");
  // The group's own process data, through the simulator's wiring.
  ASSERT_TRUE(m.slave("tool_out") && m.slave("tool_in"));
  EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", true)) << ring->describe();
  // Nobody else noticed: every cycle valid, the session operational all along.
  const auto after = ring->domain_stats();
  EXPECT_EQ(after.wkc_mismatch_count, before.wkc_mismatch_count) << ring->describe();
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  monitor.stop();
  EXPECT_TRUE(monitor.matching("state:outputs:down").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("state:inputs:down").empty()) << monitor.seen();
  EXPECT_TRUE(monitor.matching("master:recovering").empty()) << monitor.seen();
  EXPECT_TRUE(fixed_loop_follows(m, true));
}

// Fixed slaves configured with a gap in their positions (the inputs terminal at position 1 is not
// configured): the group's stations follow the last fixed position, not the number of configured
// slaves (which would give the group the outputs terminal's station).
TEST(HotConnect, GroupStationsFollowTheLastFixedPositionWhenPositionsLeaveGaps) {
  auto spec = hot_connect_spec(false);
  spec.adjust = [](master::MasterConfig& c) {
    std::erase_if(c.slaves, [](const master::SlaveConfig& s) { return s.name == "inputs"; });
    c.slaves[0].position = 0;  // coupler
    c.slaves[1].position = 2;  // outputs
    c.hot_connect.push_back(tool_group());
    c.hot_connect_poll = 10ms;
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail << "\n"
      << ring->describe();
  std::set<std::uint16_t> stations;
  for (const char* name : {"coupler", "outputs", "tool_out", "tool_in"}) {
    auto s = m.slave(name);
    ASSERT_TRUE(s) << name;
    EXPECT_TRUE(stations.insert((*s)->info().station).second)
        << name << " shares station " << (*s)->info().station;
  }
  // Ring positions 0..2 have stations base + 0..2; the group comes after them.
  const std::uint16_t base = (*m.slave("coupler"))->info().station;
  EXPECT_EQ((*m.slave("tool_out"))->info().station, base + 3);
  EXPECT_EQ((*m.slave("tool_in"))->info().station, base + 4);
  for (const char* name : {"outputs", "tool_out", "tool_in"})
    EXPECT_EQ((*m.slave(name))->state(), SlaveState::op) << name;
  EXPECT_EQ(ring->domain_stats().wkc_mismatch_count, before.wkc_mismatch_count) << ring->describe();
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnect, UnplugMarksTheGroupStaleAndReplugRestoresItsStagedOutputs) {
  auto ring = ScenarioRing::operational(hot_connect_spec(true));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  std::mutex events_mutex;
  std::vector<std::string> events;
  const auto subscription = m.subscribe_events([&](const master::Event& e, std::uint64_t) {
    if (e.kind < master::EventKind::hotconnect_appeared) return;
    std::lock_guard lock(events_mutex);
    events.push_back(std::string(master::to_string(e.kind)) + ":" + std::string(e.name()));
  });
  // Present at start: claimed once the session runs.
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail;
  auto out = m.slave("tool_out");
  auto in = m.slave("tool_in");
  ASSERT_TRUE(out && in);
  ASSERT_TRUE(ring->server->plug("tool", false));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }));
  const auto stale = (*in)->read_input("channel_1");
  ASSERT_FALSE(stale);
  EXPECT_EQ(stale.error().code(), Errc::stale) << stale.error().describe();
  EXPECT_EQ((*in)->state(), SlaveState::down);
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 200ms))
      << ring->describe();
  EXPECT_TRUE(fixed_loop_follows(m, false));
  EXPECT_TRUE(fixed_loop_follows(m, true));
  // Staged while the group is away: delivered when it is back.
  ASSERT_TRUE((*out)->write_output("channel_1", master::Value(true)));
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail;
  EXPECT_TRUE(eventually([&] {
    auto v = (*in)->read_input("channel_1");
    return v && master::as_bool(*v) == true;
  })) << ring->describe();
  const auto g = group_status(m);
  EXPECT_EQ(g.appearances, 2u);
  EXPECT_EQ(g.losses, 1u);
  EXPECT_TRUE(eventually([&] {
    std::lock_guard lock(events_mutex);
    return events.size() >= 5;
  }));
  {
    std::lock_guard lock(events_mutex);
    EXPECT_EQ(events, (std::vector<std::string>{"hotconnect.appeared:tool", "hotconnect.ready:tool",
                                                "hotconnect.lost:tool", "hotconnect.appeared:tool",
                                                "hotconnect.ready:tool"}));
  }
  EXPECT_EQ(m.state(), MasterState::operational);
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  m.unsubscribe_events(subscription);
}

// A redundant ring whose last two slaves are the group, broken in front of the group: the group
// is reached through the secondary's frame only, which counts positions from tool_out. Unplugged
// and plugged again, its scratch station and stations are written by position through that
// frame (ring position 3 is the secondary's position 0). Sent through both ports as is, position
// 3 would reach no slave on either side, and the group would never come back.
TEST(HotConnect, AGroupPluggedBehindABreakOfARedundantRingGetsItsOwnStations) {
  auto spec = hot_connect_spec(true);
  spec.transport = Transport::redundant;
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail;
  ASSERT_TRUE(ring->redundant_ports->set_topology(sim::RedundantTopology::broken_after(3)));
  ASSERT_TRUE(eventually([&] {
    const auto r = m.status().redundancy;
    return r && r->break_location;
  })) << ring->describe();
  EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", true)) << ring->describe();
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->plug("tool", false));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }))
      << group_status(m).detail;
  EXPECT_TRUE(fixed_loop_follows(m, false));
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail << "\n"
      << ring->describe();
  EXPECT_EQ(group_status(m).position, 3);
  EXPECT_EQ(group_status(m).appearances, 2u);
  // Every ESC holds the station the master gave its slave.
  ring->server->with_segment([&](sim::Segment& segment, sim::FaultInjector&) {
    for (std::size_t i = 0; i < segment.size(); ++i) {
      auto slave = m.slave(segment.name(i));
      ASSERT_TRUE(slave) << segment.name(i);
      EXPECT_EQ(segment.esc(i).station_address(), (*slave)->info().station) << segment.name(i);
    }
  });
  EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", false)) << ring->describe();
  EXPECT_TRUE(fixed_loop_follows(m, true));
  EXPECT_EQ(ring->domain_stats().wkc_mismatch_count, before.wkc_mismatch_count) << ring->describe();
  EXPECT_FALSE(ring->saw(MasterState::recovering)) << ring->describe();
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnect, AWrongDeviceIsRefusedNotConfigured) {
  // The group is known by alias 0x0777; what is plugged has alias 0.
  auto ring = ScenarioRing::operational(hot_connect_spec(false, 0x0777));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  std::atomic<int> refusals{0};
  const auto subscription = m.subscribe_events([&](const master::Event& e, std::uint64_t) {
    if (e.kind == master::EventKind::hotconnect_refused) ++refusals;
  });
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return !m.status().hot_connect_refused.empty(); }));
  const auto st = m.status();
  EXPECT_NE(st.hot_connect_refused.find("position 3"), std::string::npos) << st.hot_connect_refused;
  EXPECT_NE(st.hot_connect_refused.find("0x0af93052"), std::string::npos) << st.hot_connect_refused;
  EXPECT_EQ(group_status(m).state, HotConnectState::absent);
  // Not configured: the simulated device is still in INIT.
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 100ms));
  auto sim = ring->server->status();
  EXPECT_EQ(sim.slaves.at(3).al_state, wire::AlState::init);
  // Looked at again every retry interval (50 ms here), reported once while it lasts.
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(refusals.load(), 1);
  EXPECT_FALSE(m.status().hot_connect_refused.empty());
  m.unsubscribe_events(subscription);
}

// The group plugged is not the one declared past its first slave: an EL3202 where tool_in (an
// EL1809) should be.
RingSpec wrong_group_spec() {
  auto spec = hot_connect_spec(false);
  const std::string in = "{name: tool_in, profile: EL1809}";
  const auto at = spec.ring_yaml.find(in);
  spec.ring_yaml.replace(at, in.size(), "{name: tool_in, profile: EL3202}");
  const std::string wire = "    - {from: tool_out.channel_1, to: tool_in.channel_1}\n";
  spec.ring_yaml.erase(spec.ring_yaml.find(wire), wire.size());
  return spec;
}

struct Refusals {
  explicit Refusals(master::Master& m) : master(m) {
    subscription = m.subscribe_events([this](const master::Event& e, std::uint64_t) {
      if (e.kind != master::EventKind::hotconnect_refused) return;
      std::lock_guard lock(mutex);
      seen.emplace_back(e.detail());
    });
  }
  ~Refusals() { master.unsubscribe_events(subscription); }
  std::vector<std::string> all() {
    std::lock_guard lock(mutex);
    return seen;
  }
  master::Master& master;
  std::mutex mutex;
  std::vector<std::string> seen;
  std::uint64_t subscription = 0;
};

TEST(HotConnect, AGroupWhoseLaterSlaveDiffersIsRefusedAndNotBroughtUp) {
  auto ring = ScenarioRing::operational(wrong_group_spec());
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  Refusals refusals(m);
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::failed); }))
      << group_status(m).detail;
  const auto detail = group_status(m).detail;
  EXPECT_EQ(detail,
            "group tool: slave tool_in at position 4: product code 0x07113052 declared, "
            "0x0c823052 found");
  EXPECT_FALSE(group_status(m).position);
  EXPECT_EQ(group_status(m).appearances, 0u);
  // Not brought up: both still in INIT, the others untouched, the session operational.
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 100ms));
  auto sim = ring->server->status();
  EXPECT_EQ(sim.slaves.at(3).al_state, wire::AlState::init);
  EXPECT_EQ(sim.slaves.at(4).al_state, wire::AlState::init);
  for (const char* name : {"tool_out", "tool_in"}) {
    auto s = m.slave(name);
    ASSERT_TRUE(s);
    EXPECT_FALSE((*s)->read_input("channel_1")) << name;
  }
  // Looked at again every retry interval (50 ms here), reported once while it lasts.
  std::this_thread::sleep_for(250ms);
  const auto seen = refusals.all();
  ASSERT_EQ(seen.size(), 1u);
  EXPECT_NE(seen[0].find("slave tool_in at position 4"), std::string::npos) << seen[0];
  EXPECT_EQ(group_in(m, HotConnectState::failed), true);
  EXPECT_EQ(ring->domain_stats().wkc_mismatch_count, before.wkc_mismatch_count);
  EXPECT_TRUE(fixed_loop_follows(m, true));
  EXPECT_EQ(m.status().illegal_reservation_transitions, 0u);
}

TEST(HotConnect, AGroupShortOfSlavesIsRefusedOnceItLasts) {
  auto spec = hot_connect_spec(false);
  spec.adjust = [](master::MasterConfig& c) {
    auto g = tool_group();
    master::SlaveConfig extra;
    extra.name = "tool_extra";  // declared, never plugged
    g.slaves.push_back(extra);
    c.hot_connect.push_back(std::move(g));
    c.hot_connect_poll = 10ms;
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  Refusals refusals(m);
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::failed); }))
      << group_status(m).detail;
  EXPECT_NE(group_status(m).detail.find("2 of its 3 slaves in the ring so far (tool_extra "
                                        "missing)"),
            std::string::npos)
      << group_status(m).detail;
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(refusals.all().size(), 1u);
  auto sim = ring->server->status();
  EXPECT_EQ(sim.slaves.at(3).al_state, wire::AlState::init);
  EXPECT_EQ(sim.slaves.at(4).al_state, wire::AlState::init);
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnect, RepeatedPlugAndUnplugAtRandomTimes) {
  auto ring = ScenarioRing::operational(hot_connect_spec(false));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  std::mt19937 rng(20261127);
  std::uniform_int_distribution<int> pause_ms(0, 60);
  bool value = false;
  for (int round = 0; round < 6; ++round) {
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(rng)));
    ASSERT_TRUE(ring->server->plug("tool", true));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
        << "round " << round << ": " << group_status(m).detail << "\n"
        << ring->describe();
    ASSERT_EQ(m.state(), MasterState::operational) << "round " << round;
    // The output staged before this plug (or in this round) arrives.
    auto out = m.slave("tool_out");
    auto in = m.slave("tool_in");
    ASSERT_TRUE(out && in);
    if (round > 0) {
      EXPECT_TRUE(eventually([&] {
        auto v = (*in)->read_input("channel_1");
        return v && master::as_bool(*v) == value;
      })) << "round "
          << round << ": staged output lost";
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(rng)));
    ASSERT_TRUE(ring->server->plug("tool", false));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }))
        << "round " << round;
    value = !value;
    ASSERT_TRUE((*out)->write_output("channel_1", master::Value(value)));
    EXPECT_EQ(m.state(), MasterState::operational) << "round " << round;
  }
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_EQ(group_status(m).losses, 6u);
  EXPECT_EQ(m.status().illegal_reservation_transitions, 0u);
}

TEST(HotConnectConfig, RingFileErrorsNameWhatIsWrong) {
  const std::string head = R"(domains: [{id: main, period_us: 1000}]
slaves: [{name: coupler}]
)";
  auto parse = [&](const std::string& tail) {
    return master::parse_master_config(head + tail, "ring.yaml");
  };
  auto ok = parse(R"(hot_connect:
  - group: tool
    alias: 0x0042
    reserve_bytes: 32
    slaves: [{name: tool_io, process_data: main, revision: 0x00110000}]
)");
  ASSERT_TRUE(ok) << ok.error().describe();
  ASSERT_EQ(ok->hot_connect.size(), 1u);
  EXPECT_EQ(ok->hot_connect[0].alias, 0x0042);
  EXPECT_EQ(ok->hot_connect[0].reserve_bytes, 32u);
  EXPECT_EQ(ok->hot_connect[0].slaves[0].revision, 0x00110000u);
  EXPECT_FALSE(ok->hot_connect[0].device_id);
  // Known by an explicit device ID alone, its slave with SYNC0.
  auto by_id = parse(R"(dc: {cycle_us: 1000}
hot_connect:
  - group: tool
    identify: {device_id: 5}
    slaves: [{name: tool_io, sync: {mode: sync0}}]
)");
  ASSERT_TRUE(by_id) << by_id.error().describe();
  EXPECT_EQ(by_id->hot_connect[0].device_id, 5);
  ASSERT_TRUE(by_id->hot_connect[0].slaves[0].sync);
  // Each refused, naming what is wrong.
  const std::pair<const char*, const char*> refused[] = {
      {"hot_connect: [{group: tool, alias: 1, slaves: [{name: a, revision: -1}]}]\n",
       "slaves[0].revision"},
      {"hot_connect: [{alias: 1, slaves: [{name: a}]}]\n", "hot_connect[0]"},
      {"hot_connect: [{group: tool, slaves: [{name: a}]}]\n", "cannot be recognised"},
      {"hot_connect: [{group: tool, alias: 1, slaves: [{name: a, position: 4}]}]\n",
       "hot_connect[0].slaves[0].position"},
      {"hot_connect: [{group: tool, alias: 1, slaves: [{name: coupler}]}]\n", "used twice"},
      {"hot_connect: [{group: tool, alias: 1, slaves: [{name: a, process_data: nowhere}]}]\n",
       "unknown domain"},
      {"hot_connect: [{group: tool, alias: 1, where: 3, slaves: []}]\n", "where"},
      {"hot_connect: [{group: tool, identify: {device_id: 0}, slaves: [{name: a}]}]\n",
       "hot_connect[0].identify.device_id"},
      {"hot_connect: [{group: tool, identify: {serial: 3}, slaves: [{name: a}]}]\n", "serial"},
      {"hot_connect: [{group: tool, identify: 5, slaves: [{name: a}]}]\n", "{device_id: N}"},
  };
  for (const auto& [tail, named] : refused) {
    auto bad = parse(tail);
    ASSERT_FALSE(bad) << tail;
    EXPECT_NE(bad.error().describe().find(named), std::string::npos) << bad.error().describe();
  }
}

// ---- groups on a junction port in the middle of the ring -----------------------------------

// coupler -> inputs -> outputs -> junction (EK1122); on the junction's port 1 the group `tool`
// (tool_out -> tool_in), on its port 2 the rest of the ring (far_coupler -> far_in -> far_out).
// A frame leaves the junction by port 1 before port 2, so the group plugged sits at positions
// 4..5 and shifts the far slaves from 4..6 to 6..8. With `stranger`, a second group on the
// junction's port 2 (then the far slaves are left out): an EL2809 like tool_out followed by an
// EL3202 where tool_in should be, so that it takes tool's place in the ring when tool is out.
std::string junction_ring(bool stranger = false, bool plugged = false) {
  std::string yaml = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: inputs, profile: EL1809}
    - {name: outputs, profile: EL2809}
    - {name: junction, profile: EK1122}
    - {name: tool_out, profile: EL2809, parent: junction, port: 1, hot_connect: {group: tool, plugged: false}}
    - {name: tool_in, profile: EL1809}
)";
  if (plugged) yaml.replace(yaml.find("plugged: false"), 14, "plugged: true");
  if (stranger) {
    yaml +=
        R"(    - {name: bad_out, profile: EL2809, parent: junction, port: 2, hot_connect: {group: stranger, plugged: false}}
    - {name: bad_in, profile: EL3202}
)";
  } else {
    yaml += R"(    - {name: far_coupler, profile: EK1100, parent: junction, port: 2}
    - {name: far_in, profile: EL1809}
    - {name: far_out, profile: EL2809}
)";
  }
  yaml += R"(  wiring:
    - {from: outputs.channel_1, to: inputs.channel_1}
    - {from: tool_out.channel_1, to: tool_in.channel_1}
)";
  if (!stranger) yaml += "    - {from: far_out.channel_1, to: far_in.channel_1}\n";
  return yaml;
}

RingSpec junction_spec(bool stranger = false, std::optional<std::uint16_t> alias = std::nullopt,
                       bool plugged = false) {
  RingSpec spec;
  spec.ring_yaml = junction_ring(stranger, plugged);
  spec.adjust = [alias, stranger](master::MasterConfig& c) {
    std::vector<std::pair<const char*, bool>> fixed{{"junction", false}};
    if (!stranger)
      fixed.insert(fixed.end(), {{"far_coupler", false}, {"far_in", true}, {"far_out", true}});
    for (const auto& [name, process_data] : fixed) {
      master::SlaveConfig s;
      s.name = name;
      if (process_data) s.process_data = master::ProcessDataRequest::all("main");
      s.health_poll = 20ms;
      c.slaves.push_back(std::move(s));
    }
    c.hot_connect.push_back(tool_group(alias));
    c.hot_connect_poll = 10ms;
  };
  return spec;
}

// far_out.channel_1 -> far_in.channel_1, the slaves behind the junction's port 2.
bool far_loop_follows(master::Master& m, bool value) {
  return loop_follows(m, "far_out", "far_in", value, 2s);
}

std::uint16_t position_of(master::Master& m, const char* name) {
  auto s = m.slave(name);
  return s ? (*s)->position() : 0xFFFF;
}

TEST(HotConnect, AGroupOnAJunctionPortInTheMiddleComesAndGoesTheOthersUntouched) {
  auto ring = ScenarioRing::operational(junction_spec());
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  Monitor monitor(m);
  EXPECT_EQ(position_of(m, "far_coupler"), 4);
  EXPECT_EQ(position_of(m, "far_out"), 6);
  const auto before = ring->domain_stats();
  for (int round = 0; round < 2; ++round) {
    ASSERT_TRUE(ring->server->plug("tool", true));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
        << group_status(m).detail << "\n"
        << ring->describe();
    const auto g = group_status(m);
    EXPECT_EQ(g.position, 4);
    EXPECT_NE(g.detail.find("at position 4 (behind junction)"), std::string::npos) << g.detail;
    // The far slaves moved two places down the ring and are still addressed by their stations.
    EXPECT_EQ(position_of(m, "tool_out"), 4);
    EXPECT_EQ(position_of(m, "far_coupler"), 6);
    EXPECT_EQ(position_of(m, "far_out"), 8);
    auto in = m.slave("tool_in");
    ASSERT_TRUE(m.slave("tool_out") && in);
    EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", round == 0)) << ring->describe();
    EXPECT_TRUE(fixed_loop_follows(m, round == 0));
    EXPECT_TRUE(far_loop_follows(m, round == 0));
    ASSERT_TRUE(ring->server->plug("tool", false));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }))
        << group_status(m).detail;
    EXPECT_TRUE(eventually([&] { return position_of(m, "far_out") == 6; }))
        << position_of(m, "far_out");
    EXPECT_FALSE((*in)->read_input("channel_1"));
    EXPECT_TRUE(far_loop_follows(m, round != 0));
  }
  // The fixed slaves' cycles were never short: not one cycle lost its working counter, and
  // none of them was taken for a new device or went down.
  EXPECT_EQ(ring->domain_stats().wkc_mismatch_count, before.wkc_mismatch_count) << ring->describe();
  EXPECT_EQ(m.state(), MasterState::operational);
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_TRUE(m.status().hot_connect_refused.empty()) << m.status().hot_connect_refused;
  EXPECT_EQ(group_status(m).appearances, 2u);
  EXPECT_EQ(group_status(m).losses, 2u);
  monitor.stop();
  for (const char* name : {"junction", "far_coupler", "far_in", "far_out"}) {
    EXPECT_TRUE(monitor.matching(fmt::format("state:{}:down", name)).empty()) << monitor.seen();
  }
  EXPECT_TRUE(monitor.matching("master:recovering").empty()) << monitor.seen();
}

TEST(HotConnect, AGroupOnAJunctionPortPluggedAtStartIsFoundAndTheOthersPlacedAroundIt) {
  auto ring = ScenarioRing::operational(junction_spec(false, std::nullopt, true));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  // The fixed slaves behind the group keep the stations of their configuration (as if it were
  // not there) at the positions where they are.
  EXPECT_EQ(position_of(m, "far_coupler"), 6);
  EXPECT_EQ(position_of(m, "far_out"), 8);
  EXPECT_EQ((*m.slave("far_coupler"))->station(), 0x1004);
  EXPECT_EQ((*m.slave("far_out"))->station(), 0x1006);
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail << "\n"
      << ring->describe();
  EXPECT_EQ(group_status(m).position, 4);
  EXPECT_EQ(position_of(m, "tool_out"), 4);
  EXPECT_EQ(ring->slave_state("tool_in"), SlaveState::op);
  EXPECT_TRUE(fixed_loop_follows(m, true));
  EXPECT_TRUE(far_loop_follows(m, true));
  // Unplugged and plugged again as any group.
  ASSERT_TRUE(ring->server->plug("tool", false));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }));
  EXPECT_TRUE(eventually([&] { return position_of(m, "far_out") == 6; }));
  EXPECT_TRUE(far_loop_follows(m, false));
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail;
  EXPECT_EQ(position_of(m, "far_out"), 8);
  ASSERT_TRUE(m.slave("tool_out") && m.slave("tool_in"));
  EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", true)) << ring->describe();
  EXPECT_TRUE(far_loop_follows(m, true));
  EXPECT_EQ(m.state(), MasterState::operational);
  EXPECT_FALSE(ring->saw(MasterState::recovering));
  EXPECT_EQ(group_status(m).appearances, 2u);
}

// The same with every fixed slave given its position (counted without the group, as an ENI's
// import gives them): the group is still found in front of the far slaves.
TEST(HotConnect, AJunctionGroupPluggedAtStartIsFoundWithTheFixedSlavesPositionsGiven) {
  RingSpec spec = junction_spec(false, std::nullopt, true);
  spec.adjust = [inner = spec.adjust](master::MasterConfig& c) {
    inner(c);
    for (std::size_t i = 0; i < c.slaves.size(); ++i)
      c.slaves[i].position = static_cast<std::uint16_t>(i);
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  EXPECT_EQ(position_of(m, "far_coupler"), 6);
  EXPECT_EQ(position_of(m, "far_out"), 8);
  EXPECT_EQ((*m.slave("far_coupler"))->station(), 0x1004);
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }))
      << group_status(m).detail << "\n"
      << ring->describe();
  EXPECT_EQ(group_status(m).position, 4);
  EXPECT_TRUE(far_loop_follows(m, true));
  EXPECT_TRUE(loop_follows(m, "tool_out", "tool_in", true)) << ring->describe();
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnect, AWrongDeviceOnAJunctionPortIsRefusedTheOthersUntouched) {
  // The group is known by alias 0x0777; what is plugged on the junction has alias 0.
  auto ring = ScenarioRing::operational(junction_spec(false, 0x0777));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  const auto before = ring->domain_stats();
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return !m.status().hot_connect_refused.empty(); }));
  const auto refused = m.status().hot_connect_refused;
  EXPECT_NE(refused.find("position 4 (behind junction)"), std::string::npos) << refused;
  EXPECT_NE(refused.find("not configured"), std::string::npos) << refused;
  EXPECT_EQ(group_status(m).state, HotConnectState::absent);
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 100ms));
  auto sim = ring->server->status();
  EXPECT_EQ(sim.slaves.at(4).al_state, wire::AlState::init);  // tool_out: nothing brought up
  EXPECT_EQ(sim.slaves.at(5).al_state, wire::AlState::init);
  // The far slaves, shifted behind it, are not new devices: still operational, still cycling.
  EXPECT_EQ(position_of(m, "far_out"), 8);
  EXPECT_EQ(sim.slaves.at(8).al_state, wire::AlState::op);
  EXPECT_TRUE(far_loop_follows(m, true));
  EXPECT_TRUE(fixed_loop_follows(m, true));
  EXPECT_EQ(ring->domain_stats().wkc_mismatch_count, before.wkc_mismatch_count) << ring->describe();
}

TEST(HotConnect, TheRightGroupInARefusedGroupsPlaceJoinsWithoutWaitingTheRetryInterval) {
  // stranger (EL2809 + EL3202) looks like tool by its first slave and is refused by its second;
  // pulled out and replaced by tool, tool joins at once: the slave count changed, so the retry
  // wait (a minute here) starts afresh.
  auto spec = junction_spec(true);
  const auto adjust = spec.adjust;
  spec.adjust = [adjust](master::MasterConfig& c) {
    adjust(c);
    c.retry_interval = 60s;
  };
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(ring->server->plug("stranger", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::failed); }))
      << group_status(m).detail;
  EXPECT_NE(group_status(m).detail.find("slave tool_in at position 5"), std::string::npos)
      << group_status(m).detail;
  ASSERT_TRUE(ring->server->plug("stranger", false));
  std::this_thread::sleep_for(100ms);  // some polls see the ring without it
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }, 5s))
      << group_status(m).detail;
  EXPECT_EQ(group_status(m).position, 4);
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnectConfig, SimulatorRingErrorsNameWhatIsWrong) {
  auto first = sim::parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: EK1100, hot_connect: {group: g}}
)");
  ASSERT_FALSE(first);
  EXPECT_NE(first.error().describe().find("cabled to the master"), std::string::npos)
      << first.error().describe();
  auto twice = sim::parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: EK1100}
    - {name: b, profile: EL1809, hot_connect: {group: g}}
    - {name: c, profile: EL1809, hot_connect: {group: g}}
)");
  ASSERT_FALSE(twice);
  EXPECT_NE(twice.error().describe().find("already starts at slave 'b'"), std::string::npos)
      << twice.error().describe();
  auto nested = sim::parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: EK1100}
    - {name: b, profile: EL1809, hot_connect: {group: g}}
    - {name: c, profile: EL1809, hot_connect: {group: h}}
)");
  ASSERT_TRUE(nested);  // parsed; the segment refuses a group inside another
  auto built = sim::build_segment(*nested);
  ASSERT_FALSE(built);
  EXPECT_NE(built.error().describe().find("already part of group g"), std::string::npos)
      << built.error().describe();
  auto id_zero = sim::parse_ring(R"(simulator:
  slaves:
    - {name: a, profile: EK1100}
    - {name: b, profile: EL1809, device_id: 0}
)");
  ASSERT_FALSE(id_zero);
  EXPECT_NE(id_zero.error().describe().find("device_id"), std::string::npos)
      << id_zero.error().describe();
  auto good = sim::parse_ring(hot_connect_ring(false));
  ASSERT_TRUE(good) << good.error().describe();
  auto segment = sim::build_segment(*good);
  ASSERT_TRUE(segment) << segment.error().describe();
  const auto groups = (*segment)->hot_connect_groups();
  ASSERT_EQ(groups.size(), 1u);
  EXPECT_EQ(groups[0].slaves, 2u);
  EXPECT_FALSE(groups[0].plugged);
  // DL status of the port the group hangs on follows the cable.
  EXPECT_FALSE((*segment)->link(2, 1));
  ASSERT_TRUE((*segment)->plug("tool", true, 0));
  EXPECT_TRUE((*segment)->link(2, 1));
  auto unknown = (*segment)->plug("other", true, 0);
  ASSERT_FALSE(unknown);
  EXPECT_NE(unknown.error().describe().find("known: tool"), std::string::npos);
}

// ---- distributed clocks for a group ---------------------------------------------------------

// coupler (the reference clock) -> drive (SYNC0), then the group `tool`: one servo whose clock
// starts far off and drifts, with SYNC0.
constexpr const char* kDcRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: drive, profile: servo, clock: {drift_ppm: -40, offset_ns: 1500000}}
    - {name: tool_drive, profile: servo, clock: {drift_ppm: 70, offset_ns: 900000000}, hot_connect: {group: tool, plugged: false}}
)";

// A DC ring: 2 ms cycle, lock within 200 ns; `plain` fixed slaves without process data, then the
// fixed servo `drive` (SYNC0), and one hot-connect group per name in `groups`, each one servo
// `<group>_drive` (SYNC0) identified by its identity.
RingSpec dc_groups_spec(const char* yaml, std::vector<const char*> plain,
                        std::vector<std::string> groups) {
  RingSpec spec;
  spec.ring_yaml = yaml;
  spec.domain_period = 2ms;
  spec.adjust = [plain, groups](master::MasterConfig& c) {
    master::DcConfig dc;
    dc.cycle = 2ms;
    dc.lock_threshold = 200ns;
    c.dc = dc;
    master::SyncConfig sync;
    sync.mode = master::SyncMode::sync0;
    c.slaves.clear();
    for (const char* name : plain) {
      master::SlaveConfig s;
      s.name = name;
      c.slaves.push_back(s);
    }
    master::SlaveConfig drive;
    drive.name = "drive";
    drive.process_data = master::ProcessDataRequest::all("main");
    drive.sync = sync;
    c.slaves.push_back(drive);
    for (const auto& group : groups) {
      master::HotConnectGroup g;
      g.name = group;
      master::SlaveConfig tool;
      tool.name = fmt::format("{}_drive", group);
      tool.vendor_id = 0x00000ACE;
      tool.product_code = 0x00002402;
      tool.process_data = master::ProcessDataRequest::all("main");
      tool.health_poll = 20ms;
      tool.sync = sync;
      g.slaves.push_back(tool);
      c.hot_connect.push_back(g);
    }
    c.hot_connect_poll = 10ms;
  };
  return spec;
}

RingSpec dc_group_spec() {
  return dc_groups_spec(kDcRing, {"coupler"}, {"tool"});
}

// How far the group's clock is from the reference's, in truth (the simulator's system times at
// one instant), and whether its SYNC0 unit runs (0x0981 bit 0 and the SYNC0 bit set).
struct SimClock {
  std::int64_t offset_ns = 0;
  std::uint8_t activation = 0;
  bool running = false;
};
SimClock sim_clock(ScenarioRing& ring, std::size_t esc) {
  return ring.server->with_segment([esc](sim::Segment& segment, sim::FaultInjector&) {
    auto& ref = segment.esc(0);
    auto& tool = segment.esc(esc);
    const auto t = ref.now_ns();
    SimClock c;
    c.offset_ns = static_cast<std::int64_t>(tool.dc()->system_time(t) - ref.dc()->system_time(t));
    c.activation = tool.read_u8(0x0981);
    c.running = tool.dc()->sync_state() == sim::SyncUnitState::running;
    return c;
  });
}

TEST(HotConnectDc, AGroupWithADcSlaveJoinsTheClocksAndRunsSync0) {
  auto ring = ScenarioRing::operational(dc_group_spec());
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(m.await_dc_locked(20s)) << ring->describe();
  auto before = m.dc_status();
  ASSERT_TRUE(before) << before.error().describe();
  // Absent: the group's station is not part of the clocks' status.
  for (const auto& s : before->slaves)
    EXPECT_NE(s.station, 0x1002) << "the absent group's slave is listed";
  const auto unlocks = before->unlock_count;

  for (int round = 0; round < 2; ++round) {
    SCOPED_TRACE(round);
    ASSERT_TRUE(ring->server->plug("tool", true));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }, 15s))
        << group_status(m).detail << "\n"
        << ring->describe();
    EXPECT_EQ(ring->slave_state("tool_drive"), SlaveState::op);
    const auto info = ring->slave("tool_drive").info();
    ASSERT_TRUE(info.dc_sync);
    EXPECT_EQ(info.dc_sync->sync0_cycle_ns, 2'000'000u);
    EXPECT_NE(info.dc_sync->assign_activate, 0);
    // On the SYNC0 grid of the fixed drive: both start times are multiples of the cycle.
    EXPECT_EQ(info.dc_sync->start_time % 2'000'000u, 0u);
    std::this_thread::sleep_for(500ms);
    const auto clock = sim_clock(*ring, 2);
    EXPECT_LT(std::llabs(clock.offset_ns), 1000)
        << "system time off the reference's by " << clock.offset_ns << " ns";
    EXPECT_EQ(clock.activation & 0x03, 0x03) << int(clock.activation);
    EXPECT_TRUE(clock.running);
    auto st = m.dc_status();
    ASSERT_TRUE(st);
    bool listed = false;
    for (const auto& s : st->slaves) {
      if (s.station != 0x1002) continue;
      listed = true;
      EXPECT_FALSE(s.free_running);
      EXPECT_LT(std::llabs(s.difference_ns), 200);
    }
    EXPECT_TRUE(listed) << "the group's slave is not in the clocks' status";
    EXPECT_TRUE(st->locked);
    EXPECT_EQ(st->unlock_count, unlocks) << "the fixed slaves' lock was lost";

    ASSERT_TRUE(ring->server->plug("tool", false));
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }));
    std::this_thread::sleep_for(100ms);
    st = m.dc_status();
    ASSERT_TRUE(st);
    for (const auto& s : st->slaves)
      EXPECT_NE(s.station, 0x1002) << "the group's slave is still listed after it left";
    EXPECT_TRUE(st->locked);
    EXPECT_EQ(st->unlock_count, unlocks) << "the group's leaving cost the lock";
    EXPECT_EQ(st->free_running, 0u);
  }
  EXPECT_EQ(m.state(), MasterState::operational);
  EXPECT_FALSE(ring->saw(MasterState::recovering));
}

// coupler (the reference) -> junction_1 (EK1122): on its port 1 the group `a` (a servo), on its
// port 2 junction_2 (EK1122): on its port 1 the group `b` (a servo), on its port 2 the fixed
// `drive` (SYNC0). Both groups' cables are 1 us long, so the frame reaches `drive` over 2 us
// later with a group in than without it: a delay not measured again after a group left leaves
// `drive`'s system time that far off the reference's.
constexpr const char* kTwoDcGroupsRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: junction_1, profile: EK1122}
    - {name: a_drive, profile: servo, parent: junction_1, port: 1, cable_delay_ns: 1000, clock: {drift_ppm: 30, offset_ns: 5000000}, hot_connect: {group: a, plugged: false}}
    - {name: junction_2, profile: EK1122, parent: junction_1, port: 2}
    - {name: b_drive, profile: servo, parent: junction_2, port: 1, cable_delay_ns: 1000, clock: {drift_ppm: -30, offset_ns: 7000000}, hot_connect: {group: b, plugged: false}}
    - {name: drive, profile: servo, parent: junction_2, port: 2, clock: {drift_ppm: -40, offset_ns: 1500000}}
)";

RingSpec two_dc_groups_spec() {
  return dc_groups_spec(kTwoDcGroupsRing, {"coupler", "junction_1", "junction_2"}, {"a", "b"});
}

std::optional<master::HotConnectStatus> group_named(master::Master& m, std::string_view name) {
  for (const auto& g : m.status().hot_connect)
    if (g.group == name) return g;
  return std::nullopt;
}

bool group_in(master::Master& m, std::string_view name, HotConnectState state) {
  const auto g = group_named(m, name);
  return g && g->state == state;
}

// Two DC groups leave one shortly after the other (the second as the ring is being measured
// again for the first): the measurement runs once more, so the fixed `drive` behind both gets
// the delay of the ring without either and stays on the reference's time. The simulator's
// measurement is short: with the second leave dropped (the old behaviour) this passed too in the
// runs tried, so it guards the outcome rather than forcing the overlap.
TEST(HotConnectDc, TwoGroupsLeavingTogetherBothHaveTheDelaysMeasuredAgain) {
  auto ring = ScenarioRing::operational(two_dc_groups_spec());
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(m.await_dc_locked(20s)) << ring->describe();
  const std::size_t drive_esc = 5;
  for (const char* group : {"a", "b"}) {
    ASSERT_TRUE(ring->server->plug(group, true));
    ASSERT_TRUE(eventually([&] { return group_in(m, group, HotConnectState::present); }, 15s))
        << group << ": " << (group_named(m, group) ? group_named(m, group)->detail : "") << "\n"
        << ring->describe();
  }
  std::this_thread::sleep_for(500ms);
  auto clock = sim_clock(*ring, drive_esc);
  EXPECT_LT(std::llabs(clock.offset_ns), 1000)
      << "drive off the reference by " << clock.offset_ns << " ns with both groups in";

  for (int round = 0; round < 3; ++round) {
    SCOPED_TRACE(round);
    if (round > 0) {
      for (const char* group : {"a", "b"}) {
        ASSERT_TRUE(ring->server->plug(group, true));
        ASSERT_TRUE(eventually([&] { return group_in(m, group, HotConnectState::present); }, 15s))
            << ring->describe();
      }
    }
    // `a` out; `b` out the moment the master reports `a` lost (from the event dispatcher, while
    // the delays are being measured again for `a`), within one hot-connect poll (10 ms) of it.
    std::atomic<bool> armed{true};
    const auto id = m.subscribe_events([&](const master::Event& e, std::uint64_t) {
      if (e.kind == master::EventKind::hotconnect_lost && e.name() == "a" && armed.exchange(false))
        (void)ring->server->plug("b", false);
    });
    ASSERT_TRUE(ring->server->plug("a", false));
    ASSERT_TRUE(eventually([&] { return !armed.load(); }));
    m.unsubscribe_events(id);
    ASSERT_TRUE(eventually([&] {
      return group_in(m, "a", HotConnectState::absent) && group_in(m, "b", HotConnectState::absent);
    }));
    std::this_thread::sleep_for(600ms);
    clock = sim_clock(*ring, drive_esc);
    EXPECT_LT(std::llabs(clock.offset_ns), 1000)
        << "drive off the reference by " << clock.offset_ns << " ns after both groups left";
    auto st = m.dc_status();
    ASSERT_TRUE(st);
    EXPECT_TRUE(st->locked);
  }
  EXPECT_EQ(m.state(), MasterState::operational);
}

// coupler (the reference) -> junction (EK1122): on its port 1 the group `tool` (a servo with
// SYNC0) on a 500 ns cable, on its port 2 the fixed `drive` (SYNC0): the group plugs in front of
// a fixed DC slave, which then sees the frame 1.2 us later (two cables, the group's processing
// and turnaround, the junction's forwarding).
constexpr const char* kJunctionDcRing = R"(version: 1
simulator:
  slaves:
    - {name: coupler, profile: EK1100}
    - {name: junction, profile: EK1122}
    - {name: tool_drive, profile: servo, parent: junction, port: 1, cable_delay_ns: 500, clock: {drift_ppm: 70, offset_ns: 900000000}, hot_connect: {group: tool, plugged: false}}
    - {name: drive, profile: servo, parent: junction, port: 2, clock: {drift_ppm: -40, offset_ns: 1500000}}
)";

// dc_group_spec on kJunctionDcRing, the junction configured after the coupler; the group plugged
// at start or not.
RingSpec junction_dc_spec(bool plugged) {
  RingSpec spec = dc_group_spec();
  std::string yaml = kJunctionDcRing;
  if (plugged) {
    const std::string absent = "plugged: false";
    yaml.replace(yaml.find(absent), absent.size(), "plugged: true");
  }
  spec.ring_yaml = yaml;
  spec.adjust = [inner = spec.adjust](master::MasterConfig& c) {
    inner(c);
    master::SlaveConfig junction;
    junction.name = "junction";
    c.slaves.insert(c.slaves.begin() + 1, junction);
  };
  return spec;
}

// A DC group plugged on a junction port in the middle: the master set the port to auto close at
// startup, so the plugged group waits behind a closed port (DL status: link up, loop closed)
// until the hot-connect watch opens it and writes `drive`'s new delay right behind; at the
// unplug the ESC shuts the port itself and the watch writes the shorter delay. `drive`'s 0x092C
// difference (sampled as the master reads it) stays within the lock bound through the join and
// the leave, the lock is never lost, and its system time stays on the reference's. (Without
// auto close, the 500 ns cable took it to about 280 ns and the lock was lost at both.)
TEST(HotConnectDc, AGroupOnAJunctionPortKeepsTheFixedSlavesBehindItLocked) {
  RingSpec spec = junction_dc_spec(false);
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(m.await_dc_locked(20s)) << ring->describe();
  const auto drive_station = (*m.slave("drive"))->station();
  const std::size_t drive_esc = 3;
  auto before = m.dc_status();
  ASSERT_TRUE(before);
  const auto unlocks = before->unlock_count;
  // The master set the junction's port 1 (bits 2..3) to auto close at startup; port 2 (the
  // fixed drive's) is left in auto.
  const auto port_control = ring->server->with_segment(
      [](sim::Segment& segment, sim::FaultInjector&) { return segment.esc(1).read_u8(0x0101); });
  EXPECT_EQ(port_control & 0x3C, 0x04) << int(port_control);
  const std::int64_t bound = 200;  // the lock threshold
  for (int round = 0; round < 2; ++round) {
    SCOPED_TRACE(round);
    std::int64_t worst = 0;
    const auto sample = [&] {
      const auto st = m.dc_status();
      if (!st) return;
      for (const auto& s : st->slaves)
        if (s.station == drive_station)
          worst = std::max<std::int64_t>(worst, std::llabs(s.difference_ns));
    };
    ASSERT_TRUE(ring->server->plug("tool", true));
    const auto until = std::chrono::steady_clock::now() + 15s;
    while (!group_in(m, HotConnectState::present) && std::chrono::steady_clock::now() < until) {
      sample();
      std::this_thread::sleep_for(1ms);
    }
    ASSERT_TRUE(group_in(m, HotConnectState::present)) << group_status(m).detail;
    for (int i = 0; i < 300; ++i) {
      sample();
      std::this_thread::sleep_for(1ms);
    }
    EXPECT_LT(worst, bound) << "drive's 0x092C difference reached " << worst << " ns";
    auto clock = sim_clock(*ring, drive_esc);
    EXPECT_LT(std::llabs(clock.offset_ns), 1000)
        << "drive off the reference by " << clock.offset_ns << " ns with the group in";
    auto st = m.dc_status();
    ASSERT_TRUE(st);
    EXPECT_TRUE(st->locked);
    EXPECT_EQ(st->unlock_count, unlocks) << "the fixed slaves' lock was lost";

    worst = 0;
    ASSERT_TRUE(ring->server->plug("tool", false));
    for (int i = 0; i < 300; ++i) {
      sample();
      std::this_thread::sleep_for(1ms);
    }
    ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }));
    EXPECT_LT(worst, bound) << "drive's 0x092C difference reached " << worst << " ns";
    st = m.dc_status();
    ASSERT_TRUE(st);
    EXPECT_EQ(st->unlock_count, unlocks) << "the group's leaving cost the lock";
  }
  EXPECT_EQ(m.state(), MasterState::operational);
}

// The same group plugged at start: its port is set to auto close with the link up, so it stays
// open (the start-up's DC measurement has the group in front of `drive`); pulled, the ESC shuts
// it and `drive` gets the shorter delay; plugged again, it waits until the master opens it.
TEST(HotConnectDc, AJunctionGroupPluggedAtStartLeavesAndComesBackWithTheFixedSlavesLocked) {
  RingSpec spec = junction_dc_spec(true);
  auto ring = ScenarioRing::operational(spec);
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(m.await_dc_locked(20s)) << ring->describe();
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }, 15s))
      << group_status(m).detail << "\n"
      << ring->describe();
  const auto drive_station = (*m.slave("drive"))->station();
  const auto port_control = ring->server->with_segment(
      [](sim::Segment& segment, sim::FaultInjector&) { return segment.esc(1).read_u8(0x0101); });
  EXPECT_EQ(port_control & 0x3C, 0x04) << int(port_control);
  auto before = m.dc_status();
  ASSERT_TRUE(before);
  const auto unlocks = before->unlock_count;
  std::int64_t worst = 0;
  const auto sample_for = [&](std::chrono::milliseconds span) {
    const auto until = std::chrono::steady_clock::now() + span;
    while (std::chrono::steady_clock::now() < until) {
      if (const auto st = m.dc_status()) {
        for (const auto& s : st->slaves)
          if (s.station == drive_station)
            worst = std::max<std::int64_t>(worst, std::llabs(s.difference_ns));
      }
      std::this_thread::sleep_for(1ms);
    }
  };
  ASSERT_TRUE(ring->server->plug("tool", false));
  sample_for(300ms);
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::absent); }));
  EXPECT_LT(worst, 200) << "drive's 0x092C difference reached " << worst << " ns at the unplug";
  worst = 0;
  ASSERT_TRUE(ring->server->plug("tool", true));
  ASSERT_TRUE(eventually([&] { return group_in(m, HotConnectState::present); }, 15s))
      << group_status(m).detail;
  sample_for(300ms);
  EXPECT_LT(worst, 200) << "drive's 0x092C difference reached " << worst << " ns at the plug";
  const auto clock = sim_clock(*ring, 3);
  EXPECT_LT(std::llabs(clock.offset_ns), 1000)
      << "drive off the reference by " << clock.offset_ns << " ns with the group in";
  const auto st = m.dc_status();
  ASSERT_TRUE(st);
  EXPECT_TRUE(st->locked);
  EXPECT_EQ(st->unlock_count, unlocks) << "the fixed slaves' lock was lost";
  EXPECT_EQ(ring->slave_state("tool_drive"), SlaveState::op);
  EXPECT_EQ(m.state(), MasterState::operational);
}

// ---- groups known by an explicit device ID ---------------------------------------------------

// coupler -> inputs -> outputs -> junction; on the junction's port 1 the group `a` (device ID 5),
// on its port 2 the group `b` (device ID 6): both an EL2809 followed by an EL1809.
std::string device_id_ring(std::uint16_t a_id) {
  return fmt::format(R"(version: 1
simulator:
  slaves:
    - {{name: coupler, profile: EK1100}}
    - {{name: inputs, profile: EL1809}}
    - {{name: outputs, profile: EL2809}}
    - {{name: junction, profile: EK1122}}
    - {{name: a_out, profile: EL2809, parent: junction, port: 1, device_id: {}, hot_connect: {{group: a, plugged: false}}}}
    - {{name: a_in, profile: EL1809}}
    - {{name: b_out, profile: EL2809, parent: junction, port: 2, device_id: 6, hot_connect: {{group: b, plugged: false}}}}
    - {{name: b_in, profile: EL1809}}
  wiring:
    - {{from: outputs.channel_1, to: inputs.channel_1}}
    - {{from: a_out.channel_1, to: a_in.channel_1}}
    - {{from: b_out.channel_1, to: b_in.channel_1}}
)",
                     a_id);
}

// The master declares `left` with device ID 6 and `right` with 5: the same devices, told apart
// by their IDs only.
RingSpec device_id_spec(std::uint16_t a_id) {
  RingSpec spec;
  spec.ring_yaml = device_id_ring(a_id);
  spec.adjust = [](master::MasterConfig& c) {
    master::SlaveConfig junction;
    junction.name = "junction";
    c.slaves.push_back(junction);
    for (const auto& [name, id] :
         {std::pair<const char*, std::uint16_t>{"left", 6}, {"right", 5}}) {
      auto g = tool_group();
      g.name = name;
      g.device_id = id;
      g.slaves[0].name = std::string(name) + "_out";
      g.slaves[1].name = std::string(name) + "_in";
      c.hot_connect.push_back(g);
    }
    c.hot_connect_poll = 10ms;
  };
  return spec;
}

master::HotConnectStatus named_group(master::Master& m, const std::string& name) {
  for (const auto& g : m.status().hot_connect) {
    if (g.group == name) return g;
  }
  return {};
}

TEST(HotConnect, GroupsOfOneProductAreToldApartByTheirDeviceIds) {
  auto ring = ScenarioRing::operational(device_id_spec(5));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(ring->server->plug("a", true));  // device ID 5: `right`
  ASSERT_TRUE(eventually([&] { return named_group(m, "right").state == HotConnectState::present; }))
      << named_group(m, "right").detail << "\n"
      << ring->describe();
  EXPECT_EQ(named_group(m, "left").state, HotConnectState::absent);
  EXPECT_NE(named_group(m, "right").detail.find("device ID 5 at position 4"), std::string::npos)
      << named_group(m, "right").detail;
  ASSERT_TRUE(ring->server->plug("b", true));  // device ID 6: `left`, behind it
  ASSERT_TRUE(eventually([&] { return named_group(m, "left").state == HotConnectState::present; }))
      << named_group(m, "left").detail << "\n"
      << ring->describe();
  EXPECT_EQ(named_group(m, "left").position, 6);
  for (const char* side : {"left", "right"}) {
    auto out = m.slave(std::string(side) + "_out");
    auto in = m.slave(std::string(side) + "_in");
    ASSERT_TRUE(out && in);
    EXPECT_EQ((*in)->state(), SlaveState::op) << side;
    ASSERT_TRUE((*out)->write_output("channel_1", master::Value(true)));
    EXPECT_TRUE(eventually([&] {
      auto v = (*in)->read_input("channel_1");
      return v && master::as_bool(*v) == true;
    })) << side;
  }
  // The ID request was taken back: AL status shows the state alone.
  auto sim = ring->server->status();
  EXPECT_EQ(sim.slaves.at(4).al_state, wire::AlState::op);
  EXPECT_EQ(m.state(), MasterState::operational);
}

TEST(HotConnect, ADeviceIdNoGroupDeclaresIsRefusedNamingIt) {
  auto ring = ScenarioRing::operational(device_id_spec(9));
  ASSERT_TRUE(ring);
  auto& m = *ring->master;
  ASSERT_TRUE(ring->server->plug("a", true));
  ASSERT_TRUE(eventually([&] { return !m.status().hot_connect_refused.empty(); }));
  const auto why = m.status().hot_connect_refused;
  EXPECT_NE(why.find("device ID 9"), std::string::npos) << why;
  EXPECT_NE(why.find("position 4"), std::string::npos) << why;
  EXPECT_EQ(named_group(m, "left").state, HotConnectState::absent);
  EXPECT_EQ(named_group(m, "right").state, HotConnectState::absent);
  EXPECT_EQ(ring->server->status().slaves.at(4).al_state, wire::AlState::init);
  EXPECT_TRUE(stays([&] { return m.state() == MasterState::operational; }, 100ms));
}

}  // namespace
}  // namespace ecat::scenarios
