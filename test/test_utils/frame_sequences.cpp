// Consecutive stereo frames for the tests. See frame_sequences.hpp.
#include "frame_sequences.hpp"

#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <opencv2/imgcodecs.hpp>

#include "surgical_scene.hpp"

namespace endo_stereo {
namespace test {

FramePairs generatedSurgicalFrames(int n) {
  FramePairs out;
  SurgicalSceneParams p;
  p.width = 320;
  p.height = 240;
  p.seed = 3;
  p.hfov_deg = 2.0 * std::atan(0.5 * 320 / 685.5) * 180.0 / M_PI;
  p.distorted = false;
  SurgicalScene scene(p);
  for (int i = 0; i < n; ++i) {
    SurgicalFrame frame;
    scene.render(i, frame);
    out.left.push_back(frame.left);
    out.right.push_back(frame.right);
  }
  return out;
}

std::string invivoDir(const std::string& shared_data_dir) {
  const std::string dir = shared_data_dir + "/real/hamlyn_invivo1";
  char real[PATH_MAX];
  return realpath(dir.c_str(), real) ? std::string(real) : dir;
}

FramePairs invivoFrames(const std::string& shared_data_dir, int n) {
  FramePairs out;
  const std::string dir = invivoDir(shared_data_dir);
  for (int i = 1; i <= n; ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "/%04d.png", i);
    cv::Mat l = cv::imread(dir + "/left" + name, cv::IMREAD_COLOR);
    cv::Mat r = cv::imread(dir + "/right" + name, cv::IMREAD_COLOR);
    if (l.empty() || r.empty()) break;
    out.left.push_back(l);
    out.right.push_back(r);
  }
  return out;
}

}  // namespace test
}  // namespace endo_stereo
