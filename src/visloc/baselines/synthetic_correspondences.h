// Synthetic 2D-3D correspondence sets with known truth, shared by the tests
// and `visloc bench pose`. Layout as produced by the cascade search: per
// feature a candidate list (best descriptor distance first, at most M) and a
// flag for the reliable 1-1 matches (the hypothesis set).
//
// Families:
//   kCalibrated    focal length known; points spread over the view at depths
//                  [0.5, 1.5]·scene_depth; wrong candidates are other scene
//                  points. A hypothesis-set feature is correct with
//                  probability inlier_ratio and then its true point is its
//                  first candidate; a feature outside the hypothesis set is
//                  correct with the same probability, with its true point at
//                  a uniform rank 1..L of its L ≥ 2 candidates.
//   kUncalibrated  as kCalibrated, but the estimator is not told the focal
//                  length (drawn in [0.7, 1.4]·focal_px).
//   kFacade        a building facade seen from scene_depth: a repeated grid of
//                  windows (4 corners each, recessed 0.2 m) and balconies
//                  (0.8 m in front), plus distinctive points (door, signs,
//                  street furniture, up to ±5 m off the facade plane). The
//                  hypothesis set holds the distinctive features (correct with
//                  probability inlier_ratio); the other features are grid
//                  features whose candidate list (2..M entries) holds the same
//                  element of neighbouring grid cells (near-identical
//                  descriptors) with the true point only at rank 2..L
//                  (correct features, probability inlier_ratio), or only
//                  wrong grid points.
// Exact counts: N_h = round(hypothesis_fraction·N) features are in the
// hypothesis set and round(inlier_ratio·N_h) of them are correct; likewise
// round(inlier_ratio·(N − N_h)) of the others contain their true point.
// Correct features observe the projection of the true point plus Gaussian
// noise (noise_px per axis); wrong ones a uniform pixel.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/geometry/correspondence_set.h"

namespace visloc {

enum class SyntheticFamily { kCalibrated, kUncalibrated, kFacade };
std::string_view to_string(SyntheticFamily family);
SyntheticFamily parse_synthetic_family(std::string_view name);  // "calibrated", "uncalibrated", "facade"

struct SyntheticOptions {
  SyntheticFamily family = SyntheticFamily::kCalibrated;
  size_t num_features = 500;        // N
  double inlier_ratio = 0.3;        // fraction of correct features (see above)
  double hypothesis_fraction = -1;  // N_h/N; < 0 = family default (0.5; facade 0.3)
  size_t max_candidates = 5;        // M (paper: 5)
  double noise_px = 1.0;            // Gaussian pixel noise, standard deviation per axis
  int width = 1024;
  int height = 768;
  double focal_px = 1000;           // true focal (uncalibrated: the centre of its range)
  double scene_depth = 20;          // metres from the camera to the scene
  uint64_t seed = 0;
  void validate() const;  // throws Error(kInvalidArgument) naming the bad field
};

struct SyntheticProblem {
  CorrespondenceSet correspondences;
  PinholeCamera camera;  // as given to the estimator (no focal for kUncalibrated)
  double true_focal = 0;
  CameraPose true_cam_from_world;
  std::vector<int32_t> true_candidate;  // per feature: rank of its true point in its list, or −1
  double scene_depth = 0;
  size_t num_correct_features = 0;             // features whose list contains the true point
  size_t num_correct_hypothesis_features = 0;  // hypothesis features whose first candidate is true
};

SyntheticProblem make_synthetic_problem(const SyntheticOptions& options);

}  // namespace visloc
