// ColmapDatabaseWriter: creates a COLMAP 3.8 database (database.db, SQLite)
// and fills it with our cameras, images and features, so that COLMAP's
// matchers and mapper run on exactly the features our queries use. The
// schema is COLMAP 3.8's (cameras, images, keypoints, descriptors, matches,
// two_view_geometries). Keypoints are written with 4 columns (x, y, scale,
// orientation), which COLMAP accepts; descriptors as N × 128 uint8.
// Also writes a COLMAP text model (cameras.txt, images.txt, points3D.txt)
// for point_triangulator when poses are known.
#pragma once

#include <filesystem>
#include <optional>
#include <utility>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"

struct sqlite3;

namespace visloc {

// COLMAP camera model ids used here.
inline constexpr int kColmapSimplePinhole = 0;  // f, cx, cy
inline constexpr int kColmapPinhole = 1;        // fx, fy, cx, cy
inline constexpr int kColmapSimpleRadial = 2;   // f, cx, cy, k
// COLMAP two-view geometry configurations used here.
inline constexpr int kColmapCalibratedPair = 2;    // E (and F) hold
inline constexpr int kColmapUncalibratedPair = 3;  // F holds

class ColmapDatabaseWriter {
 public:
  enum class Mode { kCreate, kAppend };
  // kCreate: a new database at `path` (an existing file is replaced);
  // kAppend: adds to an existing COLMAP database (Error naming it if absent).
  explicit ColmapDatabaseWriter(const std::filesystem::path& path, Mode mode = Mode::kCreate);
  ~ColmapDatabaseWriter();
  ColmapDatabaseWriter(const ColmapDatabaseWriter&) = delete;
  ColmapDatabaseWriter& operator=(const ColmapDatabaseWriter&) = delete;

  // A camera from our intrinsics: SIMPLE_RADIAL when k1 != 0, else
  // SIMPLE_PINHOLE; when the focal is unknown, `fallback_focal` is written
  // with prior_focal_length = 0 so that COLMAP refines it freely.
  int64_t add_camera(const PinholeCamera& camera, double fallback_focal = 0.0);
  // An image; a known pose and/or a position prior (COLMAP 3.8 stores the
  // prior translation in prior_tx/ty/tz, used by the spatial matcher).
  int64_t add_image(const std::string& name, int64_t camera_id,
                    const std::optional<Eigen::Vector3d>& position_prior = std::nullopt);
  void add_features(int64_t image_id, const FeatureSet& features);
  // Matches of a pair (N × 2 uint32, indices into each image's keypoints)
  // into `matches`, and the same matches as the inliers of a CALIBRATED
  // two-view geometry (config 2) with F, E (row-major, as COLMAP stores
  // them) and the relative pose image2_from_image1 (unit translation). The
  // pair is stored under COLMAP's pair id; when image_id1 > image_id2 the
  // columns are swapped and the geometry inverted, as COLMAP expects.
  void add_calibrated_pair(int64_t image_id1, int64_t image_id2, const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                           const Eigen::Matrix3d& F, const Eigen::Matrix3d& E, const Eigen::Quaterniond& rotation_2_from_1,
                           const Eigen::Vector3d& direction_2_from_1);
  // A pair verified by our matching and RANSAC (twoview/image_pair.h):
  // `matches` into `matches`, `inliers` as the two-view geometry's, config 2
  // (calibrated) with E when given, else config 3 (uncalibrated) with F.
  // The relative pose is left as COLMAP 3.8's verification leaves it by
  // default (identity, zero translation).
  void add_verified_pair(int64_t image_id1, int64_t image_id2,
                         const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                         const std::vector<std::pair<uint32_t, uint32_t>>& inliers, const Eigen::Matrix3d& F,
                         const std::optional<Eigen::Matrix3d>& E);
  // Removes an image with its features, matches and two-view geometries;
  // false when there is no image of that name.
  bool remove_image(const std::string& name);
  // Commits the transaction (all or nothing).
  void commit();

 private:
  void add_pair(int64_t image_id1, int64_t image_id2, const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                const std::vector<std::pair<uint32_t, uint32_t>>& inliers, int config, const Eigen::Matrix3d& F,
                const Eigen::Matrix3d& E, const Eigen::Quaterniond& rotation_2_from_1,
                const Eigen::Vector3d& direction_2_from_1);
  std::filesystem::path path_;
  sqlite3* db_ = nullptr;
  bool committed_ = false;
};

struct ColmapTextImage {
  int64_t image_id = 0;
  int64_t camera_id = 0;
  std::string name;
  CameraPose cam_from_world;
};
struct ColmapTextCamera {
  int64_t camera_id = 0;
  PinholeCamera camera;
};

// Writes cameras.txt, images.txt (poses, no 2D points) and an empty
// points3D.txt into `dir` (created), atomically per file.
void write_colmap_text_model(const std::filesystem::path& dir, const std::vector<ColmapTextCamera>& cameras,
                             const std::vector<ColmapTextImage>& images);

}  // namespace visloc
