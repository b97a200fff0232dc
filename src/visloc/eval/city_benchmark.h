// The city benchmark (`visloc bench city`, issue #13): a synthetic city is
// rendered whole, its map is built from all streets but a few, and three
// kinds of query are localized against it:
//   positives  query views near mapped streets (other cameras than the map's);
//   negatives  query views far from every mapped placemark: on the streets left
//              out of the map, or past a mapped street's end
//              (leave_out_road_end_m); the report calls them
//              negatives_unmapped_streets;
//   foreign    photos of other places (../shared/data: KITTI, Lund, Strecha).
// A wrong pose is a positive or negative registered more than
// wrong_position_m or wrong_rotation_deg from its truth, or any registered
// foreign photo; the report counts wrong poses apart from misses. Retrieval
// is scored on the positives: is a true segment (one that shows the query
// view nearly as many points as the best one) among the candidates, at which
// rank, and how the votes are spread.
// Every stage resumes: the city render and the map build keep what is done.
#pragma once

#include <filesystem>
#include <functional>
#include <iosfwd>
#include <string>

#include <nlohmann/json.hpp>

#include "visloc/map_building/map_builder.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/synth/city_writer.h"

namespace visloc {

class OptionTable;

// kAll runs everything in this process. kPrepare renders and builds the map
// and stops; kLocalize (after kPrepare, same options) only localizes and
// reports, so that its process's peak memory is the localizer's.
enum class CityBenchmarkStage { kAll, kPrepare, kLocalize };

struct CityBenchmarkOptions {
  CityBenchmarkStage stage = CityBenchmarkStage::kAll;
  synth::CityOptions city;              // the whole city; city.queries.count views are rendered
  // The last roads of the layout are not mapped. On the default 2×2 grid the
  // last two are parallel streets 90 m apart that cross mapped ones every 90 m.
  int leave_out_roads = 2;
  // On every mapped road, the placemarks within this many metres of its last
  // placemark (the far end, by arc length) are left out of the map too, that
  // one included. Queries there stand past the end
  // of a mapped street, some looking along it into the map (the KITTI hard
  // split's case: a map of frames 0-99, queries from frames 100-159).
  double leave_out_road_end_m = 0;
  double positive_max_distance_m = 12;  // a positive is this close to a mapped placemark (in plan)...
  double negative_min_distance_m = 30;  // ...a negative this far from every one (between: neither)
  // A query near the map is a positive only when it sees the map: some
  // segment holds at least this many points in its view (in front, inside the
  // image, within visibility_range_m, not hidden by a building). Otherwise it
  // is "near_unseen" (e.g. facing an unmapped street) and not scored.
  double positive_min_visible_points = 200;
  double visibility_range_m = 60;
  // A positive's true segments: those showing it at least this share of the
  // points shown by the segment that shows it most.
  double true_segment_share = 0.5;
  size_t foreign_photos = 60;           // at most this many, spread over the shared data sets
  std::filesystem::path shared_data;    // empty: no foreign photos
  MapBuildOptions map;                  // images, GPS and poses are set by the benchmark
  LocalizerOptions localizer;
  double wrong_position_m = 5, wrong_rotation_deg = 10;
  void validate() const;
};

// `bench city`'s defaults where they differ from the struct's: a 2×2 grid layout, 8 headings at
// 10° elevation, 540 queries (about 350 positives and 60 negatives), and as many render threads and
// segments built at once as there are cores.
CityBenchmarkOptions default_city_benchmark_options();

// The options as command-line options (`bench city`): the city (--layout, --road-length,
// --grid-blocks-x/-y, --block-size, --random-roads, --building-designs, --building-design-share,
// --headings, --elevations, --size, --queries),
// the split (--leave-out-roads, --positive-distance, --negative-distance, --negatives,
// --shared-data), the run (--min-placemarks, --max-placemarks, --overlap, --jobs, --executor,
// --seed) and the localizer's (pipeline/localizer.h: --setting ... --cache-mib).
void add_options(OptionTable& table, CityBenchmarkOptions& options);

// A given shared data directory that is absent means no foreign photos (said on `log`) rather
// than validate()'s error, so that the benchmark runs where ../shared/data is not installed.
void skip_absent_shared_data(CityBenchmarkOptions& options, std::ostream& log);

// With the Slurm executor, records in `map` a `map build` equivalent to the benchmark's map build
// in out_dir, which the Slurm tasks' `map build-segment` reads (record_build_for_tasks); with the
// local executor, nothing.
void record_slurm_city_build(const std::filesystem::path& out_dir, MapBuildOptions& map);

// Runs this very command again with "--stage localize" appended (its --stage takes the last
// value) in a fresh process that inherits stdout and stderr, so that the report's peak memory is
// the localizer's; says so on `log`. Returns the process's exit status (it printed its own
// error); throws Error(kInternal) when it cannot be started or dies from a signal.
int run_localize_stage_in_new_process(std::ostream& log);

struct CityBenchmarkProgress {
  std::string stage;  // "render", "map", "localize"
  size_t done = 0, total = 0;
};

// Runs (or resumes) the benchmark in out_dir and writes report.json and
// report.md there; returns the report.
nlohmann::json run_city_benchmark(const std::filesystem::path& out_dir, const CityBenchmarkOptions& options,
                                  const std::function<void(const CityBenchmarkProgress&)>& progress = {},
                                  const std::function<void(const MapBuildProgress&)>& map_progress = {});

// `bench city`'s progress lines on `out` ("bench city: render 120/700"): on a terminal one line
// redrawn in place; in a log each stage's first and last line and every 100th render or 20th of
// other stages; of the map build only its segments, in a log only once all are built.
class CityBenchmarkProgressPrinter {
 public:
  CityBenchmarkProgressPrinter(std::ostream& out, bool terminal) : out_(out), terminal_(terminal) {}
  void operator()(const CityBenchmarkProgress& progress);
  void operator()(const MapBuildProgress& progress);

 private:
  std::ostream& out_;
  bool terminal_;
  std::string last_stage_;  // of the last line written
};

}  // namespace visloc
