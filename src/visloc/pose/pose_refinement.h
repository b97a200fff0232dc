// Non-linear refinement of an absolute pose (and the focal length when the
// intrinsics are unknown) on inlier 2D-3D correspondences: Levenberg-
// Marquardt in Eigen on the reprojection error with a robust Cauchy loss,
//   minimize Σ_i ρ(|π(f, R X_i + t) − x_i|²),  ρ(s) = c² log(1 + s/c²),
// solved by iteratively reweighted least squares (weight 1/(1 + s/c²)).
// Parameters: rotation update ω (R ← exp([ω]×) R), translation t, log f
// when the focal length is refined, and an offset o of the principal point
// when that is refined too (with a Gaussian prior of σ_o pixels around the
// assumed one: cost += |o|²/σ_o²). 2D points are measured from the assumed
// principal point (pixels), so π(f, o, p) = f (p_x/p_z, p_y/p_z) + o.
#pragma once

#include <Eigen/Core>
#include <cstddef>

#include "visloc/geometry/pose.h"

namespace visloc {

struct RefinementOptions {
  double loss_scale_px = 4.0;  // Cauchy scale c, pixels (the RANSAC threshold)
  int max_iterations = 30;     // LM iterations
  bool refine_focal = false;   // also estimate the focal length
  // Also estimate the principal point (with refine_focal only): an unknown
  // camera's principal point is seldom exactly the image centre, and an
  // offset of a few pixels biases the focal length and the position.
  bool refine_principal_point = false;
  double principal_point_prior_px = 30;  // σ_o of the prior on the offset
  double min_relative_decrease = 1e-10;  // stop when the cost decreases less than this, relatively
  void validate() const;
};

struct RefinementResult {
  CameraPose cam_from_world;
  double focal = 0;
  Eigen::Vector2d principal_point_offset = Eigen::Vector2d::Zero();  // o
  int iterations = 0;
  double initial_cost = 0;  // robust cost, px²
  double final_cost = 0;
  bool success = false;  // finite result with cost not above the initial cost
};

// points2d_centered[i] = pixel − principal point; the arrays hold n ≥ 3
// (≥ 4 with focal) correspondences.
RefinementResult refine_pose(const Eigen::Vector2d* points2d_centered, const Eigen::Vector3d* points3d, size_t n,
                             const CameraPose& initial, double initial_focal, const RefinementOptions& options,
                             const Eigen::Vector2d& initial_principal_point_offset = Eigen::Vector2d::Zero());

// First-order uncertainty of a refined pose (the Gauss-Newton covariance at
// the optimum): Σ = σ² H⁻¹ with H = Σ_i w_i J_iᵀ J_i (Cauchy IRLS weights w_i)
// and σ² the residual variance the data show: the larger of
// Σ_i w_i |r_i|² / (2n − dof) and (median |r_i| / √(2 ln 2))² · 2n/(2n − dof).
// Parameters as in refine_pose: (ω, t), plus log f with `with_focal`, plus
// the principal point offset o with `principal_point_prior_px` > 0 (its
// prior in H). Σ over (ω, t) is the 6×6 block of the full inverse: the
// intrinsics' uncertainty is marginalized, not ignored.
// With `point_covariances` (one 3×3 per correspondence, world units², e.g. a
// map point's triangulation covariance), residual i also carries the point's
// error through A_i = ∂r_i/∂X_i; the refinement (least squares on the
// residuals) does not weigh it, so Σ is the sandwich
//   σ² H⁻¹ + H⁻¹ (Σ_i w_i² J_iᵀ A_i Σ_i A_iᵀ J_i) H⁻¹.
// A map triangulated from cameras driving towards its points knows their
// depth poorly; a query farther along the street inherits that as a shift
// along the street, which its residuals hardly show (it moves the points the
// way the camera's own motion would).
struct PoseCovariance {
  bool valid = false;                  // n large enough and H invertible
  Eigen::Matrix<double, 6, 6> omega_t = Eigen::Matrix<double, 6, 6>::Zero();  // of (ω, t): ω radians, t world units
  double residual_sigma_px = 0;        // σ
  double focal_sigma_relative = 0;     // σ of log f (0 when the focal was known)
  bool with_point_uncertainty = false;  // point_covariances were given
  // The camera centre c = −Rᵀ t: its 3×3 covariance (world units²).
  Eigen::Matrix3d center(const CameraPose& pose) const;
};
PoseCovariance pose_covariance(const Eigen::Vector2d* points2d_centered, const Eigen::Vector3d* points3d, size_t n,
                               const CameraPose& pose, double focal, double loss_scale_px, bool with_focal,
                               const Eigen::Vector2d& principal_point_offset = Eigen::Vector2d::Zero(),
                               double principal_point_prior_px = 0, const Eigen::Matrix3d* point_covariances = nullptr);

}  // namespace visloc
