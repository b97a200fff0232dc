// PinholeCamera: the intrinsics of one image. Conventions (docs/conventions.md):
// pixel coordinates put the centre of the top-left pixel at (0.5, 0.5), as
// COLMAP does; the camera looks along +z, x right, y down. The optional
// radial distortion k1 maps a normalized point p to p * (1 + k1 |p|^2).
// The focal length may be unknown (queries without EXIF), in which case the
// pose solver estimates it; `has_focal` says which.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace visloc {

struct PinholeCamera {
  int width = 0;
  int height = 0;
  double focal = 0.0;  // pixels (fx); meaningful only when has_focal
  bool has_focal = false;
  // fy / fx: 1 for square pixels. A calibration with fx ≠ fy (COLMAP's
  // PINHOLE, OpenCV's camera matrix) keeps both, so its keypoints are
  // normalized exactly (an average focal moved Strecha's fx 1379.74, fy
  // 1382.08 by 0.08% and biased the pose by about a centimetre at 10 m).
  double aspect = 1.0;
  static constexpr double kMinAspect = 0.5, kMaxAspect = 2.0;  // beyond, a calibration error
  double cx = 0.0;  // principal point, pixels
  double cy = 0.0;
  double k1 = 0.0;  // radial distortion

  // A camera with principal point at the image centre.
  static PinholeCamera centered(int width, int height, std::optional<double> focal_px = {});

  // From a COLMAP camera model: SIMPLE_PINHOLE (f cx cy), PINHOLE (fx fy cx
  // cy: focal fx, aspect fy / fx), SIMPLE_RADIAL (f cx cy k), RADIAL (f cx cy k1 k2;
  // k2 must be 0), OPENCV (fx fy cx cy k1 k2 p1 p2; k2, p1, p2 must be 0).
  // Throws Error(kInvalidArgument) for another model, a wrong parameter count
  // or invalid values.
  static PinholeCamera from_colmap(const std::string& model, int width, int height, const std::vector<double>& params);
  // The COLMAP model that holds this camera exactly (requires has_focal):
  // SIMPLE_PINHOLE or SIMPLE_RADIAL for square pixels, else PINHOLE, or
  // OPENCV with k1 only. from_colmap of it gives this camera back.
  std::pair<std::string, std::vector<double>> colmap_model() const;

  // Throws Error(kInvalidArgument) naming the bad field.
  void validate() const;

  double focal_y() const { return focal * aspect; }
  // Camera-frame point (z > 0) → pixel. Requires has_focal.
  Eigen::Vector2d project(const Eigen::Vector3d& point_in_camera) const;
  // Pixel → normalized image-plane point (x/z, y/z), undistorted.
  Eigen::Vector2d normalize(const Eigen::Vector2d& pixel) const;
  // Pixel → unit ray in the camera frame.
  Eigen::Vector3d ray(const Eigen::Vector2d& pixel) const { return normalize(pixel).homogeneous().normalized(); }
  bool contains(const Eigen::Vector2d& pixel) const {
    return pixel.x() >= 0 && pixel.y() >= 0 && pixel.x() <= width && pixel.y() <= height;
  }
  // Horizontal field of view in degrees.
  double horizontal_fov_deg() const;
};

// Focal length in pixels from EXIF values: 35 mm-equivalent focal length uses
// the 36 mm width of full-frame film along the image's long side.
double focal_px_from_35mm(double focal_35mm, int width, int height);

}  // namespace visloc
