// The city benchmark (`visloc bench city`, issue #13): a synthetic city is
// rendered whole, its map is built from all streets but a few, and three
// kinds of query are localized against it:
//   positives  query views near mapped streets (other cameras than the map's);
//   negatives  query views on the streets left out of the map;
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
#include <string>

#include <nlohmann/json.hpp>

#include "visloc/map_building/map_builder.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/synth/city_writer.h"

namespace visloc {

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

struct CityBenchmarkProgress {
  std::string stage;  // "render", "map", "localize"
  size_t done = 0, total = 0;
};

// Runs (or resumes) the benchmark in out_dir and writes report.json and
// report.md there; returns the report.
nlohmann::json run_city_benchmark(const std::filesystem::path& out_dir, const CityBenchmarkOptions& options,
                                  const std::function<void(const CityBenchmarkProgress&)>& progress = {},
                                  const std::function<void(const MapBuildProgress&)>& map_progress = {});

}  // namespace visloc
