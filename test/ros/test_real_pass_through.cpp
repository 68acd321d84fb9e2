// rostest (test/ros/real_pass_through.test): real rectified endoscope frames at 25 Hz through a
// pass_through nodelet, with exact and with approximate sync: every image is counted once, every
// pair is formed, none is rejected (out of order or otherwise), and the outputs come in order.
// Skipped, with a message saying so, when ../shared/data is absent (a clean clone).
#include <sys/stat.h>

#include <algorithm>
#include <climits>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <cv_bridge/cv_bridge.h>
#include <opencv2/imgcodecs.hpp>
#include <ros/ros.h>
#include <stereo_msgs/DisparityImage.h>

#include "ros_test_utils.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
using DiagArray = diagnostic_msgs::DiagnosticArray;

std::string dataDir() {
  const std::string dir = std::string(ES_SHARED_DATA) + "/real/hamlyn_invivo1";
  char real[PATH_MAX];
  return realpath(dir.c_str(), real) ? std::string(real) : dir;
}

struct Frames {
  std::vector<cv::Mat> left, right;
};

const Frames& frames() {
  static Frames* f = [] {
    auto* fr = new Frames;
    for (int i = 1; i <= 150; ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "/%04d.png", i);
      cv::Mat l = cv::imread(dataDir() + "/left" + name, cv::IMREAD_COLOR);
      cv::Mat r = cv::imread(dataDir() + "/right" + name, cv::IMREAD_COLOR);
      if (l.empty() || r.empty()) break;
      fr->left.push_back(l);
      fr->right.push_back(r);
    }
    return fr;
  }();
  return *f;
}

void streamAndCheck(const std::string& ns) {
  const Frames& f = frames();
  if (f.left.empty()) {
    GTEST_SKIP() << "absent: real data " << dataDir()
                 << " (../shared/data beside the repository); nothing measured";
  }
  ros::NodeHandle nh;
  const int n = static_cast<int>(f.left.size());
  ros::Publisher left = nh.advertise<sensor_msgs::Image>(ns + "/left/image_rect", 20);
  ros::Publisher right = nh.advertise<sensor_msgs::Image>(ns + "/right/image_rect", 20);
  Collector<stereo_msgs::DisparityImage> disparities(nh, ns + "/disparity", 1000);
  Collector<DiagArray> diag(nh, "/diagnostics", 1000);
  ASSERT_TRUE(waitUntil([&] { return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0; },
                        20.0));
  const ros::Time t0(1700000000, 0);
  std::vector<ros::Time> stamps;
  ros::WallTime next = ros::WallTime::now();
  for (int i = 0; i < n; ++i) {
    const ros::Time t = t0 + ros::Duration(0.04 * i);
    stamps.push_back(t);
    left.publish(test::imageMsg(f.left[i], "bgr8", t, "left_rect"));
    right.publish(test::imageMsg(f.right[i], "bgr8", t, "left_rect"));
    next += ros::WallDuration(0.04);  // 25 Hz on the wall clock, whatever publishing costs
    const ros::WallDuration wait = next - ros::WallTime::now();
    if (wait > ros::WallDuration(0)) wait.sleep();
  }
  std::map<std::string, std::string> kv;
  const bool settled = static_cast<bool>(diag.waitFor([&](const DiagArray& a) {
    kv = test::statusValues(a, ns + "/reconstruction");
    const double rec = test::numberOr(kv, "pairs received", -1);
    return test::numberOr(kv, "left images", 0) >= n && test::numberOr(kv, "right images", 0) >= n &&
           test::numberOr(kv, "pairs waiting", -1) == 0 &&
           rec == test::numberOr(kv, "pairs processed", 0) + test::numberOr(kv, "pairs dropped", 0) +
                      test::numberOr(kv, "pairs rejected", 0);
  }, 60.0));
  waitUntil([&] {
    return static_cast<double>(disparities.count()) >= test::numberOr(kv, "pairs processed", 0);
  }, 10.0);
  std::printf("[ INFO     ] %s: %d real pairs (360x288, 0..127) sent at 25 Hz: %g left and %g right "
              "images counted, %g pairs formed, %g processed, %g dropped (overload), %g rejected; "
              "pipeline median %g ms, latency median %g ms\n",
              ns.c_str(), n, test::numberOr(kv, "left images", -1),
              test::numberOr(kv, "right images", -1), test::numberOr(kv, "pairs received", -1),
              test::numberOr(kv, "pairs processed", -1), test::numberOr(kv, "pairs dropped", -1),
              test::numberOr(kv, "pairs rejected", -1),
              test::numberOr(kv, "pipeline median (ms)", -1),
              test::numberOr(kv, "latency median (ms)", -1));
  ASSERT_TRUE(settled) << "the stream was not accounted for within 60 s";
  EXPECT_EQ(test::numberOr(kv, "left images", -1), n);
  EXPECT_EQ(test::numberOr(kv, "right images", -1), n) << "right images counted more than once";
  EXPECT_EQ(test::numberOr(kv, "pairs received", -1), n);
  EXPECT_EQ(test::numberOr(kv, "pairs rejected", -1), 0)
      << "last error: " << (kv.count("last error") ? kv.at("last error") : std::string());
  // Outputs in order, each the stamp of a pair sent.
  ros::Time prev;
  for (const auto& d : disparities.all()) {
    EXPECT_GT(d->header.stamp, prev);
    EXPECT_TRUE(std::binary_search(stamps.begin(), stamps.end(), d->header.stamp));
    prev = d->header.stamp;
  }
  const double processed = test::numberOr(kv, "pairs processed", -1);
  EXPECT_GE(processed, test::minimumProcessed(n, 40.0, kv, 0.75));
  EXPECT_EQ(static_cast<double>(disparities.count()), processed)
      << "a processed pair whose disparity never arrived";
  // Each output holds a surface, not a few specks: the default preset outputs about 45% of the
  // in-vivo frames' pixels on average (BENCHMARKS.md); the fewest in one output measured here
  // was 31.2% (printed below). A quarter is below every output of that run and far above a node
  // that outputs specks.
  double least = 1.0;
  for (const auto& d : disparities.all()) {
    const cv::Mat img = cv_bridge::toCvCopy(d->image)->image;
    const double valid = cv::countNonZero(img >= d->min_disparity) / double(img.total());
    least = std::min(least, valid);
    EXPECT_GE(valid, 0.25) << "output " << d->header.stamp << " holds " << 100 * valid << "% valid";
  }
  std::printf("[ INFO     ] %s: fewest valid pixels in an output: %.1f%%\n", ns.c_str(),
              100 * least);
}

TEST(RealPassThrough, ExactSync) { streamAndCheck("/real_exact"); }

TEST(RealPassThrough, ApproximateSync) { streamAndCheck("/real_approx"); }

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_real_pass_through");
}
