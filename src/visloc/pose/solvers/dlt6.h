// Normalized direct linear transform (DLT) for the 3×4 projection matrix
// from n ≥ 6 2D-3D correspondences (Hartley & Zisserman, "Multiple View
// Geometry", 2nd ed., algorithm 7.1), the paper's minimal solver when the
// query's intrinsics are unknown (s = 6).
//
// Each correspondence x = (u, v) ↔ X gives two rows of A p = 0:
//   [ Xᵀ  0ᵀ  −u Xᵀ ] p = 0,   [ 0ᵀ  Xᵀ  −v Xᵀ ] p = 0   (X homogeneous, p = vec(P) by rows).
// Points are first normalized (2D: centroid 0, mean distance √2; 3D:
// centroid 0, mean distance √3); p is the eigenvector of AᵀA of smallest
// eigenvalue (inverse iteration, eigen-solver fallback); P = T2⁻¹ P̃ T3.
// Coplanar or collinear 3D points (a null space of dimension > 1) are rejected. The sign of P is fixed so that the input
// points lie in front of the camera (positive third row), and a P whose
// left 3×3 block has a non-positive determinant (a mirror) is rejected.
//
// decompose_projection() splits P = λ K [R | t] by RQ decomposition, with
// 2D points measured from the principal point, and returns the focal
// length f = (K₀₀ + K₁₁)/2, R and t = K⁻¹ p₄ / λ (skew and residual
// principal point dropped; the non-linear refinement corrects them).
#pragma once

#include <Eigen/Core>

namespace visloc {

using Matrix34d = Eigen::Matrix<double, 3, 4>;

// Returns false for degenerate input (n < 6, coplanar or coincident points,
// a mirror solution, a non-finite result).
bool solve_dlt(const Eigen::Vector2d* points2d, const Eigen::Vector3d* points3d, int n, Matrix34d* projection);

struct DecomposedProjection {
  double focal = 0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // cam_from_world
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Matrix3d calibration = Eigen::Matrix3d::Identity();  // full K, K₂₂ = 1
};

// Returns false when P's left block is singular or a mirror.
bool decompose_projection(const Matrix34d& projection, DecomposedProjection* out);

}  // namespace visloc
