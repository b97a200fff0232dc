#include "visloc/pose/one_many_ransac.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include "visloc/util/random.h"
#include "visloc/pose/solvers/dlt6.h"
#include "visloc/pose/solvers/p3p.h"
#include "visloc/pose/ransac_loop.h"
#include "visloc/pose/sprt.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

std::string_view to_string(RansacVariant variant) {
  switch (variant) {
    case RansacVariant::kClassic11: return "classic";
    case RansacVariant::kOneManyFixed: return "1m-fixed";
    case RansacVariant::kOneManySprt: return "1m-sprt";
  }
  return "unknown";
}

RansacVariant parse_ransac_variant(std::string_view name) {
  if (name == "classic") return RansacVariant::kClassic11;
  if (name == "1m-fixed") return RansacVariant::kOneManyFixed;
  if (name == "1m-sprt") return RansacVariant::kOneManySprt;
  throw_error(ErrorCode::kInvalidArgument, "unknown RANSAC variant '", name,
              "' (expected classic, 1m-fixed or 1m-sprt)");
}

RansacLoopOptions loop_options_for(RansacVariant variant, size_t max_iterations, size_t fixed_iterations,
                                   double confidence, double sprt_delta0) {
  RansacLoopOptions l;
  l.termination = variant == RansacVariant::kClassic11      ? RansacTermination::kClassic
                  : variant == RansacVariant::kOneManyFixed ? RansacTermination::kFixed
                                                            : RansacTermination::kSprtAdaptive;
  l.sprt = variant == RansacVariant::kOneManySprt;
  l.max_iterations = variant == RansacVariant::kOneManyFixed ? fixed_iterations : max_iterations;
  l.confidence = confidence;
  l.sprt_delta0 = sprt_delta0;
  return l;
}

void RansacOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "ransac options: ", field, " ", rule, ", got ", value);
  };
  if (!(threshold_px > 0) || !std::isfinite(threshold_px)) bad("threshold_px", threshold_px, "must be positive");
  if (max_iterations == 0) bad("max_iterations", max_iterations, "must be positive");
  if (fixed_iterations == 0) bad("fixed_iterations", fixed_iterations, "must be positive");
  if (!(confidence > 0 && confidence < 1)) bad("confidence", confidence, "must be in (0, 1)");
  if (!(sprt_delta0 > 0 && sprt_delta0 < 1)) bad("sprt_delta0", sprt_delta0, "must be in (0, 1)");
  if (!(sprt_delta_prior_weight >= 0)) bad("sprt_delta_prior_weight", sprt_delta_prior_weight, "must be >= 0");
  if (!(sprt_model_cost >= 0) || !std::isfinite(sprt_model_cost))
    bad("sprt_model_cost", sprt_model_cost, "must be >= 0 (0 = solver default)");
  if (refine_rounds < 0) bad("refine_rounds", refine_rounds, "must be >= 0");
  if (refine_max_iterations < 0) bad("refine_max_iterations", refine_max_iterations, "must be >= 0");
}

namespace {

using Clock = std::chrono::steady_clock;
double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Squared reprojection error of X under P scaled by w² (no division), or
// a negative value when X is behind the camera: consistent ⇔ 0 ≤ e < thr²·w².
inline bool is_consistent(const Matrix34d& P, const Eigen::Vector3d& X, const Eigen::Vector2d& x, double thr2) {
  const double w = P(2, 0) * X[0] + P(2, 1) * X[1] + P(2, 2) * X[2] + P(2, 3);
  if (w <= 0) return false;
  const double du = P(0, 0) * X[0] + P(0, 1) * X[1] + P(0, 2) * X[2] + P(0, 3) - x[0] * w;
  const double dv = P(1, 0) * X[0] + P(1, 1) * X[1] + P(1, 2) * X[2] + P(1, 3) - x[1] * w;
  return du * du + dv * dv < thr2 * w * w;
}

inline double reprojection_error2(const Matrix34d& P, const Eigen::Vector3d& X, const Eigen::Vector2d& x) {
  const Eigen::Vector3d p = P * X.homogeneous();
  if (p.z() <= 0) return std::numeric_limits<double>::infinity();
  return (p.head<2>() / p.z() - x).squaredNorm();
}

// K [R | t] with K = [[f, 0, o_x], [0, f, o_y], [0, 0, 1]] (o: principal
// point offset from the assumed one).
Matrix34d projection_from_pose(const Eigen::Matrix3d& R, const Eigen::Vector3d& t, double focal,
                               const Eigen::Vector2d& offset = Eigen::Vector2d::Zero()) {
  Matrix34d P;
  P.leftCols<3>() = R;
  P.col(3) = t;
  P.topRows<2>() *= focal;
  P.row(0) += offset.x() * P.row(2);
  P.row(1) += offset.y() * P.row(2);
  return P;
}

// Absolute pose for the RANSAC loop (ransac_loop.h): owns the centred
// points and the hypothesis set (contiguous arrays built once per call).
// Models are 3×4 projections on centred pixels: P3P (s = 3) with a known
// focal length, else the normalized 6-point DLT (s = 6).
class AbsolutePoseEstimator {
 public:
  using Model = Matrix34d;
  static constexpr int kMaxSampleSize = 6;
  static constexpr int kMaxModels = 4;

  AbsolutePoseEstimator(const CorrespondenceSet& corr, const PinholeCamera& camera, double threshold_px,
                        bool one_many)
      : corr_(corr), calibrated_(camera.has_focal), one_many_(one_many), focal_(camera.focal),
        thr2_(threshold_px * threshold_px) {
    const size_t n = corr.num_features();
    centered_.resize(n);
    const Eigen::Vector2d pp(camera.cx, camera.cy);
    for (size_t i = 0; i < n; ++i)
      centered_[i] = calibrated_ ? Eigen::Vector2d(camera.normalize(corr.points2d[i]) * camera.focal)
                                 : Eigen::Vector2d(corr.points2d[i] - pp);
    for (size_t i = 0; i < n; ++i)
      if (corr.in_hypothesis_set[i]) hypothesis_.push_back(static_cast<uint32_t>(i));
    verified_.reserve(64);
  }

  int sample_size() const { return calibrated_ ? 3 : 6; }
  size_t num_hypotheses() const { return hypothesis_.size(); }

  int solve(const uint32_t* sample, Model* models) {
    const uint32_t* off = corr_.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr_.candidates.data();
    if (calibrated_) {
      std::array<Eigen::Vector3d, 3> bearings, world;
      for (int k = 0; k < 3; ++k) {
        const uint32_t f = hypothesis_[sample[k]];
        const Eigen::Vector2d& x = centered_[f];
        bearings[k] = Eigen::Vector3d(x.x() / focal_, x.y() / focal_, 1.0);
        world[k] = cand[off[f]];
      }
      std::array<Matrix34d, 4> solutions;
      const int count = solve_p3p(bearings, world, &solutions);
      for (int m = 0; m < count; ++m) {
        models[m] = solutions[m];
        models[m].topRows<2>() *= focal_;
      }
      return count;
    }
    std::array<Eigen::Vector2d, 6> image;
    std::array<Eigen::Vector3d, 6> world;
    for (int k = 0; k < 6; ++k) {
      const uint32_t f = hypothesis_[sample[k]];
      image[k] = centered_[f];
      world[k] = cand[off[f]];
    }
    return solve_dlt(image.data(), world.data(), 6, &models[0]) ? 1 : 0;
  }

  // ρ_1: hypothesis h's 1-1 match reprojects within the threshold.
  bool hypothesis_consistent(const Model& P, uint32_t h) const {
    const uint32_t f = hypothesis_[h];
    return is_consistent(P, corr_.candidates[corr_.candidate_offsets[f]], centered_[f], thr2_);
  }
  size_t score(const Model& P) const { return one_many_ ? count_one_many(P) : count_one_one(P); }

  // Every verified model's camera centre, principal axis and score: after the
  // loop, the best-supported model that is a different pose gives the margin.
  struct ModelSummary {
    Eigen::Vector3d center, axis;
    size_t score;
  };
  static bool summarize(const Matrix34d& P, size_t score, ModelSummary* out) {
    const Eigen::Matrix3d M = P.leftCols<3>();
    const double det = M.determinant();
    if (!(std::abs(det) > 1e-300)) return false;
    out->center = -M.inverse() * P.col(3);
    out->axis = (det > 0 ? 1.0 : -1.0) * M.row(2).transpose().normalized();
    out->score = score;
    return out->center.allFinite() && out->axis.allFinite();
  }
  void on_verified(const Model& P, size_t score) {
    if (ModelSummary summary; summarize(P, score, &summary)) verified_.push_back(summary);
  }

  // 1-M verification: features with any candidate consistent.
  size_t count_one_many(const Matrix34d& P) const {
    const uint32_t* off = corr_.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr_.candidates.data();
    const size_t n = centered_.size();
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d& x = centered_[i];
      for (uint32_t j = off[i]; j < off[i + 1]; ++j)
        if (is_consistent(P, cand[j], x, thr2_)) {
          ++count;
          break;
        }
    }
    return count;
  }
  // Classical verification: first candidates of the hypothesis set.
  size_t count_one_one(const Matrix34d& P) const {
    const uint32_t* off = corr_.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr_.candidates.data();
    size_t count = 0;
    for (uint32_t f : hypothesis_) count += is_consistent(P, cand[off[f]], centered_[f], thr2_) ? 1 : 0;
    return count;
  }

  const std::vector<Eigen::Vector2d>& centered() const { return centered_; }
  const std::vector<ModelSummary>& verified() const { return verified_; }
  double thr2() const { return thr2_; }

 private:
  const CorrespondenceSet& corr_;
  bool calibrated_, one_many_;
  double focal_, thr2_;
  std::vector<Eigen::Vector2d> centered_;  // pixel − principal point (undistorted if calibrated)
  std::vector<uint32_t> hypothesis_;       // feature ids of the hypothesis set
  std::vector<ModelSummary> verified_;
};

RansacLoopOptions loop_options(const RansacOptions& o, bool calibrated) {
  RansacLoopOptions l = loop_options_for(o.variant, o.max_iterations, o.fixed_iterations, o.confidence, o.sprt_delta0);
  l.sprt_delta_prior_weight = o.sprt_delta_prior_weight;
  l.sprt_model_cost = o.sprt_model_cost > 0 ? o.sprt_model_cost : (calibrated ? 250.0 : 1500.0);
  l.models_per_sample = calibrated ? 1.5 : 1.0;
  return l;
}

// Per feature, the candidate that fits a model best (within the threshold):
// 1-M considers every candidate, classical only the 1-1 match of the
// hypothesis set. Keeps the chosen candidates and the inliers' coordinates.
class CandidateSelection {
 public:
  CandidateSelection(const CorrespondenceSet& corr, const std::vector<Eigen::Vector2d>& centered, double thr2,
                     bool one_many, std::vector<int32_t>* chosen)
      : corr_(corr), centered_(centered), thr2_(thr2), one_many_(one_many), chosen_(chosen) {}

  size_t select(const Matrix34d& P) {
    const uint32_t* off = corr_.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr_.candidates.data();
    std::fill(chosen_->begin(), chosen_->end(), -1);
    image.clear();
    world.clear();
    world_uncertainty.clear();
    for (size_t i = 0; i < centered_.size(); ++i) {
      if (!one_many_ && !corr_.in_hypothesis_set[i]) continue;
      const uint32_t end = one_many_ ? off[i + 1] : off[i] + 1;
      double best_e = thr2_;
      int32_t best_j = -1;
      for (uint32_t j = off[i]; j < end; ++j) {
        const double e = reprojection_error2(P, cand[j], centered_[i]);
        if (e < best_e) {
          best_e = e;
          best_j = static_cast<int32_t>(j - off[i]);
        }
      }
      if (best_j >= 0) {
        (*chosen_)[i] = best_j;
        image.push_back(centered_[i]);
        world.push_back(cand[off[i] + best_j]);
        if (!corr_.candidate_uncertainty.empty())
          world_uncertainty.push_back(corr_.candidate_uncertainty[off[i] + best_j]);
      }
    }
    return image.size();
  }
  void clear() { std::fill(chosen_->begin(), chosen_->end(), -1); }

  std::vector<Eigen::Vector2d> image;  // the inliers' centred pixels
  std::vector<Eigen::Vector3d> world;  // their chosen points
  std::vector<PointUncertaintyCode> world_uncertainty;  // and those points' uncertainty, when the set has it

 private:
  const CorrespondenceSet& corr_;
  const std::vector<Eigen::Vector2d>& centered_;
  double thr2_;
  bool one_many_;
  std::vector<int32_t>* chosen_;
};

struct RefinedPose {
  CameraPose pose;
  double focal = 0;
  Eigen::Vector2d principal_point_offset = Eigen::Vector2d::Zero();
  bool principal_point_refined = false;
  double principal_point_prior_px = 0;
  size_t inliers = 0;
  int iterations = 0;
};

// Levenberg-Marquardt on the inliers (pose_refinement.h), then the
// candidates re-selected with the refined pose, `refine_rounds` times. An
// unknown camera's principal point is refined too once there are enough
// inliers to see it, under a prior of 3% of the image size.
RefinedPose refine_on_inliers(CandidateSelection& inliers, const PinholeCamera& camera, const RansacOptions& options,
                              const CameraPose& pose, double focal, size_t num_inliers) {
  constexpr size_t kMinInliersForPrincipalPoint = 50;
  const bool calibrated = camera.has_focal;
  RefinedPose out;
  out.pose = pose;
  out.focal = focal;
  out.inliers = num_inliers;
  out.principal_point_prior_px = 0.03 * std::max<double>(std::max(camera.width, camera.height), 100);
  if (!options.refine) return out;
  RefinementOptions ro;
  ro.loss_scale_px = options.threshold_px;
  ro.max_iterations = options.refine_max_iterations;
  ro.refine_focal = !calibrated;
  ro.principal_point_prior_px = out.principal_point_prior_px;
  for (int round = 0; round < options.refine_rounds; ++round) {
    if (inliers.image.size() < (calibrated ? 3u : 4u)) break;
    ro.refine_principal_point =
        options.refine_principal_point && !calibrated && inliers.image.size() >= kMinInliersForPrincipalPoint;
    const RefinementResult rr = refine_pose(inliers.image.data(), inliers.world.data(), inliers.image.size(), out.pose,
                                            out.focal, ro, out.principal_point_offset);
    out.iterations += rr.iterations;
    if (!rr.success) break;
    out.pose = rr.cam_from_world;
    out.focal = rr.focal;
    out.principal_point_offset = rr.principal_point_offset;
    out.principal_point_refined = out.principal_point_refined || ro.refine_principal_point;
    out.inliers = inliers.select(
        projection_from_pose(out.pose.rotation_matrix(), out.pose.translation, out.focal, out.principal_point_offset));
  }
  return out;
}

// The pose's evidence on its final inliers: 1-1 inlier ratio, residuals,
// image coverage (8×8 grid), depth range and the covariance.
PoseQuality measure_quality(const AbsolutePoseEstimator& estimator, const CandidateSelection& inliers,
                            const PinholeCamera& camera, const CameraPose& pose, double focal,
                            const Eigen::Vector2d& pp_offset, double threshold_px, double pp_prior_px) {
  const Matrix34d P = projection_from_pose(pose.rotation_matrix(), pose.translation, focal, pp_offset);
  PoseQuality q;
  q.hypothesis_features = estimator.num_hypotheses();
  q.hypothesis_inliers = estimator.count_one_one(P);
  std::vector<double> residuals, depths;
  residuals.reserve(inliers.image.size());
  depths.reserve(inliers.image.size());
  const Eigen::Matrix3d R = pose.rotation_matrix();
  constexpr int kGrid = 8;
  std::array<bool, kGrid * kGrid> occupied{};
  const double w = std::max<double>(1, static_cast<double>(camera.width));
  const double h = std::max<double>(1, static_cast<double>(camera.height));
  const double y_to_pixels = camera.has_focal ? camera.aspect : 1.0;
  for (size_t k = 0; k < inliers.image.size(); ++k) {
    residuals.push_back(std::sqrt(reprojection_error2(P, inliers.world[k], inliers.image[k])));
    depths.push_back((R * inliers.world[k] + pose.translation).z());
    // Calibrated, the centred points are normalized coordinates times fx: y
    // goes back to pixels by fy / fx.
    const double u = inliers.image[k].x() + camera.cx, v = inliers.image[k].y() * y_to_pixels + camera.cy;
    const int gx = std::clamp(static_cast<int>(u / w * kGrid), 0, kGrid - 1);
    const int gy = std::clamp(static_cast<int>(v / h * kGrid), 0, kGrid - 1);
    occupied[gy * kGrid + gx] = true;
    q.inlier_cells |= uint64_t(1) << (gy * kGrid + gx);
  }
  if (!residuals.empty()) {
    std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
    q.median_residual_px = residuals[residuals.size() / 2];
    std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
    q.inlier_depth_median = std::abs(depths[depths.size() / 2]);
    const size_t p90 = (9 * depths.size() + 9) / 10 - 1;  // nearest rank: the ⌈0.9 n⌉-th smallest
    std::nth_element(depths.begin(), depths.begin() + p90, depths.end());
    q.inlier_depth_p90 = depths[p90];
  }
  q.coverage = static_cast<double>(std::count(occupied.begin(), occupied.end(), true)) / (kGrid * kGrid);
  std::vector<Eigen::Matrix3d> point_covariances;
  if (!inliers.world_uncertainty.empty()) {
    point_covariances.reserve(inliers.world_uncertainty.size());
    for (const PointUncertaintyCode& c : inliers.world_uncertainty)
      point_covariances.push_back(decode_point_covariance(c));
  }
  q.covariance = pose_covariance(inliers.image.data(), inliers.world.data(), inliers.image.size(), pose, focal,
                                 threshold_px, !camera.has_focal, pp_offset, pp_prior_px,
                                 point_covariances.empty() ? nullptr : point_covariances.data());
  return q;
}

// The strongest rival: the best score of a verified model whose camera is
// elsewhere (farther than 10% of the inliers' median depth, `depth`) or looks
// elsewhere (> 10°) than both the final pose and the best model itself
// (6-point DLT models scatter: a copy of the best one is no rival).
size_t rival_score(const AbsolutePoseEstimator& estimator, double depth, const CameraPose& pose,
                   const Matrix34d& best_model, size_t best_score) {
  using ModelSummary = AbsolutePoseEstimator::ModelSummary;
  const Eigen::Vector3d c = pose.center(), a = pose.viewing_direction();
  const double cos_limit = std::cos(10.0 * M_PI / 180.0);
  auto differs = [&](const ModelSummary& m, const Eigen::Vector3d& centre, const Eigen::Vector3d& axis) {
    return (m.center - centre).norm() > 0.1 * depth || m.axis.dot(axis) < cos_limit;
  };
  ModelSummary best_summary;
  const bool have_best = AbsolutePoseEstimator::summarize(best_model, best_score, &best_summary);
  size_t rival = 0;
  for (const ModelSummary& m : estimator.verified())
    if (differs(m, c, a) && (!have_best || differs(m, best_summary.center, best_summary.axis)))
      rival = std::max(rival, m.score);
  return rival;
}

}  // namespace

PoseEstimate estimate_pose(const CorrespondenceSet& corr, const PinholeCamera& camera, const RansacOptions& options) {
  const auto t_start = Clock::now();
  options.validate();
  corr.validate();
  if (camera.has_focal && !(camera.focal > 0 && std::isfinite(camera.focal)))
    throw_error(ErrorCode::kInvalidArgument, "camera: focal must be a positive number, got ", camera.focal);

  PoseEstimate result;
  const size_t n = corr.num_features();
  const bool calibrated = camera.has_focal;
  const int s = calibrated ? 3 : 6;
  const bool one_many = options.variant != RansacVariant::kClassic11;
  RansacStatistics& st = result.stats;
  st.num_features = n;
  st.sample_size = s;
  result.chosen_candidate.assign(n, -1);
  result.focal = calibrated ? camera.focal : 0.0;

  AbsolutePoseEstimator estimator(corr, camera, options.threshold_px, one_many);
  const size_t nh = estimator.num_hypotheses();
  st.hypothesis_features = nh;
  if (nh < static_cast<size_t>(s)) {
    st.total_ms = ms_between(t_start, Clock::now());
    return result;
  }
  RandomGenerator rng(options.seed);
  const RansacLoopResult<Matrix34d> loop = run_ransac(estimator, loop_options(options, calibrated), rng);
  st.iterations = loop.stats.iterations;
  st.models = loop.stats.models;
  st.models_rejected_sprt = loop.stats.models_rejected_sprt;
  st.models_verified = loop.stats.models_verified;
  st.best_iteration = loop.stats.best_iteration;
  st.final_epsilon = loop.stats.final_epsilon;
  st.final_delta = loop.stats.final_delta;
  st.final_threshold = loop.stats.final_threshold;
  st.expected_samples = loop.stats.expected_samples;
  st.hypothesis_ms = loop.stats.hypothesis_ms;
  st.verification_ms = loop.stats.verification_ms;
  Matrix34d best_model = loop.best;
  const size_t best_score = loop.best_score;
  if (best_score == 0) {
    st.total_ms = ms_between(t_start, Clock::now());
    return result;
  }
  // Refinement: choose per feature the candidate that fits, refine, re-select.
  const auto t_refine = Clock::now();
  CandidateSelection inliers(corr, estimator.centered(), estimator.thr2(), one_many, &result.chosen_candidate);
  st.ransac_inliers = inliers.select(best_model);
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  double focal = camera.focal;
  if (calibrated) {
    R = best_model.leftCols<3>();
    R.topRows<2>() /= focal;
    t = best_model.col(3);
    t.head<2>() /= focal;
  } else {
    // Linear re-estimation on all inliers of the best model (the minimal
    // 6-point DLT is noisy), then decomposition into f, R, t.
    Matrix34d P_all;
    if (inliers.image.size() >= 12 &&
        solve_dlt(inliers.image.data(), inliers.world.data(), static_cast<int>(inliers.image.size()), &P_all) &&
        estimator.score(P_all) >= st.ransac_inliers)
      best_model = P_all;
    st.ransac_inliers = inliers.select(best_model);
    DecomposedProjection dec;
    if (!decompose_projection(best_model, &dec)) {
      st.refinement_ms = ms_between(t_refine, Clock::now());
      st.total_ms = ms_between(t_start, Clock::now());
      inliers.clear();
      return result;
    }
    R = dec.rotation;
    t = dec.translation;
    focal = dec.focal;
  }
  CameraPose pose = CameraPose::from_matrix(R, t);
  // Without refinement the inliers are those of the pose itself; with it, the
  // first round starts from the best model's inliers (selected above).
  size_t num_inliers = options.refine && options.refine_rounds > 0
                           ? st.ransac_inliers
                           : inliers.select(projection_from_pose(pose.rotation_matrix(), pose.translation, focal));
  const RefinedPose refined = refine_on_inliers(inliers, camera, options, pose, focal, num_inliers);
  st.refine_iterations += refined.iterations;
  pose = refined.pose;
  focal = refined.focal;
  num_inliers = refined.inliers;
  const Eigen::Vector2d pp_offset = refined.principal_point_offset;
  const double pp_prior_px = refined.principal_point_prior_px;
  const bool pp_refined = refined.principal_point_refined;
  result.quality = measure_quality(estimator, inliers, camera, pose, focal, pp_offset, options.threshold_px,
                                   pp_refined ? pp_prior_px : 0.0);
  result.quality.best_score = best_score;
  result.quality.rival_score = rival_score(estimator, result.quality.inlier_depth_median, pose, best_model, best_score);
  result.principal_point_offset = pp_offset;
  st.refinement_ms = ms_between(t_refine, Clock::now());
  result.has_pose = true;
  result.cam_from_world = pose;
  result.focal = focal;
  result.num_inliers = num_inliers;
  result.registered = num_inliers >= options.min_inliers;
  st.total_ms = ms_between(t_start, Clock::now());
  return result;
}

}  // namespace visloc
