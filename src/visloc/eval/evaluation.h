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
#include "visloc/util/statistics.h"

namespace visloc {

struct QueryTruth {
  std::optional<CameraPose> cam_from_world;  // same frame as the map's segments (pose truth)
  std::optional<Eigen::Vector3d> center;     // ENU metres (GPS truth) or world centre (pose truth)
};

struct PrecisionRecallPoint;  // confidence_fit.h

struct WrongPoseRule {
  double position_m = 5, rotation_deg = 10;  // a registered pose beyond either is wrong
};

struct QueryEvaluation {
  std::string image;
  bool registered = false;
  bool negative = false;       // a listed negative: must not register (no truth)
  bool wrong = false;          // registered beyond the wrong-pose rule, or a registered negative
  double position_error = -1;  // metres; -1 when not registered
  double rotation_error = -1;  // degrees; -1 when unknown
  // The pose's errors whether it registered or not (-1: no pose or no truth).
  double pose_position_error = -1, pose_rotation_error = -1;
  size_t inliers = 0;
  double confidence = 0;
  std::optional<ConfidenceFeatures> confidence_features;  // with a pose
  bool under_street = false;  // the pose's camera under the street (LocalizationResult::under_street)
  PoseUncertainty uncertainty;
  bool uncertainty_in_metres = false;  // GPS truth: the error is compared with the ENU σ
  std::optional<Eigen::Vector3d> estimated_center, true_center;
  // The cameras' viewing directions (their z axes) in the same frame, where
  // known: pose truth gives both; GPS truth neither.
  std::optional<Eigen::Vector3d> estimated_view_direction, true_view_direction;
  int segment = -1;   // the best pose's segment id (-1: none)
  StageTimes times;   // milliseconds per stage
};

struct EvaluationReport {
  size_t queries = 0, registered = 0;  // queries with truth (positives)
  size_t negatives = 0, negatives_registered = 0;
  size_t wrong_positives = 0;          // registered beyond the rule
  WrongPoseRule rule;
  size_t min_inliers = 12;             // the localizer's, for the precision-recall curve
  double min_confidence = 0;           // the localizer's threshold, marked on the curve
  std::vector<QueryEvaluation> per_query;  // positives, then negatives
  // The frame of the centres: "segment" (pose truth: the frame the map's
  // segments share), "enu" (GPS truth), "mixed" or "" (no positives).
  std::string frame;
  // Precision-recall of the confidence over the poses with ≥ min_inliers
  // (recall over the positives).
  std::vector<PrecisionRecallPoint> confidence_curve() const;
  nlohmann::json to_json(const std::vector<LocalizationResult>& results, const nlohmann::json& context) const;
};

// Compares results with the truth. Pose truth compares cam_from_segment with
// the reference pose (the map's segments share the truth's frame: known-pose
// maps, imported models); GPS truth compares the ENU centre.
// `negative_results`: localizations of images that must not register (any
// registered one is a wrong pose). `localizer` gives min_inliers and
// min_confidence for the precision-recall curve of the confidence.
EvaluationReport evaluate(const std::vector<LocalizationResult>& results,
                          const std::map<std::string, QueryTruth>& truth,
                          const std::vector<LocalizationResult>& negative_results = {},
                          const LocalizerOptions& localizer = {}, const WrongPoseRule& rule = {});

// Writes report.json, report.md, error_curve.svg/.png, top_view.svg/.png and
// precision_recall.svg/.png (the confidence over the positives' and the
// negatives' poses, the threshold marked).
// With `map_dir`, the top view draws the map under the queries: its points
// (grey), each segment's outline and id (map_overview.h), in the frame of the
// report's centres; without it, or when the map cannot be drawn in that frame,
// the queries alone.
void write_report(const std::filesystem::path& dir, const EvaluationReport& report,
                  const std::vector<LocalizationResult>& results, const nlohmann::json& context,
                  const std::filesystem::path& map_dir = {});

// median(): util/statistics.h.

// Peak resident memory of this process image (bytes): VmHWM, which starts
// afresh at exec; getrusage where /proc is absent.
uint64_t peak_memory_bytes();

}  // namespace visloc
