// The synthetic city's options as command-line options (util/option_table.h).
#include <iomanip>
#include <sstream>

#include "visloc/synth/city_writer.h"
#include "visloc/util/option_table.h"

namespace visloc::synth {
namespace {

// "5,15,30": numbers as --help shows their defaults (enough digits for a latitude).
std::string number_list_text(const std::vector<double>& values) {
  std::ostringstream s;
  s << std::setprecision(10);
  for (size_t i = 0; i < values.size(); ++i) s << (i ? "," : "") << values[i];
  return s.str();
}

std::string size_text(int width, int height) { return std::to_string(width) + "x" + std::to_string(height); }

// --query-sizes: comma-separated WIDTHxHEIGHT.
void add_query_sizes_option(OptionTable& t, QueryOptions& o) {
  std::string sizes;
  for (const auto& [width, height] : o.resolutions) {
    if (!sizes.empty()) sizes += ',';
    sizes += size_text(width, height);
  }
  t.text(
      "--query-sizes", sizes,
      [&o](const std::string& text) {
        o.resolutions.clear();
        std::stringstream items(text);
        for (std::string item; std::getline(items, item, ',');) {
          const auto [width, height] = parse_image_size(item, "--query-sizes");
          o.resolutions.push_back({width, height});
        }
      },
      "Query sizes, comma-separated WIDTHxHEIGHT");
}

// --origin lat,lon,alt.
void add_origin_option(OptionTable& t, GeoPosition& origin) {
  t.text(
      "--origin", number_list_text({origin.lat, origin.lon, origin.alt}),
      [&origin](const std::string& text) {
        const std::vector<double> v = parse_number_list(text, "--origin");
        if (v.size() != 3) throw_error(ErrorCode::kInvalidArgument, "--origin: expected lat,lon,alt, got '", text, "'");
        origin = {v[0], v[1], v[2]};
      },
      "ENU origin lat,lon,alt (WGS84)");
}

void add_layout_options(OptionTable& t, CityLayoutOptions& o) {
  add_layout_option(t, o, "Street network: line, grid or random");
  t.add("--road-length", o.road_length_m, "line: street length; random: length of each road (m)");
  t.add("--grid-blocks-x", o.grid_blocks_x, "grid: blocks east-west");
  t.add("--grid-blocks-y", o.grid_blocks_y, "grid: blocks north-south");
  t.add("--block-size", o.block_size_m, "grid: distance between parallel streets (m)");
  t.add("--random-roads", o.random_roads, "random: number of roads");
  t.add("--random-extent", o.random_extent_m, "random: roads start in this square (m)");
  t.add("--random-max-turn", o.random_max_turn_deg, "random: largest turn at a vertex (deg)");
  t.add("--road-half-width", o.road_half_width_m, "Carriageway half width (m)");
  t.add("--sidewalk", o.sidewalk_width_m, "Sidewalk width (m)");
  t.add("--floors-min", o.floors_min, "Fewest floors of a building");
  t.add("--floors-max", o.floors_max, "Most floors of a building");
  t.add("--building-width-min", o.building_width_min_m, "Narrowest frontage (m)");
  t.add("--building-width-max", o.building_width_max_m, "Widest frontage (m)");
  t.add("--spacing-min", o.placemark_spacing_min_m, "Placemark spacing, minimum (m)");
  t.add("--spacing-max", o.placemark_spacing_max_m, "Placemark spacing, maximum (m)");
  t.add("--camera-height", o.camera_height_m, "Street-view camera height (m)");
  t.add("--building-designs", o.building_designs,
        "0: every building its own design; N: buildings copy one of N designs (identical facades repeated)");
  t.add("--building-design-share", o.building_design_share,
        "With --building-designs: the share of buildings that copy a design (the others are their own)");
  t.add("--seed", o.seed, "Seed of everything (same seed, same bytes)");
}

void add_view_options(OptionTable& t, ViewSetOptions& o) {
  t.add("--headings", o.headings, "Views around each placemark (heading 0 = north)");
  add_elevations_option(t, o, "Elevations in degrees, comma-separated");
  t.add("--fov", o.fov_deg, "Horizontal field of view of database views (deg)");
  add_size_option(t, o, "Database image size WIDTHxHEIGHT");
}

void add_query_options(OptionTable& t, QueryOptions& o) {
  t.add("--queries", o.count, "Number of query images");
  add_query_sizes_option(t, o);
  t.add("--query-fov-min", o.fov_min_deg, "Query field of view, minimum (deg)");
  t.add("--query-fov-max", o.fov_max_deg, "Query field of view, maximum (deg)");
  t.add("--query-pitch-min", o.pitch_min_deg, "Query pitch, minimum (deg)");
  t.add("--query-pitch-max", o.pitch_max_deg, "Query pitch, maximum (deg)");
  t.add("--query-roll-max", o.roll_max_deg, "Query roll, largest magnitude (deg)");
  t.add("--query-exposure-min", o.exposure_min, "Exposure gain, minimum");
  t.add("--query-exposure-max", o.exposure_max, "Exposure gain, maximum");
  t.add("--query-blur-max", o.blur_max_px, "Largest Gaussian blur sigma (px)");
  t.add("--query-noise-max", o.noise_max, "Largest noise sigma (grey levels)");
  t.add("--query-cars-max", o.cars_max, "Most cars in front of a query");
  t.add("--query-trees-max", o.trees_max, "Most trees in front of a query");
  t.add("--query-gps-noise", o.gps_noise_m, "Horizontal sigma of queries/gps.csv (m)");
}

// Rendering and output.
void add_output_options(OptionTable& t, CityOptions& o) {
  t.add("--supersampling", o.render.supersampling, "s: s×s rays per pixel");
  t.add("--max-distance", o.render.max_distance_m, "Rays end here; sky beyond (m)");
  t.add("--haze-distance", o.render.haze_distance_m, "Aerial perspective distance (m)");
  add_origin_option(t, o.origin);
  t.add("--format", o.image_format, "Image format: jpg or png");
  t.add("--jpeg-quality", o.jpeg_quality, "JPEG quality");
  t.add("--photos", o.photo_dir, "Folder of photographs; crops appear on posters (e.g. ../shared/data)");
  t.add("--photo-fraction", o.render.photo_fraction, "Share of posters showing a photo crop");
  t.add("--photo-crops", o.photo_crops.count, "Number of photo crops");
  t.add("--jobs", o.jobs, "Render threads (the output does not depend on it)");
  t.flag("--resume", o.resume, "Complete an interrupted run: keep images already written");
}

}  // namespace

void add_layout_option(OptionTable& t, CityLayoutOptions& layout, std::string help) {
  t.choice("--layout", layout.layout,
           {{"line", RoadLayout::kLine}, {"grid", RoadLayout::kGrid}, {"random", RoadLayout::kRandom}},
           std::move(help));
}

void add_elevations_option(OptionTable& t, ViewSetOptions& views, std::string help) {
  t.text(
      "--elevations", number_list_text(views.elevations_deg),
      [&views](const std::string& text) { views.elevations_deg = parse_number_list(text, "--elevations"); },
      std::move(help));
}

void add_size_option(OptionTable& t, ViewSetOptions& views, std::string help) {
  t.text(
      "--size", size_text(views.width, views.height),
      [&views](const std::string& text) { std::tie(views.width, views.height) = parse_image_size(text, "--size"); },
      std::move(help));
}

void add_options(OptionTable& t, CityOptions& o) {
  add_layout_options(t, o.layout);
  add_view_options(t, o.views);
  add_query_options(t, o.queries);
  add_output_options(t, o);
}

Eigen::Vector3d parse_marker_position(const std::string& text, const std::string& option) {
  const std::vector<double> v = parse_number_list(text, option);
  if (v.size() != 3) throw_error(ErrorCode::kInvalidArgument, option, ": expected x,y,z, got '", text, "'");
  return {v[0], v[1], v[2]};
}

}  // namespace visloc::synth
