#include "bench/end_to_end_benchmark.h"

#include <cmath>
#include <iomanip>
#include <map>
#include <memory>
#include <optional>
#include <sstream>

#include "visloc/eval/evaluation.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/util/error.h"
#include "visloc/util/statistics.h"

namespace visloc {
namespace fs = std::filesystem;

void EndToEndBenchmarkOptions::validate() const {
  auto bad = [](const char* field, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "bench end-to-end options: ", field, " ", rule);
  };
  if (map.empty()) bad("map", "is needed");
  if (queries.empty()) bad("queries", "is needed");
  if (truth.empty()) bad("truth", "is needed");
  if (repeat < 1) bad("repeat", "must be >= 1");
  if (settings.empty()) bad("settings", "lists no setting");
  if (query_features == QueryFeatureSource::kImages && images_dir.empty())
    bad("images_dir", "is needed with QueryFeatureSource::kImages");
}

namespace {

// The queries' features and cameras, each once; `truth` gets the reference poses.
std::vector<PreparedQuery> prepare_queries(const EndToEndBenchmarkOptions& o, std::map<std::string, QueryTruth>* truth,
                                           const std::function<void(size_t, size_t)>& progress) {
  const auto names = read_name_list(o.queries);
  if (names.empty()) throw_error(ErrorCode::kInvalidArgument, o.queries.string(), ": no query names");
  for (const auto& p : read_pose_list(o.truth)) (*truth)[p.name].cam_from_world = p.cam_from_world;
  CamerasByName cameras;
  if (!o.intrinsics.empty()) cameras = read_intrinsics_by_name(o.intrinsics);
  std::unique_ptr<SourceFeatureStore> store;
  if (o.query_features == QueryFeatureSource::kDatabase)
    store = std::make_unique<SourceFeatureStore>(o.map, o.images_dir);
  std::vector<PreparedQuery> queries;
  for (const auto& n : names) {
    if (!truth->count(n)) throw_error(ErrorCode::kNotFound, o.truth.string(), ": no reference for '", n, "'");
    std::optional<PinholeCamera> cam;
    if (const PinholeCamera* listed = find_listed_camera(cameras, n)) cam = *listed;
    queries.push_back(prepare_query(n, o.query_features, o.images_dir, o.localizer.sift, store.get(), cam,
                                    o.localizer.use_exif_focal));
    if (progress) progress(queries.size(), names.size());
  }
  return queries;
}

struct SettingFigures {
  size_t queries = 0, registered = 0;
  double position_error_m = NAN, rotation_error_deg = NAN;  // medians
  double ms = 0, matching_ms = 0, ransac_ms = 0;            // medians per query, features excluded
};

SettingFigures run_setting(const EndToEndBenchmarkOptions& o, const std::string& setting,
                           const std::vector<PreparedQuery>& queries, const std::map<std::string, QueryTruth>& truth) {
  LocalizerOptions lo = o.localizer;
  lo.setting = parse_paper_setting(setting);
  Localizer localizer(o.map, lo);
  std::vector<LocalizationResult> results;
  std::vector<double> ms, matching, ransac;
  for (const auto& q : queries) {
    std::vector<double> runs;
    LocalizationResult r;
    for (int k = 0; k < o.repeat; ++k) {
      r = localize_prepared(localizer, q);
      runs.push_back(r.times.total - r.times.features);
    }
    ms.push_back(median(runs));
    matching.push_back(r.times.matching);
    ransac.push_back(r.times.ransac);
    results.push_back(std::move(r));
  }
  const EvaluationReport rep = evaluate(results, truth, {}, lo);
  const nlohmann::json j = rep.to_json(results, {});
  auto med = [&](const char* key) { return j[key].is_null() ? NAN : j[key]["median"].get<double>(); };
  return {rep.queries, rep.registered, med("position_error_m"), med("rotation_error_deg"),
          median(ms),  median(matching), median(ransac)};
}

}  // namespace

EndToEndBenchmarkResult run_end_to_end_benchmark(const EndToEndBenchmarkOptions& options,
                                                 const std::function<void(size_t, size_t)>& progress) {
  options.validate();
  std::map<std::string, QueryTruth> truth;
  const std::vector<PreparedQuery> queries = prepare_queries(options, &truth, progress);
  std::vector<double> feature_ms;
  for (const auto& q : queries) feature_ms.push_back(q.features_ms);

  nlohmann::json rows = nlohmann::json::array();
  double baseline_ms = NAN;
  std::ostringstream table;
  table << "| setting | registered | median pos. error (m) | median rot. "
           "error (°) | ms/query (median, excl. "
           "features) | matching ms | RANSAC ms | speed-up vs setting "
        << options.settings.front() << " |\n|---|---|---|---|---|---|---|---|\n";
  for (const std::string& setting : options.settings) {
    const SettingFigures f = run_setting(options, setting, queries, truth);
    if (std::isnan(baseline_ms)) baseline_ms = f.ms;
    rows.push_back({{"setting", setting},
                    {"queries", f.queries},
                    {"registered", f.registered},
                    {"median_position_error_m", f.position_error_m},
                    {"median_rotation_error_deg", f.rotation_error_deg},
                    {"median_ms_excluding_features", f.ms},
                    {"median_ms_matching", f.matching_ms},
                    {"median_ms_ransac", f.ransac_ms},
                    {"speedup_vs_first", baseline_ms / f.ms}});
    table << std::setprecision(4) << "| " << setting << " | " << f.registered << "/" << f.queries << " | "
          << f.position_error_m << " | " << f.rotation_error_deg << " | " << f.ms << " | " << f.matching_ms << " | "
          << f.ransac_ms << " | " << std::setprecision(3) << baseline_ms / f.ms << "× |\n";
  }
  const std::string source = to_string(options.query_features);
  table << "\nFeatures (once per query, not in ms/query): median " << std::setprecision(4) << median(feature_ms)
        << " ms (" << source << "); peak memory " << peak_memory_bytes() / (1 << 20) << " MiB.\n";
  EndToEndBenchmarkResult out;
  out.table = table.str();
  out.report = {{"map", fs::absolute(options.map).string()},
                {"query_features", source},
                {"median_feature_ms", median(feature_ms)},
                {"rows", rows}};
  return out;
}

std::function<void(size_t, size_t)> end_to_end_progress_printer(std::ostream& out) {
  return [&out](size_t done, size_t total) {
    out << "\rbench end-to-end: features " << done << "/" << total << std::flush;
    if (done == total) out << "\n";
  };
}

}  // namespace visloc
