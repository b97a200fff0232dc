#include "visloc/matching/correspondence_arrays.h"

#include "visloc/util/error.h"

namespace visloc {

CorrespondenceArrays make_correspondence_arrays(const CascadeMatches& m, std::span<const Keypoint> keypoints,
                                                std::span<const float> xyz) {
  VISLOC_CHECK(m.many_offsets.size() == m.many_query.size() + 1);
  const size_t num_points = xyz.size() / 3;
  CorrespondenceArrays out;
  const size_t n = m.many_query.size();
  out.points2d.reserve(n);
  out.in_hypothesis_set.assign(n, 0);
  out.query_feature = m.many_query;
  out.candidates.reserve(m.many_points.size());
  out.candidate_point_ids.reserve(m.many_points.size());
  // The 1-1 set's features are a subset of the 1-M set's: mark them.
  std::vector<int64_t> row_of_feature(keypoints.size(), -1);
  for (size_t i = 0; i < n; ++i) {
    const uint32_t f = m.many_query[i];
    VISLOC_CHECK(f < keypoints.size(), "query feature out of range");
    row_of_feature[f] = static_cast<int64_t>(i);
    out.points2d.push_back({keypoints[f].x, keypoints[f].y});
    for (uint32_t k = m.many_offsets[i]; k < m.many_offsets[i + 1]; ++k) {
      const uint32_t p = m.many_points[k];
      VISLOC_CHECK(p < num_points, "point out of range");
      out.candidates.push_back({xyz[3 * p], xyz[3 * p + 1], xyz[3 * p + 2]});
      out.candidate_point_ids.push_back(p);
    }
    out.candidate_offsets.push_back(static_cast<uint32_t>(out.candidates.size()));
  }
  for (size_t i = 0; i < m.query.size(); ++i) {
    VISLOC_CHECK(m.query[i] < keypoints.size());
    const int64_t row = row_of_feature[m.query[i]];
    VISLOC_CHECK(row >= 0, "a 1-1 match is missing from the 1-M set");
    VISLOC_CHECK(out.candidate_point_ids[out.candidate_offsets[row]] == m.point[i],
                 "a 1-1 match is not the first 1-M candidate");
    out.in_hypothesis_set[row] = 1;
  }
  return out;
}

}  // namespace visloc
