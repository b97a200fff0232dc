// Non-linear refinement of an absolute pose (and the focal length when the
// intrinsics are unknown) on inlier 2D-3D correspondences: Levenberg-
// Marquardt in Eigen on the reprojection error with a robust Cauchy loss,
//   minimize Σ_i ρ(|π(f, R X_i + t) − x_i|²),  ρ(s) = c² log(1 + s/c²),
// solved by iteratively reweighted least squares (weight 1/(1 + s/c²)).
// Parameters: rotation update ω (R ← exp([ω]×) R), translation t, and
// log f when the focal length is refined. 2D points are measured from the
// principal point (pixels), so π(f, p) = f (p_x/p_z, p_y/p_z).
#pragma once

#include <Eigen/Core>
#include <cstddef>

#include "visloc/geometry/pose.h"

namespace visloc {

struct RefinementOptions {
  double loss_scale_px = 4.0;  // Cauchy scale c, pixels (the RANSAC threshold)
  int max_iterations = 30;     // LM iterations
  bool refine_focal = false;   // also estimate the focal length
  double min_relative_decrease = 1e-10;  // stop when the cost decreases less than this, relatively
  void validate() const;
};

struct RefinementResult {
  CameraPose cam_from_world;
  double focal = 0;
  int iterations = 0;
  double initial_cost = 0;  // robust cost, px²
  double final_cost = 0;
  bool success = false;  // finite result with cost not above the initial cost
};

// points2d_centered[i] = pixel − principal point; the arrays hold n ≥ 3
// (≥ 4 with focal) correspondences.
RefinementResult refine_pose(const Eigen::Vector2d* points2d_centered, const Eigen::Vector3d* points3d, size_t n,
                             const CameraPose& initial, double initial_focal, const RefinementOptions& options);

}  // namespace visloc
