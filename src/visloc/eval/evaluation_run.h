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
#include <iosfwd>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/eval/protocols.h"
#include "visloc/geometry/pose_list.h"
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
  CamerasByName intrinsics;  // per query image, or '*' for all (find_listed_camera); else EXIF or an estimated focal
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

// The lists `visloc eval` names by file, read into EvaluationRunOptions by read_list_files.
struct EvaluationListFiles {
  std::filesystem::path queries;     // query names, one per line
  std::filesystem::path intrinsics;  // 'name MODEL width height params...' per query image, '*' for all
  std::filesystem::path negatives;   // paths of images that must not register, one per line
};

class OptionTable;
// `visloc eval`'s options: --map, --queries, --images, --truth, --out, --intrinsics, --query-features,
// --leave-one-out, --negatives, --compare, --colmap and the localizer's.
void add_options(OptionTable& table, EvaluationRunOptions& options, EvaluationListFiles& lists);

// Checks what the command line must give (--images with --query-features
// images; --queries and --truth unless --leave-one-out), then reads the lists
// into `options`. Throws Error(kInvalidArgument) naming the option or file.
void read_list_files(const EvaluationListFiles& lists, EvaluationRunOptions& options);
// After read_list_files: a warning naming the intrinsics file when some
// queries have no camera in it (no line of their own and no '*' line), or ""
// (no file given, or every query listed).
std::string unlisted_intrinsics_warning(const EvaluationListFiles& lists, const EvaluationRunOptions& options);

// An EvaluationRunOptions::progress that writes "eval: 12/40" lines to `log`
// (one line rewritten in place when `tty`, else every 10th).
std::function<void(size_t, size_t, const std::string&)> evaluation_progress_printer(std::ostream& log, bool tty);

// Reference poses: a COLMAP model directory, a COLMAP images.txt, or a pose
// list 'name qw qx qy qz tx ty tz'.
std::vector<NamedPose> read_reference_poses(const std::filesystem::path& path);

}  // namespace visloc
