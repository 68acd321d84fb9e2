// rostest (test/ros/faults.test): the faults of a live rig, each scripted by this node against
// the real nodelet in a real manager, on generated frames and (skipped when absent) on the real
// in-vivo frames:
// - a frozen camera: the right view re-sends one image for 2 s at 25 Hz while the left stays
//   live; no disparity from a frozen pair after ~freeze_frames, a WARN naming the camera, output
//   back within 3 pairs once the view changes;
// - a still scene with live cameras (fresh sensor noise on every frame): no freeze, nothing lost;
// - camera_info changed mid-stream (values, then the image size): each output of one geometry,
//   the temporal state reset and the change logged once each;
// - a stall and a burst: 1 s of silence, then 25 pairs within 100 ms: the newest is taken, the
//   rest counted as dropped, latency under 40 ms again within 1 s.
// Every wait has a timeout; the only sleeps pace the scripted stream.
#include <sys/stat.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <stereo_msgs/DisparityImage.h>

#include "endo_stereo/ros/conversions.hpp"
#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
using DiagArray = diagnostic_msgs::DiagnosticArray;
using Disparity = stereo_msgs::DisparityImage;
using Log = rosgraph_msgs::Log;

constexpr double kPeriodS = 0.04;  // 25 Hz
constexpr int kFreezeFrames = 10;  // faults.test: ~freeze_frames

// --- Frames ------------------------------------------------------------------------------------

struct Stereo {
  cv::Mat left, right;
  sensor_msgs::CameraInfo left_info, right_info;
};

/// The synthetic scene (320x240, focal of the 960x540 endoscope: 16..79 px) rendered once, without
/// noise (the tests add fresh noise per frame); distorted for the calibrated /geometry nodelet.
Stereo generated(bool distorted, int width = 320, int height = 240) {
  SurgicalSceneParams p;
  p.width = width;
  p.height = height;
  p.seed = 3;
  p.hfov_deg = 2.0 * std::atan(0.5 * 320 / 685.5) * 180.0 / M_PI;
  p.distorted = distorted;
  p.noise_sigma = 0.0;
  SurgicalScene scene(p);
  SurgicalFrame f;
  scene.render(0, f);
  Stereo s;
  s.left = f.left;
  s.right = f.right;
  s.left_info = ros_conv::toCameraInfo(scene.calibration().left);
  s.right_info = ros_conv::toCameraInfo(scene.calibration().right);
  return s;
}

std::string realDir() {
  const std::string dir = std::string(ES_SHARED_DATA) + "/real/hamlyn_invivo1";
  char real[PATH_MAX];
  return realpath(dir.c_str(), real) ? std::string(real) : dir;
}

/// The real in-vivo pairs 1..n (empty when the data is absent).
const std::vector<Stereo>& realFrames() {
  static std::vector<Stereo>* frames = [] {
    auto* v = new std::vector<Stereo>;
    for (int i = 1; i <= 110; ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "/%04d.png", i);
      Stereo s;
      s.left = cv::imread(realDir() + "/left" + name, cv::IMREAD_COLOR);
      s.right = cv::imread(realDir() + "/right" + name, cv::IMREAD_COLOR);
      if (s.left.empty() || s.right.empty()) break;
      v->push_back(s);
    }
    return v;
  }();
  return *frames;
}

/// @p base as a live camera sees a still scene: fresh Gaussian sensor noise of @p sigma grey
/// levels. sigma 1 is below the noise of an endoscope's video (several grey levels): the faintest
/// live signal the freeze test must not mistake for a frozen view.
cv::Mat live(const cv::Mat& base, cv::RNG& rng, double sigma = 1.0) {
  cv::Mat noise(base.size(), CV_16SC(base.channels())), s16, out;
  rng.fill(noise, cv::RNG::NORMAL, 0, sigma);
  base.convertTo(s16, noise.type());
  cv::Mat(s16 + noise).convertTo(out, base.type());
  return out;
}

// --- The scripted rig --------------------------------------------------------------------------

struct Rig {
  ros::Publisher left, right, left_info, right_info;
  std::string ns;
  explicit Rig(const std::string& ns_, bool calibrated = false, uint32_t queue = 30) : ns(ns_) {
    ros::NodeHandle nh(ns);
    const std::string kind = calibrated ? "image_raw" : "image_rect";
    left = nh.advertise<sensor_msgs::Image>("left/" + kind, queue);
    right = nh.advertise<sensor_msgs::Image>("right/" + kind, queue);
    if (calibrated) {
      left_info = nh.advertise<sensor_msgs::CameraInfo>("left/camera_info", 1, true);
      right_info = nh.advertise<sensor_msgs::CameraInfo>("right/camera_info", 1, true);
    }
  }
  bool subscribed() const { return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0; }
  void publish(const cv::Mat& l, const cv::Mat& r, const ros::Time& t) {
    left.publish(test::imageMsg(l, "bgr8", t, "left_optical"));
    right.publish(test::imageMsg(r, "bgr8", t, "left_optical"));
  }
  void publishInfo(sensor_msgs::CameraInfo l, sensor_msgs::CameraInfo r, const ros::Time& t) {
    l.header.stamp = r.header.stamp = t;
    left_info.publish(l);
    right_info.publish(r);
  }
};

/// Stamps that only grow across the tests (one clock for every namespace).
ros::Time nextStamp() {
  static ros::Time t(1700000000, 0);
  t += ros::Duration(kPeriodS);
  return t;
}

/// Paces a stream at 25 Hz on the wall clock, whatever publishing costs.
struct Pacer {
  ros::WallTime next = ros::WallTime::now();
  void wait() {
    next += ros::WallDuration(kPeriodS);
    const ros::WallDuration d = next - ros::WallTime::now();
    if (d > ros::WallDuration(0)) d.sleep();  // pacing the stream, not waiting for a result
  }
};

/// Diagnostics of @p node once every pair it received is accounted for (processed, dropped,
/// rejected or withheld) and at least @p received arrived; empty on timeout.
std::map<std::string, std::string> settled(Collector<DiagArray>& diag, const std::string& node,
                                           double received, double timeout_s = 60.0) {
  std::map<std::string, std::string> kv, last;
  const bool ok = static_cast<bool>(diag.waitFor([&](const DiagArray& a) {
    kv = test::statusValues(a, node);
    if (kv.empty()) return false;
    last = kv;
    const double rec = test::numberOr(kv, "pairs received", -1);
    return rec >= received && test::numberOr(kv, "pairs waiting", -1) == 0 &&
           rec == test::numberOr(kv, "pairs processed", 0) + test::numberOr(kv, "pairs dropped", 0) +
                      test::numberOr(kv, "pairs rejected", 0) +
                      test::numberOr(kv, "pairs withheld (frozen view)", 0);
  }, timeout_s));
  if (!ok) {
    ADD_FAILURE() << node << " not settled: received " << test::numberOr(last, "pairs received", -1)
                  << ", processed " << test::numberOr(last, "pairs processed", -1) << ", dropped "
                  << test::numberOr(last, "pairs dropped", -1) << ", withheld "
                  << test::numberOr(last, "pairs withheld (frozen view)", -1);
    return {};
  }
  return kv;
}

/// Log lines of @p level from our nodelet @p node whose text holds @p text.
std::vector<Log::ConstPtr> logLines(Collector<Log>& rosout, const std::string& node,
                                    uint8_t level, const std::string& text) {
  std::vector<Log::ConstPtr> out;
  const std::string prefix = node + ": ";
  for (const auto& m : rosout.all()) {
    if (m->level == level && m->msg.find(prefix) != std::string::npos &&
        m->msg.find(text) != std::string::npos) {
      out.push_back(m);
    }
  }
  return out;
}

// --- Frozen camera -----------------------------------------------------------------------------

/// 25 live pairs, 50 (2 s) with the right view frozen on the image it sent first in them while
/// the left stays live, then 25 live pairs again. @p at(i) gives the live pair i.
void frozenRightView(const std::string& ns, const std::function<Stereo(int)>& at) {
  ros::NodeHandle nh;
  const std::string node = ns + "/reconstruction";
  Rig rig(ns);
  Collector<Disparity> disparities(nh, ns + "/disparity", 1000);
  Collector<DiagArray> diag(nh, "/diagnostics", 5000);
  Collector<Log> rosout(nh, "/rosout", 5000);
  ASSERT_TRUE(waitUntil([&] { return rig.subscribed(); }, 20.0));
  constexpr int kA = 25, kB = 50, kC = 25;
  std::vector<ros::Time> stamps;
  std::vector<ros::Time> sent;  // ros::Time::now() when pair i was published (wall clock)
  cv::Mat frozen;
  Pacer pace;
  for (int i = 0; i < kA + kB + kC; ++i) {
    const Stereo s = at(i);
    if (i == kA) frozen = s.right.clone();
    const bool in_freeze = i >= kA && i < kA + kB;
    stamps.push_back(nextStamp());
    sent.push_back(ros::Time::now());
    rig.publish(s.left, in_freeze ? frozen : s.right, stamps.back());
    pace.wait();
  }
  const auto kv = settled(diag, node, kA + kB + kC);
  ASSERT_FALSE(kv.empty());
  waitUntil([&] {
    return static_cast<double>(disparities.count()) >= test::numberOr(kv, "pairs processed", 0);
  }, 10.0);
  // Every pair reached the nodelet (queues of 10 and 30 at 25 Hz): the run counts are exact.
  EXPECT_EQ(test::numberOr(kv, "pairs received", -1), kA + kB + kC);
  // Pairs kA+1 .. kA+kB-1 repeat the right image of pair kA: the run reaches freeze_frames at
  // pair kA + freeze_frames, and every frozen pair from there on is withheld.
  EXPECT_EQ(test::numberOr(kv, "pairs withheld (frozen view)", -1), kB - kFreezeFrames);
  int from_frozen = 0, resumed_at = -1, before = 0;
  for (const auto& d : disparities.all()) {
    const int i = static_cast<int>(std::find(stamps.begin(), stamps.end(), d->header.stamp) -
                                   stamps.begin());
    if (i < kA) ++before;
    if (i >= kA + kFreezeFrames && i < kA + kB) ++from_frozen;
    if (i >= kA + kB && resumed_at < 0) resumed_at = i - (kA + kB);
  }
  EXPECT_GT(before, 0) << "no output before the freeze";
  EXPECT_EQ(from_frozen, 0) << "disparities published from frozen pairs after freeze_frames";
  EXPECT_GE(resumed_at, 0) << "no output after the view changed again";
  EXPECT_LE(resumed_at, 2) << "output back only " << resumed_at + 1 << " pairs after the change";

  // One WARN naming the right camera (its topic), at the pair that completed the run: the check
  // runs as the pair forms, so only callback delivery stands between the two. 0.25 s is that
  // delivery on a loaded 2-core machine with the matcher busy, with room to spare (measured below).
  const std::string topic = ros::names::resolve(ns + "/right/image_rect");
  ASSERT_TRUE(waitUntil([&] {
    return !logLines(rosout, node, Log::WARN, "right camera frozen").empty();
  }, 5.0)) << "no WARN naming the right camera";
  const auto warns = logLines(rosout, node, Log::WARN, "camera frozen");
  EXPECT_EQ(warns.size(), 1u) << "the 2 s freeze was warned more than once (throttled to 5 s)";
  const Log& warn = *warns.front();
  EXPECT_NE(warn.msg.find(topic), std::string::npos) << warn.msg;
  const double after_run = (warn.header.stamp - sent[kA + kFreezeFrames]).toSec();
  const double after_start = (warn.header.stamp - sent[kA]).toSec();
  EXPECT_LT(after_run, 0.25) << warn.msg;
  // The diagnostics say it too (WARN naming the topic).
  bool diag_warned = false;
  for (const auto& a : diag.all()) {
    std::string message;
    const auto values = test::statusValues(*a, node, &message);
    if (message.find("right camera frozen") != std::string::npos &&
        message.find(topic) != std::string::npos) {
      for (const auto& st : a->status) {
        if (st.message == message) diag_warned = diag_warned || st.level == DiagArray::_status_type::value_type::WARN;
      }
    }
  }
  EXPECT_TRUE(diag_warned) << "no diagnostics WARN naming " << topic;
  EXPECT_TRUE(waitUntil([&] {
    return !logLines(rosout, node, Log::INFO, "live again").empty();
  }, 5.0)) << "the end of the freeze was not logged";
  std::printf("[ INFO     ] %s: right view frozen for %d pairs (2 s at 25 Hz): %g withheld, %d "
              "disparities from frozen pairs after freeze_frames; WARN %.3f s after the freeze "
              "began (%.3f s after the pair that completed the run of %d); output back at pair "
              "%d after the change; %g processed, %g dropped\n",
              ns.c_str(), kB, test::numberOr(kv, "pairs withheld (frozen view)", -1), from_frozen,
              after_start, after_run, kFreezeFrames, resumed_at + 1,
              test::numberOr(kv, "pairs processed", -1), test::numberOr(kv, "pairs dropped", -1));
}

/// 100 pairs (4 s at 25 Hz) of one still scene seen by live cameras: fresh noise every frame.
void stillSceneLiveCameras(const std::string& ns, const Stereo& base) {
  ros::NodeHandle nh;
  const std::string node = ns + "/reconstruction";
  Rig rig(ns);
  Collector<Disparity> disparities(nh, ns + "/disparity", 1000);
  Collector<DiagArray> diag(nh, "/diagnostics", 5000);
  Collector<Log> rosout(nh, "/rosout", 5000);
  ASSERT_TRUE(waitUntil([&] { return rig.subscribed(); }, 20.0));
  constexpr int kN = 100;
  cv::RNG rng(11);
  Pacer pace;
  for (int i = 0; i < kN; ++i) {
    rig.publish(live(base.left, rng), live(base.right, rng), nextStamp());
    pace.wait();
  }
  const auto kv = settled(diag, node, kN);
  ASSERT_FALSE(kv.empty());
  waitUntil([&] {
    return static_cast<double>(disparities.count()) >= test::numberOr(kv, "pairs processed", 0);
  }, 10.0);
  EXPECT_EQ(test::numberOr(kv, "pairs received", -1), kN);
  EXPECT_EQ(test::numberOr(kv, "pairs withheld (frozen view)", -1), 0);
  EXPECT_EQ(test::numberOr(kv, "pairs rejected", -1), 0);
  EXPECT_TRUE(logLines(rosout, node, Log::WARN, "frozen").empty()) << "a live camera called frozen";
  const double processed = test::numberOr(kv, "pairs processed", -1);
  // Nothing lost to the freeze check: every pair processed or, when the machine is slower than
  // 25 Hz, dropped for a newer one by the backlog (the same share as real_pass_through).
  EXPECT_GE(processed, test::minimumProcessed(kN, 1e3 * kPeriodS, kv, 0.75));
  EXPECT_EQ(static_cast<double>(disparities.count()), processed);
  std::printf("[ INFO     ] %s: still scene, live cameras (noise 1 grey level), %d pairs: %g "
              "processed, %g dropped, %g withheld, 0 freeze warnings; pipeline median %g ms\n",
              ns.c_str(), kN, processed, test::numberOr(kv, "pairs dropped", -1),
              test::numberOr(kv, "pairs withheld (frozen view)", -1),
              test::numberOr(kv, "pipeline median (ms)", -1));
}

TEST(FrozenCamera, GeneratedRightViewFrozenForTwoSeconds) {
  const Stereo base = generated(false);
  cv::RNG rng(5);
  frozenRightView("/frozen_gen", [&](int) {
    Stereo s;
    s.left = live(base.left, rng);
    s.right = live(base.right, rng);
    return s;
  });
}

TEST(FrozenCamera, GeneratedStillSceneWithLiveCamerasIsNotFrozen) {
  stillSceneLiveCameras("/static_gen", generated(false));
}

TEST(FrozenCamera, RealRightViewFrozenForTwoSeconds) {
  const auto& f = realFrames();
  if (f.size() < 100) {
    GTEST_SKIP() << "absent: real data " << realDir()
                 << " (../shared/data beside the repository); nothing measured";
  }
  // The real sequence as recorded (its own sensor noise and breathing motion).
  frozenRightView("/frozen_real", [&](int i) { return f[static_cast<size_t>(i) % f.size()]; });
}

TEST(FrozenCamera, RealStillSceneWithLiveCamerasIsNotFrozen) {
  const auto& f = realFrames();
  if (f.empty()) {
    GTEST_SKIP() << "absent: real data " << realDir()
                 << " (../shared/data beside the repository); nothing measured";
  }
  // The first real pair held still, with fresh noise of 1 grey level on each frame: a still
  // scene seen by live cameras (the recording itself always moves).
  stillSceneLiveCameras("/static_real", f.front());
}

// --- Geometry change ---------------------------------------------------------------------------

struct Geometry {
  uint32_t width, height;
  float f, T;
  bool operator==(const Geometry& o) const {
    return width == o.width && height == o.height && std::abs(f - o.f) < 1e-3f &&
           std::abs(T - o.T) < 1e-7f;
  }
};

Geometry geometryOf(const Disparity& d) {
  return {d.image.width, d.image.height, d.f, d.T};
}

TEST(GeometryChange, NewCameraInfoMidStreamRebuildsAndResetsOnce) {
  ros::NodeHandle nh;
  const std::string ns = "/geometry", node = ns + "/reconstruction";
  const Stereo small = generated(true);
  const Stereo large = generated(true, 384, 288);
  // The same rig recalibrated: a baseline 25% longer (right P's Tx), intrinsics unchanged.
  sensor_msgs::CameraInfo right_b = small.right_info;
  right_b.P[3] *= 1.25;
  Rig rig(ns, true);
  Collector<Disparity> disparities(nh, ns + "/disparity", 1000);
  Collector<Disparity> fused(nh, ns + "/disparity_fused", 1000);
  Collector<DiagArray> diag(nh, "/diagnostics", 5000);
  Collector<Log> rosout(nh, "/rosout", 5000);
  ASSERT_TRUE(waitUntil([&] { return rig.subscribed(); }, 20.0));
  cv::RNG rng(17);
  Pacer pace;
  int sent = 0;
  // Each phase: its camera_info first (latched, as a driver republishes it with the images), then
  // 25 pairs at 25 Hz. The second phase changes the values, the third the size too.
  auto phase = [&](const Stereo& s, const sensor_msgs::CameraInfo& r_info) {
    rig.publishInfo(s.left_info, r_info, ros::Time::now());
    for (int i = 0; i < 25; ++i, ++sent) {
      rig.publish(live(s.left, rng), live(s.right, rng), nextStamp());
      pace.wait();
    }
  };
  phase(small, small.right_info);
  ASSERT_TRUE(waitUntil([&] { return disparities.count() > 0; }, 30.0));
  phase(small, right_b);
  phase(large, large.right_info);
  const auto kv = settled(diag, node, sent);
  ASSERT_FALSE(kv.empty());
  waitUntil([&] {
    return static_cast<double>(disparities.count()) >= test::numberOr(kv, "pairs processed", 0);
  }, 10.0);
  // The outputs, in order, fall into three runs of one geometry each: no output after the first
  // of a new geometry has an old one, and the runs are those of the three calibrations.
  std::vector<Geometry> runs;
  std::map<double, Geometry> by_stamp;
  for (const auto& d : disparities.all()) {
    const Geometry g = geometryOf(*d);
    by_stamp[d->header.stamp.toSec()] = g;
    if (runs.empty() || !(runs.back() == g)) runs.push_back(g);
  }
  ASSERT_EQ(runs.size(), 3u) << "the outputs' geometries are not three runs in order";
  EXPECT_EQ(runs[0].width, 320u);
  EXPECT_EQ(runs[1].width, 320u);
  EXPECT_NEAR(runs[1].T / runs[0].T, 1.25, 1e-3) << "the second run is not the new baseline";
  EXPECT_EQ(runs[2].width, 384u);
  EXPECT_EQ(runs[2].height, 288u);
  // The fused output of each stamp has the geometry of its disparity.
  for (const auto& d : fused.all()) {
    const auto it = by_stamp.find(d->header.stamp.toSec());
    if (it != by_stamp.end()) {
      EXPECT_TRUE(it->second == geometryOf(*d)) << "fused output of another geometry";
    }
  }
  // Two changes, each logged once, each resetting the temporal state.
  EXPECT_EQ(test::numberOr(kv, "geometry changes", -1), 2);
  const auto changes = logLines(rosout, node, Log::INFO, "camera_info changed mid-stream");
  ASSERT_EQ(changes.size(), 2u);
  EXPECT_NE(changes[0]->msg.find("new calibration values"), std::string::npos) << changes[0]->msg;
  EXPECT_NE(changes[0]->msg.find("temporal state reset"), std::string::npos) << changes[0]->msg;
  EXPECT_NE(changes[1]->msg.find("image size 320x240 -> 384x288"), std::string::npos)
      << changes[1]->msg;
  // The size change reset the temporal state (its own line says why; the diagnostics' "last
  // temporal reset" may be a later one, a processing gap on a slow machine).
  EXPECT_NE(changes[1]->msg.find("temporal state reset (image size changed"), std::string::npos)
      << changes[1]->msg;
  std::printf("[ INFO     ] %s: %d pairs, camera_info changed twice (baseline x1.25, then "
              "320x240 -> 384x288): outputs in 3 runs of one geometry; %g processed, %g "
              "rejected (a pair whose images and camera_info disagree in size), %g dropped; "
              "%g temporal resets\n",
              ns.c_str(), sent, test::numberOr(kv, "pairs processed", -1),
              test::numberOr(kv, "pairs rejected", -1), test::numberOr(kv, "pairs dropped", -1),
              test::numberOr(kv, "temporal resets", -1));
}

// --- Stall and burst ---------------------------------------------------------------------------

TEST(StallAndBurst, NewestTakenRestCountedAndStreamResumes) {
  ros::NodeHandle nh;
  const std::string ns = "/burst", node = ns + "/reconstruction";
  const Stereo base = generated(false);
  Rig rig(ns);
  std::map<double, ros::WallTime> received;  // disparity stamp -> wall time it arrived here
  std::mutex mutex;
  ros::Subscriber sub = nh.subscribe<Disparity>(ns + "/disparity", 1000,
                                                [&](const Disparity::ConstPtr& d) {
    std::lock_guard<std::mutex> lock(mutex);
    received[d->header.stamp.toSec()] = ros::WallTime::now();
  });
  Collector<DiagArray> diag(nh, "/diagnostics", 5000);
  ASSERT_TRUE(waitUntil([&] { return rig.subscribed(); }, 20.0));
  cv::RNG rng(23);
  std::map<double, ros::WallTime> sent;
  auto send = [&]() {
    const ros::Time t = nextStamp();
    rig.publish(live(base.left, rng), live(base.right, rng), t);
    sent[t.toSec()] = ros::WallTime::now();
    return t;
  };
  // 3 s of a steady 25 Hz stream (the node's rate windows fill with it).
  Pacer pace;
  for (int i = 0; i < 75; ++i) {
    send();
    pace.wait();
  }
  const auto before = settled(diag, node, 75);
  ASSERT_FALSE(before.empty());
  // 1 s of silence (the time the stream stalls), then 25 pairs within 100 ms (one per 4 ms).
  ros::WallDuration(1.0).sleep();  // the scripted stall
  // The burst's messages are made beforehand, so that sending them is all the burst costs.
  std::vector<ros::Time> burst;
  std::vector<std::pair<sensor_msgs::ImagePtr, sensor_msgs::ImagePtr>> burst_msgs;
  for (int i = 0; i < 25; ++i) {
    burst.push_back(nextStamp());
    burst_msgs.emplace_back(test::imageMsg(live(base.left, rng), "bgr8", burst.back(), "left_optical"),
                            test::imageMsg(live(base.right, rng), "bgr8", burst.back(), "left_optical"));
  }
  const ros::WallTime burst_start = ros::WallTime::now();
  for (int i = 0; i < 25; ++i) {
    rig.left.publish(burst_msgs[i].first);
    rig.right.publish(burst_msgs[i].second);
    sent[burst[i].toSec()] = ros::WallTime::now();
  }
  // How long sending took is the scenario, not a property of the node: recorded (the figures in
  // RELIABILITY.md come from this line), and the bound on the pairs processed below allows for it.
  const double burst_ms = (ros::WallTime::now() - burst_start).toSec() * 1e3;
  const ros::WallTime burst_end = ros::WallTime::now();
  // Then the stream goes on at 25 Hz for 2 s, its next pair one period after the burst's last.
  std::vector<ros::Time> after;
  pace = Pacer();
  for (int i = 0; i < 50; ++i) {
    pace.wait();
    after.push_back(send());
  }
  const auto kv = settled(diag, node, 150);
  ASSERT_FALSE(kv.empty());
  waitUntil([&] {
    std::lock_guard<std::mutex> lock(mutex);
    return static_cast<double>(received.size()) >= test::numberOr(kv, "pairs processed", 0);
  }, 10.0);
  std::lock_guard<std::mutex> lock(mutex);
  int burst_processed = 0;
  for (const auto& t : burst) burst_processed += received.count(t.toSec()) ? 1 : 0;
  EXPECT_EQ(test::numberOr(kv, "pairs received", -1), 150) << "pairs lost before the nodelet";
  // The newest pair is taken. The burst's first pair is taken at once (the node is idle after the
  // stall) and searches the full range (the stall reset the temporal state); the pair taken after
  // it is the newest that had arrived when it was done: the burst's last, or, on a machine slow
  // enough that stream pairs came meanwhile, the newest of those. Its disparity coming back marks
  // when the node was free again (a little late, by the publishing latency: hence "or the next").
  ASSERT_TRUE(received.count(burst.front().toSec())) << "the burst's first pair was not processed";
  const ros::WallTime free_at = received[burst.front().toSec()];
  size_t arrived = 0;  // stream pairs after the burst sent before the node was free
  while (arrived < after.size() && sent[after[arrived].toSec()] < free_at) ++arrived;
  const bool newest_burst = arrived == 0 && received.count(burst.back().toSec()) > 0;
  bool next_instead = false;  // the newest stream pair available then, or the one after it
  for (size_t i = arrived == 0 ? 0 : arrived - 1; i <= arrived && i < after.size(); ++i) {
    next_instead = next_instead || received.count(after[i].toSec()) > 0;
  }
  EXPECT_TRUE(newest_burst || next_instead)
      << "the pair taken after the burst's first was not the newest available (" << arrived
      << " stream pairs had arrived by then)";
  // The burst arrives while the node is idle: its first pair is taken at once; once the rate
  // windows see pairs come faster than they are processed the newest is taken. Before they do,
  // the up to 3 pairs of the backlog may be caught up in order: 1 + 3 + the newest, and one more
  // for every pipeline median the burst took to send (a loaded machine spreads it out; the drop
  // policy on an exact timeline is FrameSchedulerTest's, test_frame_scheduler.cpp).
  const double pipeline_ms = test::numberOr(kv, "pipeline median (ms)", 0.0);
  const int allowed =
      5 + (pipeline_ms > 0.0 ? static_cast<int>(std::floor(burst_ms / pipeline_ms)) : 0);
  EXPECT_LE(burst_processed, allowed)
      << "the burst was processed in order instead of the newest taken (sent in " << burst_ms
      << " ms, pipeline median " << pipeline_ms << " ms)";
  const double dropped = test::numberOr(kv, "pairs dropped", 0) -
                         test::numberOr(before, "pairs dropped", 0);
  // Every pair is processed or counted (settled() above: received = processed + dropped +
  // rejected + withheld); each burst pair not processed is among the drops.
  EXPECT_EQ(test::numberOr(kv, "pairs rejected", -1), 0);
  EXPECT_EQ(test::numberOr(kv, "pairs withheld (frozen view)", -1), 0);
  EXPECT_GE(dropped, 25 - burst_processed) << "burst pairs neither processed nor counted as dropped";
  // The stream after the burst is processed again (functional: the node is not stuck behind the
  // burst): of its last 25 pairs, 75% of what the node's own processing time allows.
  int tail_processed = 0;
  for (size_t i = after.size() - 25; i < after.size(); ++i) {
    tail_processed += received.count(after[i].toSec()) ? 1 : 0;
  }
  EXPECT_GE(tail_processed, test::minimumProcessed(25, 40.0, kv, 0.75))
      << "the stream after the burst is not processed again";
  // Latency (publish here -> disparity back here) of the pairs after the burst: when it is first
  // under 40 ms again after the burst's end, and its median from there on. A time on a shared
  // machine is a measurement, not a pass/fail criterion: recorded for RELIABILITY.md (the target
  // there: under 40 ms again within 1 s).
  double recovered_s = -1.0;
  std::vector<double> latencies_ms;
  for (const auto& t : after) {
    const auto it = received.find(t.toSec());
    if (it == received.end()) continue;
    const double ms = (it->second - sent[t.toSec()]).toSec() * 1e3;
    if (recovered_s < 0 && ms < 40.0) recovered_s = (sent[t.toSec()] - burst_end).toSec();
    if (recovered_s >= 0) latencies_ms.push_back(ms);
  }
  std::sort(latencies_ms.begin(), latencies_ms.end());
  const double median = latencies_ms.empty() ? -1.0 : latencies_ms[latencies_ms.size() / 2];
  const double max_ms = latencies_ms.empty() ? -1.0 : latencies_ms.back();
  ::testing::Test::RecordProperty("burst_send_ms", std::to_string(burst_ms));
  ::testing::Test::RecordProperty("burst_pairs_processed", burst_processed);
  ::testing::Test::RecordProperty("latency_under_40ms_again_after_s", std::to_string(recovered_s));
  ::testing::Test::RecordProperty("latency_median_after_ms", std::to_string(median));
  std::printf("[ INFO     ] %s: 1 s stall, burst of 25 pairs sent in %.1f ms: %d processed "
              "(newest: %s), %g dropped since the stall; latency under 40 ms again %.3f s "
              "after the burst, then median %.1f ms (max %.1f ms) over %zu pairs; pipeline "
              "median %g ms\n",
              ns.c_str(), burst_ms, burst_processed,
              newest_burst ? "the burst's last" : (next_instead ? "the next pair's" : "none"), dropped, recovered_s, median,
              max_ms, latencies_ms.size(),
              test::numberOr(kv, "pipeline median (ms)", -1));
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_faults");
}
