#include "visloc/synth/city_writer.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <mutex>
#include <nlohmann/json.hpp>
#include <numbers>
#include <ostream>
#include <sstream>
#include <thread>

#include "visloc/geo/gps_csv.h"
#include "visloc/image/image_io.h"
#include "visloc/synth/random.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace visloc::synth {
namespace fs = std::filesystem;
namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;

void require(bool ok, const char* group, const char* field, const std::string& why) {
  if (!ok) throw_error(ErrorCode::kInvalidArgument, group, " option ", field, ": ", why);
}

std::string format_g(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string pose_fields(const CameraPose& pose) {
  const auto q = pose.q_wxyz();
  std::string s;
  for (double v : q) s += format_g(v) + " ";
  for (int i = 0; i < 3; ++i) s += format_g(pose.translation[i]) + (i < 2 ? " " : "");
  return s;
}

double median_of(std::vector<float> v) {
  if (v.empty()) return 0.0;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

uint64_t file_size_or_zero(const fs::path& p) {
  std::error_code ec;
  const auto s = fs::file_size(p, ec);
  return ec ? 0 : s;
}

nlohmann::json options_to_json(const CityOptions& o) {
  nlohmann::json j;
  const auto& l = o.layout;
  j["layout"] = {{"layout", to_string(l.layout)},
                 {"road_length_m", l.road_length_m},
                 {"grid_blocks_x", l.grid_blocks_x},
                 {"grid_blocks_y", l.grid_blocks_y},
                 {"block_size_m", l.block_size_m},
                 {"random_roads", l.random_roads},
                 {"random_extent_m", l.random_extent_m},
                 {"random_max_turn_deg", l.random_max_turn_deg},
                 {"road_half_width_m", l.road_half_width_m},
                 {"sidewalk_width_m", l.sidewalk_width_m},
                 {"building_width_min_m", l.building_width_min_m},
                 {"building_width_max_m", l.building_width_max_m},
                 {"building_depth_min_m", l.building_depth_min_m},
                 {"building_depth_max_m", l.building_depth_max_m},
                 {"floors_min", l.floors_min},
                 {"floors_max", l.floors_max},
                 {"building_gap_max_m", l.building_gap_max_m},
                 {"setback_max_m", l.setback_max_m},
                 {"wing_probability", l.wing_probability},
                 {"placemark_spacing_min_m", l.placemark_spacing_min_m},
                 {"placemark_spacing_max_m", l.placemark_spacing_max_m},
                 {"camera_height_m", l.camera_height_m},
                 {"seed", l.seed}};
  // Written only when set, so that cities made before it keep their options.
  if (l.building_designs > 0) {
    j["layout"]["building_designs"] = l.building_designs;
    j["layout"]["building_design_share"] = l.building_design_share;
  }
  j["views"] = {{"headings", o.views.headings},
                {"elevations_deg", o.views.elevations_deg},
                {"fov_deg", o.views.fov_deg},
                {"width", o.views.width},
                {"height", o.views.height}};
  const auto& q = o.queries;
  j["queries"] = {{"count", q.count},
                  {"fov_min_deg", q.fov_min_deg},
                  {"fov_max_deg", q.fov_max_deg},
                  {"resolutions", q.resolutions},
                  {"height_min_m", q.height_min_m},
                  {"height_max_m", q.height_max_m},
                  {"pitch_min_deg", q.pitch_min_deg},
                  {"pitch_max_deg", q.pitch_max_deg},
                  {"roll_max_deg", q.roll_max_deg},
                  {"side_view_probability", q.side_view_probability},
                  {"min_facade_fraction", q.min_facade_fraction},
                  {"facade_min_distance_m", q.facade_min_distance_m},
                  {"facade_range_m", q.facade_range_m},
                  {"exposure_min", q.exposure_min},
                  {"exposure_max", q.exposure_max},
                  {"gamma_min", q.gamma_min},
                  {"gamma_max", q.gamma_max},
                  {"blur_max_px", q.blur_max_px},
                  {"noise_max", q.noise_max},
                  {"cars_max", q.cars_max},
                  {"trees_max", q.trees_max},
                  {"gps_noise_m", q.gps_noise_m}};
  j["render"] = {{"supersampling", o.render.supersampling},
                 {"max_distance_m", o.render.max_distance_m},
                 {"haze_distance_m", o.render.haze_distance_m},
                 {"photo_fraction", o.render.photo_fraction}};
  j["origin"] = {{"lat", o.origin.lat}, {"lon", o.origin.lon}, {"alt", o.origin.alt}};
  j["image_format"] = o.image_format;
  j["jpeg_quality"] = o.jpeg_quality;
  j["photo_dir"] = o.photo_dir;
  j["photo_crops"] = {{"count", o.photo_crops.count}, {"size", o.photo_crops.size}, {"seed", o.photo_crops.seed}};
  nlohmann::json markers = nlohmann::json::array();
  for (const auto& m : o.markers) markers.push_back({m.x(), m.y(), m.z()});
  j["markers"] = markers;
  j["marker_radius_m"] = o.marker_radius_m;
  return j;
}

// Separable Gaussian blur of an interleaved RGB float image.
void gaussian_blur(std::vector<float>& img, int w, int h, double sigma) {
  if (sigma < 0.05) return;
  const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigma)));
  std::vector<float> kernel(static_cast<size_t>(2 * radius + 1));
  float sum = 0;
  for (int i = -radius; i <= radius; ++i) sum += kernel[static_cast<size_t>(i + radius)] = static_cast<float>(std::exp(-0.5 * i * i / (sigma * sigma)));
  for (auto& k : kernel) k /= sum;
  std::vector<float> tmp(img.size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        float acc = 0;
        for (int i = -radius; i <= radius; ++i) {
          const int xx = std::clamp(x + i, 0, w - 1);
          acc += kernel[static_cast<size_t>(i + radius)] * img[(static_cast<size_t>(y) * w + xx) * 3 + c];
        }
        tmp[(static_cast<size_t>(y) * w + x) * 3 + c] = acc;
      }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        float acc = 0;
        for (int i = -radius; i <= radius; ++i) {
          const int yy = std::clamp(y + i, 0, h - 1);
          acc += kernel[static_cast<size_t>(i + radius)] * tmp[(static_cast<size_t>(yy) * w + x) * 3 + c];
        }
        img[(static_cast<size_t>(y) * w + x) * 3 + c] = acc;
      }
}

}  // namespace

void ViewSetOptions::validate() const {
  require(headings >= 1 && headings <= 360, "views", "headings", "must be in [1, 360]");
  require(!elevations_deg.empty() && elevations_deg.size() <= 10, "views", "elevations_deg", "needs 1 to 10 values");
  for (double e : elevations_deg) require(e > -89.0 && e < 89.0, "views", "elevations_deg", "each must be in (-89, 89)");
  require(fov_deg >= 10.0 && fov_deg <= 150.0, "views", "fov_deg", "must be in [10, 150]");
  require(width >= 16 && width <= 8192, "views", "width", "must be in [16, 8192]");
  require(height >= 16 && height <= 8192, "views", "height", "must be in [16, 8192]");
}

void QueryOptions::validate() const {
  require(count >= 0 && count <= 1000000, "queries", "count", "must be in [0, 1e6]");
  require(fov_min_deg >= 10.0 && fov_min_deg <= 150.0, "queries", "fov_min_deg", "must be in [10, 150]");
  require(fov_max_deg >= fov_min_deg && fov_max_deg <= 150.0, "queries", "fov_max_deg", "must be in [fov_min_deg, 150]");
  require(!resolutions.empty(), "queries", "resolutions", "needs at least one WIDTHxHEIGHT");
  for (const auto& r : resolutions)
    require(r[0] >= 16 && r[0] <= 8192 && r[1] >= 16 && r[1] <= 8192, "queries", "resolutions",
            "each side must be in [16, 8192]");
  require(height_min_m > 0.2 && height_max_m >= height_min_m && height_max_m < 50, "queries", "height_min_m/height_max_m",
          "need 0.2 < min <= max < 50");
  require(pitch_min_deg > -89 && pitch_max_deg >= pitch_min_deg && pitch_max_deg < 89, "queries",
          "pitch_min_deg/pitch_max_deg", "need -89 < min <= max < 89");
  require(roll_max_deg >= 0 && roll_max_deg <= 45, "queries", "roll_max_deg", "must be in [0, 45]");
  require(side_view_probability >= 0 && side_view_probability <= 1, "queries", "side_view_probability", "must be in [0, 1]");
  require(exposure_min > 0 && exposure_max >= exposure_min && exposure_max <= 10, "queries", "exposure_min/exposure_max",
          "need 0 < min <= max <= 10");
  require(gamma_min > 0 && gamma_max >= gamma_min && gamma_max <= 5, "queries", "gamma_min/gamma_max",
          "need 0 < min <= max <= 5");
  require(blur_max_px >= 0 && blur_max_px <= 20, "queries", "blur_max_px", "must be in [0, 20]");
  require(noise_max >= 0 && noise_max <= 100, "queries", "noise_max", "must be in [0, 100]");
  require(cars_max >= 0 && cars_max <= 20, "queries", "cars_max", "must be in [0, 20]");
  require(min_facade_fraction >= 0 && min_facade_fraction <= 1, "queries", "min_facade_fraction", "must be in [0, 1]");
  require(facade_min_distance_m >= 0 && facade_range_m > facade_min_distance_m, "queries",
          "facade_min_distance_m/facade_range_m", "need 0 <= min < range");
  require(trees_max >= 0 && trees_max <= 20, "queries", "trees_max", "must be in [0, 20]");
  require(gps_noise_m >= 0, "queries", "gps_noise_m", "must be >= 0");
}

void CityOptions::validate() const {
  layout.validate();
  views.validate();
  queries.validate();
  render.validate();
  if (!(origin.lat >= -90 && origin.lat <= 90))
    throw_error(ErrorCode::kInvalidArgument, "city option origin.lat: must be in [-90, 90], got ", origin.lat);
  if (!(origin.lon >= -180 && origin.lon <= 180))
    throw_error(ErrorCode::kInvalidArgument, "city option origin.lon: must be in [-180, 180], got ", origin.lon);
  if (image_format != "jpg" && image_format != "png")
    throw_error(ErrorCode::kInvalidArgument, "city option image_format: must be jpg or png, got '", image_format, "'");
  if (jpeg_quality < 1 || jpeg_quality > 100)
    throw_error(ErrorCode::kInvalidArgument, "city option jpeg_quality: must be in [1, 100], got ", jpeg_quality);
  if (jobs < 1 || jobs > 256)
    throw_error(ErrorCode::kInvalidArgument, "city option jobs: must be in [1, 256], got ", jobs);
  if (!photo_dir.empty()) photo_crops.validate();
  if (!(marker_radius_m > 0))
    throw_error(ErrorCode::kInvalidArgument, "city option marker_radius_m: must be positive");
}

std::string city_options_json(const CityOptions& options) { return options_to_json(options).dump(2); }

CameraPose street_view_pose(const Eigen::Vector3d& center, double heading_deg, double pitch_deg, double roll_deg) {
  const double h = heading_deg * kDegToRad, p = pitch_deg * kDegToRad, r = roll_deg * kDegToRad;
  const Eigen::Vector3d z(std::sin(h) * std::cos(p), std::cos(h) * std::cos(p), std::sin(p));
  const Eigen::Vector3d x0(std::cos(h), -std::sin(h), 0.0);
  const Eigen::Vector3d y0 = z.cross(x0);
  Eigen::Matrix3d R;
  R.row(0) = std::cos(r) * x0 + std::sin(r) * y0;
  R.row(1) = -std::sin(r) * x0 + std::cos(r) * y0;
  R.row(2) = z;
  return CameraPose::from_matrix(R, -R * center);
}

PinholeCamera camera_from_fov(int width, int height, double fov_deg) {
  return PinholeCamera::centered(width, height, width / 2.0 / std::tan(fov_deg * kDegToRad / 2));
}

void add_markers(const CityOptions& options, CityScene& scene) {
  for (const auto& m : options.markers) {
    SpherePrimitive s;
    s.center = m;
    s.radius = options.marker_radius_m;
    s.kind = ObjectKind::kMarker;
    s.colour = {1.0f, 0.0f, 0.0f};
    scene.objects.spheres.push_back(s);
  }
}

std::string database_image_name(int placemark, int heading_index, int elevation_index) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "p%05d_h%02d_e%d", placemark, heading_index, elevation_index);
  return buf;
}

// Share of a 16 × 12 grid of rays through the image that hit a surface above
// the ground (a facade, a tree) between `min_distance` and `range` metres.
double facade_fraction(const ViewRenderer& probe, const PinholeCamera& camera, const CameraPose& cam_from_world,
                       double min_distance, double range) {
  const Eigen::Vector3d origin = cam_from_world.center();
  const Eigen::Matrix3d world_from_cam = cam_from_world.rotation.conjugate().toRotationMatrix();
  constexpr int kCols = 16, kRows = 12;
  int hits = 0;
  for (int r = 0; r < kRows; ++r)
    for (int c = 0; c < kCols; ++c) {
      const double u = (c + 0.5) * camera.width / kCols, v = (r + 0.5) * camera.height / kRows;
      const Eigen::Vector3d ray =
          (world_from_cam * Eigen::Vector3d((u - camera.cx) / camera.focal, (v - camera.cy) / camera.focal, 1))
              .normalized();
      const std::optional<double> t = probe.cast_ray(origin, ray);
      if (t && *t >= min_distance && *t <= range && (origin + *t * ray).z() > 0.3) ++hits;
    }
  return static_cast<double>(hits) / (kCols * kRows);
}

QuerySpec make_query(const CityScene& scene, const CityOptions& options, int index) {
  const QueryOptions& q = options.queries;
  SplitMix64 rng(hash_keys(options.layout.seed, 0x9e7, static_cast<uint64_t>(index)));
  QuerySpec spec;
  char name[32];
  std::snprintf(name, sizeof name, "q%05d", index);
  spec.name = name;
  spec.seed = rng.next();
  // Place: a road chosen by length, an arc position, a lateral offset on the
  // carriageway or a sidewalk; redrawn until the view shows enough facades.
  const ViewRenderer probe(scene, nullptr, options.render);
  Eigen::Vector2d xy, p, d;
  Eigen::Vector3d center;
  double heading = 0;
  for (int draw = 0; draw < 100; ++draw) {
    const double total = scene.total_road_length();
    double s = rng.uniform(0.0, total);
    size_t road = 0;
    while (road + 1 < scene.roads.size() && s > scene.roads[road].length()) s -= scene.roads[road++].length();
    scene.roads[road].at(s, p, d);
    const double reach = scene.road_half_width + scene.sidewalk_width - 0.5;
    const Eigen::Vector2d n(-d.y(), d.x());
    xy = p + n * rng.uniform(-reach, reach);
    const double height = rng.uniform(q.height_min_m, q.height_max_m);
    center = Eigen::Vector3d(xy.x(), xy.y(), height);
    const double road_heading = std::atan2(d.x(), d.y()) / kDegToRad;
    if (rng.bernoulli(q.side_view_probability))
      heading = road_heading + (rng.bernoulli(0.5) ? 90.0 : -90.0) + rng.uniform(-50.0, 50.0);
    else
      heading = road_heading + (rng.bernoulli(0.5) ? 0.0 : 180.0) + rng.uniform(-30.0, 30.0);
    heading = std::fmod(heading + 720.0, 360.0);
    const double pitch = rng.uniform(q.pitch_min_deg, q.pitch_max_deg);
    const double roll = rng.uniform(-q.roll_max_deg, q.roll_max_deg);
    spec.fov_deg = rng.uniform(q.fov_min_deg, q.fov_max_deg);
    const auto& res = q.resolutions[static_cast<size_t>(rng.uniform_int(0, static_cast<int>(q.resolutions.size()) - 1))];
    spec.camera = camera_from_fov(res[0], res[1], spec.fov_deg);
    spec.cam_from_world = street_view_pose(center, heading, pitch, roll);
    if (facade_fraction(probe, spec.camera, spec.cam_from_world, q.facade_min_distance_m, q.facade_range_m) >=
        q.min_facade_fraction)
      break;
  }
  spec.exposure = std::exp(rng.uniform(std::log(q.exposure_min), std::log(q.exposure_max)));
  spec.gamma = rng.uniform(q.gamma_min, q.gamma_max);
  spec.blur_px = rng.uniform(0.0, q.blur_max_px);
  spec.noise = rng.uniform(0.0, q.noise_max);
  spec.gps_enu = center;
  spec.gps_enu.x() += q.gps_noise_m * rng.normal();
  spec.gps_enu.y() += q.gps_noise_m * rng.normal();

  // Occluders in front of the camera, outside buildings.
  const auto free_at = [&](const Eigen::Vector2d& at, double margin) {
    if ((at - xy).norm() < 2.0) return false;
    for (const auto& b : scene.objects.boxes)
      if (footprint_contains(b, at, margin)) return false;
    for (const auto& b : spec.occluders.boxes)
      if (footprint_contains(b, at, margin)) return false;
    for (const auto& c : spec.occluders.cylinders)
      if ((Eigen::Vector2d(c.cx, c.cy) - at).norm() < margin + 1.0) return false;
    return true;
  };
  const double half_fov = spec.fov_deg / 2;
  const int cars = rng.uniform_int(0, q.cars_max), trees = rng.uniform_int(0, q.trees_max);
  for (int c = 0; c < cars; ++c) {
    const double dist = rng.uniform(4.0, 14.0), az = (heading + rng.uniform(-0.8, 0.8) * half_fov) * kDegToRad;
    const Eigen::Vector2d at = xy + dist * Eigen::Vector2d(std::sin(az), std::cos(az));
    const bool flip = rng.bernoulli(0.5);
    const uint64_t seed = rng.next();
    const Rgb colour = hashed_colour(seed, 0.0f, 0.9f, 0.15f, 0.95f);
    if (!free_at(at, 2.4)) continue;
    BoxPrimitive body;
    body.cx = at.x();
    body.cy = at.y();
    body.cos_yaw = flip ? -d.x() : d.x();
    body.sin_yaw = flip ? -d.y() : d.y();
    body.half_x = 2.1;
    body.half_y = 0.9;
    body.z_min = 0.0;
    body.z_max = 1.05;
    body.kind = ObjectKind::kCarBody;
    body.seed = seed;
    body.colour = colour;
    BoxPrimitive cabin = body;
    cabin.cx -= 0.2 * body.cos_yaw;
    cabin.cy -= 0.2 * body.sin_yaw;
    cabin.half_x = 1.15;
    cabin.half_y = 0.82;
    cabin.z_min = 1.05;
    cabin.z_max = 1.5;
    cabin.kind = ObjectKind::kCarCabin;
    spec.occluders.boxes.push_back(body);
    spec.occluders.boxes.push_back(cabin);
    ++spec.cars;
  }
  for (int t = 0; t < trees; ++t) {
    const double dist = rng.uniform(3.5, 12.0), az = (heading + rng.uniform(-0.8, 0.8) * half_fov) * kDegToRad;
    const Eigen::Vector2d at = xy + dist * Eigen::Vector2d(std::sin(az), std::cos(az));
    const double radius = rng.uniform(1.2, 2.2), trunk_h = rng.uniform(2.6, 3.4);
    const uint64_t seed = rng.next();
    if (!free_at(at, radius) || (at - xy).norm() < radius + 1.0) continue;
    CylinderPrimitive trunk;
    trunk.cx = at.x();
    trunk.cy = at.y();
    trunk.radius = 0.16;
    trunk.z_min = 0;
    trunk.z_max = trunk_h + radius * 0.5;
    trunk.kind = ObjectKind::kTreeTrunk;
    trunk.seed = seed;
    trunk.colour = {0.36f, 0.27f, 0.19f};
    SpherePrimitive canopy;
    canopy.center = Eigen::Vector3d(at.x(), at.y(), trunk_h + radius * 0.7);
    canopy.radius = radius;
    canopy.kind = ObjectKind::kTreeCanopy;
    canopy.seed = mix64(seed);
    canopy.colour = hsv_to_rgb(static_cast<float>(0.22 + 0.1 * hash_unit(seed, 1)), 0.55f, 0.45f);
    spec.occluders.cylinders.push_back(trunk);
    spec.occluders.spheres.push_back(canopy);
    ++spec.trees;
  }
  return spec;
}

void apply_photometric(const QuerySpec& q, RgbImage& image) {
  const int w = image.width, h = image.height;
  std::vector<float> f(image.pixels.size());
  for (size_t i = 0; i < f.size(); ++i) {
    const double x = std::clamp(q.exposure * image.pixels[i] / 255.0, 0.0, 1.0);
    f[i] = static_cast<float>(255.0 * std::pow(x, q.gamma));
  }
  gaussian_blur(f, w, h, q.blur_px);
  for (size_t i = 0; i < f.size(); ++i) {
    const double u1 = 1.0 - hash_unit(q.seed, i, 1), u2 = hash_unit(q.seed, i, 2);
    const double n = std::sqrt(-2.0 * std::log(u1)) * std::cos(2 * std::numbers::pi * u2);
    image.pixels[i] = static_cast<uint8_t>(std::clamp(f[i] + q.noise * n + 0.5, 0.0, 255.0));
  }
}

namespace {

// Output directory: new, or a resume of the same options; creates its subdirectories.
void prepare_city_dir(const fs::path& out, const CityOptions& options, const std::string& options_json) {
  const fs::path city_json = out / "city.json";
  std::error_code ec;
  if (fs::exists(city_json, ec)) {
    if (!options.resume)
      throw_error(ErrorCode::kInvalidArgument, out.string(),
                  ": already holds a synthetic city (city.json); use --resume to complete it, or another directory");
    const auto existing = nlohmann::json::parse(read_file(city_json), nullptr, false);
    if (existing.is_discarded() || !existing.contains("options") ||
        existing["options"] != nlohmann::json::parse(options_json))
      throw_error(ErrorCode::kInvalidArgument, city_json.string(),
                  ": was made with different options; --resume needs the same options");
  }
  for (const fs::path& dir : {out, out / "images", out / "sparse", out / "queries", out / "queries" / "images"}) {
    fs::create_directories(dir, ec);
    if (ec) throw_error(ErrorCode::kIo, dir.string(), ": cannot create directory: ", ec.message());
  }
}

// The database views: every heading and elevation at every placemark, in
// that order; image i's name and pose.
struct DatabaseViews {
  const CityScene& scene;
  const ViewSetOptions& views;
  std::string ext;  // the image files' extension, with its dot
  int per_placemark = views.headings * static_cast<int>(views.elevations_deg.size());
  size_t count = scene.placemarks.size() * static_cast<size_t>(per_placemark);
  PinholeCamera camera = camera_from_fov(views.width, views.height, views.fov_deg);

  const Placemark& placemark(size_t i) const { return scene.placemarks[i / static_cast<size_t>(per_placemark)]; }

  void view(size_t i, std::string& name, CameraPose& pose) const {
    const auto& pm = placemark(i);
    const int v = static_cast<int>(i % static_cast<size_t>(per_placemark));
    const int hi = v / static_cast<int>(views.elevations_deg.size());
    const int ei = v % static_cast<int>(views.elevations_deg.size());
    name = database_image_name(pm.id, hi, ei) + ext;
    pose = street_view_pose(pm.position, 360.0 * hi / views.headings, views.elevations_deg[static_cast<size_t>(ei)]);
  }
};

// The database's COLMAP text model (cameras, images with their poses, no
// points) and its GPS list.
void write_database_metadata(const fs::path& out, const DatabaseViews& db, const EnuFrame& enu) {
  const PinholeCamera& db_camera = db.camera;
  std::string cams =
      "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
      "# Number of cameras: 1\n";
  cams += "1 PINHOLE " + std::to_string(db_camera.width) + " " + std::to_string(db_camera.height) + " " +
          format_g(db_camera.focal) + " " + format_g(db_camera.focal) + " " + format_g(db_camera.cx) + " " +
          format_g(db_camera.cy) + "\n";
  write_file_atomic(out / "sparse" / "cameras.txt", cams);
  AtomicFileWriter images(out / "sparse" / "images.txt");
  images.write("# Image list with two lines of data per image:\n"
               "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
               "#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: " +
               std::to_string(db.count) + ", mean observations per image: 0\n");
  std::vector<GpsRecord> gps;
  gps.reserve(db.count);
  for (size_t i = 0; i < db.count; ++i) {
    std::string name;
    CameraPose pose;
    db.view(i, name, pose);
    images.write(std::to_string(i + 1) + " " + pose_fields(pose) + " 1 " + name + "\n\n");
    GeoPosition g = enu.to_geo(pose.center());
    gps.push_back({name, g, db.placemark(i).id});
  }
  images.commit();
  write_file_atomic(out / "sparse" / "points3D.txt",
                    "# 3D point list with one line of data per point:\n"
                    "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                    "# Number of points: 0, mean track length: 0\n");
  write_gps_csv(out / "gps.csv", gps);
}

// The queries' list, true poses, intrinsics, conditions and GPS.
void write_query_metadata(const fs::path& out, const CityScene& scene, const CityOptions& options,
                          const EnuFrame& enu, const std::string& ext) {
  const size_t n_q = static_cast<size_t>(options.queries.count);
  std::string list, truth, intrinsics, conditions = "name,exposure,gamma,blur_px,noise,cars,trees,fov_deg\n";
  std::vector<GpsRecord> qgps;
  for (size_t i = 0; i < n_q; ++i) {
    const QuerySpec q = make_query(scene, options, static_cast<int>(i));
    const std::string name = q.name + ext;
    list += name + "\n";
    truth += name + " " + pose_fields(q.cam_from_world) + "\n";
    intrinsics += name + " PINHOLE " + std::to_string(q.camera.width) + " " + std::to_string(q.camera.height) + " " +
                  format_g(q.camera.focal) + " " + format_g(q.camera.focal) + " " + format_g(q.camera.cx) + " " +
                  format_g(q.camera.cy) + "\n";
    char buf[256];
    std::snprintf(buf, sizeof buf, "%s,%.4f,%.4f,%.4f,%.4f,%d,%d,%.4f\n", name.c_str(), q.exposure, q.gamma, q.blur_px,
                  q.noise, q.cars, q.trees, q.fov_deg);
    conditions += buf;
    qgps.push_back({name, enu.to_geo(q.gps_enu), std::nullopt});
  }
  write_file_atomic(out / "queries" / "list.txt", list);
  write_file_atomic(out / "queries" / "truth.txt", truth);
  write_file_atomic(out / "queries" / "intrinsics.txt", intrinsics);
  write_file_atomic(out / "queries" / "conditions.csv", conditions);
  write_gps_csv(out / "queries" / "gps.csv", qgps);
}

// city.json's text: options, conventions, counts and placemarks.
std::string city_json_text(const CityOptions& options, const std::string& options_json, const CityStats& stats,
                           const CityScene& scene_base, const CityScene& scene) {
  nlohmann::json city;
  city["format"] = "visloc synthetic city";
  city["version"] = 1;
  city["options"] = nlohmann::json::parse(options_json);
  city["enu_origin"] = {{"lat", options.origin.lat}, {"lon", options.origin.lon}, {"alt", options.origin.alt}};
  city["conventions"] = {
      {"world", "local ENU metres: x east, y north, z up; ground at z = 0; origin at enu_origin (WGS84)"},
      {"poses", "world-to-camera (cam_from_world): X_cam = R X_world + t; quaternion Hamilton w x y z"},
      {"camera", "looks along +z, x right, y down; pixel centre of the top-left pixel at (0.5, 0.5)"},
      {"heading", "degrees clockwise from north; heading index k is 360 k / headings"},
      {"image_names", "pPPPPP_hHH_eE: placemark, heading index, elevation index"}};
  city["counts"] = {{"placemarks", stats.placemarks},     {"buildings", stats.buildings},
                    {"boxes", scene_base.objects.boxes.size()}, {"road_length_m", stats.road_length_m},
                    {"database_images", stats.database_images}, {"query_images", stats.query_images}};
  nlohmann::json pms = nlohmann::json::array();
  for (const auto& pm : scene.placemarks)
    pms.push_back({{"id", pm.id}, {"road", pm.road}, {"arc_m", pm.arc},
                   {"enu", {pm.position.x(), pm.position.y(), pm.position.z()}}, {"road_heading_deg", pm.road_heading_deg}});
  city["placemarks"] = pms;
  return city.dump(2) + "\n";
}

// Per image (database images first, then queries): render and total
// milliseconds (-1: kept from an earlier run) and file bytes.
struct RenderedImages {
  std::vector<float> render_ms, total_ms;
  std::vector<uint64_t> bytes;
  size_t rendered = 0;
};

// The images: a pool of workers, each with its renderer and one image.
RenderedImages render_city_images(const fs::path& out, const CityOptions& options, const CityScene& scene,
                                  const PhotoCropSet& photos, const DatabaseViews& db, const Timer& wall,
                                  const CityProgressCallback& progress) {
  const size_t n_db = db.count;
  const size_t total = n_db + static_cast<size_t>(options.queries.count);
  RenderedImages result;
  std::vector<float>& render_ms = result.render_ms;
  std::vector<float>& total_ms = result.total_ms;
  std::vector<uint64_t>& bytes = result.bytes;
  render_ms.assign(total, -1.0f);
  total_ms.assign(total, -1.0f);
  bytes.assign(total, 0);
  std::atomic<size_t> next{0}, done{0}, rendered{0};
  std::mutex progress_mutex;
  double last_report = -1.0;
  std::exception_ptr failure;
  std::mutex failure_mutex;
  const auto report = [&](bool final) {
    if (!progress) return;
    std::lock_guard<std::mutex> lock(progress_mutex);
    const double now = wall.elapsed_ms() / 1000.0;
    if (!final && now - last_report < 0.25) return;
    last_report = now;
    progress(CityProgress{done.load(), total, now});
  };
  const auto worker = [&] {
    try {
      ViewRenderer renderer(scene, &photos, options.render);
      RgbImage image;
      while (true) {
        const size_t i = next.fetch_add(1);
        if (i >= total) break;
        {
          std::lock_guard<std::mutex> lock(failure_mutex);
          if (failure) break;
        }
        Timer t;
        std::string name;
        fs::path path;
        if (i < n_db) {
          CameraPose pose;
          db.view(i, name, pose);
          path = out / "images" / name;
          if (!(options.resume && file_size_or_zero(path) > 0)) {
            render_ms[i] = static_cast<float>(renderer.render(db.camera, pose, image).milliseconds);
            write_image(path, image.width, image.height, 3, image.pixels.data(), options.jpeg_quality);
            total_ms[i] = static_cast<float>(t.elapsed_ms());
            rendered.fetch_add(1);
          }
        } else {
          const QuerySpec q = make_query(scene, options, static_cast<int>(i - n_db));
          path = out / "queries" / "images" / (q.name + db.ext);
          if (!(options.resume && file_size_or_zero(path) > 0)) {
            render_ms[i] = static_cast<float>(renderer.render(q.camera, q.cam_from_world, image, &q.occluders).milliseconds);
            apply_photometric(q, image);
            write_image(path, image.width, image.height, 3, image.pixels.data(), options.jpeg_quality);
            total_ms[i] = static_cast<float>(t.elapsed_ms());
            rendered.fetch_add(1);
          }
        }
        bytes[i] = file_size_or_zero(path);
        done.fetch_add(1);
        report(false);
      }
    } catch (...) {
      std::lock_guard<std::mutex> lock(failure_mutex);
      if (!failure) failure = std::current_exception();
    }
  };
  std::vector<std::thread> threads;
  for (int j = 1; j < options.jobs; ++j) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  if (failure) std::rethrow_exception(failure);
  report(true);
  result.rendered = rendered.load();
  return result;
}

// Bytes, counts and median milliseconds of the images into stats.
void add_image_stats(const RenderedImages& images, size_t n_db, CityStats& stats) {
  const size_t total = images.bytes.size();
  std::vector<float> db_ms, q_ms, db_total;
  for (size_t i = 0; i < total; ++i) {
    if (i < n_db) stats.database_bytes += images.bytes[i]; else stats.query_bytes += images.bytes[i];
    if (images.render_ms[i] < 0) continue;
    (i < n_db ? db_ms : q_ms).push_back(images.render_ms[i]);
    if (i < n_db) db_total.push_back(images.total_ms[i]);
  }
  stats.rendered = images.rendered;
  stats.kept = total - stats.rendered;
  stats.median_database_render_ms = median_of(db_ms);
  stats.median_query_render_ms = median_of(q_ms);
  stats.median_database_total_ms = median_of(db_total);
}

}  // namespace

CityStats write_city(const CityOptions& options_in, const fs::path& out, const CityProgressCallback& progress) {
  CityOptions options = options_in;
  options.validate();
  Timer wall;
  const std::string options_json = city_options_json(options);
  prepare_city_dir(out, options, options_json);

  const CityScene scene_base = generate_city_scene(options.layout);
  CityScene scene = scene_base;
  add_markers(options, scene);
  PhotoCropSet photos;
  if (!options.photo_dir.empty()) photos = load_photo_crops(options.photo_dir, options.photo_crops);
  const EnuFrame enu(options.origin);
  const DatabaseViews db{scene, options.views, "." + options.image_format};

  // --- Metadata first (cheap, deterministic) ---
  CityStats stats;
  stats.placemarks = static_cast<int>(scene.placemarks.size());
  stats.buildings = scene.buildings;
  stats.road_length_m = scene.total_road_length();
  stats.database_images = db.count;
  stats.query_images = static_cast<size_t>(options.queries.count);
  write_database_metadata(out, db, enu);
  write_query_metadata(out, scene, options, enu, db.ext);

  // city.json before any image: it marks the directory as made by this
  // command with these options (checked by --resume).
  const std::string city_text = city_json_text(options, options_json, stats, scene_base, scene);
  write_file_atomic(out / "city.json", city_text);

  // --- Images ---
  add_image_stats(render_city_images(out, options, scene, photos, db, wall, progress), db.count, stats);

  for (const fs::path& p : {out / "sparse" / "cameras.txt", out / "sparse" / "images.txt", out / "sparse" / "points3D.txt",
                            out / "gps.csv", out / "queries" / "list.txt", out / "queries" / "truth.txt",
                            out / "queries" / "intrinsics.txt", out / "queries" / "gps.csv", out / "queries" / "conditions.csv"})
    stats.metadata_bytes += file_size_or_zero(p);
  stats.metadata_bytes += city_text.size();
  stats.seconds = wall.elapsed_ms() / 1000.0;
  return stats;
}

namespace {

// "42s", "3m05s", "2h07m".
std::string duration_text(double s) {
  char buf[32];
  if (s < 60)
    std::snprintf(buf, sizeof buf, "%.0fs", s);
  else if (s < 3600)
    std::snprintf(buf, sizeof buf, "%dm%02ds", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
  else
    std::snprintf(buf, sizeof buf, "%dh%02dm", static_cast<int>(s) / 3600, static_cast<int>(s) / 60 % 60);
  return buf;
}

}  // namespace

void CityProgressPrinter::operator()(const CityProgress& p) {
  if (finished_ || (!terminal_ && p.done != p.total && p.elapsed_s - last_line_s_ < 10.0)) return;
  last_line_s_ = p.elapsed_s;
  finished_ = p.done == p.total;
  const double rate = p.elapsed_s > 0 ? p.done / p.elapsed_s : 0.0;
  const double eta = rate > 0 ? (p.total - p.done) / rate : 0.0;
  std::ostringstream line;
  line << (terminal_ ? "\r" : "") << "images " << p.done << "/" << p.total << ", " << std::fixed << std::setprecision(2)
       << rate << " img/s, elapsed " << duration_text(p.elapsed_s) << ", ETA " << duration_text(eta) << "   "
       << (terminal_ && p.done != p.total ? "" : "\n");
  out_ << line.str() << std::flush;
}

std::string city_summary(const CityOptions& o, const CityStats& s, const std::string& out_dir) {
  std::ostringstream text;
  text << std::fixed << std::setprecision(0) << "synthetic city in " << out_dir << ": " << to_string(o.layout.layout)
       << " layout, " << s.road_length_m << " m of road, " << s.buildings << " buildings, " << s.placemarks
       << " placemarks\n";
  text << std::setprecision(1) << "images: " << s.database_images << " database (" << o.views.width << "x"
       << o.views.height << "), " << s.query_images << " queries; rendered " << s.rendered << ", kept " << s.kept
       << "; " << s.seconds << " s\n";
  text << "median render time per image: database " << s.median_database_render_ms << " ms (with encoding and writing "
       << s.median_database_total_ms << " ms), queries " << s.median_query_render_ms << " ms\n";
  text << "bytes: database images " << s.database_bytes << ", query images " << s.query_bytes << ", metadata "
       << s.metadata_bytes << ", total " << s.database_bytes + s.query_bytes + s.metadata_bytes << "\n";
  return text.str();
}

}  // namespace visloc::synth
