// The identity check of a plugged hot-connect group before it is brought up
// (src/master/hot_connect_identity.hpp): every slave the group declares, each what it declares.
#include "master/hot_connect_identity.hpp"

#include <array>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace ecat::master {
namespace {

HotConnectGroup tool() {
  HotConnectGroup g;
  g.name = "tool";
  SlaveConfig out;
  out.name = "tool_out";
  out.vendor_id = 2;
  out.product_code = 0x0AF93052;
  SlaveConfig in;
  in.name = "tool_in";
  in.vendor_id = 2;
  in.product_code = 0x07113052;
  in.revision = 0x00110000;
  SlaveConfig any;
  any.name = "tool_any";  // declares nothing: whatever it is
  g.slaves = {out, in, any};
  return g;
}

std::vector<FoundIdentity> as_declared() {
  return {{2, 0x0AF93052, 0x00100000}, {2, 0x07113052, 0x00110000}, {0x99, 0x1234, 7}};
}

TEST(HotConnectIdentity, AGroupAsDeclaredPasses) {
  EXPECT_EQ(group_identity_mismatch(tool(), 3, as_declared()), std::nullopt);
  // More slaves behind it are not its business (another group, or refused on their own).
  auto more = as_declared();
  more.push_back({1, 1, 1});
  EXPECT_EQ(group_identity_mismatch(tool(), 3, more), std::nullopt);
}

TEST(HotConnectIdentity, ALaterSlaveThatDiffersIsNamedWithWhatDiffers) {
  auto found = as_declared();
  found[1].product_code = 0x0C823052;
  found[1].revision = 0x00120000;
  const auto why = group_identity_mismatch(tool(), 3, found);
  ASSERT_TRUE(why);
  EXPECT_EQ(*why,
            "group tool: slave tool_in at position 4: product code 0x07113052 declared, "
            "0x0c823052 found, revision 0x00110000 declared, 0x00120000 found");
  found = as_declared();
  found[1].vendor_id = 3;
  EXPECT_EQ(group_identity_mismatch(tool(), 3, found),
            "group tool: slave tool_in at position 4: vendor 0x00000002 declared, 0x00000003 "
            "found");
}

TEST(HotConnectIdentity, TheGroupsOwnIdentityAppliesToItsFirstSlave) {
  auto g = tool();
  g.product_code = 0x0AF93053;  // the group's own, over its first slave's entry
  const auto why = group_identity_mismatch(g, 0, as_declared());
  ASSERT_TRUE(why);
  EXPECT_NE(why->find("slave tool_out at position 0: product code 0x0af93053 declared"),
            std::string::npos)
      << *why;
}

TEST(HotConnectIdentity, AShortGroupNamesTheFirstMissingSlave) {
  const auto found = as_declared();
  const auto why = group_identity_mismatch(tool(), 5, std::span(found).first(1));
  EXPECT_EQ(why,
            "group tool: 1 of its 3 slaves in the ring from position 5: tool_in (position 6) "
            "is missing");
}

TEST(HotConnectIdentity, DecodesSiiWords8To13) {
  const std::array<std::uint8_t, 12> words{0x02, 0, 0, 0, 0x52, 0x30, 0x11, 0x07, 0, 0, 0x11, 0};
  const auto id = decode_found_identity(words);
  ASSERT_TRUE(id);
  EXPECT_EQ(id->vendor_id, 2u);
  EXPECT_EQ(id->product_code, 0x07113052u);
  EXPECT_EQ(id->revision, 0x00110000u);
  EXPECT_FALSE(decode_found_identity(std::span(words).first(11)));
}

// ---- place_at_start: a group plugged in front of fixed slaves when the session starts --------

constexpr FoundIdentity kCoupler{2, 0x044C2C52, 0};
constexpr FoundIdentity kInputs{2, 0x07113052, 0};
constexpr FoundIdentity kOutputs{2, 0x0AF93052, 0};
constexpr FoundIdentity kJunction{2, 0x04622C52, 0};

std::vector<SlaveConfig> fixed_named(std::initializer_list<const char*> names) {
  std::vector<SlaveConfig> out;
  for (const char* n : names) {
    SlaveConfig c;
    c.name = n;
    out.push_back(c);
  }
  return out;
}

HotConnectGroup two_slave_tool() {
  auto g = tool();
  g.slaves.pop_back();  // tool_out (EL2809), tool_in (EL1809)
  g.slaves[1].revision.reset();
  return g;
}

std::vector<StartSlave> ring_of(std::initializer_list<FoundIdentity> ids) {
  std::vector<StartSlave> out;
  for (const auto& id : ids)
    out.push_back({0, id});
  return out;
}

TEST(HotConnectPlacement, AGroupOnAJunctionShiftsTheFixedSlavesBehindIt) {
  // coupler, junction, [tool_out, tool_in], far_coupler, far_in: nothing declared by the fixed.
  const auto fixed = fixed_named({"coupler", "junction", "far_coupler", "far_in"});
  const std::vector<HotConnectGroup> groups{two_slave_tool()};
  const auto ring = ring_of({kCoupler, kJunction, kOutputs, kInputs, kCoupler, kInputs});
  const auto placed = place_at_start(fixed, groups, ring);
  ASSERT_TRUE(placed);
  EXPECT_EQ(placed->fixed, (std::vector<std::uint16_t>{0, 1, 4, 5}));
  ASSERT_EQ(placed->groups.size(), 1u);
  EXPECT_EQ(placed->groups[0], (std::pair<std::size_t, std::uint16_t>{0, 2}));
}

TEST(HotConnectPlacement, NothingInFrontMeansTheConfiguredPositions) {
  const std::vector<HotConnectGroup> groups{two_slave_tool()};
  // The group at the end of the line: the scan's, not the startup's.
  const auto fixed = fixed_named({"coupler", "inputs", "outputs"});
  EXPECT_FALSE(
      place_at_start(fixed, groups, ring_of({kCoupler, kInputs, kOutputs, kOutputs, kInputs})));
  // An EL2809 among the fixed slaves followed by something that is not tool_in is no group.
  EXPECT_FALSE(
      place_at_start(fixed_named({"coupler", "outputs", "x", "y"}), groups,
                     ring_of({kCoupler, kOutputs, kCoupler, kCoupler, kOutputs, kInputs})));
  // No room for the fixed slaves behind it: not the group.
  EXPECT_FALSE(place_at_start(fixed_named({"coupler", "a", "b"}), groups,
                              ring_of({kCoupler, kOutputs, kInputs, kCoupler})));
}

TEST(HotConnectPlacement, AFixedSlaveThatDeclaresItselfWinsItsPlace) {
  // far_out declares EL2809 and the group's head is an EL2809 too: the declared fixed slave is
  // matched first, the group then found behind it.
  auto fixed = fixed_named({"coupler", "far_out", "last"});
  fixed[1].vendor_id = kOutputs.vendor_id;
  fixed[1].product_code = kOutputs.product_code;
  const std::vector<HotConnectGroup> groups{two_slave_tool()};
  const auto placed =
      place_at_start(fixed, groups, ring_of({kCoupler, kOutputs, kOutputs, kInputs, kCoupler}));
  ASSERT_TRUE(placed);
  EXPECT_EQ(placed->fixed, (std::vector<std::uint16_t>{0, 1, 4}));
  EXPECT_EQ(placed->groups[0].second, 2);
  // By alias: the group's head carries it.
  auto by_alias = two_slave_tool();
  by_alias.alias = 0x0042;
  auto ring = ring_of({kCoupler, kOutputs, kInputs, kCoupler});
  EXPECT_FALSE(
      place_at_start(fixed_named({"coupler", "a"}), std::vector<HotConnectGroup>{by_alias}, ring));
  ring[1].alias = 0x0042;
  const auto aliased =
      place_at_start(fixed_named({"coupler", "a"}), std::vector<HotConnectGroup>{by_alias}, ring);
  ASSERT_TRUE(aliased);
  EXPECT_EQ(aliased->fixed, (std::vector<std::uint16_t>{0, 3}));
  // Positions of their own (counted without the groups) that are not the index: left alone.
  auto positioned = fixed_named({"coupler", "a"});
  positioned[1].position = 5;
  EXPECT_FALSE(place_at_start(positioned, std::vector<HotConnectGroup>{by_alias}, ring));
}

}  // namespace
}  // namespace ecat::master
