// ColmapDatabase: our own reader of COLMAP 3.8's SQLite database
// (database.db): cameras, images, keypoints, descriptors and verified
// two-view geometries. Keypoints are returned in our Keypoint form (COLMAP's
// pixel convention already matches ours); both COLMAP's 2-, 4- and 6-column
// keypoint rows are accepted (6: x, y, a11, a12, a21, a22 affine shape).
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "visloc/features/feature_set.h"

struct sqlite3;

namespace visloc {

struct ColmapDbCamera {
  int64_t camera_id = 0;
  int model = 0;  // COLMAP model id (0 SIMPLE_PINHOLE, 1 PINHOLE, 2 SIMPLE_RADIAL, ...)
  int64_t width = 0, height = 0;
  std::vector<double> params;
  bool prior_focal_length = false;
};

struct ColmapDbImage {
  int64_t image_id = 0;
  std::string name;
  int64_t camera_id = 0;
};

// COLMAP's pair id: id1 * 2147483647 + id2 with id1 < id2.
int64_t colmap_pair_id(int64_t image_id1, int64_t image_id2);

class ColmapDatabase {
 public:
  // Opens read-only. Throws Error naming the file if it is missing or not a
  // COLMAP database.
  explicit ColmapDatabase(const std::filesystem::path& path);
  ~ColmapDatabase();
  ColmapDatabase(const ColmapDatabase&) = delete;
  ColmapDatabase& operator=(const ColmapDatabase&) = delete;

  std::vector<ColmapDbCamera> cameras() const;
  std::vector<ColmapDbImage> images() const;
  std::optional<ColmapDbImage> image_by_name(const std::string& name) const;
  std::vector<Keypoint> keypoints(int64_t image_id) const;
  DescriptorMatrix descriptors(int64_t image_id) const;
  // Keypoints and descriptors of one image as a FeatureSet.
  FeatureSet features(int64_t image_id) const;
  // Inlier matches of the verified geometry between two images, as
  // (index in image1, index in image2) in the caller's order; empty if none.
  std::vector<std::pair<uint32_t, uint32_t>> verified_matches(int64_t image_id1, int64_t image_id2) const;

  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  sqlite3* db_ = nullptr;
};

}  // namespace visloc
