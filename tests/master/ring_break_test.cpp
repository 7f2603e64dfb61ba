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
  EXPECT_EQ(j["break"]["text"], "between slave 1 (station 0x1002) and slave 2 (station 0x1003)");
}

}  // namespace
}  // namespace ecat::master
