// One evaluation run, what `visloc eval` and Python's visloc.evaluate() do:
// localize a query list against a map (or, for a map imported from COLMAP,
// leave every image out in turn), optionally localize negatives that must
// not register and let COLMAP's image_registrator register the same
// queries, then compare with the truth and write the report folder:
//   OUT/report.json, report.md, plots (evaluation.h write_report)
//   OUT/poses.txt      registered queries, 'name qw qx qy qz tx ty tz'
//   OUT/results.jsonl  one localization per line (negatives marked)
//   OUT/colmap/, OUT/comparison.md  with compare_colmap
#pragma once

#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/eval/protocols.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/sfm/colmap_runner.h"

namespace visloc {

struct EvaluationRunOptions {
  std::filesystem::path map;
  std::filesystem::path out;                 // report folder (created)
  std::vector<std::string> queries;          // image names; with leave_one_out: the images left out (empty: all)
  std::filesystem::path images_dir;          // query images (needed with QueryFeatureSource::kImages)
  // Reference: a pose list 'name qw qx qy qz tx ty tz' (the map's frame), a
  // COLMAP images.txt or model directory, or a GPS CSV (.csv: positions in
  // the map's ENU frame). Not used with leave_one_out.
  std::filesystem::path truth;
  std::map<std::string, PinholeCamera> intrinsics;  // per query image; else EXIF or an estimated focal
  QueryFeatureSource query_features = QueryFeatureSource::kImages;
  bool leave_one_out = false;                // a map imported from COLMAP: its own images, one by one
  // Images that must not register (other places, foreign photos): paths,
  // relative ones against images_dir. Each registered one is a wrong pose.
  std::vector<std::string> negatives;
  bool compare_colmap = false;               // COLMAP's image_registrator on the same queries
  ColmapRunnerOptions colmap;
  LocalizerOptions localizer;
  // Recorded in the report's context (informational).
  std::string negatives_source;              // e.g. the list file the negatives came from
  // Called after each query / negative (done, total, "queries" or
  // "negatives"), and once (0, total, "colmap") before COLMAP registers them.
  std::function<void(size_t, size_t, const std::string&)> progress;
  void validate() const;
};

struct EvaluationRunResult {
  nlohmann::json report;                     // report.json
  std::string report_markdown;               // report.md
  std::optional<nlohmann::json> colmap_report;     // with compare_colmap
  std::string comparison_markdown;                 // with compare_colmap (OUT/comparison.md)
};

EvaluationRunResult run_evaluation(const EvaluationRunOptions& options);

// Reference poses: a COLMAP model directory, a COLMAP images.txt, or a pose
// list 'name qw qx qy qz tx ty tz'.
std::vector<NamedPose> read_reference_poses(const std::filesystem::path& path);

}  // namespace visloc
