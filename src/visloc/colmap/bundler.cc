#include "visloc/colmap/bundler.h"

#include <zlib.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>

#include "visloc/features/sift_extractor.h"  // sift_to_uint8
#include "visloc/image/image_io.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"
#include "visloc/util/statistics.h"

namespace visloc {
namespace fs = std::filesystem;

namespace {

// Whole file, gunzipped when it is gzip (zlib reads plain files as they are).
std::string read_maybe_gzip(const fs::path& path) {
  gzFile f = gzopen(path.c_str(), "rb");
  if (!f) throw_error(ErrorCode::kIo, path.string(), ": cannot open");
  gzbuffer(f, 1 << 18);
  std::string out;
  std::vector<char> buf(1 << 20);
  for (;;) {
    const int n = gzread(f, buf.data(), static_cast<unsigned>(buf.size()));
    if (n < 0) {
      int code = 0;
      const std::string msg = gzerror(f, &code);
      gzclose(f);
      throw_error(ErrorCode::kFormat, path.string(), ": cannot read (", msg, ")");
    }
    if (n == 0) break;
    out.append(buf.data(), static_cast<size_t>(n));
  }
  if (gzclose(f) == Z_BUF_ERROR)
    throw_error(ErrorCode::kFormat, path.string(), ": the gzip stream ends early (truncated file)");
  return out;
}

// Whitespace-separated tokens with line numbers, for error messages that
// name the file and line. `item` says what is being read ("point 12").
class TextCursor {
 public:
  TextCursor(const std::string& text, const fs::path& file) : p_(text.data()), end_(text.data() + text.size()),
                                                              file_(file.string()) {}

  // Skips spaces; false at the end of the text.
  bool skip_space() {
    while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\n' || *p_ == '\r' || *p_ == '\f' || *p_ == '\v')) {
      if (*p_ == '\n') ++line_;
      ++p_;
    }
    return p_ < end_;
  }
  uint64_t line() const { return line_; }
  // Skips the rest of the current line.
  void skip_line() {
    while (p_ < end_ && *p_ != '\n') ++p_;
    if (p_ < end_) {
      ++p_;
      ++line_;
    }
  }
  const std::string& file() const { return file_; }

  // The next token's line (after skipping spaces); 0 at the end.
  uint64_t next_line() { return skip_space() ? line_ : 0; }

  double number(const char* what) {
    std::string_view tok = token(what);
    double v = 0;
    auto [ptr, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
    if (ec != std::errc() || ptr != tok.data() + tok.size() || !std::isfinite(v)) bad(what, tok, "a finite number");
    return v;
  }
  uint64_t integer(const char* what, uint64_t max = UINT64_MAX) {
    std::string_view tok = token(what);
    uint64_t v = 0;
    auto [ptr, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
    if (ec != std::errc() || ptr != tok.data() + tok.size()) bad(what, tok, "a non-negative integer");
    if (v > max) bad(what, tok, ("an integer at most " + std::to_string(max)).c_str());
    return v;
  }
  // An integer 0..255 (descriptor element): the hot loop of key files.
  uint8_t byte(const char* what) {
    if (!skip_space()) truncated(what);
    const char* s = p_;
    unsigned v = 0;
    int digits = 0;
    while (p_ < end_ && *p_ >= '0' && *p_ <= '9' && digits < 4) {
      v = v * 10 + unsigned(*p_ - '0');
      ++p_;
      ++digits;
    }
    if (digits == 0 || v > 255 || (p_ < end_ && !is_space(*p_))) {
      p_ = s;
      std::string_view tok = token(what);
      bad(what, tok, "an integer 0..255");
    }
    return static_cast<uint8_t>(v);
  }

  [[noreturn]] void fail(const std::string& message) const {
    throw_error(ErrorCode::kFormat, file_, ":", line_, ": ", item_, item_.empty() ? "" : ": ", message);
  }
  void set_item(std::string item) { item_ = std::move(item); }
  template <typename Index>
  void set_item(const char* kind, Index index) {
    item_ = kind;
    item_ += ' ';
    item_ += std::to_string(index);
  }

 private:
  static bool is_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v'; }
  std::string_view token(const char* what) {
    if (!skip_space()) truncated(what);
    const char* s = p_;
    while (p_ < end_ && !is_space(*p_)) ++p_;
    return {s, size_t(p_ - s)};
  }
  [[noreturn]] void truncated(const char* what) const {
    throw_error(ErrorCode::kFormat, file_, ":", line_, ": ", item_, item_.empty() ? "" : ": ",
                "the file ends where ", what, " was expected (truncated file?)");
  }
  [[noreturn]] void bad(const char* what, std::string_view tok, const char* expected) const {
    std::string shown(tok.substr(0, 40));
    fail(std::string(what) + ": expected " + expected + ", found '" + shown + "'");
  }

  const char* p_;
  const char* end_;
  std::string file_;
  uint64_t line_ = 1;
  std::string item_;
};

std::string trim(std::string s) {
  while (!s.empty() && (s.back() == '\r' || s.back() == ' ' || s.back() == '\t')) s.pop_back();
  size_t b = 0;
  while (b < s.size() && (s[b] == ' ' || s[b] == '\t')) ++b;
  return s.substr(b);
}

// Lowe key file → keypoints (our pixel convention) and, when wanted,
// descriptors. Lowe's files are small enough to hold whole.
struct LoweKeys {
  std::vector<Keypoint> keypoints;
  DescriptorMatrix descriptors;
};

LoweKeys parse_lowe_keys(const fs::path& path, bool want_descriptors, bool root_sift) {
  const std::string text = read_maybe_gzip(path);
  TextCursor c(text, path);
  c.set_item("header");
  const uint64_t n = c.integer("the number of keypoints", 100'000'000);
  const uint64_t len = c.integer("the descriptor length");
  if (len != 128) c.fail("descriptor length " + std::to_string(len) + ", expected 128 (a SIFT key file: \"N 128\")");
  // A key is 132 numbers, each at least one digit and a separator: the text
  // bounds the count before anything is allocated for it.
  if (n > text.size() / 264)
    c.fail("the header promises " + std::to_string(n) + " keypoints, more than " + std::to_string(text.size()) +
           " bytes can hold (truncated?)");
  LoweKeys out;
  out.keypoints.resize(n);
  if (want_descriptors) out.descriptors = DescriptorMatrix(n);
  uint8_t raw[kDescriptorDim];
  for (uint64_t i = 0; i < n; ++i) {
    c.set_item("keypoint", i);
    const double row = c.number("row");
    const double col = c.number("column");
    const double scale = c.number("scale");
    const double orientation = c.number("orientation");
    Keypoint& k = out.keypoints[i];
    k.x = static_cast<float>(col + 0.5);
    k.y = static_cast<float>(row + 0.5);
    k.scale = static_cast<float>(scale);
    k.orientation = static_cast<float>(-orientation);
    for (int j = 0; j < kDescriptorDim; ++j) raw[j] = c.byte("a descriptor value");
    if (want_descriptors) {
      if (root_sift) lowe_descriptor_to_root_sift(raw, out.descriptors.row(i));
      else std::copy(raw, raw + kDescriptorDim, out.descriptors.row(i));
    }
  }
  c.set_item("");
  if (c.skip_space())
    c.fail("data after the " + std::to_string(n) + " keypoints announced by the header");
  return out;
}

std::string key_stem(const fs::path& p) {
  std::string name = p.filename().string();
  for (const char* ext : {".key.gz", ".key"})
    if (name.size() > std::strlen(ext) && name.ends_with(ext)) return name.substr(0, name.size() - std::strlen(ext));
  return name;
}

fs::path find_image_file(const fs::path& images_dir, const std::string& name) {
  const fs::path a = images_dir / name;
  if (fs::exists(a)) return a;
  const fs::path b = images_dir / fs::path(name).filename();
  if (fs::exists(b)) return b;
  throw_error(ErrorCode::kNotFound, "image ", name, " of the Bundler list is not in ", images_dir.string(), " (tried ",
              a.string(), (a == b ? "" : " and " + b.string()), ")");
}

}  // namespace

// ------------------------------------------------------------------ readers

BundlerFile read_bundler_file(const fs::path& path) {
  const std::string text = read_maybe_gzip(path);
  const std::string header = trim(text.substr(0, text.find('\n')));
  if (header != "# Bundle file v0.3")
    throw_error(ErrorCode::kFormat, path.string(), ":1: expected the header '# Bundle file v0.3', found '",
                header.substr(0, 60), "'");
  TextCursor c(text, path);
  c.skip_line();
  BundlerFile b;
  c.set_item("counts");
  const uint64_t num_cameras = c.integer("the number of cameras", UINT32_MAX);
  const uint64_t num_points = c.integer("the number of points", UINT32_MAX);
  // Before reserving: a camera takes at least 15 numbers, a point 7 (2 bytes each).
  if (num_cameras * 30 + num_points * 14 > text.size() + 1)
    throw_error(ErrorCode::kFormat, path.string(), ":", c.line(), ": ", num_cameras, " cameras and ", num_points,
                " points cannot fit in ", text.size(), " bytes (truncated file or wrong counts)");
  b.cameras.resize(num_cameras);
  for (uint64_t i = 0; i < num_cameras; ++i) {
    c.set_item("camera", i);
    BundlerCamera& cam = b.cameras[i];
    cam.line = c.next_line();
    cam.focal = c.number("f");
    cam.k1 = c.number("k1");
    cam.k2 = c.number("k2");
    for (int k = 0; k < 9; ++k) cam.rotation[k] = c.number("R");
    for (int k = 0; k < 3; ++k) cam.translation[k] = c.number("t");
  }
  b.points.resize(num_points);
  for (uint64_t i = 0; i < num_points; ++i) {
    c.set_item("point", i);
    BundlerPoint& p = b.points[i];
    for (int k = 0; k < 3; ++k) p.xyz[k] = c.number("position");
    for (int k = 0; k < 3; ++k) p.rgb[k] = static_cast<uint8_t>(c.integer("colour", 255));
    p.line = c.next_line();
    const uint64_t n = c.integer("the number of views", UINT32_MAX);
    p.views.reserve(std::min<uint64_t>(n, 4096));
    for (uint64_t v = 0; v < n; ++v) {
      if (c.next_line() != p.line)
        throw_error(ErrorCode::kFormat, path.string(), ":", p.line, ": point ", i, ": the view list announces ", n,
                    " views but its line holds ", v);
      BundlerView view;
      view.camera = static_cast<uint32_t>(c.integer("camera index", UINT32_MAX));
      if (view.camera >= num_cameras)
        c.fail("view " + std::to_string(v) + " names camera " + std::to_string(view.camera) + " but the file has " +
               std::to_string(num_cameras) + " cameras");
      view.key = static_cast<uint32_t>(c.integer("key index", UINT32_MAX));
      view.x = c.number("x");
      view.y = c.number("y");
      p.views.push_back(view);
    }
  }
  c.set_item("");
  if (c.skip_space()) c.fail("data after the " + std::to_string(num_points) + " points announced after the header");
  return b;
}

std::vector<BundlerListEntry> read_bundler_list(const fs::path& path) {
  const std::string text = read_maybe_gzip(path);
  std::vector<std::string> lines;
  size_t start = 0;
  while (start < text.size()) {
    size_t e = text.find('\n', start);
    if (e == std::string::npos) e = text.size();
    lines.push_back(trim(text.substr(start, e - start)));
    start = e + 1;
  }
  while (!lines.empty() && lines.back().empty()) lines.pop_back();
  std::vector<BundlerListEntry> out;
  out.reserve(lines.size());
  for (size_t i = 0; i < lines.size(); ++i) {
    const std::string& l = lines[i];
    const std::string where = path.string() + ":" + std::to_string(i + 1) + ": ";
    if (l.empty())
      throw_error(ErrorCode::kFormat, where, "blank line (line i names camera i − 1 of bundle.out)");
    std::vector<std::string> tok;
    size_t p = 0;
    while (p < l.size()) {
      while (p < l.size() && (l[p] == ' ' || l[p] == '\t')) ++p;
      size_t q = p;
      while (q < l.size() && l[q] != ' ' && l[q] != '\t') ++q;
      if (q > p) tok.emplace_back(l.substr(p, q - p));
      p = q;
    }
    BundlerListEntry e;
    e.name = tok[0];
    if (tok.size() == 3) {
      double f = 0;
      auto [ptr, ec] = std::from_chars(tok[2].data(), tok[2].data() + tok[2].size(), f);
      if (ec != std::errc() || ptr != tok[2].data() + tok[2].size() || !std::isfinite(f))
        throw_error(ErrorCode::kFormat, where, "expected 'name 0 focal', found '", l, "'");
      e.has_focal = true;
      e.focal = f;
    } else if (tok.size() != 1) {
      throw_error(ErrorCode::kFormat, where, "expected 'name' or 'name 0 focal', found '", l,
                  "' (image names with spaces are not supported by Bundler)");
    }
    out.push_back(std::move(e));
  }
  return out;
}

void lowe_descriptor_to_root_sift(const uint8_t* lowe, uint8_t* out) {
  float v[kDescriptorDim];
  for (int j = 0; j < kDescriptorDim; ++j) v[j] = lowe[j];
  sift_to_uint8(v, /*root_sift=*/true, out);
}

FeatureSet read_lowe_key_file(const fs::path& path, bool root_sift) {
  LoweKeys k = parse_lowe_keys(path, /*want_descriptors=*/true, root_sift);
  FeatureSet f;
  f.image = key_stem(path);
  f.keypoints = std::move(k.keypoints);
  f.descriptors = std::move(k.descriptors);
  f.extractor = nlohmann::json{{"source", "lowe_key_file"}, {"file", path.string()},
                               {"descriptor", root_sift ? "rootsift" : "lowe"}}
                    .dump();
  return f;
}

fs::path find_lowe_key_file(const fs::path& list_dir, const fs::path& keys_dir, const std::string& image_name) {
  std::vector<fs::path> bases;
  if (keys_dir.empty()) {
    bases.push_back(list_dir / image_name);
  } else {
    bases.push_back(keys_dir / image_name);
    const fs::path alone = keys_dir / fs::path(image_name).filename();
    if (alone != bases[0]) bases.push_back(alone);
  }
  std::string tried;
  for (const auto& b : bases) {
    fs::path key = b;
    key.replace_extension(".key");
    fs::path gz = key;
    gz += ".gz";
    for (const auto& p : {key, gz}) {
      if (fs::exists(p)) return p;
      tried += (tried.empty() ? "" : ", ") + p.string();
    }
  }
  throw_error(ErrorCode::kNotFound, "no key file for image ", image_name, " (tried ", tried, ")");
}

// --------------------------------------------------------------- conversion

void BundlerConversionOptions::validate() const {
  if (!(max_key_offset_px > 0))
    throw_error(ErrorCode::kInvalidArgument, "BundlerConversionOptions.max_key_offset_px must be > 0");
  if (!images_dir.empty() && !fs::is_directory(images_dir))
    throw_error(ErrorCode::kNotFound, "BundlerConversionOptions.images_dir: ", images_dir.string(),
                " is not a directory");
  if (!keys_dir.empty() && !fs::is_directory(keys_dir))
    throw_error(ErrorCode::kNotFound, "BundlerConversionOptions.keys_dir: ", keys_dir.string(), " is not a directory");
}

DescriptorMatrix BundlerModel::descriptors(const ColmapImage& image) const {
  VISLOC_CHECK(image.image_id >= 1 && image.image_id <= key_files.size(), "image id outside the Bundler list");
  const fs::path& file = key_files[image.image_id - 1];
  if (file.empty()) {
    if (image.points2d.empty()) return {};
    throw_error(ErrorCode::kInternal, "image ", image.name, " has 2D points but no key file");
  }
  LoweKeys k = parse_lowe_keys(file, true, root_sift);
  if (k.keypoints.size() != image.points2d.size())
    throw_error(ErrorCode::kFormat, file.string(), ": has ", k.keypoints.size(), " keys now but had ",
                image.points2d.size(), " when the model was read (the file changed)");
  return std::move(k.descriptors);
}

namespace {

// Views of registered cameras grouped by camera: (point index, view index).
using ViewsByCamera = std::vector<std::vector<std::pair<uint32_t, uint32_t>>>;

// Counts the unregistered cameras (f = 0); a registered camera's R must be a
// proper rotation.
void check_camera_rotations(const BundlerFile& bf, const fs::path& bundle_file, BundlerConversionStats& st) {
  for (size_t i = 0; i < bf.cameras.size(); ++i) {
    const BundlerCamera& cam = bf.cameras[i];
    if (!cam.registered()) {
      ++st.cameras_unregistered;
      continue;
    }
    Eigen::Matrix3d R = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(cam.rotation.data());
    const double orth = (R * R.transpose() - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (orth > 1e-4 || R.determinant() < 0)
      throw_error(ErrorCode::kFormat, bundle_file.string(), ":", cam.line, ": camera ", i,
                  ": R is not a rotation (max |R Rᵀ − I| = ", orth, ", det = ", R.determinant(), ")");
  }
}

// Views of registered cameras by camera; counts the views of unregistered ones as dropped.
ViewsByCamera group_views_by_camera(const BundlerFile& bf, BundlerConversionStats& st) {
  ViewsByCamera by_camera(bf.cameras.size());
  for (size_t p = 0; p < bf.points.size(); ++p)
    for (size_t v = 0; v < bf.points[p].views.size(); ++v) {
      const uint32_t cam = bf.points[p].views[v].camera;
      if (bf.cameras[cam].registered()) by_camera[cam].emplace_back(uint32_t(p), uint32_t(v));
      else ++st.observations_dropped;
    }
  return by_camera;
}

// cam_from_world = diag(1, −1, −1) [R | t] (Bundler's camera looks down −z with +y up).
void set_cam_from_world(const BundlerCamera& cam, ColmapImage& im) {
  Eigen::Matrix3d R = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(cam.rotation.data());
  Eigen::Vector3d tv(cam.translation[0], cam.translation[1], cam.translation[2]);
  const Eigen::Vector3d flip(1, -1, -1);
  R = flip.asDiagonal() * R;
  tv = flip.asDiagonal() * tv;
  Eigen::Quaterniond q(R);
  q.normalize();
  im.cam_from_world_q_wxyz = {q.w(), q.x(), q.y(), q.z()};
  im.cam_from_world_t = {tv[0], tv[1], tv[2]};
}

// Principal point (cx, cy) and image size of camera c: from the image's
// header when there is an images folder, otherwise the median offset of the
// views from their keys (image size = twice the principal point).
std::array<double, 2> principal_point(const BundlerFile& bf, const std::vector<std::pair<uint32_t, uint32_t>>& views,
                                      const std::vector<Keypoint>& keys, const std::string& image_name,
                                      const BundlerConversionOptions& options, ColmapCamera& camera) {
  double cx = 0, cy = 0;
  if (!options.images_dir.empty()) {
    const ImageMetadata md = read_image_metadata(find_image_file(options.images_dir, image_name));
    camera.width = static_cast<uint64_t>(md.width);
    camera.height = static_cast<uint64_t>(md.height);
    cx = 0.5 * md.width;
    cy = 0.5 * md.height;
  } else {
    std::vector<double> ox, oy;
    ox.reserve(views.size());
    oy.reserve(views.size());
    for (auto [p, v] : views) {
      const BundlerView& view = bf.points[p].views[v];
      ox.push_back(double(keys[view.key].x) - view.x);
      oy.push_back(double(keys[view.key].y) + view.y);
    }
    VISLOC_CHECK(!ox.empty());
    cx = median(ox);
    cy = median(oy);
    camera.width = static_cast<uint64_t>(std::max(0.0, std::round(2 * cx)));
    camera.height = static_cast<uint64_t>(std::max(0.0, std::round(2 * cy)));
  }
  return {cx, cy};
}

// Registered camera c as a COLMAP image and RADIAL camera appended to
// out.model: its keys (every view must name one of them) become the 2D
// points, the views' positions replace their keys' and link them to the
// points. False (nothing added) when it has no view and no images folder.
bool convert_camera(size_t c, const BundlerFile& bf, const std::vector<std::pair<uint32_t, uint32_t>>& views,
                    const std::string& image_name, const fs::path& list_dir, const fs::path& bundle_file,
                    const BundlerConversionOptions& options, BundlerModel& out) {
  BundlerConversionStats& st = out.stats;
  const BundlerCamera& cam = bf.cameras[c];
  if (views.empty() && options.images_dir.empty()) {
    ++st.images_dropped_no_principal_point;
    return false;
  }
  ColmapImage im;
  im.image_id = static_cast<uint32_t>(c + 1);
  im.camera_id = im.image_id;
  im.name = image_name;
  set_cam_from_world(cam, im);

  ColmapCamera camera;
  camera.camera_id = im.camera_id;
  camera.model_id = colmap_camera_model_id("RADIAL");
  std::vector<Keypoint> keys;
  if (!views.empty()) {
    out.key_files[c] = find_lowe_key_file(list_dir, options.keys_dir, im.name);
    keys = parse_lowe_keys(out.key_files[c], /*want_descriptors=*/false, false).keypoints;
    st.keys += keys.size();
    for (auto [p, v] : views) {
      const BundlerView& view = bf.points[p].views[v];
      if (view.key >= keys.size())
        throw_error(ErrorCode::kFormat, bundle_file.string(), ":", bf.points[p].line, ": point ", p, ": view ", v,
                    " names key ", view.key, " of camera ", c, " (", im.name, ") but ",
                    out.key_files[c].string(), " has ", keys.size(), " keys");
    }
  }
  const auto [cx, cy] = principal_point(bf, views, keys, im.name, options, camera);
  camera.params = {cam.focal, cx, cy, cam.k1, cam.k2};

  im.points2d.resize(keys.size());
  im.point3d_ids.assign(keys.size(), kColmapInvalidPoint3DId);
  for (size_t k = 0; k < keys.size(); ++k) im.points2d[k] = {keys[k].x, keys[k].y};
  const double tol2 = options.max_key_offset_px * options.max_key_offset_px;
  for (auto [p, v] : views) {
    const BundlerView& view = bf.points[p].views[v];
    const std::array<double, 2> obs{cx + view.x, cy - view.y};
    const double dx = obs[0] - keys[view.key].x, dy = obs[1] - keys[view.key].y;
    if (dx * dx + dy * dy > tol2) ++st.observations_off_key;
    im.points2d[view.key] = obs;
    im.point3d_ids[view.key] = int64_t(p) + 1;
  }
  out.model.cameras.push_back(std::move(camera));
  out.model.images.push_back(std::move(im));
  return true;
}

// Points: id = index in bundle.out + 1; tracks keep the views of kept images
// (points left without a view are dropped).
void convert_points(const BundlerFile& bf, const std::vector<bool>& image_kept, BundlerModel& out) {
  BundlerConversionStats& st = out.stats;
  out.model.points.reserve(bf.points.size());
  for (size_t p = 0; p < bf.points.size(); ++p) {
    const BundlerPoint& bp = bf.points[p];
    ColmapPoint3D pt;
    pt.point3d_id = int64_t(p) + 1;
    pt.xyz = bp.xyz;
    pt.rgb = bp.rgb;
    for (const auto& v : bp.views)
      if (image_kept[v.camera]) pt.track.push_back({v.camera + 1, v.key});
    if (pt.track.empty()) continue;
    st.observations += pt.track.size();
    out.model.points.push_back(std::move(pt));
  }
}

}  // namespace

BundlerModel read_bundler_model(const fs::path& bundle_file, const fs::path& list_file,
                                const BundlerConversionOptions& options) {
  options.validate();
  Timer t;
  BundlerModel out;
  out.root_sift = options.root_sift;
  BundlerConversionStats& st = out.stats;
  const BundlerFile bf = read_bundler_file(bundle_file);
  const std::vector<BundlerListEntry> list = read_bundler_list(list_file);
  if (list.size() != bf.cameras.size())
    throw_error(ErrorCode::kFormat, list_file.string(), ": lists ", list.size(), " images but ",
                bundle_file.string(), " has ", bf.cameras.size(),
                " cameras (camera i of bundle.out is line i + 1 of the list)");
  st.cameras = bf.cameras.size();
  st.points_read = bf.points.size();
  st.principal_point = options.images_dir.empty() ? "key files" : "image size";
  check_camera_rotations(bf, bundle_file, st);
  const ViewsByCamera by_camera = group_views_by_camera(bf, st);
  st.ms_bundle = t.elapsed_ms();

  t.reset();
  const fs::path list_dir = list_file.parent_path().empty() ? fs::path(".") : list_file.parent_path();
  out.key_files.assign(bf.cameras.size(), {});
  std::vector<bool> image_kept(bf.cameras.size(), false);
  for (size_t c = 0; c < bf.cameras.size(); ++c) {
    if (!bf.cameras[c].registered()) continue;
    image_kept[c] = convert_camera(c, bf, by_camera[c], list[c].name, list_dir, bundle_file, options, out);
  }
  st.ms_keys = t.elapsed_ms();

  convert_points(bf, image_kept, out);
  st.images = out.model.images.size();
  st.points = out.model.points.size();
  return out;
}

}  // namespace visloc
