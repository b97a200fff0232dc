// Minimal solvers of two-view geometry, for the RANSAC loop (ransac_loop.h):
//
//   fundamental, 7 points   x2ᵀ F x1 = 0: the 2-dimensional null space
//       F = a F1 + (1 − a) F2 of the 7 × 9 system, and det F = 0, a cubic in
//       a (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., 11.1.2):
//       1 or 3 solutions. Points are normalized first (centroid 0, mean
//       distance √2).
//   homography, 4 points    x2 ~ H x1: normalized DLT (H&Z algorithm 4.2).
//   essential, 5 points     q2ᵀ E q1 = 0 on calibrated bearings: the
//       4-dimensional null space E = x X + y Y + z Z + W, the ten cubic
//       constraints det E = 0 and 2 E Eᵀ E − tr(E Eᵀ) E = 0, Gauss-Jordan
//       elimination of the 10 cubic monomials and the eigenvectors of the
//       10 × 10 action matrix of x (Stewénius, Engels and Nistér, "Recent
//       developments on direct relative orientation", ISPRS 2006): up to 10
//       solutions.
//
// Inputs are pixels for F and H (models map pixels to pixels) and
// normalized image coordinates (K⁻¹ x) for E. Degenerate samples give 0.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <limits>

namespace visloc {

int solve_fundamental_7pt(const Eigen::Vector2d* x1, const Eigen::Vector2d* x2, std::array<Eigen::Matrix3d, 3>* out);
int solve_homography_4pt(const Eigen::Vector2d* x1, const Eigen::Vector2d* x2, Eigen::Matrix3d* out);
int solve_essential_5pt(const Eigen::Vector2d* q1, const Eigen::Vector2d* q2, std::array<Eigen::Matrix3d, 10>* out);

// Sampson distance (pixels², first-order geometric error) of x1 ↔ x2 under F.
inline double sampson_error2(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2) {
  const Eigen::Vector3d p1(x1.x(), x1.y(), 1.0), p2(x2.x(), x2.y(), 1.0);
  const Eigen::Vector3d Fx1 = F * p1, Ftx2 = F.transpose() * p2;
  const double e = p2.dot(Fx1);
  const double d = Fx1.x() * Fx1.x() + Fx1.y() * Fx1.y() + Ftx2.x() * Ftx2.x() + Ftx2.y() * Ftx2.y();
  return d > 0 ? e * e / d : std::numeric_limits<double>::infinity();
}

// Squared transfer error |x2 − H x1|² (pixels²); infinite for points mapped to infinity.
inline double transfer_error2(const Eigen::Matrix3d& H, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2) {
  const Eigen::Vector3d p = H * Eigen::Vector3d(x1.x(), x1.y(), 1.0);
  if (!(std::abs(p.z()) > 1e-12)) return std::numeric_limits<double>::infinity();
  return (p.head<2>() / p.z() - x2).squaredNorm();
}

// Symmetric epipolar distance (pixels, the mean of the two point-line
// distances) of x1 ↔ x2 under F.
double symmetric_epipolar_distance(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2);

}  // namespace visloc
