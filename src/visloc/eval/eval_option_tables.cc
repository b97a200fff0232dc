// Command-line options of the evaluation run, the segment study and the
// confidence fit (util/option_table.h).
#include <algorithm>
#include <climits>
#include <cmath>

#include "visloc/eval/confidence_fit.h"
#include "visloc/eval/evaluation_run.h"
#include "visloc/eval/segment_study.h"
#include "visloc/map_building/map_builder.h"
#include "visloc/util/option_table.h"

namespace visloc {
namespace {

// "4,6,8" for a list's default.
std::string join_numbers(const std::vector<int>& values) {
  std::string text;
  for (int v : values) {
    if (!text.empty()) text += ',';
    text += std::to_string(v);
  }
  return text;
}

// Parses a comma-separated list of whole numbers into `field`.
std::function<void(const std::string&)> whole_number_list(std::vector<int>& field, std::string option) {
  return [&field, option](const std::string& text) {
    std::vector<int> values;
    for (double v : parse_number_list(text, option)) {
      if (v != std::floor(v) || std::abs(v) > 1e6)
        throw_error(ErrorCode::kInvalidArgument, option, ": ", v, " is not an integer");
      values.push_back(static_cast<int>(v));
    }
    field = values;
  };
}

}  // namespace

void add_options(OptionTable& t, EvaluationRunOptions& o, EvaluationListFiles& lists) {
  t.add("--map", o.map, "Map directory").require();
  t.add("--queries", lists.queries,
        "Query image names, one per line (required unless --leave-one-out; with it: the images to leave out)");
  t.add("--images", o.images_dir, "Directory of the query images (needed with --query-features images)");
  t.add("--truth", o.truth,
        "Reference: poses 'name qw qx qy qz tx ty tz' (the map's frame), a COLMAP images.txt or model directory, "
        "or a GPS CSV (.csv: positions); not used with --leave-one-out (the model's poses are the truth)");
  t.add("--out", o.out, "Report directory").require();
  t.add("--intrinsics", lists.intrinsics,
        "Query intrinsics, 'name MODEL width height params...' per line ('*' for every query without a line); a "
        "query without one takes its EXIF focal, else an estimated one");
  t.choice("--query-features", o.query_features,
           {{"images", QueryFeatureSource::kImages}, {"database", QueryFeatureSource::kDatabase}},
           "Query features: 'images' (our SIFT on the photos) or 'database' (the imported model's own features "
           "and intrinsics)");
  t.flag("--leave-one-out", o.leave_one_out,
         "Localize every image of the imported COLMAP model against the model without it");
  t.add("--negatives", lists.negatives,
        "Images that must not register (other places, foreign photos): one path per line, relative paths against "
        "--images; each registered one counts as a wrong pose");
  t.choice("--compare", o.compare_colmap, {{"colmap", true}},
           "Also run a peer on the same queries: 'colmap' (image_registrator)");
  t.add("--colmap", o.colmap.binary, "COLMAP executable (with --compare colmap)");
  add_options(t, o.localizer);
}

void add_options(OptionTable& t, SegmentStudyOptions& o) {
  t.text("--placemarks", join_numbers(o.placemarks), whole_number_list(o.placemarks, "--placemarks"),
         "Placemarks per segment, comma-separated");
  t.text("--overlaps", join_numbers(o.overlaps), whole_number_list(o.overlaps, "--overlaps"),
         "Placemarks shared by neighbours, comma-separated");
  t.text(
      "--jobs", std::to_string(o.map.jobs),
      [&o](const std::string& text) {
        // 0 or less: every core (MapBuildOptions::jobs = 0).
        o.map.jobs = static_cast<int>(std::max(0LL, parse_whole_number(text, "--jobs", INT_MIN, INT_MAX)));
      },
      "Segments built at once (0: cores)");
  t.add("--max-queries", o.max_queries, "Localize at most this many queries per data set, evenly spread (0: all)");
  t.flag("--keep-maps", o.keep_maps, "Keep every configuration's map (default: only its result)");
  add_pq_bytes_option(t, o.map.pq);
  add_options(t, o.localizer);
}

void add_options(OptionTable& t, ConfidenceFitOptions& o) {
  t.add("--target-precision", o.target_precision,
        "--fit: the threshold gives at least this precision on the registered poses");
  t.add("--l2", o.l2, "--fit: L2 penalty on the standardized weights (< 0: chosen by 5-fold cross-validation)");
  t.add("--min-inliers", o.min_inliers, "Poses with at least this many inliers are the registered ones");
}

void add_options(OptionTable& t, ConfidenceBenchmarkOptions& o) {
  t.add("--reports", o.reports, "report.json files (bench city or eval)").require();
  t.add("--out", o.out_dir, "Output directory").require();
  t.flag("--fit", o.fit, "Fit a model on the reports (else check one)");
  t.flag("--fit-sigma", o.fit_sigma,
         "Fit only the sigma scales (without and with the map points' uncertainty) of the checked model on the "
         "reports' right poses at its threshold, keeping its weights");
  t.add("--model", o.model_file, "Check this model.json (written by --fit) instead of the builtin model");
  add_options(t, o.fit_options);
  t.add("--wrong-position", o.rule.position_m, "A pose farther than this (m) from the truth is wrong");
  t.add("--wrong-rotation", o.rule.rotation_deg, "... or turned more than this (degrees)");
}

}  // namespace visloc
