#include "visloc/map_building/planted_map.h"

#include <nlohmann/json.hpp>
#include <optional>

#include "visloc/colmap/colmap_model.h"
#include "visloc/map/map.h"
#include "visloc/map_building/segment_builder.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/mapped_file.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace fs = std::filesystem;

PlantedSegment random_planted_segment(size_t n, RandomGenerator& rng) {
  PlantedSegment s;
  for (size_t i = 0; i < n; ++i) {
    s.xyz.emplace_back(rng.uniform(-12, 12), rng.uniform(-8, 8), rng.uniform(15, 30));
    std::array<uint8_t, kDescriptorDim> d{};
    for (auto& v : d) v = static_cast<uint8_t>(rng.below(128));
    s.descriptors.push_back(d);
  }
  return s;
}

Similarity3d planted_enu_from_segment(int k) {
  Similarity3d s;
  s.scale = 2.0;
  s.rotation << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  s.translation = Eigen::Vector3d(100.0 * k + 5, -7, 1.5);
  return s;
}

PlantedMap::PlantedMap(const std::string& name, const std::vector<PlantedSegment>& segments, PlantedCamera camera,
                       int cameras_per_segment, const PlantedMapOptions& options) {
  dir_ = unique_temp_path("visloc_planted_" + name);
  fs::remove_all(dir_);
  fs::create_directories(dir_ / "segments");
  std::vector<float> all;
  for (const auto& s : segments)
    for (const auto& d : s.descriptors) all.insert(all.end(), d.begin(), d.end());
  PqTrainingOptions pq;
  pq.iterations = 8;
  const PqCodebook codebook = PqCodebook::train(all.data(), all.size() / kDescriptorDim, pq);
  MapManifest man;
  man.enu_origin_lat_lon_alt = std::array<double, 3>{55.7, 13.19, 20.0};
  codebook.write(dir_ / man.pq_codebook_file, "{}");
  ItqOptions itq;
  itq.iterations = 10;
  std::optional<BinaryHasher> map_hasher;
  if (options.map_hash_rotation) {
    map_hasher = train_itq(all.data(), all.size() / kDescriptorDim, itq).hasher;
    man.hash_rotation_file = kHashRotationFileName;
    write_hash_rotation_file(dir_ / man.hash_rotation_file, *map_hasher, "{}");
  }
  for (size_t k = 0; k < segments.size(); ++k) {
    const PlantedSegment& s = segments[k];
    ColmapModel model;
    model.cameras.push_back({1, 1, static_cast<uint64_t>(camera.width), static_cast<uint64_t>(camera.height),
                             {camera.focal, camera.focal, camera.width / 2.0, camera.height / 2.0}});
    for (int c = 0; c < cameras_per_segment; ++c) {  // 2 m apart along x, looking along +z
      ColmapImage im;
      im.image_id = static_cast<uint32_t>(c + 1);
      im.name = "seg" + std::to_string(k) + "_" + std::to_string(c) + ".jpg";
      im.camera_id = 1;
      im.cam_from_world_t = {-(2.0 * c - (cameras_per_segment - 1)), 0, 0};
      model.images.push_back(im);
    }
    PointDescriptors desc;
    desc.num_points = s.xyz.size();
    for (size_t i = 0; i < s.xyz.size(); ++i) {
      ColmapPoint3D p;
      p.point3d_id = static_cast<int64_t>(i + 1);
      p.xyz = {s.xyz[i].x(), s.xyz[i].y(), s.xyz[i].z()};
      model.points.push_back(p);
      desc.mean.insert(desc.mean.end(), s.descriptors[i].begin(), s.descriptors[i].end());
      desc.track_size.push_back(3);
    }
    const auto id = static_cast<uint32_t>(options.first_segment_id + k);
    SegmentData data = make_segment_data(model, desc, codebook, itq, id, nullptr, map_hasher ? &*map_hasher : nullptr);
    const Similarity3d e = planted_enu_from_segment(static_cast<int>(k));
    nlohmann::json r = nlohmann::json::array();
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r.push_back(e.rotation(i, j));
    data.extra_meta["enu_from_segment"] = {{"scale", e.scale},
                                           {"rotation_row_major", r},
                                           {"translation", {e.translation.x(), e.translation.y(), e.translation.z()}}};
    const std::string file = "segments/" + std::to_string(k) + ".vlseg";
    // float32: the tests compare what they read with the planted points exactly.
    write_segment_file(dir_ / file, data, {.coordinates = PointCoordinates::kFloat32});
    const MappedFile mapped(dir_ / file);
    man.segments.push_back({id, file, "", s.xyz.size(), model.images.size(), static_cast<uint64_t>(mapped.size()),
                            crc32c(mapped.data(), mapped.size())});
  }
  write_manifest(dir_, man);
}

PlantedMap::~PlantedMap() {
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

}  // namespace visloc
