// rostest (test/ros/ros_params.test): ROS parameters -> core structs through the same keys as
// the YAML presets (one path: config/*.yaml -> ROS params -> structs).
#include <algorithm>

#include <gtest/gtest.h>
#include <ros/package.h>
#include <ros/ros.h>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/ros/ros_params.hpp"
#include "endo_stereo/ros/stereo_image_proc_params.hpp"
#include "endo_stereo/ros/unknown_params.hpp"

namespace endo_stereo {
namespace {

std::string yaml(const PipelineParams& p) { return pipelineParamsToYaml(p); }

TEST(PipelineParamsFromRos, NothingSetKeepsTheDefaults) {
  ros::NodeHandle pnh("~empty");
  PipelineParams p;
  EXPECT_EQ(loadPipelineParamsFromRos(pnh, p), "");
  EXPECT_EQ(yaml(p), yaml(PipelineParams()));
}

TEST(PipelineParamsFromRos, SectionKeysAreApplied) {
  ros::NodeHandle pnh("~set");
  pnh.setParam("matcher/delta_min", 0.3);
  pnh.setParam("matcher/subpixel", false);
  pnh.setParam("matcher/max_disparity", 47);
  pnh.setParam("temporal/max_gap_s", 2);  // an int where a double is expected is fine
  pnh.setParam("rectify/mode", std::string("uncalibrated"));
  PipelineParams p;
  ASSERT_EQ(loadPipelineParamsFromRos(pnh, p), "");
  EXPECT_DOUBLE_EQ(p.matcher.delta_min, 0.3);
  EXPECT_FALSE(p.matcher.subpixel);
  EXPECT_EQ(p.matcher.max_disparity, 47);
  EXPECT_DOUBLE_EQ(p.temporal.max_gap_s, 2.0);
  EXPECT_EQ(p.rectify.mode, RectifyMode::kUncalibrated);
}

TEST(PipelineParamsFromRos, RosparamLoadOfAPresetEqualsTheYamlLoader) {
  // The .test file loads config/default.yaml and config/paper.yaml with <rosparam command="load">
  // as a launch file does; the structs must equal what the CLI's YAML loader makes of the files.
  const std::string pkg = ros::package::getPath("endo_stereo");
  for (const std::string preset : {"default", "paper"}) {
    ros::NodeHandle pnh("~" + preset);
    PipelineParams from_ros, from_yaml;
    ASSERT_EQ(loadPipelineParamsFromRos(pnh, from_ros), "") << preset;
    ASSERT_EQ(loadPipelineParams(pkg + "/config/" + preset + ".yaml", from_yaml), "") << preset;
    EXPECT_EQ(yaml(from_ros), yaml(from_yaml)) << preset;
  }
}

TEST(PipelineParamsFromRos, ConfigFileThenOverrides) {
  ros::NodeHandle pnh("~file");
  pnh.setParam("config_file", ros::package::getPath("endo_stereo") + "/config/paper.yaml");
  pnh.setParam("matcher/window_max_px", 23);
  PipelineParams p, paper;
  ASSERT_EQ(loadPipelineParamsFromRos(pnh, p), "");
  ASSERT_EQ(loadPipelineParams(ros::package::getPath("endo_stereo") + "/config/paper.yaml", paper), "");
  EXPECT_EQ(p.matcher.window_max_px, 23);
  paper.matcher.window_max_px = 23;
  EXPECT_EQ(yaml(p), yaml(paper));
}

TEST(PipelineParamsFromRos, UnknownKeyIsAnErrorNamingIt) {
  ros::NodeHandle pnh("~typo");
  pnh.setParam("matcher/delta_mni", 0.3);
  PipelineParams p;
  const std::string before = yaml(p);
  const std::string e = loadPipelineParamsFromRos(pnh, p);
  EXPECT_NE(e.find("matcher/delta_mni"), std::string::npos) << e;
  EXPECT_EQ(yaml(p), before);
}

TEST(PipelineParamsFromRos, WrongTypeIsAnError) {
  ros::NodeHandle pnh("~type");
  pnh.setParam("matcher/max_disparity", std::string("many"));
  PipelineParams p;
  const std::string e = loadPipelineParamsFromRos(pnh, p);
  EXPECT_NE(e.find("matcher/max_disparity"), std::string::npos) << e;
  ros::NodeHandle pnh2("~notmap");
  pnh2.setParam("matcher", 3);
  EXPECT_NE(loadPipelineParamsFromRos(pnh2, p).find("expected a map"), std::string::npos);
}

TEST(PipelineParamsFromRos, StoreThenLoadRoundTrips) {
  ros::NodeHandle pnh("~store");
  PipelineParams p;
  p.matcher.max_disparity = 95;
  p.filter.fill_holes = false;
  p.rectify.mode = RectifyMode::kPassThrough;
  p.rectify.baseline_m = 0.0045;
  storePipelineParamsToRos(pnh, p);
  PipelineParams back;
  ASSERT_EQ(loadPipelineParamsFromRos(pnh, back), "");
  EXPECT_EQ(yaml(back), yaml(p));
}

TEST(RosParamsFromRos, PlainNamesOverrideThePresetRosSection) {
  ros::NodeHandle pnh("~ros_settings");
  pnh.setParam("ros/approximate_sync", true);
  pnh.setParam("ros/queue_size", 7);
  pnh.setParam("queue_size", 3);
  pnh.setParam("sync_tolerance_s", 0.02);
  pnh.setParam("target_frame", std::string("world"));
  pnh.setParam("ros/backlog_pairs", 5);
  pnh.setParam("backlog_max_age_s", 0.5);
  RosParams r;
  ASSERT_EQ(loadRosParams(pnh, r), "");
  EXPECT_EQ(r.backlog_pairs, 5);
  EXPECT_DOUBLE_EQ(r.backlog_max_age_s, 0.5);
  EXPECT_TRUE(r.approximate_sync);
  EXPECT_EQ(r.queue_size, 3);
  EXPECT_DOUBLE_EQ(r.sync_tolerance_s, 0.02);
  EXPECT_EQ(r.target_frame, "world");
  EXPECT_EQ(r.validate(), "");
}

TEST(RosParamsFromRos, WrongTypeAndRangeAreReported) {
  ros::NodeHandle pnh("~ros_bad");
  pnh.setParam("queue_size", 2.5);
  RosParams r;
  EXPECT_NE(loadRosParams(pnh, r).find("queue_size"), std::string::npos);
  r.queue_size = 0;
  EXPECT_NE(r.validate().find("queue_size"), std::string::npos);
  r = RosParams();
  r.sync_tolerance_s = 0.0;
  EXPECT_NE(r.validate().find("sync_tolerance_s"), std::string::npos);
  r = RosParams();
  r.tf_timeout_s = -1.0;
  EXPECT_NE(r.validate().find("tf_timeout_s"), std::string::npos);
  r = RosParams();
  r.camera_info_wait_s = 11.0;
  EXPECT_NE(r.validate().find("camera_info_wait_s"), std::string::npos);
  r.camera_info_wait_s = 0.0;  // 0 = refuse at once, as before
  EXPECT_EQ(r.validate(), "");
  r = RosParams();
  r.backlog_pairs = 0;
  EXPECT_NE(r.validate().find("backlog_pairs"), std::string::npos);
  r = RosParams();
  r.backlog_max_age_s = 0.0;
  EXPECT_NE(r.validate().find("backlog_max_age_s"), std::string::npos);
}

TEST(RosParamsFromRos, NoInputWarningDelayIsValidated) {
  ros::NodeHandle pnh("~silence");
  pnh.setParam("no_input_warn_s", 2);
  RosParams r;
  ASSERT_EQ(loadRosParams(pnh, r), "");
  EXPECT_DOUBLE_EQ(r.no_input_warn_s, 2.0);
  r.no_input_warn_s = 0.0;
  EXPECT_NE(r.validate().find("no_input_warn_s"), std::string::npos);
}

TEST(StereoImageProcNames, MinAndRangeGiveTheirSearchRange) {
  ros::NodeHandle pnh("~sip_both");
  pnh.setParam("min_disparity", 20);
  pnh.setParam("disparity_range", 96);
  PipelineParams p;  // 0..63, as a preset would have it
  StereoImageProcReport report;
  ASSERT_EQ(applyStereoImageProcParams(pnh, p, &report), "");
  EXPECT_EQ(p.matcher.min_disparity, 20);
  EXPECT_EQ(p.matcher.max_disparity, 115);  // stereo_image_proc searches min .. min + range - 1
  ASSERT_EQ(report.mapped.size(), 1u);
  EXPECT_NE(report.mapped[0].find("20..115"), std::string::npos) << report.mapped[0];
  EXPECT_TRUE(report.ignored.empty());
}

TEST(StereoImageProcNames, MinAloneKeepsTheWidthAndRangeAloneKeepsTheMin) {
  ros::NodeHandle a("~sip_min");
  a.setParam("min_disparity", 16);
  PipelineParams p;
  p.matcher.min_disparity = 0;
  p.matcher.max_disparity = 63;
  ASSERT_EQ(applyStereoImageProcParams(a, p, nullptr), "");
  EXPECT_EQ(p.matcher.min_disparity, 16);
  EXPECT_EQ(p.matcher.max_disparity, 79);
  ros::NodeHandle b("~sip_range");
  b.setParam("disparity_range", 32);
  ASSERT_EQ(applyStereoImageProcParams(b, p, nullptr), "");
  EXPECT_EQ(p.matcher.min_disparity, 16);
  EXPECT_EQ(p.matcher.max_disparity, 47);
}

TEST(StereoImageProcNames, UnmappedNamesAreListedOnceWithWhatWeDoInstead) {
  ros::NodeHandle pnh("~sip_ignored");
  pnh.setParam("correlation_window_size", 15);
  pnh.setParam("speckle_range", 4);
  pnh.setParam("P1", 200.0);
  pnh.setParam("queue_size", 10);  // ours too: not listed
  PipelineParams p;
  const std::string before = yaml(p);
  StereoImageProcReport report;
  ASSERT_EQ(applyStereoImageProcParams(pnh, p, &report), "");
  EXPECT_EQ(yaml(p), before);
  ASSERT_EQ(report.ignored.size(), 3u);
  std::string all;
  for (const auto& l : report.ignored) all += l + "\n";
  EXPECT_NE(all.find("~correlation_window_size has no equivalent"), std::string::npos) << all;
  EXPECT_NE(all.find("window_min_px"), std::string::npos) << all;
  EXPECT_NE(all.find("~speckle_range"), std::string::npos) << all;
  EXPECT_NE(all.find("~P1"), std::string::npos) << all;
}

TEST(StereoImageProcNames, WrongTypeOrEmptyRangeIsAnErrorNamingIt) {
  ros::NodeHandle a("~sip_type");
  a.setParam("min_disparity", 2.5);
  PipelineParams p;
  EXPECT_NE(applyStereoImageProcParams(a, p, nullptr).find("min_disparity"), std::string::npos);
  ros::NodeHandle b("~sip_zero");
  b.setParam("disparity_range", 0);
  EXPECT_NE(applyStereoImageProcParams(b, p, nullptr).find("disparity_range"), std::string::npos);
  EXPECT_EQ(yaml(p), yaml(PipelineParams()));
}

TEST(PipelineParamsFromRos, StoringAfterAChangeWritesTheChangedValues) {
  ros::NodeHandle pnh("~store_changed");
  PipelineParams p;
  storePipelineParamsToRos(pnh, p);
  PipelineParams q = p;
  q.matcher.max_disparity = 99;
  pnh.setParam("matcher/delta_min", 0.77);  // not changed in q: left as it is on the server
  storePipelineParamsToRos(pnh, q, &p);
  int max_d = 0;
  double delta = 0.0;
  ASSERT_TRUE(pnh.getParam("matcher/max_disparity", max_d));
  ASSERT_TRUE(pnh.getParam("matcher/delta_min", delta));
  EXPECT_EQ(max_d, 99);
  EXPECT_DOUBLE_EQ(delta, 0.77);
}

TEST(UnknownParams, NamedWithTheClosestKnownName) {
  ros::NodeHandle pnh("~unknown");
  pnh.setParam("rectify_mode", std::string("pass_through"));  // the README's old spelling
  pnh.setParam("max_disparty", 99);                           // a typo of a section's field
  pnh.setParam("ros/queue_sise", 3);                          // a typo under the preset's ros:
  pnh.setParam("zzzz_qqqq_wwww", 1);                          // like nothing we read
  // Known: read by the loaders, so never listed.
  pnh.setParam("queue_size", 10);
  pnh.setParam("ros/queue_size", 10);
  pnh.setParam("matcher/max_disparity", 47);
  pnh.setParam("disparity_range", 96);         // stereo_image_proc's name
  pnh.setParam("matcher_max_disparity", 47);   // dynamic_reconfigure's copy
  pnh.setParam("config_file", std::string(""));
  std::vector<UnknownParam> u = unknownPrivateParams(pnh, knownPrivateParams());
  std::sort(u.begin(), u.end(),
            [](const UnknownParam& a, const UnknownParam& b) { return a.name < b.name; });
  ASSERT_EQ(u.size(), 4u);
  EXPECT_EQ(u[0].name, "max_disparty");
  EXPECT_EQ(u[0].closest, "matcher/max_disparity");
  EXPECT_EQ(u[1].name, "rectify_mode");
  EXPECT_EQ(u[1].closest, "rectify/mode");
  EXPECT_EQ(u[2].name, "ros/queue_sise");
  EXPECT_EQ(u[2].closest, "ros/queue_size");
  EXPECT_EQ(u[3].name, "zzzz_qqqq_wwww");
  EXPECT_EQ(u[3].closest, "");
}

TEST(UnknownParams, EveryNameOfBothPresetsIsKnown) {
  // The .test file loads both presets into ~default and ~paper: nothing there may be warned about.
  for (const char* ns : {"~default", "~paper"}) {
    const std::vector<UnknownParam> u =
        unknownPrivateParams(ros::NodeHandle(ns), knownPrivateParams());
    for (const UnknownParam& p : u) ADD_FAILURE() << ns << "/" << p.name << " is unknown";
  }
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_ros_params");
  ros::NodeHandle nh;
  return RUN_ALL_TESTS();
}
