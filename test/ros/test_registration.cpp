// rostest (test/ros/registration.test): the nodelet's points2 of a synthetic calibrated pair go to
// endo_stereo_registration_client, which registers them by ICP to the scene's exact surface moved
// by a known offset. Requirement: the registration converges with an RMS under 1 mm at endoscope
// scale (the scene is a 320x240 window at the 960x540 endoscope's focal length, 685.5 px, with
// the tissue about 80 mm away).
#include <cmath>

#include <geometry_msgs/TransformStamped.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <std_msgs/Float64.h>

#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;

TEST(RegistrationClient, ConvergesOnTheSyntheticScene) {
  ros::NodeHandle nh, pnh("~");
  SurgicalSceneParams p;
  p.width = 320;
  p.height = 240;
  p.seed = 3;
  p.distorted = true;
  double focal_px = 685.5, start_time = 1700000000.0;
  pnh.param("focal_px", focal_px, focal_px);
  pnh.param("start_time", start_time, start_time);
  p.hfov_deg = 2.0 * std::atan(0.5 * p.width / focal_px) * 180.0 / M_PI;
  SurgicalScene scene(p);
  sensor_msgs::CameraInfo li = ros_conv::toCameraInfo(scene.calibration().left);
  sensor_msgs::CameraInfo ri = ros_conv::toCameraInfo(scene.calibration().right);

  ros::NodeHandle sns("/stereo");
  ros::Publisher left = sns.advertise<sensor_msgs::Image>("left/image_raw", 5);
  ros::Publisher right = sns.advertise<sensor_msgs::Image>("right/image_raw", 5);
  ros::Publisher left_info = sns.advertise<sensor_msgs::CameraInfo>("left/camera_info", 1, true);
  ros::Publisher right_info = sns.advertise<sensor_msgs::CameraInfo>("right/camera_info", 1, true);
  Collector<std_msgs::Float64> rms(nh, "/stereo/registration/rms_m");
  Collector<geometry_msgs::TransformStamped> tf(nh, "/stereo/registration/transform");

  // The client subscribes points2 at start-up, so the nodelet subscribes its inputs.
  ASSERT_TRUE(waitUntil([&] { return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0; },
                        20.0));
  left_info.publish(li);
  right_info.publish(ri);
  // Frame k is published with the stamp start + k / fps, the stamp the client maps back to the
  // frame it renders as reference. Another frame follows only if no result came (e.g. the
  // camera_info reached the nodelet after the first pair).
  SurgicalFrame frame;
  int k = 0;
  const bool got = test::publishUntil(
      [&] {
        scene.render(k, frame);
        const ros::Time stamp(start_time + k / p.fps);
        left.publish(test::imageMsg(frame.left, "bgr8", stamp, li.header.frame_id));
        right.publish(test::imageMsg(frame.right, "bgr8", stamp, ri.header.frame_id));
        ++k;
      },
      [&] { return rms.count() > 0; }, 5 * 20.0, 20.0, 5);
  ASSERT_TRUE(got) << "no registration result";
  const double rms_m = rms.all().front()->data;
  std::printf("[ INFO     ] ICP RMS %.4f mm\n", rms_m * 1e3);
  ASSERT_TRUE(std::isfinite(rms_m)) << "ICP did not converge";
  EXPECT_LT(rms_m, 1e-3);

  // The recovered transform is the known model offset of the .test file (1.5, -1, 2 mm), to half
  // a millimetre (measured: 0.27 mm). A translation is what a smooth tissue patch pins down; a
  // rotation of about 1 deg around the camera centre 80 mm away looks like a 1.4 mm shift of the
  // patch, and ICP (point-to-point or generalized) settles for that shift (measured: it recovered
  // none of a 1.4 deg rotation), so rotations are not asked of it here.
  auto t = tf.waitFor([](const geometry_msgs::TransformStamped&) { return true; }, 5.0);
  ASSERT_TRUE(t);
  EXPECT_NEAR(t->transform.translation.x, 0.0015, 5e-4);
  EXPECT_NEAR(t->transform.translation.y, -0.001, 5e-4);
  EXPECT_NEAR(t->transform.translation.z, 0.002, 5e-4);
  EXPECT_NEAR(t->transform.rotation.w, 1.0, 1e-4);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_registration");
}
