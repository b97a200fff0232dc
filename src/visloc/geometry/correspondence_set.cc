#include "visloc/geometry/correspondence_set.h"

#include <algorithm>
#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

size_t CorrespondenceSet::num_hypothesis_features() const {
  return static_cast<size_t>(std::count_if(in_hypothesis_set.begin(), in_hypothesis_set.end(),
                                           [](uint8_t v) { return v != 0; }));
}

void CorrespondenceSet::add_feature(const Eigen::Vector2d& pixel,
                                    const std::vector<Eigen::Vector3d>& feature_candidates,
                                    bool reliable_one_to_one, const std::vector<uint32_t>& ids) {
  if (candidate_offsets.empty()) candidate_offsets.push_back(0);
  if (feature_candidates.empty())
    throw_error(ErrorCode::kInvalidArgument, "correspondence set: a feature needs at least one candidate");
  if (!ids.empty() && ids.size() != feature_candidates.size())
    throw_error(ErrorCode::kInvalidArgument, "correspondence set: ", ids.size(), " ids for ",
                feature_candidates.size(), " candidates");
  if (!candidate_uncertainty.empty())
    throw_error(ErrorCode::kInvalidArgument,
                "correspondence set: add features before filling candidate_uncertainty (one per candidate)");
  if (!ids.empty() && candidate_point_ids.size() != candidates.size())
    throw_error(ErrorCode::kInvalidArgument,
                "correspondence set: candidate ids given for some features but not others");
  points2d.push_back(pixel);
  candidates.insert(candidates.end(), feature_candidates.begin(), feature_candidates.end());
  candidate_point_ids.insert(candidate_point_ids.end(), ids.begin(), ids.end());
  candidate_offsets.push_back(static_cast<uint32_t>(candidates.size()));
  in_hypothesis_set.push_back(reliable_one_to_one ? 1 : 0);
}

void CorrespondenceSet::clear() {
  points2d.clear();
  candidate_offsets.clear();
  candidates.clear();
  in_hypothesis_set.clear();
  candidate_point_ids.clear();
  query_feature.clear();
  candidate_uncertainty.clear();
}

void CorrespondenceSet::validate() const {
  const size_t n = points2d.size();
  const bool empty = n == 0 && candidate_offsets.empty() && candidates.empty() && in_hypothesis_set.empty();
  if (!empty) {
    if (candidate_offsets.size() != n + 1)
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidate_offsets has ",
                  candidate_offsets.size(), " entries, expected ", n + 1);
    if (in_hypothesis_set.size() != n)
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: in_hypothesis_set has ",
                  in_hypothesis_set.size(), " entries, expected ", n);
    if (candidate_offsets[0] != 0)
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidate_offsets[0] must be 0");
    for (size_t i = 0; i < n; ++i)
      if (candidate_offsets[i + 1] <= candidate_offsets[i])
        throw_error(ErrorCode::kInvalidArgument, "correspondence set: feature ", i,
                    " has no candidates (candidate_offsets must increase strictly)");
    if (candidate_offsets[n] != candidates.size())
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidate_offsets ends at ",
                  candidate_offsets[n], " but there are ", candidates.size(), " candidates");
  }
  if (!candidate_point_ids.empty() && candidate_point_ids.size() != candidates.size())
    throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidate_point_ids has ",
                candidate_point_ids.size(), " entries, expected 0 or ", candidates.size());
  if (!candidate_uncertainty.empty() && candidate_uncertainty.size() != candidates.size())
    throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidate_uncertainty has ",
                candidate_uncertainty.size(), " entries, expected 0 or ", candidates.size());
  if (!query_feature.empty() && query_feature.size() != n)
    throw_error(ErrorCode::kInvalidArgument, "correspondence set: query_feature has ", query_feature.size(),
                " entries, expected 0 or ", n);
  for (size_t i = 0; i < n; ++i)
    if (!points2d[i].allFinite())
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: points2d[", i, "] is not finite");
  for (size_t j = 0; j < candidates.size(); ++j)
    if (!candidates[j].allFinite())
      throw_error(ErrorCode::kInvalidArgument, "correspondence set: candidates[", j, "] is not finite");
}

}  // namespace visloc
