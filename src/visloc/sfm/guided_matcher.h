// Guided matching for known poses (map building at city scale, issue #12).
// When both cameras' poses and intrinsics are known, the epipolar geometry of
// a pair is known too: a feature of image A can only match a feature of
// image B that lies near its epipolar line. GuidedMatcher keeps, for every
// feature of A, the features of B whose Sampson distance to it is at most a
// few pixels, and picks the nearest RootSIFT descriptor among them with
// COLMAP's rules: angle between unit descriptors ≤ max_angle, Lowe's ratio on
// angles, and (optionally) mutual best match within the band.
//
// The search is blocked brute force over contiguous arrays: undistorted,
// centred coordinates of B and the Sampson terms of B are arrays (structure
// of arrays); for each feature of A one vectorizable pass over them marks the
// band, then descriptor dot products run on the band only. All buffers live
// in the matcher and are reused from pair to pair: nothing is allocated per
// feature, and nothing per pair once the buffers have grown to the largest
// image.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <utility>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"

namespace visloc {

struct GuidedMatchOptions {
  double max_sampson_px = 4.0;  // epipolar band: Sampson distance in pixels
  double max_ratio = 0.8;       // best / second-best descriptor angle (COLMAP: 0.8)
  double max_angle_rad = 0.7;   // angle between unit descriptors (COLMAP's max_distance: 0.7)
  bool cross_check = true;      // keep (a, b) only when a is also b's best within the band
  int min_matches = 15;         // pairs with fewer matches are left out (COLMAP: min_num_inliers 15)
  void validate() const;
};

// The geometry of a pair from its known poses: b_from_a = (R, t) with t of
// unit length (COLMAP's convention for two-view geometries), E = [t]x R and
// F = K_b^-T E K_a^-1 in pixels (the keypoints' convention: the centre of the
// top-left pixel is (0.5, 0.5)). Lens distortion is not in F: the matcher
// undistorts keypoints first.
struct TwoViewGeometry {
  Eigen::Matrix3d E = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d F = Eigen::Matrix3d::Zero();
  Eigen::Quaterniond b_from_a_rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d b_from_a_direction = Eigen::Vector3d::Zero();  // unit translation (0 when the centres coincide)
  double baseline = 0;                                            // |c_b - c_a| in the poses' units
};
TwoViewGeometry two_view_geometry(const PinholeCamera& camera_a, const CameraPose& a_from_world,
                                  const PinholeCamera& camera_b, const CameraPose& b_from_world);

using FeatureMatch = std::pair<uint32_t, uint32_t>;  // (index in A, index in B)

// Undistorted keypoint coordinates relative to the principal point, in
// pixels of a distortion-free camera of the same focal (structure of arrays).
struct CenteredKeypoints {
  std::vector<float> x, y;
  double focal = 0;
  void assign(const FeatureSet& features, const PinholeCamera& camera);
  size_t size() const { return x.size(); }
};

class GuidedMatcher {
 public:
  explicit GuidedMatcher(const GuidedMatchOptions& options = {});

  // Matches of A's features into B's under the pair's epipolar geometry.
  // `a` and `b` must come from CenteredKeypoints::assign on the same features.
  // The returned vector is the matcher's own and stays valid until the next
  // call; it is empty when fewer than min_matches were found.
  const std::vector<FeatureMatch>& match(const FeatureSet& features_a, const CenteredKeypoints& a,
                                         const FeatureSet& features_b, const CenteredKeypoints& b,
                                         const TwoViewGeometry& geometry);

  // Statistics of the last call.
  size_t last_band_candidates() const { return band_candidates_; }

 private:
  GuidedMatchOptions options_;
  // Workspace, grown to the largest image and reused.
  std::vector<float> gb2_;                // |F^T x_b|^2 over the first two components, per B feature
  std::vector<uint8_t> band_;             // per B feature: in the band of the current A feature
  std::vector<uint32_t> candidates_;      // B indices in the band
  std::vector<int32_t> best_dot_of_b_;    // per B feature: best descriptor dot over A (cross-check)
  std::vector<uint32_t> best_a_of_b_;
  std::vector<FeatureMatch> tentative_;   // A → B best matches before the cross-check
  std::vector<FeatureMatch> matches_;
  size_t band_candidates_ = 0;
};

// Candidate pairs of known poses: views at most max_distance apart whose
// viewing directions are within max_angle_deg; (i, j) with i < j.
std::vector<std::pair<size_t, size_t>> overlapping_pairs(const std::vector<CameraPose>& cam_from_world,
                                                         double max_distance, double max_angle_deg);

}  // namespace visloc
