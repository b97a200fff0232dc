#include "visloc/sfm/segment_plan.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "visloc/util/error.h"

namespace visloc {

void SegmentPlanOptions::validate() const {
  if (min_placemarks < 1)
    throw_error(ErrorCode::kInvalidArgument, "segment min_placemarks must be >= 1, got ", min_placemarks);
  if (max_placemarks < min_placemarks)
    throw_error(ErrorCode::kInvalidArgument, "segment max_placemarks (", max_placemarks,
                ") must be >= min_placemarks (", min_placemarks, ")");
  if (overlap < 0 || overlap >= min_placemarks)
    throw_error(ErrorCode::kInvalidArgument, "segment overlap must be in [0, min_placemarks), got ", overlap);
  if (!(placemark_radius >= 0))
    throw_error(ErrorCode::kInvalidArgument, "placemark_radius must be >= 0, got ", placemark_radius);
}

std::vector<Placemark> group_placemarks(const std::vector<GpsRecord>& records, const EnuFrame& frame,
                                        double radius) {
  std::vector<Placemark> out;
  const bool have_ids = !records.empty() &&
                        std::all_of(records.begin(), records.end(), [](const GpsRecord& r) { return r.placemark.has_value(); });
  if (have_ids) {
    std::map<int, size_t> index_of;
    for (size_t i = 0; i < records.size(); ++i) {
      auto [it, inserted] = index_of.emplace(*records[i].placemark, out.size());
      if (inserted) out.push_back({*records[i].placemark, {}, {}});
      out[it->second].images.push_back(i);
    }
  } else {
    Eigen::Vector3d anchor;
    for (size_t i = 0; i < records.size(); ++i) {
      const Eigen::Vector3d p = frame.to_enu(records[i].position);
      if (out.empty() || (p - anchor).head<2>().norm() > radius) {
        out.push_back({static_cast<int>(out.size()), {}, {}});
        anchor = p;
      }
      out.back().images.push_back(i);
    }
  }
  for (auto& pm : out) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (size_t i : pm.images) sum += frame.to_enu(records[i].position);
    pm.center_enu = sum / static_cast<double>(pm.images.size());
  }
  return out;
}

std::vector<std::vector<int>> partition_segments(int n, const SegmentPlanOptions& o) {
  o.validate();
  std::vector<std::vector<int>> out;
  if (n <= 0) return out;
  if (n <= o.max_placemarks) {
    std::vector<int> all(n);
    for (int i = 0; i < n; ++i) all[i] = i;
    out.push_back(all);
    return out;
  }
  const int stride_max = o.max_placemarks - o.overlap;
  const int k = (n - o.overlap + stride_max - 1) / stride_max;
  std::vector<int> starts(k + 1);
  for (int i = 0; i <= k; ++i)
    starts[i] = static_cast<int>(std::lround(static_cast<double>(i) * (n - o.overlap) / k));
  for (int i = 0; i < k; ++i) {
    int begin = starts[i];
    int end = std::min(n, starts[i + 1] + o.overlap);
    // Short routes (max < n < 2 max - overlap) cannot meet the minimum with
    // the nominal overlap: widen the window, which only adds overlap.
    if (end - begin < o.min_placemarks) {
      end = std::min(n, begin + o.min_placemarks);
      begin = std::max(0, end - o.min_placemarks);
    }
    std::vector<int> seg;
    for (int j = begin; j < end; ++j) seg.push_back(j);
    out.push_back(std::move(seg));
  }
  return out;
}

namespace {

std::vector<Placemark> chain_order(std::vector<Placemark> pms) {
  if (pms.size() < 3) return pms;
  // Start from the placemark farthest from the centroid (an end of the route).
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : pms) c += p.center_enu;
  c /= static_cast<double>(pms.size());
  size_t start = 0;
  for (size_t i = 1; i < pms.size(); ++i)
    if ((pms[i].center_enu - c).norm() > (pms[start].center_enu - c).norm()) start = i;
  std::vector<Placemark> out;
  std::vector<bool> used(pms.size(), false);
  size_t cur = start;
  for (size_t step = 0; step < pms.size(); ++step) {
    used[cur] = true;
    out.push_back(pms[cur]);
    double best = std::numeric_limits<double>::infinity();
    size_t next = cur;
    for (size_t j = 0; j < pms.size(); ++j)
      if (!used[j] && (pms[j].center_enu - pms[cur].center_enu).norm() < best) {
        best = (pms[j].center_enu - pms[cur].center_enu).norm();
        next = j;
      }
    cur = next;
  }
  return out;
}

}  // namespace

SegmentPlan plan_segments(const std::vector<GpsRecord>& records, const EnuFrame& frame,
                          const SegmentPlanOptions& options) {
  options.validate();
  SegmentPlan plan;
  plan.placemarks = group_placemarks(records, frame, options.placemark_radius);
  if (options.order == PlacemarkOrder::kChain) plan.placemarks = chain_order(std::move(plan.placemarks));
  plan.segments = partition_segments(static_cast<int>(plan.placemarks.size()), options);
  return plan;
}

}  // namespace visloc
