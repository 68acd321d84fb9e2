// The clone-agreement test (test_simd_clones.cpp): the matcher is built once per SIMD clone, each
// build in a namespace of its own (the macro endo_stereo renamed, see CMakeLists.txt), and each
// exposes runMatcherForCloneTest in that namespace. Types here are global so that every build
// shares them.
#pragma once

#include <opencv2/core.hpp>

struct CloneTestOutput {
  cv::Mat disparity, code, confidence;
};

/// The two configurations the test runs: the default presets (depth-edge filter with its second
/// chance, post-filters) on a full search, and the same with per-pixel ranges @p lo / @p hi
/// (CV_16SC1; empty = full search). @p threads: MatcherParams::num_threads.
#define ES_DECLARE_CLONE_RUNNER(ns)                                                          \
  namespace ns {                                                                             \
  CloneTestOutput runMatcherForCloneTest(const cv::Mat& left, const cv::Mat& right,          \
                                         const cv::Mat& lo, const cv::Mat& hi, int threads); \
  }
