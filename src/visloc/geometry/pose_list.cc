#include "visloc/geometry/pose_list.h"

#include <cmath>
#include <iomanip>
#include <map>
#include <set>
#include <sstream>

#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {

std::vector<NamedPose> read_pose_list(const std::filesystem::path& path) {
  std::istringstream in(read_file(path));
  std::vector<NamedPose> out;
  std::set<std::string> seen;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos || line[line.find_first_not_of(" \t")] == '#') continue;
    std::istringstream s(line);
    NamedPose p;
    std::array<double, 4> q;
    Eigen::Vector3d t;
    if (!(s >> p.name >> q[0] >> q[1] >> q[2] >> q[3] >> t.x() >> t.y() >> t.z()))
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": expected 'name qw qx qy qz tx ty tz'");
    std::string extra;
    if (s >> extra) throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": unexpected '", extra, "' after tz");
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(std::abs(norm - 1.0) < 1e-3))
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": quaternion norm is ", norm, ", not 1");
    if (!t.allFinite()) throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": translation is not finite");
    if (!seen.insert(p.name).second)
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": image '", p.name, "' listed twice");
    p.cam_from_world = CameraPose::from_wxyz(q, t);
    out.push_back(std::move(p));
  }
  return out;
}

std::vector<NamedPose> read_colmap_images_txt_poses(const std::filesystem::path& path) {
  std::istringstream in(read_file(path));
  std::vector<NamedPose> out;
  std::string line;
  int line_no = 0;
  bool expect_pose = true;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (!line.empty() && line[0] == '#') continue;
    if (!expect_pose) {  // the POINTS2D line (may be empty): triples X Y POINT3D_ID
      std::istringstream s(line);
      std::vector<std::string> tokens;
      for (std::string tok; s >> tok;) tokens.push_back(tok);
      if (tokens.size() % 3 != 0)
        throw_error(ErrorCode::kFormat, path.string(), ":", line_no,
                    ": expected the POINTS2D line (X Y POINT3D_ID triples) after the image line; "
                    "COLMAP's images.txt has two lines per image");
      expect_pose = true;
      continue;
    }
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    std::istringstream s(line);
    long long id = 0, camera_id = 0;
    std::array<double, 4> q;
    Eigen::Vector3d t;
    NamedPose p;
    if (!(s >> id >> q[0] >> q[1] >> q[2] >> q[3] >> t.x() >> t.y() >> t.z() >> camera_id >> p.name))
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no,
                  ": expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME' (COLMAP images.txt)");
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(std::abs(norm - 1.0) < 1e-3))
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": quaternion norm is ", norm, ", not 1");
    if (!t.allFinite()) throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": translation is not finite");
    p.cam_from_world = CameraPose::from_wxyz(q, t);
    out.push_back(std::move(p));
    expect_pose = false;
  }
  return out;
}

void write_pose_list(const std::filesystem::path& path, const std::vector<NamedPose>& poses) {
  std::ostringstream s;
  s << std::setprecision(12);
  for (const auto& p : poses) {
    const auto q = p.cam_from_world.q_wxyz();
    const auto& t = p.cam_from_world.translation;
    s << p.name << ' ' << q[0] << ' ' << q[1] << ' ' << q[2] << ' ' << q[3] << ' ' << t.x() << ' ' << t.y() << ' '
      << t.z() << '\n';
  }
  write_file_atomic(path, s.str());
}

std::vector<NamedCamera> read_intrinsics_list(const std::filesystem::path& path) {
  std::istringstream in(read_file(path));
  std::vector<NamedCamera> out;
  std::map<std::string, int> first_line;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    size_t b = line.find_first_not_of(" \t\r");
    if (b == std::string::npos || line[b] == '#') continue;
    std::istringstream s(line);
    NamedCamera c;
    std::string model;
    int w = 0, h = 0;
    if (!(s >> c.name >> model >> w >> h))
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": expected 'name MODEL width height params...'");
    std::vector<double> p;
    double v;
    while (s >> v) p.push_back(v);
    if (!s.eof())
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": a camera parameter is not a number");
    try {
      c.camera = PinholeCamera::from_colmap(model, w, h, p);
      c.camera.validate();
    } catch (const Error& e) {
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": ", e.what());
    }
    auto [it, fresh] = first_line.emplace(c.name, line_no);
    if (!fresh)
      throw_error(ErrorCode::kFormat, path.string(), ":", line_no, ": image '", c.name, "' already has intrinsics on line ",
                  it->second);
    out.push_back(std::move(c));
  }
  return out;
}

CamerasByName read_intrinsics_by_name(const std::filesystem::path& path) {
  CamerasByName out;
  for (NamedCamera& c : read_intrinsics_list(path)) out.emplace(std::move(c.name), c.camera);
  return out;
}

const PinholeCamera* find_listed_camera(const CamerasByName& cameras, const std::string& image_name) {
  auto it = cameras.find(image_name);
  if (it == cameras.end()) {
    const std::string file_name = std::filesystem::path(image_name).filename().string();
    if (file_name != image_name) it = cameras.find(file_name);
  }
  if (it == cameras.end()) it = cameras.find(kEveryImage);
  return it == cameras.end() ? nullptr : &it->second;
}

std::string unlisted_cameras_warning(const CamerasByName& cameras, const std::filesystem::path& list_file,
                                     const std::vector<std::string>& image_names, const std::string& what) {
  size_t unlisted = 0;
  for (const std::string& name : image_names) unlisted += find_listed_camera(cameras, name) == nullptr;
  if (unlisted == 0) return {};
  std::ostringstream s;
  s << "warning: " << unlisted << " of " << image_names.size() << " " << what << " have no line in "
    << list_file.string() << " (and it has no '*' line); they are localized without it ('focal_estimated' in "
    << "their JSON says whether their focal length was estimated)";
  return s.str();
}

std::vector<std::string> read_name_list(const std::filesystem::path& path) {
  std::istringstream in(read_file(path));
  std::vector<std::string> out;
  std::string line;
  while (std::getline(in, line)) {
    size_t b = line.find_first_not_of(" \t\r");
    if (b == std::string::npos || line[b] == '#') continue;
    size_t e = line.find_last_not_of(" \t\r");
    out.push_back(line.substr(b, e - b + 1));
  }
  return out;
}

}  // namespace visloc
