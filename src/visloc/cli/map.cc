// visloc map import --colmap MODEL --database DB --out MAP [--holdout LIST]
// visloc map import --bundler bundle.out --list LIST [--keys DIR] [--images DIR] --out MAP [--holdout LIST]
// visloc map info MAP [--json]
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "visloc/cli/commands.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map/map.h"
#include "visloc/util/error.h"

namespace visloc::cli {
namespace {

void add_import(CLI::App& map) {
  struct Args {
    std::string colmap, database, out, holdout, images, bundler, list, keys;
    std::string pq_database, pq_images;
    ColmapImportOptions options;
    bool raw_sift = false;
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
  cmd->add_option("--colmap", args->colmap, "COLMAP model directory (cameras/images/points3D, .bin or .txt)");
  cmd->add_option("--database", args->database, "COLMAP database.db holding the model's keypoints and descriptors");
  cmd->add_option("--bundler", args->bundler, "Bundler v0.3 bundle.out (plain or gzip)");
  cmd->add_option("--list", args->list, "Bundler image list (\"name [0 focal]\" per camera of bundle.out)");
  cmd->add_option("--keys", args->keys,
                  "Folder of the Lowe key files (NAME.key or NAME.key.gz, NAME the listed image name or its\n"
                  "file name, extension replaced); default: next to the listed images, relative to the list");
  cmd->add_option("--images", args->images,
                  "Bundler: image folder; the principal point is the image centre read from each image's size\n"
                  "(default: derived from the key files and the views' centred coordinates; unused by --colmap)");
  cmd->add_flag("--raw-sift", args->raw_sift,
                "Bundler: keep Lowe's L2 SIFT integers instead of converting them to RootSIFT\n"
                "(our queries and COLMAP's features are RootSIFT: keep the default unless the queries are raw too)");
  cmd->add_option("--out", args->out, "Output map directory");
  cmd->add_option("--holdout", args->holdout,
                  "File listing images to remove from the model (Dubrovnik protocol) and keep as queries\n"
                  "(Bundler: names as written in the list)");
  cmd->add_option("--pq-train-database", args->pq_database,
                  "Train the PQ codebook on the image descriptors of this COLMAP database (an independent set)\n"
                  "instead of a sample of the map's own point descriptors");
  cmd->add_option("--pq-train-images", args->pq_images, "File listing the images of --pq-train-database to use");
  cmd->add_option("--itq-iterations", args->options.itq.iterations, "ITQ iterations")->capture_default_str();
  cmd->add_option_function<std::string>(
         "--hash-rotation",
         [args](const std::string& v) { args->options.hash_rotation = parse_hash_rotation_scope(v); },
         "ITQ hash rotation stored in the segment ('segment') or in MAP/hash_rotation.vlitq ('map') [segment]")
      ->check(CLI::IsMember({"segment", "map"}));
  cmd->add_option("--seed", args->options.itq.seed, "Seed of ITQ's initial rotation and of PQ training")
      ->capture_default_str();
  cmd->add_flag("--no-descriptors", [args](int64_t) { args->options.keep_descriptors = false; },
                "Do not keep the mean descriptors (descriptors/*.vldesc; needed by the raw-SIFT baselines)");
  cmd->add_flag("--overwrite", args->options.overwrite, "Replace an existing map in --out");
  cmd->add_flag("--json", args->json, "Print the import statistics as JSON");
  cmd->callback([args] {
    MapImportSources in;
    in.colmap_model = args->colmap;
    in.database = args->database;
    in.bundle_file = args->bundler;
    in.bundler_list = args->list;
    in.bundler.keys_dir = args->keys;
    in.bundler.images_dir = args->images;
    in.bundler.root_sift = !args->raw_sift;
    in.holdout_list = args->holdout;
    in.pq_training_list = args->pq_images;
    ColmapImportOptions o = args->options;
    o.pq.seed = o.itq.seed;  // --seed seeds both
    o.pq_training_database = args->pq_database;
    const MapImportResult r = import_map(in, args->out, o);
    if (args->json) {
      nlohmann::json j = to_json(r);
      j["map"] = args->out;
      std::cout << j.dump(2) << "\n";
      return;
    }
    std::cout << import_summary(r, in, args->out);
  });
}

void add_info(CLI::App& map) {
  struct Args {
    std::string map;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = map.add_subcommand("info", "Print the segments, points, images and measured bytes per point of a map");
  cmd->add_option("map", args->map, "Map directory")->required();
  cmd->add_flag("--json", args->json, "Print JSON");
  cmd->callback([args] {
    MapInfo info = map_info(args->map);
    if (args->json) {
      std::cout << info.to_json().dump(2) << "\n";
      return;
    }
    std::cout << "map " << args->map << ": " << info.segments.size() << " segment(s), " << info.total_points
              << " points\n"
              << std::setw(8) << "segment" << std::setw(10) << "points" << std::setw(8) << "images" << std::setw(12)
              << "file bytes" << std::setw(14) << "B/pt (points)" << std::setw(12) << "B/pt (file)" << "\n";
    for (const auto& s : info.segments)
      std::cout << std::setw(8) << s.id << std::setw(10) << s.points << std::setw(8) << s.images << std::setw(12)
                << s.bytes.file << std::fixed << std::setprecision(1) << std::setw(14)
                << s.bytes.per_point_bytes_per_point(s.points) << std::setw(12)
                << s.bytes.file_bytes_per_point(s.points) << "\n";
    const double n = info.total_points ? double(info.total_points) : 1.0;
    std::cout << std::fixed << std::setprecision(1) << "total: " << double(info.total_per_point_bytes) / n
              << " bytes/point in per-point sections (xyz 12 + hash 16 + PQ 16); " << double(info.total_bytes) / n
              << " bytes/point in all files: segments (images, metadata"
              << (info.hash_rotation_bytes ? "" : ", a hash rotation each") << "), the shared PQ codebook ("
              << info.codebook_bytes << " bytes)"
              << (info.hash_rotation_bytes ? " and the shared hash rotation (" + std::to_string(info.hash_rotation_bytes) + " bytes)"
                                           : std::string())
              << "\n";
  });
}

}  // namespace

void add_map_command(CLI::App& app) {
  CLI::App* map = app.add_subcommand("map", "Build, import and inspect maps");
  map->require_subcommand(1);
  add_map_build_commands(*map);  // build, update (map_build.cc)
  add_import(*map);
  add_info(*map);
}

}  // namespace visloc::cli
