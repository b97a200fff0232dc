// Ground truth for retrieval: which segments are correct for a query.
//
// Definition (used by `visloc bench retrieval`): among the map images facing
// within `max_view_angle_deg` of the query (the angle between the cameras'
// viewing directions; every image qualifies when either direction is
// unknown), take those whose camera centre is within `distance_tolerance_m`
// of the nearest such centre to the query's true centre; the correct segments
// are all segments containing one of them. A query is retrieved correctly
// when at least one candidate segment is correct (the paper's criterion,
// section IV: "at least one correct model").
#pragma once

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "visloc/geometry/pose.h"
#include "visloc/retrieval/segment_voter.h"

namespace visloc {

struct ImagePlacement {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();   // metres, one frame for map and queries
  std::optional<Eigen::Vector3d> viewing_direction;   // unit, camera +z in the same frame
};

struct CorrectSegmentOptions {
  double max_view_angle_deg = 90.0;   // facing constraint (when directions are known)
  double distance_tolerance_m = 0.5;  // ties: images within this of the nearest distance
  void validate() const;
};

// Map image ids (indices into map_images) nearest to the query per the rule above.
std::vector<int64_t> nearest_map_images(const ImagePlacement& query, std::span<const ImagePlacement> map_images,
                                        const CorrectSegmentOptions& options);
std::vector<int32_t> correct_segments(const ImagePlacement& query, std::span<const ImagePlacement> map_images,
                                      const SegmentTable& table, const CorrectSegmentOptions& options);


}  // namespace visloc
