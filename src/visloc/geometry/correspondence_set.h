// CorrespondenceSet: the 2D-3D matches of one query image against one map
// segment, as produced by the cascade correspondence search (CCS; matching/
// fill_correspondence_set) and consumed by the one-many RANSAC (pose/; Tran
// et al., section III-B). In geometry/ so that both modules share the type.
//
// Layout (compressed sparse rows, structure of arrays):
//   feature i ∈ [0, n):   points2d[i]        pixel of the query feature,
//                                             (0.5, 0.5) = centre of the top-left pixel
//                         candidates[candidate_offsets[i] .. candidate_offsets[i+1])
//                                             its candidate 3D points P_i, sorted by
//                                             descriptor distance, best first (|P_i| ≤ M)
//                         in_hypothesis_set[i] 1 when the first candidate is a reliable
//                                             1-1 match (passed the strict ratio ν_h) and
//                                             may be sampled for hypotheses
//   candidate_point_ids   optional, empty or one id per candidate (map point ids)
//   query_feature         optional, empty or one query feature index per feature
//   candidate_uncertainty optional, empty or one code per candidate: the map
//                         point's triangulation covariance (point_uncertainty.h),
//                         which the pose's covariance then includes
//
// The hypothesis set of the paper is {(q_i, p_i1) : in_hypothesis_set[i] = 1};
// the verification set is every (q_i, p_ij).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "visloc/geometry/point_uncertainty.h"

namespace visloc {

struct CorrespondenceSet {
  std::vector<Eigen::Vector2d> points2d;     // pixel, (0.5,0.5) = centre of top-left pixel
  std::vector<uint32_t> candidate_offsets;   // size n+1, candidate_offsets[0] = 0
  std::vector<Eigen::Vector3d> candidates;   // 3D points, per feature sorted by descriptor distance
  std::vector<uint8_t> in_hypothesis_set;    // 1 = first candidate is a reliable 1-1 match
  std::vector<uint32_t> candidate_point_ids; // optional: ids of the 3D points, same length as candidates
  std::vector<uint32_t> query_feature;       // optional: query feature index of each feature, same length as points2d
  std::vector<PointUncertaintyCode> candidate_uncertainty;  // optional: same length as candidates

  size_t num_features() const { return points2d.size(); }
  size_t num_candidates(size_t feature) const {
    return candidate_offsets[feature + 1] - candidate_offsets[feature];
  }
  size_t num_hypothesis_features() const;

  // Appends one feature with its candidate list (best first); leaves
  // query_feature alone (a caller that keeps it appends to it).
  void add_feature(const Eigen::Vector2d& pixel, const std::vector<Eigen::Vector3d>& feature_candidates,
                   bool reliable_one_to_one, const std::vector<uint32_t>& ids = {});
  void clear();

  // Throws Error(kInvalidArgument) naming the inconsistent field (sizes,
  // offsets not monotone, a feature without candidates, non-finite values;
  // candidate_point_ids and query_feature are either empty or complete).
  void validate() const;
};

}  // namespace visloc
