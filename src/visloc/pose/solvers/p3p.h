// P3P: the absolute pose of a calibrated camera from three 2D-3D
// correspondences, after the Lambda Twist formulation (M. Persson and
// K. Nordberg, "Lambda Twist: An Accurate Fast Robust Perspective Three Point
// (P3P) Solver", ECCV 2018).
//
// With unit bearing vectors y_i and world points x_i, the unknown depths
// λ_i (camera point c_i = λ_i y_i) satisfy, for each pair,
//   |λ_i y_i − λ_j y_j|² = a_ij = |x_i − x_j|²,
//   i.e. Λᵀ M_ij Λ = a_ij with Λ = (λ1, λ2, λ3), b_ij = −2 y_i·y_j.
// D1 = a23 M12 − a12 M23 and D2 = a23 M13 − a13 M23 are homogeneous conics
// through every solution; a root γ of the cubic det(D1 + γ D2) = 0 makes
// D0 = D1 + γ D2 degenerate, a pair of lines nᵀΛ = 0 read from its
// eigen-decomposition (σ_p (e_pᵀΛ)² + σ_n (e_nᵀΛ)² = 0). On each line the
// ratio of two depths solves a quadratic; the scale follows from a23. Each
// candidate is refined by Gauss-Newton on the three equations and kept when
// all three hold; R, t then align the world triangle to the camera triangle.
#pragma once

#include <Eigen/Core>
#include <array>

namespace visloc {

using Matrix34d = Eigen::Matrix<double, 3, 4>;

// bearings: unit (or any positive-scale) rays in the camera frame; points:
// world points. Writes up to 4 cam_from_world [R | t] into `solutions` and
// returns their number (0 for degenerate input: collinear or coincident
// points, parallel rays).
int solve_p3p(const std::array<Eigen::Vector3d, 3>& bearings, const std::array<Eigen::Vector3d, 3>& points,
              std::array<Matrix34d, 4>* solutions);

// Real roots of c3 x³ + c2 x² + c1 x + c0 (degrades to lower degree when the
// leading coefficients vanish); returns how many were written.
int solve_cubic_real(double c3, double c2, double c1, double c0, double roots[3]);

}  // namespace visloc
