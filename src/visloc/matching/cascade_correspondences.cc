#include "visloc/matching/cascade_correspondences.h"

#include "visloc/util/error.h"

namespace visloc {

void fill_correspondence_set(const CascadeMatches& m, std::span<const Keypoint> keypoints, std::span<const float> xyz,
                             CorrespondenceSet& out, std::span<const PointUncertaintyCode> point_uncertainty) {
  const size_t n = m.many_query.size();
  VISLOC_CHECK(m.many_offsets.size() == n + 1 && m.many_offsets[0] == 0 && m.many_offsets[n] == m.many_points.size());
  VISLOC_CHECK(m.point.size() == m.query.size());
  const size_t num_points = xyz.size() / 3;
  VISLOC_CHECK(point_uncertainty.empty() || point_uncertainty.size() == num_points, "one point uncertainty per point");
  out.clear();
  out.points2d.reserve(n);
  out.candidate_offsets.reserve(n + 1);
  out.candidate_offsets.push_back(0);
  out.candidates.reserve(m.many_points.size());
  out.candidate_point_ids.reserve(m.many_points.size());
  out.in_hypothesis_set.assign(n, 0);
  out.query_feature.assign(m.many_query.begin(), m.many_query.end());
  // Both sets are in search order and the 1-1 features are a subset of the
  // 1-M features: a merge marks them.
  size_t next = 0;  // the next 1-1 match
  for (size_t i = 0; i < n; ++i) {
    const uint32_t f = m.many_query[i];
    VISLOC_CHECK(f < keypoints.size(), "query feature out of range");
    VISLOC_CHECK(m.many_offsets[i] < m.many_offsets[i + 1], "a 1-M row without candidates");
    out.points2d.emplace_back(double(keypoints[f].x), double(keypoints[f].y));
    for (uint32_t k = m.many_offsets[i]; k < m.many_offsets[i + 1]; ++k) {
      const uint32_t p = m.many_points[k];
      VISLOC_CHECK(p < num_points, "point out of range");
      out.candidates.emplace_back(double(xyz[3 * p]), double(xyz[3 * p + 1]), double(xyz[3 * p + 2]));
      out.candidate_point_ids.push_back(p);
    }
    out.candidate_offsets.push_back(static_cast<uint32_t>(out.candidates.size()));
    if (next < m.query.size() && m.query[next] == f) {
      VISLOC_CHECK(m.point[next] == m.many_points[m.many_offsets[i]], "a 1-1 match is not the first 1-M candidate");
      out.in_hypothesis_set[i] = 1;
      ++next;
    }
  }
  VISLOC_CHECK(next == m.query.size(), "a 1-1 match is missing from the 1-M set (or out of search order)");
  if (!point_uncertainty.empty()) {
    out.candidate_uncertainty.resize(out.candidate_point_ids.size());
    for (size_t k = 0; k < out.candidate_point_ids.size(); ++k)
      out.candidate_uncertainty[k] = point_uncertainty[out.candidate_point_ids[k]];
  }
}

CorrespondenceSet make_correspondence_set(const CascadeMatches& matches, std::span<const Keypoint> keypoints,
                                          std::span<const float> points_xyz,
                                          std::span<const PointUncertaintyCode> point_uncertainty) {
  CorrespondenceSet out;
  fill_correspondence_set(matches, keypoints, points_xyz, out, point_uncertainty);
  return out;
}

}  // namespace visloc
