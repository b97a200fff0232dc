// visloc view MAP [--report DIR] --out FILE.html [--max-points N] [--frame auto|enu|segment] [--title T] [--json]
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/viewer/viewer.h"

namespace visloc::cli {

void add_view_command(CLI::App& app) {
  struct Args {
    std::string map, report, out, frame = "auto";
    ViewerOptions options;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "view",
      "Write one HTML file that shows a map in 3D in any browser, offline (no server, no network):\n"
      "its points coloured by segment, its cameras as frusta, a ground grid in metres with a scale bar\n"
      "(and a north arrow when the map is georegistered), each segment's outline and id. With --report\n"
      "(a folder `visloc eval --out` wrote): each query's true and estimated camera joined by a line\n"
      "coloured by the error, wrong poses ringed, misses crossed; click a query for its inliers,\n"
      "confidence, errors and per-stage times. Drag to orbit, right-drag to pan, wheel to zoom, T: top view.");
  cmd->add_option("map", args->map, "Map directory")->required();
  cmd->add_option("--report", args->report, "Evaluation report folder (report.json) to draw over the map");
  cmd->add_option("--out", args->out, "Output HTML file")->required();
  cmd->add_option("--max-points", args->options.max_points,
                  "Map points drawn at most, spread over the segments by size")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--frame", args->frame,
                  "Frame: 'enu' (georegistered maps: east, north, up), 'segment' (the segments' own shared frame:\n"
                  "imported models, known-pose maps; up estimated from the cameras), 'auto' (the report's frame,\n"
                  "else enu when every segment is georegistered)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "enu", "segment"}));
  cmd->add_option("--title", args->options.title, "Page title [visloc: MAP]");
  cmd->add_flag("--json", args->json, "Print what was written as JSON");
  cmd->callback([args] {
    args->options.frame = parse_overview_frame(args->frame);
    const ViewerSummary s = write_viewer(args->map, args->report, args->out, args->options);
    if (args->json) {
      std::cout << s.to_json().dump() << "\n";
    } else {
      std::cout << "wrote " << args->out << ": " << s.points_drawn << " of " << s.points_in_map << " points, "
                << s.cameras << " cameras, " << s.segments << " segments";
      if (!args->report.empty()) std::cout << ", " << s.queries << " queries";
      std::cout << " (" << s.frame << " frame; " << s.file_bytes / 1024 << " KiB, three.js " << s.three_version
                << ")\n";
    }
  });
}

}  // namespace visloc::cli
