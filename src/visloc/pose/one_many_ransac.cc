#include "visloc/pose/one_many_ransac.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include "visloc/util/random.h"
#include "visloc/pose/solvers/dlt6.h"
#include "visloc/pose/solvers/p3p.h"
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

// The data of one estimation: contiguous arrays built once per call.
struct Workspace {
  const CorrespondenceSet& corr;
  std::vector<Eigen::Vector2d> centered;  // pixel − principal point (undistorted if calibrated)
  std::vector<uint32_t> hypothesis;       // feature ids of the hypothesis set
  std::vector<uint32_t> sprt_order;       // the hypothesis set in a random order
  double thr2 = 16;

  // 1-M verification: features with any candidate consistent.
  size_t count_one_many(const Matrix34d& P) const {
    const uint32_t* off = corr.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr.candidates.data();
    const size_t n = centered.size();
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector2d& x = centered[i];
      for (uint32_t j = off[i]; j < off[i + 1]; ++j)
        if (is_consistent(P, cand[j], x, thr2)) {
          ++count;
          break;
        }
    }
    return count;
  }
  // Classical verification: first candidates of the hypothesis set.
  size_t count_one_one(const Matrix34d& P) const {
    const uint32_t* off = corr.candidate_offsets.data();
    const Eigen::Vector3d* cand = corr.candidates.data();
    size_t count = 0;
    for (uint32_t f : hypothesis) count += is_consistent(P, cand[off[f]], centered[f], thr2) ? 1 : 0;
    return count;
  }
};

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
  const bool use_sprt = options.variant == RansacVariant::kOneManySprt;
  RansacStatistics& st = result.stats;
  st.num_features = n;
  st.sample_size = s;
  result.chosen_candidate.assign(n, -1);
  result.focal = calibrated ? camera.focal : 0.0;

  Workspace ws{corr, {}, {}, {}, options.threshold_px * options.threshold_px};
  ws.centered.resize(n);
  const Eigen::Vector2d pp(camera.cx, camera.cy);
  for (size_t i = 0; i < n; ++i)
    ws.centered[i] = calibrated ? Eigen::Vector2d(camera.normalize(corr.points2d[i]) * camera.focal)
                                : Eigen::Vector2d(corr.points2d[i] - pp);
  for (size_t i = 0; i < n; ++i)
    if (corr.in_hypothesis_set[i]) ws.hypothesis.push_back(static_cast<uint32_t>(i));
  const size_t nh = ws.hypothesis.size();
  st.hypothesis_features = nh;
  if (nh < static_cast<size_t>(s)) {
    st.total_ms = ms_between(t_start, Clock::now());
    return result;
  }

  RandomGenerator rng(options.seed);
  ws.sprt_order = ws.hypothesis;
  for (size_t i = nh - 1; i > 0; --i) std::swap(ws.sprt_order[i], ws.sprt_order[rng.below(static_cast<uint32_t>(i + 1))]);

  // SPRT state (Chum & Matas 2008; sprt.h).
  const double model_cost = options.sprt_model_cost > 0 ? options.sprt_model_cost : (calibrated ? 250.0 : 1500.0);
  const double models_per_sample = calibrated ? 1.5 : 1.0;
  SprtTest sprt;
  double delta = options.sprt_delta0;
  double rejected_consistent = 0, rejected_tested = 0;
  if (use_sprt) sprt.update(static_cast<double>(s) / static_cast<double>(nh), delta, model_cost, models_per_sample);

  const size_t cap = options.variant == RansacVariant::kOneManyFixed ? options.fixed_iterations : options.max_iterations;
  size_t k_max = cap;

  const uint32_t* off = corr.candidate_offsets.data();
  const Eigen::Vector3d* cand = corr.candidates.data();
  std::array<uint32_t, 6> sample{};
  std::array<Eigen::Vector2d, 6> s2;
  std::array<Eigen::Vector3d, 6> s3;
  std::array<Eigen::Vector3d, 3> bearings, world3;
  std::array<Matrix34d, 4> models;
  Matrix34d best_model = Matrix34d::Zero();
  size_t best_score = 0;
  const double f = camera.focal;
  // Every verified model's camera centre, principal axis and score: after the
  // loop, the best-supported model that is a different pose gives the margin.
  struct ModelSummary {
    Eigen::Vector3d center, axis;
    size_t score;
  };
  std::vector<ModelSummary> verified;
  verified.reserve(64);
  auto summarize = [](const Matrix34d& P, size_t score, ModelSummary* out) {
    const Eigen::Matrix3d M = P.leftCols<3>();
    const double det = M.determinant();
    if (!(std::abs(det) > 1e-300)) return false;
    out->center = -M.inverse() * P.col(3);
    out->axis = (det > 0 ? 1.0 : -1.0) * M.row(2).transpose().normalized();
    out->score = score;
    return out->center.allFinite() && out->axis.allFinite();
  };

  size_t iter = 0;
  for (; iter < k_max; ++iter) {
    const auto t0 = Clock::now();
    // Sample s distinct hypothesis-set features.
    for (int k = 0; k < s; ++k) {
      uint32_t pick;
      bool repeated;
      do {
        pick = ws.hypothesis[rng.below(static_cast<uint32_t>(nh))];
        repeated = false;
        for (int m = 0; m < k; ++m) repeated |= sample[m] == pick;
      } while (repeated);
      sample[k] = pick;
    }
    int num_models = 0;
    if (calibrated) {
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector2d& x = ws.centered[sample[k]];
        bearings[k] = Eigen::Vector3d(x.x() / f, x.y() / f, 1.0);
        world3[k] = cand[off[sample[k]]];
      }
      num_models = solve_p3p(bearings, world3, &models);
      for (int m = 0; m < num_models; ++m) models[m].topRows<2>() *= f;
    } else {
      for (int k = 0; k < 6; ++k) {
        s2[k] = ws.centered[sample[k]];
        s3[k] = cand[off[sample[k]]];
      }
      num_models = solve_dlt(s2.data(), s3.data(), 6, &models[0]) ? 1 : 0;
    }
    const auto t1 = Clock::now();
    st.hypothesis_ms += ms_between(t0, t1);

    for (int m = 0; m < num_models; ++m) {
      const Matrix34d& P = models[m];
      ++st.models;
      size_t hyp_inliers = 0;
      if (use_sprt) {
        // Pre-verification on the hypothesis set, random start, cyclic order.
        double lambda = 1.0;
        size_t tested = 0;
        bool rejected = false;
        const size_t start = rng.below(static_cast<uint32_t>(nh));
        for (size_t j = 0; j < nh; ++j) {
          size_t idx = start + j;
          if (idx >= nh) idx -= nh;
          const uint32_t feat = ws.sprt_order[idx];
          const bool c = is_consistent(P, cand[off[feat]], ws.centered[feat], ws.thr2);
          hyp_inliers += c ? 1 : 0;
          ++tested;
          if (sprt.enabled()) {
            lambda *= c ? sprt.consistent_factor : sprt.inconsistent_factor;
            if (lambda > sprt.threshold) {
              rejected = true;
              break;
            }
          }
        }
        if (rejected) {
          ++st.models_rejected_sprt;
          rejected_consistent += static_cast<double>(hyp_inliers);
          rejected_tested += static_cast<double>(tested);
          const double w = options.sprt_delta_prior_weight;
          const double new_delta = (options.sprt_delta0 * w + rejected_consistent) / (w + rejected_tested);
          if (std::abs(new_delta - delta) > 0.05 * delta) {
            delta = std::max(new_delta, 1e-6);
            sprt.update(sprt.epsilon, delta, model_cost, models_per_sample);
          }
          continue;
        }
      }
      ++st.models_verified;
      const size_t score = one_many ? ws.count_one_many(P) : ws.count_one_one(P);
      if (ModelSummary summary; summarize(P, score, &summary)) verified.push_back(summary);
      if (score > best_score) {
        best_score = score;
        best_model = P;
        st.best_iteration = iter;
        if (options.variant == RansacVariant::kClassic11) {
          const double eps = static_cast<double>(score) / static_cast<double>(nh);
          k_max = static_cast<size_t>(std::ceil(
              adaptive_iterations(std::pow(eps, s), options.confidence, static_cast<double>(cap))));
        } else if (use_sprt) {
          const double eps = std::max(static_cast<double>(hyp_inliers), static_cast<double>(s)) / static_cast<double>(nh);
          sprt.update(eps, delta, model_cost, models_per_sample);
          k_max = static_cast<size_t>(std::ceil(
              adaptive_iterations(sprt.good_sample_probability(s), options.confidence, static_cast<double>(cap))));
        }
      }
    }
    st.verification_ms += ms_between(t1, Clock::now());
  }
  st.iterations = iter;
  if (use_sprt) {
    st.final_epsilon = sprt.epsilon;
    st.final_delta = delta;
    st.final_threshold = sprt.threshold;
    const double pg = sprt.good_sample_probability(s);
    st.expected_samples = pg > 0 ? 1.0 / pg : std::numeric_limits<double>::infinity();
  }
  if (best_score == 0) {
    st.total_ms = ms_between(t_start, Clock::now());
    return result;
  }

  // Refinement: choose per feature the candidate that fits, refine, re-select.
  const auto t_refine = Clock::now();
  std::vector<Eigen::Vector2d> inlier2d;
  std::vector<Eigen::Vector3d> inlier3d;
  auto select = [&](const Matrix34d& P) {
    size_t count = 0;
    std::fill(result.chosen_candidate.begin(), result.chosen_candidate.end(), -1);
    inlier2d.clear();
    inlier3d.clear();
    for (size_t i = 0; i < n; ++i) {
      if (!one_many && !corr.in_hypothesis_set[i]) continue;
      const uint32_t end = one_many ? off[i + 1] : off[i] + 1;
      double best_e = ws.thr2;
      int32_t best_j = -1;
      for (uint32_t j = off[i]; j < end; ++j) {
        const double e = reprojection_error2(P, cand[j], ws.centered[i]);
        if (e < best_e) {
          best_e = e;
          best_j = static_cast<int32_t>(j - off[i]);
        }
      }
      if (best_j >= 0) {
        result.chosen_candidate[i] = best_j;
        inlier2d.push_back(ws.centered[i]);
        inlier3d.push_back(cand[off[i] + best_j]);
        ++count;
      }
    }
    return count;
  };
  auto select_count = [&](const Matrix34d& P) {
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      if (!one_many && !corr.in_hypothesis_set[i]) continue;
      const uint32_t end = one_many ? off[i + 1] : off[i] + 1;
      for (uint32_t j = off[i]; j < end; ++j)
        if (is_consistent(P, cand[j], ws.centered[i], ws.thr2)) {
          ++count;
          break;
        }
    }
    return count;
  };
  st.ransac_inliers = select(best_model);

  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  double focal = f;
  if (calibrated) {
    R = best_model.leftCols<3>();
    R.topRows<2>() /= f;
    t = best_model.col(3);
    t.head<2>() /= f;
  } else {
    // Linear re-estimation on all inliers of the best model (the minimal
    // 6-point DLT is noisy), then decomposition into f, R, t.
    Matrix34d P_all;
    if (inlier2d.size() >= 12 && solve_dlt(inlier2d.data(), inlier3d.data(), static_cast<int>(inlier2d.size()), &P_all) &&
        select_count(P_all) >= st.ransac_inliers)
      best_model = P_all;
    st.ransac_inliers = select(best_model);
    DecomposedProjection dec;
    if (!decompose_projection(best_model, &dec)) {
      st.refinement_ms = ms_between(t_refine, Clock::now());
      st.total_ms = ms_between(t_start, Clock::now());
      std::fill(result.chosen_candidate.begin(), result.chosen_candidate.end(), -1);
      return result;
    }
    R = dec.rotation;
    t = dec.translation;
    focal = dec.focal;
  }
  CameraPose pose = CameraPose::from_matrix(R, t);
  // Without refinement the inliers are those of the pose itself; with it, the
  // first round starts from the best model's inliers (selected above).
  size_t inliers = options.refine && options.refine_rounds > 0
                       ? st.ransac_inliers
                       : select(projection_from_pose(pose.rotation_matrix(), pose.translation, focal));
  Eigen::Vector2d pp_offset = Eigen::Vector2d::Zero();
  // An unknown camera's principal point is refined too when there are
  // enough inliers to see it, under a prior of 3% of the image size.
  constexpr size_t kMinInliersForPrincipalPoint = 50;
  const double pp_prior_px = 0.03 * std::max<double>(std::max(camera.width, camera.height), 100);
  bool pp_refined = false;
  if (options.refine) {
    RefinementOptions ro;
    ro.loss_scale_px = options.threshold_px;
    ro.max_iterations = options.refine_max_iterations;
    ro.refine_focal = !calibrated;
    ro.principal_point_prior_px = pp_prior_px;
    for (int round = 0; round < options.refine_rounds; ++round) {
      if (inlier2d.size() < (calibrated ? 3u : 4u)) break;
      ro.refine_principal_point = options.refine_principal_point && !calibrated &&
                                  inlier2d.size() >= kMinInliersForPrincipalPoint;
      const RefinementResult rr =
          refine_pose(inlier2d.data(), inlier3d.data(), inlier2d.size(), pose, focal, ro, pp_offset);
      st.refine_iterations += rr.iterations;
      if (!rr.success) break;
      pose = rr.cam_from_world;
      focal = rr.focal;
      pp_offset = rr.principal_point_offset;
      pp_refined = pp_refined || ro.refine_principal_point;
      inliers = select(projection_from_pose(pose.rotation_matrix(), pose.translation, focal, pp_offset));
    }
  }
  // The pose's evidence: 1-1 inlier ratio, residuals, image coverage and the
  // covariance on the final inliers.
  {
    const Matrix34d P = projection_from_pose(pose.rotation_matrix(), pose.translation, focal, pp_offset);
    PoseQuality& q = result.quality;
    q.hypothesis_features = ws.hypothesis.size();
    q.hypothesis_inliers = ws.count_one_one(P);
    std::vector<double> residuals;
    residuals.reserve(inlier2d.size());
    constexpr int kGrid = 8;
    std::array<bool, kGrid * kGrid> occupied{};
    const double w = std::max<double>(1, static_cast<double>(camera.width));
    const double h = std::max<double>(1, static_cast<double>(camera.height));
    for (size_t k = 0; k < inlier2d.size(); ++k) {
      residuals.push_back(std::sqrt(reprojection_error2(P, inlier3d[k], inlier2d[k])));
      const double u = inlier2d[k].x() + camera.cx, v = inlier2d[k].y() + camera.cy;
      const int gx = std::clamp(static_cast<int>(u / w * kGrid), 0, kGrid - 1);
      const int gy = std::clamp(static_cast<int>(v / h * kGrid), 0, kGrid - 1);
      occupied[gy * kGrid + gx] = true;
    }
    if (!residuals.empty()) {
      std::nth_element(residuals.begin(), residuals.begin() + residuals.size() / 2, residuals.end());
      q.median_residual_px = residuals[residuals.size() / 2];
    }
    q.coverage = static_cast<double>(std::count(occupied.begin(), occupied.end(), true)) / (kGrid * kGrid);
    q.covariance = pose_covariance(inlier2d.data(), inlier3d.data(), inlier2d.size(), pose, focal,
                                   options.threshold_px, !calibrated, pp_offset, pp_refined ? pp_prior_px : 0.0);
  }
  result.principal_point_offset = pp_offset;
  // The strongest rival: a verified model whose camera is elsewhere (farther
  // than 10% of the inliers' median depth) or looks elsewhere (> 10°).
  {
    const Eigen::Vector3d c = pose.center(), a = pose.viewing_direction();
    std::vector<double> depths;
    depths.reserve(inlier3d.size());
    const Eigen::Matrix3d R = pose.rotation_matrix();
    for (const auto& X : inlier3d) depths.push_back((R * X + pose.translation).z());
    double depth = 0;
    if (!depths.empty()) {
      std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
      depth = std::abs(depths[depths.size() / 2]);
    }
    const double cos_limit = std::cos(10.0 * M_PI / 180.0);
    auto differs = [&](const ModelSummary& m, const Eigen::Vector3d& centre, const Eigen::Vector3d& axis) {
      return (m.center - centre).norm() > 0.1 * depth || m.axis.dot(axis) < cos_limit;
    };
    // A rival differs from the refined pose and from the best model itself
    // (6-point DLT models scatter: a copy of the best one is no rival).
    ModelSummary best_summary;
    const bool have_best = summarize(best_model, best_score, &best_summary);
    size_t rival = 0;
    for (const ModelSummary& m : verified)
      if (differs(m, c, a) && (!have_best || differs(m, best_summary.center, best_summary.axis)))
        rival = std::max(rival, m.score);
    result.quality.rival_score = rival;
    result.quality.best_score = best_score;
  }
  st.refinement_ms = ms_between(t_refine, Clock::now());
  result.has_pose = true;
  result.cam_from_world = pose;
  result.focal = focal;
  result.num_inliers = inliers;
  result.registered = inliers >= options.min_inliers;
  st.total_ms = ms_between(t_start, Clock::now());
  return result;
}

}  // namespace visloc
