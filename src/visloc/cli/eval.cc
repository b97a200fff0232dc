// visloc eval: localize a query list against a map and report against the
// truth; or, for an imported COLMAP model, leave-one-out over its images;
// optionally with COLMAP's image_registrator on the same queries.
#include <unistd.h>

#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/eval/evaluation.h"
#include "visloc/eval/protocols.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/map.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {
namespace fs = std::filesystem;

namespace {

// Reference poses: a COLMAP model directory, a COLMAP images.txt, or a pose
// list 'name qw qx qy qz tx ty tz'.
std::vector<NamedPose> read_reference_poses(const fs::path& path) {
  if (fs::is_directory(path)) {
    std::vector<NamedPose> out;
    for (const auto& im : read_colmap_model(path).images)
      out.push_back({im.name, colmap_image_pose(im)});
    return out;
  }
  if (path.filename() == "images.txt") return read_colmap_images_txt_poses(path);
  return read_pose_list(path);
}

void write_results(const fs::path& dir, const std::vector<LocalizationResult>& results,
                   const std::vector<LocalizationResult>& negative_results, const EvaluationReport& rep,
                   const nlohmann::json& context) {
  write_report(dir, rep, results, context);
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

}  // namespace

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
    args->options.setting = parse_paper_setting(args->setting);
    const QueryFeatureSource source = parse_query_feature_source(args->query_features);
    const bool compare = args->compare == "colmap";
    const fs::path out(args->out);
    if (source == QueryFeatureSource::kImages && args->images.empty())
      throw_error(ErrorCode::kInvalidArgument, "eval: --images is needed with --query-features images");
    std::map<std::string, PinholeCamera> cameras;
    if (!args->intrinsics.empty())
      for (auto& c : read_intrinsics_list(args->intrinsics)) cameras[c.name] = c.camera;
    const bool tty = ::isatty(STDERR_FILENO);
    auto progress = [tty](size_t done, size_t total) {
      if (tty)
        std::cerr << "\reval: " << done << "/" << total << std::flush;
      else if (done == total || done % 10 == 0)
        std::cerr << "eval: " << done << "/" << total << "\n";
    };

    std::vector<LocalizationResult> results;
    std::map<std::string, QueryTruth> truth;
    std::optional<ColmapRegistrationResult> peer;
    nlohmann::json context = {{"map", fs::absolute(args->map).string()},
                              {"setting", args->setting},
                              {"query_features", args->query_features}};
    if (args->leave_one_out) {
      const SourceFeatureStore store(args->map);
      if (!store.is_colmap())
        throw_error(ErrorCode::kInvalidArgument, args->map, ": --leave-one-out needs a map imported from COLMAP");
      LeaveOneOutOptions o;
      o.localizer = args->options;
      o.features = source;
      o.images_dir = args->images;
      if (!args->queries.empty()) {
        o.images = read_name_list(args->queries);
        if (o.images.empty()) throw_error(ErrorCode::kInvalidArgument, args->queries, ": no query names");
      }
      o.intrinsics = cameras;
      o.work_dir = out / ".visloc-eval-scratch";
      o.compare_colmap = compare;
      o.colmap = args->colmap;
      o.progress = progress;
      LeaveOneOutResult r = run_leave_one_out(store.model_dir(), store.database(), o);
      if (tty) std::cerr << "\n";
      results = std::move(r.results);
      truth = std::move(r.truth);
      peer = std::move(r.colmap);
      context["protocol"] = "leave-one-out";
      context["truth"] = "poses of the model " + store.model_dir().string();
      context["seconds_rebuilding_maps"] = r.seconds_import;
    } else {
      if (args->queries.empty() || args->truth.empty())
        throw_error(ErrorCode::kInvalidArgument, "eval: --queries and --truth are needed (or --leave-one-out)");
      const auto names = read_name_list(args->queries);
      if (names.empty()) throw_error(ErrorCode::kInvalidArgument, args->queries, ": no query names");
      if (fs::path(args->truth).extension() == ".csv") {
        const MapManifest man = read_manifest(args->map);
        if (!man.enu_origin_lat_lon_alt)
          throw_error(ErrorCode::kInvalidArgument, args->map, ": the map has no ENU origin; GPS truth needs one");
        const auto& o = *man.enu_origin_lat_lon_alt;
        EnuFrame frame({o[0], o[1], o[2]});
        for (const auto& r : read_gps_csv(args->truth)) truth[r.image].center = frame.to_enu(r.position);
      } else {
        for (const auto& p : read_reference_poses(args->truth)) truth[p.name].cam_from_world = p.cam_from_world;
      }
      for (const auto& n : names)
        if (!truth.count(n)) throw_error(ErrorCode::kNotFound, args->truth, ": no reference for '", n, "'");
      std::unique_ptr<SourceFeatureStore> store;
      if (source == QueryFeatureSource::kDatabase || compare)
        store = std::make_unique<SourceFeatureStore>(args->map, args->images);
      if (compare && !store->is_colmap())
        throw_error(ErrorCode::kInvalidArgument, args->map, ": --compare colmap needs a map imported from COLMAP");
      Localizer localizer(args->map, args->options);
      std::vector<PreparedQuery> prepared;
      for (size_t i = 0; i < names.size(); ++i) {
        std::optional<PinholeCamera> cam;
        if (auto it = cameras.find(names[i]); it != cameras.end()) cam = it->second;
        PreparedQuery q = prepare_query(names[i], source, args->images, args->options.sift, store.get(), cam,
                                        args->options.use_exif_focal);
        results.push_back(localize_prepared(localizer, q));
        if (compare) prepared.push_back(std::move(q));
        progress(i + 1, names.size());
      }
      if (tty) std::cerr << "\n";
      if (compare) {
        std::cerr << "eval: registering " << prepared.size() << " queries with COLMAP's image_registrator\n";
        ColmapModel model = read_colmap_model(store->model_dir());
        std::vector<std::string> in_model;
        for (const auto& q : prepared)
          if (model.image_index_by_name(q.name) >= 0) in_model.push_back(q.name);
        const MapManifest man = read_manifest(args->map);
        for (const auto& n : in_model)
          if (std::find(man.holdout_images.begin(), man.holdout_images.end(), n) == man.holdout_images.end())
            throw_error(ErrorCode::kInvalidArgument, "eval --compare colmap: query '", n,
                        "' is part of the map (import the map with --holdout, "
                        "or use --leave-one-out)");
        remove_images(model, man.holdout_images);
        peer = register_with_colmap(model, store->database(), prepared, args->colmap, out / ".visloc-eval-scratch" / "colmap");
        fs::remove_all(out / ".visloc-eval-scratch");
      }
      context["truth"] = fs::absolute(args->truth).string();
    }

    // Negatives: localized from their files (EXIF focal, else estimated).
    std::vector<LocalizationResult> negative_results;
    if (!args->negatives.empty()) {
      const auto list = read_name_list(args->negatives);
      if (list.empty()) throw_error(ErrorCode::kInvalidArgument, args->negatives, ": no image paths");
      Localizer localizer(args->map, args->options);
      for (size_t i = 0; i < list.size(); ++i) {
        fs::path p = list[i];
        if (p.is_relative() && !args->images.empty()) p = fs::path(args->images) / p;
        if (!fs::is_regular_file(p))
          throw_error(ErrorCode::kNotFound, args->negatives, ": negative image '", list[i], "' not found at ",
                      p.string());
        LocalizationResult r = localizer.localize_file(p);
        r.image = p.string();
        negative_results.push_back(std::move(r));
        if (tty) std::cerr << "\reval: negatives " << i + 1 << "/" << list.size() << std::flush;
      }
      if (tty) std::cerr << "\n";
      context["negatives"] = fs::absolute(args->negatives).string();
    }
    EvaluationReport rep = evaluate(results, truth, negative_results, args->options);
    write_results(out, results, negative_results, rep, context);
    std::cout << read_file(out / "report.md");
    if (peer) {
      EvaluationReport peer_rep = evaluate(peer->results, truth);
      nlohmann::json peer_context = context;
      peer_context["method"] =
          "COLMAP 3.8 image_registrator (matches_importer "
          "against every model image)";
      peer_context["seconds_matching"] = peer->seconds_matching;
      peer_context["seconds_registration"] = peer->seconds_registration;
      write_results(out / "colmap", peer->results, {}, peer_rep, peer_context);
      std::vector<double> ours_ms, peer_ms;
      for (const auto& r : results) ours_ms.push_back(r.times.total - r.times.features);
      for (const auto& r : peer->results) peer_ms.push_back(r.times.total - r.times.features);
      const double ours = median(ours_ms), theirs = median(peer_ms);
      std::ostringstream md;
      md << "# visloc against COLMAP on the same queries\n\n"
         << "Query features: " << args->query_features << "; setting " << args->setting
         << (args->leave_one_out ? "; leave-one-out" : "") << ".\n\n"
         << "| method | queries | registered | rate | median pos. error (m) | "
            "median rot. error (°) | "
            "median ms/query excl. features |\n|---|---|---|---|---|---|---|\n"
         << comparison_row("visloc", rep.to_json(results, context), ours)
         << comparison_row("COLMAP image_registrator", peer_rep.to_json(peer->results, peer_context), theirs)
         << "\nCOLMAP wall time: matching " << peer->seconds_matching << " s, registration "
         << peer->seconds_registration << " s; speed-up of visloc (medians): " << std::setprecision(3) << theirs / ours
         << "×.\n";
      write_file_atomic(out / "comparison.md", md.str());
      std::cout << "\n" << md.str();
    }
  });
}

}  // namespace visloc::cli
