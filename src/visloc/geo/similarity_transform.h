// Similarity3d: X_dst = s R X_src + t, e.g. enu_from_segment (an SfM
// reconstruction's arbitrary frame → local ENU metres). Estimated in closed
// form (Umeyama, PAMI 1991, through Eigen::umeyama) inside a RANSAC over
// minimal 3-point samples, because GPS positions carry outliers of metres.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <vector>

namespace visloc {

struct Similarity3d {
  double scale = 1.0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Eigen::Vector3d apply(const Eigen::Vector3d& x) const { return scale * (rotation * x) + translation; }
  Similarity3d inverse() const;
  Eigen::Matrix4d matrix() const;
};

struct SimilarityRansacOptions {
  double inlier_threshold = 5.0;  // metres in the destination frame (GPS noise)
  int max_iterations = 2000;
  uint64_t seed = 1;
  int min_inliers = 3;
  void validate() const;
};

struct SimilarityEstimate {
  Similarity3d transform;
  std::vector<uint8_t> inliers;   // per correspondence
  int inlier_count = 0;
  double rms_residual = 0.0;      // metres, over inliers
  double median_residual = 0.0;   // metres, over all points
  double max_residual = 0.0;      // metres, over all points
  std::vector<double> residuals;  // per correspondence, metres
};

// Upright similarity: the source frame's "up" direction is known (the mean
// of the cameras' up axes for street-level imagery), so the rotation is that
// alignment followed by a yaw about the destination's z axis (ENU up). Only
// 4 degrees of freedom (yaw, scale, translation) remain, solvable from 2
// pairs; unlike the full similarity it is well-posed when the camera
// centres lie along one straight street. Robust in the same way.
SimilarityEstimate estimate_upright_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                                      const std::vector<Eigen::Vector3d>& dst,
                                                      const Eigen::Vector3d& src_up,
                                                      const SimilarityRansacOptions& options = {});

// Least squares over all pairs (at least 3, not collinear). Throws Error when degenerate.
Similarity3d estimate_similarity(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst);

// Robust estimate; the final transform is refit on the inliers. Throws
// Error(kInvalidArgument) with fewer than 3 pairs or when no model reaches
// min_inliers.
SimilarityEstimate estimate_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                              const std::vector<Eigen::Vector3d>& dst,
                                              const SimilarityRansacOptions& options = {});

// For camera centres along streets: the upright fit, and — when the centres
// spread in two directions (a turn, a square: second principal extent ≥ 10 %
// of the first) — also the full 7-DoF fit, kept if it has at least as many
// inliers and an RMS below 0.8× the upright one's (the upright model is
// nested in it, so a lower RMS alone would always pick it). The cameras' mean up axis is only as vertical as
// the capture (a car pitching on a slope tilted KITTI's by 0.5°: 0.8 m over
// 90 m), and a reference frame may not be upright at all (Strecha's).
SimilarityEstimate estimate_street_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                                     const std::vector<Eigen::Vector3d>& dst,
                                                     const Eigen::Vector3d& src_up,
                                                     const SimilarityRansacOptions& options = {});

}  // namespace visloc
