// How well the map knows each of its 3D points: the first-order covariance of
// a point triangulated from its track, stored per point in 4 bytes (segment
// section PTUNC), so that a pose's reported uncertainty includes the map's
// own error and not only the query's keypoint noise.
//
// Why: a query's pose covariance from its own residuals treats the map's
// points as exact. Where a point was triangulated from a short baseline along
// its viewing direction (a street-view car driving towards it), its depth is
// known to metres, and a query that sees it from farther along the same
// street inherits that error as a shift along the street, a shift its own
// residuals hardly show (it moves the points the way the camera's own motion
// would). Measured (session 39, KITTI hard split: map of frames 0-99,
// queries 100-159, 30 right poses, errors 0.01-1.4 m, all the same way along
// the street): without it 0 / 1 of 30 errors within the reported 1σ / 2σ
// (σ × 1.44, the builtin sigma_scale), with it 3 / 15 of 30 unscaled (7 / 29
// at 1.44).
// Opt-in (map build / import --point-uncertainty): the synthetic training
// cities' errors come out well inside the σ it gives (68% within 0.60σ), the
// KITTI odd frames' outside (68% within 1.39σ), so no fitted scale serves both;
// the localizer applies it unscaled (ConfidenceModel::
// sigma_scale_with_point_uncertainty = 1).
//
// The model: Σ_X = σ_m² (Σ_c B_cᵀ B_c)⁻¹ over the track's cameras c, B_c the
// 2×3 Jacobian of camera c's pixel projection at X, σ_m the segment's keypoint
// noise (pixels) from its reprojection errors. Stored as its major axis (the
// direction the point is least known along) and two standard deviations:
//   Σ ≈ σ_minor² I + (σ_major² − σ_minor²) d dᵀ,
// with σ_minor the middle eigenvalue's root (conservative for the smallest).
// Encoding, 4 bytes: d in octahedral coordinates (2 × uint8 over the upper
// hemisphere, ±d alike: within 0.6° of the axis, 0.53° at worst over 20,000
// random axes in the test), then σ_major and σ_minor as 8 × (log2 σ + 24), rounded,
// clamped to 1..255 (steps of 9%, 6e-8 to 235 segment units; a point known
// worse than that gets 235), 0 for an exact point (σ = 0).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

namespace visloc {

using PointUncertaintyCode = std::array<uint8_t, 4>;

// The compact form of a 3×3 point covariance (symmetric, positive
// semi-definite; its negative eigenvalues count as 0). A non-finite input
// encodes as the largest σ along z, one whose eigenvalues are all negative
// as the largest σ along its least negative one's axis: never as "exact".
PointUncertaintyCode encode_point_covariance(const Eigen::Matrix3d& covariance);
// Its decoded covariance, segment units²: finite for every 4 bytes.
Eigen::Matrix3d decode_point_covariance(const PointUncertaintyCode& code);
// The σ a log2 code stands for (0 for code 0).
double point_sigma_from_code(uint8_t code);
inline constexpr double kMaxPointSigma = 235.0;  // the largest σ the code holds (≈ 2^7.875)

// One camera of a point's track: where it is and how it projects (pinhole,
// fx and fy in pixels; the principal point does not change the Jacobian).
struct TrackCamera {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  // cam_from_world
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  double fx = 1, fy = 1;
};

// Σ_X = noise_px² (Σ_c B_cᵀ B_c)⁻¹ of a point seen by `cameras` (those behind
// the camera are ignored). Without two views that fix it in 3D (fewer than 2
// cameras in front, or rays so nearly parallel that the information matrix is
// singular), the major axis gets kMaxPointSigma² along the least-known
// direction.
Eigen::Matrix3d triangulation_covariance(const Eigen::Vector3d& X, std::span<const TrackCamera> cameras,
                                         double noise_px);

// A segment's keypoint noise σ_m (pixels, per axis) from its points' mean
// reprojection errors `errors` (COLMAP's point error: the mean |r| over the
// track) and track lengths: |r| of a 2-D Gaussian has E|r|² = (4/π)(E|r|)²,
// and triangulating a point from k views leaves 2k − 3 degrees of freedom,
// so σ_m² = Σ_p k_p (4/π) e_p² / Σ_p (2 k_p − 3) over the points with k_p ≥ 2
// and a finite error ≥ 0. 0 when no point qualifies.
double keypoint_noise_from_reprojection_errors(std::span<const double> errors, std::span<const uint32_t> track_lengths);

}  // namespace visloc
