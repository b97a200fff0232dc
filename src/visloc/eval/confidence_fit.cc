#include "visloc/eval/confidence_fit.h"

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <numeric>
#include <ostream>
#include <sstream>

#include "visloc/eval/plot.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {

void ConfidenceFitOptions::validate() const {
  if (std::isnan(l2) || !std::isfinite(l2))
    throw_error(ErrorCode::kInvalidArgument, "confidence fit: l2 must be a number (< 0: chosen by cross-validation)");
  if (!(target_precision > 0 && target_precision <= 1))
    throw_error(ErrorCode::kInvalidArgument, "confidence fit: target_precision must be in (0, 1]");
  if (!(min_inliers >= 0) || !std::isfinite(min_inliers))
    throw_error(ErrorCode::kInvalidArgument, "confidence fit: min_inliers must be >= 0");
}

std::vector<ConfidenceSample> read_confidence_samples(const std::filesystem::path& path, const WrongPoseRule& rule) {
  nlohmann::json report;
  try {
    report = nlohmann::json::parse(read_file(path));
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, path.string(), ": not JSON: ", e.what());
  }
  if (!report.is_object() || !report.contains("per_query") || !report["per_query"].is_array())
    throw_error(ErrorCode::kFormat, path.string(), ": no per_query array (a report.json of bench city or eval)");
  std::vector<ConfidenceSample> samples;
  try {
    // The σ in the report is the covariance's times this (1 before it existed).
    double report_sigma_scale = 1;
    if (report.contains("uncertainty") && report["uncertainty"].is_object())
      report_sigma_scale = report["uncertainty"].value("sigma_scale", 1.0);
    if (!(report_sigma_scale > 0) || !std::isfinite(report_sigma_scale))
      throw_error(ErrorCode::kFormat, path.string(), ": uncertainty.sigma_scale must be a positive number");
    for (const auto& q : report["per_query"]) {
      if (!q.is_object() || !q.contains("confidence_features")) continue;  // no pose
      const std::string kind = q.value("kind", std::string(q.value("negative", false) ? "negative_listed" : "query"));
      // Every pose with a truth is a sample, judged by its error. That includes
      // the city benchmark's "between" and "near_unseen" queries: it does not
      // score them, since whether they should register is open, but a pose
      // they return is right or wrong all the same, and queries just past a
      // mapped street's end (the KITTI hard split's wrong poses, 16-18 m past
      // the last mapped frame) are "between".
      ConfidenceSample s;
      try {
        s.features = ConfidenceFeatures::from_json(q["confidence_features"]);
      } catch (const Error& e) {
        throw_error(ErrorCode::kFormat, path.string(), ": ", q.value("image", std::string("?")), ": ", e.what());
      }
      if (kind == "foreign" || kind == "negative_listed") {
        s.right = false;  // these must not register at all
      } else {
        const auto pos = q.find("pose_position_error_m");
        if (pos == q.end() || !pos->is_number()) continue;  // no truth to judge the pose by
        const auto rot = q.find("pose_rotation_error_deg");
        const double rot_err = rot != q.end() && rot->is_number() ? rot->get<double>() : 0.0;
        s.right = pos->get<double>() <= rule.position_m && rot_err <= rule.rotation_deg;
        // σ in the units of the pose error: the segment's, or metres when eval
        // judged the pose by GPS truth (error_frame "enu").
        const auto sigma =
            q.find(q.value("error_frame", std::string("segment")) == "enu" ? "position_sigma_m" : "position_sigma");
        const double scale = q.value("sigma_scale", report_sigma_scale);
        if (!(scale > 0) || !std::isfinite(scale))
          throw_error(ErrorCode::kFormat, path.string(), ": ", q.value("image", std::string("?")),
                      ": sigma_scale must be a positive number");
        if (sigma != q.end() && sigma->is_number() && sigma->get<double>() > 0)
          s.error_over_unscaled_sigma = pos->get<double>() / sigma->get<double>() * scale;
        s.map_point_uncertainty = q.value("map_point_uncertainty", false);
      }
      samples.push_back(s);
    }
  } catch (const nlohmann::json::exception& e) {
    throw_error(ErrorCode::kFormat, path.string(), ": bad per_query entry: ", e.what());
  }
  return samples;
}

std::vector<PrecisionRecallPoint> precision_recall_curve(const std::vector<double>& scores,
                                                        const std::vector<bool>& right, size_t positives) {
  std::vector<size_t> order(scores.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return scores[a] > scores[b]; });
  std::vector<PrecisionRecallPoint> curve;
  size_t accepted = 0, accepted_right = 0;
  for (size_t k = 0; k < order.size(); ++k) {
    ++accepted;
    accepted_right += right[order[k]] ? 1 : 0;
    if (k + 1 < order.size() && scores[order[k + 1]] == scores[order[k]]) continue;  // ties accepted together
    PrecisionRecallPoint p;
    p.threshold = scores[order[k]];
    p.accepted = accepted;
    p.accepted_right = accepted_right;
    p.precision = double(accepted_right) / double(accepted);
    p.recall = positives ? double(accepted_right) / double(positives) : 0.0;
    curve.push_back(p);
  }
  return curve;
}

double sigma_scale_for_share(std::vector<double> error_over_sigma, double share) {
  if (!(share > 0 && share <= 1))
    throw_error(ErrorCode::kInvalidArgument, "sigma scale: the share must be in (0, 1], got ", share);
  if (error_over_sigma.empty()) return 1;
  // Nearest rank ceil(share n); the epsilon keeps 0.68 × 150 = 102.00000000000001 at 102.
  const size_t rank = static_cast<size_t>(std::ceil(share * static_cast<double>(error_over_sigma.size()) - 1e-9));
  const size_t k = std::clamp<size_t>(rank, 1, error_over_sigma.size()) - 1;
  std::nth_element(error_over_sigma.begin(), error_over_sigma.begin() + static_cast<std::ptrdiff_t>(k),
                   error_over_sigma.end());
  return std::max(error_over_sigma[k], 1e-9);
}

double threshold_for_precision(const std::vector<PrecisionRecallPoint>& curve, double target) {
  double threshold = 1.0;
  for (const auto& p : curve)
    if (p.precision >= target) threshold = std::min(threshold, p.threshold);
  return threshold;
}

namespace {

// Weighted logistic regression by Newton's method on standardized inputs;
// `active` selects the inputs used. Returns (bias, weights) on raw inputs.
std::pair<double, Eigen::VectorXd> fit_logistic(const Eigen::MatrixXd& X, const Eigen::VectorXd& y,
                                                const Eigen::VectorXd& weight, const std::vector<int>& active,
                                                double l2) {
  const Eigen::Index n = X.rows();
  const Eigen::Index d = static_cast<Eigen::Index>(active.size());
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(d), scale = Eigen::VectorXd::Ones(d);
  Eigen::MatrixXd Z(n, d + 1);
  Z.col(0).setOnes();
  for (Eigen::Index k = 0; k < d; ++k) {
    const Eigen::VectorXd c = X.col(active[k]);
    mean[k] = c.mean();
    const double sd = std::sqrt((c.array() - mean[k]).square().mean());
    scale[k] = sd > 1e-12 ? sd : 1.0;
    // A constant input (e.g. one that reports older than it give its
    // default): a zero column, so that rounding in the mean cannot give it a
    // tiny weight of either sign.
    if (sd > 1e-12)
      Z.col(k + 1) = (c.array() - mean[k]) / scale[k];
    else
      Z.col(k + 1).setZero();
  }
  Eigen::VectorXd beta = Eigen::VectorXd::Zero(d + 1);
  for (int it = 0; it < 100; ++it) {
    const Eigen::VectorXd p = ((-(Z * beta)).array().exp() + 1.0).inverse().matrix();
    Eigen::VectorXd g = Z.transpose() * (weight.array() * (p - y).array()).matrix();
    Eigen::MatrixXd H = Z.transpose() * (weight.array() * p.array() * (1 - p.array())).matrix().asDiagonal() * Z;
    for (Eigen::Index k = 1; k <= d; ++k) {
      g[k] += l2 * beta[k];
      H(k, k) += l2;
    }
    H.diagonal().array() += 1e-9;
    const Eigen::VectorXd step = H.ldlt().solve(g);
    if (!step.allFinite()) break;
    beta -= step;
    if (step.norm() < 1e-10) break;
  }
  Eigen::VectorXd w = Eigen::VectorXd::Zero(X.cols());
  double bias = beta[0];
  for (Eigen::Index k = 0; k < d; ++k) {
    w[active[k]] = beta[k + 1] / scale[k];
    bias -= beta[k + 1] * mean[k] / scale[k];
  }
  return {bias, w};
}

}  // namespace

namespace {

// Logistic fit kept monotone: drops, one at a time, the input whose weight is
// most against its expected sign (the others can change sign once it is
// gone) and refits. Returns (bias, weights) and the dropped inputs.
std::pair<double, Eigen::VectorXd> fit_monotone(const Eigen::MatrixXd& X, const Eigen::VectorXd& y,
                                                const Eigen::VectorXd& weight, double l2,
                                                std::vector<std::string>* dropped) {
  std::vector<int> active(kConfidenceInputs);
  std::iota(active.begin(), active.end(), 0);
  const auto& signs = confidence_input_signs();
  for (;;) {
    auto model = fit_logistic(X, y, weight, active, l2);
    int worst = -1;
    double worst_value = 0;
    for (int k : active) {
      const double against = -signs[k] * model.second[k] * std::sqrt(X.col(k).array().square().mean());
      if (against > worst_value) {
        worst_value = against;
        worst = k;
      }
    }
    if (worst < 0) return model;
    if (dropped) dropped->push_back(confidence_input_names()[worst]);
    active.erase(std::find(active.begin(), active.end(), worst));
  }
}

Eigen::MatrixXd rows(const Eigen::MatrixXd& m, const std::vector<Eigen::Index>& idx) {
  Eigen::MatrixXd out(static_cast<Eigen::Index>(idx.size()), m.cols());
  for (size_t i = 0; i < idx.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = m.row(idx[i]);
  return out;
}

}  // namespace

ConfidenceFit fit_confidence(const std::vector<ConfidenceSample>& samples, const ConfidenceFitOptions& options) {
  options.validate();
  ConfidenceFit fit;
  fit.samples = samples.size();
  for (const auto& s : samples) (s.right ? fit.right : fit.wrong)++;
  if (fit.right < 5 || fit.wrong < 5)
    throw_error(ErrorCode::kInvalidArgument, "confidence fit: needs at least 5 right and 5 wrong poses, got ",
                fit.right, " right and ", fit.wrong, " wrong");
  const Eigen::Index n = static_cast<Eigen::Index>(samples.size());
  Eigen::MatrixXd X(n, kConfidenceInputs);
  Eigen::VectorXd y(n), weight(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto x = confidence_inputs(samples[i].features);
    for (int k = 0; k < kConfidenceInputs; ++k) X(i, k) = x[k];
    y[i] = samples[i].right ? 1 : 0;
    // Both classes weigh as much in all (the wrong poses are rare).
    weight[i] = samples[i].right ? 0.5 * n / double(fit.right) : 0.5 * n / double(fit.wrong);
  }
  // The penalty: given, or the candidate with the smallest weighted log loss
  // in 5-fold cross-validation (folds by sample index, classes interleaved).
  fit.l2 = options.l2;
  if (options.l2 < 0) {
    constexpr int kFolds = 5;
    double best_loss = INFINITY;
    for (double l2 : {0.01, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0}) {
      double loss = 0;
      for (int fold = 0; fold < kFolds; ++fold) {
        std::vector<Eigen::Index> train, test;
        for (Eigen::Index i = 0; i < n; ++i) (i % kFolds == fold ? test : train).push_back(i);
        Eigen::VectorXd y_train(static_cast<Eigen::Index>(train.size())), w_train(y_train.size());
        for (size_t i = 0; i < train.size(); ++i) {
          y_train[static_cast<Eigen::Index>(i)] = y[train[i]];
          w_train[static_cast<Eigen::Index>(i)] = weight[train[i]];
        }
        const auto m = fit_monotone(rows(X, train), y_train, w_train, l2, nullptr);
        for (Eigen::Index i : test) {
          const double z = m.first + X.row(i).dot(m.second);
          const double p = std::clamp(1.0 / (1.0 + std::exp(-z)), 1e-9, 1 - 1e-9);
          loss -= weight[i] * (y[i] > 0.5 ? std::log(p) : std::log(1 - p));
        }
      }
      fit.cross_validation.push_back({l2, loss / double(n)});
      if (loss < best_loss) {
        best_loss = loss;
        fit.l2 = l2;
      }
    }
  }
  const std::pair<double, Eigen::VectorXd> model = fit_monotone(X, y, weight, fit.l2, &fit.dropped_inputs);
  fit.model.bias = model.first;
  for (int k = 0; k < kConfidenceInputs; ++k) fit.model.weights[k] = model.second[k];

  std::vector<double> scores;
  std::vector<bool> right;
  for (const auto& s : samples)
    if (s.features.inliers >= options.min_inliers) {
      scores.push_back(fit.model.evaluate(s.features));
      right.push_back(s.right);
    }
  fit.threshold_samples = scores.size();
  const size_t positives = static_cast<size_t>(std::count(right.begin(), right.end(), true));
  const auto curve = precision_recall_curve(scores, right, positives);
  fit.model.threshold = threshold_for_precision(curve, options.target_precision);
  for (const auto& p : curve)
    if (p.threshold >= fit.model.threshold) fit.at_threshold = p;
  // σ: calibrated on the poses the model registers and gets right.
  fit.model.sigma_scale = fit.model.sigma_scale_with_point_uncertainty = 1;
  std::array<size_t, 2> counts{};
  fit.model = fit_sigma_scales(samples, fit.model, options.min_inliers, &counts);
  fit.sigma_samples = counts[0];
  fit.sigma_samples_with_point_uncertainty = counts[1];
  return fit;
}

ConfidenceModel fit_sigma_scales(const std::vector<ConfidenceSample>& samples, const ConfidenceModel& model,
                                 double min_inliers, std::array<size_t, 2>* counts) {
  std::array<std::vector<double>, 2> ratios;
  for (const auto& s : samples)
    if (s.right && s.error_over_unscaled_sigma >= 0 && s.features.inliers >= min_inliers &&
        model.evaluate(s.features) >= model.threshold)
      ratios[s.map_point_uncertainty ? 1 : 0].push_back(s.error_over_unscaled_sigma);
  ConfidenceModel out = model;
  if (!ratios[0].empty()) out.sigma_scale = sigma_scale_for_share(ratios[0]);
  if (!ratios[1].empty()) out.sigma_scale_with_point_uncertainty = sigma_scale_for_share(ratios[1]);
  if (counts) *counts = {ratios[0].size(), ratios[1].size()};
  return out;
}

nlohmann::json ConfidenceFit::to_json() const {
  nlohmann::json cv = nlohmann::json::array();
  for (const auto& [l2_value, loss] : cross_validation) cv.push_back({{"l2", l2_value}, {"log_loss", loss}});
  return {{"model", model.to_json()},
          {"l2", l2},
          {"cross_validation", cv},
          {"samples", samples},
          {"right_poses", right},
          {"wrong_poses", wrong},
          {"threshold_samples", threshold_samples},
          {"sigma_samples", sigma_samples},
          {"sigma_samples_with_point_uncertainty", sigma_samples_with_point_uncertainty},
          {"dropped_inputs", dropped_inputs},
          {"at_threshold",
           {{"precision", at_threshold.precision},
            {"recall", at_threshold.recall},
            {"accepted", at_threshold.accepted},
            {"accepted_right", at_threshold.accepted_right}}}};
}

void plot_precision_recall(const std::filesystem::path& stem, const std::string& title,
                           const std::vector<PrecisionRecallPoint>& curve, double threshold) {
  Plot plot(title, "recall (right poses / positives)", "precision", 0, 1, 0, 1);
  double prev_r = 0, prev_p = 1;
  bool first = true;
  for (const auto& p : curve) {
    if (!first) plot.line(prev_r, prev_p, p.recall, p.precision, "#1f77b4", {180, 119, 31}, 2);
    first = false;
    prev_r = p.recall;
    prev_p = p.precision;
  }
  // The chosen threshold: the last point at or above it.
  const PrecisionRecallPoint* mark = nullptr;
  for (const auto& p : curve)
    if (p.threshold >= threshold) mark = &p;
  if (mark) {
    plot.point(mark->recall, mark->precision, "#d62728", {40, 39, 214}, 5);
    plot.label(mark->recall, mark->precision, "threshold " + Plot::fmt(threshold), -60, -10);
  }
  plot.save(stem);
}

nlohmann::json ConfidenceCheck::to_json() const {
  return {{"poses_with_min_inliers", poses_with_min_inliers},
          {"right_poses_registered", right_registered},
          {"right_poses_lost", right_lost},
          {"wrong_poses_registered", wrong_registered},
          {"threshold", threshold},
          {"sigma_scale", sigma_scale},
          {"sigma_scale_with_point_uncertainty", sigma_scale_with_point_uncertainty},
          {"right_poses_registered_with_sigma", with_sigma},
          {"within_1_sigma", within_1_sigma},
          {"within_2_sigma", within_2_sigma}};
}

ConfidenceCheck check_confidence(const std::vector<ConfidenceSample>& samples, const ConfidenceModel& model,
                                 double min_inliers) {
  ConfidenceCheck out;
  out.threshold = model.threshold;
  out.sigma_scale = model.sigma_scale;
  out.sigma_scale_with_point_uncertainty = model.sigma_scale_with_point_uncertainty;
  std::vector<double> scores;
  std::vector<bool> right;
  for (const auto& s : samples) {
    if (s.features.inliers < min_inliers) continue;
    const double c = model.evaluate(s.features);
    scores.push_back(c);
    right.push_back(s.right);
    const bool accepted = c >= model.threshold;
    if (s.right) (accepted ? out.right_registered : out.right_lost)++;
    else if (accepted) ++out.wrong_registered;
    if (s.right && accepted && s.error_over_unscaled_sigma >= 0) {
      const double z = s.error_over_unscaled_sigma / model.sigma_scale_for(s.map_point_uncertainty);
      ++out.with_sigma;
      out.within_1_sigma += z <= 1;
      out.within_2_sigma += z <= 2;
    }
  }
  if (out.with_sigma) {
    out.within_1_sigma /= static_cast<double>(out.with_sigma);
    out.within_2_sigma /= static_cast<double>(out.with_sigma);
  }
  out.poses_with_min_inliers = scores.size();
  out.curve = precision_recall_curve(scores, right, out.right_registered + out.right_lost);
  return out;
}

std::string confidence_model_code(const ConfidenceModel& model) {
  std::ostringstream code;
  code << std::setprecision(17) << "    m.bias = " << model.bias << ";\n";
  for (int k = 0; k < kConfidenceInputs; ++k)
    code << "    m.weights[" << k << "] = " << model.weights[k] << ";  // " << confidence_input_names()[k] << "\n";
  code << "    threshold " << model.threshold << "\n";
  code << "    m.sigma_scale = " << model.sigma_scale << ";\n";
  code << "    m.sigma_scale_with_point_uncertainty = " << model.sigma_scale_with_point_uncertainty << ";\n";
  return code.str();
}

void ConfidenceBenchmarkOptions::validate() const {
  fit_options.validate();
  if (!(rule.position_m > 0) || !(rule.rotation_deg > 0))
    throw_error(ErrorCode::kInvalidArgument, "bench confidence: --wrong-position and --wrong-rotation must be > 0");
  if (fit && !model_file.empty())
    throw_error(ErrorCode::kInvalidArgument, "bench confidence: --fit and --model exclude each other");
  if (fit && fit_sigma)
    throw_error(ErrorCode::kInvalidArgument, "bench confidence: --fit and --fit-sigma exclude each other");
}

void run_confidence_benchmark(const ConfidenceBenchmarkOptions& o, std::ostream& out, std::ostream& log) {
  o.validate();
  std::vector<ConfidenceSample> samples;
  for (const auto& r : o.reports) {
    const auto s = read_confidence_samples(r, o.rule);
    log << "bench confidence: " << r << ": " << s.size() << " poses\n";
    samples.insert(samples.end(), s.begin(), s.end());
  }
  std::filesystem::create_directories(o.out_dir);
  ConfidenceModel model = ConfidenceModel::builtin();
  nlohmann::json summary;
  if (o.fit) {
    const ConfidenceFit fit = fit_confidence(samples, o.fit_options);
    model = fit.model;
    summary = fit.to_json();
    write_file_atomic(o.out_dir / "model.json", model.to_json().dump(2));
    out << "Fitted model (C++ for ConfidenceModel::builtin):\n" << confidence_model_code(model);
  } else if (!o.model_file.empty()) {
    try {
      model = ConfidenceModel::from_json(nlohmann::json::parse(read_file(o.model_file)));
    } catch (const nlohmann::json::exception& e) {
      throw_error(ErrorCode::kFormat, o.model_file.string(), ": not JSON: ", e.what());
    } catch (const Error& e) {
      throw_error(ErrorCode::kFormat, o.model_file.string(), ": ", e.what());
    }
  }
  if (o.fit_sigma) {
    std::array<size_t, 2> counts{};
    model = fit_sigma_scales(samples, model, o.fit_options.min_inliers, &counts);
    summary["sigma_fit"] = {{"right_poses_without_point_uncertainty", counts[0]},
                            {"right_poses_with_point_uncertainty", counts[1]},
                            {"sigma_scale", model.sigma_scale},
                            {"sigma_scale_with_point_uncertainty", model.sigma_scale_with_point_uncertainty}};
    write_file_atomic(o.out_dir / "model.json", model.to_json().dump(2));
    out << "Fitted sigma scales (" << counts[0] << " and " << counts[1]
        << " right poses at the threshold without and with the map points' uncertainty; a group without one "
           "keeps the model's):\n"
        << confidence_model_code(model);
  }
  // Precision and recall of the model on these poses (registered: ≥ min_inliers).
  const ConfidenceCheck check = check_confidence(samples, model, o.fit_options.min_inliers);
  plot_precision_recall(o.out_dir / "precision_recall", o.fit ? "Confidence (fit)" : "Confidence (check)", check.curve,
                        model.threshold);
  summary["checked"] = check.to_json();
  write_file_atomic(o.out_dir / (o.fit ? "fit.json" : "check.json"), summary.dump(2));
  out << "Poses with >= " << o.fit_options.min_inliers << " inliers: " << check.poses_with_min_inliers
      << "; at confidence >= " << model.threshold << ": " << check.right_registered << " right registered, "
      << check.right_lost << " right lost, " << check.wrong_registered << " wrong registered. σ (scale "
      << model.sigma_scale << ", " << model.sigma_scale_with_point_uncertainty
      << " with the map points' uncertainty): of " << check.with_sigma << " right poses registered with one, "
      << check.within_1_sigma << " within 1σ, " << check.within_2_sigma << " within 2σ.\n";
}

}  // namespace visloc
