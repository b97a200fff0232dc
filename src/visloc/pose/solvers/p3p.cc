#include "visloc/pose/solvers/p3p.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cmath>
#include <numbers>

namespace visloc {
namespace {

int solve_quadratic_real(double a, double b, double c, double roots[2]) {
  if (a == 0.0) {
    if (b == 0.0) return 0;
    roots[0] = -c / b;
    return 1;
  }
  const double disc = b * b - 4 * a * c;
  if (disc < 0) return 0;
  const double s = std::sqrt(disc);
  // Numerically stable pair of roots.
  const double q = -0.5 * (b + (b >= 0 ? s : -s));
  if (q == 0.0) {
    roots[0] = 0.0;
    return 1;
  }
  roots[0] = q / a;
  roots[1] = c / q;
  return 2;
}

double det3(const Eigen::Matrix3d& m) { return m.determinant(); }

// Residuals of the three distance equations Λᵀ M_ij Λ − a_ij.
struct DepthEquations {
  double b12, b13, b23, a12, a13, a23;
  Eigen::Vector3d residual(const Eigen::Vector3d& l) const {
    return {l[0] * l[0] + l[1] * l[1] + b12 * l[0] * l[1] - a12,
            l[0] * l[0] + l[2] * l[2] + b13 * l[0] * l[2] - a13,
            l[1] * l[1] + l[2] * l[2] + b23 * l[1] * l[2] - a23};
  }
  Eigen::Matrix3d jacobian(const Eigen::Vector3d& l) const {
    Eigen::Matrix3d j;
    j << 2 * l[0] + b12 * l[1], 2 * l[1] + b12 * l[0], 0,  //
        2 * l[0] + b13 * l[2], 0, 2 * l[2] + b13 * l[0],   //
        0, 2 * l[1] + b23 * l[2], 2 * l[2] + b23 * l[1];
    return j;
  }
};

}  // namespace

int solve_cubic_real(double c3, double c2, double c1, double c0, double roots[3]) {
  const double scale = std::max({std::abs(c3), std::abs(c2), std::abs(c1), std::abs(c0)});
  if (scale == 0.0) return 0;
  if (std::abs(c3) < 1e-14 * scale) return solve_quadratic_real(c2, c1, c0, roots);
  const double B = c2 / c3, C = c1 / c3, D = c0 / c3;
  // Depressed cubic t³ + p t + q with x = t − B/3.
  const double p = C - B * B / 3.0;
  const double q = 2.0 * B * B * B / 27.0 - B * C / 3.0 + D;
  const double disc = q * q / 4.0 + p * p * p / 27.0;
  int n = 0;
  if (disc > 0) {
    const double s = std::sqrt(disc);
    roots[n++] = std::cbrt(-q / 2.0 + s) + std::cbrt(-q / 2.0 - s) - B / 3.0;
  } else if (p == 0.0) {
    roots[n++] = -B / 3.0;
  } else {
    const double r = 2.0 * std::sqrt(-p / 3.0);
    const double arg = std::clamp(3.0 * q / (p * r), -1.0, 1.0);
    const double phi = std::acos(arg) / 3.0;
    for (int k = 0; k < 3; ++k) roots[n++] = r * std::cos(phi - 2.0 * std::numbers::pi * k / 3.0) - B / 3.0;
  }
  // Newton polish on the monic cubic.
  for (int i = 0; i < n; ++i) {
    double x = roots[i];
    for (int it = 0; it < 3; ++it) {
      const double f = ((x + B) * x + C) * x + D;
      const double df = (3 * x + 2 * B) * x + C;
      if (df == 0.0) break;
      x -= f / df;
    }
    if (std::isfinite(x)) roots[i] = x;
  }
  return n;
}

namespace {

// The three correspondences as P3P sees them: unit bearings, the distance
// equations and their conics M_ij.
struct P3PProblem {
  Eigen::Vector3d y[3];  // unit bearings
  DepthEquations eq;
  double max_a = 0;  // largest squared side of the world triangle
  Eigen::Matrix3d M12, M13, M23;
};

// Normalizes the bearings and sets up the equations; false for degenerate
// input (zero or non-finite bearings, coincident or collinear world points,
// parallel rays).
bool set_up_problem(const std::array<Eigen::Vector3d, 3>& bearings, const std::array<Eigen::Vector3d, 3>& points,
                    P3PProblem* pb) {
  Eigen::Vector3d* y = pb->y;
  for (int i = 0; i < 3; ++i) {
    const double nrm = bearings[i].norm();
    if (!(nrm > 0) || !std::isfinite(nrm)) return false;
    y[i] = bearings[i] / nrm;
  }
  const Eigen::Vector3d& x1 = points[0];
  const Eigen::Vector3d& x2 = points[1];
  const Eigen::Vector3d& x3 = points[2];
  DepthEquations& eq = pb->eq;
  eq.a12 = (x1 - x2).squaredNorm();
  eq.a13 = (x1 - x3).squaredNorm();
  eq.a23 = (x2 - x3).squaredNorm();
  eq.b12 = -2.0 * y[0].dot(y[1]);
  eq.b13 = -2.0 * y[0].dot(y[2]);
  eq.b23 = -2.0 * y[1].dot(y[2]);
  // Degenerate: coincident or collinear world points, parallel rays.
  const double area2 = (x2 - x1).cross(x3 - x1).squaredNorm();
  pb->max_a = std::max({eq.a12, eq.a13, eq.a23});
  const double max_a = pb->max_a;
  if (!(max_a > 0) || area2 < 1e-20 * max_a * max_a) return false;
  if (y[0].cross(y[1]).squaredNorm() < 1e-24 || y[0].cross(y[2]).squaredNorm() < 1e-24 ||
      y[1].cross(y[2]).squaredNorm() < 1e-24)
    return false;

  pb->M12 << 1, eq.b12 / 2, 0, eq.b12 / 2, 1, 0, 0, 0, 0;
  pb->M13 << 1, 0, eq.b13 / 2, 0, 0, 0, eq.b13 / 2, 0, 1;
  pb->M23 << 0, 0, 0, 0, 1, eq.b23 / 2, 0, eq.b23 / 2, 1;
  return true;
}

// Real roots γ of the cubic det(D1 + γ D2) = 0; returns how many.
int solve_gamma_cubic(const Eigen::Matrix3d& D1, const Eigen::Matrix3d& D2, double gammas[3]) {
  // det(D1 + γ D2) = c0 + c1 γ + c2 γ² + c3 γ³ by multilinearity in columns.
  const double c3 = det3(D2), c0 = det3(D1);
  double c1 = 0, c2 = 0;
  for (int i = 0; i < 3; ++i) {
    Eigen::Matrix3d a = D1, b = D2;
    a.col(i) = D2.col(i);
    b.col(i) = D1.col(i);
    c1 += det3(a);
    c2 += det3(b);
  }
  return solve_cubic_real(c3, c2, c1, c0, gammas);
}

// The degenerate conic D0 as a pair of real lines nᵀΛ = 0 (writes the two
// normals), or two complex lines meeting in one real point (writes that point
// and sets *single_point). Returns how many vectors were written (0 when the
// eigen-decomposition fails).
int degenerate_conic_lines(const Eigen::Matrix3d& D0, Eigen::Vector3d directions_or_normals[2], bool* single_point) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(D0);
  if (es.info() != Eigen::Success) return 0;
  const Eigen::Vector3d ev = es.eigenvalues();
  // The eigenvalue closest to zero belongs to the null direction.
  int null_idx = 0;
  for (int k = 1; k < 3; ++k)
    if (std::abs(ev[k]) < std::abs(ev[null_idx])) null_idx = k;
  const int ia = (null_idx + 1) % 3, ib = (null_idx + 2) % 3;
  int num_lines = 0;
  *single_point = false;
  if (ev[ia] * ev[ib] < 0) {
    const int ip = ev[ia] > 0 ? ia : ib, in = ev[ia] > 0 ? ib : ia;
    const double s = std::sqrt(-ev[in] / ev[ip]);
    directions_or_normals[num_lines++] = es.eigenvectors().col(ip) + s * es.eigenvectors().col(in);
    directions_or_normals[num_lines++] = es.eigenvectors().col(ip) - s * es.eigenvectors().col(in);
  } else {
    // Two complex lines meeting in one real point: Λ ∝ the null vector.
    directions_or_normals[num_lines++] = es.eigenvectors().col(null_idx);
    *single_point = true;
  }
  return num_lines;
}

// Depth directions on the plane nᵀΛ = 0 (n = `normal`); returns how many.
int directions_in_plane(const Eigen::Vector3d& normal, const P3PProblem& pb, Eigen::Vector3d dirs[2]) {
  int num_dirs = 0;
  // Basis (u, v) of the plane nᵀΛ = 0; on it, a12 Q23 − a23 Q12 = 0 fixes the direction.
  const Eigen::Vector3d n = normal.normalized();
  Eigen::Vector3d u = n.unitOrthogonal();
  Eigen::Vector3d v = n.cross(u);
  Eigen::Matrix<double, 3, 2> B;
  B << u, v;
  const Eigen::Matrix2d G = pb.eq.a12 * (B.transpose() * pb.M23 * B) - pb.eq.a23 * (B.transpose() * pb.M12 * B);
  double r[2];
  if (std::abs(G(0, 0)) >= std::abs(G(1, 1))) {
    const int nr = solve_quadratic_real(G(0, 0), 2 * G(0, 1), G(1, 1), r);  // r = α/β
    for (int k = 0; k < nr; ++k) dirs[num_dirs++] = r[k] * u + v;
  } else {
    const int nr = solve_quadratic_real(G(1, 1), 2 * G(0, 1), G(0, 0), r);  // r = β/α
    for (int k = 0; k < nr; ++k) dirs[num_dirs++] = u + r[k] * v;
  }
  return num_dirs;
}

// Scales a depth direction to a23, refines it by Gauss-Newton and adds it to
// `depths` when all three equations hold and it is new (at most 4).
void add_depth_candidate(const Eigen::Vector3d& direction, const P3PProblem& pb, Eigen::Vector3d depths[4],
                         int* num_depths) {
  const DepthEquations& eq = pb.eq;
  const double max_a = pb.max_a;
  Eigen::Vector3d l = direction;
  const double q = l.dot(pb.M23 * l);
  if (!(q > 0)) return;
  l *= std::sqrt(eq.a23 / q);
  if (l.sum() < 0) l = -l;
  if (l.minCoeff() <= 0) return;
  // Gauss-Newton on the three equations.
  for (int it = 0; it < 5; ++it) {
    const Eigen::Vector3d f = eq.residual(l);
    if (f.cwiseAbs().maxCoeff() < 1e-15 * max_a) break;
    const Eigen::Matrix3d J = eq.jacobian(l);
    const double dj = J.determinant();
    if (std::abs(dj) < 1e-300) break;
    l -= J.inverse() * f;
  }
  const Eigen::Vector3d f = eq.residual(l);
  if (!l.allFinite() || l.minCoeff() <= 0 || f.cwiseAbs().maxCoeff() > 1e-6 * max_a) return;
  bool duplicate = false;
  for (int k = 0; k < *num_depths; ++k)
    if ((depths[k] - l).norm() < 1e-8 * l.norm()) duplicate = true;
  if (!duplicate && *num_depths < 4) depths[(*num_depths)++] = l;
}

// Rigid alignment: the frame of the world triangle, X = [x1−x2, x1−x3,
// (x1−x2)×(x1−x3)], maps to the camera triangle's frame Y, so R = Y X⁻¹
// (exact for exact depths; the depths were refined) and t = c1 − R x1.
int poses_from_depths(const P3PProblem& pb, const std::array<Eigen::Vector3d, 3>& points,
                      const Eigen::Vector3d depths[4], int num_depths, std::array<Matrix34d, 4>* solutions) {
  const Eigen::Vector3d* y = pb.y;
  const Eigen::Vector3d& x1 = points[0];
  const Eigen::Vector3d& x2 = points[1];
  const Eigen::Vector3d& x3 = points[2];
  int count = 0;
  Eigen::Matrix3d X;
  X.col(0) = x1 - x2;
  X.col(1) = x1 - x3;
  X.col(2) = X.col(0).cross(X.col(1));
  const Eigen::Matrix3d Xinv = X.inverse();
  for (int k = 0; k < num_depths; ++k) {
    const Eigen::Vector3d c1 = depths[k][0] * y[0], c2 = depths[k][1] * y[1], c3 = depths[k][2] * y[2];
    Eigen::Matrix3d Y;
    Y.col(0) = c1 - c2;
    Y.col(1) = c1 - c3;
    Y.col(2) = Y.col(0).cross(Y.col(1));
    const Eigen::Matrix3d R = Y * Xinv;
    if (!R.allFinite()) continue;
    (*solutions)[count].leftCols<3>() = R;
    (*solutions)[count].col(3) = c1 - R * x1;
    ++count;
  }
  return count;
}

}  // namespace

int solve_p3p(const std::array<Eigen::Vector3d, 3>& bearings, const std::array<Eigen::Vector3d, 3>& points,
              std::array<Matrix34d, 4>* solutions) {
  P3PProblem pb;
  if (!set_up_problem(bearings, points, &pb)) return 0;
  const Eigen::Matrix3d D1 = pb.eq.a23 * pb.M12 - pb.eq.a12 * pb.M23;
  const Eigen::Matrix3d D2 = pb.eq.a23 * pb.M13 - pb.eq.a13 * pb.M23;
  double gammas[3];
  const int num_gammas = solve_gamma_cubic(D1, D2, gammas);

  // The first root γ that yields depths: on each line of the degenerate
  // conic D0 = D1 + γ D2, candidate depth directions, refined and kept.
  Eigen::Vector3d depths[4];
  int num_depths = 0;
  for (int g = 0; g < num_gammas && num_depths == 0; ++g) {
    const Eigen::Matrix3d D0 = D1 + gammas[g] * D2;
    Eigen::Vector3d directions_or_normals[2];
    bool single_point = false;
    const int num_lines = degenerate_conic_lines(D0, directions_or_normals, &single_point);
    for (int li = 0; li < num_lines; ++li) {
      Eigen::Vector3d dirs[2];
      int num_dirs = 0;
      if (single_point) {
        dirs[num_dirs++] = directions_or_normals[li];
      } else {
        num_dirs = directions_in_plane(directions_or_normals[li], pb, dirs);
      }
      for (int d = 0; d < num_dirs; ++d) add_depth_candidate(dirs[d], pb, depths, &num_depths);
    }
  }
  if (num_depths == 0) return 0;
  return poses_from_depths(pb, points, depths, num_depths, solutions);
}

}  // namespace visloc
