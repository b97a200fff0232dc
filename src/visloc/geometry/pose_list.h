// Pose lists in the visuallocalization.net format: one image per line,
// `name qw qx qy qz tx ty tz` (cam_from_world, Hamilton quaternion), '#'
// comments and blank lines ignored. Errors name the file and the line.
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"

namespace visloc {

struct NamedPose {
  std::string name;
  CameraPose cam_from_world;
};

std::vector<NamedPose> read_pose_list(const std::filesystem::path& path);
// Poses from a COLMAP text model's images.txt (pairs of lines: 'IMAGE_ID QW
// QX QY QZ TX TY TZ CAMERA_ID NAME', then the 2D points, possibly empty).
std::vector<NamedPose> read_colmap_images_txt_poses(const std::filesystem::path& path);

void write_pose_list(const std::filesystem::path& path, const std::vector<NamedPose>& poses);

// Per-image intrinsics in hloc's query-list format, one image per line:
// `name MODEL width height params...` with MODEL SIMPLE_PINHOLE (f cx cy),
// PINHOLE (fx fy cx cy), SIMPLE_RADIAL (f cx cy k), RADIAL (f cx cy k1 k2;
// k2 must be 0) or OPENCV (fx fy cx cy k1 k2 p1 p2; k2, p1, p2 must be 0). Errors name the file and the line.
// The name '*' (kEveryImage) gives the camera of every image that has no line
// of its own.
struct NamedCamera {
  std::string name;
  PinholeCamera camera;
};
std::vector<NamedCamera> read_intrinsics_list(const std::filesystem::path& path);

inline constexpr const char* kEveryImage = "*";
using CamerasByName = std::map<std::string, PinholeCamera>;
// The same list keyed by image name ('*' kept as its own key).
CamerasByName read_intrinsics_by_name(const std::filesystem::path& path);
// The camera the list gives the image named `image_name` (as the caller lists
// it, e.g. "query/day/x.jpg", or a bare file name): the entry of that exact
// name, else of its file name ("x.jpg"), else the '*' entry, else null.
const PinholeCamera* find_listed_camera(const CamerasByName& cameras, const std::string& image_name);
// "warning: N of M <what> have no line in FILE (and it has no '*' line); ..."
// when some of `image_names` get no camera (find_listed_camera) from the list
// read from `list_file`; "" when all do.
std::string unlisted_cameras_warning(const CamerasByName& cameras, const std::filesystem::path& list_file,
                                     const std::vector<std::string>& image_names, const std::string& what);

// A list of image names, one per line ('#' comments, blank lines ignored).
std::vector<std::string> read_name_list(const std::filesystem::path& path);

}  // namespace visloc
