// write_city: renders a synthetic street-view data set with exact ground
// truth (`visloc synth city`), streaming every image to disk as soon as it
// is rendered, so memory stays at one image per worker whatever the number
// of placemarks.
//
// Database views follow the paper (Tran et al., Sec. IV-A): at every
// placemark, `headings` rectilinear views 360°/headings apart (heading 0 =
// north, clockwise) at each elevation (5°, 15°, 30° above the horizon), 90°
// field of view, 640×640. Queries are taken at random places on the road and
// sidewalks (between and beside placemarks) by other cameras: other focal
// lengths and resolutions, hand height, pitch and roll, exposure and gamma
// change, blur, noise, and occluders (cars, trees) absent from the database.
//
// Output layout of DIR (world frame: local ENU metres, x east, y north,
// z up, origin = ENU origin in city.json; poses are world-to-camera,
// Hamilton quaternion w x y z, camera +z forward, x right, y down; pixel
// centre of the top-left pixel at (0.5, 0.5)):
//   city.json                 every option, the ENU origin, counts, conventions
//   images/pPPPPP_hHH_eE.jpg  database views (placemark, heading index, elevation index)
//   gps.csv                   image,lat,lon,alt,placemark (exact, WGS84)
//   sparse/cameras.txt        COLMAP text: one PINHOLE camera (fx fy cx cy)
//   sparse/images.txt         COLMAP text: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, empty 2D line
//   sparse/points3D.txt       COLMAP text, no points (for point_triangulator)
//   queries/images/qNNNNN.jpg query photographs
//   queries/list.txt          query names, one a line
//   queries/truth.txt         name qw qx qy qz tx ty tz (visuallocalization.net, world-to-camera)
//   queries/intrinsics.txt    name PINHOLE width height fx fy cx cy (hloc's query list format)
//   queries/gps.csv           image,lat,lon,alt (GPS with gps_noise_m horizontal noise)
//   queries/conditions.csv    name,exposure,gamma,blur_px,noise,cars,trees,fov_deg
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <string>
#include <vector>

#include "visloc/geo/enu_frame.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/synth/city_scene.h"
#include "visloc/synth/photo_crops.h"
#include "visloc/synth/ray_renderer.h"

namespace visloc {
class OptionTable;
}

namespace visloc::synth {

struct ViewSetOptions {
  int headings = 20;                                   // views around the placemark (18° apart)
  std::vector<double> elevations_deg = {5, 15, 30};    // pitch above the horizon
  double fov_deg = 90.0;                               // horizontal field of view
  int width = 640;
  int height = 640;
  void validate() const;
};

struct QueryOptions {
  int count = 20;
  double fov_min_deg = 45.0;   // horizontal field of view, uniform in [min, max]
  double fov_max_deg = 75.0;
  std::vector<std::array<int, 2>> resolutions = {{1024, 768}, {768, 1024}, {800, 600}};  // width, height
  double height_min_m = 1.4;   // camera above the ground
  double height_max_m = 1.8;
  double pitch_min_deg = -5.0;
  double pitch_max_deg = 20.0;
  double roll_max_deg = 4.0;
  double side_view_probability = 0.7;  // facing a facade; otherwise along the street
  double exposure_min = 0.6;   // gain, log-uniform in [min, max]
  double exposure_max = 1.6;
  double gamma_min = 0.8;
  double gamma_max = 1.25;
  double blur_max_px = 1.5;    // Gaussian blur sigma, uniform in [0, max]
  double noise_max = 6.0;      // Gaussian noise sigma in grey levels, uniform in [0, max]
  int cars_max = 3;            // occluders per query, uniform in [0, max]
  int trees_max = 2;
  double gps_noise_m = 5.0;    // horizontal sigma of the noisy GPS in queries/gps.csv
  // A query must show the city as the map saw it: at least this share of a
  // coarse grid of rays hits a building (not ground or sky) between
  // facade_min_distance_m and facade_range_m, else its place and view are
  // drawn again (up to 100 draws; the last one is kept). Rejected are photos
  // of empty road or sky at a street's end and close-ups of a wall from the
  // sidewalk (1-2 m away: 5× the scale at which the map's views, taken from
  // the road's centre line, saw it, and often a plain wall): no method can
  // localize the first, and the map does not hold the second.
  double min_facade_fraction = 0.3;
  double facade_min_distance_m = 4.0;
  double facade_range_m = 60.0;
  void validate() const;
};

struct CityOptions {
  CityLayoutOptions layout;    // layout.seed seeds everything
  ViewSetOptions views;
  QueryOptions queries;
  RenderOptions render;
  GeoPosition origin{1.2966, 103.7764, 15.0};  // ENU origin (WGS84); Singapore, as the paper
  std::string image_format = "jpg";            // jpg or png
  int jpeg_quality = 92;
  std::string photo_dir;                       // optional: photo crops for posters
  PhotoCropOptions photo_crops;
  int jobs = 1;                                // render threads (output does not depend on it)
  bool resume = false;                         // keep images already in DIR
  std::vector<Eigen::Vector3d> markers;        // flat red spheres at these ENU points (tests)
  double marker_radius_m = 0.3;
  void validate() const;
};

// The options as command-line options (`synth city`): --layout ... --seed (the layout), --headings,
// --elevations, --fov, --size (database views), --queries ... --query-gps-noise, --supersampling,
// --max-distance, --haze-distance, --origin, --format, --jpeg-quality, --photos, --photo-fraction,
// --photo-crops, --jobs, --resume. Not --marker, which is repeatable: see parse_marker_position.
void add_options(OptionTable& table, CityOptions& options);
// Single entries for commands that bind a few city options with help of their own (`bench city`):
// --layout line|grid|random, --elevations "5,15,30" (degrees), --size WIDTHxHEIGHT (database views).
void add_layout_option(OptionTable& table, CityLayoutOptions& layout, std::string help);
void add_elevations_option(OptionTable& table, ViewSetOptions& views, std::string help);
void add_size_option(OptionTable& table, ViewSetOptions& views, std::string help);
// "x,y,z" (ENU metres) → a marker position (CityOptions::markers); throws Error(kInvalidArgument) naming `option`.
Eigen::Vector3d parse_marker_position(const std::string& text, const std::string& option);

// One database view of a placemark.
CameraPose street_view_pose(const Eigen::Vector3d& center, double heading_deg, double pitch_deg,
                            double roll_deg = 0.0);
PinholeCamera camera_from_fov(int width, int height, double horizontal_fov_deg);
std::string database_image_name(int placemark, int heading_index, int elevation_index);
// Adds the options' red marker spheres (tests, calibration) to a scene.
void add_markers(const CityOptions& options, CityScene& scene);

// A query: camera, pose, photometric conditions and occluders; a pure
// function of (scene, options, index).
struct QuerySpec {
  std::string name;
  PinholeCamera camera;
  CameraPose cam_from_world;
  double fov_deg = 0;
  double exposure = 1, gamma = 1, blur_px = 0, noise = 0;
  int cars = 0, trees = 0;
  SceneObjects occluders;
  Eigen::Vector3d gps_enu = Eigen::Vector3d::Zero();  // noisy
  uint64_t seed = 0;
};
QuerySpec make_query(const CityScene& scene, const CityOptions& options, int index);
// Exposure, gamma, blur and noise, in place.
void apply_photometric(const QuerySpec& query, RgbImage& image);

struct CityProgress {
  size_t done = 0;       // images finished (rendered or kept)
  size_t total = 0;
  double elapsed_s = 0;
};

struct CityStats {
  int placemarks = 0;
  int buildings = 0;
  double road_length_m = 0;
  size_t database_images = 0;
  size_t query_images = 0;
  size_t rendered = 0;           // this run
  size_t kept = 0;               // already present (resume)
  uint64_t database_bytes = 0;   // image files
  uint64_t query_bytes = 0;
  uint64_t metadata_bytes = 0;
  double median_database_render_ms = 0;  // ray casting only
  double median_query_render_ms = 0;
  double median_database_total_ms = 0;   // render + encode + write
  double seconds = 0;
};

using CityProgressCallback = std::function<void(const CityProgress&)>;

// Renders the city into out_dir (created). Throws Error for bad options, a
// non-empty DIR without `resume`, or a DIR made with other options.
CityStats write_city(const CityOptions& options, const std::filesystem::path& out_dir,
                     const CityProgressCallback& progress = {});

// The JSON of every option (city.json's "options").
std::string city_options_json(const CityOptions& options);

// `synth city`'s progress line on `out`, "images 120/400, 3.20 img/s, elapsed 37s, ETA 1m27s": on a
// terminal one line redrawn in place; in a log a line every 10 s, and the last one.
class CityProgressPrinter {
 public:
  CityProgressPrinter(std::ostream& out, bool terminal) : out_(out), terminal_(terminal) {}
  void operator()(const CityProgress& progress);

 private:
  std::ostream& out_;
  bool terminal_;
  double last_line_s_ = -10.0;  // elapsed time at the last line written
  bool finished_ = false;       // the last line is written
};

// What `synth city` prints when the city is written to out_dir: the city (layout, road length,
// buildings, placemarks), the image counts, median render times and the bytes written (four lines).
std::string city_summary(const CityOptions& options, const CityStats& stats, const std::string& out_dir);

}  // namespace visloc::synth
