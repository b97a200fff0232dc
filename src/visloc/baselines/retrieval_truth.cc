#include "visloc/baselines/retrieval_truth.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include "visloc/util/error.h"

namespace visloc {

void CorrectSegmentOptions::validate() const {
  if (!(max_view_angle_deg > 0 && max_view_angle_deg <= 180))
    throw_error(ErrorCode::kInvalidArgument, "truth option max_view_angle_deg = ", max_view_angle_deg,
                ": must be in (0, 180]");
  if (!(distance_tolerance_m >= 0))
    throw_error(ErrorCode::kInvalidArgument, "truth option distance_tolerance_m = ", distance_tolerance_m,
                ": must be non-negative");
}

std::vector<int64_t> nearest_map_images(const ImagePlacement& query, std::span<const ImagePlacement> map_images,
                                        const CorrectSegmentOptions& options) {
  options.validate();
  const double cos_limit = std::cos(options.max_view_angle_deg * M_PI / 180.0);
  auto facing = [&](const ImagePlacement& m) {
    if (!query.viewing_direction || !m.viewing_direction) return true;
    return query.viewing_direction->normalized().dot(m.viewing_direction->normalized()) >= cos_limit - 1e-12;
  };
  double best = std::numeric_limits<double>::infinity();
  for (const auto& m : map_images)
    if (facing(m)) best = std::min(best, (m.center - query.center).norm());
  std::vector<int64_t> out;
  if (!std::isfinite(best)) return out;
  for (size_t i = 0; i < map_images.size(); ++i)
    if (facing(map_images[i]) && (map_images[i].center - query.center).norm() <= best + options.distance_tolerance_m)
      out.push_back(static_cast<int64_t>(i));
  return out;
}

std::vector<int32_t> correct_segments(const ImagePlacement& query, std::span<const ImagePlacement> map_images,
                                      const SegmentTable& table, const CorrectSegmentOptions& options) {
  if (table.image_count() != map_images.size())
    throw_error(ErrorCode::kInvalidArgument, "correct_segments: ", map_images.size(), " map images but the table has ",
                table.image_count());
  std::vector<int32_t> out;
  for (int64_t i : nearest_map_images(query, map_images, options))
    for (int32_t s : table.segments(static_cast<size_t>(i))) out.push_back(s);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}


}  // namespace visloc
