#include "visloc/eval/evaluation_run.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <memory>
#include <ostream>
#include <sstream>

#include "visloc/eval/evaluation.h"
#include "visloc/geo/enu_frame.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/map.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace fs = std::filesystem;

std::vector<NamedPose> read_reference_poses(const fs::path& path) {
  if (fs::is_directory(path)) {
    std::vector<NamedPose> out;
    for (const auto& im : read_colmap_model(path).images) out.push_back({im.name, colmap_image_pose(im)});
    return out;
  }
  if (path.filename() == "images.txt") return read_colmap_images_txt_poses(path);
  return read_pose_list(path);
}

void EvaluationRunOptions::validate() const {
  localizer.validate();
  if (map.empty()) throw_error(ErrorCode::kInvalidArgument, "evaluation: map is needed");
  if (out.empty()) throw_error(ErrorCode::kInvalidArgument, "evaluation: out (the report folder) is needed");
  if (query_features == QueryFeatureSource::kImages && images_dir.empty())
    throw_error(ErrorCode::kInvalidArgument, "evaluation: images (the query folder) is needed with query features 'images'");
  if (!leave_one_out && (queries.empty() || truth.empty()))
    throw_error(ErrorCode::kInvalidArgument, "evaluation: queries and truth are needed (or leave_one_out)");
}

namespace {

void write_results(const fs::path& dir, const std::vector<LocalizationResult>& results,
                   const std::vector<LocalizationResult>& negative_results, const EvaluationReport& rep,
                   const nlohmann::json& context, const fs::path& map_dir) {
  write_report(dir, rep, results, context, map_dir);
  std::vector<NamedPose> poses;  // registered queries, visuallocalization.net format
  for (const auto& r : results)
    if (r.registered) poses.push_back({r.image, r.cam_from_segment});
  write_pose_list(dir / "poses.txt", poses);
  std::ostringstream lines;
  for (const auto& r : results) lines << to_json(r).dump() << '\n';
  for (const auto& r : negative_results) {
    nlohmann::json j = to_json(r);
    j["negative"] = true;
    lines << j.dump() << '\n';
  }
  write_file_atomic(dir / "results.jsonl", lines.str());
}

// One row of the side-by-side table, from a report's JSON.
std::string comparison_row(const std::string& method, const nlohmann::json& j, double ms_per_query) {
  auto num = [](const nlohmann::json& v, int precision) {
    if (v.is_null()) return std::string("–");
    std::ostringstream s;
    s << std::setprecision(precision) << v.get<double>();
    return s.str();
  };
  std::ostringstream s;
  s << "| " << method << " | " << j["queries"] << " | " << j["registered"] << " | " << num(j["registration_rate"], 3)
    << " | " << num(j["position_error_m"].is_null() ? nlohmann::json() : j["position_error_m"]["median"], 3) << " | "
    << num(j["rotation_error_deg"].is_null() ? nlohmann::json() : j["rotation_error_deg"]["median"], 3) << " | "
    << std::fixed << std::setprecision(1) << ms_per_query << " |\n";
  return s.str();
}

void report_progress(const EvaluationRunOptions& o, size_t done, size_t total, const char* what) {
  if (o.progress) o.progress(done, total, what);
}

// The queries' results, their reference poses or positions, and COLMAP's
// registrations of the same queries (compare_colmap).
struct QueryRun {
  std::vector<LocalizationResult> results;
  std::map<std::string, QueryTruth> truth;
  std::optional<ColmapRegistrationResult> peer;
};

// Leave-one-out: each query image taken out of the COLMAP model the map was imported from.
QueryRun localize_leave_one_out(const EvaluationRunOptions& o, nlohmann::json& context) {
  const SourceFeatureStore store(o.map);
  if (!store.is_colmap())
    throw_error(ErrorCode::kInvalidArgument, o.map.string(), ": leave-one-out needs a map imported from COLMAP");
  LeaveOneOutOptions l;
  l.localizer = o.localizer;
  // Each fold's map is imported without descriptors, so none fits a hash
  // blend: the folds search with the weight of the map given (as reported).
  if (l.localizer.hash_blend_source == HashBlendSource::kMap) {
    l.localizer.hash_blend_source = HashBlendSource::kGiven;
    l.localizer.search.hash_blend_weight = static_cast<float>(read_manifest(o.map).fitted_hash_blend().value_or(0.0));
  }
  l.features = o.query_features;
  l.images_dir = o.images_dir;
  l.images = o.queries;
  l.intrinsics = o.intrinsics;
  l.work_dir = o.out / ".visloc-eval-scratch";
  l.compare_colmap = o.compare_colmap;
  l.colmap = o.colmap;
  l.progress = [&o](size_t done, size_t total) { report_progress(o, done, total, "queries"); };
  LeaveOneOutResult r = run_leave_one_out(store.model_dir(), store.database(), l);
  QueryRun run;
  run.results = std::move(r.results);
  run.truth = std::move(r.truth);
  run.peer = std::move(r.colmap);
  size_t listed_cameras = 0;
  for (const auto& q : run.results) listed_cameras += find_listed_camera(o.intrinsics, q.image) != nullptr;
  if (!o.intrinsics.empty()) context["queries_with_given_intrinsics"] = listed_cameras;  // with a list only
  context["protocol"] = "leave-one-out";
  context["truth"] = "poses of the model " + store.model_dir().string();
  context["seconds_rebuilding_maps"] = r.seconds_import;
  return run;
}

// The truth of every query: a GPS CSV (positions, in the map's ENU frame) or reference poses.
std::map<std::string, QueryTruth> read_query_truth(const EvaluationRunOptions& o) {
  std::map<std::string, QueryTruth> truth;
  if (o.truth.extension() == ".csv") {
    const MapManifest man = read_manifest(o.map);
    if (!man.enu_origin_lat_lon_alt)
      throw_error(ErrorCode::kInvalidArgument, o.map.string(), ": the map has no ENU origin; GPS truth needs one");
    const auto& origin = *man.enu_origin_lat_lon_alt;
    EnuFrame frame({origin[0], origin[1], origin[2]});
    for (const auto& r : read_gps_csv(o.truth)) truth[r.image].center = frame.to_enu(r.position);
  } else {
    for (const auto& p : read_reference_poses(o.truth)) truth[p.name].cam_from_world = p.cam_from_world;
  }
  for (const auto& n : o.queries)
    if (!truth.count(n)) throw_error(ErrorCode::kNotFound, o.truth.string(), ": no reference for '", n, "'");
  return truth;
}

// COLMAP's image_registrator on the same prepared queries, against the map's
// model without its holdout images.
ColmapRegistrationResult register_queries_with_colmap(const EvaluationRunOptions& o, const SourceFeatureStore& store,
                                                      const std::vector<PreparedQuery>& prepared) {
  ColmapModel model = read_colmap_model(store.model_dir());
  std::vector<std::string> in_model;
  for (const auto& q : prepared)
    if (model.image_index_by_name(q.name) >= 0) in_model.push_back(q.name);
  const MapManifest man = read_manifest(o.map);
  for (const auto& n : in_model)
    if (std::find(man.holdout_images.begin(), man.holdout_images.end(), n) == man.holdout_images.end())
      throw_error(ErrorCode::kInvalidArgument, "evaluation against COLMAP: query '", n,
                  "' is part of the map (import the map with a holdout list, or use leave-one-out)");
  remove_images(model, man.holdout_images);
  report_progress(o, 0, prepared.size(), "colmap");
  ColmapRegistrationResult peer =
      register_with_colmap(model, store.database(), prepared, o.colmap, o.out / ".visloc-eval-scratch" / "colmap");
  fs::remove_all(o.out / ".visloc-eval-scratch");
  return peer;
}

// The query list against the map, with its truth file.
QueryRun localize_query_list(const EvaluationRunOptions& o, nlohmann::json& context) {
  QueryRun run;
  run.truth = read_query_truth(o);
  std::unique_ptr<SourceFeatureStore> store;
  if (o.query_features == QueryFeatureSource::kDatabase || o.compare_colmap)
    store = std::make_unique<SourceFeatureStore>(o.map, o.images_dir);
  if (o.compare_colmap && !store->is_colmap())
    throw_error(ErrorCode::kInvalidArgument, o.map.string(), ": comparing with COLMAP needs a map imported from COLMAP");
  Localizer localizer(o.map, o.localizer);
  std::vector<PreparedQuery> prepared;
  size_t listed_cameras = 0;
  for (size_t i = 0; i < o.queries.size(); ++i) {
    std::optional<PinholeCamera> cam;
    if (const PinholeCamera* listed = find_listed_camera(o.intrinsics, o.queries[i])) {
      cam = *listed;
      ++listed_cameras;
    }
    PreparedQuery q = prepare_query(o.queries[i], o.query_features, o.images_dir, o.localizer.sift, store.get(), cam,
                                    o.localizer.use_exif_focal);
    run.results.push_back(localize_prepared(localizer, q));
    if (o.compare_colmap) prepared.push_back(std::move(q));
    report_progress(o, i + 1, o.queries.size(), "queries");
  }
  if (o.compare_colmap) run.peer = register_queries_with_colmap(o, *store, prepared);
  if (!o.intrinsics.empty()) context["queries_with_given_intrinsics"] = listed_cameras;  // with a list only
  context["truth"] = fs::absolute(o.truth).string();
  return run;
}

// Negatives: localized from their files (EXIF focal, else estimated).
std::vector<LocalizationResult> localize_negatives(const EvaluationRunOptions& o, nlohmann::json& context) {
  std::vector<LocalizationResult> negative_results;
  if (!o.negatives.empty()) {
    Localizer localizer(o.map, o.localizer);
    for (size_t i = 0; i < o.negatives.size(); ++i) {
      fs::path p = o.negatives[i];
      if (p.is_relative() && !o.images_dir.empty()) p = o.images_dir / p;
      if (!fs::is_regular_file(p))
        throw_error(ErrorCode::kNotFound, o.negatives_source.empty() ? std::string("negatives") : o.negatives_source,
                    ": negative image '", o.negatives[i], "' not found at ", p.string());
      LocalizationResult r = localizer.localize_file(p);
      r.image = p.string();
      negative_results.push_back(std::move(r));
      report_progress(o, i + 1, o.negatives.size(), "negatives");
    }
    context["negatives"] = o.negatives_source.empty() ? nlohmann::json(o.negatives.size())
                                                      : nlohmann::json(fs::absolute(o.negatives_source).string());
  }
  return negative_results;
}

// COLMAP's report (OUT/colmap) and the side-by-side table (OUT/comparison.md).
void write_colmap_comparison(const EvaluationRunOptions& o, const QueryRun& run, const EvaluationReport& rep,
                             const nlohmann::json& context, EvaluationRunResult& result) {
  const fs::path& out = o.out;
  const ColmapRegistrationResult& peer = *run.peer;
  const EvaluationReport peer_rep = evaluate(peer.results, run.truth);
  nlohmann::json peer_context = context;
  peer_context["method"] = "COLMAP 3.8 image_registrator (matches_importer against every model image)";
  peer_context["seconds_matching"] = peer.seconds_matching;
  peer_context["seconds_registration"] = peer.seconds_registration;
  write_results(out / "colmap", peer.results, {}, peer_rep, peer_context, o.map);
  result.colmap_report = nlohmann::json::parse(read_file(out / "colmap" / "report.json"));
  std::vector<double> ours_ms, peer_ms;
  for (const auto& r : run.results) ours_ms.push_back(r.times.total - r.times.features);
  for (const auto& r : peer.results) peer_ms.push_back(r.times.total - r.times.features);
  const double ours = median(ours_ms), theirs = median(peer_ms);
  std::ostringstream md;
  md << "# visloc against COLMAP on the same queries\n\n"
     << "Query features: " << to_string(o.query_features) << "; setting " << to_string(o.localizer.setting)
     << (o.leave_one_out ? "; leave-one-out" : "") << ".\n\n"
     << "| method | queries | registered | rate | median pos. error (m) | "
        "median rot. error (°) | "
        "median ms/query excl. features |\n|---|---|---|---|---|---|---|\n"
     << comparison_row("visloc", rep.to_json(run.results, context), ours)
     << comparison_row("COLMAP image_registrator", peer_rep.to_json(peer.results, peer_context), theirs)
     << "\nCOLMAP wall time: matching " << peer.seconds_matching << " s, registration "
     << peer.seconds_registration << " s; speed-up of visloc (medians): " << std::setprecision(3) << theirs / ours
     << "×.\n";
  result.comparison_markdown = md.str();
  write_file_atomic(out / "comparison.md", result.comparison_markdown);
}

}  // namespace

EvaluationRunResult run_evaluation(const EvaluationRunOptions& o) {
  o.validate();
  const fs::path& out = o.out;
  nlohmann::json context = {{"map", fs::absolute(o.map).string()},
                            {"setting", to_string(o.localizer.setting)},
                            {"query_features", to_string(o.query_features)}};
  // The cascade search's hash-blend weight the localizer uses: given, or the map's fitted one.
  context["hash_blend"] = hash_blend_text(o.localizer);
  const double blend = o.localizer.hash_blend_source == HashBlendSource::kMap
                           ? read_manifest(o.map).fitted_hash_blend().value_or(0.0)
                           : double(o.localizer.search.hash_blend_weight);
  context["hash_blend_weight"] = std::round(blend * 1e6) / 1e6;  // a float weight without its float digits
  const QueryRun run = o.leave_one_out ? localize_leave_one_out(o, context) : localize_query_list(o, context);
  const std::vector<LocalizationResult> negative_results = localize_negatives(o, context);

  EvaluationRunResult result;
  const EvaluationReport rep = evaluate(run.results, run.truth, negative_results, o.localizer);
  write_results(out, run.results, negative_results, rep, context, o.map);
  result.report = nlohmann::json::parse(read_file(out / "report.json"));
  result.report_markdown = read_file(out / "report.md");
  if (run.peer) write_colmap_comparison(o, run, rep, context, result);
  return result;
}

void read_list_files(const EvaluationListFiles& lists, EvaluationRunOptions& o) {
  if (o.query_features == QueryFeatureSource::kImages && o.images_dir.empty())
    throw_error(ErrorCode::kInvalidArgument, "eval: --images is needed with --query-features images");
  if (!o.leave_one_out && (lists.queries.empty() || o.truth.empty()))
    throw_error(ErrorCode::kInvalidArgument, "eval: --queries and --truth are needed (or --leave-one-out)");
  if (!lists.queries.empty()) {
    o.queries = read_name_list(lists.queries);
    if (o.queries.empty()) throw_error(ErrorCode::kInvalidArgument, lists.queries.string(), ": no query names");
  }
  if (!lists.intrinsics.empty()) o.intrinsics = read_intrinsics_by_name(lists.intrinsics);
  if (!lists.negatives.empty()) {
    o.negatives = read_name_list(lists.negatives);
    if (o.negatives.empty()) throw_error(ErrorCode::kInvalidArgument, lists.negatives.string(), ": no image paths");
    o.negatives_source = lists.negatives.string();
  }
}

std::string unlisted_intrinsics_warning(const EvaluationListFiles& lists, const EvaluationRunOptions& o) {
  if (lists.intrinsics.empty()) return {};
  return unlisted_cameras_warning(o.intrinsics, lists.intrinsics, o.queries, "queries");
}

std::function<void(size_t, size_t, const std::string&)> evaluation_progress_printer(std::ostream& log, bool tty) {
  return [&log, tty](size_t done, size_t total, const std::string& what) {
    if (what == "colmap") {
      log << "eval: registering " << total << " queries with COLMAP's image_registrator\n";
      return;
    }
    const std::string label = what == "negatives" ? "eval: negatives " : "eval: ";
    if (tty)
      log << "\r" << label << done << "/" << total << (done == total ? "\n" : "") << std::flush;
    else if (done == total || done % 10 == 0)
      log << label << done << "/" << total << "\n";
  };
}

}  // namespace visloc
