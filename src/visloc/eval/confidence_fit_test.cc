// Confidence fit, precision-recall and wrong poses in the evaluation report.
#include <gtest/gtest.h>

#include <filesystem>
#include <random>

#include "visloc/eval/confidence_fit.h"
#include "visloc/eval/evaluation.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace {

TEST(PrecisionRecall, CurveAndThresholdOnAHandExample) {
  // Scores best first: right, right, wrong, right, wrong; 4 positives in all.
  const std::vector<double> scores = {0.9, 0.8, 0.7, 0.6, 0.5};
  const std::vector<bool> right = {true, true, false, true, false};
  const auto curve = precision_recall_curve(scores, right, 4);
  ASSERT_EQ(curve.size(), 5u);
  EXPECT_DOUBLE_EQ(curve[1].precision, 1.0);
  EXPECT_DOUBLE_EQ(curve[1].recall, 0.5);
  EXPECT_DOUBLE_EQ(curve[2].precision, 2.0 / 3);
  EXPECT_DOUBLE_EQ(curve[3].recall, 0.75);
  EXPECT_DOUBLE_EQ(threshold_for_precision(curve, 1.0), 0.8);
  EXPECT_DOUBLE_EQ(threshold_for_precision(curve, 0.7), 0.6);  // 3 of 4 at 0.6
  // Ties are accepted together.
  const auto tied = precision_recall_curve({0.5, 0.5, 0.4}, {true, false, true}, 2);
  ASSERT_EQ(tied.size(), 2u);
  EXPECT_DOUBLE_EQ(tied[0].precision, 0.5);
}

// Right poses: many inliers, wide coverage; wrong ones: few, clustered, far
// from the map's cameras; with noise so that the classes overlap a little.
std::vector<ConfidenceSample> synthetic_samples(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 1);
  std::vector<ConfidenceSample> out;
  for (int i = 0; i < 400; ++i) {
    const bool right = i % 4 != 0;
    ConfidenceSample s;
    s.right = right;
    s.features.inliers = std::exp((right ? 4.0 : 2.5) + 0.5 * noise(rng));
    s.features.inlier_ratio = std::clamp((right ? 0.6 : 0.15) + 0.15 * noise(rng), 0.0, 1.0);
    s.features.coverage = std::clamp((right ? 0.35 : 0.08) + 0.08 * noise(rng), 0.0, 1.0);
    s.features.residual = std::clamp((right ? 0.2 : 0.35) + 0.08 * noise(rng), 0.0, 1.0);
    s.features.margin = std::clamp((right ? 0.05 : 0.6) + 0.2 * noise(rng), 0.0, 1.0);
    s.features.vote_share = std::clamp(0.4 + 0.1 * noise(rng), 0.0, 1.0);  // uninformative
    s.features.camera_distance = std::abs((right ? 0.05 : 1.0) + 0.3 * noise(rng));
    out.push_back(s);
  }
  return out;
}

TEST(ConfidenceFit, LearnsTheExpectedSignsAndAThresholdOfThePrecision) {
  const auto samples = synthetic_samples(1);
  const ConfidenceFit fit = fit_confidence(samples, ConfidenceFitOptions{});
  EXPECT_EQ(fit.right, 300u);
  EXPECT_EQ(fit.wrong, 100u);
  EXPECT_FALSE(fit.cross_validation.empty());
  const auto& signs = confidence_input_signs();
  for (int k = 0; k < kConfidenceInputs; ++k) EXPECT_GE(signs[k] * fit.model.weights[k], 0.0) << k;
  EXPECT_GT(fit.model.weights[2], 0.0);  // coverage carries information
  EXPECT_LT(fit.model.weights[4], 0.0);  // so does the margin
  EXPECT_GE(fit.at_threshold.precision, 0.995);
  EXPECT_GT(fit.at_threshold.recall, 0.5);
  // On new samples of the same kind the model separates the classes.
  size_t right_kept = 0, wrong_kept = 0;
  for (const auto& s : synthetic_samples(2)) {
    const bool kept = fit.model.evaluate(s.features) >= fit.model.threshold;
    (s.right ? right_kept : wrong_kept) += kept;
  }
  EXPECT_GT(right_kept, 200u);
  EXPECT_LE(wrong_kept, 3u);
}

TEST(ConfidenceFit, RejectsDataWithoutBothClasses) {
  auto samples = synthetic_samples(3);
  for (auto& s : samples) s.right = true;
  EXPECT_THROW(fit_confidence(samples, ConfidenceFitOptions{}), Error);
  ConfidenceFitOptions bad;
  bad.target_precision = 0;
  EXPECT_THROW(bad.validate(), Error);
}

LocalizationResult pose_result(const std::string& name, bool registered, const CameraPose& pose, double confidence) {
  LocalizationResult r;
  r.image = name;
  r.registered = registered;
  r.segment = 0;
  r.inliers = 40;
  r.cam_from_segment = pose;
  r.confidence = confidence;
  r.confidence_features.inliers = 40;
  r.uncertainty.valid = true;
  r.uncertainty.position_sigma = 0.1;
  return r;
}

TEST(Evaluation, CountsWrongPosesApartFromMissesAndReadsBackAsSamples) {
  const CameraPose truth = CameraPose::from_matrix(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0));
  const CameraPose near = CameraPose::from_matrix(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.05, 0, 0));
  const CameraPose far = CameraPose::from_matrix(Eigen::Matrix3d::Identity(), Eigen::Vector3d(8, 0, 0));
  std::map<std::string, QueryTruth> t;
  for (const char* n : {"a", "b", "c", "d", "e"}) t[n].cam_from_world = truth;
  std::vector<LocalizationResult> results = {pose_result("a", true, near, 0.99), pose_result("b", true, far, 0.9),
                                             pose_result("c", false, near, 0.2), LocalizationResult{},
                                             pose_result("e", false, far, 0.9)};
  results[3].image = "d";
  results[4].under_street.assessed = results[4].under_street.under_street = true;  // e: above the threshold
  std::vector<LocalizationResult> negatives = {pose_result("/x/n1.jpg", true, far, 0.95),
                                               pose_result("/x/n2.jpg", false, far, 0.1),
                                               pose_result("/x/n3.jpg", false, far, 0.1)};
  negatives[2].under_street.assessed = negatives[2].under_street.under_street = true;  // n3: below it too
  LocalizerOptions lo;
  lo.min_confidence = 0.5;
  const EvaluationReport rep = evaluate(results, t, negatives, lo);
  EXPECT_EQ(rep.queries, 5u);
  EXPECT_EQ(rep.registered, 2u);
  EXPECT_EQ(rep.wrong_positives, 1u);
  EXPECT_EQ(rep.negatives, 3u);
  EXPECT_EQ(rep.negatives_registered, 1u);
  const nlohmann::json j = rep.to_json(results, {});
  EXPECT_EQ(j["wrong_poses"]["total"], 2);
  EXPECT_EQ(j["confidence"]["rejected_right_poses"], 1);  // c: right pose, 40 inliers, confidence 0.2
  EXPECT_EQ(j["confidence"]["rejected_wrong_poses"], 2);  // n2, n3 (below the threshold)
  EXPECT_EQ(j["under_street"]["rejected_wrong_poses"], 1);  // e
  EXPECT_EQ(j["under_street"]["rejected_right_poses"], 0);
  EXPECT_DOUBLE_EQ(j["uncertainty"]["within_1_sigma"].get<double>(), 0.5);  // a within 0.1, b not

  const auto dir = unique_temp_path("visloc_eval_conf");
  write_report(dir, rep, results, {});
  EXPECT_TRUE(std::filesystem::exists(dir / "precision_recall.png"));
  const auto samples = read_confidence_samples(dir / "report.json", WrongPoseRule{});
  ASSERT_EQ(samples.size(), 7u);  // a, b, c, e and the three negatives (d has no pose)
  size_t right = 0;
  for (const auto& s : samples) right += s.right;
  EXPECT_EQ(right, 2u);  // a and c
  const nlohmann::json written = nlohmann::json::parse(read_file(dir / "report.json"));
  size_t marked = 0;
  for (const auto& q : written["per_query"]) marked += q.value("under_street", false);
  EXPECT_EQ(marked, 2u);  // e and n3
  write_file_atomic(dir / "bad.json", "{\"per_query\": 3}");
  EXPECT_THROW(read_confidence_samples(dir / "bad.json", WrongPoseRule{}), Error);
  std::filesystem::remove_all(dir);
}

TEST(ConfidenceFit, SigmaScaleIsThe68thPercentileOfErrorOverSigma) {
  EXPECT_EQ(sigma_scale_for_share({}), 1.0);
  std::vector<double> ratios;
  for (int i = 1; i <= 100; ++i) ratios.push_back(i / 50.0);  // 0.02 ... 2.00
  EXPECT_DOUBLE_EQ(sigma_scale_for_share(ratios), 68 / 50.0);
  EXPECT_DOUBLE_EQ(sigma_scale_for_share(ratios, 0.9), 90 / 50.0);
  EXPECT_DOUBLE_EQ(sigma_scale_for_share({3.0}), 3.0);
  // 0.68 × 150 is 102.00000000000001 in floating point: still the 102nd.
  std::vector<double> distinct;
  for (int i = 1; i <= 150; ++i) distinct.push_back(i);
  EXPECT_DOUBLE_EQ(sigma_scale_for_share(distinct), 102);
  EXPECT_THROW(sigma_scale_for_share(distinct, 0), Error);
  EXPECT_THROW(sigma_scale_for_share(distinct, std::nan("")), Error);
}

// The fit calibrates σ on its right poses at the threshold, and a check
// counts their errors within the model's σ.
TEST(ConfidenceFit, CalibratesSigmaOnTheRightPosesItRegisters) {
  std::vector<ConfidenceSample> samples;
  int right_count = 0;
  for (int i = 0; i < 200; ++i) {
    ConfidenceSample s;
    s.right = i % 4 != 0;
    const int k = s.right ? right_count++ : 0;
    s.features.inliers = s.right ? 60 + i % 30 : 12 + i % 5;
    s.features.coverage = s.right ? 0.5 : 0.1;
    s.features.residual = 0.3;
    s.features.explained = 0.08;
    s.error_over_unscaled_sigma = s.right ? 0.5 + (k % 10) * 0.25 : 30;  // 0.5 ... 2.75
    samples.push_back(s);
  }
  // Right poses with too few inliers to register: their errors do not count.
  for (int i = 0; i < 20; ++i) {
    ConfidenceSample s;
    s.right = true;
    s.features.inliers = 8;
    s.features.coverage = 0.5;
    s.features.residual = 0.3;
    s.features.explained = 0.08;
    s.error_over_unscaled_sigma = 50;
    samples.push_back(s);
  }
  const ConfidenceFit fit = fit_confidence(samples, ConfidenceFitOptions{});
  EXPECT_EQ(fit.sigma_samples, 150u);
  // Right poses' ratios: 15 of each of 0.5, 0.75, ..., 2.75; the 102nd of 150 is 2.0.
  EXPECT_DOUBLE_EQ(fit.model.sigma_scale, 2.0);
  const ConfidenceCheck check = check_confidence(samples, fit.model, 12);
  EXPECT_EQ(check.with_sigma, 150u);
  EXPECT_DOUBLE_EQ(check.within_1_sigma, 0.7);  // ratios up to 2.0: 7 of 10
  EXPECT_DOUBLE_EQ(check.within_2_sigma, 1.0);
}

// A report's σ was its covariance's times its uncertainty.sigma_scale: the
// samples undo it.
TEST(ConfidenceFit, SamplesUndoTheReportsSigmaScale) {
  nlohmann::json q = {{"image", "a"},
                      {"kind", "positive"},
                      {"confidence_features", ConfidenceFeatures{}.to_json()},
                      {"pose_position_error_m", 0.3},
                      {"pose_rotation_error_deg", 1.0},
                      {"position_sigma", 0.2}};
  nlohmann::json report = {{"per_query", {q}}, {"uncertainty", {{"sigma_scale", 1.5}}}};
  const auto dir = unique_temp_path("visloc_sigma_conf");
  std::filesystem::create_directories(dir);
  write_file_atomic(dir / "report.json", report.dump());
  auto samples = read_confidence_samples(dir / "report.json", WrongPoseRule{});
  ASSERT_EQ(samples.size(), 1u);
  EXPECT_DOUBLE_EQ(samples[0].error_over_unscaled_sigma, 0.3 / 0.2 * 1.5);
  report.erase("uncertainty");  // written before sigma_scale: the σ was the covariance's
  write_file_atomic(dir / "report.json", report.dump());
  samples = read_confidence_samples(dir / "report.json", WrongPoseRule{});
  EXPECT_DOUBLE_EQ(samples[0].error_over_unscaled_sigma, 0.3 / 0.2);
  // eval with GPS truth: the error is in metres, so is the σ it is divided by.
  report["per_query"][0]["error_frame"] = "enu";
  report["per_query"][0]["position_sigma_m"] = 0.4;
  write_file_atomic(dir / "report.json", report.dump());
  samples = read_confidence_samples(dir / "report.json", WrongPoseRule{});
  EXPECT_DOUBLE_EQ(samples[0].error_over_unscaled_sigma, 0.3 / 0.4);
  report["uncertainty"] = {{"sigma_scale", -2}};
  write_file_atomic(dir / "report.json", report.dump());
  EXPECT_THROW(read_confidence_samples(dir / "report.json", WrongPoseRule{}), Error);
  std::filesystem::remove_all(dir);
}

// A city benchmark report: every kind of query with a pose is a sample, the
// ones the benchmark does not score ("between", "near_unseen") too, judged by
// the pose's error; foreign photos are wrong whatever their pose.
TEST(ConfidenceFit, ReadsEveryCityQueryKindWithAPose) {
  nlohmann::json features = ConfidenceFeatures{}.to_json();
  auto entry = [&](const char* kind, double error_m) {
    nlohmann::json q = {{"image", kind}, {"kind", kind}, {"confidence_features", features}};
    if (error_m >= 0) q["pose_position_error_m"] = error_m, q["pose_rotation_error_deg"] = 1.0;
    return q;
  };
  nlohmann::json report = {{"per_query",
                            {entry("positive", 0.1), entry("negative", 40), entry("between", 30),
                             entry("near_unseen", 0.2), entry("foreign", -1), entry("positive", -1)}}};
  const auto dir = unique_temp_path("visloc_city_conf");
  std::filesystem::create_directories(dir);
  write_file_atomic(dir / "report.json", report.dump());
  const auto samples = read_confidence_samples(dir / "report.json", WrongPoseRule{});
  ASSERT_EQ(samples.size(), 5u);  // the last positive has no pose error
  const std::vector<bool> right = {true, false, false, true, false};
  for (size_t i = 0; i < samples.size(); ++i) EXPECT_EQ(samples[i].right, right[i]) << i;
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace visloc
