// ViewOffset: the views of a stream out of step by a constant number of frames, re-paired.
#include <gtest/gtest.h>

#include <utility>
#include <vector>

#include "endo_stereo/core/view_offset.hpp"

namespace endo_stereo {
namespace {

// A stream whose right view is k frames late: pair i carries left frame i and right frame i - k
// (the frame numbers are the views' payload). What comes out must pair equal frame numbers.
std::vector<std::pair<int, int>> run(int k, int pairs, int offset) {
  ViewOffset<int> v(offset);
  std::vector<std::pair<int, int>> out;
  for (int i = 0; i < pairs; ++i) {
    int left = i, right = i - k;
    if (v.push(0.04 * i, left, right)) out.emplace_back(left, right);
  }
  return out;
}

TEST(ViewOffset, ZeroPassesEveryPairUnchanged) {
  const auto out = run(0, 5, 0);
  ASSERT_EQ(out.size(), 5u);
  for (int i = 0; i < 5; ++i) EXPECT_EQ(out[i], std::make_pair(i, i));
}

TEST(ViewOffset, RightViewLateIsRepairedFrameForFrame) {
  for (const int k : {1, 2}) {
    const auto out = run(k, 10, k);
    ASSERT_EQ(out.size(), size_t(10 - k)) << k;  // the first k pairs are held
    for (size_t i = 0; i < out.size(); ++i) {
      EXPECT_EQ(out[i].first, out[i].second) << "k " << k << ", output " << i;
      EXPECT_EQ(out[i].first, int(i)) << "left frames in order, none skipped";
    }
  }
}

TEST(ViewOffset, LeftViewLateIsRepairedFrameForFrame) {
  const auto out = run(-1, 10, -1);  // pair i: left frame i, right frame i + 1
  ASSERT_EQ(out.size(), 9u);
  for (size_t i = 0; i < out.size(); ++i) {
    EXPECT_EQ(out[i].first, out[i].second) << i;
    EXPECT_EQ(out[i].first, int(i) + 1);
  }
}

TEST(ViewOffset, TheWrongSignMakesItWorseAndIsNotHidden) {
  const auto out = run(1, 6, -1);  // right late by 1, compensated as if it were early
  ASSERT_EQ(out.size(), 5u);
  for (const auto& p : out) EXPECT_EQ(p.second - p.first, -2);  // now 2 frames apart
}

TEST(ViewOffset, TimeGoingBackStartsAgain) {
  ViewOffset<int> v(1);
  int l = 0, r = -1;
  EXPECT_FALSE(v.push(10.0, l, r));
  l = 1, r = 0;
  ASSERT_TRUE(v.push(10.04, l, r));
  EXPECT_EQ(l, 0);
  EXPECT_EQ(r, 0);
  // A looping bag: stamps back to 5 s. The held left frame 1 belongs to the old stretch.
  l = 100, r = 99;
  EXPECT_FALSE(v.push(5.0, l, r));
  l = 101, r = 100;
  ASSERT_TRUE(v.push(5.04, l, r));
  EXPECT_EQ(l, 100);
  EXPECT_EQ(r, 100);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
