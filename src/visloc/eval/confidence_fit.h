// Fitting and checking the localizer's confidence (pipeline/confidence.h):
//   * samples: every pose a report saw (registered or not) with its
//     confidence inputs and whether it was right: within 5 m and 10° of the
//     truth; a foreign photo's or a listed negative's pose is never right;
//   * the fit: logistic regression (Newton / IRLS with an L2 penalty on
//     standardized inputs chosen by 5-fold cross-validation, classes
//     weighted to equal mass), kept monotone:
//     an input whose weight comes out with the wrong sign
//     (confidence_input_signs) is dropped and the rest refitted;
//   * the threshold: the lowest confidence at which the registered poses
//     (≥ min_inliers) at or above it are right with the target precision;
//   * the σ scale: the 68th percentile of error / σ over the right poses
//     at or above the threshold;
//   * the precision-recall curve of a confidence over a query set.
#pragma once

#include <array>
#include <filesystem>
#include <iosfwd>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/eval/evaluation.h"
#include "visloc/pipeline/confidence.h"

namespace visloc {

struct ConfidenceSample {
  ConfidenceFeatures features;
  bool right = false;  // the pose is within the wrong-pose thresholds of the truth
  // The pose's position error over its σ before any sigma_scale (the σ
  // times the query's sigma_scale, else the report's uncertainty.sigma_scale,
  // 1 when absent); -1 without a σ or a truth.
  double error_over_unscaled_sigma = -1;
  bool map_point_uncertainty = false;  // the σ included the map points' uncertainty
};

// The samples of a report.json written by `visloc bench city` (per_query
// with kind, confidence_features and pose_position_error_m) or by `visloc
// eval` (per_query with negative, confidence_features and pose errors).
// Every query with a pose and a truth is a sample, right when the pose is
// within `rule` (bench city's "between" and "near_unseen" queries too, which
// its report does not score); foreign photos and listed negatives are wrong.
// Throws Error(kFormat) naming the file when it holds neither.
std::vector<ConfidenceSample> read_confidence_samples(const std::filesystem::path& report, const WrongPoseRule& rule);

struct ConfidenceFitOptions {
  double l2 = -1;                   // penalty on the standardized weights; < 0: by 5-fold cross-validation
  double target_precision = 0.995;  // of the registered poses at the threshold
  double min_inliers = 12;          // the poses the threshold is chosen on (as the localizer registers)
  void validate() const;
};

struct PrecisionRecallPoint {
  double threshold = 0, precision = 1, recall = 0;
  size_t accepted = 0, accepted_right = 0;
};

// Over descending thresholds (each distinct score): precision = right poses
// accepted / poses accepted, recall = right poses accepted / `positives`.
// A sample is accepted at threshold t when its score ≥ t.
std::vector<PrecisionRecallPoint> precision_recall_curve(const std::vector<double>& scores,
                                                        const std::vector<bool>& right, size_t positives);

// The sigma_scale that puts the given share of `error_over_sigma` within
// 1σ: its nearest-rank quantile (1 when empty).
double sigma_scale_for_share(std::vector<double> error_over_sigma, double share = 0.68);

// The lowest threshold whose precision is at least `target` (1.0 when none:
// nothing is accepted but a perfect score).
double threshold_for_precision(const std::vector<PrecisionRecallPoint>& curve, double target);

struct ConfidenceFit {
  ConfidenceModel model;
  size_t samples = 0, right = 0, wrong = 0;  // all poses
  size_t threshold_samples = 0;              // those with ≥ min_inliers
  std::vector<std::string> dropped_inputs;   // weights with the wrong sign
  double l2 = 0;                             // the penalty used
  std::vector<std::pair<double, double>> cross_validation;  // (l2, weighted log loss per sample)
  PrecisionRecallPoint at_threshold;         // on the fit's own data
  size_t sigma_samples = 0;                  // right poses at the threshold with a σ (model.sigma_scale)
  size_t sigma_samples_with_point_uncertainty = 0;  // (model.sigma_scale_with_point_uncertainty)
  nlohmann::json to_json() const;
};

ConfidenceFit fit_confidence(const std::vector<ConfidenceSample>& samples, const ConfidenceFitOptions& options);

// The σ scales alone, for `model`'s weights and threshold: sigma_scale over
// the right poses at the threshold (≥ min_inliers, with a σ) whose σ left out
// the map points' uncertainty, sigma_scale_with_point_uncertainty over those
// whose σ included it (sigma_scale_for_share, 68%). A group without a pose
// keeps the model's scale. `counts` gets the two groups' sizes.
ConfidenceModel fit_sigma_scales(const std::vector<ConfidenceSample>& samples, const ConfidenceModel& model,
                                 double min_inliers, std::array<size_t, 2>* counts = nullptr);

// Writes a precision-recall plot (stem.svg, stem.png) with `threshold` marked.
void plot_precision_recall(const std::filesystem::path& stem, const std::string& title,
                           const std::vector<PrecisionRecallPoint>& curve, double threshold);

// A model checked on samples: the poses with ≥ min_inliers (the registered
// ones) split at the model's threshold into right poses kept, right poses
// lost and wrong poses kept; the precision-recall curve of its confidence
// over them (recall over the right ones).
struct ConfidenceCheck {
  size_t poses_with_min_inliers = 0;
  size_t right_registered = 0, right_lost = 0, wrong_registered = 0;
  double threshold = 0, sigma_scale = 1, sigma_scale_with_point_uncertainty = 1;  // the model's
  // Of the right poses registered that have a σ: how many, and the fractions
  // of their errors within 1 and 2 of the model's σ (its sigma_scale).
  size_t with_sigma = 0;
  double within_1_sigma = 0, within_2_sigma = 0;
  std::vector<PrecisionRecallPoint> curve;
  nlohmann::json to_json() const;  // the counts and the threshold
};

ConfidenceCheck check_confidence(const std::vector<ConfidenceSample>& samples, const ConfidenceModel& model,
                                 double min_inliers);

// The model as the C++ statements of ConfidenceModel::builtin (full precision).
std::string confidence_model_code(const ConfidenceModel& model);

// `visloc bench confidence`: fit a model on the poses of reports (fit), or
// check one on them (model_file, else the builtin model). Writes model.json
// (fit), fit.json or check.json and the precision-recall plot to out_dir.
struct ConfidenceBenchmarkOptions {
  std::vector<std::string> reports;  // report.json of `visloc bench city` or `visloc eval`
  std::filesystem::path out_dir;
  bool fit = false;
  bool fit_sigma = false;            // fit the σ scales only (fit_sigma_scales), the model's weights kept
  std::filesystem::path model_file;  // a model.json written by a fit
  ConfidenceFitOptions fit_options;
  WrongPoseRule rule;
  void validate() const;
};

class OptionTable;
// The fit's options: --target-precision, --l2, --min-inliers.
void add_options(OptionTable& table, ConfidenceFitOptions& options);
// `visloc bench confidence`'s options: --reports, --out, --fit, --model, the
// fit's, --wrong-position, --wrong-rotation.
void add_options(OptionTable& table, ConfidenceBenchmarkOptions& options);

// Runs it: each report's pose count to `log`; the fitted model's C++ (fit)
// and the counts at the model's threshold to `out`.
void run_confidence_benchmark(const ConfidenceBenchmarkOptions& options, std::ostream& out, std::ostream& log);

}  // namespace visloc
