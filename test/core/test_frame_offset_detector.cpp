// FrameOffsetDetector on generated stereo video (the synthetic surgical scene, 320x240, its
// breathing, heartbeat, drifting endoscope and moving instrument) and, when present, the real
// in-vivo frames: a right view planted one frame late is found (+1), one frame early (-1); a
// stream in step gives 0; a still scene with live cameras (fresh noise on every frame) gives no
// verdict at all.
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "endo_stereo/core/frame_offset_detector.hpp"
#include "frame_sequences.hpp"

namespace endo_stereo {
namespace {

using Frames = test::FramePairs;

/// 40 consecutive frames of the generated surgical scene at 320x240 (16..79 px), with its noise.
const Frames& generated() {
  static const Frames* f = new Frames(test::generatedSurgicalFrames(40));
  return *f;
}

std::string realDir() { return test::invivoDir(ES_SHARED_DATA); }

/// The real rectified in-vivo pairs (360x288, 0..127), empty when absent.
const Frames& realFrames() {
  static const Frames* f = new Frames(test::invivoFrames(ES_SHARED_DATA, 60));
  return *f;
}

/// Streams @p f with the right view @p late frames late (right(t) = the image taken at t-late)
/// into @p d at 25 Hz until a verdict or the frames run out. @return the pairs it took (-1: none).
int stream(FrameOffsetDetector& d, const Frames& f, int late) {
  const int n = static_cast<int>(f.left.size());
  for (int t = std::max(0, late), k = 0; t < n && t - late < n; ++t, ++k) {
    if (d.update(f.left[static_cast<size_t>(t)], f.right[static_cast<size_t>(t - late)], k * 0.04)) {
      return k + 1;
    }
  }
  return -1;
}

std::string costs(const FrameOffsetDetector& d) {
  std::string s;
  for (double c : d.lastCosts()) s += " " + std::to_string(c);
  return s;
}

void expectOffset(const Frames& f, int late, const char* what) {
  FrameOffsetDetector d(16, 79);
  const int took = stream(d, f, late);
  ASSERT_GT(took, 0) << what << ": no verdict; " << d.describe() << "; costs" << costs(d);
  EXPECT_EQ(d.offset(), late) << what << ": " << d.describe() << "; costs" << costs(d);
  std::printf("[ INFO     ] %s, right view %+d frame(s) late: verdict %+d after %d pairs (%s); "
              "last costs (offsets -1, 0, +1)%s\n",
              what, late, d.offset(), took, d.describe().c_str(), costs(d).c_str());
}

TEST(FrameOffsetDetector, GeneratedRightViewOneFrameLateIsPlusOne) {
  expectOffset(generated(), 1, "generated");
}

TEST(FrameOffsetDetector, GeneratedRightViewOneFrameEarlyIsMinusOne) {
  expectOffset(generated(), -1, "generated");
}

TEST(FrameOffsetDetector, GeneratedStreamInStepIsZero) { expectOffset(generated(), 0, "generated"); }

TEST(FrameOffsetDetector, StillSceneWithLiveCamerasGivesNoVerdict) {
  // One generated pair held still, fresh Gaussian noise of 1.5 grey levels on each frame (the
  // scene's own sensor noise): the three right images differ by noise only.
  const Frames& g = generated();
  FrameOffsetDetector d(16, 79);
  cv::RNG rng(7);
  auto noisy = [&](const cv::Mat& m) {
    cv::Mat n(m.size(), CV_16SC3), s, out;
    rng.fill(n, cv::RNG::NORMAL, 0, 1.5);
    m.convertTo(s, CV_16SC3);
    cv::Mat(s + n).convertTo(out, CV_8UC3);
    return out;
  };
  double worst_gap = 0.0;
  for (int k = 0; k < 300; ++k) {
    EXPECT_FALSE(d.update(noisy(g.left[0]), noisy(g.right[0]), k * 0.04))
        << "a verdict on a still scene at pair " << k << ": " << d.describe();
    const auto& c = d.lastCosts();
    if (c.size() == 3) {
      const double lo = std::min({c[0], c[1], c[2]}), hi = std::max({c[0], c[1], c[2]});
      worst_gap = std::max(worst_gap, hi / lo - 1.0);
    }
  }
  EXPECT_FALSE(d.verdictKnown());
  EXPECT_GE(d.undecidedChecks(), 2) << "300 pairs span the start check and a periodic one";
  // The largest relative spread of the three costs: what clear_margin (0.15) must stay above.
  EXPECT_LT(worst_gap, 0.05);
  std::printf("[ INFO     ] still scene, 300 pairs: no verdict (%s); largest spread of the three "
              "costs %.1f %%\n", d.describe().c_str(), 100.0 * worst_gap);
}

TEST(FrameOffsetDetector, RestartForgetsTheVerdictAndChecksAgain) {
  FrameOffsetDetector d(16, 79);
  ASSERT_GT(stream(d, generated(), 1), 0);
  ASSERT_EQ(d.offset(), 1);
  d.restart();
  EXPECT_FALSE(d.verdictKnown());
  EXPECT_TRUE(d.checking());
  ASSERT_GT(stream(d, generated(), 0), 0);
  EXPECT_EQ(d.offset(), 0);
}

TEST(FrameOffsetDetector, RealRightViewOneFrameLateIsPlusOne) {
  const Frames& f = realFrames();
  if (f.left.empty()) GTEST_SKIP() << "absent: real data " << realDir() << "; nothing measured";
  FrameOffsetDetector d(0, 127);
  const int took = stream(d, f, 1);
  ASSERT_GT(took, 0) << "no verdict; " << d.describe() << "; costs" << costs(d);
  EXPECT_EQ(d.offset(), 1) << d.describe();
  std::printf("[ INFO     ] real, right view 1 frame late: verdict %+d after %d pairs; costs%s\n",
              d.offset(), took, costs(d).c_str());
  FrameOffsetDetector in_step(0, 127);
  const int took0 = stream(in_step, f, 0);
  // In step: a verdict of 0, or none (the recording may move too little); never an offset.
  EXPECT_EQ(in_step.offset(), 0) << in_step.describe();
  std::printf("[ INFO     ] real, in step: %s after %d pairs; costs%s\n",
              in_step.describe().c_str(), took0, costs(in_step).c_str());
}

TEST(FrameOffsetDetector, RecheckKeepsTheVerdictUntilTheCheckGivesOne) {
  FrameOffsetDetector d(16, 79);
  ASSERT_GT(stream(d, generated(), 1), 0);
  d.recheck();
  EXPECT_TRUE(d.checking());
  EXPECT_EQ(d.offset(), 1) << "the verdict holds while the new check runs";
  ASSERT_GT(stream(d, generated(), 0), 0);
  EXPECT_EQ(d.offset(), 0);
}

TEST(FrameOffsetDetector, ParametersAreValidated) {
  FrameOffsetParams p;
  EXPECT_EQ(p.validate(), "");
  p.max_offset = 0;
  EXPECT_NE(p.validate().find("max_offset"), std::string::npos);
  EXPECT_THROW(FrameOffsetDetector(0, 63, p), std::invalid_argument);
  EXPECT_THROW(FrameOffsetDetector(10, 5), std::invalid_argument);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
