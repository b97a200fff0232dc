// visloc bench end-to-end: the whole localizer on a query set, once per
// paper setting (1, 2, 3, 3+) on the same features in the same run, so that
// the settings' times are comparable ratios (setting 1 = the baseline: full
// cascade search + classical RANSAC). Feature extraction is done once per
// query and reported apart; "ms/query" excludes it.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/eval/evaluation.h"
#include "visloc/eval/protocols.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

void add_bench_end_to_end(CLI::App& bench) {
  struct Args {
    std::string map, queries, images, truth, intrinsics, query_features = "images", json, setting = "3+";
    std::vector<std::string> settings{"1", "2", "3", "3+"};
    int repeat = 1;
    LocalizerOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand("end-to-end",
                                       "Whole localizer on a query set, once per paper setting on "
                                       "the same features (setting 1 is the baseline)");
  cmd->add_option("--map", args->map, "Map directory")->required();
  cmd->add_option("--queries", args->queries, "Query image names, one per line")->required();
  cmd->add_option("--images", args->images, "Directory of the query images (with --query-features images)");
  cmd->add_option("--truth", args->truth, "Reference poses 'name qw qx qy qz tx ty tz' (the map's frame)")->required();
  cmd->add_option("--intrinsics", args->intrinsics, "Per-image intrinsics 'name MODEL w h params...'");
  cmd->add_option("--query-features", args->query_features, "'images' (our SIFT) or 'database' (the model's own)")
      ->check(CLI::IsMember({"images", "database"}))
      ->capture_default_str();
  cmd->add_option("--settings", args->settings, "Settings to run, in order")->delimiter(',')->capture_default_str();
  cmd->add_option("--repeat", args->repeat, "Localize each query this many times per setting (times: median)")
      ->capture_default_str();
  cmd->add_option("--json", args->json, "Also write the table as JSON to this file");
  add_localizer_options(cmd, args->options, args->setting);
  cmd->callback([args] {
    if (args->repeat < 1) throw_error(ErrorCode::kInvalidArgument, "--repeat must be >= 1");
    if (args->settings.empty()) throw_error(ErrorCode::kInvalidArgument, "--settings lists no setting");
    const QueryFeatureSource source = parse_query_feature_source(args->query_features);
    if (source == QueryFeatureSource::kImages && args->images.empty())
      throw_error(ErrorCode::kInvalidArgument, "bench end-to-end: --images is needed with --query-features images");
    const auto names = read_name_list(args->queries);
    if (names.empty()) throw_error(ErrorCode::kInvalidArgument, args->queries, ": no query names");
    std::map<std::string, QueryTruth> truth;
    for (const auto& p : read_pose_list(args->truth)) truth[p.name].cam_from_world = p.cam_from_world;
    std::map<std::string, PinholeCamera> cameras;
    if (!args->intrinsics.empty())
      for (auto& c : read_intrinsics_list(args->intrinsics)) cameras[c.name] = c.camera;
    std::unique_ptr<SourceFeatureStore> store;
    if (source == QueryFeatureSource::kDatabase) store = std::make_unique<SourceFeatureStore>(args->map, args->images);
    const bool tty = ::isatty(STDERR_FILENO);
    std::vector<PreparedQuery> queries;
    std::vector<double> feature_ms;
    for (const auto& n : names) {
      if (!truth.count(n)) throw_error(ErrorCode::kNotFound, args->truth, ": no reference for '", n, "'");
      std::optional<PinholeCamera> cam;
      if (auto it = cameras.find(n); it != cameras.end()) cam = it->second;
      queries.push_back(
          prepare_query(n, source, args->images, args->options.sift, store.get(), cam, args->options.use_exif_focal));
      feature_ms.push_back(queries.back().features_ms);
      if (tty) std::cerr << "\rbench end-to-end: features " << queries.size() << "/" << names.size() << std::flush;
    }
    if (tty) std::cerr << "\n";

    nlohmann::json rows = nlohmann::json::array();
    double baseline_ms = NAN;
    std::ostringstream table;
    table << "| setting | registered | median pos. error (m) | median rot. "
             "error (°) | ms/query (median, excl. "
             "features) | matching ms | RANSAC ms | speed-up vs setting "
          << args->settings.front() << " |\n|---|---|---|---|---|---|---|---|\n";
    for (const std::string& setting : args->settings) {
      LocalizerOptions o = args->options;
      o.setting = parse_paper_setting(setting);
      Localizer localizer(args->map, o);
      std::vector<LocalizationResult> results;
      std::vector<double> ms, matching, ransac;
      for (const auto& q : queries) {
        std::vector<double> runs;
        LocalizationResult r;
        for (int k = 0; k < args->repeat; ++k) {
          r = localize_prepared(localizer, q);
          runs.push_back(r.times.total - r.times.features);
        }
        ms.push_back(median(runs));
        matching.push_back(r.times.matching);
        ransac.push_back(r.times.ransac);
        results.push_back(std::move(r));
      }
      const EvaluationReport rep = evaluate(results, truth, {}, o);
      const nlohmann::json j = rep.to_json(results, {});
      const double m = median(ms);
      if (std::isnan(baseline_ms)) baseline_ms = m;
      auto med = [&](const char* key) { return j[key].is_null() ? NAN : j[key]["median"].get<double>(); };
      rows.push_back({{"setting", setting},
                      {"queries", rep.queries},
                      {"registered", rep.registered},
                      {"median_position_error_m", med("position_error_m")},
                      {"median_rotation_error_deg", med("rotation_error_deg")},
                      {"median_ms_excluding_features", m},
                      {"median_ms_matching", median(matching)},
                      {"median_ms_ransac", median(ransac)},
                      {"speedup_vs_first", baseline_ms / m}});
      table << std::setprecision(4) << "| " << setting << " | " << rep.registered << "/" << rep.queries << " | "
            << med("position_error_m") << " | " << med("rotation_error_deg") << " | " << m << " | " << median(matching)
            << " | " << median(ransac) << " | " << std::setprecision(3) << baseline_ms / m << "× |\n";
    }
    table << "\nFeatures (once per query, not in ms/query): median " << std::setprecision(4) << median(feature_ms)
          << " ms (" << args->query_features << "); peak memory " << peak_memory_bytes() / (1 << 20) << " MiB.\n";
    std::cout << table.str();
    if (!args->json.empty())
      write_file_atomic(args->json, nlohmann::json({{"map", fs::absolute(args->map).string()},
                                                    {"query_features", args->query_features},
                                                    {"median_feature_ms", median(feature_ms)},
                                                    {"rows", rows}})
                                        .dump(2));
  });
}

}  // namespace visloc::cli
