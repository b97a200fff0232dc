#include "visloc/pose/pose_refinement.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <cmath>
#include <vector>

#include "visloc/util/error.h"

namespace visloc {

void RefinementOptions::validate() const {
  if (!(loss_scale_px > 0) || !std::isfinite(loss_scale_px))
    throw_error(ErrorCode::kInvalidArgument, "refinement: loss_scale_px must be positive, got ", loss_scale_px);
  if (max_iterations < 0)
    throw_error(ErrorCode::kInvalidArgument, "refinement: max_iterations must be >= 0, got ", max_iterations);
  if (!(min_relative_decrease >= 0))
    throw_error(ErrorCode::kInvalidArgument, "refinement: min_relative_decrease must be >= 0");
  if (refine_principal_point && !refine_focal)
    throw_error(ErrorCode::kInvalidArgument, "refinement: refine_principal_point needs refine_focal");
  if (!(principal_point_prior_px > 0) || !std::isfinite(principal_point_prior_px))
    throw_error(ErrorCode::kInvalidArgument, "refinement: principal_point_prior_px must be positive, got ",
                principal_point_prior_px);
}

namespace {

struct State {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  double focal;
  Eigen::Vector2d pp = Eigen::Vector2d::Zero();  // principal point offset
};

// inv_prior2 = 1/σ_o² (0: no principal point term).
double robust_cost(const State& s, const Eigen::Vector2d* x, const Eigen::Vector3d* X, size_t n, double c2,
                   double inv_prior2) {
  double cost = s.pp.squaredNorm() * inv_prior2;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p = s.R * X[i] + s.t;
    if (p.z() <= 0) {
      cost += c2 * std::log1p(1e6);  // behind the camera: a large constant penalty
      continue;
    }
    const Eigen::Vector2d r = s.focal * p.head<2>() / p.z() + s.pp - x[i];
    cost += c2 * std::log1p(r.squaredNorm() / c2);
  }
  return cost;
}

Eigen::Matrix3d exp_so3(const Eigen::Vector3d& w) {
  const double a = w.norm();
  if (a < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

// Residual r = f π(R X + t) + o − x of one correspondence and its Jacobian
// over (ω, t, log f, o): d r/dp = f [[1/z, 0, −x/z²], [0, 1/z, −y/z²]],
// dp/dω = −[R X]×, dp/dt = I. False when X is behind the camera.
bool residual_and_jacobian(const Eigen::Matrix3d& R, const Eigen::Vector3d& t, double focal,
                           const Eigen::Vector2d& pp, const Eigen::Vector3d& X, const Eigen::Vector2d& x,
                           Eigen::Vector2d* r, Eigen::Matrix<double, 2, 9>* J) {
  const Eigen::Vector3d RX = R * X;
  const Eigen::Vector3d p = RX + t;
  if (p.z() <= 0) return false;
  const double iz = 1.0 / p.z();
  const Eigen::Vector2d proj(p.x() * iz, p.y() * iz);
  *r = focal * proj + pp - x;
  Eigen::Matrix<double, 2, 3> dr_dp;
  dr_dp << focal * iz, 0, -focal * proj.x() * iz, 0, focal * iz, -focal * proj.y() * iz;
  Eigen::Matrix3d skew;
  skew << 0, -RX.z(), RX.y(), RX.z(), 0, -RX.x(), -RX.y(), RX.x(), 0;
  J->setZero();
  J->leftCols<3>() = -dr_dp * skew;
  J->block<2, 3>(0, 3) = dr_dp;
  J->col(6) = focal * proj;  // d r / d(log f)
  (*J)(0, 7) = 1;            // d r / d o
  (*J)(1, 8) = 1;
  return true;
}

}  // namespace

RefinementResult refine_pose(const Eigen::Vector2d* x, const Eigen::Vector3d* X, size_t n, const CameraPose& initial,
                             double initial_focal, const RefinementOptions& options,
                             const Eigen::Vector2d& initial_pp) {
  options.validate();
  RefinementResult result;
  result.cam_from_world = initial;
  result.focal = initial_focal;
  result.principal_point_offset = initial_pp;
  const bool with_pp = options.refine_principal_point;
  const int dof = options.refine_focal ? 7 : 6;  // the prior pins o: it adds no unknowns to count against n
  if (n * 2 < static_cast<size_t>(dof) || !(initial_focal > 0) || !initial_pp.allFinite()) return result;
  const double c2 = options.loss_scale_px * options.loss_scale_px;
  const double inv_prior2 =
      with_pp ? 1.0 / (options.principal_point_prior_px * options.principal_point_prior_px) : 0.0;

  State s{initial.rotation_matrix(), initial.translation, initial_focal, with_pp ? initial_pp : Eigen::Vector2d::Zero()};
  const Eigen::Vector2d fixed_pp = with_pp ? Eigen::Vector2d::Zero() : initial_pp;  // applied to x when not refined
  std::vector<Eigen::Vector2d> shifted;
  if (!with_pp && !initial_pp.isZero()) {
    shifted.assign(x, x + n);
    for (auto& p : shifted) p -= fixed_pp;
    x = shifted.data();
  }
  double cost = robust_cost(s, x, X, n, c2, inv_prior2);
  result.initial_cost = cost;
  double lambda = 1e-3;
  using Mat7 = Eigen::Matrix<double, 9, 9>;
  using Vec7 = Eigen::Matrix<double, 9, 1>;
  int it = 0;
  for (; it < options.max_iterations; ++it) {
    Mat7 H = Mat7::Zero();
    Vec7 g = Vec7::Zero();
    for (size_t i = 0; i < n; ++i) {
      Eigen::Vector2d r;
      Eigen::Matrix<double, 2, 9> J;
      if (!residual_and_jacobian(s.R, s.t, s.focal, s.pp, X[i], x[i], &r, &J)) continue;
      const double w = 1.0 / (1.0 + r.squaredNorm() / c2);  // IRLS weight of the Cauchy loss
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * r;
    }
    if (with_pp) {  // the prior |o|²/σ_o²
      H(7, 7) += inv_prior2;
      H(8, 8) += inv_prior2;
      g.segment<2>(7) += inv_prior2 * s.pp;
    }
    auto freeze = [&](int k) {
      H.row(k).setZero();
      H.col(k).setZero();
      H(k, k) = 1;
      g[k] = 0;
    };
    if (!options.refine_focal) freeze(6);
    if (!with_pp) {
      freeze(7);
      freeze(8);
    }
    bool improved = false;
    for (int attempt = 0; attempt < 10; ++attempt) {
      Mat7 A = H;
      A.diagonal() += lambda * H.diagonal().cwiseMax(1e-9);
      const Vec7 delta = -A.ldlt().solve(g);
      if (!delta.allFinite()) break;
      State next{exp_so3(delta.head<3>()) * s.R, s.t + delta.segment<3>(3), s.focal * std::exp(delta[6]),
                 s.pp + delta.segment<2>(7)};
      const double next_cost = robust_cost(next, x, X, n, c2, inv_prior2);
      if (next_cost < cost) {
        const double decrease = (cost - next_cost) / std::max(cost, 1e-300);
        s = next;
        cost = next_cost;
        lambda = std::max(lambda * 0.3, 1e-10);
        improved = decrease > options.min_relative_decrease;
        break;
      }
      lambda *= 10;
    }
    if (!improved) break;
  }
  result.iterations = it;
  result.final_cost = cost;
  if (s.R.allFinite() && s.t.allFinite() && std::isfinite(s.focal) && s.focal > 0 && s.pp.allFinite() &&
      cost <= result.initial_cost) {
    result.cam_from_world = CameraPose::from_matrix(s.R, s.t);
    result.focal = s.focal;
    result.principal_point_offset = with_pp ? s.pp : initial_pp;
    result.success = true;
  }
  return result;
}

PoseCovariance pose_covariance(const Eigen::Vector2d* x, const Eigen::Vector3d* X, size_t n, const CameraPose& pose,
                               double focal, double loss_scale_px, bool with_focal, const Eigen::Vector2d& pp,
                               double pp_prior_px, const Eigen::Matrix3d* point_covariances) {
  PoseCovariance out;
  out.omega_t.setZero();
  const bool with_pp = with_focal && pp_prior_px > 0;
  const int dof = with_focal ? 7 : 6;
  if (n * 2 <= static_cast<size_t>(dof) || !(focal > 0) || !(loss_scale_px > 0)) return out;
  const double c2 = loss_scale_px * loss_scale_px;
  const Eigen::Matrix3d R = pose.rotation_matrix();
  using Mat7 = Eigen::Matrix<double, 9, 9>;
  Mat7 H = Mat7::Zero();
  Mat7 M = Mat7::Zero();  // the points' uncertainty term (below), in the same pass
  double weighted_sq = 0;
  size_t used = 0;
  std::vector<double> norms;
  norms.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector2d r;
    Eigen::Matrix<double, 2, 9> J;
    if (!residual_and_jacobian(R, pose.translation, focal, pp, X[i], x[i], &r, &J)) continue;
    const double w = 1.0 / (1.0 + r.squaredNorm() / c2);
    H.noalias() += w * J.transpose() * J;
    if (point_covariances) {
      const Eigen::Matrix<double, 9, 3> JA = J.transpose() * (J.block<2, 3>(0, 3) * R);  // A = ∂r/∂X
      M.noalias() += (w * w) * JA * point_covariances[i] * JA.transpose();
    }
    weighted_sq += w * r.squaredNorm();
    norms.push_back(r.norm());
    ++used;
  }
  if (!M.allFinite()) return out;
  if (used * 2 <= static_cast<size_t>(dof)) return out;
  // The noise: the larger of the weighted residual variance and a robust one
  // from the median residual (|r| of a 2-D Gaussian is Rayleigh: median
  // σ √(2 ln 2)); the inliers were cut at the RANSAC threshold and the Cauchy
  // weights shrink the tail, which both make the first too small.
  std::nth_element(norms.begin(), norms.begin() + norms.size() / 2, norms.end());
  const double robust_sigma = norms[norms.size() / 2] / std::sqrt(2.0 * std::log(2.0));
  const double dof_correction = static_cast<double>(2 * used) / static_cast<double>(2 * used - dof);
  const double sigma2 =
      std::max(weighted_sq / static_cast<double>(2 * used - dof), robust_sigma * robust_sigma * dof_correction);
  // The prior enters H in units of the noise: |o|²/σ_o² against |r|²/σ².
  const double prior = with_pp ? sigma2 / (pp_prior_px * pp_prior_px) : 0.0;
  if (with_pp) {
    H(7, 7) += prior;
    H(8, 8) += prior;
  }
  // With the points' uncertainty: the refinement still minimizes the
  // Cauchy-weighted squared residuals (w_i the inverse of residual i's noise
  // variance over σ²), but residual i also carries A_i e_i, the point's error
  // e_i ~ N(0, Σ_i) through A_i = ∂r_i/∂X_i. The estimate's covariance is
  // then the sandwich
  //   H⁻¹ (Σ_i w_i² J_iᵀ (σ²/w_i I + A_i Σ_i A_iᵀ) J_i) H⁻¹
  //   = σ² H⁻¹ + H⁻¹ (Σ_i w_i² J_iᵀ A_i Σ_i A_iᵀ J_i) H⁻¹,
  // σ² H⁻¹ exactly when every Σ_i = 0 (with the principal point's prior, H
  // holds it in noise units, σ²/σ_o², where the refinement weighs it 1/σ_o²:
  // the identity is then approximate). A_i Σ_i A_iᵀ is not clamped to the
  // RANSAC threshold: a point's error may project far beyond it in a pattern
  // the pose absorbs (the radial shift of a forward translation), leaving an
  // inlier; clamped, ransac_test.cc's street-view map had 6 of 40 errors
  // within 2σ instead of 37. σ² comes from the residuals, which already show
  // the part of the points' error the pose cannot absorb: that part is
  // counted twice, so the σ errs large.
  // (M is accumulated with H above: it does not depend on σ².)
  const int params = with_pp ? 9 : with_focal ? 7 : 6;
  const Eigen::MatrixXd Hp = H.topLeftCorner(params, params);
  Eigen::LDLT<Eigen::MatrixXd> ldlt(Hp);
  if (ldlt.info() != Eigen::Success) return out;
  const Eigen::MatrixXd H_inv = ldlt.solve(Eigen::MatrixXd::Identity(params, params));
  Mat7 cov = Mat7::Zero();
  cov.topLeftCorner(params, params) = sigma2 * H_inv;
  if (point_covariances) cov.topLeftCorner(params, params) += H_inv * M.topLeftCorner(params, params) * H_inv;
  if (!cov.allFinite() || (cov.diagonal().array() < 0).any()) return out;
  out.omega_t = cov.topLeftCorner<6, 6>();
  out.residual_sigma_px = std::sqrt(sigma2);
  out.focal_sigma_relative = with_focal ? std::sqrt(cov(6, 6)) : 0;
  out.with_point_uncertainty = point_covariances != nullptr;
  out.valid = true;
  return out;
}

Eigen::Matrix3d PoseCovariance::center(const CameraPose& pose) const {
  // c = −Rᵀ t; with R ← exp([ω]×) R: c(ω, t) ≈ c − Rᵀ [t]× ω − Rᵀ δt.
  const Eigen::Matrix3d Rt = pose.rotation_matrix().transpose();
  const Eigen::Vector3d& t = pose.translation;
  Eigen::Matrix3d t_skew;
  t_skew << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  Eigen::Matrix<double, 3, 6> Jc;
  Jc.leftCols<3>() = -Rt * t_skew;
  Jc.rightCols<3>() = -Rt;
  return Jc * omega_t * Jc.transpose();
}

}  // namespace visloc
