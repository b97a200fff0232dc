#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_map_command(CLI::App& app) {
  CLI::App* map = app.add_subcommand("map", "Build, import and inspect maps");
  map->require_subcommand(1);
  add_not_implemented(*map, "build", "Build a map from geotagged images with COLMAP", "issue #6");
  add_not_implemented(*map, "import", "Import a COLMAP or Bundler model as a map", "issue #3");
  add_not_implemented(*map, "info", "Print the segments, points and bytes per point of a map", "issue #3");
  add_not_implemented(*map, "update", "Rebuild one segment of a map", "issue #6");
}

}  // namespace visloc::cli
