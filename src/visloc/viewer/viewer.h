#pragma once
// `visloc view`: one HTML file that shows a map, and optionally an evaluation
// report over it, in 3D in any browser, offline (no server, no network):
//  - the map's points (subsampled to max_points), coloured by segment;
//  - the map's cameras as frusta; a ground grid in metres, a scale bar and,
//    in an east-north-up frame, a north arrow;
//  - each segment's outline on the ground and its id;
//  - with a report (the folder `visloc eval` writes): each query's true and
//    estimated camera joined by a line coloured by the error, wrong poses and
//    misses marked; clicking a query shows its name, inliers, confidence,
//    errors and per-stage times.
// three.js is inlined (viewer_assets.h). The page exposes what it drew as
// window.visloc_scene {points, cameras, queries, segments, load_ms, errors}
// and in the hidden element #visloc-stats (for headless browsers).
#include <cstdint>
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "visloc/map/map_overview.h"

namespace visloc {

struct ViewerOptions {
  size_t max_points = 1'000'000;  // map points drawn, spread over the segments by size
  // The frame drawn (map_overview.h). kAuto follows the report's centres
  // ("segment" for pose truth, "enu" for GPS truth), else the map's.
  OverviewFrame frame = OverviewFrame::kAuto;
  std::string title;  // empty: "visloc: <map folder>"
  void validate() const;
};

class OptionTable;
// `visloc view`'s options: --max-points, --frame, --title.
void add_options(OptionTable& table, ViewerOptions& options);

struct ViewerSummary {
  size_t points_drawn = 0, points_in_map = 0, cameras = 0, segments = 0, queries = 0;
  size_t points_far = 0;  // kept but beyond the drawn box (stray points far from the map): not drawn
  uint64_t file_bytes = 0;
  std::string frame;  // "enu" or "segment"
  std::string three_version;
  nlohmann::json to_json() const;
  // "wrote OUT: N of M points, C cameras, S segments[, Q queries] (FRAME frame; K KiB, three.js V)".
  std::string to_text(const std::filesystem::path& out, bool with_report) const;
};

// Writes `out` (atomically). `report_dir` may be empty (no report). Throws
// Error: kInvalidArgument for bad options or a frame the map or report
// cannot give, kFormat naming the file for a bad report.json, kNotImplemented
// when the build has no three.js (the message says how to get it).
ViewerSummary write_viewer(const std::filesystem::path& map_dir, const std::filesystem::path& report_dir,
                           const std::filesystem::path& out, const ViewerOptions& options = {});

}  // namespace visloc
