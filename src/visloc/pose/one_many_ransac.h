// Robust absolute pose from a CorrespondenceSet: classical RANSAC on 1-1
// matches, and the one-many (1-M) RANSAC of Tran et al. (section III-B and
// its algorithm figure), with fixed iterations or with SPRT pre-verification
// and adaptive termination (see sprt.h for the formulas).
//
//   hypothesis  s correspondences (q_i, p_i1) drawn from the hypothesis set
//               (in_hypothesis_set = 1): P3P (s = 3) when the camera has a
//               focal length, else the normalized 6-point DLT (s = 6);
//   pre-verify  (kOneManySprt) Wald's SPRT over the hypothesis set in a
//               seeded random order, starting at a random offset per model:
//               ρ_1 = 1 when p_i1 reprojects within the threshold;
//   verify      1-M: C = Σ_i ρ_M, ρ_M = 1 when ANY candidate p_ij of
//               feature i reprojects within the threshold (and lies in front
//               of the camera); classical: C = Σ over the hypothesis set of ρ_1;
//   best model  the largest C; for the SPRT variant ε ← (hypothesis-set
//               inliers of the best model)/N_h, δ ← the pooled fraction of
//               consistent points among the points tested on rejected models
//               (with a prior of δ0), A recomputed, k_max = log(1−η)/
//               log(1 − ε^s(1 − 1/A)); classical RANSAC stops at
//               log(1−η)/log(1 − ε^s) with ε its inlier ratio;
//   refine      per feature, the candidate with the smallest reprojection
//               error under the best model (within the threshold) is chosen;
//               Levenberg-Marquardt with a Cauchy loss (pose_refinement.h) on
//               those, re-selection with the refined pose, repeated
//               `refine_rounds` times.
//
// Models are 3×4 projection matrices on pixels measured from the principal
// point (undistorted by the camera's k1 when the focal length is known).
// Nothing is allocated inside the sampling loop: the workspace (centred
// points, hypothesis indices, SPRT order) is built once per call.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/geometry/correspondence_set.h"
#include "visloc/pose/pose_refinement.h"
#include "visloc/pose/ransac_loop.h"

namespace visloc {

enum class RansacVariant {
  kClassic11,     // paper setting 1: hypotheses and verification on the 1-1 set, adaptive
  kOneManyFixed,  // paper settings 2/3: 1-M verification, fixed iteration count
  kOneManySprt,   // paper setting 3+: 1-M with SPRT pre-verification, adaptive (default)
};
std::string_view to_string(RansacVariant variant);
// "classic", "1m-fixed", "1m-sprt"; throws Error(kInvalidArgument) otherwise.
RansacVariant parse_ransac_variant(std::string_view name);

// The loop options (ransac_loop.h) a variant means: its termination, SPRT
// on or off, and its sample cap (fixed_iterations for kOneManyFixed, else
// max_iterations). The SPRT costs are the estimator's to set.
RansacLoopOptions loop_options_for(RansacVariant variant, size_t max_iterations, size_t fixed_iterations,
                                   double confidence, double sprt_delta0);

struct RansacOptions {
  RansacVariant variant = RansacVariant::kOneManySprt;
  double threshold_px = 4.0;        // reprojection threshold (paper: 4 px, from ACS)
  size_t min_inliers = 12;          // registered when at least this many inliers (paper IV)
  size_t max_iterations = 10000;    // cap on samples of the adaptive variants
  size_t fixed_iterations = 5000;   // samples of kOneManyFixed (paper settings 2/3)
  double confidence = 0.9999;       // η of the adaptive termination
  double sprt_delta0 = 0.01;        // initial δ (paper)
  double sprt_delta_prior_weight = 100;  // δ prior counts as this many tested points
  // t_M: time of one hypothesis (sampling + minimal solver) in units of one
  // point verification; 0 = the solver's default (P3P 250, DLT 1500: order-
  // of-magnitude estimates from ~5 µs per P3P and ~10 µs per DLT against a
  // few ns per projected point; fixed values keep runs deterministic).
  double sprt_model_cost = 0;
  bool refine = true;               // non-linear refinement on the inliers
  int refine_rounds = 2;            // refine, re-select candidates, refine again
  int refine_max_iterations = 30;   // LM iterations per round
  // Unknown focal: also refine the principal point (prior σ = 3% of the
  // image size) once the pose has ≥ 50 inliers.
  bool refine_principal_point = true;
  uint64_t seed = 0;                // random sampling seed (deterministic)

  void validate() const;  // throws Error(kInvalidArgument) naming the bad field
};

struct RansacStatistics {
  size_t num_features = 0;
  size_t hypothesis_features = 0;  // N_h
  int sample_size = 0;             // s: 3 (P3P) or 6 (DLT)
  size_t iterations = 0;           // samples drawn
  size_t models = 0;               // models produced by the minimal solver
  size_t models_rejected_sprt = 0; // rejected by the SPRT pre-verification
  size_t models_verified = 0;      // fully verified
  size_t best_iteration = 0;
  size_t ransac_inliers = 0;       // inliers of the best RANSAC model (before refinement)
  double final_epsilon = 0, final_delta = 0, final_threshold = 0;  // SPRT state at the end
  double expected_samples = 0;     // μ = 1/(ε^s(1 − 1/A)) at the end (SPRT variant)
  int refine_iterations = 0;
  double hypothesis_ms = 0;    // sampling and minimal solvers
  double verification_ms = 0;  // SPRT and full verification
  double refinement_ms = 0;    // candidate selection and LM
  double total_ms = 0;
};

// How well the final pose fits its data: the pose's own evidence, which the
// localizer turns into a confidence and an uncertainty.
struct PoseQuality {
  size_t hypothesis_features = 0;  // N_h: features with a 1-1 match
  size_t hypothesis_inliers = 0;   // of them, those whose 1-1 match fits the final pose
  double median_residual_px = 0;   // reprojection error of the inliers, median
  double coverage = 0;             // fraction of the cells of an 8×8 image grid holding an inlier
  uint64_t inlier_cells = 0;       // those cells: bit 8·row + column
  double inlier_depth_median = 0;  // |median| of the inliers' depths (world units)
  double inlier_depth_p90 = 0;     // 90th percentile (nearest rank) of the inliers' depths (world units)
  // RANSAC scores: of the best model, and of the best verified model that is
  // a different pose (camera farther than 10% of the inliers' median depth,
  // or turned > 10°): an ambiguity of the scene, e.g. a repeated facade.
  size_t best_score = 0, rival_score = 0;
  PoseCovariance covariance;       // of the final pose, from the inliers
};

struct PoseEstimate {
  bool has_pose = false;    // a model was found
  bool registered = false;  // has_pose and num_inliers >= min_inliers
  CameraPose cam_from_world;
  double focal = 0;         // pixels; the camera's focal when it was known
  // Estimated offset of the principal point from the assumed one (pixels;
  // 0 unless the focal was unknown and refine_principal_point).
  Eigen::Vector2d principal_point_offset = Eigen::Vector2d::Zero();
  size_t num_inliers = 0;   // features with a chosen candidate
  // Per feature: index into its candidate list of the candidate that fits
  // the final pose, or -1.
  std::vector<int32_t> chosen_candidate;
  PoseQuality quality;      // set with has_pose
  RansacStatistics stats;
};

PoseEstimate estimate_pose(const CorrespondenceSet& correspondences, const PinholeCamera& camera,
                           const RansacOptions& options);

}  // namespace visloc
