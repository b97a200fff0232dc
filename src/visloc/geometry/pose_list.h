// Pose lists in the visuallocalization.net format: one image per line,
// `name qw qx qy qz tx ty tz` (cam_from_world, Hamilton quaternion), '#'
// comments and blank lines ignored. Errors name the file and the line.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "visloc/geometry/pose.h"

namespace visloc {

struct NamedPose {
  std::string name;
  CameraPose cam_from_world;
};

std::vector<NamedPose> read_pose_list(const std::filesystem::path& path);
void write_pose_list(const std::filesystem::path& path, const std::vector<NamedPose>& poses);

// A list of image names, one per line ('#' comments, blank lines ignored).
std::vector<std::string> read_name_list(const std::filesystem::path& path);

}  // namespace visloc
