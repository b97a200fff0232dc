#include "visloc/colmap/colmap_model.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>
#include <unordered_set>

#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {

CameraPose colmap_image_pose(const ColmapImage& image) {
  const auto& t = image.cam_from_world_t;
  return CameraPose::from_wxyz(image.cam_from_world_q_wxyz, Eigen::Vector3d(t[0], t[1], t[2]));
}
namespace fs = std::filesystem;

namespace {

struct ModelInfo {
  int id;
  const char* name;
  int num_params;
};
constexpr ModelInfo kModels[] = {
    {0, "SIMPLE_PINHOLE", 3}, {1, "PINHOLE", 4},        {2, "SIMPLE_RADIAL", 4},
    {3, "RADIAL", 5},         {4, "OPENCV", 8},         {5, "OPENCV_FISHEYE", 8},
    {6, "FULL_OPENCV", 12},   {7, "FOV", 5},            {8, "SIMPLE_RADIAL_FISHEYE", 4},
    {9, "RADIAL_FISHEYE", 5}, {10, "THIN_PRISM_FISHEYE", 12},
};

// Bounds-checked little-endian reader over a whole file.
class BinaryCursor {
 public:
  BinaryCursor(const fs::path& path) : path_(path), data_(read_file(path)) {}
  template <typename T>
  T get(const char* what) {
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, data_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string get_cstring(const char* what) {
    const size_t end = data_.find('\0', pos_);
    if (end == std::string::npos)
      throw_error(ErrorCode::kFormat, path_.string(), ": truncated ", what, " at byte ", pos_);
    std::string s = data_.substr(pos_, end - pos_);
    pos_ = end + 1;
    return s;
  }
  // A count that must fit in the remaining bytes at `min_record` bytes each.
  uint64_t get_count(size_t min_record, const char* what) {
    const uint64_t n = get<uint64_t>(what);
    if (min_record > 0 && n > (data_.size() - pos_) / min_record)
      throw_error(ErrorCode::kFormat, path_.string(), ": ", what, " count ", n,
                  " exceeds what the file can hold (truncated or corrupt)");
    return n;
  }
  void expect_end() const {
    if (pos_ != data_.size())
      throw_error(ErrorCode::kFormat, path_.string(), ": ", data_.size() - pos_, " unexpected trailing bytes");
  }

 private:
  void need(size_t n, const char* what) const {
    if (data_.size() - pos_ < n)
      throw_error(ErrorCode::kFormat, path_.string(), ": truncated while reading ", what, " at byte ", pos_);
  }
  fs::path path_;
  std::string data_;
  size_t pos_ = 0;
};

class BinaryBuffer {
 public:
  template <typename T>
  void put(T v) {
    const size_t at = data_.size();
    data_.resize(at + sizeof(T));
    std::memcpy(data_.data() + at, &v, sizeof(T));
  }
  void put_cstring(const std::string& s) {
    data_.append(s);
    data_.push_back('\0');
  }
  const std::string& str() const { return data_; }

 private:
  std::string data_;
};

void check_params(const fs::path& path, const ColmapCamera& c) { validate_colmap_camera(c, path.string()); }

// Sorts by id, checks uniqueness and that tracks and 2D-3D links are consistent.
void finalize(ColmapModel& m, const fs::path& dir) {
  std::sort(m.images.begin(), m.images.end(), [](auto& a, auto& b) { return a.image_id < b.image_id; });
  std::sort(m.points.begin(), m.points.end(), [](auto& a, auto& b) { return a.point3d_id < b.point3d_id; });
  std::unordered_set<uint32_t> camera_ids;
  for (const auto& c : m.cameras)
    if (!camera_ids.insert(c.camera_id).second)
      throw_error(ErrorCode::kFormat, dir.string(), ": duplicate camera id ", c.camera_id);
  // Accepted quaternions (±1% of unit length, e.g. a text model written with
  // few digits) are normalized here, once, so that every later reader (a
  // segment's IMAGES checks ±0.1%) sees a unit quaternion.
  for (auto& im : m.images) {
    validate_colmap_image_pose(im, dir.string());
    auto& q = im.cam_from_world_q_wxyz;
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (double& x : q) x /= norm;
  }
  for (const auto& p : m.points)
    for (double x : p.xyz)
      if (!std::isfinite(x))
        throw_error(ErrorCode::kFormat, dir.string(), ": 3D point ", p.point3d_id, " has a non-finite position");
  for (size_t i = 1; i < m.images.size(); ++i)
    if (m.images[i].image_id == m.images[i - 1].image_id)
      throw_error(ErrorCode::kFormat, dir.string(), ": duplicate image id ", m.images[i].image_id);
  for (size_t i = 1; i < m.points.size(); ++i)
    if (m.points[i].point3d_id == m.points[i - 1].point3d_id)
      throw_error(ErrorCode::kFormat, dir.string(), ": duplicate 3D point id ", m.points[i].point3d_id);
  for (const auto& im : m.images)
    if (m.camera_index(im.camera_id) < 0)
      throw_error(ErrorCode::kFormat, dir.string(), ": image ", im.name, " refers to missing camera ",
                  im.camera_id);
  for (const auto& p : m.points)
    for (const auto& e : p.track) {
      const int64_t ii = m.image_index(e.image_id);
      if (ii < 0)
        throw_error(ErrorCode::kFormat, dir.string(), ": track of 3D point ", p.point3d_id,
                    " refers to missing image ", e.image_id);
      if (e.point2d_idx >= m.images[ii].points2d.size())
        throw_error(ErrorCode::kFormat, dir.string(), ": track of 3D point ", p.point3d_id, " refers to 2D point ",
                    e.point2d_idx, " of image ", m.images[ii].name, " which has ", m.images[ii].points2d.size());
    }
}

std::istringstream line_stream(const std::string& line) { return std::istringstream(line); }

bool next_data_line(std::istream& in, std::string& line) {
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    return true;
  }
  return false;
}

std::ifstream open_text(const fs::path& path) {
  require_regular_file(path);
  std::ifstream in(path);
  if (!in) throw_error(ErrorCode::kIo, path.string(), ": cannot open");
  return in;
}

}  // namespace

void validate_colmap_camera(const ColmapCamera& c, const std::string& file) {
  auto fail = [&](const auto&... parts) {
    throw_error(ErrorCode::kFormat, file, ": camera ", c.camera_id, ": ", parts...);
  };
  int expected = 0;
  try {
    expected = colmap_camera_model_num_params(c.model_id);
  } catch (const Error&) {
    fail("unknown camera model id ", c.model_id);
  }
  if (static_cast<int>(c.params.size()) != expected)
    fail("model ", colmap_camera_model_name(c.model_id), " takes ", expected, " parameters, found ", c.params.size());
  if (c.width == 0 || c.height == 0 || c.width > kColmapMaxImageSide || c.height > kColmapMaxImageSide)
    fail("image size ", c.width, "x", c.height, " is not valid (each side 1..", kColmapMaxImageSide, " pixels)");
  for (double p : c.params)
    if (!std::isfinite(p)) fail("a parameter is not finite (", p, ")");
  // COLMAP's models put one focal first (SIMPLE_PINHOLE, SIMPLE_RADIAL,
  // RADIAL and their fisheye forms) or fx, fy, then the principal point.
  const bool one_focal = c.model_id == 0 || c.model_id == 2 || c.model_id == 3 || c.model_id == 8 || c.model_id == 9;
  const int focals = one_focal ? 1 : 2;
  for (int k = 0; k < focals; ++k)
    if (!(c.params[k] > 0)) fail("focal length must be positive, found ", c.params[k]);
  const double cx = c.params[focals], cy = c.params[focals + 1];
  if (!(cx >= 0 && cx <= double(c.width) && cy >= 0 && cy <= double(c.height)))
    fail("principal point (", cx, ", ", cy, ") lies outside the ", c.width, "x", c.height, " image");
}

void validate_colmap_image_pose(const ColmapImage& im, const std::string& file) {
  const auto& q = im.cam_from_world_q_wxyz;
  const auto& t = im.cam_from_world_t;
  double norm2 = 0;
  for (double x : q) norm2 += x * x;
  if (!std::isfinite(norm2) || std::abs(std::sqrt(norm2) - 1.0) > 1e-2)
    throw_error(ErrorCode::kFormat, file, ": image ", im.image_id, " (", im.name,
                "): rotation is not a unit quaternion (", q[0], " ", q[1], " ", q[2], " ", q[3], ")");
  if (!std::isfinite(t[0]) || !std::isfinite(t[1]) || !std::isfinite(t[2]))
    throw_error(ErrorCode::kFormat, file, ": image ", im.image_id, " (", im.name, "): translation is not finite");
  for (const auto& p : im.points2d)
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]))
      throw_error(ErrorCode::kFormat, file, ": image ", im.image_id, " (", im.name, "): a 2D point is not finite");
}

int colmap_camera_model_num_params(int model_id) {
  for (const auto& m : kModels)
    if (m.id == model_id) return m.num_params;
  throw_error(ErrorCode::kFormat, "unknown COLMAP camera model id ", model_id);
}

std::string colmap_camera_model_name(int model_id) {
  for (const auto& m : kModels)
    if (m.id == model_id) return m.name;
  throw_error(ErrorCode::kFormat, "unknown COLMAP camera model id ", model_id);
}

int colmap_camera_model_id(const std::string& name) {
  for (const auto& m : kModels)
    if (name == m.name) return m.id;
  throw_error(ErrorCode::kFormat, "unknown COLMAP camera model '", name, "'");
}

int64_t ColmapModel::image_index(uint32_t image_id) const {
  auto it = std::lower_bound(images.begin(), images.end(), image_id,
                             [](const ColmapImage& im, uint32_t id) { return im.image_id < id; });
  return it != images.end() && it->image_id == image_id ? it - images.begin() : -1;
}

int64_t ColmapModel::image_index_by_name(const std::string& name) const {
  for (size_t i = 0; i < images.size(); ++i)
    if (images[i].name == name) return static_cast<int64_t>(i);
  return -1;
}

int64_t ColmapModel::camera_index(uint32_t camera_id) const {
  for (size_t i = 0; i < cameras.size(); ++i)
    if (cameras[i].camera_id == camera_id) return static_cast<int64_t>(i);
  return -1;
}

size_t ColmapModel::num_observations() const {
  size_t n = 0;
  for (const auto& p : points) n += p.track.size();
  return n;
}

ColmapModel read_colmap_model_binary(const fs::path& dir) {
  ColmapModel m;
  {
    BinaryCursor c(dir / "cameras.bin");
    const uint64_t n = c.get_count(24, "cameras");
    for (uint64_t i = 0; i < n; ++i) {
      ColmapCamera cam;
      cam.camera_id = c.get<uint32_t>("camera id");
      cam.model_id = c.get<int32_t>("camera model");
      cam.width = c.get<uint64_t>("camera width");
      cam.height = c.get<uint64_t>("camera height");
      int np = 0;
      try {
        np = colmap_camera_model_num_params(cam.model_id);
      } catch (const Error& e) {
        throw_error(ErrorCode::kFormat, (dir / "cameras.bin").string(), ": camera ", cam.camera_id, ": ", e.what());
      }
      for (int k = 0; k < np; ++k) cam.params.push_back(c.get<double>("camera parameters"));
      m.cameras.push_back(std::move(cam));
    }
    c.expect_end();
  }
  {
    BinaryCursor c(dir / "images.bin");
    const uint64_t n = c.get_count(73, "images");
    for (uint64_t i = 0; i < n; ++i) {
      ColmapImage im;
      im.image_id = c.get<uint32_t>("image id");
      for (auto& q : im.cam_from_world_q_wxyz) q = c.get<double>("image rotation");
      for (auto& t : im.cam_from_world_t) t = c.get<double>("image translation");
      im.camera_id = c.get<uint32_t>("image camera id");
      im.name = c.get_cstring("image name");
      const uint64_t np = c.get_count(24, "image 2D points");
      im.points2d.resize(np);
      im.point3d_ids.resize(np);
      for (uint64_t k = 0; k < np; ++k) {
        im.points2d[k][0] = c.get<double>("2D point");
        im.points2d[k][1] = c.get<double>("2D point");
        const int64_t id = c.get<int64_t>("2D point's 3D id");
        im.point3d_ids[k] = id < 0 ? kColmapInvalidPoint3DId : id;
      }
      m.images.push_back(std::move(im));
    }
    c.expect_end();
  }
  {
    BinaryCursor c(dir / "points3D.bin");
    const uint64_t n = c.get_count(51, "3D points");
    m.points.reserve(n);
    for (uint64_t i = 0; i < n; ++i) {
      ColmapPoint3D p;
      p.point3d_id = static_cast<int64_t>(c.get<uint64_t>("3D point id"));
      for (auto& x : p.xyz) x = c.get<double>("3D point position");
      for (auto& x : p.rgb) x = c.get<uint8_t>("3D point colour");
      p.error = c.get<double>("3D point error");
      const uint64_t nt = c.get_count(8, "track");
      p.track.resize(nt);
      for (auto& e : p.track) {
        e.image_id = c.get<uint32_t>("track image id");
        e.point2d_idx = c.get<uint32_t>("track 2D point index");
      }
      m.points.push_back(std::move(p));
    }
    c.expect_end();
  }
  for (const auto& cam : m.cameras) check_params(dir / "cameras.bin", cam);
  finalize(m, dir);
  return m;
}

ColmapModel read_colmap_model_text(const fs::path& dir) {
  ColmapModel m;
  std::string line;
  {
    const fs::path path = dir / "cameras.txt";
    auto in = open_text(path);
    while (next_data_line(in, line)) {
      auto s = line_stream(line);
      ColmapCamera cam;
      std::string model;
      if (!(s >> cam.camera_id >> model >> cam.width >> cam.height))
        throw_error(ErrorCode::kFormat, path.string(), ": bad camera line '", line, "'");
      try {
        cam.model_id = colmap_camera_model_id(model);
      } catch (const Error& e) {
        throw_error(ErrorCode::kFormat, path.string(), ": camera ", cam.camera_id, ": ", e.what());
      }
      double v;
      while (s >> v) cam.params.push_back(v);
      if (!s.eof())
        throw_error(ErrorCode::kFormat, path.string(), ": camera ", cam.camera_id, ": a parameter is not a number ('",
                    line.substr(0, 120), "')");
      check_params(path, cam);
      m.cameras.push_back(std::move(cam));
    }
  }
  {
    const fs::path path = dir / "images.txt";
    auto in = open_text(path);
    // Image lines come in pairs; the 2D point line may be empty, so it is read
    // with getline directly rather than skipping blank lines.
    while (next_data_line(in, line)) {
      auto s = line_stream(line);
      ColmapImage im;
      auto& q = im.cam_from_world_q_wxyz;
      auto& t = im.cam_from_world_t;
      if (!(s >> im.image_id >> q[0] >> q[1] >> q[2] >> q[3] >> t[0] >> t[1] >> t[2] >> im.camera_id))
        throw_error(ErrorCode::kFormat, path.string(), ": bad image line '", line, "'");
      std::getline(s >> std::ws, im.name);
      while (!im.name.empty() && (im.name.back() == ' ' || im.name.back() == '\r')) im.name.pop_back();
      if (im.name.empty()) throw_error(ErrorCode::kFormat, path.string(), ": image ", im.image_id, " has no name");
      std::string pts;
      if (!std::getline(in, pts))
        throw_error(ErrorCode::kFormat, path.string(), ": image ", im.name, " lacks its 2D point line");
      auto ps = line_stream(pts);
      std::vector<double> v;
      double x;
      while (ps >> x) v.push_back(x);
      if (!ps.eof() || v.size() % 3 != 0)
        throw_error(ErrorCode::kFormat, path.string(), ": bad 2D point line of image ", im.name,
                    " (expected X Y POINT3D_ID triples)");
      for (size_t k = 0; k < v.size(); k += 3) {
        im.points2d.push_back({v[k], v[k + 1]});
        if (!(v[k + 2] < 9.0e18) || v[k + 2] != std::floor(v[k + 2]))
          throw_error(ErrorCode::kFormat, path.string(), ": image ", im.name, ": bad POINT3D_ID ", v[k + 2]);
        im.point3d_ids.push_back(v[k + 2] < 0 ? kColmapInvalidPoint3DId : static_cast<int64_t>(v[k + 2]));
      }
      m.images.push_back(std::move(im));
    }
  }
  {
    const fs::path path = dir / "points3D.txt";
    auto in = open_text(path);
    while (next_data_line(in, line)) {
      auto s = line_stream(line);
      ColmapPoint3D p;
      int r, g, b;
      if (!(s >> p.point3d_id >> p.xyz[0] >> p.xyz[1] >> p.xyz[2] >> r >> g >> b >> p.error))
        throw_error(ErrorCode::kFormat, path.string(), ": bad 3D point line '", line.substr(0, 80), "'");
      p.rgb = {static_cast<uint8_t>(r), static_cast<uint8_t>(g), static_cast<uint8_t>(b)};
      std::vector<int64_t> v;
      int64_t x;
      while (s >> x) v.push_back(x);
      for (size_t k = 0; k + 1 < v.size(); k += 2)
        p.track.push_back({static_cast<uint32_t>(v[k]), static_cast<uint32_t>(v[k + 1])});
      if (!s.eof() || v.size() % 2 != 0)
        throw_error(ErrorCode::kFormat, path.string(), ": bad track of 3D point ", p.point3d_id);
      m.points.push_back(std::move(p));
    }
  }
  finalize(m, dir);
  return m;
}

ColmapModel read_colmap_model(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw_error(ErrorCode::kIo, dir.string(), ": no such COLMAP model directory");
  const bool binary = fs::exists(dir / "cameras.bin") && fs::exists(dir / "images.bin") &&
                      fs::exists(dir / "points3D.bin");
  if (binary) return read_colmap_model_binary(dir);
  for (const char* f : {"cameras.txt", "images.txt", "points3D.txt"})
    if (!fs::exists(dir / f))
      throw_error(ErrorCode::kIo, dir.string(),
                  ": not a COLMAP model (needs cameras, images and points3D as .bin or .txt; missing ", f, ")");
  return read_colmap_model_text(dir);
}

void write_colmap_model_binary(const ColmapModel& m, const fs::path& dir) {
  fs::create_directories(dir);
  BinaryBuffer cams;
  cams.put<uint64_t>(m.cameras.size());
  for (const auto& c : m.cameras) {
    cams.put<uint32_t>(c.camera_id);
    cams.put<int32_t>(c.model_id);
    cams.put<uint64_t>(c.width);
    cams.put<uint64_t>(c.height);
    for (double p : c.params) cams.put<double>(p);
  }
  write_file_atomic(dir / "cameras.bin", cams.str());
  BinaryBuffer ims;
  ims.put<uint64_t>(m.images.size());
  for (const auto& im : m.images) {
    ims.put<uint32_t>(im.image_id);
    for (double q : im.cam_from_world_q_wxyz) ims.put<double>(q);
    for (double t : im.cam_from_world_t) ims.put<double>(t);
    ims.put<uint32_t>(im.camera_id);
    ims.put_cstring(im.name);
    ims.put<uint64_t>(im.points2d.size());
    for (size_t k = 0; k < im.points2d.size(); ++k) {
      ims.put<double>(im.points2d[k][0]);
      ims.put<double>(im.points2d[k][1]);
      ims.put<int64_t>(im.point3d_ids[k]);
    }
  }
  write_file_atomic(dir / "images.bin", ims.str());
  BinaryBuffer pts;
  pts.put<uint64_t>(m.points.size());
  for (const auto& p : m.points) {
    pts.put<uint64_t>(static_cast<uint64_t>(p.point3d_id));
    for (double x : p.xyz) pts.put<double>(x);
    for (uint8_t c : p.rgb) pts.put<uint8_t>(c);
    pts.put<double>(p.error);
    pts.put<uint64_t>(p.track.size());
    for (const auto& e : p.track) {
      pts.put<uint32_t>(e.image_id);
      pts.put<uint32_t>(e.point2d_idx);
    }
  }
  write_file_atomic(dir / "points3D.bin", pts.str());
}

void write_colmap_model_text(const ColmapModel& m, const fs::path& dir) {
  fs::create_directories(dir);
  std::ostringstream c;
  c << std::setprecision(17) << "# Camera list with one line of data per camera:\n"
    << "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  for (const auto& cam : m.cameras) {
    c << cam.camera_id << ' ' << colmap_camera_model_name(cam.model_id) << ' ' << cam.width << ' ' << cam.height;
    for (double p : cam.params) c << ' ' << p;
    c << '\n';
  }
  write_file_atomic(dir / "cameras.txt", c.str());
  std::ostringstream i;
  i << std::setprecision(17) << "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
    << "# POINTS2D[] as (X, Y, POINT3D_ID)\n";
  for (const auto& im : m.images) {
    const auto& q = im.cam_from_world_q_wxyz;
    const auto& t = im.cam_from_world_t;
    i << im.image_id << ' ' << q[0] << ' ' << q[1] << ' ' << q[2] << ' ' << q[3] << ' ' << t[0] << ' ' << t[1]
      << ' ' << t[2] << ' ' << im.camera_id << ' ' << im.name << '\n';
    for (size_t k = 0; k < im.points2d.size(); ++k)
      i << (k ? " " : "") << im.points2d[k][0] << ' ' << im.points2d[k][1] << ' ' << im.point3d_ids[k];
    i << '\n';
  }
  write_file_atomic(dir / "images.txt", i.str());
  std::ostringstream p;
  p << std::setprecision(17) << "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
  for (const auto& pt : m.points) {
    p << pt.point3d_id << ' ' << pt.xyz[0] << ' ' << pt.xyz[1] << ' ' << pt.xyz[2] << ' ' << int(pt.rgb[0]) << ' '
      << int(pt.rgb[1]) << ' ' << int(pt.rgb[2]) << ' ' << pt.error;
    for (const auto& e : pt.track) p << ' ' << e.image_id << ' ' << e.point2d_idx;
    p << '\n';
  }
  write_file_atomic(dir / "points3D.txt", p.str());
}

ColmapHoldoutStats remove_images(ColmapModel& m, const std::vector<std::string>& names, size_t min_track_length) {
  ColmapHoldoutStats st;
  std::unordered_set<uint32_t> removed;
  std::string missing;
  for (const auto& n : names) {
    const int64_t i = m.image_index_by_name(n);
    if (i < 0) missing += (missing.empty() ? "" : ", ") + n;
    else removed.insert(m.images[i].image_id);
  }
  if (!missing.empty()) throw_error(ErrorCode::kNotFound, "images to hold out are not in the model: ", missing);
  st.images_removed = removed.size();
  std::vector<ColmapImage> kept_images;
  for (auto& im : m.images)
    if (!removed.count(im.image_id)) kept_images.push_back(std::move(im));
  m.images = std::move(kept_images);

  std::vector<ColmapPoint3D> kept_points;
  std::unordered_set<int64_t> dropped;
  for (auto& p : m.points) {
    const size_t before = p.track.size();
    std::erase_if(p.track, [&](const ColmapTrackElement& e) { return removed.count(e.image_id) > 0; });
    st.observations_removed += before - p.track.size();
    if (p.track.size() < min_track_length) {
      dropped.insert(p.point3d_id);
      ++st.points_dropped;
    } else {
      kept_points.push_back(std::move(p));
    }
  }
  m.points = std::move(kept_points);
  st.points_kept = m.points.size();
  for (auto& im : m.images)
    for (auto& id : im.point3d_ids)
      if (id != kColmapInvalidPoint3DId && dropped.count(id)) id = kColmapInvalidPoint3DId;
  return st;
}

}  // namespace visloc
