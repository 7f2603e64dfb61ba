// The identity check of a plugged hot-connect group before it is brought up
// (src/master/hot_connect_identity.hpp): every slave the group declares, each what it declares.
#include "master/hot_connect_identity.hpp"

#include <array>
#include <string>
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

}  // namespace
}  // namespace ecat::master
