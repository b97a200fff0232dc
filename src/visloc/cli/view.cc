// visloc view MAP [--report DIR] --out FILE.html [--max-points N] [--frame auto|enu|segment] [--title T] [--json]
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/viewer/viewer.h"

namespace visloc::cli {

void add_view_command(CLI::App& app) {
  struct Args {
    std::filesystem::path map, report, out;
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
  OptionTable t;
  t.add("map", args->map, "Map directory").require();
  t.add("--report", args->report, "Evaluation report folder (report.json) to draw over the map");
  t.add("--out", args->out, "Output HTML file").require();
  add_options(t, args->options);
  t.flag("--json", args->json, "Print what was written as JSON");
  bind_options(cmd, t);
  cmd->callback([args] {
    const ViewerSummary s = write_viewer(args->map, args->report, args->out, args->options);
    if (args->json)
      std::cout << s.to_json().dump() << "\n";
    else
      std::cout << s.to_text(args->out, !args->report.empty()) << "\n";
  });
}

}  // namespace visloc::cli
