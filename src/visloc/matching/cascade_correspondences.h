// The cascade search's result as the correspondence set one-many RANSAC
// consumes (geometry/correspondence_set.h): one feature row per feature of
// the 1-M set (every 1-1 feature is in it), in search order:
//   points2d            the query keypoint, (0.5, 0.5) = centre of the top-left
//                       pixel (the keypoints' convention), float widened to double
//   candidates          the segment's 3D points, nearest descriptor first
//   candidate_point_ids their point index in the segment
//   in_hypothesis_set   1 when the feature's first candidate passed ν_h (1-1 set)
//   query_feature       the query feature index of the row
//   candidate_uncertainty  with `point_uncertainty` (one code per segment
//                       point, or empty): each candidate's code
#pragma once

#include <span>

#include "visloc/features/feature_set.h"
#include "visloc/geometry/correspondence_set.h"
#include "visloc/matching/cascade_index.h"

namespace visloc {

// Fills `out` (its previous content replaced, its capacity reused: a caller
// that keeps the set across segments and queries allocates nothing once it has
// grown). `points_xyz` is the segment's N × 3 float32 positions. Throws
// Error(kInternal) if the matches name a feature or point out of range or are
// not a search's result (the 1-1 set must be the first candidates of 1-M rows,
// in the same order).
void fill_correspondence_set(const CascadeMatches& matches, std::span<const Keypoint> keypoints,
                             std::span<const float> points_xyz, CorrespondenceSet& out,
                             std::span<const PointUncertaintyCode> point_uncertainty = {});
CorrespondenceSet make_correspondence_set(const CascadeMatches& matches, std::span<const Keypoint> keypoints,
                                          std::span<const float> points_xyz,
                                          std::span<const PointUncertaintyCode> point_uncertainty = {});

}  // namespace visloc
