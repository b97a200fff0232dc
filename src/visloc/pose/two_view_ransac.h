// Two-view geometry with the paper's one-many RANSAC (Tran et al. III-B
// applied to image pairs, its facade figure): hypotheses from the 1-1
// matches (ratio 0.8), verification on the 1-M matches (ratio 0.9, up to M
// candidates per feature), SPRT pre-verification, in the same loop as the
// absolute pose (ransac_loop.h). Models: the fundamental matrix (7-point),
// the homography (4-point) or, with both cameras calibrated, the essential
// matrix (5-point); Sampson error (F, E) or transfer error (H) in pixels;
// then Levenberg-Marquardt on the inliers (each feature's best candidate)
// and the inliers chosen again.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string_view>
#include <vector>

#include "visloc/pose/one_many_ransac.h"
#include "visloc/pose/ransac_loop.h"

namespace visloc {

enum class TwoViewModel { kFundamental, kHomography, kEssential };
std::string_view to_string(TwoViewModel model);
// "F", "H", "E"; throws Error(kInvalidArgument) otherwise.
TwoViewModel parse_two_view_model(std::string_view name);

// Matches from image 1 to image 2: per feature of image 1, its candidates in
// image 2 best first (CSR), and whether its best one passed the strict
// ratio test (the hypothesis set).
struct TwoViewCorrespondences {
  std::vector<Eigen::Vector2d> points1;        // pixels, one per feature of image 1 with candidates
  std::vector<uint32_t> feature1;              // its index in image 1's features
  std::vector<uint32_t> candidate_offsets{0};  // size points1.size() + 1
  std::vector<Eigen::Vector2d> candidates;     // image-2 pixels
  std::vector<uint32_t> candidate_feature2;    // their indices in image 2's features
  std::vector<uint8_t> in_hypothesis_set;
  size_t size() const { return points1.size(); }
  void validate() const;  // throws Error(kInvalidArgument) when the arrays disagree
};

struct TwoViewOptions {
  TwoViewModel model = TwoViewModel::kFundamental;
  RansacVariant variant = RansacVariant::kOneManySprt;
  double threshold_px = 2.0;      // Sampson distance (F, E) or transfer error (H), pixels
  size_t max_iterations = 10000;  // cap of the adaptive variants
  size_t fixed_iterations = 5000; // samples of 1m-fixed
  double confidence = 0.9999;
  double sprt_delta0 = 0.01;
  bool refine = true;
  int refine_max_iterations = 20;
  uint64_t seed = 0;
  // Pixel-from-normalized calibrations, needed for kEssential.
  std::optional<Eigen::Matrix3d> calibration1, calibration2;
  void validate() const;
};

struct TwoViewEstimate {
  bool found = false;
  TwoViewModel model = TwoViewModel::kFundamental;
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Zero();       // F or H (pixels to pixels) or E (normalized)
  Eigen::Matrix3d fundamental = Eigen::Matrix3d::Zero();  // F in pixels (F, and E through the calibrations)
  size_t inliers = 0;             // features with a candidate that fits
  size_t one_to_one_inliers = 0;  // of them, hypothesis-set features whose best candidate fits
  size_t extra_inliers = 0;       // inliers - one_to_one_inliers: what 1-M verification adds
  // Per correspondence: the index of the chosen candidate in its list, or -1.
  std::vector<int32_t> chosen_candidate;
  // Per correspondence: 1 for the 1-1 inliers (hypothesis-set features whose
  // 1-1 match fits the model).
  std::vector<uint8_t> one_to_one_inlier;
  RansacLoopStatistics stats;
  double ransac_inliers = 0;      // of the best RANSAC model, before refinement
  double total_ms = 0;
};

TwoViewEstimate estimate_two_view(const TwoViewCorrespondences& matches, const TwoViewOptions& options);

}  // namespace visloc
