#include "visloc/pose/solvers/two_view.h"

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace visloc {

namespace {

// Similarity taking the points to centroid 0, mean distance √2.
Eigen::Matrix3d normalizing_transform(const Eigen::Vector2d* x, int n) {
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (int i = 0; i < n; ++i) c += x[i];
  c /= n;
  double d = 0;
  for (int i = 0; i < n; ++i) d += (x[i] - c).norm();
  d /= n;
  const double s = d > 1e-12 ? std::sqrt(2.0) / d : 1.0;
  Eigen::Matrix3d T;
  T << s, 0, -s * c.x(), 0, s, -s * c.y(), 0, 0, 1;
  return T;
}

Eigen::Vector3d apply(const Eigen::Matrix3d& T, const Eigen::Vector2d& x) { return T * Eigen::Vector3d(x.x(), x.y(), 1.0); }

// Real roots of c3 a³ + c2 a² + c1 a + c0 (companion matrix eigenvalues).
int real_cubic_roots(double c3, double c2, double c1, double c0, double roots[3]) {
  const double scale = std::max({std::abs(c3), std::abs(c2), std::abs(c1), std::abs(c0)});
  if (!(scale > 0)) return 0;
  if (std::abs(c3) < 1e-12 * scale) {  // quadratic (or linear)
    if (std::abs(c2) < 1e-12 * scale) {
      if (std::abs(c1) < 1e-12 * scale) return 0;
      roots[0] = -c0 / c1;
      return 1;
    }
    const double disc = c1 * c1 - 4 * c2 * c0;
    if (disc < 0) return 0;
    const double q = -0.5 * (c1 + std::copysign(std::sqrt(disc), c1));
    int n = 0;
    roots[n++] = q / c2;
    if (std::abs(q) > 0) roots[n++] = c0 / q;
    return n;
  }
  Eigen::Matrix3d companion;
  companion << -c2 / c3, -c1 / c3, -c0 / c3, 1, 0, 0, 0, 1, 0;
  const Eigen::EigenSolver<Eigen::Matrix3d> es(companion, false);
  int n = 0;
  for (int i = 0; i < 3; ++i) {
    const auto v = es.eigenvalues()[i];
    if (std::abs(v.imag()) <= 1e-10 * std::max(1.0, std::abs(v.real()))) roots[n++] = v.real();
  }
  return n;
}

}  // namespace

int solve_fundamental_7pt(const Eigen::Vector2d* x1, const Eigen::Vector2d* x2, std::array<Eigen::Matrix3d, 3>* out) {
  const Eigen::Matrix3d T1 = normalizing_transform(x1, 7), T2 = normalizing_transform(x2, 7);
  Eigen::MatrixXd A(7, 9);  // dynamic: GCC 12 warns on fixed-size JacobiSVD internals
  for (int i = 0; i < 7; ++i) {
    const Eigen::Vector3d p = apply(T1, x1[i]), q = apply(T2, x2[i]);
    A.row(i) << q.x() * p.x(), q.x() * p.y(), q.x(), q.y() * p.x(), q.y() * p.y(), q.y(), p.x(), p.y(), 1.0;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  const auto& s = svd.singularValues();
  if (!(s(6) > 1e-10 * s(0))) return 0;  // rank < 7: a null space of dimension > 2
  auto as_matrix = [](const Eigen::VectorXd& v) {
    Eigen::Matrix3d M;
    M << v(0), v(1), v(2), v(3), v(4), v(5), v(6), v(7), v(8);
    return M;
  };
  const Eigen::Matrix3d F1 = as_matrix(svd.matrixV().col(7)), F2 = as_matrix(svd.matrixV().col(8));
  // det(a F1 + (1 − a) F2) = c3 a³ + c2 a² + c1 a + c0, from its values at a = 0, 1, −1, 2.
  const double d0 = F2.determinant(), d1 = F1.determinant();
  const double dm1 = (2 * F2 - F1).determinant(), d2 = (2 * F1 - F2).determinant();
  const double c0 = d0, c2 = 0.5 * (d1 + dm1) - d0, odd = 0.5 * (d1 - dm1);  // odd = c3 + c1
  const double c3 = ((d2 - 4 * c2 - c0) - 2 * odd) / 6.0, c1 = odd - c3;
  double roots[3];
  const int n = real_cubic_roots(c3, c2, c1, c0, roots);
  int count = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Matrix3d Fn = roots[i] * F1 + (1 - roots[i]) * F2;
    Eigen::Matrix3d F = T2.transpose() * Fn * T1;
    const double norm = F.norm();
    if (!(norm > 0) || !F.allFinite()) continue;
    (*out)[count++] = F / norm;
  }
  return count;
}

int solve_homography_4pt(const Eigen::Vector2d* x1, const Eigen::Vector2d* x2, Eigen::Matrix3d* out) {
  const Eigen::Matrix3d T1 = normalizing_transform(x1, 4), T2 = normalizing_transform(x2, 4);
  Eigen::MatrixXd A(8, 9);
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector3d p = apply(T1, x1[i]), q = apply(T2, x2[i]);
    A.row(2 * i) << 0, 0, 0, -p.x(), -p.y(), -1, q.y() * p.x(), q.y() * p.y(), q.y();
    A.row(2 * i + 1) << p.x(), p.y(), 1, 0, 0, 0, -q.x() * p.x(), -q.x() * p.y(), -q.x();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  const auto& s = svd.singularValues();
  if (!(s(7) > 1e-10 * s(0))) return 0;  // three collinear points, coincident points
  const Eigen::VectorXd h = svd.matrixV().col(8);
  Eigen::Matrix3d Hn;
  Hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  Eigen::Matrix3d H = T2.inverse() * Hn * T1;
  if (!H.allFinite() || !(std::abs(H.determinant()) > 1e-12 * std::pow(H.norm(), 3))) return 0;
  *out = H / H.norm();
  return 1;
}

// ---- 5-point essential matrix --------------------------------------------

namespace {

// Polynomials of degree ≤ 3 in x, y, z; monomials in the order
// x³ x²y x²z xy² xyz xz² y³ y²z yz² z³ | x² xy xz y² yz z² | x y z | 1.
using Poly = std::array<double, 20>;
constexpr int kExponents[20][3] = {{3, 0, 0}, {2, 1, 0}, {2, 0, 1}, {1, 2, 0}, {1, 1, 1}, {1, 0, 2}, {0, 3, 0},
                                   {0, 2, 1}, {0, 1, 2}, {0, 0, 3}, {2, 0, 0}, {1, 1, 0}, {1, 0, 1}, {0, 2, 0},
                                   {0, 1, 1}, {0, 0, 2}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, 0, 0}};

int monomial_index(int a, int b, int c) {
  for (int i = 0; i < 20; ++i)
    if (kExponents[i][0] == a && kExponents[i][1] == b && kExponents[i][2] == c) return i;
  return -1;
}

// The product table: index of monomial i × monomial j (−1 above degree 3).
struct ProductTable {
  int index[20][20];
  ProductTable() {
    for (int i = 0; i < 20; ++i)
      for (int j = 0; j < 20; ++j) {
        const int a = kExponents[i][0] + kExponents[j][0], b = kExponents[i][1] + kExponents[j][1],
                  c = kExponents[i][2] + kExponents[j][2];
        index[i][j] = a + b + c <= 3 ? monomial_index(a, b, c) : -1;
      }
  }
};

Poly multiply(const Poly& p, const Poly& q) {
  static const ProductTable table;
  Poly r{};
  for (int i = 0; i < 20; ++i) {
    if (p[i] == 0) continue;
    for (int j = 0; j < 20; ++j) {
      if (q[j] == 0) continue;
      const int k = table.index[i][j];
      if (k >= 0) r[k] += p[i] * q[j];  // degrees never exceed 3 here (callers multiply ≤ 3 linear factors)
    }
  }
  return r;
}
Poly add(const Poly& p, const Poly& q, double qs = 1.0) {
  Poly r;
  for (int i = 0; i < 20; ++i) r[i] = p[i] + qs * q[i];
  return r;
}
Poly scaled(const Poly& p, double s) {
  Poly r;
  for (int i = 0; i < 20; ++i) r[i] = s * p[i];
  return r;
}

}  // namespace

int solve_essential_5pt(const Eigen::Vector2d* q1, const Eigen::Vector2d* q2, std::array<Eigen::Matrix3d, 10>* out) {
  Eigen::MatrixXd A(5, 9);
  for (int i = 0; i < 5; ++i) {
    const Eigen::Vector3d p(q1[i].x(), q1[i].y(), 1.0), q(q2[i].x(), q2[i].y(), 1.0);
    A.row(i) << q.x() * p.x(), q.x() * p.y(), q.x(), q.y() * p.x(), q.y() * p.y(), q.y(), p.x(), p.y(), 1.0;
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullV);
  if (!(svd.singularValues()(4) > 1e-10 * svd.singularValues()(0))) return 0;
  // X, Y, Z, W: the null space in a fixed, generic basis. E = xX + yY + zZ + W
  // misses an E with no W component, and the SVD's own basis can put one
  // there: two views that differ by a translation along a camera axis (R = I,
  // as same-heading street views of a synthetic city) give constraints with
  // structural zeros, and the cubic block below is then singular.
  static const Eigen::Matrix4d generic_rotation =  // immutable, computed once
      (Eigen::Matrix4d() << 0.8, -0.3, 0.2, 0.4, 0.1, 0.7, -0.5, 0.3, -0.4, 0.2, 0.6, 0.5, 0.3, 0.5, 0.2, -0.7)
          .finished()
          .householderQr()
          .householderQ();
  const Eigen::Matrix<double, 9, 4> N = svd.matrixV().rightCols(4) * generic_rotation;
  // E(x, y, z) entry by entry, linear: x X + y Y + z Z + W.
  Poly E[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      Poly p{};
      p[16] = N(3 * r + c, 0);
      p[17] = N(3 * r + c, 1);
      p[18] = N(3 * r + c, 2);
      p[19] = N(3 * r + c, 3);
      E[r][c] = p;
    }
  Eigen::Matrix<double, 10, 20> M;
  // det E.
  const Poly det = add(add(multiply(E[0][0], add(multiply(E[1][1], E[2][2]), multiply(E[1][2], E[2][1]), -1)),
                           multiply(E[0][1], add(multiply(E[1][0], E[2][2]), multiply(E[1][2], E[2][0]), -1)), -1),
                       multiply(E[0][2], add(multiply(E[1][0], E[2][1]), multiply(E[1][1], E[2][0]), -1)));
  for (int k = 0; k < 20; ++k) M(0, k) = det[k];
  // E Eᵀ (quadratic), its trace, and 2 E Eᵀ E − tr(E Eᵀ) E (cubic).
  Poly EEt[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      Poly s{};
      for (int k = 0; k < 3; ++k) s = add(s, multiply(E[i][k], E[j][k]));
      EEt[i][j] = s;
    }
  const Poly trace = add(add(EEt[0][0], EEt[1][1]), EEt[2][2]);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      Poly s{};
      for (int k = 0; k < 3; ++k) s = add(s, multiply(EEt[i][k], E[k][j]));
      const Poly row = add(scaled(s, 2.0), multiply(trace, E[i][j]), -1);
      for (int k = 0; k < 20; ++k) M(1 + 3 * i + j, k) = row[k];
    }
  // Gauss-Jordan: the cubic monomials in terms of the basis (degree ≤ 2).
  const Eigen::Matrix<double, 10, 10> cubic = M.leftCols<10>();
  const Eigen::FullPivLU<Eigen::Matrix<double, 10, 10>> lu(cubic);
  if (!lu.isInvertible()) return 0;
  const Eigen::Matrix<double, 10, 10> G = lu.solve(M.rightCols<10>());  // cubic_i = −G(i, :) · basis
  // Action matrix of x on the basis b = (x², xy, xz, y², yz, z², x, y, z, 1).
  Eigen::Matrix<double, 10, 10> action = Eigen::Matrix<double, 10, 10>::Zero();
  for (int k = 0; k < 6; ++k) action.row(k) = -G.row(k);  // x·x² = x³, x·xy = x²y, ..., x·z² = xz²
  action(6, 0) = 1;  // x·x = x²
  action(7, 1) = 1;  // x·y = xy
  action(8, 2) = 1;  // x·z = xz
  action(9, 6) = 1;  // x·1 = x
  // At a solution, b satisfies action · b = x b.
  const Eigen::EigenSolver<Eigen::Matrix<double, 10, 10>> es(action);
  if (es.info() != Eigen::Success) return 0;
  int count = 0;
  for (int i = 0; i < 10; ++i) {
    const auto lambda = es.eigenvalues()[i];
    if (std::abs(lambda.imag()) > 1e-8 * std::max(1.0, std::abs(lambda.real()))) continue;
    const Eigen::Matrix<std::complex<double>, 10, 1> v = es.eigenvectors().col(i);
    if (!(std::abs(v(9)) > 1e-12)) continue;
    const double x = (v(6) / v(9)).real(), y = (v(7) / v(9)).real(), z = (v(8) / v(9)).real();
    const Eigen::Matrix<double, 9, 1> e = x * N.col(0) + y * N.col(1) + z * N.col(2) + N.col(3);
    Eigen::Matrix3d Em;
    Em << e(0), e(1), e(2), e(3), e(4), e(5), e(6), e(7), e(8);
    const double norm = Em.norm();
    if (!(norm > 0) || !Em.allFinite()) continue;
    (*out)[count++] = Em / norm;
  }
  return count;
}

double symmetric_epipolar_distance(const Eigen::Matrix3d& F, const Eigen::Vector2d& x1, const Eigen::Vector2d& x2) {
  const Eigen::Vector3d p1(x1.x(), x1.y(), 1.0), p2(x2.x(), x2.y(), 1.0);
  const Eigen::Vector3d l2 = F * p1, l1 = F.transpose() * p2;
  const double e = std::abs(p2.dot(l2));
  const double n2 = l2.head<2>().norm(), n1 = l1.head<2>().norm();
  if (!(n1 > 0 && n2 > 0)) return std::numeric_limits<double>::infinity();
  return 0.5 * (e / n1 + e / n2);
}

}  // namespace visloc
