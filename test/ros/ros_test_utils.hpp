/**
 * @file ros_test_utils.hpp
 * @brief Helpers of the rostest gtest nodes: collect messages and wait for one that matches with
 * a timeout (never a fixed sleep that can hang), read endo_stereo's diagnostics, ask the master
 * what a node publishes and subscribes to, build stereo
 * input messages from a synthetic surgical frame, re-publish an input until its result arrives,
 * and the main() every rostest gtest node shares.
 *
 * The test main() (runRosGtests) starts a ros::AsyncSpinner, so callbacks run while a test waits.
 */
#pragma once

#include <cmath>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "endo_stereo/ros/conversions.hpp"
#include "endo_stereo/synthetic/surgical_scene.hpp"

namespace endo_stereo {
namespace test {

/// The synthetic calibrated scene of the rostests, rendered once per process (rendering is the
/// slow part): a 320x240 window at the focal length of the 960x540 endoscope (70 deg horizontal
/// field of view there: f = 480 / tan(35 deg) = 685.5 px), so disparities (about 16..79 px) and
/// the depth resolution are those of the real scale while a frame stays cheap to match; seed 3,
/// distorted, so that raw != rectified (the calibrated rectification path is exercised).
/// Uses endo_stereo_surgical_scene: a test calling it links that library.
struct CalibratedScene {
  std::unique_ptr<SurgicalScene> scene;
  SurgicalFrame frame;
  sensor_msgs::CameraInfo left_info, right_info;
};
constexpr double kSceneFocalPx = 685.5;

inline const CalibratedScene& calibratedScene() {
  static CalibratedScene* s = [] {
    auto* sc = new CalibratedScene;
    SurgicalSceneParams p;
    p.width = 320;
    p.height = 240;
    p.seed = 3;
    p.hfov_deg = 2.0 * std::atan(0.5 * p.width / kSceneFocalPx) * 180.0 / M_PI;
    p.distorted = true;
    sc->scene = std::make_unique<SurgicalScene>(p);
    sc->scene->render(0, sc->frame);
    sc->left_info = ros_conv::toCameraInfo(sc->scene->calibration().left);
    sc->right_info = ros_conv::toCameraInfo(sc->scene->calibration().right);
    return sc;
  }();
  return *s;
}

/// Subscribes to a topic and keeps every message received, in order.
template <class M>
class Collector {
 public:
  using ConstPtr = boost::shared_ptr<const M>;
  Collector(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size = 100) {
    sub_ = nh.subscribe<M>(topic, queue_size, &Collector::cb, this);
  }
  ~Collector() { sub_.shutdown(); }

  /// The first message received so far, or later within @p timeout_s, for which @p pred holds;
  /// null on timeout.
  ConstPtr waitFor(const std::function<bool(const M&)>& pred, double timeout_s) {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    std::unique_lock<std::mutex> lock(mutex_);
    size_t checked = 0;
    for (;;) {
      for (; checked < msgs_.size(); ++checked) {
        if (pred(*msgs_[checked])) return msgs_[checked];
      }
      if (cv_.wait_until(lock, deadline) == std::cv_status::timeout) {
        for (; checked < msgs_.size(); ++checked) {
          if (pred(*msgs_[checked])) return msgs_[checked];
        }
        return nullptr;
      }
      if (!ros::ok()) return nullptr;
    }
  }
  std::vector<ConstPtr> all() {
    std::lock_guard<std::mutex> lock(mutex_);
    return msgs_;
  }
  size_t count() {
    std::lock_guard<std::mutex> lock(mutex_);
    return msgs_.size();
  }
  void clear() {
    std::lock_guard<std::mutex> lock(mutex_);
    msgs_.clear();
  }
  uint32_t numPublishers() const { return sub_.getNumPublishers(); }
  void shutdown() { sub_.shutdown(); }

 private:
  void cb(const ConstPtr& msg) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      msgs_.push_back(msg);
    }
    cv_.notify_all();
  }
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<ConstPtr> msgs_;
};

/// Poll @p cond every 20 ms until it holds or @p timeout_s passes. @return whether it held.
inline bool waitUntil(const std::function<bool()>& cond, double timeout_s) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout_s);
  while (ros::ok()) {
    if (cond()) return true;
    if (ros::WallTime::now() > deadline) return false;
    ros::WallDuration(0.02).sleep();
  }
  return false;
}

/// Call @p publish_once, then wait up to @p period_s for @p done; repeat until @p done holds,
/// @p timeout_s passes or (when @p max_publishes > 0) @p max_publishes inputs were sent. Robust
/// to the latency of a lazy subscription and to a camera_info that arrives after the first images.
/// @return whether @p done held.
inline bool publishUntil(const std::function<void()>& publish_once,
                         const std::function<bool()>& done, double timeout_s,
                         double period_s = 0.25, int max_publishes = 0) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout_s);
  for (int sent = 0; ros::ok() && ros::WallTime::now() < deadline &&
                     (max_publishes <= 0 || sent < max_publishes);
       ++sent) {
    publish_once();
    if (waitUntil(done, period_s)) return true;
  }
  return done();
}

/// The main() of a rostest gtest node named @p node_name: gtest and ROS initialised, callbacks
/// served by a two-thread AsyncSpinner while the tests wait. @return RUN_ALL_TESTS()'s status.
inline int runRosGtests(int argc, char** argv, const std::string& node_name) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int rc = RUN_ALL_TESTS();
  ros::shutdown();
  return rc;
}

/// The key/value pairs of the status of the nodelet @p nodelet_name ("/stereo/reconstruction")
/// in a diagnostics message; empty when it holds none.
inline std::map<std::string, std::string> statusValues(const diagnostic_msgs::DiagnosticArray& a,
                                                       const std::string& nodelet_name,
                                                       std::string* message = nullptr) {
  std::map<std::string, std::string> kv;
  const std::string want = nodelet_name.substr(nodelet_name[0] == '/' ? 1 : 0) + ": ";
  for (const auto& s : a.status) {
    if (s.name.compare(0, want.size(), want) != 0) continue;
    for (const auto& v : s.values) kv[v.key] = v.value;
    if (message) *message = s.message;
  }
  return kv;
}

inline double numberOr(const std::map<std::string, std::string>& kv, const std::string& key,
                       double fallback) {
  auto it = kv.find(key);
  if (it == kv.end()) return fallback;
  try {
    return std::stod(it->second);
  } catch (...) {
    return fallback;
  }
}

/// The fewest of @p sent pairs, paced at @p period_ms, that a node must process: @p share of
/// what its own compute time allows. A pair that arrives while the node is busy is dropped, by
/// design, so at most period / median of them can be matched when the median processing time
/// exceeds the period. @p diagnostics holds "pipeline median (ms)".
/// The share is the caller's margin for jitter: where a frame costs close to the period (the real
/// 360x288 frames at 25 Hz on a shared 2-core machine), pairs are dropped in bursts even with a
/// median under the period (8% of 150 seen on a quiet machine), so such streams use 0.75; a node
/// that outputs little still fails.
inline double minimumProcessed(int sent, double period_ms,
                               const std::map<std::string, std::string>& diagnostics,
                               double share) {
  const double median_ms = numberOr(diagnostics, "pipeline median (ms)", period_ms);
  const double capacity = median_ms > period_ms ? period_ms / median_ms : 1.0;
  return share * sent * capacity;
}

/// Topics one node publishes and subscribes to, as registered with the master.
struct NodeTopics {
  std::set<std::string> published, subscribed;
};

/// What node @p node (a nodelet manager: all its nodelets together) publishes and subscribes
/// to, from the master's getSystemState; empty when the master cannot be asked.
inline NodeTopics topicsOf(const std::string& node) {
  NodeTopics t;
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  if (!ros::master::execute("getSystemState", args, result, payload, true)) return t;
  for (int kind = 0; kind < 2; ++kind) {
    for (int i = 0; i < payload[kind].size(); ++i) {
      const std::string topic = static_cast<std::string>(payload[kind][i][0]);
      for (int j = 0; j < payload[kind][i][1].size(); ++j) {
        if (static_cast<std::string>(payload[kind][i][1][j]) != node) continue;
        (kind == 0 ? t.published : t.subscribed).insert(topic);
      }
    }
  }
  return t;
}

inline sensor_msgs::ImagePtr imageMsg(const cv::Mat& m, const std::string& encoding,
                                      const ros::Time& stamp, const std::string& frame) {
  std_msgs::Header h;
  h.stamp = stamp;
  h.frame_id = frame;
  return boost::make_shared<sensor_msgs::Image>(ros_conv::matToImage(m, encoding, h));
}

}  // namespace test
}  // namespace endo_stereo
