#include "visloc/pose/pose_refinement.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

void RefinementOptions::validate() const {
  if (!(loss_scale_px > 0) || !std::isfinite(loss_scale_px))
    throw_error(ErrorCode::kInvalidArgument, "refinement: loss_scale_px must be positive, got ", loss_scale_px);
  if (max_iterations < 0)
    throw_error(ErrorCode::kInvalidArgument, "refinement: max_iterations must be >= 0, got ", max_iterations);
  if (!(min_relative_decrease >= 0))
    throw_error(ErrorCode::kInvalidArgument, "refinement: min_relative_decrease must be >= 0");
}

namespace {

struct State {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  double focal;
};

double robust_cost(const State& s, const Eigen::Vector2d* x, const Eigen::Vector3d* X, size_t n, double c2) {
  double cost = 0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d p = s.R * X[i] + s.t;
    if (p.z() <= 0) {
      cost += c2 * std::log1p(1e6);  // behind the camera: a large constant penalty
      continue;
    }
    const Eigen::Vector2d r = s.focal * p.head<2>() / p.z() - x[i];
    cost += c2 * std::log1p(r.squaredNorm() / c2);
  }
  return cost;
}

Eigen::Matrix3d exp_so3(const Eigen::Vector3d& w) {
  const double a = w.norm();
  if (a < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

}  // namespace

RefinementResult refine_pose(const Eigen::Vector2d* x, const Eigen::Vector3d* X, size_t n, const CameraPose& initial,
                             double initial_focal, const RefinementOptions& options) {
  options.validate();
  RefinementResult result;
  result.cam_from_world = initial;
  result.focal = initial_focal;
  const int dof = options.refine_focal ? 7 : 6;
  if (n * 2 < static_cast<size_t>(dof) || !(initial_focal > 0)) return result;
  const double c2 = options.loss_scale_px * options.loss_scale_px;

  State s{initial.rotation_matrix(), initial.translation, initial_focal};
  double cost = robust_cost(s, x, X, n, c2);
  result.initial_cost = cost;
  double lambda = 1e-3;
  using Mat7 = Eigen::Matrix<double, 7, 7>;
  using Vec7 = Eigen::Matrix<double, 7, 1>;
  int it = 0;
  for (; it < options.max_iterations; ++it) {
    Mat7 H = Mat7::Zero();
    Vec7 g = Vec7::Zero();
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector3d RX = s.R * X[i];
      const Eigen::Vector3d p = RX + s.t;
      if (p.z() <= 0) continue;
      const double iz = 1.0 / p.z();
      const Eigen::Vector2d proj(p.x() * iz, p.y() * iz);
      const Eigen::Vector2d r = s.focal * proj - x[i];
      const double w = 1.0 / (1.0 + r.squaredNorm() / c2);  // IRLS weight of the Cauchy loss
      // d(residual)/dp = f [[1/z, 0, −x/z²], [0, 1/z, −y/z²]].
      Eigen::Matrix<double, 2, 3> dr_dp;
      dr_dp << s.focal * iz, 0, -s.focal * proj.x() * iz, 0, s.focal * iz, -s.focal * proj.y() * iz;
      Eigen::Matrix<double, 2, 7> J = Eigen::Matrix<double, 2, 7>::Zero();
      // dp/dω = −[R X]×, dp/dt = I.
      Eigen::Matrix3d skew;
      skew << 0, -RX.z(), RX.y(), RX.z(), 0, -RX.x(), -RX.y(), RX.x(), 0;
      J.leftCols<3>() = -dr_dp * skew;
      J.block<2, 3>(0, 3) = dr_dp;
      J.col(6) = s.focal * proj;  // d(residual)/d(log f)
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * r;
    }
    if (!options.refine_focal) {
      H.row(6).setZero();
      H.col(6).setZero();
      H(6, 6) = 1;
      g[6] = 0;
    }
    bool improved = false;
    for (int attempt = 0; attempt < 10; ++attempt) {
      Mat7 A = H;
      A.diagonal() += lambda * H.diagonal().cwiseMax(1e-9);
      const Vec7 delta = -A.ldlt().solve(g);
      if (!delta.allFinite()) break;
      State next{exp_so3(delta.head<3>()) * s.R, s.t + delta.segment<3>(3), s.focal * std::exp(delta[6])};
      const double next_cost = robust_cost(next, x, X, n, c2);
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
  if (s.R.allFinite() && s.t.allFinite() && std::isfinite(s.focal) && s.focal > 0 && cost <= result.initial_cost) {
    result.cam_from_world = CameraPose::from_matrix(s.R, s.t);
    result.focal = s.focal;
    result.success = true;
  }
  return result;
}

}  // namespace visloc
