#pragma once
// A map planted by a test, with no shared data and no COLMAP: segments of
// given 3D points and descriptors, compressed like any map (ITQ, PQ) and
// geo-registered by a known similarity. Test support only (library
// visloc_map_test_support, built with the tests).
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/geo/similarity_transform.h"
#include "visloc/util/random.h"

namespace visloc {

struct PlantedSegment {
  std::vector<Eigen::Vector3d> xyz;
  std::vector<std::array<uint8_t, kDescriptorDim>> descriptors;
};

// n points in front of cameras at the origin looking along +z (the segment
// frame is a camera frame: x right, y down, z forward), random descriptors.
PlantedSegment random_planted_segment(size_t n, RandomGenerator& rng);

// ENU from segment k's frame: x → east, z (forward) → north, y (down) → −up;
// scale 2, shifted 100 m east per k.
Similarity3d planted_enu_from_segment(int k);

struct PlantedCamera {
  int width = 640, height = 480;
  double focal = 500;
};

struct PlantedMapOptions {
  // One ITQ rotation for the whole map (learned on every segment's
  // descriptors, as `map build --hash-rotation map`), else one per segment.
  bool map_hash_rotation = false;
  // Segment k's id in the manifest: first_segment_id + k (ids that differ
  // from manifest positions).
  uint32_t first_segment_id = 0;
};

class PlantedMap {
 public:
  // Segments in manifest order, segment k geo-registered by
  // planted_enu_from_segment(k); each has `cameras_per_segment` map cameras
  // 2 m apart along x, looking along +z. The map is written under a unique
  // temporary folder, removed by the destructor.
  PlantedMap(const std::string& name, const std::vector<PlantedSegment>& segments, PlantedCamera camera = {},
             int cameras_per_segment = 4, const PlantedMapOptions& options = {});
  ~PlantedMap();
  PlantedMap(const PlantedMap&) = delete;
  PlantedMap& operator=(const PlantedMap&) = delete;
  const std::filesystem::path& dir() const { return dir_; }

 private:
  std::filesystem::path dir_;
};

}  // namespace visloc
