#include "input/load_shedding.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

TEST(LoadShedding, OnAtHalfTheBoundOffAtAQuarter) {
  LoadShedding s(12);
  EXPECT_FALSE(s.Update(0));
  EXPECT_FALSE(s.Update(5));
  EXPECT_TRUE(s.Update(6)) << "half of 12 waiting or in flight";
  // Between the marks it keeps what it does, either way.
  EXPECT_TRUE(s.Update(4));
  EXPECT_TRUE(s.Update(9));
  EXPECT_FALSE(s.Update(3)) << "a quarter of 12";
  EXPECT_FALSE(s.Update(5));
  EXPECT_TRUE(s.Update(12));
}

TEST(LoadShedding, SmallBoundsKeepTheMarksApart) {
  LoadShedding one(1);
  EXPECT_FALSE(one.Update(1));
  EXPECT_TRUE(one.Update(2));
  EXPECT_FALSE(one.Update(1));
  LoadShedding three(3);
  EXPECT_TRUE(three.Update(2));
  EXPECT_TRUE(three.Update(2));
  EXPECT_FALSE(three.Update(1));
}

}  // namespace
}  // namespace rolamos
