// Where a redundant ring is open, from the slaves' DL status (master/ring_break.hpp).
#include <optional>
#include <vector>

#include <gtest/gtest.h>

#include <ecat/master/ring_break.hpp>

#include "master/json_view.hpp"

namespace ecat::master {
namespace {

using Where = link::RingBreak::Where;

// Four slaves, every link up (the last one's port 1 cabled to the secondary port).
std::vector<RingPortReading> whole_ring() {
  std::vector<RingPortReading> out;
  for (std::uint16_t i = 0; i < 4; ++i) {
    wire::DlStatus dl;
    for (std::size_t p = 0; p < 2; ++p) {
      dl.ports[p].physical_link = true;
      dl.ports[p].communication = true;
    }
    out.push_back({static_cast<std::uint16_t>(0x1001 + i), dl});
  }
  return out;
}

void lose(std::vector<RingPortReading>& r, std::size_t slave, std::size_t port) {
  r[slave].dl_status->ports[port].physical_link = false;
  r[slave].dl_status->ports[port].communication = false;
  r[slave].dl_status->ports[port].loop_closed = true;
}

TEST(RingBreak, WholeRingHasNone) {
  EXPECT_FALSE(locate_ring_break(whole_ring()));
  EXPECT_FALSE(locate_ring_break(std::vector<RingPortReading>{}));
}

TEST(RingBreak, BetweenSlavesFromEitherEnd) {
  for (std::size_t port : {1u, 0u}) {
    auto r = whole_ring();
    // The cable between slaves 1 and 2: slave 1's port 1, or slave 2's port 0, or both.
    lose(r, port == 1 ? 1 : 2, port);
    const auto b = locate_ring_break(r);
    ASSERT_TRUE(b) << port;
    EXPECT_EQ(b->where, Where::between_slaves);
    EXPECT_EQ(b->before_position, 1u);
    EXPECT_EQ(b->before_station, 0x1002);
    EXPECT_EQ(b->after_position, 2u);
    EXPECT_EQ(b->after_station, 0x1003);
    EXPECT_EQ(link::describe(*b), "between slave 1 (station 0x1002) and slave 2 (station 0x1003)");
  }
}

TEST(RingBreak, MasterCables) {
  auto r = whole_ring();
  lose(r, 0, 0);
  auto b = locate_ring_break(r);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->where, Where::primary_cable);
  EXPECT_EQ(b->before_station, 0x1001);
  EXPECT_EQ(link::describe(*b), "at the primary port's cable (slave 0, station 0x1001, port 0)");
  r = whole_ring();
  lose(r, 3, 1);
  b = locate_ring_break(r);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->where, Where::secondary_cable);
  EXPECT_EQ(b->before_position, 3u);
  EXPECT_EQ(link::to_string(b->where), "secondary_cable");
}

TEST(RingBreak, TheFirstLostLinkInRingOrder) {
  auto r = whole_ring();
  lose(r, 2, 1);
  lose(r, 0, 1);
  const auto b = locate_ring_break(r);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->before_position, 0u);
}

TEST(RingBreak, ASilentSlaveBeforeTheBreakLeavesItUnlocated) {
  auto r = whole_ring();
  lose(r, 2, 1);
  r[1].dl_status.reset();
  EXPECT_FALSE(locate_ring_break(r));
  // A silent slave after the break does not matter.
  r = whole_ring();
  lose(r, 0, 1);
  r[3].dl_status.reset();
  ASSERT_TRUE(locate_ring_break(r));
}

// ---- a ring through a junction ----------------------------------------------------------------
// 0 coupler -> 1 junction (EK1122); on its port 3 (E-bus) 2 terminal, the end of that branch; on
// its port 1 the branch 3 -> 4 (ends at 4); on its port 2 the ring goes on: 5 -> 6, whose port 1
// is cabled to the secondary port. The ring: 0, 1, 5, 6; the branches: 2 and 3, 4.
std::vector<RingPortReading> junction_ring() {
  const std::vector<std::vector<std::size_t>> linked{{0, 1}, {0, 3, 1, 2}, {0},   {0, 1},
                                                     {0},    {0, 1},       {0, 1}};
  std::vector<RingPortReading> out;
  for (std::size_t i = 0; i < linked.size(); ++i) {
    wire::DlStatus dl;
    for (std::size_t p = 0; p < 4; ++p)
      dl.ports[p].loop_closed = true;
    for (const std::size_t p : linked[i]) {
      dl.ports[p].physical_link = true;
      dl.ports[p].communication = true;
      dl.ports[p].loop_closed = false;
    }
    out.push_back({static_cast<std::uint16_t>(0x1001 + i), dl});
  }
  return out;
}

RingTree shape_of(const std::vector<RingPortReading>& r) {
  std::vector<std::uint16_t> dl;
  std::vector<std::uint16_t> stations;
  for (const auto& s : r) {
    dl.push_back(s.dl_status->encode());
    stations.push_back(s.station);
  }
  auto tree = ring_tree(dl, stations, true);
  EXPECT_TRUE(tree) << tree.error().describe();
  return tree ? *tree : RingTree{};
}

TEST(RingBreak, TheJunctionRingsShape) {
  const RingTree t = shape_of(junction_ring());
  ASSERT_EQ(t.slaves.size(), 7u);
  EXPECT_EQ(t.slaves[2].parent, 1u);
  EXPECT_EQ(t.slaves[2].parent_port, 3);
  EXPECT_EQ(t.slaves[3].parent, 1u);
  EXPECT_EQ(t.slaves[3].parent_port, 1);
  EXPECT_EQ(t.slaves[4].parent, 3u);
  EXPECT_EQ(t.slaves[5].parent, 1u);
  EXPECT_EQ(t.slaves[5].parent_port, 2);
  EXPECT_EQ(t.return_port, 1);
  // Without the cable back to the master, the last slave's open port 1 is an error.
  std::vector<std::uint16_t> dl;
  for (const auto& s : junction_ring())
    dl.push_back(s.dl_status->encode());
  auto line = ring_tree(dl, {}, false);
  ASSERT_FALSE(line);
  EXPECT_NE(line.error().message().find("slave 6 (station 0x0000) has port 1 open"),
            std::string::npos)
      << line.error().describe();
}

TEST(RingBreak, OnTheShapeAWholeJunctionRingHasNoneWhereTheLineRuleSeesOne) {
  const auto r = junction_ring();
  const RingTree t = shape_of(r);
  EXPECT_FALSE(locate_ring_break(r, t));
  // As a line, the branch ends (slave 2's and 4's port 1 without link) look like breaks.
  EXPECT_TRUE(locate_ring_break(r));
}

TEST(RingBreak, OnTheShapeTheJunctionsRingPortAndTheCableBehindIt) {
  const RingTree t = shape_of(junction_ring());
  // The junction's port 2 (the ring goes on there), from either end.
  for (const bool junction_end : {true, false}) {
    auto r = junction_ring();
    if (junction_end) {
      lose(r, 1, 2);
    } else {
      lose(r, 5, 0);
    }
    const auto b = locate_ring_break(r, t);
    ASSERT_TRUE(b) << junction_end;
    EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 1, 0x1002, 5, 0x1006, 2, 0}));
    EXPECT_EQ(link::describe(*b),
              "between slave 1 (station 0x1002, port 2) and slave 5 (station 0x1006, port 0)");
  }
  // Behind the junction, between 5 and 6: a line cable.
  auto r = junction_ring();
  lose(r, 5, 1);
  lose(r, 6, 0);
  auto b = locate_ring_break(r, t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 5, 0x1006, 6, 0x1007}));
  // The secondary's cable and the primary's.
  r = junction_ring();
  lose(r, 6, 1);
  b = locate_ring_break(r, t);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->where, Where::secondary_cable);
  EXPECT_EQ(b->before_position, 6u);
  EXPECT_EQ(b->before_port, 1);
  r = junction_ring();
  lose(r, 0, 0);
  b = locate_ring_break(r, t);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->where, Where::primary_cable);
  EXPECT_EQ(b->before_port, 0);
}

TEST(RingBreak, OnTheShapeABranchNeitherBreaksTheRingNorHidesItsBreak) {
  const RingTree t = shape_of(junction_ring());
  // The branch 3 -> 4 lost its cable inside (and the junction's port 3 its terminal): the ring
  // is whole.
  auto r = junction_ring();
  lose(r, 3, 1);
  lose(r, 4, 0);
  lose(r, 1, 3);
  EXPECT_FALSE(locate_ring_break(r, t));
  // Slaves on the branches silent (cut off), the ring broken behind the junction: found.
  r = junction_ring();
  r[2].dl_status.reset();
  r[3].dl_status.reset();
  r[4].dl_status.reset();
  lose(r, 5, 1);
  const auto b = locate_ring_break(r, t);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->before_position, 5u);
  EXPECT_EQ(b->after_position, 6u);
  // A slave on the ring silent before the break: not located.
  r[1].dl_status.reset();
  EXPECT_FALSE(locate_ring_break(r, t));
  // A shape of another ring: none.
  const auto whole = junction_ring();
  EXPECT_FALSE(locate_ring_break(std::span(whole).first(5), t));
}

// The control endpoint's status document on a redundant link (detail::redundancy_json).
TEST(RingBreak, StatusJson) {
  link::RedundancyStatus r;
  r.ring = link::RingState::broken;
  r.primary.name = "eth0";
  r.secondary.name = "eth1";
  r.secondary.healthy = false;
  r.ring_breaks = 2;
  auto j = detail::redundancy_json(r);
  EXPECT_EQ(j["topology"], "redundant");
  EXPECT_EQ(j["ring"], "broken");
  EXPECT_EQ(j["primary"]["name"], "eth0");
  EXPECT_EQ(j["secondary"]["healthy"], false);
  EXPECT_EQ(j["ring_breaks"], 2);
  EXPECT_TRUE(j["break"].is_null());
  r.break_location = link::RingBreak{Where::between_slaves, 1, 0x1002, 2, 0x1003};
  j = detail::redundancy_json(r);
  EXPECT_EQ(j["break"]["where"], "between_slaves");
  EXPECT_EQ(j["break"]["before"]["position"], 1);
  EXPECT_EQ(j["break"]["after"]["station"], 0x1003);
  EXPECT_EQ(j["break"]["before"]["port"], 1);
  EXPECT_EQ(j["break"]["after"]["port"], 0);
  EXPECT_EQ(j["break"]["text"], "between slave 1 (station 0x1002) and slave 2 (station 0x1003)");
}

}  // namespace
}  // namespace ecat::master
