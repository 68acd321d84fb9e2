// rostest (test/ros/out_of_step.test): views out of step against the real nodelet in a real
// manager. This node streams a moving scene at 25 Hz with the right view one frame late (right
// image t is the one taken at t-1) and checks for the WARN with offset +1 within 5 s (log and
// diagnostics); the same stream in step gives no such warning. Generated frames always; the real
// in-vivo frames when present (skipped, saying "absent:", otherwise).
// Every wait has a timeout; the only sleeps pace the stream.
#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>

#include "ros_test_utils.hpp"
#include "frame_sequences.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
using DiagArray = diagnostic_msgs::DiagnosticArray;
using Log = rosgraph_msgs::Log;

constexpr double kPeriodS = 0.04;  // 25 Hz
constexpr int kPairs = 100;        // 4 s of stream

using Frames = test::FramePairs;

/// 40 consecutive frames of the generated surgical scene at 320x240 (16..79 px), with its noise.
const Frames& generated() {
  static const Frames* f = new Frames(test::generatedSurgicalFrames(40));
  return *f;
}

std::string realDir() { return test::invivoDir(ES_SHARED_DATA); }

/// The real rectified in-vivo pairs (360x288, 0..127), empty when absent.
const Frames& realFrames() {
  static const Frames* f = new Frames(test::invivoFrames(ES_SHARED_DATA, kPairs + 1));
  return *f;
}

/// Frame index of stream pair @p i: forward, then back (ping-pong), so a short sequence streams
/// as long as needed and every two consecutive pairs are consecutive frames.
size_t at(int i, size_t n) {
  const int period = 2 * (static_cast<int>(n) - 1);
  const int k = i % period;
  return static_cast<size_t>(k < static_cast<int>(n) ? k : period - k);
}

struct Result {
  std::vector<Log::ConstPtr> warnings;  // "views out of step" lines of the node
  double first_warning_s = -1.0;        // after the first pair was sent
  std::string offset;                   // diagnostics' "right frame offset" at the end
  std::string state;                    // diagnostics' "views in step"
  bool diag_warn = false;               // a diagnostics WARN naming the offset
  double mean_density = 0.0;            // valid share of the disparities, mean over outputs
  size_t outputs = 0;
};

/// Streams @p f into namespace @p ns, the right view @p late frames late, and collects what the
/// node said.
Result run(const std::string& ns, const Frames& f, int late) {
  ros::NodeHandle nh;
  const std::string node = ns + "/reconstruction";
  ros::Publisher left = nh.advertise<sensor_msgs::Image>(ns + "/left/image_rect", 10);
  ros::Publisher right = nh.advertise<sensor_msgs::Image>(ns + "/right/image_rect", 10);
  Collector<stereo_msgs::DisparityImage> disparities(nh, ns + "/disparity", 1000);
  Collector<DiagArray> diag(nh, "/diagnostics", 5000);
  Collector<Log> rosout(nh, "/rosout", 5000);
  Result r;
  EXPECT_TRUE(waitUntil([&] {
    return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0;
  }, 20.0)) << node << " never subscribed";
  static ros::Time stamp(1700000000, 0);
  const ros::Time start = ros::Time::now();
  ros::WallTime next = ros::WallTime::now();
  const size_t n = f.left.size();
  for (int i = 0; i < kPairs; ++i) {
    // Right image of pair i: the one taken late frames earlier (the stream starts at i = late).
    const size_t li = at(i + late, n), ri = at(i, n);
    stamp += ros::Duration(kPeriodS);
    left.publish(test::imageMsg(f.left[li], "bgr8", stamp, "left_optical"));
    right.publish(test::imageMsg(f.right[ri], "bgr8", stamp, "left_optical"));
    next += ros::WallDuration(kPeriodS);
    const ros::WallDuration d = next - ros::WallTime::now();
    if (d > ros::WallDuration(0)) d.sleep();  // pacing the stream, not waiting for a result
  }
  // The check ran on the callback threads while the stream ran; the last diagnostics (period
  // 0.1 s) and log lines are at most a few periods behind.
  waitUntil([&] {
    for (const auto& a : diag.all()) {
      if (test::numberOr(test::statusValues(*a, node), "pairs received", 0) >= kPairs) return true;
    }
    return false;
  }, 10.0);
  const std::string prefix = node + ": ";
  for (const auto& m : rosout.all()) {
    if (m->msg.find(prefix) != std::string::npos &&
        m->msg.find("views out of step") != std::string::npos) {
      r.warnings.push_back(m);
      if (r.first_warning_s < 0) r.first_warning_s = (m->header.stamp - start).toSec();
    }
  }
  for (const auto& a : diag.all()) {
    std::string message;
    const auto kv = test::statusValues(*a, node, &message);
    if (kv.empty()) continue;
    r.offset = kv.count("right frame offset") ? kv.at("right frame offset") : "";
    r.state = kv.count("views in step") ? kv.at("views in step") : "";
    if (message.find("out of step by +1") != std::string::npos) r.diag_warn = true;
  }
  EXPECT_GT(disparities.count(), 0u) << "no output at all from " << node;
  for (const auto& d : disparities.all()) {
    const sensor_msgs::Image& im = d->image;
    size_t valid = 0;
    for (uint32_t y = 0; y < im.height; ++y) {
      const float* row = reinterpret_cast<const float*>(&im.data[y * im.step]);
      for (uint32_t x = 0; x < im.width; ++x) {
        valid += std::isfinite(row[x]) && row[x] >= d->min_disparity;
      }
    }
    r.mean_density += double(valid) / double(std::max<size_t>(1, size_t(im.width) * im.height));
  }
  r.outputs = disparities.count();
  if (r.outputs) r.mean_density /= double(r.outputs);
  return r;
}

void expectLateFound(const std::string& ns, const Frames& f) {
  const Result r = run(ns, f, 1);
  ASSERT_FALSE(r.warnings.empty()) << ns << ": no out-of-step warning; diagnostics: " << r.state;
  EXPECT_EQ(r.warnings.front()->level, Log::WARN);
  EXPECT_NE(r.warnings.front()->msg.find("offset +1"), std::string::npos)
      << r.warnings.front()->msg;
  // The limit: the check starts with the stream and decides in about 10 pairs (0.4 s).
  EXPECT_LE(r.first_warning_s, 5.0);
  EXPECT_EQ(r.offset, "1");
  EXPECT_TRUE(r.diag_warn) << "no diagnostics WARN naming the offset";
  std::printf("[ INFO     ] %s, right view 1 frame late: WARN %.2f s after the first pair (%zu "
              "line(s)): \"%s\"; diagnostics: right frame offset %s\n",
              ns.c_str(), r.first_warning_s, r.warnings.size(),
              r.warnings.front()->msg.c_str(), r.offset.c_str());
}

void expectInStepQuiet(const std::string& ns, const Frames& f, bool verdict_required) {
  const Result r = run(ns, f, 0);
  EXPECT_TRUE(r.warnings.empty()) << ns << ": " << r.warnings.front()->msg;
  if (verdict_required) {
    EXPECT_EQ(r.offset, "0") << r.state;
  } else {
    EXPECT_TRUE(r.offset == "0" || r.offset == "unknown") << r.state;
  }
  std::printf("[ INFO     ] %s, in step: %zu out-of-step warnings; diagnostics: right frame offset "
              "%s (%s)\n", ns.c_str(), r.warnings.size(), r.offset.c_str(), r.state.c_str());
}

TEST(OutOfStep, GeneratedRightViewOneFrameLateWarnsPlusOne) {
  expectLateFound("/late_gen", generated());
}

TEST(OutOfStep, GeneratedInStepGivesNoWarning) {
  // The generated scene always moves: the check must decide, and decide 0.
  expectInStepQuiet("/step_gen", generated(), true);
}

// ~right_frame_offset 1 on the same late stream (/comp_gen, out_of_step.test): the node re-pairs
// the views, so the check finds them in step and the output is as dense as the in-step stream's.
TEST(OutOfStep, GeneratedOneFrameLateCompensatedIsAsInStep) {
  const Result in_step = run("/step_gen", generated(), 0);
  const Result late = run("/late_gen", generated(), 1);
  const Result comp = run("/comp_gen", generated(), 1);
  EXPECT_TRUE(comp.warnings.empty()) << comp.warnings.front()->msg;
  EXPECT_EQ(comp.offset, "0") << comp.state;
  // Measured (generated 320x240 stream, 100 pairs): in step 75.76%, compensated 75.83%, one frame
  // late 69.63% (its moving pixels fail the criteria). Allowed: 1 point between compensated and in
  // step (the compensated stream's first pair is held, and each node drops pairs on its own when
  // the machine is busy), and the uncompensated one lower.
  ::testing::Test::RecordProperty("density_in_step", std::to_string(in_step.mean_density));
  ::testing::Test::RecordProperty("density_late", std::to_string(late.mean_density));
  ::testing::Test::RecordProperty("density_compensated", std::to_string(comp.mean_density));
  EXPECT_NEAR(comp.mean_density, in_step.mean_density, 0.01);
  EXPECT_LT(late.mean_density, comp.mean_density);
  std::printf("[ INFO     ] density per output: in step %.4f (%zu outputs), right 1 frame late "
              "%.4f (%zu), late with ~right_frame_offset 1 %.4f (%zu); compensated: %zu "
              "out-of-step warnings, right frame offset %s\n",
              in_step.mean_density, in_step.outputs, late.mean_density, late.outputs,
              comp.mean_density, comp.outputs, comp.warnings.size(), comp.offset.c_str());
}

TEST(OutOfStep, RealRightViewOneFrameLateWarnsPlusOne) {
  const Frames& f = realFrames();
  if (f.left.size() < 3) GTEST_SKIP() << "absent: real data " << realDir() << "; nothing measured";
  expectLateFound("/late_real", f);
}

TEST(OutOfStep, RealInStepGivesNoWarning) {
  const Frames& f = realFrames();
  if (f.left.size() < 3) GTEST_SKIP() << "absent: real data " << realDir() << "; nothing measured";
  expectInStepQuiet("/step_real", f, false);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_out_of_step");
}
