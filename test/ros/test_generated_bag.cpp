// endo_stereo_generate end to end: it writes images, ground truth, camera_info YAML and a ROS bag
// that reads back (rosbag C++ API) with the expected topics, stamps, encodings and contents.
#include <cmath>
#include <cstdlib>
#include <map>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "surgical_scene.hpp"

#ifndef ES_GENERATE_BIN
#error "ES_GENERATE_BIN must name the endo_stereo_generate executable"
#endif

namespace endo_stereo {
namespace {

cv::Mat imageOf(const sensor_msgs::Image& msg, int type) {
  return cv::Mat(int(msg.height), int(msg.width), type, const_cast<uint8_t*>(msg.data.data()), msg.step);
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  cv::Mat diff;
  cv::compare(a, b, diff, cv::CMP_NE);
  return cv::countNonZero(diff.reshape(1)) == 0;
}

class GeneratedSequence : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char tmpl[] = "/tmp/endo_stereo_gen_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    const std::string cmd = std::string(ES_GENERATE_BIN) + " --out " + dir_ + "/seq --bag " + dir_ +
                            "/seq.bag --bag-gt --frames 6 --first 2 --width 160 --height 96 --seed 5"
                            " --namespace /endoscope --start-time 1000 --threads 2 > " + dir_ + "/log.txt 2>&1";
    status_ = std::system(cmd.c_str());
  }
  static void TearDownTestSuite() {
    const std::string cmd = "rm -rf " + dir_;
    (void)std::system(cmd.c_str());
  }
  static std::string dir_;
  static int status_;
};

std::string GeneratedSequence::dir_;
int GeneratedSequence::status_ = -1;

TEST_F(GeneratedSequence, BagReadsBackWithConsistentStamps) {
  ASSERT_EQ(status_, 0) << "see " << dir_ << "/log.txt";
  rosbag::Bag bag(dir_ + "/seq.bag", rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, int> counts;
  std::map<std::string, std::vector<double>> stamps;
  for (const rosbag::MessageInstance& m : view) {
    ++counts[m.getTopic()];
    if (auto img = m.instantiate<sensor_msgs::Image>()) {
      stamps[m.getTopic()].push_back(img->header.stamp.toSec());
      EXPECT_EQ(img->width, 160u);
      EXPECT_EQ(img->height, 96u);
      EXPECT_DOUBLE_EQ(img->header.stamp.toSec(), m.getTime().toSec());
    } else if (auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
      stamps[m.getTopic()].push_back(info->header.stamp.toSec());
      EXPECT_EQ(info->width, 160u);
    } else {
      ADD_FAILURE() << "unexpected type on " << m.getTopic();
    }
  }
  for (const char* t : {"/endoscope/left/image_raw", "/endoscope/right/image_raw",
                        "/endoscope/left/camera_info", "/endoscope/right/camera_info",
                        "/endoscope/ground_truth/disparity"}) {
    EXPECT_EQ(counts[t], 6) << t;
    ASSERT_EQ(stamps[t].size(), 6u) << t;
    for (int k = 0; k < 6; ++k) {
      // Frame i at start + i / fps (first = 2); ros::Time keeps nanoseconds.
      EXPECT_NEAR(stamps[t][k], 1000.0 + (2 + k) / 25.0, 1e-9) << t << " message " << k;
      // The same stamp on all four topics of a frame.
      EXPECT_DOUBLE_EQ(stamps[t][k], stamps["/endoscope/left/image_raw"][k]) << t;
    }
  }
  EXPECT_EQ(counts.size(), 5u);
}

TEST_F(GeneratedSequence, BagImagesMatchFilesAndTheScene) {
  ASSERT_EQ(status_, 0);
  rosbag::Bag bag(dir_ + "/seq.bag", rosbag::bagmode::Read);
  rosbag::View left_view(bag, rosbag::TopicQuery("/endoscope/left/image_raw"));
  SurgicalSceneParams p;
  p.width = 160;
  p.height = 96;
  p.seed = 5;
  const SurgicalScene scene(p);
  SurgicalFrame frame;
  int index = 2;
  for (const rosbag::MessageInstance& m : left_view) {
    const auto img = m.instantiate<sensor_msgs::Image>();
    ASSERT_TRUE(img);
    EXPECT_EQ(img->encoding, "bgr8");
    EXPECT_EQ(img->header.frame_id, "endoscope_left_optical");
    EXPECT_EQ(img->header.seq, uint32_t(index));
    char name[64];
    std::snprintf(name, sizeof(name), "/seq/left/%06d.png", index);
    const cv::Mat png = cv::imread(dir_ + name, cv::IMREAD_UNCHANGED);
    EXPECT_TRUE(identical(imageOf(*img, CV_8UC3), png)) << name;
    // Deterministic: the library renders the same frame in this process.
    scene.render(index, frame);
    EXPECT_TRUE(identical(imageOf(*img, CV_8UC3), frame.left)) << "frame " << index;
    std::snprintf(name, sizeof(name), "/seq/gt/%06d.pfm", index);
    std::string error;
    const cv::Mat gt = readPfm(dir_ + name, &error);
    ASSERT_FALSE(gt.empty()) << error;
    EXPECT_TRUE(identical(gt, frame.gt_disparity)) << name;
    ++index;
  }
  EXPECT_EQ(index, 8);
}

TEST_F(GeneratedSequence, CameraInfoMatchesTheYamlFiles) {
  ASSERT_EQ(status_, 0);
  StereoCalibration calib;
  std::string error;
  ASSERT_TRUE(loadStereoCameraInfoYaml(dir_ + "/seq/left.yaml", dir_ + "/seq/right.yaml", calib, &error))
      << error;
  rosbag::Bag bag(dir_ + "/seq.bag", rosbag::bagmode::Read);
  for (int k = 0; k < 2; ++k) {
    const CameraCalibration& c = k == 0 ? calib.left : calib.right;
    rosbag::View view(bag, rosbag::TopicQuery(k == 0 ? "/endoscope/left/camera_info" : "/endoscope/right/camera_info"));
    const auto info = view.begin()->instantiate<sensor_msgs::CameraInfo>();
    ASSERT_TRUE(info);
    EXPECT_EQ(info->distortion_model, c.distortion_model);
    for (int i = 0; i < 9; ++i) EXPECT_NEAR(info->K[i], c.K.val[i], 1e-9);
    for (int i = 0; i < 12; ++i) EXPECT_NEAR(info->P[i], c.P.val[i], 1e-9);
    EXPECT_EQ(info->header.frame_id, k == 0 ? "endoscope_left_optical" : "endoscope_right_optical");
  }
  // The right camera's P encodes the baseline: Tx = -f * B, B = 4.5 mm by default.
  EXPECT_NEAR(-calib.right.P(0, 3) / calib.right.P(0, 0), 0.0045, 1e-9);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
