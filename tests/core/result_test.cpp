#include <string>

#include <gtest/gtest.h>

#include <ecat/result.hpp>

namespace ecat {
namespace {

Result<int> parse_positive(int v) {
  if (v <= 0) return Error(Errc::invalid_argument, "value " + std::to_string(v) + " is not positive");
  return v;
}

TEST(Result, HoldsValueOrError) {
  auto good = parse_positive(3);
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, 3);
  EXPECT_EQ(good.value_or(7), 3);

  auto bad = parse_positive(-1);
  ASSERT_FALSE(bad);
  EXPECT_EQ(bad.error().code(), Errc::invalid_argument);
  EXPECT_EQ(bad.error().message(), "value -1 is not positive");
  EXPECT_EQ(bad.value_or(7), 7);
}

TEST(Result, ContextChainsCauses) {
  Error inner(Errc::timeout, "no reply from station 0x1001");
  Error outer = inner.context("reading SII word 0x0008");
  EXPECT_EQ(outer.code(), Errc::timeout);
  ASSERT_NE(outer.cause(), nullptr);
  EXPECT_EQ(outer.cause()->message(), "no reply from station 0x1001");
  EXPECT_EQ(outer.describe(), "reading SII word 0x0008: no reply from station 0x1001");
  Error recoded = inner.context(Errc::mailbox_error, "SDO upload 0x1018:01");
  EXPECT_EQ(recoded.code(), Errc::mailbox_error);
}

TEST(Result, VoidResult) {
  Result<void> fine = ok();
  EXPECT_TRUE(fine.ok());
  Result<void> failed = Error(Errc::closed, "link closed");
  EXPECT_FALSE(failed.ok());
  EXPECT_EQ(failed.error().code(), Errc::closed);
}

TEST(Result, MisuseAborts) {
  auto bad = parse_positive(0);
  EXPECT_DEATH((void)bad.value(), "value\\(\\) called on an error Result: value 0 is not positive");
  auto good = parse_positive(1);
  EXPECT_DEATH((void)good.error(), "error\\(\\) called on a successful Result");
}

TEST(Errc, EveryCodeHasText) {
  for (int i = 0; i <= static_cast<int>(Errc::internal); ++i) {
    EXPECT_NE(to_string(static_cast<Errc>(i)), "unknown error") << i;
  }
}

}  // namespace
}  // namespace ecat
