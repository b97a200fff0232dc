#include "visloc/pose/two_view_ransac.h"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>

#include "visloc/pose/solvers/two_view.h"
#include "visloc/util/error.h"

namespace visloc {

std::string_view to_string(TwoViewModel model) {
  switch (model) {
    case TwoViewModel::kFundamental: return "F";
    case TwoViewModel::kHomography: return "H";
    case TwoViewModel::kEssential: return "E";
  }
  return "?";
}

TwoViewModel parse_two_view_model(std::string_view name) {
  if (name == "F") return TwoViewModel::kFundamental;
  if (name == "H") return TwoViewModel::kHomography;
  if (name == "E") return TwoViewModel::kEssential;
  throw_error(ErrorCode::kInvalidArgument, "two-view model '", name, "': must be F, H or E");
}

void TwoViewCorrespondences::validate() const {
  const size_t n = points1.size();
  if (feature1.size() != n || in_hypothesis_set.size() != n || candidate_offsets.size() != n + 1 ||
      candidate_offsets.front() != 0 || candidate_offsets.back() != candidates.size() ||
      candidate_feature2.size() != candidates.size())
    throw_error(ErrorCode::kInvalidArgument, "two-view correspondences: array sizes disagree");
  for (size_t i = 0; i < n; ++i)
    if (candidate_offsets[i + 1] <= candidate_offsets[i])
      throw_error(ErrorCode::kInvalidArgument, "two-view correspondences: feature ", i, " has no candidate");
}

void TwoViewOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "two-view options: ", field, " ", rule, ", got ", value);
  };
  if (!(threshold_px > 0) || !std::isfinite(threshold_px)) bad("threshold_px", threshold_px, "must be positive");
  if (max_iterations == 0) bad("max_iterations", max_iterations, "must be positive");
  if (fixed_iterations == 0) bad("fixed_iterations", fixed_iterations, "must be positive");
  if (!(confidence > 0 && confidence < 1)) bad("confidence", confidence, "must be in (0, 1)");
  if (!(sprt_delta0 > 0 && sprt_delta0 < 1)) bad("sprt_delta0", sprt_delta0, "must be in (0, 1)");
  if (refine_max_iterations < 0) bad("refine_max_iterations", refine_max_iterations, "must be >= 0");
  if (model == TwoViewModel::kEssential && (!calibration1 || !calibration2))
    throw_error(ErrorCode::kInvalidArgument, "two-view options: the essential matrix needs both calibrations");
  for (const auto& K : {calibration1, calibration2})
    if (K && (!K->allFinite() || !(std::abs(K->determinant()) > 0)))
      throw_error(ErrorCode::kInvalidArgument, "two-view options: a calibration is singular or not finite");
}

namespace {

// Squared error of x1 ↔ x2 under a pixel-space model (F: Sampson; H: transfer).
inline double model_error2(bool homography, const Eigen::Matrix3d& M, const Eigen::Vector2d& x1,
                           const Eigen::Vector2d& x2) {
  return homography ? transfer_error2(M, x1, x2) : sampson_error2(M, x1, x2);
}

// The estimator the RANSAC loop runs. Models are pixel-space F or H (an E is
// turned into its F through the calibrations for scoring).
class TwoViewEstimator {
 public:
  using Model = Eigen::Matrix3d;
  static constexpr int kMaxSampleSize = 7;
  static constexpr int kMaxModels = 10;

  TwoViewEstimator(const TwoViewCorrespondences& m, const TwoViewOptions& o)
      : m_(m), model_(o.model), one_many_(o.variant != RansacVariant::kClassic11),
        thr2_(o.threshold_px * o.threshold_px) {
    for (size_t i = 0; i < m.size(); ++i)
      if (m.in_hypothesis_set[i]) hypothesis_.push_back(static_cast<uint32_t>(i));
    if (model_ == TwoViewModel::kEssential) {
      K1inv_ = o.calibration1->inverse();
      K2inv_ = o.calibration2->inverse();
    }
  }
  int sample_size() const { return model_ == TwoViewModel::kFundamental ? 7 : model_ == TwoViewModel::kHomography ? 4 : 5; }
  size_t num_hypotheses() const { return hypothesis_.size(); }

  int solve(const uint32_t* sample, Model* models) {
    std::array<Eigen::Vector2d, kMaxSampleSize> a, b;
    const int s = sample_size();
    for (int k = 0; k < s; ++k) {
      const uint32_t f = hypothesis_[sample[k]];
      a[k] = m_.points1[f];
      b[k] = m_.candidates[m_.candidate_offsets[f]];
    }
    if (model_ == TwoViewModel::kHomography) return solve_homography_4pt(a.data(), b.data(), &models[0]);
    if (model_ == TwoViewModel::kFundamental) {
      std::array<Eigen::Matrix3d, 3> F;
      const int n = solve_fundamental_7pt(a.data(), b.data(), &F);
      for (int i = 0; i < n; ++i) models[i] = F[i];
      return n;
    }
    for (int k = 0; k < s; ++k) {
      a[k] = (K1inv_ * a[k].homogeneous()).hnormalized();
      b[k] = (K2inv_ * b[k].homogeneous()).hnormalized();
    }
    std::array<Eigen::Matrix3d, 10> E;
    const int n = solve_essential_5pt(a.data(), b.data(), &E);
    for (int i = 0; i < n; ++i) models[i] = K2inv_.transpose() * E[i] * K1inv_;
    return n;
  }
  bool hypothesis_consistent(const Model& M, uint32_t h) const {
    const uint32_t f = hypothesis_[h];
    return model_error2(homography(), M, m_.points1[f], m_.candidates[m_.candidate_offsets[f]]) < thr2_;
  }
  size_t score(const Model& M) const {
    size_t count = 0;
    if (!one_many_) {
      for (uint32_t f : hypothesis_) count += hypothesis_consistent_feature(M, f);
      return count;
    }
    for (size_t i = 0; i < m_.size(); ++i)
      for (uint32_t j = m_.candidate_offsets[i]; j < m_.candidate_offsets[i + 1]; ++j)
        if (model_error2(homography(), M, m_.points1[i], m_.candidates[j]) < thr2_) {
          ++count;
          break;
        }
    return count;
  }
  void on_verified(const Model&, size_t) {}

  bool homography() const { return model_ == TwoViewModel::kHomography; }
  bool one_many() const { return one_many_; }
  double thr2() const { return thr2_; }
  const Eigen::Matrix3d& K1inv() const { return K1inv_; }
  const Eigen::Matrix3d& K2inv() const { return K2inv_; }

 private:
  bool hypothesis_consistent_feature(const Model& M, uint32_t f) const {
    return model_error2(homography(), M, m_.points1[f], m_.candidates[m_.candidate_offsets[f]]) < thr2_;
  }
  const TwoViewCorrespondences& m_;
  TwoViewModel model_;
  bool one_many_;
  double thr2_;
  std::vector<uint32_t> hypothesis_;
  Eigen::Matrix3d K1inv_ = Eigen::Matrix3d::Identity(), K2inv_ = Eigen::Matrix3d::Identity();
};

// Per feature, the candidate of smallest error within the threshold.
size_t choose_candidates(const TwoViewCorrespondences& m, const TwoViewEstimator& est, const Eigen::Matrix3d& M,
                         std::vector<int32_t>* chosen) {
  size_t count = 0;
  chosen->assign(m.size(), -1);
  for (size_t i = 0; i < m.size(); ++i) {
    if (!est.one_many() && !m.in_hypothesis_set[i]) continue;
    const uint32_t begin = m.candidate_offsets[i];
    const uint32_t end = est.one_many() ? m.candidate_offsets[i + 1] : begin + 1;
    double best = est.thr2();
    for (uint32_t j = begin; j < end; ++j) {
      const double e = model_error2(est.homography(), M, m.points1[i], m.candidates[j]);
      if (e < best) {
        best = e;
        (*chosen)[i] = static_cast<int32_t>(j - begin);
      }
    }
    count += (*chosen)[i] >= 0;
  }
  return count;
}

// Projections onto the model's manifold: rank 2 (F), an essential matrix
// (two equal singular values) through the calibrations (E), none (H).
Eigen::Matrix3d project_model(const Eigen::Matrix3d& M, TwoViewModel model, const Eigen::Matrix3d& K1inv,
                              const Eigen::Matrix3d& K2inv) {
  if (model == TwoViewModel::kHomography) return M / M.norm();
  Eigen::Matrix3d X = model == TwoViewModel::kEssential ? Eigen::Matrix3d(K2inv.transpose().inverse() * M * K1inv.inverse()) : M;
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(X, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d s = svd.singularValues();
  if (model == TwoViewModel::kEssential) s = Eigen::Vector3d(1, 1, 0);
  else s(2) = 0;
  X = svd.matrixU() * s.asDiagonal() * svd.matrixV().transpose();
  if (model == TwoViewModel::kEssential) X = K2inv.transpose() * X * K1inv;
  return X / X.norm();
}

// Similarity taking points to centroid 0, mean distance √2 (Hartley).
Eigen::Matrix3d hartley(const std::vector<Eigen::Vector2d>& x) {
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (const auto& p : x) c += p;
  c /= static_cast<double>(x.size());
  double d = 0;
  for (const auto& p : x) d += (p - c).norm();
  d /= static_cast<double>(x.size());
  const double s = d > 1e-12 ? std::sqrt(2.0) / d : 1.0;
  Eigen::Matrix3d T;
  T << s, 0, -s * c.x(), 0, s, -s * c.y(), 0, 0, 1;
  return T;
}

// Levenberg-Marquardt on the chosen inliers' signed errors, in pixels: the
// Sampson residual e/√d (F, E) or the transfer error's two components (H).
// The 9 entries are those of the model in Hartley-normalized coordinates
// (well scaled), with a forward-difference Jacobian; after every step the
// model is projected back onto its manifold, and a step is kept only when
// the cost falls.
Eigen::Matrix3d refine_model(const TwoViewCorrespondences& m, const std::vector<int32_t>& chosen,
                             const Eigen::Matrix3d& start, TwoViewModel model, const TwoViewEstimator& est,
                             int max_iterations) {
  std::vector<Eigen::Vector2d> p1, p2;
  for (size_t i = 0; i < m.size(); ++i)
    if (chosen[i] >= 0) {
      p1.push_back(m.points1[i]);
      p2.push_back(m.candidates[m.candidate_offsets[i] + static_cast<uint32_t>(chosen[i])]);
    }
  const bool homography = model == TwoViewModel::kHomography;
  if (p1.size() < (homography ? 5u : 8u)) return start;
  const Eigen::Matrix3d T1 = hartley(p1), T2 = hartley(p2);
  // Pixel model from normalized: F = T2ᵀ Fn T1, H = T2⁻¹ Hn T1.
  const Eigen::Matrix3d T2inv = T2.inverse(), T1inv = T1.inverse();
  auto to_pixels = [&](const Eigen::Matrix3d& N) -> Eigen::Matrix3d {
    return homography ? Eigen::Matrix3d(T2inv * N * T1) : Eigen::Matrix3d(T2.transpose() * N * T1);
  };
  auto to_normalized = [&](const Eigen::Matrix3d& M) -> Eigen::Matrix3d {
    return homography ? Eigen::Matrix3d(T2 * M * T1inv) : Eigen::Matrix3d(T2inv.transpose() * M * T1inv);
  };
  const int per_point = homography ? 2 : 1;
  const Eigen::Index rows = static_cast<Eigen::Index>(p1.size()) * per_point;
  auto residuals = [&](const Eigen::Matrix3d& M, Eigen::VectorXd& r) {
    for (size_t k = 0; k < p1.size(); ++k) {
      const Eigen::Index at = static_cast<Eigen::Index>(k) * per_point;
      if (homography) {
        const Eigen::Vector3d q = M * p1[k].homogeneous();
        const Eigen::Vector2d d = std::abs(q.z()) > 1e-12 ? Eigen::Vector2d(q.head<2>() / q.z() - p2[k]) : Eigen::Vector2d(1e3, 1e3);
        r(at) = std::clamp(d.x(), -1e3, 1e3);
        r(at + 1) = std::clamp(d.y(), -1e3, 1e3);
      } else {
        const Eigen::Vector3d a = p1[k].homogeneous(), b = p2[k].homogeneous();
        const Eigen::Vector3d Fa = M * a, Ftb = M.transpose() * b;
        const double denom = Fa.x() * Fa.x() + Fa.y() * Fa.y() + Ftb.x() * Ftb.x() + Ftb.y() * Ftb.y();
        r(at) = denom > 0 ? std::clamp(b.dot(Fa) / std::sqrt(denom), -1e3, 1e3) : 1e3;
      }
    }
  };
  auto project = [&](const Eigen::Matrix3d& N) {
    return to_normalized(project_model(to_pixels(N), model, est.K1inv(), est.K2inv()));
  };
  Eigen::Matrix3d N = project(to_normalized(start));
  N /= N.norm();
  Eigen::VectorXd r(rows), rp(rows);
  residuals(to_pixels(N), r);
  double current = r.squaredNorm(), lambda = 1e-3;
  Eigen::MatrixXd J(rows, 9);
  for (int it = 0; it < max_iterations; ++it) {
    for (int p = 0; p < 9; ++p) {  // forward differences: the residuals are smooth and the entries ~1
      constexpr double h = 1e-7;
      Eigen::Matrix3d Np = N;
      Np(p / 3, p % 3) += h;
      residuals(to_pixels(Np), rp);
      J.col(p) = (rp - r) / h;
    }
    const Eigen::MatrixXd JtJ = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool accepted = false, converged = false;
    for (int attempt = 0; attempt < 8 && !accepted; ++attempt) {
      Eigen::MatrixXd A = JtJ;
      A.diagonal() += lambda * (JtJ.diagonal().array() + 1e-12).matrix();
      const Eigen::VectorXd step = A.ldlt().solve(-g);
      Eigen::Matrix3d candidate = N;
      for (int p = 0; p < 9; ++p) candidate(p / 3, p % 3) += step(p);
      candidate = project(candidate);
      candidate /= candidate.norm();
      residuals(to_pixels(candidate), rp);
      const double c = rp.squaredNorm();
      if (std::isfinite(c) && c < current) {
        converged = current - c <= 1e-6 * current;  // a relative decrease below 1e-6 ends the refinement
        N = candidate;
        r = rp;
        current = c;
        lambda = std::max(lambda / 10, 1e-9);
        accepted = true;
      } else {
        lambda *= 10;
      }
    }
    if (!accepted || converged) break;
  }
  const Eigen::Matrix3d M = to_pixels(N);
  return M / M.norm();
}

}  // namespace

TwoViewEstimate estimate_two_view(const TwoViewCorrespondences& matches, const TwoViewOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.validate();
  matches.validate();
  TwoViewEstimate out;
  out.model = options.model;
  out.chosen_candidate.assign(matches.size(), -1);
  TwoViewEstimator estimator(matches, options);
  RansacLoopOptions lo = loop_options_for(options.variant, options.max_iterations, options.fixed_iterations,
                                          options.confidence, options.sprt_delta0);
  // t_M in point verifications (a Sampson error is ~10 ns): 7-point F ~10 µs
  // with 1-3 models, 4-point H ~5 µs, 5-point E ~30 µs with up to 10 models.
  lo.sprt_model_cost = options.model == TwoViewModel::kEssential ? 3000 : options.model == TwoViewModel::kHomography ? 500 : 1000;
  lo.models_per_sample = options.model == TwoViewModel::kEssential ? 4 : options.model == TwoViewModel::kFundamental ? 1.5 : 1;
  RandomGenerator rng(options.seed);
  const RansacLoopResult<Eigen::Matrix3d> loop = run_ransac(estimator, lo, rng);
  out.stats = loop.stats;
  auto finish = [&] {
    out.total_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    return out;
  };
  if (loop.best_score == 0) return finish();
  Eigen::Matrix3d M = loop.best;
  out.ransac_inliers = static_cast<double>(choose_candidates(matches, estimator, M, &out.chosen_candidate));
  if (options.refine) {
    const Eigen::Matrix3d refined = refine_model(matches, out.chosen_candidate, M, options.model, estimator,
                                                 options.refine_max_iterations);
    std::vector<int32_t> chosen;
    if (choose_candidates(matches, estimator, refined, &chosen) >= static_cast<size_t>(out.ransac_inliers)) {
      M = refined;
      out.chosen_candidate = std::move(chosen);
    }
  }
  out.found = true;
  out.inliers = static_cast<size_t>(std::count_if(out.chosen_candidate.begin(), out.chosen_candidate.end(),
                                                  [](int32_t c) { return c >= 0; }));
  // A 1-1 inlier: a hypothesis-set feature whose own 1-1 match fits (even
  // when another of its candidates fits better).
  out.one_to_one_inlier.assign(matches.size(), 0);
  for (size_t i = 0; i < matches.size(); ++i)
    if (matches.in_hypothesis_set[i] && out.chosen_candidate[i] >= 0 &&
        model_error2(estimator.homography(), M, matches.points1[i], matches.candidates[matches.candidate_offsets[i]]) <
            estimator.thr2()) {
      out.one_to_one_inlier[i] = 1;
      ++out.one_to_one_inliers;
    }
  out.extra_inliers = out.inliers - out.one_to_one_inliers;
  if (options.model == TwoViewModel::kHomography) {
    out.matrix = M;
  } else {
    out.fundamental = M / M.norm();
    out.matrix = options.model == TwoViewModel::kEssential
                     ? Eigen::Matrix3d(options.calibration2->transpose() * M * *options.calibration1)
                     : M;
    out.matrix /= out.matrix.norm();
  }
  return finish();
}

}  // namespace visloc
