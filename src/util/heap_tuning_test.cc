#include "util/heap_tuning.h"

#include <gtest/gtest.h>

namespace rolamos {
namespace {

TEST(TunablesWithHugePageHeap, AddsTheTunableAndKeepsTheUsersOthers) {
  EXPECT_EQ(TunablesWithHugePageHeap(""), "glibc.malloc.hugetlb=1");
  EXPECT_EQ(TunablesWithHugePageHeap("glibc.malloc.check=3"), "glibc.malloc.check=3:glibc.malloc.hugetlb=1");
  EXPECT_EQ(TunablesWithHugePageHeap("glibc.malloc.hugetlbx=2"), "glibc.malloc.hugetlbx=2:glibc.malloc.hugetlb=1");
}

TEST(TunablesWithHugePageHeap, LeavesAChoiceAlreadyMade) {
  // Also what stops the restarted program from restarting again.
  EXPECT_EQ(TunablesWithHugePageHeap("glibc.malloc.hugetlb=0"), std::nullopt);
  EXPECT_EQ(TunablesWithHugePageHeap("glibc.malloc.check=3:glibc.malloc.hugetlb=1"), std::nullopt);
  EXPECT_EQ(TunablesWithHugePageHeap(*TunablesWithHugePageHeap("glibc.mem.tagging=0")), std::nullopt);
}

TEST(HugePagesOnRequest, OnlyTheMadviseMode) {
  EXPECT_TRUE(HugePagesOnRequest("always [madvise] never"));
  EXPECT_FALSE(HugePagesOnRequest("[always] madvise never"));
  EXPECT_FALSE(HugePagesOnRequest("always madvise [never]"));
  EXPECT_FALSE(HugePagesOnRequest(""));
}

}  // namespace
}  // namespace rolamos
