// `visloc bench pose`: robust absolute pose on synthetic correspondence sets
// with known truth (baselines/synthetic_correspondences.h), comparing in the
// same run classical RANSAC on the 1-1 matches, the one-many RANSAC with a
// fixed iteration count (paper settings 2/3) and with SPRT (setting 3+), and
// OpenCV's solvePnPRansac (P3P in RANSAC; USAC MAGSAC++), which see only the
// 1-1 matches and are always given the focal length (the true one for the
// uncalibrated family).
//
// Success: registered (≥ min inliers), rotation error < 2° and camera
// position error < 5% of the scene depth. Medians over all trials; a method
// that returns no pose counts as an infinite error.
//
// The (#4) expectations are evaluated on the measured figures and
// reported (PoseBenchmarkResult::expectations); pose_benchmark_test.cc
// asserts them on a small fixed-seed run.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/pose/one_many_ransac.h"

namespace visloc {

struct PoseBenchmarkOptions {
  // Problem families: "calibrated", "uncalibrated", "facade" (SyntheticFamily).
  std::vector<std::string> families{"calibrated", "uncalibrated", "facade"};
  std::vector<size_t> features{100, 500, 2000};              // query features N per problem
  std::vector<double> inlier_ratios{0.05, 0.15, 0.3, 0.6};   // of the 1-1 set
  int trials = 4;                  // problems per (family, features, inlier ratio)
  double noise_px = 1.0;           // pixel noise, standard deviation per axis
  size_t max_candidates = 5;       // candidate list length M (paper: 5)
  uint64_t seed = 1;               // of the problems and the estimators
  // Threshold, iteration caps, confidence, min_inliers of every method
  // (OpenCV's: threshold, confidence, min_inliers); `variant` and `seed` are
  // set per method and problem.
  RansacOptions ransac;
  int opencv_iterations = 10000;   // iteration cap of OpenCV's RANSACs
  bool opencv = true;              // run the OpenCV baselines
  void validate() const;           // throws Error(kInvalidArgument) naming the bad field
};

// One method on one family: over all its problems (inlier_ratio < 0) or over
// those of one inlier ratio.
struct PoseMethodSummary {
  std::string method, family;
  double inlier_ratio = -1;
  size_t trials = 0;
  double success_rate = 0;
  double median_rotation_error_deg = 0;  // infinite when most trials found no pose
  double median_position_error = 0;      // metres (the scene depth is 20 m)
  double median_inliers = 0;
  double median_ms = 0;
};

// An expectation of the issue, evaluated on the measured figures.
struct PoseExpectation {
  std::string expectation;
  bool holds = false;
  std::string measured;  // e.g. "23 vs 7 (3.29x)"
};

struct PoseBenchmarkResult {
  std::vector<PoseMethodSummary> overall;          // per family (in order), per method
  std::vector<PoseMethodSummary> by_inlier_ratio;  // per family, method, inlier ratio
  std::vector<PoseExpectation> expectations;
  double wall_s = 0;
  nlohmann::json report;  // methods, by_inlier_ratio, expectations, config, notes (`--json`)
  std::string table;      // the text report

  // The summary of `method` ("classic-ransac", "1m-fixed", "1m-sprt",
  // "opencv-p3p-ransac", "opencv-usac-magsac") on `family`, over all
  // ratios (inlier_ratio < 0) or one; nullptr when it was not run.
  const PoseMethodSummary* find(const std::string& method, const std::string& family,
                                double inlier_ratio = -1) const;
};

// The expectations on the overall figures (facade: 1-M SPRT has
// ≥ 1.5× the inliers of classical RANSAC and succeeds more often; per family:
// 1-M SPRT ≥ 10× faster than 1-M fixed-`fixed_iterations`, success within 1
// point of it, within 2× of classical RANSAC's time).
std::vector<PoseExpectation> pose_expectations(const std::vector<PoseMethodSummary>& overall,
                                               const std::vector<std::string>& families, size_t fixed_iterations);

// `progress` (may be empty) receives one line per family and problem size.
PoseBenchmarkResult run_pose_benchmark(const PoseBenchmarkOptions& options,
                                       const std::function<void(const std::string&)>& progress = {});

class OptionTable;
// The options but `features` as command-line options (bench/option_tables.cc): --family, --inlier-ratio,
// --trials, --noise, --max-candidates, --seed, --threshold, --max-iterations, --fixed-iterations,
// --opencv-iterations, --no-opencv.
void add_options(OptionTable& table, PoseBenchmarkOptions& options);

}  // namespace visloc
