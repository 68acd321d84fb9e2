// rostest (test/ros/respawn.test): the nodelet manager dies mid-stream and roslaunch respawns it.
// This node streams generated pairs at 25 Hz into /respawn/reconstruction, asks the manager for
// its pid over XML-RPC (getPid, as rosnode does) and kills it with SIGKILL, then keeps streaming
// and checks that
// - roslaunch starts a new manager process and a new loader process for the nodelet;
// - disparities resume within 5 s of the nodelet's respawn;
// - the first status of the new nodelet shows a fresh process and a fresh temporal state
//   (counters restarted, frames since the temporal state began = the pairs it has matched).
// Every wait has a timeout; the only sleeps pace the stream.
#include <signal.h>
#include <sys/types.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <bond/Status.h>
#include <gtest/gtest.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <stereo_msgs/DisparityImage.h>
#include <xmlrpcpp/XmlRpcClient.h>

#include "ros_test_utils.hpp"
#include "surgical_scene.hpp"

namespace endo_stereo {
namespace {

using test::Collector;
using test::waitUntil;
using DiagArray = diagnostic_msgs::DiagnosticArray;
using Disparity = stereo_msgs::DisparityImage;

constexpr double kPeriodS = 0.04;  // 25 Hz

/// The pid of the running node @p node (0 when it is not registered or does not answer).
int pidOf(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, false)) return 0;
  std::string host;
  uint32_t port = 0;
  if (!ros::network::splitURI(static_cast<std::string>(payload), host, port)) return 0;
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue call, reply;
  call[0] = ros::this_node::getName();
  // A node that was killed leaves its registration behind until a new one takes the name: its
  // URI then refuses the connection, and the call fails.
  if (!client.execute("getPid", call, reply) || client.isFault() || reply.getType() !=
      XmlRpc::XmlRpcValue::TypeArray || reply.size() < 3 || static_cast<int>(reply[0]) != 1) {
    return 0;
  }
  return static_cast<int>(reply[2]);
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

cv::Mat live(const cv::Mat& base, cv::RNG& rng) {
  cv::Mat noise(base.size(), CV_16SC(base.channels())), s16, out;
  rng.fill(noise, cv::RNG::NORMAL, 0, 1.0);
  base.convertTo(s16, noise.type());
  cv::Mat(s16 + noise).convertTo(out, base.type());
  return out;
}

TEST(Respawn, ManagerKilledMidStreamComesBackWithAFreshTemporalState) {
  ros::NodeHandle nh;
  const std::string ns = "/respawn", node = ns + "/reconstruction";
  // The synthetic scene at 320x240 (search 16..79, as faults.test), a few frames of its motion.
  SurgicalSceneParams p;
  p.width = 320;
  p.height = 240;
  p.seed = 5;
  p.hfov_deg = 2.0 * std::atan(0.5 * 320 / 685.5) * 180.0 / M_PI;
  p.distorted = false;
  p.noise_sigma = 0.0;
  SurgicalScene scene(p);
  std::vector<SurgicalFrame> frames(10);
  for (int i = 0; i < 10; ++i) scene.render(i, frames[static_cast<size_t>(i)]);

  ros::Publisher left = nh.advertise<sensor_msgs::Image>(ns + "/left/image_rect", 10);
  ros::Publisher right = nh.advertise<sensor_msgs::Image>(ns + "/right/image_rect", 10);
  std::mutex mutex;
  std::vector<std::pair<ros::Time, ros::WallTime>> received;  // disparity stamp, arrival here
  ros::Subscriber sub = nh.subscribe<Disparity>(ns + "/disparity", 100,
                                                [&](const Disparity::ConstPtr& d) {
    std::lock_guard<std::mutex> lock(mutex);
    received.emplace_back(d->header.stamp, ros::WallTime::now());
  });
  Collector<DiagArray> diag(nh, "/diagnostics", 20000);
  // The bond between the loader and the manager: each side publishes its status (id of the bond,
  // its own instance id) every second on /manager/bond.
  Collector<bond::Status> bond_status(nh, "/manager/bond", 1000);
  auto outputs = [&] {
    std::lock_guard<std::mutex> lock(mutex);
    return received.size();
  };

  ASSERT_TRUE(waitUntil([&] {
    return left.getNumSubscribers() > 0 && right.getNumSubscribers() > 0;
  }, 30.0)) << "the nodelet never subscribed";
  const int manager_pid = pidOf("/manager"), loader_pid = pidOf(node);
  ASSERT_GT(manager_pid, 0) << "no pid from /manager";
  ASSERT_GT(loader_pid, 0) << "no pid from " << node;

  cv::RNG rng(29);
  ros::Time stamp(1700000000, 0);
  int sent = 0;
  auto send = [&] {
    const SurgicalFrame& f = frames[static_cast<size_t>(sent) % frames.size()];
    stamp += ros::Duration(kPeriodS);
    left.publish(test::imageMsg(live(f.left, rng), "bgr8", stamp, "left_optical"));
    right.publish(test::imageMsg(live(f.right, rng), "bgr8", stamp, "left_optical"));
    ++sent;
  };

  // 1. The stream runs: at least 25 disparities out.
  Pacer pace;
  const ros::WallTime start = ros::WallTime::now();
  while (outputs() < 25 && (ros::WallTime::now() - start).toSec() < 30.0) {
    send();
    pace.wait();
  }
  ASSERT_GE(outputs(), 25u) << "the stream did not run before the kill";
  // The loader only notices a dead manager once their bond has formed (each side has heard the
  // other); a manager killed before that leaves the loader waiting for a sister that never comes.
  // Formed: two statuses from each of two instances of one bond id (heartbeats 1 s apart, so the
  // second of each is sent after the other side's first could arrive).
  auto bond_formed = [&] {
    std::map<std::string, std::map<std::string, int>> seen;  // bond id -> instance -> statuses
    for (const auto& m : bond_status.all()) ++seen[m->id][m->instance_id];
    for (const auto& b : seen) {
      int sides = 0;
      for (const auto& i : b.second) sides += i.second >= 2 ? 1 : 0;
      if (sides >= 2) return true;
    }
    return false;
  };
  // 10 s: the bond's connect timeout; the stream goes on meanwhile.
  for (const ros::WallTime t0 = ros::WallTime::now();
       !bond_formed() && (ros::WallTime::now() - t0).toSec() < 10.0;) {
    send();
    pace.wait();
  }
  ASSERT_TRUE(bond_formed()) << "no bond between the loader and the manager within 10 s";
  // The last status of the first nodelet before the kill.
  std::map<std::string, std::string> before;
  for (const auto& a : diag.all()) {
    const auto kv = test::statusValues(*a, node);
    if (!kv.empty()) before = kv;
  }
  const double processed_before = test::numberOr(before, "pairs processed", -1);
  ASSERT_GT(processed_before, 0);
  const size_t diag_at_kill = diag.count();

  // 2. SIGKILL to the manager mid-stream; the stream goes on.
  const size_t outputs_at_kill = outputs();
  ASSERT_EQ(kill(manager_pid, SIGKILL), 0) << "kill -9 " << manager_pid << " failed";
  const ros::WallTime killed = ros::WallTime::now();
  ros::WallTime manager_back, loader_back, resumed;
  int new_manager = 0, new_loader = 0;
  ros::WallTime next_poll = killed;
  // The bond between loader and manager breaks after bond's heartbeat timeout (4 s, fixed in
  // nodelet's loader), then the loader is respawned and loads the nodelet: 30 s is several times
  // what that takes on a loaded machine, and bounds a test that would otherwise stream forever.
  while ((ros::WallTime::now() - killed).toSec() < 30.0) {
    send();
    if (ros::WallTime::now() >= next_poll && (new_manager == 0 || new_loader == 0)) {
      // Two XML-RPC calls per node: every 100 ms, so the pacing stays near 25 Hz.
      next_poll = ros::WallTime::now() + ros::WallDuration(0.1);
      if (new_manager == 0) {
        const int pid = pidOf("/manager");
        if (pid > 0 && pid != manager_pid) {
          new_manager = pid;
          manager_back = ros::WallTime::now();
        }
      }
      if (new_loader == 0) {
        const int pid = pidOf(node);
        if (pid > 0 && pid != loader_pid) {
          new_loader = pid;
          loader_back = ros::WallTime::now();
        }
      }
    }
    {
      std::lock_guard<std::mutex> lock(mutex);
      for (size_t i = outputs_at_kill; i < received.size() && resumed.isZero(); ++i) {
        // An output of a pair sent before the kill may still be on its way: only a later
        // arrival counts, and only once the new nodelet exists.
        if (!loader_back.isZero() && received[i].second > loader_back) resumed = received[i].second;
      }
    }
    if (!resumed.isZero() && outputs() >= outputs_at_kill + 25) break;
    pace.wait();
  }
  ASSERT_GT(new_manager, 0) << "the manager was not respawned within 30 s";
  ASSERT_GT(new_loader, 0) << "the nodelet's loader was not respawned within 30 s";
  ASSERT_FALSE(resumed.isZero()) << "no disparity within 30 s of the kill";
  const double manager_s = (manager_back - killed).toSec();
  const double loader_s = (loader_back - killed).toSec();
  const double resumed_s = (resumed - killed).toSec();
  // The target: outputs resume within 5 s of the respawn, here the nodelet's (the manager
  // comes back at once; the nodelet follows its loader).
  EXPECT_LE(resumed_s - loader_s, 5.0) << "outputs back only " << resumed_s - loader_s
                                       << " s after the nodelet was respawned";
  // Kill to output: bond's heartbeat timeout (4 s after the last heartbeat, sent every 1 s) plus
  // the 5 s above.
  EXPECT_LE(resumed_s, 10.0);

  // 3. The new nodelet's first status with a matched pair: a fresh process (its counters start
  // again) whose temporal state began with its own first pair.
  std::map<std::string, std::string> first;
  ASSERT_TRUE(waitUntil([&] {
    const auto all = diag.all();
    for (size_t i = diag_at_kill; i < all.size(); ++i) {
      const auto kv = test::statusValues(*all[i], node);
      const double processed = test::numberOr(kv, "pairs processed", -1);
      // The old process's last statuses may still arrive: it had processed processed_before
      // pairs, the new one starts from 0.
      if (processed >= 1 && processed < processed_before) {
        first = kv;
        return true;
      }
    }
    return false;
  }, 10.0)) << "no status of the respawned nodelet with a processed pair";
  const double processed = test::numberOr(first, "pairs processed", -1);
  const double since_reset = test::numberOr(first, "frames since temporal reset", -1);
  EXPECT_GE(since_reset, 1);
  EXPECT_LE(since_reset, processed) << "the temporal state is older than the process";
  EXPECT_LT(processed, processed_before);
  std::printf("[ INFO     ] %s: %zu disparities before SIGKILL to the manager (pid %d, %g pairs "
              "processed); manager respawned (pid %d) %.2f s after the kill, nodelet loader "
              "(pid %d) %.2f s after; first disparity %.2f s after the kill, %.2f s after the "
              "nodelet's respawn; first status of the new nodelet: %g pairs processed, %g frames "
              "since the temporal state began, priors used %s; %d pairs sent in all\n",
              node.c_str(), outputs_at_kill, manager_pid, processed_before, new_manager,
              manager_s, new_loader, loader_s, resumed_s, resumed_s - loader_s, processed,
              since_reset, first["priors used"].c_str(), sent);
}

}  // namespace
}  // namespace endo_stereo

int main(int argc, char** argv) {
  return endo_stereo::test::runRosGtests(argc, argv, "test_respawn");
}
