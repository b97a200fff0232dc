// The city benchmark's options as command-line options (util/option_table.h).
#include <algorithm>
#include <limits>
#include <thread>

#include "visloc/eval/city_benchmark.h"
#include "visloc/util/option_table.h"

namespace visloc {
namespace {

int number_of_cores() { return static_cast<int>(std::max(1u, std::thread::hardware_concurrency())); }

// The city: its streets, its views and its queries.
void add_city_options(OptionTable& t, synth::CityOptions& o) {
  synth::add_layout_option(t, o.layout, "Street network: line, grid or random");
  t.add("--road-length", o.layout.road_length_m, "line: street length; random: each road's (m)");
  t.add("--grid-blocks-x", o.layout.grid_blocks_x, "grid: blocks east-west");
  t.add("--grid-blocks-y", o.layout.grid_blocks_y, "grid: blocks north-south");
  t.add("--block-size", o.layout.block_size_m, "grid: distance between parallel streets (m)");
  t.add("--random-roads", o.layout.random_roads, "random: number of roads");
  t.add("--building-designs", o.layout.building_designs,
        "0: every building its own design; N: buildings copy one of N designs (identical facades repeated)");
  t.add("--building-design-share", o.layout.building_design_share,
        "With --building-designs: the share of buildings that copy a design (the others are their own)");
  t.add("--headings", o.views.headings, "Views around each placemark");
  synth::add_elevations_option(t, o.views, "View elevations in degrees, comma-separated");
  synth::add_size_option(t, o.views, "Map image size WIDTHxHEIGHT");
  t.add("--queries", o.queries.count, "Query views rendered (positives and negatives)");
}

// What is mapped, and which queries are positives and negatives.
void add_split_options(OptionTable& t, CityBenchmarkOptions& o) {
  t.add("--leave-out-roads", o.leave_out_roads, "The last roads of the layout are left out of the map");
  t.add("--leave-out-road-end", o.leave_out_road_end_m,
        "Metres at the far end of every mapped road (from its last placemark) left out of the map too: queries "
        "past a mapped street's end (0: none)");
  t.add("--positive-distance", o.positive_max_distance_m,
        "A query within this distance (m, in plan) of a mapped placemark is a positive");
  t.add("--negative-distance", o.negative_min_distance_m,
        "A query farther than this (m) from every mapped placemark is a negative");
  t.add("--negatives", o.foreign_photos, "Foreign photos from --shared-data (negatives)");
  t.add("--shared-data", o.shared_data, "Real photos for foreign negatives ('' for none)");
}

// The map build and the run.
void add_run_options(OptionTable& t, CityBenchmarkOptions& o) {
  t.add("--min-placemarks", o.map.plan.min_placemarks, "Map: placemarks per segment, at least");
  t.add("--max-placemarks", o.map.plan.max_placemarks, "Map: placemarks per segment, at most");
  t.add("--overlap", o.map.plan.overlap, "Map: placemarks shared by consecutive segments");
  t.text(
      "--jobs", "0",
      [&o](const std::string& text) {
        const long long jobs =
            parse_whole_number(text, "--jobs", std::numeric_limits<int>::min(), std::numeric_limits<int>::max());
        o.city.jobs = o.map.jobs = jobs > 0 ? static_cast<int>(jobs) : number_of_cores();
      },
      "Render threads and segments built at once (0: cores)");
  t.choice("--executor", o.map.executor, {{"local", BuildExecutor::kLocal}, {"slurm", BuildExecutor::kSlurm}},
           "Map build: local or slurm (see 'map build --help')");
  t.add("--seed", o.city.layout.seed, "Seed of the city");
  t.flag("--point-uncertainty", o.map.segment_file.point_uncertainty,
         "Map: store each point's triangulation uncertainty, so that the poses' sigma includes the map's error "
         "(see 'map build --help')");
  add_fit_blend_options(t, o.map.fit_hash_blend);
}

}  // namespace

CityBenchmarkOptions default_city_benchmark_options() {
  CityBenchmarkOptions o;
  o.city.layout.layout = synth::RoadLayout::kGrid;
  o.city.layout.grid_blocks_x = o.city.layout.grid_blocks_y = 2;
  o.city.views.headings = 8;
  o.city.views.elevations_deg = {10};
  o.city.queries.count = 540;  // about 350 positives and 60 negatives on the default grid
  o.city.jobs = o.map.jobs = number_of_cores();
  return o;
}

void add_options(OptionTable& t, CityBenchmarkOptions& o) {
  add_city_options(t, o.city);
  add_split_options(t, o);
  add_run_options(t, o);
  add_options(t, o.localizer);
}

}  // namespace visloc
