// Where a redundant ring is open, from the slaves' DL status (master/ring_break.hpp).
#include <array>
#include <optional>
#include <random>
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

// ---- the shape of a ring broken since start (broken_ring_tree) ---------------------------------

std::vector<std::uint16_t> raw(const std::vector<RingPortReading>& r) {
  std::vector<std::uint16_t> out;
  for (const auto& s : r)
    out.push_back(s.dl_status->encode());
  return out;
}

std::vector<std::uint16_t> stations_of(const std::vector<RingPortReading>& r) {
  std::vector<std::uint16_t> out;
  for (const auto& s : r)
    out.push_back(s.station);
  return out;
}

using Ports = std::vector<std::optional<wire::PortDescriptor>>;

wire::PortDescriptor ports_0_to(std::size_t count) {
  wire::PortDescriptor d;
  for (std::size_t p = 0; p < count; ++p)
    d.ports[p] = wire::PortType::ebus;
  return d;
}

// The junction ring's ports: the junction has four, slave 4 (the branch's end) `end_ports`, the
// others two.
Ports junction_ports(std::size_t end_ports = 2) {
  Ports out(7, ports_0_to(2));
  out[1] = ports_0_to(4);
  out[4] = ports_0_to(end_ports);
  return out;
}

Result<RingTree> broken_shape(const std::vector<RingPortReading>& r, const Ports& ports,
                              std::size_t primary_side) {
  const auto dl = raw(r);
  const auto stations = stations_of(r);
  return broken_ring_tree(dl, ports, stations, primary_side);
}

void expect_same_tree(const RingTree& got, const RingTree& want) {
  ASSERT_EQ(got.slaves.size(), want.slaves.size());
  for (std::size_t i = 0; i < got.slaves.size(); ++i) {
    EXPECT_EQ(got.slaves[i].parent, want.slaves[i].parent) << "slave " << i;
    EXPECT_EQ(got.slaves[i].parent_port, want.slaves[i].parent_port) << "slave " << i;
    EXPECT_EQ(got.slaves[i].children, want.slaves[i].children) << "slave " << i;
  }
  EXPECT_EQ(got.return_port, want.return_port);
}

TEST(RingBreak, ABrokenLineRingsShapeIsTheWholeOnes) {
  const RingTree whole = shape_of(whole_ring());
  const Ports ports(4, ports_0_to(2));
  for (std::size_t after = 1; after < 4; ++after) {
    SCOPED_TRACE(after);
    auto r = whole_ring();
    lose(r, after - 1, 1);
    lose(r, after, 0);
    const auto t = broken_shape(r, ports, after);
    ASSERT_TRUE(t) << t.error().describe();
    expect_same_tree(*t, whole);
    const auto b = locate_ring_break(r, *t);
    ASSERT_TRUE(b);
    EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, after - 1,
                                   static_cast<std::uint16_t>(0x1001 + after - 1), after,
                                   static_cast<std::uint16_t>(0x1001 + after), 1, 0}));
  }
}

TEST(RingBreak, ABrokenJunctionRingsShapeInTheMainLineAndBehindTheJunction) {
  const RingTree whole = shape_of(junction_ring());
  // In front of the junction, between 0 and 1: the coupler's port 1 is its only free one.
  auto r = junction_ring();
  lose(r, 0, 1);
  lose(r, 1, 0);
  auto t = broken_shape(r, junction_ports(), 1);
  ASSERT_TRUE(t) << t.error().describe();
  expect_same_tree(*t, whole);
  // Behind it, between 5 and 6: the line rule takes the terminal's end (slave 2's port 1) for
  // the break; on the shape it is 5's port 1 (the junction's ports are all used by then).
  r = junction_ring();
  lose(r, 5, 1);
  lose(r, 6, 0);
  t = broken_shape(r, junction_ports(), 6);
  ASSERT_TRUE(t) << t.error().describe();
  expect_same_tree(*t, whole);
  const auto line = locate_ring_break(r);
  ASSERT_TRUE(line);
  EXPECT_EQ(line->before_position, 2u);
  auto b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 5, 0x1006, 6, 0x1007, 1, 0}));
  // The break moves while the ring was never whole (to the junction's ring port): the shape
  // still names it.
  r = junction_ring();
  lose(r, 1, 2);
  lose(r, 5, 0);
  b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 1, 0x1002, 5, 0x1006, 2, 0}));
}

TEST(RingBreak, ABrokenJunctionRingsShapeAtTheJunctionsRingPortBehindABranch) {
  // At the junction's port 2, right behind the branch 3 -> 4: slave 5 may hang on the
  // junction's port 2 or on the branch's end (4's port 1); nothing tells which.
  auto r = junction_ring();
  lose(r, 1, 2);
  lose(r, 5, 0);
  auto t = broken_shape(r, junction_ports(), 5);
  ASSERT_FALSE(t);
  EXPECT_EQ(t.error().code(), Errc::not_found);
  EXPECT_NE(t.error().message().find("slave 4 (station 0x1005)'s port 1, slave 1 (station "
                                     "0x1002)'s port 2"),
            std::string::npos)
      << t.error().describe();
  // Without the port descriptors, every free port could be.
  EXPECT_FALSE(broken_shape(r, {}, 5));
  // The branch's end has no port 1: the junction's port 2 it is.
  t = broken_shape(r, junction_ports(1), 5);
  ASSERT_TRUE(t) << t.error().describe();
  expect_same_tree(*t, shape_of(junction_ring()));
  const auto b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 1, 0x1002, 5, 0x1006, 2, 0}));
}

TEST(RingBreak, ABrokenJunctionRingsShapeWithABranchCutInside) {
  // The branch 3 -> 4 lost its cable inside (4 is gone from the ring: 5 and 6 are now 4 and 5)
  // and the ring is broken behind the junction: 3's free port 1 is off the way to the break.
  auto r = junction_ring();
  lose(r, 3, 1);
  lose(r, 5, 1);
  lose(r, 6, 0);
  r.erase(r.begin() + 4);
  Ports ports = junction_ports();
  ports.erase(ports.begin() + 4);
  const auto t = broken_shape(r, ports, 5);
  ASSERT_TRUE(t) << t.error().describe();
  EXPECT_EQ(t->slaves[3].parent, 1u);
  EXPECT_EQ(t->slaves[3].parent_port, 1);
  EXPECT_EQ(t->slaves[3].children, (std::array<std::optional<std::size_t>, 4>{}));
  EXPECT_EQ(t->slaves[4].parent, 1u);
  EXPECT_EQ(t->slaves[4].parent_port, 2);
  EXPECT_EQ(t->slaves[5].parent, 4u);
  EXPECT_EQ(t->slaves[5].parent_port, 1);
  EXPECT_EQ(t->return_port, 1);
  const auto b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::between_slaves, 4, 0x1006, 5, 0x1007, 1, 0}));
}

TEST(RingBreak, ABrokenJunctionRingsShapeAtEitherMasterCable) {
  const RingTree whole = shape_of(junction_ring());
  // The primary's cable: everything on the secondary's side, from slave 0.
  auto r = junction_ring();
  lose(r, 0, 0);
  auto t = broken_shape(r, junction_ports(), 0);
  ASSERT_TRUE(t) << t.error().describe();
  expect_same_tree(*t, whole);
  auto b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(b->where, Where::primary_cable);
  // The secondary's: the last slave's only free port.
  r = junction_ring();
  lose(r, 6, 1);
  t = broken_shape(r, junction_ports(), 7);
  ASSERT_TRUE(t) << t.error().describe();
  expect_same_tree(*t, whole);
  b = locate_ring_break(r, *t);
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (link::RingBreak{Where::secondary_cable, 6, 0x1007, 6, 0x1007, 1, 0}));
  // ... and with a last slave of four ports, any of three.
  Ports four = junction_ports();
  four[6] = ports_0_to(4);
  EXPECT_FALSE(broken_shape(r, four, 7));
}

TEST(RingBreak, ABrokenPictureThatIsNoSuchRingHasNoShape) {
  const auto code = [](const Result<RingTree>& t) {
    return t ? std::optional<Errc>{} : std::optional<Errc>{t.error().code()};
  };
  auto r = junction_ring();
  lose(r, 5, 1);
  lose(r, 6, 0);
  // Counted on another side than the DL status shows.
  EXPECT_EQ(code(broken_shape(r, junction_ports(), 5)), Errc::malformed);
  EXPECT_EQ(code(broken_shape(r, junction_ports(), 7)), Errc::malformed);
  EXPECT_EQ(code(broken_shape(r, junction_ports(), 8)), Errc::invalid_argument);
  EXPECT_EQ(code(broken_shape({}, {}, 0)), Errc::invalid_argument);
  // One end of the cable still up: an open port with nothing behind it.
  r = junction_ring();
  lose(r, 6, 0);
  const auto one_end = broken_shape(r, junction_ports(), 6);
  EXPECT_EQ(code(one_end), Errc::malformed);
  // A whole ring is not a broken one.
  EXPECT_EQ(code(broken_shape(junction_ring(), junction_ports(), 7)), Errc::malformed);
  // Broken twice (the secondary's cable too): no way back to the secondary port.
  r = junction_ring();
  lose(r, 5, 1);
  lose(r, 6, 0);
  lose(r, 6, 1);
  const auto twice = broken_shape(r, junction_ports(), 6);
  ASSERT_FALSE(twice);
  EXPECT_NE(twice.error().message().find("no open port left for the cable back"), std::string::npos)
      << twice.error().describe();
  // Port descriptors that deny a port with a link are not believed: behind the junction then
  // every free port is a candidate.
  r = junction_ring();
  lose(r, 5, 1);
  lose(r, 6, 0);
  Ports lying = junction_ports();
  lying[1] = ports_0_to(2);  // the junction's ports 2 and 3 have links
  EXPECT_EQ(code(broken_shape(r, lying, 6)), Errc::not_found);
}

// Random rings through junctions (each slave with random ports, hung in frame order on a random
// free port of the way to the last slave), each broken at a random cable of the ring: a shape
// given is the true one and locates the true break; many are given. Random pictures of no ring:
// no crash, and a shape given is a tree in frame order.
TEST(RingBreak, ABrokenRingsShapeIsNeverAWrongOne) {
  std::mt19937 rng(16);
  const auto pick = [&](std::size_t n) {
    return std::uniform_int_distribution<std::size_t>(0, n - 1)(rng);
  };
  constexpr std::array<std::uint8_t, 3> kOrder{3, 1, 2};
  std::size_t given = 0;
  std::size_t tried = 0;
  for (int round = 0; round < 4000; ++round) {
    const std::size_t n = 1 + pick(10);
    Ports ports(n);
    for (auto& d : ports) {
      d = wire::PortDescriptor{};
      d->ports[0] = wire::PortType::ebus;
      for (std::uint8_t p = 1; p < 4; ++p)
        if (pick(3) != 0) d->ports[p] = pick(2) ? wire::PortType::ebus : wire::PortType::mii;
    }
    // The tree: slave k hangs on a free port (after the used ones) of a slave on the way from
    // 0 to k - 1.
    RingTree truth;
    truth.slaves.resize(n);
    std::vector<std::size_t> used(n, 0);  // ports used, as a position in kOrder + 1
    bool ok = true;
    for (std::size_t k = 1; k < n && ok; ++k) {
      std::vector<std::pair<std::size_t, std::uint8_t>> free;
      for (std::optional<std::size_t> s = k - 1; s; s = truth.slaves[*s].parent) {
        for (std::size_t o = used[*s]; o < kOrder.size(); ++o)
          if (ports[*s]->ports[kOrder[o]] != wire::PortType::not_implemented)
            free.emplace_back(*s, kOrder[o]);
      }
      if (free.empty()) {
        ok = false;
        break;
      }
      const auto [parent, port] = free[pick(free.size())];
      truth.slaves[k].parent = parent;
      truth.slaves[k].parent_port = port;
      truth.slaves[parent].children[port] = k;
      for (std::size_t o = 0; o < kOrder.size(); ++o)
        if (kOrder[o] == port) used[parent] = o + 1;
    }
    if (!ok) continue;
    std::vector<std::uint8_t> back;
    for (const auto p : kOrder)
      if (ports[n - 1]->ports[p] != wire::PortType::not_implemented) back.push_back(p);
    if (back.empty()) continue;
    truth.return_port = back[pick(back.size())];
    std::vector<RingPortReading> r(n);
    for (std::size_t i = 0; i < n; ++i) {
      r[i].station = static_cast<std::uint16_t>(0x1001 + i);
      wire::DlStatus dl;
      for (std::uint8_t p = 0; p < 4; ++p) {
        const bool up =
            p == 0 || truth.slaves[i].children[p] || (i == n - 1 && p == *truth.return_port);
        dl.ports[p].physical_link = up;
        dl.ports[p].communication = up;
        dl.ports[p].loop_closed = !up;
      }
      r[i].dl_status = dl;
    }
    // The ring's cables: the primary's (0), into each slave on the way to the last, the
    // secondary's (n).
    std::vector<std::size_t> cables{0, n};
    for (std::optional<std::size_t> s = n - 1; s && *s > 0; s = truth.slaves[*s].parent)
      cables.push_back(*s);
    const std::size_t cable = cables[pick(cables.size())];
    link::RingBreak expected;
    if (cable == 0) {
      lose(r, 0, 0);
      expected = {Where::primary_cable, 0, 0x1001, 0, 0x1001, 0, 0};
    } else if (cable == n) {
      lose(r, n - 1, *truth.return_port);
      const auto st = static_cast<std::uint16_t>(0x1001 + n - 1);
      expected = {Where::secondary_cable, n - 1, st, n - 1, st, *truth.return_port, 0};
    } else {
      const std::size_t parent = *truth.slaves[cable].parent;
      lose(r, parent, truth.slaves[cable].parent_port);
      lose(r, cable, 0);
      expected = {Where::between_slaves,
                  parent,
                  static_cast<std::uint16_t>(0x1001 + parent),
                  cable,
                  static_cast<std::uint16_t>(0x1001 + cable),
                  truth.slaves[cable].parent_port,
                  0};
    }
    ++tried;
    const auto t = broken_shape(r, ports, cable);
    if (!t) continue;
    ++given;
    SCOPED_TRACE(::testing::Message()
                 << "round " << round << ", " << n << " slaves, cable " << cable);
    expect_same_tree(*t, truth);
    EXPECT_EQ(locate_ring_break(r, *t), expected);
    if (HasFailure()) return;
  }
  EXPECT_GT(tried, 1000u);
  EXPECT_GT(given, tried / 4) << given << " of " << tried;

  for (int round = 0; round < 4000; ++round) {
    const std::size_t n = 1 + pick(8);
    std::vector<std::uint16_t> dl(n);
    Ports ports(n);
    for (std::size_t i = 0; i < n; ++i) {
      dl[i] = static_cast<std::uint16_t>(rng());
      if (pick(4) != 0) ports[i] = wire::PortDescriptor::decode(static_cast<std::uint8_t>(rng()));
    }
    const auto t = broken_ring_tree(dl, ports, {}, pick(n + 2));
    if (!t) continue;
    ASSERT_EQ(t->slaves.size(), n);
    for (std::size_t i = 1; i < n; ++i) {
      ASSERT_TRUE(t->slaves[i].parent);
      ASSERT_LT(*t->slaves[i].parent, i);
      EXPECT_EQ(t->slaves[*t->slaves[i].parent].children[t->slaves[i].parent_port], i);
    }
  }
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
