#include "visloc/pose/solvers/dlt6.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>
#include <cmath>

namespace visloc {

bool solve_dlt(const Eigen::Vector2d* points2d, const Eigen::Vector3d* points3d, int n, Matrix34d* projection) {
  if (n < 6) return false;
  // Normalizing similarities.
  Eigen::Vector2d c2 = Eigen::Vector2d::Zero();
  Eigen::Vector3d c3 = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    c2 += points2d[i];
    c3 += points3d[i];
  }
  c2 /= n;
  c3 /= n;
  double d2 = 0, d3 = 0;
  for (int i = 0; i < n; ++i) {
    d2 += (points2d[i] - c2).norm();
    d3 += (points3d[i] - c3).norm();
  }
  d2 /= n;
  d3 /= n;
  if (!(d2 > 0) || !(d3 > 0)) return false;
  const double s2 = std::sqrt(2.0) / d2, s3 = std::sqrt(3.0) / d3;

  Eigen::Matrix<double, 12, 12> AtA = Eigen::Matrix<double, 12, 12>::Zero();
  Eigen::Matrix<double, 12, 1> r1, r2;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d x = s2 * (points2d[i] - c2);
    const Eigen::Vector4d X = (s3 * (points3d[i] - c3)).homogeneous();
    r1 << X, Eigen::Vector4d::Zero(), -x.x() * X;
    r2 << Eigen::Vector4d::Zero(), X, -x.y() * X;
    AtA.selfadjointView<Eigen::Lower>().rankUpdate(r1);
    AtA.selfadjointView<Eigen::Lower>().rankUpdate(r2);
  }
  // Coplanar or collinear 3D points leave a null space of dimension > 1.
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d d = s3 * (points3d[i] - c3);
    cov.noalias() += d * d.transpose();
  }
  const double tr = cov.trace() / 3.0;
  if (!(cov.determinant() > 1e-9 * tr * tr * tr)) return false;
  // Null vector of AᵀA: inverse iteration on AᵀA + σI (σ tiny), which
  // converges in a few steps because the smallest eigenvalue is ≈ 0 and well
  // separated for non-degenerate input; the eigen-solver is the fallback.
  const Eigen::Matrix<double, 12, 12> H = AtA.selfadjointView<Eigen::Lower>();
  Eigen::Matrix<double, 12, 12> Hs = H;
  Hs.diagonal().array() += 1e-12 * H.trace();
  Eigen::LLT<Eigen::Matrix<double, 12, 12>> llt(Hs);
  Eigen::Matrix<double, 12, 1> p = Eigen::Matrix<double, 12, 1>::Constant(1.0 / std::sqrt(12.0));
  // Stops when an iteration changes p by < 1e-13, or accepts after 10
  // iterations a change < 1e-7 (samples with outliers have a small
  // eigenvalue gap; their models only need to be scored).
  bool converged = false;
  if (llt.info() == Eigen::Success) {
    double change = 1;
    for (int it = 0; it < 10 && change >= 1e-13; ++it) {
      const Eigen::Matrix<double, 12, 1> next = llt.solve(p).normalized();
      change = std::min((next - p).norm(), (next + p).norm());
      p = next;
    }
    converged = change < 1e-7;
  }
  if (!converged || !p.allFinite()) {
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 12, 12>> es(H);
    if (es.info() != Eigen::Success) return false;
    p = es.eigenvectors().col(0);
  }
  Matrix34d Pn;
  Pn << p.segment<4>(0).transpose(), p.segment<4>(4).transpose(), p.segment<4>(8).transpose();

  Eigen::Matrix3d T2 = Eigen::Matrix3d::Identity();
  T2(0, 0) = T2(1, 1) = s2;
  T2.block<2, 1>(0, 2) = -s2 * c2;
  Eigen::Matrix3d T2inv = Eigen::Matrix3d::Identity();
  T2inv(0, 0) = T2inv(1, 1) = 1.0 / s2;
  T2inv.block<2, 1>(0, 2) = c2;
  Eigen::Matrix4d T3 = Eigen::Matrix4d::Identity();
  T3.topLeftCorner<3, 3>() *= s3;
  T3.block<3, 1>(0, 3) = -s3 * c3;
  Matrix34d P = T2inv * Pn * T3;

  // Cheirality: the majority of the input points in front.
  int front = 0;
  for (int i = 0; i < n; ++i) front += (P.row(2).dot(points3d[i].homogeneous()) > 0) ? 1 : -1;
  if (front < 0) P = -P;
  if (P.leftCols<3>().determinant() <= 0) return false;
  const double scale = P.norm();
  if (!(scale > 0) || !P.allFinite()) return false;
  *projection = P / scale;
  return true;
}

bool decompose_projection(const Matrix34d& projection, DecomposedProjection* out) {
  Matrix34d P = projection;
  Eigen::Matrix3d M = P.leftCols<3>();
  double det = M.determinant();
  if (det == 0.0 || !std::isfinite(det)) return false;
  if (det < 0) {
    P = -P;
    M = -M;
  }
  // RQ via QR of the row-reversed transpose: with J the exchange matrix,
  // (J M)ᵀ = Q' R'  ⇒  M = (J R'ᵀ J)(J Q'ᵀ) = K R.
  Eigen::Matrix3d J = Eigen::Matrix3d::Zero();
  J(0, 2) = J(1, 1) = J(2, 0) = 1;
  Eigen::HouseholderQR<Eigen::Matrix3d> qr((J * M).transpose());
  const Eigen::Matrix3d Rq = qr.matrixQR().triangularView<Eigen::Upper>();
  const Eigen::Matrix3d Q = qr.householderQ();
  Eigen::Matrix3d K = J * Rq.transpose() * J;
  Eigen::Matrix3d R = J * Q.transpose();
  // Positive diagonal of K.
  for (int i = 0; i < 3; ++i)
    if (K(i, i) < 0) {
      K.col(i) = -K.col(i);
      R.row(i) = -R.row(i);
    }
  if (R.determinant() < 0) return false;  // cannot happen with det(M) > 0; kept as a guard
  const double lambda = K(2, 2);
  if (!(lambda > 0)) return false;
  K /= lambda;
  out->calibration = K;
  out->rotation = R;
  out->translation = K.inverse() * P.col(3) / lambda;
  out->focal = 0.5 * (K(0, 0) + K(1, 1));
  return out->focal > 0 && out->translation.allFinite();
}

}  // namespace visloc
