// endo_stereo_bench: scores our matcher and its peers (OpenCV StereoBM, StereoSGBM and
// cv::stereo::QuasiDenseStereo) on the same frames in the same run, times them, measures peak
// memory, and sweeps the precision-density trade-off. `make bench` runs it (scripts/bench.sh).
//
// Protocol (evaluation.hpp, the Middlebury convention): error rates bad1 / bad2 count the pixels a
// method output within the nonocc mask; density = output pixels / ground-truth pixels there.
// Timings are medians of repeated runs, methods interleaved within each repetition so that a
// change of machine load affects all of them alike.
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stereo/quasi_dense_stereo.hpp>
#include <string>
#include <vector>

#include "endo_stereo/core/evaluation.hpp"
#include "endo_stereo/core/image_io.hpp"
#include "endo_stereo/core/matcher.hpp"
#include "endo_stereo/core/params_io.hpp"
#include "json_writer.hpp"
#include "tool_args.hpp"
#include "machine_info.hpp"
#include "surgical_scene.hpp"
#include "synthetic_scene.hpp"

extern char** environ;

namespace {

using endo_stereo::tools::cpuModel;
using endo_stereo::tools::loadAverage;

using endo_stereo::tools::JsonWriter;
using Clock = std::chrono::steady_clock;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

const char* kUsage = R"(endo_stereo_bench - score and time endo_stereo against OpenCV's matchers

Usage: endo_stereo_bench [options]
  --root DIR        repository root (presets in DIR/config; default: the source tree built from)
  --data DIR        Middlebury scenes (default: ROOT/../shared/data/middlebury)
  --repeats N       timed repetitions per method and scene, median reported (default 5)
  --json FILE       machine-readable results (default: ROOT/docs/benchmark_results.json)
  --curve FILE      precision-density sweep as CSV (default: ROOT/docs/precision_density.csv)
  --quick           1 repetition, a short sweep, no memory probe (a smoke test)
  --timing-only     only the 960x540 timing table (printed; no scoring, no files written)
  --help
)";

struct Options {
  std::string root = ES_SOURCE_DIR;
  std::string data;
  std::string json;
  std::string curve;
  int repeats = 5;
  bool quick = false;
  bool timing_only = false;
};

double processCpuMs() {
  timespec ts{};
  ::clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double msSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

bool dirExists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

// --- the methods -----------------------------------------------------------------------------

/// A scene as every method sees it: gray rectified pair, ground truth, masks, the search range.
struct Scene {
  std::string name;
  cv::Mat left, right;  // CV_8UC1
  cv::Mat gt;           // CV_32FC1, NaN unknown
  cv::Mat nonocc;       // CV_8UC1, 255 evaluated
  cv::Mat disc;         // CV_8UC1, 255 near discontinuities (may be empty)
  int min_disparity = 0;
  int num_disparities = 16;  // multiple of 16 (SGBM's and BM's granularity)
};

/// One matcher under test. compute() must leave a CV_32FC1 disparity with NaN = no output.
struct Method {
  std::string name;
  std::function<void(const Scene&)> prepare;  // build the object for this scene (not timed)
  std::function<void(const Scene&, cv::Mat&)> compute;
};

cv::Mat fromFixedPoint(const cv::Mat& disp16, int min_disparity) {
  // BM/SGBM write (min_disparity - 1) * 16 for "no disparity".
  cv::Mat out(disp16.size(), CV_32FC1);
  for (int y = 0; y < disp16.rows; ++y) {
    const int16_t* s = disp16.ptr<int16_t>(y);
    float* d = out.ptr<float>(y);
    for (int x = 0; x < disp16.cols; ++x) {
      d[x] = s[x] < min_disparity * 16 ? kNaN : s[x] / 16.0f;
    }
  }
  return out;
}

endo_stereo::PipelineParams loadPreset(const std::string& root, const std::string& name,
                                       std::string* note) {
  endo_stereo::PipelineParams p;
  const std::string path = root + "/config/" + name + ".yaml";
  if (!std::ifstream(path)) {
    *note = "preset " + path + " not found: built-in defaults used";
    return p;
  }
  const std::string err = endo_stereo::loadPipelineParams(path, p);
  if (!err.empty()) *note = "preset " + path + ": " + err + " (built-in defaults used)";
  return p;
}

// Ours as users run it: Pipeline::process on the gray pair (already rectified, mono8). Without
// @p keep_priors every call is the first frame of a stream (what endo_stereo_cli does with a single
// pair: the full search); with it the pipeline keeps its temporal state from call to call, 40 ms
// apart, so that after the first call the same pair is matched again with narrowed ranges (a
// still scene in steady state).
Method ourMethod(const std::string& name, const endo_stereo::PipelineParams& preset,
                 int threads = 0, bool keep_priors = false) {
  auto pipeline = std::make_shared<std::unique_ptr<endo_stereo::Pipeline>>();
  auto out = std::make_shared<endo_stereo::PipelineOutput>();
  auto stamp = std::make_shared<double>(0.0);
  Method m;
  m.name = name;
  m.prepare = [=](const Scene& s) {
    endo_stereo::PipelineParams p = preset;
    p.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
    p.output.point_cloud = false;
    p.output.fused = false;
    p.output.coverage = false;
    p.matcher.min_disparity = s.min_disparity;
    p.matcher.max_disparity = s.min_disparity + s.num_disparities - 1;
    p.matcher.num_threads = threads;
    *pipeline = std::make_unique<endo_stereo::Pipeline>(p);
    (*pipeline)->setColorOutput(false);
    *stamp = 0.0;
  };
  m.compute = [=](const Scene& s, cv::Mat& disparity) {
    if (!keep_priors) (*pipeline)->reset();
    const endo_stereo::StereoInput in{s.left, s.right, "mono8", "mono8", *stamp};
    *stamp += 0.04;
    std::string error;
    if (!(*pipeline)->process(in, *out, &error)) {
      throw std::runtime_error(s.name + ": " + error);
    }
    disparity = out->match.disparity;
  };
  return m;
}

cv::Ptr<cv::StereoSGBM> makeSgbm(int min_disparity, int num_disparities, int uniqueness = 10,
                                 int mode = cv::StereoSGBM::MODE_SGBM) {
  // The settings of OpenCV's samples/cpp/stereo_match.cpp, with blockSize 5 (P1 200, P2 800).
  const int bs = 5;
  return cv::StereoSGBM::create(min_disparity, num_disparities, bs, 8 * bs * bs, 32 * bs * bs,
                                /*disp12MaxDiff=*/1, /*preFilterCap=*/63, uniqueness,
                                /*speckleWindowSize=*/100, /*speckleRange=*/32, mode);
}

Method sgbmMethod(const std::string& name, int uniqueness = 10,
                  int mode = cv::StereoSGBM::MODE_SGBM) {
  auto sgbm = std::make_shared<cv::Ptr<cv::StereoSGBM>>();
  auto raw = std::make_shared<cv::Mat>();
  Method m;
  m.name = name;
  m.prepare = [=](const Scene& s) {
    *sgbm = makeSgbm(s.min_disparity, s.num_disparities, uniqueness, mode);
  };
  m.compute = [=](const Scene& s, cv::Mat& disparity) {
    (*sgbm)->compute(s.left, s.right, *raw);
    disparity = fromFixedPoint(*raw, s.min_disparity);
  };
  return m;
}

Method bmMethod() {
  auto bm = std::make_shared<cv::Ptr<cv::StereoBM>>();
  auto raw = std::make_shared<cv::Mat>();
  Method m;
  m.name = "OpenCV BM";
  m.prepare = [=](const Scene& s) {
    // samples/cpp/stereo_match.cpp settings (blockSize 9).
    *bm = cv::StereoBM::create(s.num_disparities, 9);
    (*bm)->setMinDisparity(s.min_disparity);
    (*bm)->setPreFilterCap(31);
    (*bm)->setTextureThreshold(10);
    (*bm)->setUniquenessRatio(15);
    (*bm)->setSpeckleWindowSize(100);
    (*bm)->setSpeckleRange(32);
    (*bm)->setDisp12MaxDiff(1);
  };
  m.compute = [=](const Scene& s, cv::Mat& disparity) {
    (*bm)->compute(s.left, s.right, *raw);
    disparity = fromFixedPoint(*raw, s.min_disparity);
  };
  return m;
}

Method quasiDenseMethod() {
  auto qds = std::make_shared<cv::Ptr<cv::stereo::QuasiDenseStereo>>();
  Method m;
  m.name = "OpenCV QuasiDense";
  m.prepare = [=](const Scene& s) {
    *qds = cv::stereo::QuasiDenseStereo::create(s.left.size());  // default parameters
  };
  m.compute = [=](const Scene& s, cv::Mat& disparity) {
    (*qds)->process(s.left, s.right);
    cv::Mat d = (*qds)->getDisparity();
    d.convertTo(disparity, CV_32F);
    // Unmatched pixels come back as 0: not output. (Every scene here has disparities >= 1, so
    // a true disparity of 0 is not lost.)
    disparity.setTo(kNaN, d == 0);
  };
  return m;
}

// --- scenes ----------------------------------------------------------------------------------

int roundUp16(int n) { return (n + 15) / 16 * 16; }

Scene fromMiddlebury(const endo_stereo::MiddleburyScene& m) {
  Scene s;
  s.name = m.name;
  s.left = m.left;
  s.right = m.right;
  s.gt = m.gt;
  s.nonocc = m.nonocc;
  s.disc = m.disc;
  s.min_disparity = 0;
  s.num_disparities = roundUp16(m.max_disp + 1);
  return s;
}

cv::Mat toGray(const cv::Mat& bgr) {
  cv::Mat g;
  cv::cvtColor(bgr, g, cv::COLOR_BGR2GRAY);  // BT.601 luma, as the pipeline converts
  return g;
}

// Pixels within 2 px of a ground-truth disparity step > 1 px, inside the evaluated mask: the
// Middlebury "disc" mask, rebuilt for scenes that come without one.
cv::Mat discontinuityMask(const cv::Mat& gt, const cv::Mat& nonocc) {
  cv::Mat step(gt.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < gt.rows; ++y) {
    for (int x = 0; x < gt.cols; ++x) {
      const float d = gt.at<float>(y, x);
      const float r = x + 1 < gt.cols ? gt.at<float>(y, x + 1) : d;
      const float b = y + 1 < gt.rows ? gt.at<float>(y + 1, x) : d;
      if (std::abs(d - r) > 1.f || std::abs(d - b) > 1.f) step.at<uint8_t>(y, x) = 255;
    }
  }
  cv::dilate(step, step, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5)));
  cv::Mat disc;
  cv::bitwise_and(step, nonocc, disc);
  return disc;
}

Scene surgicalScene(int width, int height, int num_disparities, int frame_index) {
  endo_stereo::SurgicalSceneParams p;
  p.width = width;
  p.height = height;
  p.seed = 7;
  endo_stereo::SurgicalScene scene(p);
  endo_stereo::SurgicalFrame f;
  scene.render(frame_index, f);
  Scene s;
  s.name = "surgical " + std::to_string(width) + "x" + std::to_string(height);
  s.left = toGray(f.left);
  s.right = toGray(f.right);
  s.gt = f.gt_disparity.clone();
  s.nonocc = f.visibility == endo_stereo::kVisibleBoth;
  s.disc = discontinuityMask(s.gt, s.nonocc);
  double lo = 0, hi = 0;
  cv::minMaxLoc(s.gt, &lo, &hi, nullptr, nullptr, s.nonocc);
  const double centre = 0.5 * (lo + hi);
  s.num_disparities = num_disparities;
  // A fixed-width range around the scene's disparities, starting at 0 when that covers them
  // (0..63 is the usual full search of a 960x540 endoscope frame).
  s.min_disparity = std::max(0, static_cast<int>(std::floor(centre - num_disparities / 2.0)));
  if (hi - lo > num_disparities - 8) {
    std::cerr << "note: " << s.name << " disparities span " << hi - lo << " px, more than "
              << num_disparities << " - 8\n";
  }
  return s;
}

Scene slantedScene() {
  endo_stereo::SyntheticSceneParams p;
  p.width = 640;
  p.height = 480;
  p.seed = 11;
  p.base_disparity_px = 20.0;
  p.slope_x = 0.02;
  p.slope_y = 0.01;
  p.curvature = 2e-5;
  p.noise_stdev = 2.0;
  p.occluder = cv::Rect(250, 150, 140, 160);
  p.occluder_disparity_px = 40.0;
  p.textureless = cv::Rect(60, 330, 90, 90);
  p.saturated = cv::Rect(480, 60, 80, 60);
  const endo_stereo::SyntheticScene syn = endo_stereo::makeSyntheticScene(p);
  Scene s;
  s.name = "synthetic slanted+occluder 640x480";
  s.left = syn.left;
  s.right = syn.right;
  s.gt = syn.disparity;
  s.nonocc = syn.occluded == 0;
  s.disc = discontinuityMask(s.gt, s.nonocc);
  s.min_disparity = 0;
  s.num_disparities = 64;
  return s;
}

// --- runs ------------------------------------------------------------------------------------

struct Row {
  std::string scene, method;
  endo_stereo::DisparityScore nonocc, disc;
  double median_ms = 0;
  std::vector<double> times_ms;
  double median_cpu_ms = 0;  // CPU time of the whole process (all threads) during the call
  std::vector<double> cpu_ms;
  double ratio_sgbm = 0;  // median time / SGBM's median time on the same scene
};

std::vector<Row> runScene(const Scene& s, std::vector<Method>& methods, int repeats) {
  std::vector<Row> rows(methods.size());
  std::vector<cv::Mat> outputs(methods.size());
  for (size_t m = 0; m < methods.size(); ++m) methods[m].prepare(s);
  for (int r = 0; r < repeats; ++r) {
    for (size_t m = 0; m < methods.size(); ++m) {
      const double cpu = processCpuMs();
      const auto t = Clock::now();
      methods[m].compute(s, outputs[m]);
      rows[m].times_ms.push_back(msSince(t));
      rows[m].cpu_ms.push_back(processCpuMs() - cpu);
    }
  }
  double sgbm_ms = 0;
  for (size_t m = 0; m < methods.size(); ++m) {
    rows[m].scene = s.name;
    rows[m].method = methods[m].name;
    rows[m].median_ms = median(rows[m].times_ms);
    rows[m].median_cpu_ms = median(rows[m].cpu_ms);
    rows[m].nonocc = endo_stereo::scoreDisparity(outputs[m], s.gt, s.nonocc);
    if (!s.disc.empty()) rows[m].disc = endo_stereo::scoreDisparity(outputs[m], s.gt, s.disc);
    if (methods[m].name == "OpenCV SGBM") sgbm_ms = rows[m].median_ms;
  }
  for (Row& r : rows) r.ratio_sgbm = sgbm_ms > 0 ? r.median_ms / sgbm_ms : 0;
  return rows;
}

void printRows(const std::vector<Row>& rows) {
  std::printf(
      "| scene | method | bad1 %% | bad2 %% | density %% | bad2 near edges %% | "
      "median ms | time / SGBM |\n|---|---|---:|---:|---:|---:|---:|---:|\n");
  for (const Row& r : rows) {
    std::printf("| %s | %s | %.2f | %.2f | %.1f | %.2f | %.1f | %.2f |\n", r.scene.c_str(),
                r.method.c_str(), 100 * r.nonocc.bad1, 100 * r.nonocc.bad2, 100 * r.nonocc.density,
                100 * r.disc.bad2, r.median_ms, r.ratio_sgbm);
  }
  std::fflush(stdout);
}

void writeScore(JsonWriter& j, const endo_stereo::DisparityScore& s) {
  j.beginObject();
  j.key("bad1").value(s.bad1).key("bad2").value(s.bad2).key("density").value(s.density);
  j.key("mean_abs_error_px").value(s.mean_abs_error);
  j.key("n_out").value(s.n_out).key("n_gt").value(s.n_gt);
  j.key("n_bad1").value(s.n_bad1).key("n_bad2").value(s.n_bad2);
  j.endObject();
}

void writeRows(JsonWriter& j, const std::vector<Row>& rows) {
  j.beginArray();
  for (const Row& r : rows) {
    j.beginObject();
    j.key("scene").value(r.scene).key("method").value(r.method);
    j.key("nonocc");
    writeScore(j, r.nonocc);
    j.key("disc");
    writeScore(j, r.disc);
    j.key("median_ms").value(r.median_ms).key("time_over_sgbm").value(r.ratio_sgbm);
    j.key("median_cpu_ms").value(r.median_cpu_ms);
    j.key("times_ms").beginArray();
    for (double t : r.times_ms) j.value(t);
    j.endArray();
    j.endObject();
  }
  j.endArray();
}

// --- peak memory: a fresh child process runs only our matcher -------------------------------

// The high-water mark of this process's resident memory (VmHWM), KiB. Unlike getrusage()'s
// ru_maxrss, which Linux carries across execve() from the parent, VmHWM belongs to the current
// address space, so a freshly spawned probe reports its own peak only.
long peakRssKib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::atol(line.c_str() + 6);
  }
  return -1;
}

// Child side: `--rss-probe OUT LEFT RIGHT MIN MAX MODE`, MODE full | prior | sgbm | none. Loads
// the pair, matches it three times, writes its peak RSS (KiB) to OUT and exits.
int rssProbe(int argc, char** argv) {
  if (argc < 8) return 2;
  const cv::Mat left = cv::imread(argv[3], cv::IMREAD_GRAYSCALE);
  const cv::Mat right = cv::imread(argv[4], cv::IMREAD_GRAYSCALE);
  if (left.empty() || right.empty()) return 3;
  const std::string mode = argv[7];
  endo_stereo::MatcherParams mp;
  if (!endo_stereo::tools::parseInt(argv[5], &mp.min_disparity) ||
      !endo_stereo::tools::parseInt(argv[6], &mp.max_disparity)) {
    return 2;
  }
  if (mode == "none") {
    // The baseline: the program and its libraries with the two images loaded, no matching.
  } else if (mode == "sgbm") {
    auto sgbm = makeSgbm(mp.min_disparity, mp.max_disparity - mp.min_disparity + 1);
    cv::Mat raw;
    for (int i = 0; i < 3; ++i) sgbm->compute(left, right, raw);
  } else {
    // Ours through Pipeline with the built-in defaults: "full" matches each pair as a first
    // frame (priors off), "prior" keeps the priors, so that the second and third calls search
    // narrowed ranges around the previous call's disparities.
    endo_stereo::PipelineParams p;
    p.rectify.mode = endo_stereo::RectifyMode::kPassThrough;
    p.output.point_cloud = false;
    p.matcher.min_disparity = mp.min_disparity;
    p.matcher.max_disparity = mp.max_disparity;
    p.temporal.enabled = mode == "prior";
    endo_stereo::Pipeline pipeline(p);
    pipeline.setColorOutput(false);
    endo_stereo::PipelineOutput out;
    std::string error;
    for (int i = 0; i < 3; ++i) {
      if (!pipeline.process({left, right, "mono8", "mono8", 0.04 * i}, out, &error)) return 3;
    }
  }
  std::ofstream(argv[2]) << peakRssKib() << "\n";
  return 0;
}

// Parent side: spawns this program as a probe. @return its peak RSS in MiB, NaN on failure.
double probePeakRss(const std::string& out_file, const std::vector<std::string>& args) {
  std::vector<std::string> all = {"endo_stereo_bench", "--rss-probe", out_file};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : all) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  char exe[4096];
  const ssize_t n = ::readlink("/proc/self/exe", exe, sizeof(exe) - 1);
  if (n <= 0) return std::numeric_limits<double>::quiet_NaN();
  exe[n] = '\0';
  pid_t pid = 0;
  if (posix_spawn(&pid, exe, nullptr, nullptr, argv.data(), environ) != 0) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  long kib = -1;
  std::ifstream(out_file) >> kib;
  std::remove(out_file.c_str());
  return kib > 0 ? kib / 1024.0 : std::numeric_limits<double>::quiet_NaN();
}

Options parseArgs(int argc, char** argv) {
  Options o;
  endo_stereo::tools::ArgReader args(argc, argv);
  while (args.next()) {
    if (args.is("--help") || args.is("-h")) {
      std::cout << kUsage;
      std::exit(0);
    } else if (args.is("--root")) {
      o.root = args.text();
    } else if (args.is("--data")) {
      o.data = args.text();
    } else if (args.is("--repeats")) {
      o.repeats = args.integer(1);
    } else if (args.is("--json")) {
      o.json = args.text();
    } else if (args.is("--curve")) {
      o.curve = args.text();
    } else if (args.is("--quick")) {
      o.quick = true;
    } else if (args.is("--timing-only")) {
      o.timing_only = true;
    } else {
      args.unknown();
    }
  }
  return o;
}

// Reads the flags and fills in the defaults that depend on others. @return false on bad usage
// (reported).
bool readOptions(int argc, char** argv, Options* o) {
  try {
    *o = parseArgs(argc, argv);
  } catch (const endo_stereo::tools::UsageError& e) {
    std::cerr << "endo_stereo_bench: " << e.what() << "\n";
    return false;
  }
  if (o->quick) o->repeats = 1;
  if (o->data.empty()) o->data = o->root + "/../shared/data/middlebury";
  if (o->json.empty()) o->json = o->root + "/docs/benchmark_results.json";
  if (o->curve.empty()) o->curve = o->root + "/docs/precision_density.csv";
  return true;
}

/// When and with how many OpenCV threads the benchmark runs.
struct RunInfo {
  std::string date;
  int opencv_threads = 0;
};

// The title and the machine line.
RunInfo printHeader(const Options& o) {
  RunInfo info;
  info.opencv_threads = cv::getNumThreads();
  std::time_t now = std::time(nullptr);
  char date[64];
  std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M %Z", std::localtime(&now));
  info.date = date;
  std::printf(
      "# endo_stereo benchmark\n\nmachine: %s, %u logical CPUs, OpenCV %s with %d threads; "
      "%s; %d repetitions per timing (median); load average at start %s\n\n",
      cpuModel().c_str(), std::max(1u, static_cast<unsigned>(sysconf(_SC_NPROCESSORS_ONLN))),
      CV_VERSION, info.opencv_threads, date, o.repeats, loadAverage().c_str());
  return info;
}

/// The presets our matcher runs with.
struct Presets {
  endo_stereo::PipelineParams default_preset, paper;
};

// ROOT/config/default.yaml and paper.yaml; a warning for each that could not be read.
Presets loadPresets(const std::string& root) {
  std::string note_default, note_paper;
  Presets p;
  p.default_preset = loadPreset(root, "default", &note_default);
  p.paper = loadPreset(root, "paper", &note_paper);
  if (!note_default.empty()) std::printf("WARNING: %s\n", note_default.c_str());
  if (!note_paper.empty()) std::printf("WARNING: %s\n", note_paper.c_str());
  return p;
}

// The results' first keys: the machine and the settings.
void beginResults(JsonWriter& j, const Options& o, const RunInfo& info) {
  j.beginObject();
  j.key("date").value(info.date);
  j.key("cpu").value(cpuModel());
  j.key("opencv").value(CV_VERSION);
  j.key("opencv_threads").value(info.opencv_threads);
  j.key("repeats").value(o.repeats);
  j.key("load_average_start").value(loadAverage());
}

/// The scenes with ground truth: Middlebury's first, the 960x540 surgical scene last.
struct SceneSet {
  std::vector<Scene> scenes;
  bool have_middlebury = false;
  size_t num_middlebury = 0;  // how many of the first scenes are Middlebury's
};

// Middlebury's scenes (those found) and the synthetic slanted scene, unless --timing-only; the
// surgical 960x540 scene of the timing case.
SceneSet loadScenes(const Options& o) {
  SceneSet set;
  if (o.timing_only) {
    // Only the timing case below: no Middlebury scenes to load.
  } else if (!dirExists(o.data)) {
    std::printf(
        "SKIP Middlebury: data not found at %s (expected ../shared/data/middlebury "
        "beside the repository); scoring synthetic scenes only\n\n",
        o.data.c_str());
  } else {
    for (const char* name : {"tsukuba", "venus", "teddy"}) {
      try {
        set.scenes.push_back(fromMiddlebury(endo_stereo::loadMiddleburyScene(o.data + "/" + name)));
        set.have_middlebury = true;
      } catch (const std::exception& ex) {
        std::printf("SKIP Middlebury %s: %s\n", name, ex.what());
      }
    }
  }
  set.num_middlebury = set.scenes.size();
  if (!o.timing_only) set.scenes.push_back(slantedScene());  // the timing case needs only the next
  set.scenes.push_back(surgicalScene(960, 540, 64, 0));
  return set;
}

// --- 1. accuracy and speed on scenes with ground truth (the table unless --timing-only) ---------
void accuracySection(const Options& o, const SceneSet& set, const Presets& presets, JsonWriter& j) {
  std::vector<Method> methods = {ourMethod("ours (default)", presets.default_preset),
                                 ourMethod("ours (paper)", presets.paper), bmMethod(),
                                 sgbmMethod("OpenCV SGBM"), quasiDenseMethod()};
  std::vector<Row> all_rows;
  if (!o.timing_only) {
    std::printf("## Accuracy (nonocc mask; errors among output pixels) and time\n\n");
    for (const Scene& s : set.scenes) {
      std::fprintf(stderr, "scoring %s ...\n", s.name.c_str());
      const std::vector<Row> rows = runScene(s, methods, o.repeats);
      all_rows.insert(all_rows.end(), rows.begin(), rows.end());
    }
    printRows(all_rows);
  }
  j.key("middlebury_found").value(set.have_middlebury);
  j.key("accuracy");
  writeRows(j, all_rows);
}

void printTimingRows(const std::vector<Row>& rows) {
  std::printf(
      "| method | median ms | min ms | time / SGBM | median CPU ms | CPU / SGBM CPU | bad2 %% | "
      "density %% |\n|---|---:|---:|---:|---:|---:|---:|---:|\n");
  double sgbm_cpu = 0;
  for (const Row& r : rows) {
    if (r.method == "OpenCV SGBM") sgbm_cpu = r.median_cpu_ms;
  }
  for (const Row& r : rows) {
    std::printf("| %s | %.1f | %.1f | %.2f | %.1f | %.2f | %.2f | %.1f |\n", r.method.c_str(),
                r.median_ms, *std::min_element(r.times_ms.begin(), r.times_ms.end()), r.ratio_sgbm,
                r.median_cpu_ms, sgbm_cpu > 0 ? r.median_cpu_ms / sgbm_cpu : 0.0,
                100 * r.nonocc.bad2, 100 * r.nonocc.density);
  }
}

// --- 2. the 960x540, 64-disparity timing case on @p big ----------------------------------------
std::vector<Row> timingSection(const Options& o, const Scene& big,
                               const endo_stereo::PipelineParams& preset_default) {
  std::printf("\n## Timing at %dx%d, %d disparities [%d, %d] (%s)\n\n", big.left.cols,
              big.left.rows, big.num_disparities, big.min_disparity,
              big.min_disparity + big.num_disparities - 1, big.name.c_str());
  std::vector<Method> timing = {ourMethod("ours full search, 2 threads", preset_default, 2),
                                ourMethod("ours full search, 1 thread", preset_default, 1),
                                sgbmMethod("OpenCV SGBM"),
                                sgbmMethod("OpenCV SGBM 3WAY", 10, cv::StereoSGBM::MODE_SGBM_3WAY)};
  // Ours with priors in steady state: the same pair again, 40 ms later, its previous disparities
  // narrowing the search (+-4 px around each, temporal.prior_radius_px).
  timing.push_back(ourMethod("ours, priors (same pair again), 2 threads", preset_default, 2, true));
  timing.push_back(ourMethod("ours, priors (same pair again), 1 thread", preset_default, 1, true));
  const int timing_repeats = std::max(o.repeats, o.quick ? 1 : 7);
  const std::vector<Row> timing_rows = runScene(big, timing, timing_repeats);
  printTimingRows(timing_rows);
  std::printf("(load average after the timing: %s)\n", loadAverage().c_str());
  return timing_rows;
}

// Peak memory of a process running only our matcher on @p big (a fresh child process, so the
// benchmark's own scenes do not count), and of SGBM for reference.
void memorySection(const Scene& big, JsonWriter& j) {
  char tmpl[] = "/tmp/es_bench_XXXXXX";
  const char* dir = ::mkdtemp(tmpl);
  if (!dir) return;
  const std::string d(dir);
  cv::imwrite(d + "/l.png", big.left);
  cv::imwrite(d + "/r.png", big.right);
  const std::string lo = std::to_string(big.min_disparity);
  const std::string hi = std::to_string(big.min_disparity + big.num_disparities - 1);
  const std::string rss = d + "/rss.txt";
  const double rss_full = probePeakRss(rss, {d + "/l.png", d + "/r.png", lo, hi, "full"});
  const double rss_prior = probePeakRss(rss, {d + "/l.png", d + "/r.png", lo, hi, "prior"});
  const double rss_sgbm = probePeakRss(rss, {d + "/l.png", d + "/r.png", lo, hi, "sgbm"});
  const double rss_base = probePeakRss(rss, {d + "/l.png", d + "/r.png", lo, hi, "none"});
  std::printf(
      "\npeak RSS of a process matching one %dx%d pair: ours full search %.1f MiB, "
      "ours with priors (the pair three times) %.1f MiB, OpenCV SGBM %.1f MiB (the same process loading the images "
      "without matching: %.1f MiB)\n",
      big.left.cols, big.left.rows, rss_full, rss_prior, rss_sgbm, rss_base);
  j.key("peak_rss_mib").beginObject();
  j.key("ours_full").value(rss_full).key("ours_prior").value(rss_prior);
  j.key("sgbm").value(rss_sgbm).key("baseline_no_matching").value(rss_base);
  j.endObject();
  for (const char* f : {"/l.png", "/r.png"}) std::remove((d + f).c_str());
  ::rmdir(dir);
}

// Ours with the default preset and one knob set, through the same key names as the presets and
// --set (params_io.hpp).
Method oursWith(const endo_stereo::PipelineParams& preset_default, const std::string& key,
                double value) {
  endo_stereo::PipelineParams p = preset_default;
  char text[32];
  std::snprintf(text, sizeof(text), "%g", value);
  const std::string err = endo_stereo::setPipelineParam(p, key, text);
  if (!err.empty()) std::fprintf(stderr, "endo_stereo_bench: %s\n", err.c_str());
  return ourMethod("ours", p);
}

/// The sweep's points: a method with one knob's value on the first @p count scenes, each scene
/// and the pooled figures in the CSV, the pooled ones in the table and the JSON.
class SweepPoints {
 public:
  SweepPoints(const std::vector<Scene>& scenes, size_t count, std::ofstream& csv, JsonWriter& j)
      : scenes_(scenes), count_(count), csv_(csv), j_(j) {}

  void add(const std::string& method, const std::string& knob, double value, Method m) {
    int64_t out = 0, gt = 0, bad1 = 0, bad2 = 0;
    for (size_t i = 0; i < count_; ++i) {
      const Scene& s = scenes_[i];
      m.prepare(s);
      cv::Mat d;
      m.compute(s, d);
      const endo_stereo::DisparityScore sc = endo_stereo::scoreDisparity(d, s.gt, s.nonocc);
      out += sc.n_out;
      gt += sc.n_gt;
      bad1 += sc.n_bad1;
      bad2 += sc.n_bad2;
      csv_ << method << "," << knob << "," << value << "," << s.name << "," << sc.bad1 << ","
           << sc.bad2 << "," << sc.density << "," << sc.n_out << "," << sc.n_gt << "\n";
    }
    const double b1 = out ? double(bad1) / out : 0, b2 = out ? double(bad2) / out : 0;
    const double dens = gt ? double(out) / gt : 0;
    csv_ << method << "," << knob << "," << value << ",pooled," << b1 << "," << b2 << "," << dens
         << "," << out << "," << gt << "\n";
    std::printf("| %s | %s | %g | %.2f | %.2f | %.1f |\n", method.c_str(), knob.c_str(), value,
                100 * b2, 100 * b1, 100 * dens);
    std::fflush(stdout);
    j_.beginObject();
    j_.key("method").value(method).key("knob").value(knob).key("value").value(value);
    j_.key("bad1").value(b1).key("bad2").value(b2).key("density").value(dens);
    j_.endObject();
  }

 private:
  const std::vector<Scene>& scenes_;
  const size_t count_;
  std::ofstream& csv_;
  JsonWriter& j_;
};

// --- 3. precision-density: our knobs beside SGBM's uniquenessRatio (--curve, the JSON's "sweep") -
void sweepSection(const Options& o, const SceneSet& set,
                  const endo_stereo::PipelineParams& preset_default, JsonWriter& j) {
  std::printf("\n## Precision-density sweep (%s)\n\n",
              set.have_middlebury ? "pooled over the Middlebury scenes, nonocc"
                                  : "synthetic scenes only: Middlebury missing");
  const std::vector<double> deltas =
      o.quick ? std::vector<double>{0.05, 0.2}
              : std::vector<double>{0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6};
  const std::vector<double> jumps =
      o.quick ? std::vector<double>{2.0} : std::vector<double>{1.0, 1.5, 2.0, 3.0, 4.0, 6.0};
  const std::vector<int> uniqueness =
      o.quick ? std::vector<int>{5, 20}
              : std::vector<int>{0, 5, 10, 15, 20, 30, 40, 50, 60, 70, 80, 100};
  const size_t sweep_scenes = set.have_middlebury ? set.num_middlebury : set.scenes.size();
  std::ofstream csv(o.curve);
  csv << "method,knob,value,scene,bad1,bad2,density,n_out,n_gt\n";
  std::printf(
      "| method | knob | value | bad2 %% | bad1 %% | density %% |\n"
      "|---|---|---:|---:|---:|---:|\n");
  j.key("sweep").beginArray();
  SweepPoints sweep(set.scenes, sweep_scenes, csv, j);
  for (double dm : deltas) {
    sweep.add("ours (default)", "delta_min", dm, oursWith(preset_default, "matcher.delta_min", dm));
  }
  // The paper's knob is not monotone once the edge test is on (docs/method.md: pixels rejected at
  // small windows go on to larger ones, which fatten more); the edge test's threshold is the
  // knob that trades precision for density in the default preset, so it is swept too.
  for (double jump : jumps) {
    sweep.add("ours (default)", "edge_disparity_jump_px", jump,
              oursWith(preset_default, "matcher.edge_disparity_jump_px", jump));
  }
  for (int u : uniqueness) {
    sweep.add("OpenCV SGBM", "uniquenessRatio", u, sgbmMethod("OpenCV SGBM", u));
  }
  j.endArray();
}

// Closes the results and writes them to --json. @return the exit status.
int writeResults(const Options& o, JsonWriter& j) {
  j.endObject();
  std::ofstream json(o.json);
  json << j.str();
  if (!json) {
    std::cerr << "endo_stereo_bench: cannot write " << o.json << "\n";
    return 1;
  }
  std::printf("\nresults: %s\nsweep: %s\n", o.json.c_str(), o.curve.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc > 1 && std::string(argv[1]) == "--rss-probe") return rssProbe(argc, argv);
  Options o;
  if (!readOptions(argc, argv, &o)) return endo_stereo::tools::kExitUsage;
  const RunInfo info = printHeader(o);
  const Presets presets = loadPresets(o.root);
  JsonWriter j;
  beginResults(j, o, info);
  const SceneSet set = loadScenes(o);
  accuracySection(o, set, presets, j);
  const Scene& big = set.scenes.back();
  const std::vector<Row> timing_rows = timingSection(o, big, presets.default_preset);
  if (o.timing_only) return 0;
  j.key("timing_960x540");
  writeRows(j, timing_rows);
  if (!o.quick) memorySection(big, j);
  sweepSection(o, set, presets.default_preset, j);
  return writeResults(o, j);
}
