// ColmapModel: our own reader (and writer) of COLMAP 3.8 sparse models,
// binary (cameras.bin, images.bin, points3D.bin) or text (cameras.txt,
// images.txt, points3D.txt), as documented in COLMAP's "Output format" page.
//
// Conventions kept from COLMAP: an image's pose is cam_from_world
// (quaternion w-x-y-z, Hamilton, and translation t; camera centre = −Rᵀt);
// 2D points are in pixels with the centre of the top-left pixel at
// (0.5, 0.5); the i-th 2D point of an image is the i-th keypoint of that
// image in the COLMAP database, which is how a 3D point's track
// (image_id, point2D_idx) reaches its SIFT descriptors.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <unordered_map>
#include <vector>

#include "visloc/geometry/pose.h"

namespace visloc {

inline constexpr int64_t kColmapInvalidPoint3DId = -1;

struct ColmapCamera {
  uint32_t camera_id = 0;
  int model_id = 1;  // COLMAP model id: 0 SIMPLE_PINHOLE, 1 PINHOLE, 2 SIMPLE_RADIAL, ...
  uint64_t width = 0, height = 0;
  std::vector<double> params;
};

struct ColmapImage {
  uint32_t image_id = 0;
  std::string name;
  uint32_t camera_id = 0;
  std::array<double, 4> cam_from_world_q_wxyz{1, 0, 0, 0};
  std::array<double, 3> cam_from_world_t{0, 0, 0};
  std::vector<std::array<double, 2>> points2d;  // pixels
  std::vector<int64_t> point3d_ids;             // per 2D point; kColmapInvalidPoint3DId if none
};

// The image's pose as our CameraPose (cam_from_world).
CameraPose colmap_image_pose(const ColmapImage& image);

struct ColmapTrackElement {
  uint32_t image_id = 0;
  uint32_t point2d_idx = 0;
};

struct ColmapPoint3D {
  int64_t point3d_id = 0;
  std::array<double, 3> xyz{0, 0, 0};
  std::array<uint8_t, 3> rgb{0, 0, 0};
  double error = 0;
  std::vector<ColmapTrackElement> track;
};

struct ColmapModel {
  std::vector<ColmapCamera> cameras;
  std::vector<ColmapImage> images;   // sorted by image_id
  std::vector<ColmapPoint3D> points;  // sorted by point3d_id

  // Index of the image with this id / name in `images`, or -1.
  int64_t image_index(uint32_t image_id) const;
  int64_t image_index_by_name(const std::string& name) const;
  int64_t camera_index(uint32_t camera_id) const;
  size_t num_observations() const;
};

// Number of parameters of a COLMAP camera model id; throws for unknown ids.
int colmap_camera_model_num_params(int model_id);
// Checks a camera's meaning: known model, its parameter count, finite values,
// positive focal, principal point inside the image, each side 1..
// kColmapMaxImageSide. Throws Error(kFormat) naming `file` and the camera.
inline constexpr uint64_t kColmapMaxImageSide = 1u << 17;
void validate_colmap_camera(const ColmapCamera& camera, const std::string& file);
// A unit quaternion (±1%), finite translation and finite 2D points.
void validate_colmap_image_pose(const ColmapImage& image, const std::string& file);
// "PINHOLE" etc. ↔ model id.
std::string colmap_camera_model_name(int model_id);
int colmap_camera_model_id(const std::string& name);

// Reads a model directory: binary files if cameras.bin, images.bin and
// points3D.bin are all present, else the text files. Throws Error(kIo /
// kFormat) naming the file and the problem (missing file, truncated record,
// unknown camera model, a track naming an absent image or 2D point...).
ColmapModel read_colmap_model(const std::filesystem::path& dir);
ColmapModel read_colmap_model_binary(const std::filesystem::path& dir);
ColmapModel read_colmap_model_text(const std::filesystem::path& dir);
// Writers (atomic), mainly for tests and exchange with COLMAP.
void write_colmap_model_binary(const ColmapModel& model, const std::filesystem::path& dir);
void write_colmap_model_text(const ColmapModel& model, const std::filesystem::path& dir);

// Removes images from a model as the Dubrovnik query protocol does: the
// images go, their observations leave every track, points left with fewer
// than `min_track_length` observations are dropped, and the remaining images'
// 2D points that referred to dropped points become unassigned. Names not in
// the model are an Error(kNotFound) naming them.
struct ColmapHoldoutStats {
  size_t images_removed = 0;
  size_t observations_removed = 0;  // track elements of the removed images
  size_t points_dropped = 0;        // points left with < min_track_length observations
  size_t points_kept = 0;
};
ColmapHoldoutStats remove_images(ColmapModel& model, const std::vector<std::string>& image_names,
                                 size_t min_track_length = 2);

}  // namespace visloc
