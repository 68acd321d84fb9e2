// rostest (test/ros/stereo_image_proc.test): endo_stereo for stereo_image_proc users.
// - A user's command line (`_min_disparity:=20 _disparity_range:=96 _approximate_sync:=True
//   _queue_size:=10` and names with no equivalent) gives the range 20..115, says so in the
//   start-up line, warns once by name about the others; the parameter server shows the values in
//   use after a reconfigure.
// - stereo_image_proc's own point_cloud2 nodelet, fed our disparity, computes the cloud we
//   publish on points2: the same valid pixels, the same coordinates (so the DisparityImage
//   conventions cannot drift), also after a live reconfigure of the range.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <dynamic_reconfigure/Reconfigure.h>
#include <rosgraph_msgs/Log.h>
#include <algorithm>
#include <gtest/gtest.h>
#include <nodelet/loader.h>
#include <ros/console.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>
#include <stereo_msgs/DisparityImage.h>

#include "endo_stereo/ros/conversions.hpp"
#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;

/// Every log line of this process, with its level.
class LogCapture : public ros::console::LogAppender {
 public:
  LogCapture() { ros::console::register_appender(this); }
  ~LogCapture() override { ros::console::deregister_appender(this); }
  void log(ros::console::Level level, const char* str, const char*, const char*, int) override {
    std::lock_guard<std::mutex> lock(mutex_);
    lines_.emplace_back(level, str);
  }
  /// Lines at @p level containing every one of @p needles.
  std::vector<std::string> find(ros::console::Level level, const std::vector<std::string>& needles) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::vector<std::string> out;
    for (const auto& l : lines_) {
      if (l.first != level) continue;
      bool all = true;
      for (const auto& n : needles) all = all && l.second.find(n) != std::string::npos;
      if (all) out.push_back(l.second);
    }
    return out;
  }

 private:
  std::mutex mutex_;
  std::vector<std::pair<ros::console::Level, std::string>> lines_;
};

/// ERROR and FATAL lines of every node (the master's aggregated /rosout), kept from the moment
/// this test process subscribes: a reconfigure callback that throws logs there, wherever it runs.
class RosoutErrors {
 public:
  RosoutErrors() : collector_(nh_, "/rosout_agg", 1000) {}
  std::vector<std::string> exceptions() {
    std::vector<std::string> out;
    for (const auto& m : collector_.all()) {
      if (m->level < rosgraph_msgs::Log::ERROR) continue;
      std::string text = m->msg;
      std::transform(text.begin(), text.end(), text.begin(), ::tolower);
      if (text.find("exception") != std::string::npos || text.find("what()") != std::string::npos) {
        out.push_back(m->name + ": " + m->msg);
      }
    }
    return out;
  }

 private:
  ros::NodeHandle nh_;
  Collector<rosgraph_msgs::Log> collector_;
};

RosoutErrors& rosoutErrors() {
  static RosoutErrors* errors = new RosoutErrors();  // lives as long as the process's ROS
  return *errors;
}

bool reconfigureInt(const std::string& node, const std::string& name, int value) {
  dynamic_reconfigure::Reconfigure srv;
  dynamic_reconfigure::IntParameter p;
  p.name = name;
  p.value = value;
  srv.request.config.ints.push_back(p);
  if (!ros::service::waitForService(node + "/set_parameters", 10000)) return false;
  // A call can fail at the transport (seen once in CI on a loaded 2-core machine: the second of
  // two back-to-back calls returned false while the node logged nothing); setting a parameter is
  // idempotent, so it is tried again. Each failed call is recorded in the test's own result
  // (property "set_parameters_failed_calls") and printed, and a failure that comes with an
  // exception in any node's log fails the test: a callback that throws now and then must not pass
  // on a retry. What the test asserts is the effect: the values read back and the range the next
  // disparity carries.
  for (int attempt = 1; attempt <= 3; ++attempt) {
    if (ros::service::call(node + "/set_parameters", srv)) return true;
    static int failed_calls = 0;
    ::testing::Test::RecordProperty("set_parameters_failed_calls", ++failed_calls);
    std::fprintf(stderr, "[ WARN     ] %s/set_parameters %s=%d: call %d failed\n", node.c_str(),
                 name.c_str(), value, attempt);
    ros::Duration(0.5).sleep();  // lets a log line of the failed call reach /rosout_agg
    const std::vector<std::string> thrown = rosoutErrors().exceptions();
    if (!thrown.empty()) {
      ADD_FAILURE() << node << "/set_parameters failed and a node logged an exception: "
                    << thrown.front();
      return false;
    }
  }
  return false;
}

int intParam(const std::string& name) {
  int v = -1000;
  ros::param::get(name, v);
  return v;
}

TEST(StereoImageProcParams, AUsersCommandLineGivesTheirRangeAndNamesWhatIsIgnored) {
  rosoutErrors();  // listens from the start, for the reconfigure calls below
  const std::string node = "/sip_user/reconstruction";
  ros::NodeHandle pnh(node);
  // As `rosrun endo_stereo endo_stereo_node _min_disparity:=20 _disparity_range:=96
  // _approximate_sync:=True _queue_size:=10 _correlation_window_size:=15 ...` sets them.
  pnh.setParam("min_disparity", 20);
  pnh.setParam("disparity_range", 96);
  pnh.setParam("approximate_sync", true);
  pnh.setParam("queue_size", 10);
  pnh.setParam("correlation_window_size", 15);
  pnh.setParam("speckle_size", 100);
  pnh.setParam("stereo_algorithm", 1);
  // Names this node does not read: a misspelling and the other spelling of ~rectify/mode.
  pnh.setParam("rectify_mode", std::string("pass_through"));
  pnh.setParam("max_disparty", 99);
  // A preset's range, which the stereo_image_proc names take precedence over.
  pnh.setParam("matcher/min_disparity", 0);
  pnh.setParam("matcher/max_disparity", 63);
  LogCapture logs;
  nodelet::Loader loader(false);
  ASSERT_TRUE(loader.load(node, "endo_stereo/reconstruction", nodelet::M_string(),
                          nodelet::V_string()));

  const auto ready = logs.find(ros::console::levels::Info,
                               {"ready:", "disparity range 20..115", "approximate sync",
                                "queue 10", "/sip_user/left/image_raw", "rectify mode calibrated",
                                "outputs disparity, points2"});
  EXPECT_EQ(ready.size(), 1u) << "no start-up line with the range, the sync and the topics";
  for (const std::string name : {"correlation_window_size", "speckle_size", "stereo_algorithm"}) {
    EXPECT_EQ(logs.find(ros::console::levels::Warn, {"~" + name + " "}).size(), 1u)
        << "not warned once about " << name;
  }
  EXPECT_EQ(logs.find(ros::console::levels::Warn, {"~rectify_mode ", "did you mean ~rectify/mode?"})
                .size(),
            1u);
  EXPECT_EQ(logs.find(ros::console::levels::Warn,
                      {"~max_disparty ", "did you mean ~matcher/max_disparity?"})
                .size(),
            1u);
  for (const std::string name : {"min_disparity", "disparity_range", "approximate_sync",
                                  "queue_size"}) {
    EXPECT_TRUE(logs.find(ros::console::levels::Warn, {"~" + name + " "}).empty())
        << name << " is understood, yet warned about";
  }
  EXPECT_EQ(intParam(node + "/matcher/min_disparity"), 20);
  EXPECT_EQ(intParam(node + "/matcher/max_disparity"), 115);

  // After a reconfigure the parameter server shows the values in use, under both names.
  ASSERT_TRUE(reconfigureInt(node, "matcher_max_disparity", 99));
  EXPECT_EQ(intParam(node + "/matcher/max_disparity"), 99);
  EXPECT_EQ(intParam(node + "/matcher/min_disparity"), 20);
  EXPECT_EQ(intParam(node + "/disparity_range"), 80);
  EXPECT_EQ(intParam(node + "/min_disparity"), 20);
  ASSERT_TRUE(reconfigureInt(node, "matcher_min_disparity", 30));
  EXPECT_EQ(intParam(node + "/matcher/min_disparity"), 30);
  EXPECT_EQ(intParam(node + "/min_disparity"), 30);
  EXPECT_EQ(intParam(node + "/disparity_range"), 70);
  EXPECT_TRUE(loader.unload(node));
}

// ------------------------------------------------------------------------------------------------
// stereo_image_proc/point_cloud2 on our disparity.

// The scene of test_nodelet_synthetic: a 320x240 window at the 960x540 endoscope's focal length,
// distorted lenses (the calibrated path rectifies), disparities inside 16..79.
constexpr double kFocalPx = 685.5;

struct Xyz {
  float x, y, z;
};

/// The x y z of every point of an organized cloud, by the fields' offsets (no assumption about
/// the layout: the two publishers may order their fields differently).
bool readXyz(const sensor_msgs::PointCloud2& msg, std::vector<Xyz>* out, std::string* error) {
  int ox = -1, oy = -1, oz = -1;
  for (const auto& f : msg.fields) {
    if (f.datatype != sensor_msgs::PointField::FLOAT32) continue;
    if (f.name == "x") ox = static_cast<int>(f.offset);
    if (f.name == "y") oy = static_cast<int>(f.offset);
    if (f.name == "z") oz = static_cast<int>(f.offset);
  }
  if (ox < 0 || oy < 0 || oz < 0) {
    *error = "no float32 x, y, z fields";
    return false;
  }
  out->clear();
  for (uint32_t r = 0; r < msg.height; ++r) {
    for (uint32_t c = 0; c < msg.width; ++c) {
      const uint8_t* p = msg.data.data() + r * msg.row_step + c * msg.point_step;
      Xyz q;
      std::memcpy(&q.x, p + ox, 4);
      std::memcpy(&q.y, p + oy, 4);
      std::memcpy(&q.z, p + oz, 4);
      out->push_back(q);
    }
  }
  return true;
}

/// Compares the two clouds of one stamp; prints the figures. Tolerance: both clouds are computed
/// in float32 from the same float disparities and the same f, T, cx, cy, by different formulas
/// (our x = (u - cx) Z / f with Z = f T / d; point_cloud2 multiplies [u v d 1] by the 4x4 matrix Q
/// and divides by W): a handful of float roundings each (measured: at most 1.2e-7 relative, one
/// float ulp). 1e-6 relative (about 8 ulps) separates that from any convention error (a pixel, a
/// principal point, a sign), which moves points by 1e-3 relative or more at these depths.
void expectSameCloud(const sensor_msgs::PointCloud2& ours, const sensor_msgs::PointCloud2& theirs) {
  ASSERT_EQ(ours.width, theirs.width);
  ASSERT_EQ(ours.height, theirs.height);
  EXPECT_EQ(ours.header.frame_id, theirs.header.frame_id);
  std::vector<Xyz> a, b;
  std::string e;
  ASSERT_TRUE(readXyz(ours, &a, &e)) << "ours: " << e;
  ASSERT_TRUE(readXyz(theirs, &b, &e)) << "stereo_image_proc's: " << e;
  int64_t valid = 0, only_ours = 0, only_theirs = 0, far = 0;
  double max_rel = 0.0;
  for (size_t i = 0; i < a.size(); ++i) {
    const bool va = std::isfinite(a[i].z), vb = std::isfinite(b[i].z);
    if (va != vb) {
      ++(va ? only_ours : only_theirs);
      continue;
    }
    if (!va) continue;
    ++valid;
    const double dx = a[i].x - b[i].x, dy = a[i].y - b[i].y, dz = a[i].z - b[i].z;
    const double rel = std::sqrt(dx * dx + dy * dy + dz * dz) /
                       std::sqrt(double(a[i].x) * a[i].x + double(a[i].y) * a[i].y +
                                 double(a[i].z) * a[i].z);
    max_rel = std::max(max_rel, rel);
    if (rel > 1e-6) ++far;
  }
  std::printf("[ INFO     ] stamp %.3f: %ld points valid in both, %ld only in ours, %ld only in "
              "stereo_image_proc's, largest relative difference %.2e\n",
              ours.header.stamp.toSec(), static_cast<long>(valid), static_cast<long>(only_ours),
              static_cast<long>(only_theirs), max_rel);
  EXPECT_GT(valid, static_cast<int64_t>(a.size() / 4)) << "too few points to compare";
  EXPECT_EQ(only_ours, 0);
  EXPECT_EQ(only_theirs, 0);
  EXPECT_EQ(far, 0) << "largest relative difference " << max_rel;
}

TEST(PointCloud2, StereoImageProcsCloudOfOurDisparityIsOurCloud) {
  rosoutErrors();  // listens from the start, for the reconfigure calls below
  ros::NodeHandle nh;
  SurgicalSceneParams sp;
  sp.width = 320;
  sp.height = 240;
  sp.seed = 5;
  sp.hfov_deg = 2.0 * std::atan(0.5 * sp.width / kFocalPx) * 180.0 / M_PI;
  sp.distorted = true;
  SurgicalScene scene(sp);
  int dmin = 0, dmax = 0;
  scene.suggestedDisparityRange(&dmin, &dmax);
  ASSERT_GE(dmin, 16);
  ASSERT_LE(dmax, 79);
  const sensor_msgs::CameraInfo left_info = ros_conv::toCameraInfo(scene.calibration().left);
  sensor_msgs::CameraInfo right_info = ros_conv::toCameraInfo(scene.calibration().right);
  // image_geometry's StereoCameraModel (point_cloud2) asserts that both camera_info name one
  // frame, and an assertion takes the whole manager down: one frame, as stereo drivers publish.
  right_info.header.frame_id = left_info.header.frame_id;

  ros::Publisher left = nh.advertise<sensor_msgs::Image>("/pc/left/image_raw", 5);
  ros::Publisher right = nh.advertise<sensor_msgs::Image>("/pc/right/image_raw", 5);
  ros::Publisher li = nh.advertise<sensor_msgs::CameraInfo>("/pc/left/camera_info", 5);
  ros::Publisher ri = nh.advertise<sensor_msgs::CameraInfo>("/pc/right/camera_info", 5);
  Collector<sensor_msgs::PointCloud2> ours(nh, "/pc/points2");
  Collector<sensor_msgs::PointCloud2> theirs(nh, "/pc_sip/points2");
  Collector<stereo_msgs::DisparityImage> disparities(nh, "/pc/disparity");
  // Our inputs subscribed, and point_cloud2's: it alone subscribes to our left/image_rect_color
  // (the two nodelets share one process, so the master is asked, not the connection counts).
  ASSERT_TRUE(waitUntil([&] {
    return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0 &&
           test::topicsOf("/manager").subscribed.count("/pc/left/image_rect_color") > 0;
  }, 30.0)) << "inputs not subscribed by both nodelets (is stereo_image_proc's point_cloud2 "
               "loaded? see the manager's output)";

  int frame = 0;
  ros::Time stamp(1700000000, 0);
  // One frame: camera_info and images with one stamp (point_cloud2 pairs its four inputs by
  // exact stamps); true once both clouds of that stamp arrived and were compared.
  auto oneFrame = [&]() -> bool {
    SurgicalFrame f;
    scene.render(frame++, f);
    stamp += ros::Duration(0.04);
    sensor_msgs::CameraInfo l = left_info, r = right_info;
    l.header.stamp = r.header.stamp = stamp;
    li.publish(l);
    ri.publish(r);
    left.publish(test::imageMsg(f.left, "bgr8", stamp, left_info.header.frame_id));
    right.publish(test::imageMsg(f.right, "bgr8", stamp, right_info.header.frame_id));
    const ros::Time t = stamp;
    auto a = ours.waitFor([&](const sensor_msgs::PointCloud2& m) { return m.header.stamp == t; }, 10.0);
    auto b = theirs.waitFor([&](const sensor_msgs::PointCloud2& m) { return m.header.stamp == t; }, 5.0);
    if (!a || !b) return false;
    expectSameCloud(*a, *b);
    return true;
  };
  int compared = 0;
  // The first frames may find point_cloud2's connections still coming up: up to 10 tries for 3.
  for (int i = 0; i < 10 && compared < 3; ++i) compared += oneFrame() ? 1 : 0;
  ASSERT_EQ(compared, 3) << "clouds of the same stamp did not arrive from both nodelets: "
                         << ours.count() << " of ours, " << theirs.count()
                         << " of stereo_image_proc's, " << disparities.count() << " disparities";

  // A live reconfigure of the range: the disparity's offsets change, the clouds must not differ.
  ASSERT_TRUE(reconfigureInt("/pc/reconstruction", "matcher_min_disparity", 12));
  ASSERT_TRUE(reconfigureInt("/pc/reconstruction", "matcher_max_disparity", 83));
  compared = 0;
  for (int i = 0; i < 5 && compared < 2; ++i) compared += oneFrame() ? 1 : 0;
  ASSERT_EQ(compared, 2);
  const auto d = disparities.all().back();
  const double doffs = scene.calibration().left.P(0, 2) - scene.calibration().right.P(0, 2);
  EXPECT_FLOAT_EQ(d->min_disparity, static_cast<float>(12 - doffs)) << "the new range not in use";
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_stereo_image_proc");
}
