// Evaluation of localization results against reference poses or positions:
// registration rate, position / rotation error statistics, counts under the
// paper's thresholds, recall at (0.25 m, 2°), (0.5 m, 5°), (5 m, 10°),
// per-stage times, and the report files (report.json, report.md, a
// cumulative error curve as SVG and PNG, a top view of truth and estimates).
#pragma once

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "visloc/pipeline/localizer.h"

namespace visloc {

struct QueryTruth {
  std::optional<CameraPose> cam_from_world;  // same frame as the map's segments (pose truth)
  std::optional<Eigen::Vector3d> center;     // ENU metres (GPS truth) or world centre (pose truth)
};

struct QueryEvaluation {
  std::string image;
  bool registered = false;
  double position_error = -1;  // metres; -1 when not registered
  double rotation_error = -1;  // degrees; -1 when unknown
  std::optional<Eigen::Vector3d> estimated_center, true_center;
};

struct EvaluationReport {
  size_t queries = 0, registered = 0;
  std::vector<QueryEvaluation> per_query;
  nlohmann::json to_json(const std::vector<LocalizationResult>& results, const nlohmann::json& context) const;
};

// Compares results with the truth. Pose truth compares cam_from_segment with
// the reference pose (the map's segments share the truth's frame: known-pose
// maps, imported models); GPS truth compares the ENU centre.
EvaluationReport evaluate(const std::vector<LocalizationResult>& results,
                          const std::map<std::string, QueryTruth>& truth);

// Writes report.json, report.md, error_curve.svg/.png and top_view.svg/.png.
void write_report(const std::filesystem::path& dir, const EvaluationReport& report,
                  const std::vector<LocalizationResult>& results, const nlohmann::json& context);

// Median of a sample (NaN when empty); even sizes average the middle two.
double median(std::vector<double> values);

// Peak resident memory of this process image (bytes): VmHWM, which starts
// afresh at exec; getrusage where /proc is absent.
uint64_t peak_memory_bytes();

}  // namespace visloc
