// The arrays one-many RANSAC consumes (pose module's CorrespondenceSet),
// built from a cascade search result without depending on the pose module:
//   points2d            n × (x, y) pixels of the query features
//   candidate_offsets   n + 1 CSR offsets into candidates
//   candidates          3D points (x, y, z), nearest descriptor first
//   candidate_point_ids point index in the segment, parallel to candidates
//   in_hypothesis_set   1 when the feature's first candidate passed ν_h (1-1 set)
// One row per feature of the 1-M set (every 1-1 feature is in it).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/cascade_index.h"

namespace visloc {

struct CorrespondenceArrays {
  std::vector<std::array<double, 2>> points2d;
  std::vector<uint32_t> candidate_offsets{0};
  std::vector<std::array<double, 3>> candidates;
  std::vector<uint32_t> candidate_point_ids;
  std::vector<uint8_t> in_hypothesis_set;
  std::vector<uint32_t> query_feature;  // the query feature index of each row
};

// `points_xyz` is the segment's N × 3 float32 positions. Throws Error(kInternal)
// if the matches name a feature or point out of range.
CorrespondenceArrays make_correspondence_arrays(const CascadeMatches& matches, std::span<const Keypoint> keypoints,
                                                std::span<const float> points_xyz);

}  // namespace visloc
