// The pure parts of the DC module: topology reconstruction, delays and offsets from hand-built
// receive-time snapshots, difference decoding, AssignActivate resolution, latch control bytes.
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/config/esi.hpp>
#include <ecat/master/dc.hpp>
#include <ecat/wire/registers.hpp>
#include <ecat/wire/sii.hpp>

namespace ecat::master {
namespace {

// A segment as the test describes it; nodes listed in frame (depth-first) order.
struct Node {
  std::optional<std::size_t> parent;  // nullopt: the previous node (a line); node 0: the master
  std::uint8_t port = 1;
  std::int64_t cable = 5;
  std::int64_t processing = 100;
  std::int64_t forwarding = 50;
  bool dc = true;
  std::uint64_t clock_base = 0;  // local time at true time 0
};

struct Built {
  std::vector<DcSlaveSnapshot> snapshots;
  std::vector<std::int64_t> arrival;  // true arrival times
};

std::uint16_t dl_status(const std::array<bool, 4>& open) {
  wire::DlStatus dl;
  for (std::size_t p = 0; p < 4; ++p) {
    dl.ports[p].physical_link = open[p];
    dl.ports[p].communication = open[p];
    dl.ports[p].loop_closed = !open[p];
  }
  return dl.encode();
}

// Frame timing as an ESC chain produces it: processing on the way out of port 0, forwarding on
// the way back through each port, the return to port 0 after the last port.
class Model {
 public:
  explicit Model(std::vector<Node> nodes) : nodes_(std::move(nodes)) {
    children_.resize(nodes_.size());
    for (std::size_t i = 1; i < nodes_.size(); ++i) {
      const std::size_t parent = nodes_[i].parent.value_or(i - 1);
      children_[parent][nodes_[i].port] = i;
    }
  }

  Built build() {
    Built out;
    out.snapshots.resize(nodes_.size());
    out.arrival.resize(nodes_.size());
    visit(0, nodes_[0].cable, out);
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      auto& s = out.snapshots[i];
      s.station = static_cast<std::uint16_t>(0x1001 + i);
      s.dc_supported = nodes_[i].dc;
      std::array<bool, 4> open{true, false, false, false};
      for (std::size_t p = 1; p < 4; ++p)
        open[p] = children_[i][p].has_value();
      s.dl_status = dl_status(open);
      s.speed_counter_start = 0x1000;
    }
    return out;
  }

 private:
  std::int64_t visit(std::size_t i, std::int64_t arrival, Built& out) {
    const Node& node = nodes_[i];
    auto& s = out.snapshots[i];
    out.arrival[i] = arrival;
    auto local = [&](std::int64_t t) { return node.clock_base + static_cast<std::uint64_t>(t); };
    s.port_time[0] = static_cast<std::uint32_t>(local(arrival));
    s.epu_time = node.dc ? local(arrival) : 0;
    std::int64_t t = arrival + node.processing;
    for (std::uint8_t port : {3, 1, 2}) {
      if (!children_[i][port]) continue;
      const std::size_t c = *children_[i][port];
      const std::int64_t back = visit(c, t + nodes_[c].cable, out) + nodes_[c].cable;
      s.port_time[port] = static_cast<std::uint32_t>(local(back));
      t = back + node.forwarding;
    }
    return t + node.forwarding;
  }

  std::vector<Node> nodes_;
  std::vector<std::array<std::optional<std::size_t>, 4>> children_;
};

// Designated initializers would leave members out (a warning here); these spell the variants.
Node line_node(std::uint64_t clock_base = 0, bool dc = true) {
  Node n;
  n.clock_base = clock_base;
  n.dc = dc;
  return n;
}
Node branch_node(std::size_t parent, std::uint8_t port, std::int64_t cable,
                 std::uint64_t clock_base) {
  Node n;
  n.parent = parent;
  n.port = port;
  n.cable = cable;
  n.clock_base = clock_base;
  return n;
}
Node timed_node(std::int64_t processing, std::int64_t forwarding) {
  Node n;
  n.processing = processing;
  n.forwarding = forwarding;
  return n;
}

constexpr std::int64_t kMasterTime = 777'000'000'000'000'000;

TEST(DcPlan, LineOfThree) {
  Model model({line_node(5'000'000'000ull), line_node(123'456'789ull),
               line_node(0xFFFF'FF00ull)});  // the last one wraps its 32-bit port times
  auto built = model.build();
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_TRUE(plan) << plan.error().describe();
  EXPECT_EQ(plan->reference_position, 0u);
  EXPECT_EQ(plan->reference_station, 0x1001);
  ASSERT_EQ(plan->slaves.size(), 3u);
  EXPECT_FALSE(plan->slaves[0].parent.has_value());
  EXPECT_EQ(plan->slaves[1].parent, std::optional<std::size_t>(0));
  EXPECT_EQ(plan->slaves[1].parent_port, 1);
  EXPECT_EQ(plan->slaves[2].parent, std::optional<std::size_t>(1));
  EXPECT_EQ(plan->slaves[0].delay_ns, 0u);
  EXPECT_EQ(plan->slaves[1].delay_ns, 105u);  // processing 100 + cable 5
  EXPECT_EQ(plan->slaves[2].delay_ns, 210u);
  for (std::size_t i = 0; i < 3; ++i) {
    // System time at the latch = master time + delay.
    const std::uint64_t system =
        built.snapshots[i].epu_time + static_cast<std::uint64_t>(plan->slaves[i].offset_ns);
    EXPECT_EQ(system, static_cast<std::uint64_t>(kMasterTime) + plan->slaves[i].delay_ns) << i;
  }
}

TEST(DcPlan, BranchesThroughJunctionPorts) {
  // 0: junction with 1 on port 3, 2 on port 1 (with 3 behind it on port 1, and 4 on 3's port 2
  // via a nested junction), 5 on port 2; long and short cables, different clocks.
  Node root = line_node(1'000);
  root.cable = 7;
  Model model({root, branch_node(0, 3, 40, 9'999'999), branch_node(0, 1, 12, 42),
               branch_node(2, 1, 300, 77'000), branch_node(3, 2, 9, 5),
               branch_node(0, 2, 150, 31'337)});
  auto built = model.build();
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_TRUE(plan) << plan.error().describe();
  const std::vector<std::pair<std::size_t, std::uint8_t>> expected_parents{
      {0, 3}, {0, 1}, {2, 1}, {3, 2}, {0, 2}};
  for (std::size_t i = 1; i < 6; ++i) {
    EXPECT_EQ(plan->slaves[i].parent, std::optional<std::size_t>(expected_parents[i - 1].first))
        << i;
    EXPECT_EQ(plan->slaves[i].parent_port, expected_parents[i - 1].second) << i;
  }
  for (std::size_t i = 0; i < 6; ++i) {
    const std::int64_t expected = built.arrival[i] - built.arrival[0];
    EXPECT_NEAR(static_cast<double>(plan->slaves[i].delay_ns), static_cast<double>(expected), 1.0)
        << "slave " << i;
  }
  // Spot check against hand-computed values: slave 1 = 100 + 40; slave 5 follows the whole
  // port-3 and port-1 subtrees.
  EXPECT_EQ(plan->slaves[1].delay_ns, 140u);
  EXPECT_EQ(built.arrival[1] - built.arrival[0], 140);
}

TEST(DcPlan, NonDcSlavesAreSkippedAndTheReferenceIsTheFirstDcSlave) {
  Model model({line_node(0, false), line_node(10), line_node(0, false), line_node()});
  auto built = model.build();
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_TRUE(plan) << plan.error().describe();
  EXPECT_EQ(plan->reference_position, 1u);
  EXPECT_EQ(plan->reference_station, 0x1002);
  EXPECT_FALSE(plan->slaves[0].dc);
  EXPECT_TRUE(plan->slaves[1].dc);
  EXPECT_FALSE(plan->slaves[2].dc);
  EXPECT_TRUE(plan->slaves[3].dc);
  EXPECT_EQ(plan->slaves[1].delay_ns, 0u);
  EXPECT_EQ(plan->slaves[3].delay_ns, 210u);
  EXPECT_EQ(plan->slaves[0].offset_ns, 0);
  EXPECT_EQ(plan->dc_positions(), (std::vector<std::size_t>{1, 3}));
}

TEST(DcPlan, NoDcSlaveIsAnError) {
  Model model({line_node(0, false), line_node(0, false)});
  auto built = model.build();
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_EQ(plan.error().code(), Errc::not_found);
  EXPECT_NE(plan.error().message().find("no DC-capable slave among 2"), std::string::npos)
      << plan.error().message();
}

TEST(DcPlan, MoreSlavesThanOpenPorts) {
  Model model({line_node(), line_node(), line_node()});
  auto built = model.build();
  built.snapshots[1].dl_status = dl_status({true, false, false, false});  // slave 1 looks last
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_EQ(plan.error().code(), Errc::malformed);
  EXPECT_NE(plan.error().message().find("slave 2 (station 0x1003) has no open port left"),
            std::string::npos)
      << plan.error().message();
}

TEST(DcPlan, OpenPortWithNothingBehindIt) {
  Model model({line_node(), line_node()});
  auto built = model.build();
  built.snapshots[1].dl_status = dl_status({true, false, true, false});
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_NE(plan.error().message().find("slave 1 (station 0x1002) has port 2 open"),
            std::string::npos)
      << plan.error().message();
}

// A redundant ring: the last slave's port 1 is cabled back to the master's second port. The
// plan accepts that one open port (and only on the last slave) when told so, with the delays of
// the line.
TEST(DcPlan, RedundantRingReturnsToTheMaster) {
  Model model({line_node(), line_node(), line_node()});
  auto built = model.build();
  auto line = plan_dc(built.snapshots, kMasterTime);
  ASSERT_TRUE(line) << line.error().describe();
  built.snapshots[2].dl_status = dl_status({true, true, false, false});
  auto plain = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plain);
  EXPECT_NE(plain.error().message().find("slave 2 (station 0x1003) has port 1 open"),
            std::string::npos)
      << plain.error().message();
  DcPlanOptions options;
  options.ring_returns_to_master = true;
  auto ring = plan_dc(built.snapshots, kMasterTime, options);
  ASSERT_TRUE(ring) << ring.error().describe();
  for (std::size_t i = 0; i < 3; ++i)
    EXPECT_EQ(ring->slaves[i].delay_ns, line->slaves[i].delay_ns) << i;
  // A second open port with nothing behind it is still one too many.
  built.snapshots[2].dl_status = dl_status({true, true, true, false});
  auto two = plan_dc(built.snapshots, kMasterTime, options);
  ASSERT_FALSE(two);
  EXPECT_NE(two.error().message().find("slave 2 (station 0x1003) has port 2 open"),
            std::string::npos)
      << two.error().message();
  // And an open port on an earlier slave is never the way back.
  built.snapshots[2].dl_status = dl_status({true, false, false, false});
  built.snapshots[0].dl_status = dl_status({true, true, true, false});
  auto early = plan_dc(built.snapshots, kMasterTime, options);
  ASSERT_FALSE(early);
}

TEST(DcPlan, NonMonotonicReceiveTime) {
  Model model({line_node(), line_node()});
  auto built = model.build();
  built.snapshots[0].port_time[1] = built.snapshots[0].port_time[0] - 10;
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_EQ(plan.error().code(), Errc::malformed);
  EXPECT_NE(plan.error().message().find("slave 0 (station 0x1001): port 1 time"), std::string::npos)
      << plan.error().message();
}

TEST(DcPlan, ParentWithoutReceiveTimes) {
  Model model({line_node(), line_node(), line_node()});
  auto built = model.build();
  built.snapshots[1].receive_times_valid = false;
  auto plan = plan_dc(built.snapshots, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_EQ(plan.error().code(), Errc::unsupported);
  EXPECT_NE(plan.error().message().find("slave 1 (station 0x1002) has no receive times"),
            std::string::npos)
      << plan.error().message();
}

TEST(DcPlan, EmptyInput) {
  auto plan = plan_dc({}, kMasterTime);
  ASSERT_FALSE(plan);
  EXPECT_EQ(plan.error().code(), Errc::invalid_argument);
}

TEST(DcPlan, TimingModelIsConfigurable) {
  Model model({timed_node(300, 80), timed_node(300, 80), timed_node(300, 80)});
  auto built = model.build();
  DcPlanOptions options;
  options.timing = {300, 80};
  auto plan = plan_dc(built.snapshots, kMasterTime, options);
  ASSERT_TRUE(plan) << plan.error().describe();
  EXPECT_EQ(plan->slaves[1].delay_ns, 305u);
  EXPECT_EQ(plan->slaves[2].delay_ns, 610u);
}

TEST(DcDifference, SignAndMagnitude) {
  EXPECT_EQ(decode_dc_difference(0x0000'0000u), 0);
  EXPECT_EQ(decode_dc_difference(0x0000'0064u), 100);
  EXPECT_EQ(decode_dc_difference(0x8000'0064u), -100);
  EXPECT_EQ(decode_dc_difference(0x7FFF'FFFFu), 0x7FFF'FFFF);
  EXPECT_EQ(decode_dc_difference(0xFFFF'FFFFu), -0x7FFF'FFFF);
}

TEST(DcSync, AssignActivateSources) {
  SyncConfig sync;
  sync.mode = SyncMode::free_run;
  EXPECT_EQ(resolve_assign_activate(sync, nullptr),
            std::make_pair(std::uint16_t{0}, AssignActivateSource::none));
  sync.mode = SyncMode::sync0;
  EXPECT_EQ(resolve_assign_activate(sync, nullptr),
            std::make_pair(std::uint16_t{0x0300}, AssignActivateSource::mode_default));
  sync.mode = SyncMode::sync1;
  EXPECT_EQ(resolve_assign_activate(sync, nullptr),
            std::make_pair(std::uint16_t{0x0700}, AssignActivateSource::mode_default));

  wire::SiiImage sii;
  wire::SiiDcSync free_run;
  free_run.assign_activate = 0;
  wire::SiiDcSync s0;
  s0.assign_activate = 0x0320;
  wire::SiiDcSync s1;
  s1.assign_activate = 0x0730;
  sii.dc = {free_run, s1, s0};
  sync.mode = SyncMode::sync0;
  EXPECT_EQ(resolve_assign_activate(sync, &sii),
            std::make_pair(std::uint16_t{0x0320}, AssignActivateSource::sii));
  sync.mode = SyncMode::sync1;
  EXPECT_EQ(resolve_assign_activate(sync, &sii),
            std::make_pair(std::uint16_t{0x0730}, AssignActivateSource::sii));
  // An ESI description comes before the SII; an OpMode without SYNC0 never matches.
  config::EsiDevice esi;
  esi.dc_op_modes = {{"DcOff", "", 0x0000}, {"DcSync01", "", 0x0770}, {"DcSync", "", 0x0340}};
  sync.mode = SyncMode::sync0;
  EXPECT_EQ(resolve_assign_activate(sync, &sii, &esi),
            std::make_pair(std::uint16_t{0x0340}, AssignActivateSource::esi));
  sync.mode = SyncMode::sync1;
  EXPECT_EQ(resolve_assign_activate(sync, &sii, &esi),
            std::make_pair(std::uint16_t{0x0770}, AssignActivateSource::esi));
  config::EsiDevice without_dc;
  EXPECT_EQ(resolve_assign_activate(sync, &sii, &without_dc),
            std::make_pair(std::uint16_t{0x0730}, AssignActivateSource::sii));
  EXPECT_EQ(to_string(AssignActivateSource::esi), "ESI");
  sync.assign_activate = 0x0E00;
  EXPECT_EQ(resolve_assign_activate(sync, &sii, &esi),
            std::make_pair(std::uint16_t{0x0E00}, AssignActivateSource::config));
}

TEST(DcSync, LatchControlBytes) {
  std::vector<LatchConfig> latches{
      {"a", 0, LatchEdge::rising}, {"b", 1, LatchEdge::falling}, {"c", 1, LatchEdge::rising}};
  EXPECT_EQ(latch_control(latches, 0), 0x01);
  EXPECT_EQ(latch_control(latches, 1), 0x03);
  EXPECT_EQ(latch_control({}, 0), 0x00);
}

}  // namespace
}  // namespace ecat::master
