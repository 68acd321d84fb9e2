// rostest (test/ros/nodelet_synthetic.test, and nodelet_backlog.test for the Backlog tests): a
// real master, a nodelet manager and several endo_stereo/reconstruction nodelets, fed a synthetic
// calibrated surgical pair with exact ground truth. Every wait has a timeout; nothing relies on a
// fixed sleep.
//
// Namespaces (see the .test files): /stereo (exact sync), /approx (approximate sync),
// /bad (bad-input sequence), /tf and /tf_missing (target_frame with and without a transform);
// /backlog, /newest, /stale and /overload (the backlog between the callbacks and the processing
// thread, nodelet_backlog.test).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <dynamic_reconfigure/Reconfigure.h>
#include <gtest/gtest.h>
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <stereo_msgs/DisparityImage.h>
#include <opencv2/imgproc.hpp>
#include <tf2_ros/static_transform_broadcaster.h>

#include "endo_stereo/ros/conversions.hpp"
#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
using DiagArray = diagnostic_msgs::DiagnosticArray;

// The scene: test::calibratedScene() (ros_test_utils.hpp).
// Disparity search range of the .test file (matcher/min_disparity, matcher/max_disparity); the
// scene's suggested range must lie inside it (checked below).
constexpr int kMinDisparity = 16;
constexpr int kMaxDisparity = 79;

using Scene = test::CalibratedScene;
const Scene& scene() { return test::calibratedScene(); }

/// Publishers of one stereo namespace. camera_info is latched, so a lazily subscribing nodelet
/// gets the calibration however late it subscribes.
struct StereoPublisher {
  ros::Publisher left, right, left_info, right_info;
  std::string left_frame, right_frame;
  explicit StereoPublisher(const std::string& ns, uint32_t queue = 5) {
    ros::NodeHandle nh(ns);
    left = nh.advertise<sensor_msgs::Image>("left/image_raw", queue);
    right = nh.advertise<sensor_msgs::Image>("right/image_raw", queue);
    left_info = nh.advertise<sensor_msgs::CameraInfo>("left/camera_info", 1, true);
    right_info = nh.advertise<sensor_msgs::CameraInfo>("right/camera_info", 1, true);
  }
  void publishInfo(sensor_msgs::CameraInfo l, sensor_msgs::CameraInfo r, const ros::Time& t) {
    l.header.stamp = r.header.stamp = t;
    left_info.publish(l);
    right_info.publish(r);
  }
  void publishGoodInfo() {
    publishInfo(scene().left_info, scene().right_info, ros::Time::now());
  }
  void publishPair(const ros::Time& stamp, const ros::Time& right_stamp = ros::Time()) {
    const Scene& s = scene();
    left.publish(test::imageMsg(s.frame.left, "bgr8", stamp, s.left_info.header.frame_id));
    right.publish(test::imageMsg(s.frame.right, "bgr8", right_stamp.isZero() ? stamp : right_stamp,
                                 s.right_info.header.frame_id));
  }
  bool inputsSubscribed() const {
    return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0;
  }
};

/// Stamps that only grow, so the nodelet never sees an out-of-order pair unless a test wants it.
ros::Time nextStamp() {
  static ros::Time t(1700000000, 0);
  t += ros::Duration(0.04);
  return t;
}

/// Publish fresh pairs (every @p period_s) until @p done holds or @p timeout_s passes: robust to
/// the latency of a lazy subscription and to camera_info arriving after the first pair.
bool publishUntil(StereoPublisher& pub, const std::function<bool()>& done, double timeout_s,
                  ros::Time* last_stamp = nullptr, double period_s = 0.25) {
  return test::publishUntil(
      [&] {
        const ros::Time t = nextStamp();
        if (last_stamp) *last_stamp = t;
        pub.publishPair(t);
      },
      done, timeout_s, period_s);
}

float at(const stereo_msgs::DisparityImage& msg, int r, int c) {
  float v;
  std::memcpy(&v, msg.image.data.data() + r * msg.image.step + c * sizeof(float), sizeof(float));
  return v;
}

// ------------------------------------------------------------------------------------------------

TEST(LazySubscription, InputsSubscribedOnlyWhileSomeoneListens) {
  ros::NodeHandle nh;
  StereoPublisher pub("/stereo");
  // Nothing listens to /stereo's outputs yet: the nodelet must not subscribe its inputs. Absence
  // can only be observed for a while; 1.5 s is several connection round trips on a loaded machine.
  EXPECT_FALSE(waitUntil([&] { return pub.left.getNumSubscribers() > 0; }, 1.5))
      << "the nodelet subscribed to its inputs without any output subscriber";
  {
    Collector<stereo_msgs::DisparityImage> disparity(nh, "/stereo/disparity");
    EXPECT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0))
        << "no input subscription after a disparity subscriber appeared";
    EXPECT_TRUE(waitUntil([&] { return pub.left_info.getNumSubscribers() > 0; }, 10.0));
  }
  EXPECT_TRUE(waitUntil([&] { return pub.left.getNumSubscribers() == 0; }, 10.0))
      << "the inputs stayed subscribed after the last output subscriber left";
}

TEST(CalibratedPair, DisparityAndCloudMatchGroundTruth) {
  ros::NodeHandle nh;
  const Scene& s = scene();
  StereoPublisher pub("/stereo");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/stereo/disparity");
  Collector<sensor_msgs::PointCloud2> clouds(nh, "/stereo/points2");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  pub.publishGoodInfo();
  ros::Time stamp;
  ASSERT_TRUE(publishUntil(pub, [&] { return disparities.count() > 0 && clouds.count() > 0; },
                           60.0, &stamp, 1.0))
      << "no disparity and cloud within 60 s";
  // Use the first pair for which both outputs arrived.
  stereo_msgs::DisparityImage::ConstPtr d;
  sensor_msgs::PointCloud2::ConstPtr cloud;
  for (const auto& m : disparities.all()) {
    cloud = clouds.waitFor([&](const sensor_msgs::PointCloud2& c) {
      return c.header.stamp == m->header.stamp;
    }, 5.0);
    if (cloud) {
      d = m;
      break;
    }
  }
  ASSERT_TRUE(d && cloud);

  int suggested_min = 0, suggested_max = 0;
  s.scene->suggestedDisparityRange(&suggested_min, &suggested_max);
  EXPECT_GE(suggested_min, kMinDisparity) << "widen the range here and in the .test file";
  EXPECT_LE(suggested_max, kMaxDisparity) << "widen the range here and in the .test file";

  // --- Conventions (README, ROS usage: DisparityImage and PointCloud2).
  const cv::Matx34d& pl = s.scene->calibration().left.P;
  const cv::Matx34d& pr = s.scene->calibration().right.P;
  EXPECT_EQ(d->header.frame_id, s.left_info.header.frame_id);
  EXPECT_EQ(d->image.header.stamp, d->header.stamp);
  EXPECT_EQ(d->image.encoding, "32FC1");
  EXPECT_NEAR(d->f, pl(0, 0), 1e-3);
  EXPECT_NEAR(d->T, -pr(0, 3) / pr(0, 0), 1e-7);
  const double doffs = pl(0, 2) - pr(0, 2);
  EXPECT_FLOAT_EQ(d->min_disparity, static_cast<float>(kMinDisparity - doffs));
  EXPECT_FLOAT_EQ(d->max_disparity, static_cast<float>(kMaxDisparity - doffs));
  EXPECT_GT(d->delta_d, 0.0f);
  EXPECT_LE(d->delta_d, 1.0f);
  const int W = static_cast<int>(d->image.width), H = static_cast<int>(d->image.height);
  ASSERT_EQ(W, s.frame.gt_disparity.cols);
  ASSERT_EQ(H, s.frame.gt_disparity.rows);
  const auto& vw = d->valid_window;
  EXPECT_LE(vw.x_offset + vw.width, static_cast<uint32_t>(W));
  EXPECT_LE(vw.y_offset + vw.height, static_cast<uint32_t>(H));
  EXPECT_GT(vw.width, 0u);

  // --- Disparity against ground truth; invalid layout.
  int64_t valid = 0, bad2 = 0, invalid_marked = 0;
  std::vector<double> abs_err;  // |d - gt| of the non-bad2 pixels: the sub-pixel precision
  int x0 = W, y0 = H, x1 = -1, y1 = -1;
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const float v = at(*d, r, c);
      ASSERT_TRUE(std::isfinite(v)) << "NaN in the published disparity at " << r << "," << c;
      if (v < d->min_disparity) {
        EXPECT_FLOAT_EQ(v, d->min_disparity - 1.0f);
        ++invalid_marked;
        continue;
      }
      ++valid;
      x0 = std::min(x0, c), x1 = std::max(x1, c), y0 = std::min(y0, r), y1 = std::max(y1, r);
      const double gt = s.frame.gt_disparity.at<float>(r, c) - doffs;
      if (std::abs(v - gt) > 2.0) {
        ++bad2;
      } else {
        abs_err.push_back(std::abs(v - gt));
      }
    }
  }
  ASSERT_GT(valid, 0);
  EXPECT_EQ(vw.x_offset, static_cast<uint32_t>(x0));
  EXPECT_EQ(vw.y_offset, static_cast<uint32_t>(y0));
  EXPECT_EQ(vw.width, static_cast<uint32_t>(x1 - x0 + 1));
  EXPECT_EQ(vw.height, static_cast<uint32_t>(y1 - y0 + 1));
  const double density = double(valid) / (W * H);
  const double bad2_rate = double(bad2) / valid;
  std::printf("[ INFO     ] density %.3f, bad2 among valid %.4f (%ld of %ld)\n", density,
              bad2_rate, static_cast<long>(bad2), static_cast<long>(valid));
  EXPECT_LT(bad2_rate, 0.02) << "target: bad2 among valid pixels under 2%";
  {
    double sq = 0.0;
    for (double e : abs_err) sq += e * e;
    std::vector<double> sorted = abs_err;
    std::sort(sorted.begin(), sorted.end());
    const double rms = std::sqrt(sq / sorted.size());
    std::printf("[ INFO     ] |d - gt| of non-bad2 pixels: median %.3f, p90 %.3f, rms %.3f px; "
                "published delta_d %.3f\n", sorted[sorted.size() / 2],
                sorted[sorted.size() * 9 / 10], rms, d->delta_d);
    // delta_d claims the sub-pixel precision (ros_params.hpp); it must not overclaim by more
    // than a factor 2.
    EXPECT_LE(rms, 2.0 * d->delta_d);
  }
  // A density floor so that an output with almost nothing valid cannot pass the error test.
  EXPECT_GT(density, 0.3);

  // --- The cloud: organized, NaN exactly where the disparity is invalid, Z = f T / d, and
  // against the ground-truth depth.
  EXPECT_EQ(cloud->header.frame_id, s.left_info.header.frame_id);
  EXPECT_EQ(cloud->height, static_cast<uint32_t>(H));
  EXPECT_EQ(cloud->width, static_cast<uint32_t>(W));
  EXPECT_FALSE(cloud->is_dense);
  OrganizedCloud oc;
  std::string error;
  ASSERT_TRUE(ros_conv::fromPointCloud2(*cloud, oc, &error)) << error;
  std::vector<double> rel_err;
  int64_t good_disp_points = 0, good_disp_within_1pct = 0;
  for (int r = 0; r < H; ++r) {
    for (int c = 0; c < W; ++c) {
      const cv::Vec3f p = oc.xyz.at<cv::Vec3f>(r, c);
      const float v = at(*d, r, c);
      if (v < d->min_disparity) {
        EXPECT_TRUE(std::isnan(p[2])) << "point at an invalid pixel " << r << "," << c;
        continue;
      }
      if (!std::isfinite(p[2])) continue;  // d <= 0 has no depth
      EXPECT_NEAR(p[2], d->f * d->T / v, 1e-4 * p[2]) << r << "," << c;
      const double z_gt = s.frame.gt_depth_m.at<float>(r, c);
      const double e = std::abs(p[2] - z_gt) / z_gt;
      rel_err.push_back(e);
      const double gt = s.frame.gt_disparity.at<float>(r, c) - doffs;
      if (std::abs(v - gt) <= 2.0) {
        ++good_disp_points;
        if (e < 0.01) ++good_disp_within_1pct;
      }
    }
  }
  ASSERT_FALSE(rel_err.empty());
  std::sort(rel_err.begin(), rel_err.end());
  const double median_rel = rel_err[rel_err.size() / 2];
  const double p90_rel = rel_err[rel_err.size() * 9 / 10];
  const double share_1pct = double(good_disp_within_1pct) / std::max<int64_t>(1, good_disp_points);
  std::printf("[ INFO     ] depth: relative error median %.5f, p90 %.5f; share within 1%% "
              "(non-bad2) %.4f\n", median_rel, p90_rel, share_1pct);
  EXPECT_LT(median_rel, 0.01) << "target: cloud depths within 1%";
  EXPECT_GT(share_1pct, 0.95);
}

TEST(Reconfigure, ChangeTakesEffectOnTheNextFrame) {
  ros::NodeHandle nh;
  StereoPublisher pub("/stereo");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/stereo/disparity");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  pub.publishGoodInfo();
  ASSERT_TRUE(publishUntil(pub, [&] { return disparities.count() > 0; }, 30.0));
  EXPECT_FLOAT_EQ(disparities.all().back()->max_disparity, kMaxDisparity);

  auto reconfigure = [&](const std::string& name, int value, int* echoed) {
    dynamic_reconfigure::Reconfigure srv;
    dynamic_reconfigure::IntParameter p;
    p.name = name;
    p.value = value;
    srv.request.config.ints.push_back(p);
    if (!ros::service::waitForService("/stereo/reconstruction/set_parameters", 10000)) return false;
    if (!ros::service::call("/stereo/reconstruction/set_parameters", srv)) return false;
    for (const auto& i : srv.response.config.ints) {
      if (i.name == name) *echoed = i.value;
    }
    return true;
  };
  int echoed = -1;
  ASSERT_TRUE(reconfigure("matcher_max_disparity", 95, &echoed));
  EXPECT_EQ(echoed, 95);
  // The parameter server shows the value in use.
  int on_server = -1;
  EXPECT_TRUE(nh.getParam("/stereo/reconstruction/matcher/max_disparity", on_server));
  EXPECT_EQ(on_server, 95);
  // The call has returned: the very next pair published must be processed with the new range.
  disparities.clear();
  ros::Time t = nextStamp();
  pub.publishPair(t);
  auto next = disparities.waitFor(
      [&](const stereo_msgs::DisparityImage& m) { return m.header.stamp == t; }, 20.0);
  ASSERT_TRUE(next) << "no output for the pair after the reconfigure call";
  EXPECT_FLOAT_EQ(next->max_disparity, 95.0f);

  // An invalid request (an even window) is refused: the server reports the values in use and
  // the next frame still runs with them.
  ASSERT_TRUE(reconfigure("matcher_window_min_px", 8, &echoed));
  EXPECT_NE(echoed, 8);
  EXPECT_TRUE(nh.getParam("/stereo/reconstruction/matcher/window_min_px", on_server));
  EXPECT_NE(on_server, 8) << "a refused value reached the parameter server";
  t = nextStamp();
  pub.publishPair(t);
  next = disparities.waitFor(
      [&](const stereo_msgs::DisparityImage& m) { return m.header.stamp == t; }, 20.0);
  ASSERT_TRUE(next);
  EXPECT_FLOAT_EQ(next->max_disparity, 95.0f);

  ASSERT_TRUE(reconfigure("matcher_max_disparity", kMaxDisparity, &echoed));
}

TEST(CameraInfoAfterImages, APairWaitsForTheFirstCameraInfo) {
  // At start-up the image connections can come up before the camera_info ones (rosbag play):
  // the first pair then finds no calibration although it is on its way. It must wait for it
  // (~camera_info_wait_s, 2 s in the .test file) and be processed, not refused.
  ros::NodeHandle nh;
  StereoPublisher pub("/late_info");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/late_info/disparity");
  Collector<DiagArray> diag(nh, "/diagnostics");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  ASSERT_TRUE(waitUntil([&] { return pub.left_info.getNumSubscribers() > 0 &&
                                     pub.right_info.getNumSubscribers() > 0; }, 10.0));
  const ros::Time t = nextStamp();
  pub.publishPair(t);  // no camera_info has been published on /late_info yet
  ros::WallDuration(0.3).sleep();
  pub.publishGoodInfo();
  ASSERT_TRUE(waitUntil([&] { return disparities.count() > 0; }, 10.0))
      << "the pair published 0.3 s before the camera_info was not processed";
  EXPECT_EQ(disparities.all().front()->header.stamp, t);
  std::map<std::string, std::string> kv;
  ASSERT_TRUE(diag.waitFor([&](const DiagArray& a) {
    kv = test::statusValues(a, "/late_info/reconstruction");
    return test::numberOr(kv, "pairs processed", 0) >= 1;
  }, 10.0));
  EXPECT_EQ(test::numberOr(kv, "pairs rejected", -1), 0)
      << "last error: " << (kv.count("last error") ? kv.at("last error") : std::string());
}

TEST(ApproximateSync, PairsStampsWithinTheTolerance) {
  ros::NodeHandle nh;
  StereoPublisher pub("/approx");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/approx/disparity");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  pub.publishGoodInfo();
  // Right stamps 4 ms after the left ones (tolerance 10 ms in the .test file).
  std::vector<ros::Time> lefts;
  const bool got = test::publishUntil(
      [&] {
        const ros::Time t = nextStamp();
        lefts.push_back(t);
        pub.publishPair(t, t + ros::Duration(0.004));
      },
      [&] { return disparities.count() > 0; }, 30.0, 0.25);
  ASSERT_TRUE(got) << "approximate sync never paired stamps 4 ms apart";
  // Outputs carry the left image's stamp.
  const ros::Time out = disparities.all().front()->header.stamp;
  EXPECT_NE(std::find(lefts.begin(), lefts.end(), out), lefts.end());
}

TEST(ExactSync, OffsetStampsDoNotPairAndAreReported) {
  ros::NodeHandle nh;
  StereoPublisher pub("/stereo");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/stereo/disparity");
  Collector<DiagArray> diag(nh, "/diagnostics");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  disparities.clear();
  // unpaired_timeout_s is 0.3 s in the .test file: 1.5 s of offset pairs must be reported.
  for (int i = 0; i < 15; ++i) {
    const ros::Time t = nextStamp();
    pub.publishPair(t, t + ros::Duration(0.004));
    ros::WallDuration(0.1).sleep();  // pacing a stream, not waiting for a result
  }
  auto report = diag.waitFor([](const DiagArray& a) {
    const auto kv = test::statusValues(a, "/stereo/reconstruction");
    auto it = kv.find("last error");
    return it != kv.end() && it->second.find("do not pair") != std::string::npos;
  }, 5.0);
  EXPECT_TRUE(report) << "offset stamps under exact sync were not reported";
  EXPECT_EQ(disparities.count(), 0u);
}

// --- Overload: a burst of pairs arriving faster than they are processed (/backlog: up to 5
// pairs wait; /newest: only the newest waits; /stale: 5 may wait, but not for more than 1 ms;
// /overload: 5 may wait, and a flood follows a steady stream).

struct BurstOutcome {
  std::vector<ros::Time> stamps;       // the burst's stamps, in order
  std::vector<ros::Time> outputs;      // stamps of the burst's disparities, in arrival order
  double received = 0, processed = 0, dropped = 0;  // the burst's share of the counters
};

/// Gets one pair through @p ns, waits until the nodelet is idle, publishes @p n pairs back to
/// back, and waits until every one of them is accounted for (processed or dropped).
::testing::AssertionResult runBurst(const std::string& ns, int n, BurstOutcome* out) {
  ros::NodeHandle nh;
  StereoPublisher pub(ns);
  Collector<stereo_msgs::DisparityImage> disparities(nh, ns + "/disparity");
  Collector<DiagArray> diag(nh, "/diagnostics");
  const std::string node = ns + "/reconstruction";
  if (!waitUntil([&] { return pub.inputsSubscribed(); }, 10.0)) {
    return ::testing::AssertionFailure() << ns << ": inputs never subscribed";
  }
  pub.publishGoodInfo();
  if (!publishUntil(pub, [&] { return disparities.count() > 0; }, 30.0)) {
    return ::testing::AssertionFailure() << ns << ": no output for the first pairs";
  }
  // Idle: every pair received so far is accounted for and none waits.
  auto settled = [&](double extra_received, std::map<std::string, std::string>* kv_out) {
    return [=](const DiagArray& a) {
      const auto kv = test::statusValues(a, node);
      const double rec = test::numberOr(kv, "pairs received", -1);
      const double done = test::numberOr(kv, "pairs processed", 0) +
                          test::numberOr(kv, "pairs dropped", 0) +
                          test::numberOr(kv, "pairs rejected", 0);
      const bool ok = rec >= extra_received && rec == done &&
                      test::numberOr(kv, "pairs waiting", -1) == 0;
      if (ok && kv_out) *kv_out = kv;
      return ok;
    };
  };
  std::map<std::string, std::string> before, after;
  diag.clear();
  if (!diag.waitFor(settled(1, &before), 10.0)) {
    return ::testing::AssertionFailure() << ns << ": never idle before the burst";
  }
  disparities.clear();
  for (int i = 0; i < n; ++i) {
    out->stamps.push_back(nextStamp());
    pub.publishPair(out->stamps.back());
  }
  const double rec0 = test::numberOr(before, "pairs received", 0);
  diag.clear();
  if (!diag.waitFor(settled(rec0 + n, &after), 30.0)) {
    return ::testing::AssertionFailure() << ns << ": the burst was not accounted for in 30 s";
  }
  out->received = test::numberOr(after, "pairs received", 0) - rec0;
  out->processed = test::numberOr(after, "pairs processed", 0) -
                   test::numberOr(before, "pairs processed", 0);
  // The disparities travel on their own connection: wait for as many as were processed.
  waitUntil([&] { return static_cast<double>(disparities.count()) >= out->processed; }, 10.0);
  for (const auto& m : disparities.all()) out->outputs.push_back(m->header.stamp);
  out->dropped =
      test::numberOr(after, "pairs dropped", 0) - test::numberOr(before, "pairs dropped", 0);
  std::printf("[ INFO     ] %s: burst of %d: %g processed, %g dropped; pipeline median %g ms\n",
              ns.c_str(), n, out->processed, out->dropped,
              test::numberOr(after, "pipeline median (ms)", -1));
  return ::testing::AssertionSuccess();
}

// Within its first 10 pairs the node always catches a burst up (the start-up grace of the
// overload test), so this is the start-up stall's case.
TEST(Backlog, ABurstThatFitsTheBacklogIsProcessedWholeAndInOrder) {
  BurstOutcome b;
  ASSERT_TRUE(runBurst("/backlog", 5, &b));
  EXPECT_EQ(b.received, 5);
  EXPECT_EQ(b.dropped, 0);
  EXPECT_EQ(b.processed, 5);
  EXPECT_EQ(b.outputs, b.stamps);
}

/// A burst of 5 on @p ns of which some pairs were skipped for the newest: every pair accounted
/// for, at least one dropped, the last one processed and every processed one published.
void expectNewestTaken(const std::string& ns) {
  BurstOutcome b;
  ASSERT_TRUE(runBurst(ns, 5, &b));
  EXPECT_EQ(b.received, 5);
  EXPECT_EQ(b.processed + b.dropped, 5);
  EXPECT_GE(b.dropped, 1);
  ASSERT_FALSE(b.outputs.empty());
  EXPECT_EQ(b.outputs.back(), b.stamps.back());
  EXPECT_EQ(static_cast<double>(b.outputs.size()), b.processed);
}

TEST(Backlog, WithABacklogOfOneOnlyTheNewestWaits) {
  // The first pair is taken at once; the others, sent back to back, arrive while it is
  // processed and replace one another.
  expectNewestTaken("/newest");
}

TEST(Backlog, PairsWaitingLongerThanTheMaximumAgeMakeWayForTheNewest) {
  // Room for all five, but each waits longer than 1 ms while the first one is processed.
  expectNewestTaken("/stale");
}

TEST(Backlog, WhenFramesComeFasterThanTheyAreProcessedTheNewestIsTaken) {
  // /overload: 5 pairs may wait, for up to 10 s (the age limit plays no part here); queues of 50
  // messages on both ends, so that the flood reaches the nodelet whole.
  ros::NodeHandle nh;
  StereoPublisher pub("/overload", 50);
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/overload/disparity");
  Collector<DiagArray> diag(nh, "/diagnostics");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  pub.publishGoodInfo();
  ASSERT_TRUE(publishUntil(pub, [&] { return disparities.count() > 0; }, 30.0));
  // A steady stream the node keeps up with (each pair processed before the next is sent), past
  // the start-up grace: 12 pairs.
  for (int i = 0; i < 12; ++i) {
    const ros::Time t = nextStamp();
    pub.publishPair(t);
    ASSERT_TRUE(disparities.waitFor(
        [&](const stereo_msgs::DisparityImage& m) { return m.header.stamp == t; }, 20.0))
        << "steady pair " << i << " not processed";
    ros::WallDuration(0.05).sleep();
  }
  // Then a flood: 30 pairs 4 ms apart (strictly back to back, images were lost in transport).
  // /overload searches 128 disparities on one thread, about 40 ms a pair here: ten times the
  // flood's spacing, so that a loaded machine stretching the flood still overloads the node.
  disparities.clear();
  diag.clear();
  std::vector<ros::Time> flood;
  std::vector<ros::WallTime> sent;
  for (int i = 0; i < 30; ++i) {
    flood.push_back(nextStamp());
    pub.publishPair(flood.back());
    sent.push_back(ros::WallTime::now());
    ros::WallDuration(0.004).sleep();
  }
  const double last_five_span_ms = (sent.back() - sent[sent.size() - 5]).toSec() * 1e3;
  // The newest pair is always processed.
  ASSERT_TRUE(disparities.waitFor(
      [&](const stereo_msgs::DisparityImage& m) { return m.header.stamp == flood.back(); }, 30.0));
  std::map<std::string, std::string> kv, last_kv;
  const bool settled = static_cast<bool>(diag.waitFor([&](const DiagArray& a) {
    kv = test::statusValues(a, "/overload/reconstruction");
    if (!kv.empty()) last_kv = kv;
    return test::numberOr(kv, "pairs received", 0) >= 30 &&
           test::numberOr(kv, "pairs waiting", -1) == 0 &&
           test::numberOr(kv, "pairs received", -1) ==
               test::numberOr(kv, "pairs processed", 0) + test::numberOr(kv, "pairs dropped", 0) +
                   test::numberOr(kv, "pairs rejected", 0);
  }, 10.0));
  ASSERT_TRUE(settled) << "not settled: received " << test::numberOr(last_kv, "pairs received", -1)
                       << ", processed " << test::numberOr(last_kv, "pairs processed", -1)
                       << ", dropped " << test::numberOr(last_kv, "pairs dropped", -1)
                       << ", waiting " << test::numberOr(last_kv, "pairs waiting", -1)
                       << ", left " << test::numberOr(last_kv, "left images", -1) << ", right "
                       << test::numberOr(last_kv, "right images", -1);
  std::printf("[ INFO     ] /overload: %g received, %g processed, %g dropped; pipeline median "
              "%g ms; the flood's last five pairs sent within %.1f ms\n",
              test::numberOr(kv, "pairs received", -1), test::numberOr(kv, "pairs processed", -1),
              test::numberOr(kv, "pairs dropped", -1),
              test::numberOr(kv, "pipeline median (ms)", -1), last_five_span_ms);
  EXPECT_GE(test::numberOr(kv, "pairs dropped", 0), 1);
  // In order, the pairs waiting when the flood ended (up to 5) would all be processed; taking
  // the newest skips them: of the last five, at most the one in progress and the newest.
  int last_five = 0;
  std::string processed;  // the flood's pairs that came out, by index, for a failure's message
  for (const auto& m : disparities.all()) {
    const auto it = std::find(flood.begin(), flood.end(), m->header.stamp);
    if (it != flood.end()) processed += " " + std::to_string(it - flood.begin());
    if (m->header.stamp >= flood[flood.size() - 5]) ++last_five;
  }
  EXPECT_LE(last_five, 2) << "the pairs waiting at the end of the flood were processed in order;"
                          << " flood pairs processed:" << processed << "; the last five were sent"
                          << " within " << last_five_span_ms << " ms, a pair takes "
                          << test::numberOr(kv, "pipeline median (ms)", -1) << " ms";
  EXPECT_GE(last_five, 1);
}

// --- Bad input: each case must be reported (diagnostics "last error", pairs rejected) and the
// next good pair processed. All in /bad, in this order.

class BadInput : public ::testing::Test {
 protected:
  BadInput() : pub_("/bad"), disparities_(nh_, "/bad/disparity"), diag_(nh_, "/diagnostics") {}

  void SetUp() override {
    ASSERT_TRUE(waitUntil([&] { return pub_.inputsSubscribed(); }, 10.0));
  }

  /// Publish pairs made by @p send until the diagnostics report an error containing @p needle.
  bool expectReported(const std::string& needle, const std::function<void(const ros::Time&)>& send) {
    diag_.clear();
    const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(20.0);
    while (ros::ok() && ros::WallTime::now() < deadline) {
      send(nextStamp());
      auto hit = diag_.waitFor([&](const DiagArray& a) {
        const auto kv = test::statusValues(a, "/bad/reconstruction");
        auto it = kv.find("last error");
        return it != kv.end() && it->second.find(needle) != std::string::npos;
      }, 0.5);
      if (hit) return true;
    }
    return false;
  }

  /// Publish good info and pairs until one of them comes out.
  bool expectGoodPairProcessed() {
    pub_.publishGoodInfo();
    disparities_.clear();
    return publishUntil(pub_, [&] { return disparities_.count() > 0; }, 30.0, nullptr, 0.5);
  }

  ros::NodeHandle nh_;
  StereoPublisher pub_;
  Collector<stereo_msgs::DisparityImage> disparities_;
  Collector<DiagArray> diag_;
};

TEST_F(BadInput, MissingCameraInfo) {
  // /bad has had no camera_info yet.
  EXPECT_TRUE(expectReported("no camera_info", [&](const ros::Time& t) { pub_.publishPair(t); }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, ZeroCameraInfo) {
  EXPECT_TRUE(expectReported("width/height must be > 0", [&](const ros::Time& t) {
    pub_.publishInfo(sensor_msgs::CameraInfo(), sensor_msgs::CameraInfo(), t);
    pub_.publishPair(t);
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, NaNInCameraInfo) {
  EXPECT_TRUE(expectReported("NaN", [&](const ros::Time& t) {
    sensor_msgs::CameraInfo l = scene().left_info;
    l.K[0] = std::nan("");
    pub_.publishInfo(l, scene().right_info, t);
    pub_.publishPair(t);
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, CameraInfoForAnotherImageSize) {
  EXPECT_TRUE(expectReported("describes", [&](const ros::Time& t) {
    sensor_msgs::CameraInfo l = scene().left_info, r = scene().right_info;
    l.width = r.width = 640;
    l.height = r.height = 480;
    pub_.publishInfo(l, r, t);
    pub_.publishPair(t);
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, MismatchedSizes) {
  cv::Mat small;
  cv::resize(scene().frame.right, small, cv::Size(160, 120));
  EXPECT_TRUE(expectReported("image sizes differ", [&](const ros::Time& t) {
    pub_.left.publish(test::imageMsg(scene().frame.left, "bgr8", t, "l"));
    pub_.right.publish(test::imageMsg(small, "bgr8", t, "r"));
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, UnsupportedEncoding) {
  cv::Mat f(240, 320, CV_32FC1, cv::Scalar(0.5));
  EXPECT_TRUE(expectReported("unsupported encoding", [&](const ros::Time& t) {
    pub_.left.publish(test::imageMsg(f, "32FC1", t, "l"));
    pub_.right.publish(test::imageMsg(f, "32FC1", t, "r"));
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, RightImagesWithoutLeft) {
  EXPECT_TRUE(expectReported("without a left", [&](const ros::Time& t) {
    pub_.right.publish(test::imageMsg(scene().frame.right, "bgr8", t, "r"));
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, OutOfOrderStamps) {
  ASSERT_TRUE(expectGoodPairProcessed());
  const ros::Time newest = disparities_.all().back()->header.stamp;
  // 0.1 s older than the last processed pair: out of order (a jump back of more than
  // restart_jump_back_s would be a stream restart instead).
  EXPECT_TRUE(expectReported("out-of-order", [&](const ros::Time&) {
    pub_.publishPair(newest - ros::Duration(0.1));
  }));
  EXPECT_TRUE(expectGoodPairProcessed());
}

TEST_F(BadInput, NodeletStillRunsAfterAllOfIt) {
  EXPECT_TRUE(expectGoodPairProcessed());
  auto diag = diag_.waitFor([](const DiagArray& a) {
    return !test::statusValues(a, "/bad/reconstruction").empty();
  }, 5.0);
  ASSERT_TRUE(diag);
  const auto kv = test::statusValues(*diag, "/bad/reconstruction");
  EXPECT_GE(test::numberOr(kv, "pairs rejected", 0), 7);
  EXPECT_GE(test::numberOr(kv, "pairs processed", 0), 8);
}

// --- image_transport: compressed input.

TEST(CompressedTransport, NodeletTakesCompressedImages) {
  ros::NodeHandle nh;
  const Scene& s = scene();
  // PNG: lossless, so the pair is the same as over the raw transport.
  nh.setParam("/comp/left/image_raw/compressed/format", std::string("png"));
  nh.setParam("/comp/right/image_raw/compressed/format", std::string("png"));
  image_transport::ImageTransport it(nh);
  image_transport::Publisher left = it.advertise("/comp/left/image_raw", 5);
  image_transport::Publisher right = it.advertise("/comp/right/image_raw", 5);
  ros::Publisher li = nh.advertise<sensor_msgs::CameraInfo>("/comp/left/camera_info", 1, true);
  ros::Publisher ri = nh.advertise<sensor_msgs::CameraInfo>("/comp/right/camera_info", 1, true);
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/comp/disparity");
  // The nodelet (~image_transport: compressed) subscribes <base>/compressed, not the raw topic.
  ASSERT_TRUE(waitUntil([&] { return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0; },
                        10.0));
  li.publish(s.left_info);
  ri.publish(s.right_info);
  test::publishUntil(
      [&] {
        const ros::Time t = nextStamp();
        left.publish(test::imageMsg(s.frame.left, "bgr8", t, s.left_info.header.frame_id));
        right.publish(test::imageMsg(s.frame.right, "bgr8", t, s.right_info.header.frame_id));
      },
      [&] { return disparities.count() > 0; }, 60.0, 1.0);
  ASSERT_GT(disparities.count(), 0u) << "no disparity from compressed input";
  auto d = disparities.all().front();
  int64_t valid = 0;
  for (uint32_t r = 0; r < d->image.height; ++r) {
    for (uint32_t c = 0; c < d->image.width; ++c) valid += at(*d, r, c) >= d->min_disparity;
  }
  EXPECT_GT(double(valid) / (d->image.width * d->image.height), 0.3);
}

// --- tf2 target_frame.

TEST(TargetFrame, CloudIsTransformedOrWithheldWithAWarning) {
  ros::NodeHandle nh;
  const Scene& s = scene();
  tf2_ros::StaticTransformBroadcaster broadcaster;
  geometry_msgs::TransformStamped tf;
  tf.header.stamp = ros::Time(0);
  tf.header.frame_id = "world";
  tf.child_frame_id = s.left_info.header.frame_id;
  tf.transform.translation.x = 0.1;
  tf.transform.rotation.w = 1.0;
  broadcaster.sendTransform(tf);

  StereoPublisher pub("/tf");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/tf/disparity");
  Collector<sensor_msgs::PointCloud2> clouds(nh, "/tf/points2");
  ASSERT_TRUE(waitUntil([&] { return pub.inputsSubscribed(); }, 10.0));
  pub.publishGoodInfo();
  ASSERT_TRUE(publishUntil(pub, [&] { return clouds.count() > 0; }, 60.0, nullptr, 1.0));
  auto cloud = clouds.all().front();
  EXPECT_EQ(cloud->header.frame_id, "world");
  auto d = disparities.waitFor([&](const stereo_msgs::DisparityImage& m) {
    return m.header.stamp == cloud->header.stamp;
  }, 5.0);
  ASSERT_TRUE(d);
  OrganizedCloud oc;
  ASSERT_TRUE(ros_conv::fromPointCloud2(*cloud, oc, nullptr));
  // x_world = x_optical + 0.1 with x_optical = (u - cx) Z / f.
  const double cx = s.scene->calibration().left.P(0, 2);
  int checked = 0;
  for (int r = 0; r < oc.xyz.rows; r += 7) {
    for (int c = 0; c < oc.xyz.cols; c += 7) {
      const cv::Vec3f p = oc.xyz.at<cv::Vec3f>(r, c);
      if (!std::isfinite(p[2])) continue;
      EXPECT_NEAR(p[0] - 0.1, (c - cx) * p[2] / d->f, 1e-5);
      ++checked;
    }
  }
  EXPECT_GT(checked, 100);

  // No transform to "nowhere": the disparity still comes, the cloud is withheld and counted.
  StereoPublisher pub2("/tf_missing");
  Collector<stereo_msgs::DisparityImage> d2(nh, "/tf_missing/disparity");
  Collector<sensor_msgs::PointCloud2> c2(nh, "/tf_missing/points2");
  Collector<DiagArray> diag(nh, "/diagnostics");
  ASSERT_TRUE(waitUntil([&] { return pub2.inputsSubscribed(); }, 10.0));
  pub2.publishGoodInfo();
  ASSERT_TRUE(publishUntil(pub2, [&] { return d2.count() > 0; }, 60.0, nullptr, 1.0));
  EXPECT_TRUE(diag.waitFor([](const DiagArray& a) {
    return test::numberOr(test::statusValues(a, "/tf_missing/reconstruction"), "tf failures", 0) >= 1;
  }, 10.0));
  EXPECT_EQ(c2.count(), 0u);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_nodelet_synthetic");
}
