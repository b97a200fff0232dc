// `visloc bench pairs`: two-view estimation on neighbouring image pairs of
// the Strecha scenes (castle-P30 and castle-P19: repeated windows; entry-P10,
// fountain-P11), against the fundamental matrix of their laser ground-truth
// cameras, and optionally on synthetic facade pairs rendered by `visloc synth
// city` (truth: the rendered poses). Methods: classic, 1m (fixed iterations), 1m-sprt (this library)
// and OpenCV's findFundamentalMat with USAC_MAGSAC and with RANSAC on the
// same 1-1 matches (threshold × √2: OpenCV bounds both point-line distances,
// the Sampson distance is about a line distance / √2).
//
// Truth correspondences of a pair: the matches (any 1-M candidate) within
// truth_px of the true F's epipolar lines (symmetric distance). A method
// succeeds when its F puts them, median, within success_px of its epipolar
// lines. Its true inliers are its inliers within success_px under the true F.
// Epipolar distances cannot tell a match from a wrong one further along the
// same epipolar line (a window beside the true one on a horizontal facade
// seen from a horizontal baseline): both counts include such matches.
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/features/sift_extractor.h"

namespace visloc {

// Strecha's camera file: K (3 lines), distortion, R (camera to world, 3
// lines), centre C, width height. Throws Error naming the file (kIo:
// cannot be read; kFormat: not a camera).
struct StrechaCamera {
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d world_from_camera = Eigen::Matrix3d::Identity();
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  int width = 0, height = 0;
};
StrechaCamera read_strecha_camera(const std::filesystem::path& path);

// F with x2ᵀ F x1 = 0 for pixels of camera 1 and camera 2.
Eigen::Matrix3d fundamental_between(const StrechaCamera& camera1, const StrechaCamera& camera2);

struct PairBenchmarkOptions {
  std::filesystem::path strecha_dir;  // ../shared/data/strecha
  std::vector<std::string> scenes = {"castle-P30", "castle-P19", "entry-P10", "fountain-P11"};
  // Synthetic facade pairs: folders written by `visloc synth city` (images
  // pPPPPP_hHH_eE.jpg, known poses in sparse/). A pair is one heading seen
  // from two neighbouring placemarks; truth from the rendered poses. The
  // scene is named "synthetic:<folder name>" and summarized apart.
  std::vector<std::filesystem::path> synthetic_cities;
  int max_pairs_per_scene = 0;        // 0: every neighbouring pair (i, i+1)
  SiftOptions sift;
  double threshold_px = 2.0;          // RANSAC inlier threshold (all methods)
  double truth_px = 1.0;
  double success_px = 2.0;
  size_t fixed_iterations = 1000;     // 1m
  bool opencv = true;
  uint64_t seed = 1;
  void validate() const;
};

class OptionTable;
// `visloc bench pairs`' options: --data, --scenes, --max-pairs, --threshold,
// --iterations, --max-features, --no-opencv, --seed.
void add_options(OptionTable& table, PairBenchmarkOptions& options);

struct PairBenchmarkRow {
  std::string scene, pair, method;
  bool found = false, success = false;
  double median_error_px = -1;  // of the truth correspondences under the estimated F
  size_t inliers = 0, true_inliers = 0, truth_correspondences = 0;
  double ms = 0;
};

struct PairBenchmarkResult {
  std::vector<PairBenchmarkRow> rows;
  nlohmann::json report;  // config, per-row results, summaries, expectations
  std::string markdown;
};

// `progress` (may be empty) receives one line per pair.
PairBenchmarkResult run_pair_benchmark(const PairBenchmarkOptions& options,
                                       const std::function<void(const std::string&)>& progress = {});

}  // namespace visloc
