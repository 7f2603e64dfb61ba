// The hot path's signal lookup (detail::SlaveHotPath::find_index, Slave::Impl::HotPath): a name
// compares as its length and its first and last eight bytes (the whole name up to 16 bytes) plus
// its middle beyond that, so names of every length, names that share a prefix or a suffix, and
// names that differ in one byte anywhere must each find their own signal and nothing else;
// duplicates keep the first.
#include <cstddef>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "master/slave_impl.hpp"

namespace ecat::master {
namespace {

using HotPath = detail::SlaveHotPath;

HotPath view_of(const std::vector<std::string>& names) {
  HotPath view;
  for (const auto& n : names) {
    Signal s;
    s.name = n;
    view.signals.push_back(s);
  }
  view.index_names();
  return view;
}

TEST(SlaveHotPathNames, EveryLengthAndEveryByteCounts) {
  std::vector<std::string> names;
  // Lengths 1..40, each a prefix of the next, and for each one a twin differing in one byte
  // (first, middle or last in turn).
  const std::string base = "abcdefghijklmnopqrstuvwxyz0123456789ABCDEFGH";
  for (std::size_t n = 1; n <= 40; ++n) {
    names.push_back(base.substr(0, n));
    std::string twin = base.substr(0, n);
    const std::size_t at = n % 3 == 0 ? 0 : n % 3 == 1 ? n / 2 : n - 1;
    twin[at] = '_';
    names.push_back(twin);
  }
  names.push_back("");  // an empty name is a name too
  const HotPath view = view_of(names);
  ASSERT_FALSE(view.signal_index.empty());
  for (std::size_t k = 0; k < names.size(); ++k) {
    EXPECT_EQ(view.find_index(names[k]), static_cast<std::ptrdiff_t>(k)) << '"' << names[k] << '"';
  }
  // Absent: one byte more or less, or one byte changed at each position of a long name.
  EXPECT_EQ(view.find_index(base.substr(0, 41)), -1);
  EXPECT_EQ(view.find_index("zz"), -1);
  const std::string long_name = base.substr(0, 30);
  for (std::size_t at = 0; at < long_name.size(); ++at) {
    std::string changed = long_name;
    changed[at] = '#';
    EXPECT_EQ(view.find_index(changed), -1) << at;
  }
  // A view string that is not NUL-terminated (a slice of a longer buffer) finds the same.
  const std::string buffer = names[20] + "trailing";
  EXPECT_EQ(view.find_index(std::string_view(buffer).substr(0, names[20].size())), 20);
}

TEST(SlaveHotPathNames, DuplicatesKeepTheFirstAndNoSignalsFindNothing) {
  const HotPath dup = view_of({"channel_1", "channel_2", "channel_1"});
  EXPECT_TRUE(dup.signal_index.empty()) << "a duplicate turns the table off";
  EXPECT_EQ(dup.find_index("channel_1"), 0);
  EXPECT_EQ(dup.find_index("channel_2"), 1);
  EXPECT_EQ(dup.find_index("channel_3"), -1);
  const HotPath none = view_of({});
  EXPECT_EQ(none.find_index("channel_1"), -1);
  EXPECT_EQ(none.find_index(""), -1);
}

}  // namespace
}  // namespace ecat::master
