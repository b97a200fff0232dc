// Guided confirmation of a pose: does the photo show the map where the pose
// says it should? The segment's points that the pose predicts in view (in
// front of the camera, no deeper than the inliers' 90th percentile, inside
// the image as the pose's camera model projects them: explained_fraction's
// set, but with the radial distortion up to its fold, and square pixels for
// an estimated focal) are each looked for in the
// photo, at their projection: a point is confirmed when a query keypoint lies
// within a radius of it and that keypoint's descriptor is as close to the
// point's code as the pose's own inliers are to theirs (their 90th
// percentile). It is matching guided by the pose, so it needs no ratio test:
// a right pose finds the map's points also where the global search let them
// go (the ratio test loses a repeated window, the 1-1 rule a second view of
// it), a wrong one only on what made it (a repeated facade, a copied
// building), and the map's points around that stay unconfirmed.
//
// Counted apart: the predicted points in the cells of the 8×8 image grid that
// hold no inlier. There the global matching found nothing, so what is
// confirmed is new evidence, and what the pose predicts and the photo does
// not show counts against it. (The inliers' cells come from their undistorted
// positions, the examined points' from their distorted projections: with a
// strong k1 they may disagree near the image's edges.)
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "visloc/features/feature_set.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/matching/pq_codebook.h"

namespace visloc {

struct GuidedConfirmation {
  size_t predicted = 0;              // map points predicted in view
  size_t examined = 0;               // of them, looked for (every k-th: at most max_examined)
  size_t confirmed = 0;              // of those, found in the photo at their projection
  size_t examined_off_inliers = 0;   // examined in a cell without inliers
  size_t confirmed_off_inliers = 0;  // of them, confirmed
  // confirmed / examined (0 when nothing is examined), and off the inliers.
  double share() const { return examined ? double(confirmed) / double(examined) : 0.0; }
  double share_off_inliers() const {
    return examined_off_inliers ? double(confirmed_off_inliers) / double(examined_off_inliers) : 0.0;
  }
  nlohmann::json to_json() const;
  static GuidedConfirmation from_json(const nlohmann::json& j);  // throws Error(kFormat)
};

struct GuidedConfirmationInput {
  std::span<const float> xyz;      // the segment's points, N × 3
  const uint8_t* codes = nullptr;  // their PQ (or residual) codes, N × codebook.code_bytes()
  const PqCodebook* codebook = nullptr;
  CameraPose cam_from_segment;
  const PinholeCamera* camera = nullptr;  // image size, principal point; aspect and k1 when has_focal
  double focal = 0;                       // the pose's focal (as estimated)
  Eigen::Vector2d principal_point_offset = Eigen::Vector2d::Zero();
  double max_depth = 0;                 // the inliers' 90th percentile depth
  std::span<const Keypoint> keypoints;  // the query's, pixels
  const DescriptorMatrix* descriptors = nullptr;
  uint64_t inlier_cells = 0;  // PoseQuality::inlier_cells (8×8 grid)
  double radius_px = 8;       // a keypoint this near a projection can confirm it
  float max_distance = 0;     // descriptor distance bound (the inliers' 90th percentile)
  // The predicted points looked for: every k-th in the segment's order, k
  // the smallest that keeps them at most this many (on a large segment the
  // share is a sample's: on 100K points with 10K keypoints, looking for all
  // of a pose's 47K predicted points took 33 ms).
  size_t max_examined = 4096;
};

// Reusable buffers (a keypoint grid, a decoded code): no allocation once
// they have grown to a query's size.
class GuidedConfirmer {
 public:
  GuidedConfirmation measure(const GuidedConfirmationInput& in);

 private:
  struct CellKeypoint {
    float x, y;
    uint32_t index;
  };
  std::vector<uint32_t> cell_start_, fill_;
  std::vector<CellKeypoint> cell_keypoints_;  // by cell
  std::vector<float> decoded_;
  struct InView {
    uint32_t point;
    float u, v;  // its pixel
  };
  std::vector<InView> in_view_;
};

}  // namespace visloc
