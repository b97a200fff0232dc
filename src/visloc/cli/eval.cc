// visloc eval: localize a query list against a map and report against the
// truth; or, for an imported COLMAP model, leave-one-out over its images;
// optionally with COLMAP's image_registrator on the same queries.
#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/eval/evaluation_run.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

void add_eval_command(CLI::App& app) {
  struct Args {
    std::string map, queries, images, truth, out, intrinsics, setting = "3+", query_features = "images", compare,
        negatives;
    bool leave_one_out = false;
    LocalizerOptions options;
    ColmapRunnerOptions colmap;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("eval",
                                     "Localize a query list against a map and write report.json, "
                                     "report.md and plots.\n"
                                     "With --leave-one-out (a map imported from a COLMAP model): "
                                     "every image of the model in turn is removed,\n"
                                     "the map rebuilt without it, and the image localized (truth: its "
                                     "pose in the model).\n"
                                     "With --compare colmap: COLMAP's image_registrator registers the "
                                     "same queries into the same model\n"
                                     "(report in OUT/colmap/, side by side in OUT/comparison.md).");
  cmd->add_option("--map", args->map, "Map directory")->required();
  cmd->add_option("--queries", args->queries,
                  "Query image names, one per line (required unless "
                  "--leave-one-out; with it: the images to leave out)");
  cmd->add_option("--images", args->images, "Directory of the query images (needed with --query-features images)");
  cmd->add_option("--truth", args->truth,
                  "Reference: poses 'name qw qx qy qz tx ty tz' (the map's frame), a COLMAP images.txt or "
                  "model directory, or a GPS CSV (.csv: positions); "
                  "not used with --leave-one-out (the model's poses are the truth)");
  cmd->add_option("--out", args->out, "Report directory")->required();
  cmd->add_option("--intrinsics", args->intrinsics, "Per-image intrinsics 'name MODEL w h params...'");
  cmd->add_option("--query-features", args->query_features,
                  "Query features: 'images' (our SIFT on the photos) or "
                  "'database' (the imported model's own "
                  "features and intrinsics)")
      ->check(CLI::IsMember({"images", "database"}))
      ->capture_default_str();
  cmd->add_flag("--leave-one-out", args->leave_one_out,
                "Localize every image of the imported COLMAP model against the "
                "model without it");
  cmd->add_option("--negatives", args->negatives,
                  "Images that must not register (other places, foreign photos): one path per line, relative "
                  "paths against --images; each registered one counts as a wrong pose");
  cmd->add_option("--compare", args->compare, "Also run a peer on the same queries: 'colmap' (image_registrator)")
      ->check(CLI::IsMember({"colmap"}));
  cmd->add_option("--colmap", args->colmap.binary, "COLMAP executable (with --compare colmap)")->capture_default_str();
  add_localizer_options(cmd, args->options, args->setting);
  cmd->callback([args] {
    EvaluationRunOptions o;
    o.localizer = args->options;
    o.localizer.setting = parse_paper_setting(args->setting);
    o.query_features = parse_query_feature_source(args->query_features);
    o.map = args->map;
    o.out = args->out;
    o.images_dir = args->images;
    o.truth = args->truth;
    o.leave_one_out = args->leave_one_out;
    o.compare_colmap = args->compare == "colmap";
    o.colmap = args->colmap;
    if (o.query_features == QueryFeatureSource::kImages && args->images.empty())
      throw_error(ErrorCode::kInvalidArgument, "eval: --images is needed with --query-features images");
    if (!o.leave_one_out && (args->queries.empty() || args->truth.empty()))
      throw_error(ErrorCode::kInvalidArgument, "eval: --queries and --truth are needed (or --leave-one-out)");
    if (!args->queries.empty()) {
      o.queries = read_name_list(args->queries);
      if (o.queries.empty()) throw_error(ErrorCode::kInvalidArgument, args->queries, ": no query names");
    }
    if (!args->intrinsics.empty())
      for (auto& c : read_intrinsics_list(args->intrinsics)) o.intrinsics[c.name] = c.camera;
    if (!args->negatives.empty()) {
      o.negatives = read_name_list(args->negatives);
      if (o.negatives.empty()) throw_error(ErrorCode::kInvalidArgument, args->negatives, ": no image paths");
      o.negatives_source = args->negatives;
    }
    const bool tty = ::isatty(STDERR_FILENO);
    o.progress = [tty](size_t done, size_t total, const std::string& what) {
      if (what == "colmap") {
        std::cerr << "eval: registering " << total << " queries with COLMAP's image_registrator\n";
        return;
      }
      const std::string label = what == "negatives" ? "eval: negatives " : "eval: ";
      if (tty)
        std::cerr << "\r" << label << done << "/" << total << (done == total ? "\n" : "") << std::flush;
      else if (done == total || done % 10 == 0)
        std::cerr << label << done << "/" << total << "\n";
    };
    const EvaluationRunResult r = run_evaluation(o);
    std::cout << r.report_markdown;
    if (r.colmap_report) std::cout << "\n" << r.comparison_markdown;
  });
}

}  // namespace visloc::cli
