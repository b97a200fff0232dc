// visloc synth city --out DIR [options]: renders a synthetic street-view city
// with exact ground truth (src/visloc/synth/city_writer.h documents the
// output layout), with a progress line on stderr and a summary on stdout.
// --measure-pairs N then measures SIFT matching between adjacent placemarks
// under the true geometry (view_pair_check.h).
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <unistd.h>

#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/synth/city_writer.h"
#include "visloc/synth/view_pair_check.h"
#include "visloc/util/error.h"

namespace visloc::cli {

std::vector<double> parse_numbers(const std::string& text, const char* option) {
  std::vector<double> out;
  std::stringstream s(text);
  std::string item;
  while (std::getline(s, item, ',')) {
    try {
      size_t used = 0;
      out.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw_error(ErrorCode::kInvalidArgument, option, ": '", item, "' is not a number (in '", text, "')");
    }
  }
  return out;
}

namespace {

std::array<int, 2> parse_size(const std::string& text, const char* option) {
  const auto x = text.find('x');
  int w = 0, h = 0;
  if (x == std::string::npos || std::sscanf(text.c_str(), "%dx%d", &w, &h) != 2)
    throw_error(ErrorCode::kInvalidArgument, option, ": '", text, "' is not WIDTHxHEIGHT");
  return {w, h};
}

std::string duration(double s) {
  char buf[32];
  if (s < 60) std::snprintf(buf, sizeof buf, "%.0fs", s);
  else if (s < 3600) std::snprintf(buf, sizeof buf, "%dm%02ds", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
  else std::snprintf(buf, sizeof buf, "%dh%02dm", static_cast<int>(s) / 3600, static_cast<int>(s) / 60 % 60);
  return buf;
}

void print_check(const char* label, const synth::ViewPairCheck& c) {
  std::printf("  %-6s features A %zu, B %zu; A on a surface %zu, covisible in B %zu; ratio matches %zu; "
              "true (reprojection) %zu; epipolar inliers %zu\n"
              "         true / features A = %.3f, true / covisible A = %.3f, precision = %.3f, epipolar precision = %.3f\n",
              label, c.features_a, c.features_b, c.with_surface_a, c.covisible_a, c.ratio_matches, c.true_matches,
              c.epipolar_inliers, c.true_fraction_of_features(), c.true_fraction_of_covisible(), c.precision(),
              c.epipolar_precision());
}

struct SynthCityArgs {
  synth::CityOptions city;
  std::string out, layout = "line", elevations = "5,15,30", size = "640x640",
              query_sizes = "1024x768,768x1024,800x600", origin = "1.2966,103.7764,15";
  std::vector<std::string> markers;
  int measure_pairs = 0;
  SiftOptions sift;
  bool quiet = false;
};

// --layout ... --seed: the street network and its buildings.
void add_city_layout_options(CLI::App* cmd, SynthCityArgs& a) {
  synth::CityOptions& o = a.city;
  cmd->add_option("--layout", a.layout, "Street network: line, grid or random")->capture_default_str();
  cmd->add_option("--road-length", o.layout.road_length_m, "line: street length; random: length of each road (m)")
      ->capture_default_str();
  cmd->add_option("--grid-blocks-x", o.layout.grid_blocks_x, "grid: blocks east-west")->capture_default_str();
  cmd->add_option("--grid-blocks-y", o.layout.grid_blocks_y, "grid: blocks north-south")->capture_default_str();
  cmd->add_option("--block-size", o.layout.block_size_m, "grid: distance between parallel streets (m)")
      ->capture_default_str();
  cmd->add_option("--random-roads", o.layout.random_roads, "random: number of roads")->capture_default_str();
  cmd->add_option("--random-extent", o.layout.random_extent_m, "random: roads start in this square (m)")
      ->capture_default_str();
  cmd->add_option("--random-max-turn", o.layout.random_max_turn_deg, "random: largest turn at a vertex (deg)")
      ->capture_default_str();
  cmd->add_option("--road-half-width", o.layout.road_half_width_m, "Carriageway half width (m)")->capture_default_str();
  cmd->add_option("--sidewalk", o.layout.sidewalk_width_m, "Sidewalk width (m)")->capture_default_str();
  cmd->add_option("--floors-min", o.layout.floors_min, "Fewest floors of a building")->capture_default_str();
  cmd->add_option("--floors-max", o.layout.floors_max, "Most floors of a building")->capture_default_str();
  cmd->add_option("--building-width-min", o.layout.building_width_min_m, "Narrowest frontage (m)")->capture_default_str();
  cmd->add_option("--building-width-max", o.layout.building_width_max_m, "Widest frontage (m)")->capture_default_str();
  cmd->add_option("--spacing-min", o.layout.placemark_spacing_min_m, "Placemark spacing, minimum (m)")
      ->capture_default_str();
  cmd->add_option("--spacing-max", o.layout.placemark_spacing_max_m, "Placemark spacing, maximum (m)")
      ->capture_default_str();
  cmd->add_option("--camera-height", o.layout.camera_height_m, "Street-view camera height (m)")->capture_default_str();
  cmd->add_option("--seed", o.layout.seed, "Seed of everything (same seed, same bytes)")->capture_default_str();
}

// --headings ... --size: the database views.
void add_city_view_options(CLI::App* cmd, SynthCityArgs& a) {
  synth::CityOptions& o = a.city;
  cmd->add_option("--headings", o.views.headings, "Views around each placemark (heading 0 = north)")
      ->capture_default_str();
  cmd->add_option("--elevations", a.elevations, "Elevations in degrees, comma-separated")->capture_default_str();
  cmd->add_option("--fov", o.views.fov_deg, "Horizontal field of view of database views (deg)")->capture_default_str();
  cmd->add_option("--size", a.size, "Database image size WIDTHxHEIGHT")->capture_default_str();
}

// --queries ... --query-gps-noise: the query images.
void add_city_query_options(CLI::App* cmd, SynthCityArgs& a) {
  synth::CityOptions& o = a.city;
  cmd->add_option("--queries", o.queries.count, "Number of query images")->capture_default_str();
  cmd->add_option("--query-sizes", a.query_sizes, "Query sizes, comma-separated WIDTHxHEIGHT")->capture_default_str();
  cmd->add_option("--query-fov-min", o.queries.fov_min_deg, "Query field of view, minimum (deg)")->capture_default_str();
  cmd->add_option("--query-fov-max", o.queries.fov_max_deg, "Query field of view, maximum (deg)")->capture_default_str();
  cmd->add_option("--query-pitch-min", o.queries.pitch_min_deg, "Query pitch, minimum (deg)")->capture_default_str();
  cmd->add_option("--query-pitch-max", o.queries.pitch_max_deg, "Query pitch, maximum (deg)")->capture_default_str();
  cmd->add_option("--query-roll-max", o.queries.roll_max_deg, "Query roll, largest magnitude (deg)")->capture_default_str();
  cmd->add_option("--query-exposure-min", o.queries.exposure_min, "Exposure gain, minimum")->capture_default_str();
  cmd->add_option("--query-exposure-max", o.queries.exposure_max, "Exposure gain, maximum")->capture_default_str();
  cmd->add_option("--query-blur-max", o.queries.blur_max_px, "Largest Gaussian blur sigma (px)")->capture_default_str();
  cmd->add_option("--query-noise-max", o.queries.noise_max, "Largest noise sigma (grey levels)")->capture_default_str();
  cmd->add_option("--query-cars-max", o.queries.cars_max, "Most cars in front of a query")->capture_default_str();
  cmd->add_option("--query-trees-max", o.queries.trees_max, "Most trees in front of a query")->capture_default_str();
  cmd->add_option("--query-gps-noise", o.queries.gps_noise_m, "Horizontal sigma of queries/gps.csv (m)")
      ->capture_default_str();
}

// --supersampling ... --measure-pairs and the SIFT options: rendering, output and the pair check.
void add_city_output_options(CLI::App* cmd, SynthCityArgs& a) {
  synth::CityOptions& o = a.city;
  cmd->add_option("--supersampling", o.render.supersampling, "s: s×s rays per pixel")->capture_default_str();
  cmd->add_option("--max-distance", o.render.max_distance_m, "Rays end here; sky beyond (m)")->capture_default_str();
  cmd->add_option("--haze-distance", o.render.haze_distance_m, "Aerial perspective distance (m)")->capture_default_str();
  cmd->add_option("--origin", a.origin, "ENU origin lat,lon,alt (WGS84)")->capture_default_str();
  cmd->add_option("--format", o.image_format, "Image format: jpg or png")->capture_default_str();
  cmd->add_option("--jpeg-quality", o.jpeg_quality, "JPEG quality")->capture_default_str();
  cmd->add_option("--photos", o.photo_dir, "Folder of photographs; crops appear on posters (e.g. ../shared/data)");
  cmd->add_option("--photo-fraction", o.render.photo_fraction, "Share of posters showing a photo crop")
      ->capture_default_str();
  cmd->add_option("--photo-crops", o.photo_crops.count, "Number of photo crops")->capture_default_str();
  cmd->add_option("--marker", a.markers, "Red sphere at x,y,z (ENU metres); repeatable (calibration, tests)");
  cmd->add_option("--jobs", o.jobs, "Render threads (the output does not depend on it)")->capture_default_str();
  cmd->add_flag("--resume", o.resume, "Complete an interrupted run: keep images already written");
  cmd->add_flag("--quiet", a.quiet, "No progress line");
  cmd->add_option("--measure-pairs", a.measure_pairs,
                  "Then measure SIFT matches between N pairs of adjacent placemarks under the true geometry")
      ->capture_default_str();
  add_sift_options(cmd, a.sift);
}

// The options given as text (--layout, --elevations, --size, --query-sizes,
// --origin, --marker) into a.city; validates it.
void parse_city_args(SynthCityArgs& a) {
  synth::CityOptions& o = a.city;
  o.layout.layout = synth::parse_road_layout(a.layout);
  o.views.elevations_deg = parse_numbers(a.elevations, "--elevations");
  const auto size = parse_size(a.size, "--size");
  o.views.width = size[0];
  o.views.height = size[1];
  o.queries.resolutions.clear();
  std::stringstream qs(a.query_sizes);
  for (std::string item; std::getline(qs, item, ',');) o.queries.resolutions.push_back(parse_size(item, "--query-sizes"));
  const auto origin = parse_numbers(a.origin, "--origin");
  if (origin.size() != 3) throw_error(ErrorCode::kInvalidArgument, "--origin: expected lat,lon,alt, got '", a.origin, "'");
  o.origin = {origin[0], origin[1], origin[2]};
  o.markers.clear();
  for (const auto& m : a.markers) {
    const auto v = parse_numbers(m, "--marker");
    if (v.size() != 3) throw_error(ErrorCode::kInvalidArgument, "--marker: expected x,y,z, got '", m, "'");
    o.markers.emplace_back(v[0], v[1], v[2]);
  }
  if (a.measure_pairs < 0) throw_error(ErrorCode::kInvalidArgument, "--measure-pairs: must be >= 0");
  o.validate();
}

// visloc synth city: renders, prints the summary, then measures adjacent pairs (--measure-pairs).
void run_synth_city(SynthCityArgs& a) {
  parse_city_args(a);
  const synth::CityOptions& o = a.city;
  const bool tty = isatty(STDERR_FILENO) != 0;
  double last_line = -10.0;
  bool finished = false;
  synth::CityProgressCallback progress;
  if (!a.quiet) {
    progress = [tty, &last_line, &finished](const synth::CityProgress& p) {
      // On a terminal the line is redrawn; in a log, one line every 10 s.
      if (finished || (!tty && p.done != p.total && p.elapsed_s - last_line < 10.0)) return;
      last_line = p.elapsed_s;
      finished = p.done == p.total;
      const double rate = p.elapsed_s > 0 ? p.done / p.elapsed_s : 0.0;
      const double eta = rate > 0 ? (p.total - p.done) / rate : 0.0;
      std::fprintf(stderr, "%simages %zu/%zu, %.2f img/s, elapsed %s, ETA %s   %s", tty ? "\r" : "", p.done, p.total,
                   rate, duration(p.elapsed_s).c_str(), duration(eta).c_str(),
                   (tty && p.done != p.total) ? "" : "\n");
      std::fflush(stderr);
    };
  }
  const synth::CityStats s = synth::write_city(o, a.out, progress);
  std::printf("synthetic city in %s: %s layout, %.0f m of road, %d buildings, %d placemarks\n", a.out.c_str(),
              a.layout.c_str(), s.road_length_m, s.buildings, s.placemarks);
  std::printf("images: %zu database (%dx%d), %zu queries; rendered %zu, kept %zu; %.1f s\n", s.database_images,
              o.views.width, o.views.height, s.query_images, s.rendered, s.kept, s.seconds);
  std::printf("median render time per image: database %.1f ms (with encoding and writing %.1f ms), queries %.1f ms\n",
              s.median_database_render_ms, s.median_database_total_ms, s.median_query_render_ms);
  std::printf("bytes: database images %llu, query images %llu, metadata %llu, total %llu\n",
              static_cast<unsigned long long>(s.database_bytes), static_cast<unsigned long long>(s.query_bytes),
              static_cast<unsigned long long>(s.metadata_bytes),
              static_cast<unsigned long long>(s.database_bytes + s.query_bytes + s.metadata_bytes));
  if (a.measure_pairs > 0) {
    const synth::AdjacentPairReport r = synth::measure_adjacent_placemarks(o, a.out, a.measure_pairs, a.sift);
    std::printf("adjacent placemarks: %d pairs, %zu image pairs (same heading and elevation), SIFT %.0f ms in total\n",
                r.pairs, r.view_pairs, r.sift_ms);
    print_check("side", r.side);
    print_check("along", r.along);
    print_check("all", r.all());
  }
  std::fflush(stdout);
}

// visloc synth city.
void add_synth_city_command(CLI::App* synth) {
  auto a = std::make_shared<SynthCityArgs>();
  CLI::App* cmd = synth->add_subcommand(
      "city", "Render a synthetic street-view city: placemarks of rectilinear views, queries, exact poses");
  cmd->add_option("--out", a->out, "Output directory (layout: see docs/formats.md)")->required();
  add_city_layout_options(cmd, *a);
  add_city_view_options(cmd, *a);
  add_city_query_options(cmd, *a);
  add_city_output_options(cmd, *a);
  cmd->callback([a] { run_synth_city(*a); });
}

}  // namespace

void add_synth_command(CLI::App& app) {
  CLI::App* synth = app.add_subcommand("synth", "Generate synthetic data with exact ground truth");
  synth->require_subcommand(1);
  add_synth_city_command(synth);
}

}  // namespace visloc::cli
