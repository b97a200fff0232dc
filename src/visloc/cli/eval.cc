// visloc eval: localize a query list against a map and report against the truth.
#include <unistd.h>

#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/eval/evaluation.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/map.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

void add_eval_command(CLI::App& app) {
  struct Args {
    std::string map, queries, images, truth, out, intrinsics, setting = "3+";
    LocalizerOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "eval", "Localize a query list against a map and write report.json, report.md and plots");
  cmd->add_option("--map", args->map, "Map directory")->required();
  cmd->add_option("--queries", args->queries, "Query image names, one per line")->required();
  cmd->add_option("--images", args->images, "Directory of the query images")->required();
  cmd->add_option("--truth", args->truth,
                  "Reference: poses 'name qw qx qy qz tx ty tz' (the map's frame) or a GPS CSV (.csv: positions)")
      ->required();
  cmd->add_option("--out", args->out, "Report directory")->required();
  cmd->add_option("--intrinsics", args->intrinsics, "Per-image intrinsics 'name MODEL w h params...'");
  cmd->add_option("--setting", args->setting, "The paper's ablation setting: 1, 2, 3 or 3+")
      ->check(CLI::IsMember({"1", "2", "3", "3+"}))
      ->capture_default_str();
  cmd->add_option("--max-segments", args->options.max_segments, "Candidate segments searched")->capture_default_str();
  add_sift_options(cmd, args->options.sift);
  cmd->callback([args] {
    args->options.setting = parse_paper_setting(args->setting);
    const auto names = read_name_list(args->queries);
    if (names.empty()) throw_error(ErrorCode::kInvalidArgument, args->queries, ": no query names");
    std::map<std::string, QueryTruth> truth;
    if (fs::path(args->truth).extension() == ".csv") {
      const MapManifest man = read_manifest(args->map);
      if (!man.enu_origin_lat_lon_alt)
        throw_error(ErrorCode::kInvalidArgument, args->map, ": the map has no ENU origin; GPS truth needs one");
      const auto& o = *man.enu_origin_lat_lon_alt;
      EnuFrame frame({o[0], o[1], o[2]});
      for (const auto& r : read_gps_csv(args->truth)) truth[r.image].center = frame.to_enu(r.position);
    } else {
      for (const auto& p : read_pose_list(args->truth)) truth[p.name].cam_from_world = p.cam_from_world;
    }
    std::map<std::string, PinholeCamera> cameras;
    if (!args->intrinsics.empty())
      for (auto& c : read_intrinsics_list(args->intrinsics)) cameras[c.name] = c.camera;
    Localizer localizer(args->map, args->options);
    std::vector<LocalizationResult> results;
    std::ostringstream lines;
    const bool tty = ::isatty(STDERR_FILENO);
    for (size_t i = 0; i < names.size(); ++i) {
      if (!truth.count(names[i])) throw_error(ErrorCode::kNotFound, args->truth, ": no reference for '", names[i], "'");
      std::optional<PinholeCamera> cam;
      if (auto it = cameras.find(names[i]); it != cameras.end()) cam = it->second;
      results.push_back(localizer.localize_file(fs::path(args->images) / names[i], cam));
      lines << to_json(results.back()).dump() << '\n';
      if (tty) std::cerr << "\reval: " << i + 1 << "/" << names.size() << std::flush;
    }
    if (tty) std::cerr << "\n";
    EvaluationReport rep = evaluate(results, truth);
    nlohmann::json context = {{"map", fs::absolute(args->map).string()}, {"setting", args->setting},
                              {"truth", fs::absolute(args->truth).string()}};
    write_report(args->out, rep, results, context);
    write_file_atomic(fs::path(args->out) / "results.jsonl", lines.str());
    std::cout << read_file(fs::path(args->out) / "report.md");
  });
}

}  // namespace visloc::cli
