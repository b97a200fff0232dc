#include "visloc/colmap/point_descriptors.h"

#include <algorithm>
#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

namespace {

// The track element sampled for point p: one picked by a hash of p, so that
// the sample does not lean to the images COLMAP registered first (its
// tracks' order).
const ColmapTrackElement& sampled_track_element(const ColmapPoint3D& point, size_t p) {
  const uint64_t mixed = (uint64_t(p) + 1) * 0x9E3779B97F4A7C15ull;
  return point.track[size_t(mixed >> 33) % point.track.size()];
}
uint32_t sampled_element(const ColmapPoint3D& point, size_t p) { return sampled_track_element(point, p).image_id; }
uint32_t sampled_index(const ColmapPoint3D& point, size_t p) { return sampled_track_element(point, p).point2d_idx; }

}  // namespace

PointDescriptors compute_point_descriptors(const ColmapModel& model, const ImageDescriptorSource& source,
                                           const std::string& source_name, size_t observation_sample) {
  PointDescriptors out;
  out.num_points = model.points.size();
  out.mean.assign(out.num_points * kDescriptorDim, 0.0f);
  out.track_size.assign(out.num_points, 0);
  // Sampled point p's row in sampled_observations, or -1.
  std::vector<int32_t> sample_row;
  const size_t sampled = std::min(observation_sample, out.num_points);
  if (sampled > 0) {
    sample_row.assign(out.num_points, -1);
    for (size_t k = 0; k < sampled; ++k) {
      const auto p = static_cast<uint32_t>(k * out.num_points / sampled);
      sample_row[p] = static_cast<int32_t>(k);
      out.sampled_points.push_back(p);
    }
    out.sampled_observations.resize(sampled);
  }
  // Observations grouped by image so that each image's descriptors are read once.
  std::vector<std::vector<std::pair<uint32_t, uint32_t>>> by_image(model.images.size());  // (point index, 2D idx)
  for (size_t p = 0; p < model.points.size(); ++p)
    for (const auto& e : model.points[p].track) {
      const int64_t ii = model.image_index(e.image_id);
      VISLOC_CHECK(ii >= 0, "track refers to a missing image");
      by_image[ii].emplace_back(static_cast<uint32_t>(p), e.point2d_idx);
    }
  for (size_t ii = 0; ii < model.images.size(); ++ii) {
    if (by_image[ii].empty()) continue;
    const auto& image = model.images[ii];
    DescriptorMatrix d = source(image);
    for (auto [p, k] : by_image[ii]) {
      if (k >= d.rows())
        throw_error(ErrorCode::kFormat, source_name, ": image ", image.name, " has ", d.rows(),
                    " descriptors but the model refers to 2D point ", k,
                    " (descriptors and model do not belong together)");
      float* m = &out.mean[size_t(p) * kDescriptorDim];
      const uint8_t* r = d.row(k);
      for (int j = 0; j < kDescriptorDim; ++j) m[j] += r[j];
      if (!sample_row.empty() && sample_row[p] >= 0 && sampled_element(model.points[p], p) == image.image_id &&
          sampled_index(model.points[p], p) == k)
        std::copy_n(r, kDescriptorDim, out.sampled_observations.row(size_t(sample_row[p])));
      ++out.track_size[p];
    }
  }
  for (size_t p = 0; p < out.num_points; ++p) {
    if (out.track_size[p] == 0) continue;
    const float inv = 1.0f / static_cast<float>(out.track_size[p]);
    for (int j = 0; j < kDescriptorDim; ++j) out.mean[p * kDescriptorDim + j] *= inv;
  }
  return out;
}

ImageDescriptorSource database_descriptor_source(const ColmapDatabase& database) {
  return [&database](const ColmapImage& image) {
    auto db_image = database.image_by_name(image.name);
    if (!db_image)
      throw_error(ErrorCode::kFormat, database.path().string(), ": image ", image.name,
                  " of the model is not in the database");
    return database.descriptors(db_image->image_id);
  };
}

PointDescriptors compute_point_descriptors(const ColmapModel& model, const ColmapDatabase& database,
                                           size_t observation_sample) {
  return compute_point_descriptors(model, database_descriptor_source(database), database.path().string(),
                                   observation_sample);
}

DescriptorMatrix round_descriptors(const std::vector<float>& values) {
  VISLOC_CHECK(values.size() % kDescriptorDim == 0);
  DescriptorMatrix out(values.size() / kDescriptorDim);
  for (size_t i = 0; i < values.size(); ++i)
    out.data()[i] = static_cast<uint8_t>(std::clamp(std::lround(values[i]), 0L, 255L));
  return out;
}

}  // namespace visloc
