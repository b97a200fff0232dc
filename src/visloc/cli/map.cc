// visloc map import --colmap MODEL --database DB --out MAP [--holdout LIST]
// visloc map import --bundler bundle.out --list LIST [--keys DIR] [--images DIR] --out MAP [--holdout LIST]
// visloc map info MAP [--json]
// visloc map fit-blend MAP [--views N] [--weight-steps N] [--store] [--json]
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/map/map.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map_building/hash_blend_fit.h"
#include "visloc/util/error.h"

namespace visloc::cli {
namespace {

void add_import(CLI::App& map) {
  struct Args {
    MapImportSources sources;
    ColmapImportOptions options;
    std::string out;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = map.add_subcommand(
      "import",
      "Import a reconstruction as a one-segment map with compressed descriptors:\n"
      "  COLMAP:  --colmap MODEL_DIR --database DB --out MAP\n"
      "  Bundler: --bundler bundle.out --list list.txt [--keys DIR] [--images DIR] --out MAP\n"
      "           (Dubrovnik, Rome, Vienna, Aachen: bundle.out + image list + Lowe SIFT .key/.key.gz files;\n"
      "           camera i of bundle.out is line i of the list, a view's key index is a row of that image's\n"
      "           key file; Bundler's -z-looking, y-up cameras become COLMAP's via diag(1,-1,-1); cameras\n"
      "           with f = 0 are dropped; principal point = image centre, from --images or the key files;\n"
      "           key descriptors are converted to RootSIFT like our SIFT's, see docs/formats.md)");
  OptionTable t;
  add_options(t, args->sources);
  t.add("--out", args->out, "Output map directory");
  add_options(t, args->options);
  t.flag("--json", args->json, "Print the import statistics as JSON");
  bind_options(cmd, t);
  cmd->callback([args] {
    args->options.pq.seed = args->options.itq.seed;  // --seed seeds both
    const MapImportResult r = import_map(args->sources, args->out, args->options);
    nlohmann::json j = to_json(r);
    j["map"] = args->out;
    std::cout << (args->json ? j.dump(2) + "\n" : import_summary(r, args->sources, args->out));
  });
}

void add_info(CLI::App& map) {
  auto map_dir = std::make_shared<std::string>();
  auto json = std::make_shared<bool>(false);
  CLI::App* cmd =
      map.add_subcommand("info", "Print the segments, points, images and measured bytes per point of a map");
  OptionTable t;
  t.add("map", *map_dir, "Map directory").require();
  t.flag("--json", *json, "Print JSON");
  bind_options(cmd, t);
  cmd->callback([map_dir, json] {
    const MapInfo info = map_info(*map_dir);
    std::cout << (*json ? info.to_json().dump(2) + "\n" : info.summary(*map_dir));
  });
}

void add_fit_blend(CLI::App& map) {
  struct Args {
    std::string map_dir;
    MapBlendFitOptions options;
    bool store = false;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = map.add_subcommand(
      "fit-blend",
      "Fit the weight of the hash codes' distance in the cascade search's ranking (localize/eval --hash-blend) on "
      "the map's own data: held-out views of its points (one observation each, read again from the COLMAP model "
      "and database the map was imported from, or a built map's MAP/work, searched with their point re-encoded "
      "without them) and its points as distractors; prints the weight with the most net right 1-1 matches, and "
      "with --store writes it into the map's manifest, where localize and eval take it by default (--hash-blend "
      "map). Needs a map from map import --colmap or map build that kept its descriptors (and, built, its work "
      "folder)");
  OptionTable t;
  t.add("map", args->map_dir, "Map directory").require();
  t.add("--views", args->options.views,
        "Points sampled over the map (shared among its segments by their points): each a distractor, and a "
        "held-out view when it has 2 views or more")
      .range(2, 100000);
  t.add("--weight-steps", args->options.fit.weight_steps, "The weights tried: k / N for k = 0..N").range(1, 1000);
  t.flag("--store", args->store,
         "Write the weight into the map's manifest, with the checksums of the segments it was fitted on (a "
         "rebuilt segment makes it unused until fitted again); refused while a build of the map is running");
  t.flag("--json", args->json, "Print JSON");
  bind_options(cmd, t);
  cmd->callback([args] {
    const MapBlendFit fit = fit_map_hash_blend(args->map_dir, args->options);
    if (args->store) store_map_hash_blend(args->map_dir, fit);
    if (args->json) {
      nlohmann::json j = fit.to_json();
      j["stored"] = args->store;
      std::cout << j.dump(2) << "\n";
    } else {
      std::cout << fit.summary(args->map_dir)
                << (args->store ? "stored in the map's manifest: localize and eval use it by default\n"
                                : "not stored: add --store, or search with --hash-blend " +
                                      nlohmann::json(fit.fit.weight).dump() + "\n");
    }
  });
}

}  // namespace

void add_map_command(CLI::App& app) {
  CLI::App* map = app.add_subcommand("map", "Build, import and inspect maps");
  map->require_subcommand(1);
  add_map_build_commands(*map);  // build, update (map_build.cc)
  add_import(*map);
  add_info(*map);
  add_fit_blend(*map);
}

}  // namespace visloc::cli
