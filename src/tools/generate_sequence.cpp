// endo_stereo_generate: renders a synthetic surgical stereo sequence with exact ground truth
// (test/test_utils/surgical_scene.hpp) and writes it as image files, PFM ground truth, camera_info
// YAML and, optionally, a ROS bag. `endo_stereo_generate --help` lists the flags.
//
// Exit status: 0 success; 1 an output could not be written; 2 bad usage.
#include <chrono>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <sys/stat.h>

#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>

#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "endo_stereo/core/calibration_io.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "surgical_scene.hpp"
#include "tool_args.hpp"

namespace {

using endo_stereo::tools::kExitUsage;
using endo_stereo::tools::UsageError;

constexpr int kExitOk = 0;
constexpr int kExitOutput = 1;

const char* kUsage = R"(endo_stereo_generate - synthetic surgical stereo video with exact ground truth

Renders a calibrated stereo endoscope looking at deforming tissue (breathing, heartbeat) with
vessels, mottling, wet highlights that differ between the views, and a moving metallic instrument.
Deterministic: the same flags give the same files.

Usage:
  endo_stereo_generate --out DIR [options]
  endo_stereo_generate --bag FILE.bag --no-images [options]     (a bag only)

Output (DIR):
  left/000000.png, right/000000.png   raw images, BGR (rectified unless --distorted)
  gt/000000.pfm                       ground-truth disparity of the rectified left view, px
  nonocc/000000.png                   255 where the right camera sees the left pixel's point
  instrument/000000.png               255 where the left pixel sees an instrument
  specular/000000.png                 255 where the left image has a highlight (> 2 grey levels)
  left.yaml, right.yaml               camera_info YAML (K, D, R, P; P(0,3) = -f * baseline)
  sequence.yaml                       frames, fps, size, seed, f, baseline, suggested disparity range
  The CLI reads the frames as --left DIR/left/%06d.png --right DIR/right/%06d.png.

Options:
  --out DIR               output folder (created)
  --frames N              number of frames (default 100)
  --first N               index of the first frame (default 0; frame i is at time i / fps)
  --width W, --height H   image size (default 960 x 540)
  --seed S                random seed (default 1)
  --fps F                 frame rate (default 25)
  --distorted             plumb_bob lenses and misaligned cameras (raw != rectified); the YAML
                          then holds the rectification (R, P) and the ground truth stays rectified
  --instruments N         number of instruments, 0..2 (default 1)
  --instrument-speed X    instrument speed factor (default 1)
  --textureless-instrument  plain metal without brushed texture or markings
  --no-specular           matte tissue (no highlights on the tissue)
  --noise SIGMA           sensor noise, grey levels (default 1.5)
  --blur N                motion blur: N sub-frame renders over --exposure (default 1 = none)
  --exposure S            exposure time for motion blur, s (default 0.02)
  --interlaced            odd rows are a second field captured half a frame later
  --no-gt                 do not write gt/, nonocc/, instrument/, specular/
  --no-images             do not write left/ and right/ PNGs (e.g. with --bag only)
  --threads N             worker threads (0 = OpenCV's default); output does not depend on it

ROS bag:
  --bag FILE.bag          also write a bag with <ns>/left/image_raw, <ns>/right/image_raw
                          (sensor_msgs/Image, bgr8) and <ns>/left/camera_info,
                          <ns>/right/camera_info, all four with the same stamp per frame
  --namespace NS          topic namespace (default /endoscope)
  --start-time T          stamp of frame 0, s since the epoch (default 1600000000)
  --bag-gt                also write <ns>/ground_truth/disparity (32FC1, rectified left)
  --bag-compression C     none (default), lz4 or bz2
  -h, --help              this text
)";

bool makeDir(const std::string& path) {
  if (mkdir(path.c_str(), 0755) == 0) return true;
  struct stat st;
  return stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

std::string frameName(int index, const char* ext) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06d.%s", index, ext);
  return buf;
}

void fillCameraInfo(const endo_stereo::CameraCalibration& c, sensor_msgs::CameraInfo& msg) {
  msg.width = uint32_t(c.width);
  msg.height = uint32_t(c.height);
  msg.distortion_model = c.distortion_model;
  msg.D = c.D;
  for (int i = 0; i < 9; ++i) msg.K[i] = c.K.val[i];
  for (int i = 0; i < 9; ++i) msg.R[i] = c.R.val[i];
  for (int i = 0; i < 12; ++i) msg.P[i] = c.P.val[i];
  msg.binning_x = 0;
  msg.binning_y = 0;
  msg.header.frame_id = c.frame_id;
}

void fillImage(const cv::Mat& img, const std::string& encoding, int elem_bytes,
               sensor_msgs::Image& msg) {
  msg.width = uint32_t(img.cols);
  msg.height = uint32_t(img.rows);
  msg.encoding = encoding;
  msg.is_bigendian = 0;
  msg.step = uint32_t(img.cols * elem_bytes);
  msg.data.resize(size_t(msg.step) * img.rows);
  for (int y = 0; y < img.rows; ++y) {
    std::memcpy(&msg.data[size_t(y) * msg.step], img.ptr(y), msg.step);
  }
}

using endo_stereo::tools::ArgReader;

// An output that cannot be written (kExitOutput); an empty message prints no line.
struct OutputError {
  std::string message;
};

// --first, --fps and --threads take any integer or number: parseArgs checks --first, the scene's
// parameters --fps, and --threads goes to cv::setNumThreads as given.
endo_stereo::tools::SharedRanges sharedRanges() {
  endo_stereo::tools::SharedRanges r;
  r.first_min = INT_MIN;
  r.threads_min = INT_MIN;
  r.fps_positive = false;
  return r;
}

// The shared flags (tool_args.hpp) this tool takes (its fps is params.fps), and its own.
struct Options : endo_stereo::tools::SharedOptions {
  Options()
      : SharedOptions(endo_stereo::tools::kFlagFirst | endo_stereo::tools::kFlagFps |
                          endo_stereo::tools::kFlagThreads | endo_stereo::tools::kFlagBag |
                          endo_stereo::tools::kFlagOutDir,
                      sharedRanges()) {
    fps = params.fps;
  }
  endo_stereo::SurgicalSceneParams params;
  std::string compression = "none";
  int frames = 100;
  double start_time = 1600000000.0;
  bool write_gt = true, write_images = true, bag_gt = false;
};

// The scene: --frames, --width, --height, --seed, --distorted, --instruments, --instrument-speed,
// --textureless-instrument.
bool readSceneOption(ArgReader& args, Options& o) {
  endo_stereo::SurgicalSceneParams& params = o.params;
  if (args.is("--frames")) {
    o.frames = args.integer();
  } else if (args.is("--width")) {
    params.width = args.integer();
  } else if (args.is("--height")) {
    params.height = args.integer();
  } else if (args.is("--seed")) {
    // a 32-bit seed, negative values taken modulo 2^32
    params.seed = uint64_t(uint32_t(args.integer64(INT32_MIN, UINT32_MAX)));
  } else if (args.is("--distorted")) {
    params.distorted = true;
  } else if (args.is("--instruments")) {
    params.instruments = args.integer();
  } else if (args.is("--instrument-speed")) {
    params.instrument_speed = args.number();
  } else if (args.is("--textureless-instrument")) {
    params.instrument_texture = 0.0;
  } else {
    return false;
  }
  return true;
}

// The camera's picture: --no-specular, --noise, --blur, --exposure, --interlaced.
bool readImagingOption(ArgReader& args, Options& o) {
  endo_stereo::SurgicalSceneParams& params = o.params;
  if (args.is("--no-specular")) {
    params.specular_strength = 0.0;
  } else if (args.is("--noise")) {
    params.noise_sigma = args.number();
  } else if (args.is("--blur")) {
    params.motion_blur_samples = args.integer();
  } else if (args.is("--exposure")) {
    params.exposure_s = args.number();
  } else if (args.is("--interlaced")) {
    params.interlaced = true;
  } else {
    return false;
  }
  return true;
}

// What is written: --no-gt, --no-images, --start-time, --bag-gt, --bag-compression.
bool readOutputOption(ArgReader& args, Options& o) {
  if (args.is("--no-gt")) {
    o.write_gt = false;
  } else if (args.is("--no-images")) {
    o.write_images = false;
  } else if (args.is("--start-time")) {
    o.start_time = args.number();
  } else if (args.is("--bag-gt")) {
    o.bag_gt = true;
  } else if (args.is("--bag-compression")) {
    o.compression = args.text();
  } else {
    return false;
  }
  return true;
}

Options parseArgs(int argc, char** argv) {
  Options o;
  endo_stereo::tools::readArguments(argc, argv, kUsage, o, [&o](ArgReader& args) {
    return readSceneOption(args, o) || readImagingOption(args, o) || readOutputOption(args, o);
  });
  o.params.fps = o.fps;
  if (o.out_dir.empty() && o.bag.empty()) {
    throw UsageError("give --out DIR and/or --bag FILE (see --help)");
  }
  if (o.out_dir.empty()) o.write_images = o.write_gt = false;
  if (o.frames < 1 || o.first < 0) throw UsageError("--frames must be >= 1 and --first >= 0");
  if (o.compression != "none" && o.compression != "lz4" && o.compression != "bz2") {
    throw UsageError("--bag-compression must be none, lz4 or bz2");
  }
  if (!(o.start_time > 0)) throw UsageError("--start-time must be > 0");
  return o;
}

// "/" or "/NS/" for the namespace @p ns (a leading slash added, trailing ones dropped).
std::string topicPrefix(std::string ns) {
  while (ns.size() > 1 && ns.back() == '/') ns.pop_back();
  if (ns.empty() || ns[0] != '/') ns = "/" + ns;
  return ns == "/" ? "/" : ns + "/";
}

// DIR and the subfolders of the files asked for.
void makeFolders(const Options& o) {
  if (!makeDir(o.out_dir)) throw OutputError{"cannot create " + o.out_dir};
  for (const char* sub : {"left", "right"}) {
    if (o.write_images && !makeDir(o.out_dir + "/" + sub)) throw OutputError{""};
  }
  for (const char* sub : {"gt", "nonocc", "instrument", "specular"}) {
    if (o.write_gt && !makeDir(o.out_dir + "/" + sub)) throw OutputError{""};
  }
}

// DIR/left.yaml, DIR/right.yaml and DIR/sequence.yaml.
void writeSequenceFiles(const Options& o, const endo_stereo::SurgicalScene& scene) {
  const endo_stereo::SurgicalSceneParams& params = o.params;
  const endo_stereo::StereoCalibration& calib = scene.calibration();
  std::string error;
  if (!endo_stereo::saveCameraInfoYaml(o.out_dir + "/left.yaml", calib.left, "endoscope_left",
                                       &error) ||
      !endo_stereo::saveCameraInfoYaml(o.out_dir + "/right.yaml", calib.right, "endoscope_right",
                                       &error)) {
    throw OutputError{error};
  }
  int d_min = 0, d_max = 0;
  scene.suggestedDisparityRange(&d_min, &d_max);
  const endo_stereo::RectifiedGeometry geo = scene.geometry();
  std::ofstream meta(o.out_dir + "/sequence.yaml");
  meta << "# endo_stereo_generate: synthetic surgical stereo sequence\n"
       << "frames: " << o.frames << "\nfirst: " << o.first << "\nfps: " << params.fps
       << "\nwidth: " << params.width << "\nheight: " << params.height << "\nseed: " << params.seed
       << "\ndistorted: " << (params.distorted ? "true" : "false")
       << "\ninterlaced: " << (params.interlaced ? "true" : "false")
       << "\ninstruments: " << params.instruments << "\nnoise_sigma: " << params.noise_sigma
       << "\nmotion_blur_samples: " << params.motion_blur_samples << "\nfocal_px: " << geo.f_px
       << "\nbaseline_m: " << geo.baseline_m << "\ndoffs_px: " << geo.doffs()
       << "\nmin_disparity: " << d_min << "\nmax_disparity: " << d_max
       << "\nleft: left/%06d.png\nright: right/%06d.png"
       << "\nground_truth: gt/%06d.pfm\nnonocc: nonocc/%06d.png\n";
  if (!meta) throw OutputError{"cannot write " + o.out_dir + "/sequence.yaml"};
}

// The bag of --bag (null without one), compressed as --bag-compression says.
std::unique_ptr<rosbag::Bag> openBag(const Options& o) {
  if (o.bag.empty()) return nullptr;
  try {
    auto bag = std::make_unique<rosbag::Bag>(o.bag, rosbag::bagmode::Write);
    if (o.compression == "lz4") bag->setCompression(rosbag::compression::LZ4);
    if (o.compression == "bz2") bag->setCompression(rosbag::compression::BZ2);
    return bag;
  } catch (const std::exception& e) {
    throw OutputError{"cannot open bag " + o.bag + ": " + e.what()};
  }
}

// A frame's images, ground truth and masks in DIR, as asked for.
void writeFrameFiles(const Options& o, const endo_stereo::SurgicalFrame& frame, int index) {
  const std::vector<int> png_flags{cv::IMWRITE_PNG_COMPRESSION, 1};
  const std::string name_png = frameName(index, "png");
  const std::string& out_dir = o.out_dir;
  try {
    if (o.write_images) {
      if (!cv::imwrite(out_dir + "/left/" + name_png, frame.left, png_flags) ||
          !cv::imwrite(out_dir + "/right/" + name_png, frame.right, png_flags)) {
        throw OutputError{"cannot write images of frame " + std::to_string(index)};
      }
    }
    if (o.write_gt) {
      std::string error;
      if (!endo_stereo::writePfm(out_dir + "/gt/" + frameName(index, "pfm"), frame.gt_disparity,
                                 &error)) {
        throw OutputError{error};
      }
      const cv::Mat nonocc = frame.visibility == endo_stereo::kVisibleBoth;
      if (!cv::imwrite(out_dir + "/nonocc/" + name_png, nonocc, png_flags) ||
          !cv::imwrite(out_dir + "/instrument/" + name_png, frame.instrument_mask, png_flags) ||
          !cv::imwrite(out_dir + "/specular/" + name_png, frame.left_specular, png_flags)) {
        throw OutputError{"cannot write masks of frame " + std::to_string(index)};
      }
    }
  } catch (const cv::Exception& e) {
    throw OutputError{e.what()};
  }
}

// A frame's messages in the bag: both images and camera_infos under @p prefix with one stamp,
// and with --bag-gt the ground truth.
void writeBagFrame(const Options& o, rosbag::Bag& bag, const std::string& prefix,
                   const endo_stereo::StereoCalibration& calib,
                   const endo_stereo::SurgicalFrame& frame, int index) {
  const ros::Time stamp(o.start_time + frame.stamp_s);
  sensor_msgs::Image left, right;
  sensor_msgs::CameraInfo left_info, right_info;
  fillImage(frame.left, "bgr8", 3, left);
  fillImage(frame.right, "bgr8", 3, right);
  fillCameraInfo(calib.left, left_info);
  fillCameraInfo(calib.right, right_info);
  for (auto* h : {&left.header, &right.header, &left_info.header, &right_info.header}) {
    h->stamp = stamp;
    h->seq = uint32_t(index);
  }
  left.header.frame_id = calib.left.frame_id;
  right.header.frame_id = calib.right.frame_id;
  try {
    bag.write(prefix + "left/image_raw", stamp, left);
    bag.write(prefix + "left/camera_info", stamp, left_info);
    bag.write(prefix + "right/image_raw", stamp, right);
    bag.write(prefix + "right/camera_info", stamp, right_info);
    if (o.bag_gt) {
      sensor_msgs::Image gt;
      fillImage(frame.gt_disparity, "32FC1", 4, gt);
      gt.header = left.header;
      bag.write(prefix + "ground_truth/disparity", stamp, gt);
    }
  } catch (const std::exception& e) {
    throw OutputError{std::string("writing the bag failed: ") + e.what()};
  }
}

// Renders every frame and writes it to the files and the bag (null: none), with a progress line
// every 25 frames and at the end. @return the seconds spent rendering.
double writeFrames(const Options& o, const endo_stereo::SurgicalScene& scene, rosbag::Bag* bag,
                   const std::string& prefix) {
  endo_stereo::SurgicalFrame frame;
  double render_s = 0.0;
  for (int k = 0; k < o.frames; ++k) {
    const int index = o.first + k;
    const auto r0 = std::chrono::steady_clock::now();
    scene.render(index, frame);
    render_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - r0).count();
    writeFrameFiles(o, frame, index);
    if (bag) writeBagFrame(o, *bag, prefix, scene.calibration(), frame, index);
    if ((k + 1) % 25 == 0 || k + 1 == o.frames) {
      std::cerr << "endo_stereo_generate: " << (k + 1) << "/" << o.frames << " frames\n";
    }
  }
  return render_s;
}

// The scene's parameters checked, the folder's files, every frame; then the figures on stdout.
int generate(const Options& o) {
  const std::string prefix = topicPrefix(o.ns);
  const std::string error = o.params.validate();
  if (!error.empty()) throw UsageError(error);
  cv::setNumThreads(o.threads);

  const auto t0 = std::chrono::steady_clock::now();
  endo_stereo::SurgicalScene scene(o.params);
  if (!o.out_dir.empty()) {
    makeFolders(o);
    writeSequenceFiles(o, scene);
  }
  const std::unique_ptr<rosbag::Bag> bag = openBag(o);
  const double render_s = writeFrames(o, scene, bag.get(), prefix);
  if (bag) bag->close();
  const double total_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  int d_min = 0, d_max = 0;
  scene.suggestedDisparityRange(&d_min, &d_max);
  std::cout << "frames: " << o.frames << "\nsize: " << o.params.width << "x" << o.params.height
            << "\nrender_s_per_frame: " << render_s / o.frames << "\ntotal_s: " << total_s
            << "\nsuggested_disparity_range: [" << d_min << ", " << d_max << "]\n";
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return generate(parseArgs(argc, argv));
  } catch (const UsageError& e) {
    std::cerr << "endo_stereo_generate: " << e.what() << "\n";
    return kExitUsage;
  } catch (const OutputError& e) {
    if (!e.message.empty()) std::cerr << "endo_stereo_generate: " << e.message << "\n";
    return kExitOutput;
  }
}
