#include "visloc/geo/similarity_transform.h"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "visloc/util/error.h"
#include "visloc/util/random.h"

namespace visloc {

Similarity3d Similarity3d::inverse() const {
  Similarity3d inv;
  inv.scale = 1.0 / scale;
  inv.rotation = rotation.transpose();
  inv.translation = -(inv.scale * (inv.rotation * translation));
  return inv;
}

Eigen::Matrix4d Similarity3d::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = scale * rotation;
  m.topRightCorner<3, 1>() = translation;
  return m;
}

void SimilarityRansacOptions::validate() const {
  if (!(inlier_threshold > 0))
    throw_error(ErrorCode::kInvalidArgument, "similarity RANSAC: inlier_threshold must be positive, got ", inlier_threshold);
  if (max_iterations < 1)
    throw_error(ErrorCode::kInvalidArgument, "similarity RANSAC: max_iterations must be >= 1, got ", max_iterations);
  if (min_inliers < 3)
    throw_error(ErrorCode::kInvalidArgument, "similarity RANSAC: min_inliers must be >= 3, got ", min_inliers);
}

namespace {

bool fit(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
         const std::vector<int>& idx, Similarity3d& out) {
  const int n = static_cast<int>(idx.size());
  Eigen::Matrix3Xd a(3, n), b(3, n);
  for (int i = 0; i < n; ++i) {
    a.col(i) = src[idx[i]];
    b.col(i) = dst[idx[i]];
  }
  // Degenerate when the source points are (nearly) collinear or coincident.
  Eigen::Matrix3Xd centred = a.colwise() - a.rowwise().mean();
  Eigen::JacobiSVD<Eigen::Matrix3Xd> svd(centred);
  const auto sv = svd.singularValues();
  if (!(sv(0) > 0) || sv(1) < 1e-9 * sv(0)) return false;
  const Eigen::Matrix4d m = Eigen::umeyama(a, b, true);
  const double s = std::cbrt(m.topLeftCorner<3, 3>().determinant());
  if (!(s > 0) || !std::isfinite(s)) return false;
  out.scale = s;
  out.rotation = m.topLeftCorner<3, 3>() / s;
  out.translation = m.topRightCorner<3, 1>();
  return true;
}

// Truncated quadratic (MSAC) score of a transform: inliers within the
// threshold and their cost (outliers cost thr²).
void score_similarity(const Similarity3d& t, const std::vector<Eigen::Vector3d>& src,
                      const std::vector<Eigen::Vector3d>& dst, double thr2, int& count, double& cost) {
  count = 0;
  cost = 0;
  for (size_t i = 0; i < src.size(); ++i) {
    const double r2 = (t.apply(src[i]) - dst[i]).squaredNorm();
    if (r2 < thr2) {
      ++count;
      cost += r2;
    } else {
      cost += thr2;
    }
  }
}

// Residuals, inlier mask and their statistics for out.transform.
void fill_residuals(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst, double threshold,
                    SimilarityEstimate& out) {
  const size_t n = src.size();
  out.inliers.assign(n, 0);
  out.residuals.resize(n);
  out.inlier_count = 0;
  double sum2 = 0;
  for (size_t i = 0; i < n; ++i) {
    out.residuals[i] = (out.transform.apply(src[i]) - dst[i]).norm();
    if (out.residuals[i] < threshold) {
      out.inliers[i] = 1;
      ++out.inlier_count;
      sum2 += out.residuals[i] * out.residuals[i];
    }
  }
  out.rms_residual = out.inlier_count ? std::sqrt(sum2 / out.inlier_count) : 0.0;
  std::vector<double> r = out.residuals;
  std::sort(r.begin(), r.end());
  out.median_residual = r.size() % 2 ? r[r.size() / 2] : 0.5 * (r[r.size() / 2 - 1] + r[r.size() / 2]);
  out.max_residual = r.back();
}

}  // namespace

Similarity3d estimate_similarity(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst) {
  if (src.size() != dst.size() || src.size() < 3)
    throw_error(ErrorCode::kInvalidArgument, "similarity: need at least 3 point pairs, got ", src.size(), " and ", dst.size());
  std::vector<int> all(src.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
  Similarity3d t;
  if (!fit(src, dst, all, t))
    throw_error(ErrorCode::kInvalidArgument, "similarity: points are collinear or coincident");
  return t;
}

SimilarityEstimate estimate_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                              const std::vector<Eigen::Vector3d>& dst,
                                              const SimilarityRansacOptions& options) {
  options.validate();
  const int n = static_cast<int>(src.size());
  if (src.size() != dst.size() || n < 3)
    throw_error(ErrorCode::kInvalidArgument, "similarity: need at least 3 point pairs, got ", src.size(), " and ", dst.size());
  RandomGenerator rng(options.seed);
  auto pick = [&rng, n] { return static_cast<int>(rng.below(static_cast<uint32_t>(n))); };
  const double thr2 = options.inlier_threshold * options.inlier_threshold;
  int best_count = -1;
  double best_cost = INFINITY;
  Similarity3d best;
  std::vector<int> sample(3);
  // With few points, every triple is tried; otherwise random triples.
  const bool exhaustive = n <= 20;
  int iterations = 0;
  auto consider = [&](const std::vector<int>& s) {
    Similarity3d t;
    if (!fit(src, dst, s, t)) return;
    int count;
    double cost;
    score_similarity(t, src, dst, thr2, count, cost);
    if (count > best_count || (count == best_count && cost < best_cost)) {
      best_count = count;
      best_cost = cost;
      best = t;
    }
  };
  if (exhaustive) {
    for (int a = 0; a < n; ++a)
      for (int b = a + 1; b < n; ++b)
        for (int c = b + 1; c < n; ++c) consider({a, b, c});
  } else {
    for (; iterations < options.max_iterations; ++iterations) {
      sample[0] = pick();
      do sample[1] = pick(); while (sample[1] == sample[0]);
      do sample[2] = pick(); while (sample[2] == sample[0] || sample[2] == sample[1]);
      consider(sample);
      if (best_count == n) break;
    }
  }
  if (best_count < options.min_inliers)
    throw_error(ErrorCode::kInvalidArgument, "similarity: no transform has ", options.min_inliers,
                " inliers within ", options.inlier_threshold, " m (best: ", std::max(best_count, 0), " of ", n, ")");
  // Refit on the inliers (twice: the refit can change the inlier set).
  SimilarityEstimate out;
  out.transform = best;
  for (int round = 0; round < 2; ++round) {
    std::vector<int> inl;
    for (int i = 0; i < n; ++i)
      if ((out.transform.apply(src[i]) - dst[i]).squaredNorm() < thr2) inl.push_back(i);
    Similarity3d refit;
    if (static_cast<int>(inl.size()) >= 3 && fit(src, dst, inl, refit)) out.transform = refit;
  }
  fill_residuals(src, dst, options.inlier_threshold, out);
  return out;
}

namespace {

// Rotation taking unit vector a onto unit vector b.
Eigen::Matrix3d align(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return Eigen::Quaterniond::FromTwoVectors(a, b).toRotationMatrix();
}

// 4-DoF least squares: x already levelled (up = +z); returns s, yaw, t.
bool fit_upright(const std::vector<Eigen::Vector3d>& x, const std::vector<Eigen::Vector3d>& y, const std::vector<int>& idx,
                 const Eigen::Matrix3d& level, Similarity3d& out) {
  const int n = static_cast<int>(idx.size());
  if (n < 2) return false;
  Eigen::Vector2d mx = Eigen::Vector2d::Zero(), my = Eigen::Vector2d::Zero();
  double mzx = 0, mzy = 0;
  for (int i : idx) {
    mx += x[i].head<2>();
    my += y[i].head<2>();
    mzx += x[i].z();
    mzy += y[i].z();
  }
  mx /= n;
  my /= n;
  mzx /= n;
  mzy /= n;
  // 2D Procrustes with scale on the horizontal components (complex-number form).
  double a = 0, b = 0, sxx = 0;
  for (int i : idx) {
    const Eigen::Vector2d p = x[i].head<2>() - mx, q = y[i].head<2>() - my;
    a += p.x() * q.x() + p.y() * q.y();
    b += p.x() * q.y() - p.y() * q.x();
    sxx += p.squaredNorm();
  }
  if (!(sxx > 1e-12)) return false;
  const double yaw = std::atan2(b, a);
  const double s = std::hypot(a, b) / sxx;
  if (!(s > 0) || !std::isfinite(s)) return false;
  const Eigen::Matrix3d rz = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  out.scale = s;
  out.rotation = rz * level;
  const Eigen::Vector2d t2 = my - s * (rz.topLeftCorner<2, 2>() * mx);
  out.translation = {t2.x(), t2.y(), mzy - s * mzx};
  return true;
}

}  // namespace

SimilarityEstimate estimate_upright_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                                      const std::vector<Eigen::Vector3d>& dst,
                                                      const Eigen::Vector3d& src_up,
                                                      const SimilarityRansacOptions& options) {
  options.validate();
  const int n = static_cast<int>(src.size());
  if (src.size() != dst.size() || n < 2)
    throw_error(ErrorCode::kInvalidArgument, "upright similarity: need at least 2 point pairs, got ", src.size(),
                " and ", dst.size());
  if (!(src_up.norm() > 0)) throw_error(ErrorCode::kInvalidArgument, "upright similarity: the up vector is zero");
  const Eigen::Matrix3d level = align(src_up.normalized(), Eigen::Vector3d::UnitZ());
  std::vector<Eigen::Vector3d> x(n);
  for (int i = 0; i < n; ++i) x[i] = level * src[i];
  const double thr2 = options.inlier_threshold * options.inlier_threshold;
  RandomGenerator rng(options.seed);
  auto pick = [&rng, n] { return static_cast<int>(rng.below(static_cast<uint32_t>(n))); };
  int best_count = -1;
  double best_cost = INFINITY;
  Similarity3d best;
  auto consider = [&](int i, int j) {
    Similarity3d t;
    if (!fit_upright(x, dst, {i, j}, level, t)) return;
    int count = 0;
    double cost = 0;
    score_similarity(t, src, dst, thr2, count, cost);
    if (count > best_count || (count == best_count && cost < best_cost)) {
      best_count = count;
      best_cost = cost;
      best = t;
    }
  };
  if (n <= 60) {
    for (int i = 0; i < n; ++i)
      for (int j = i + 1; j < n; ++j) consider(i, j);
  } else {
    for (int it = 0; it < options.max_iterations; ++it) {
      const int i = pick();
      int j = pick();
      if (i == j) continue;
      consider(i, j);
    }
  }
  const int min_inliers = std::min(options.min_inliers, n);
  if (best_count < std::max(2, min_inliers))
    throw_error(ErrorCode::kInvalidArgument, "upright similarity: no transform has ", min_inliers, " inliers within ",
                options.inlier_threshold, " m (best: ", std::max(best_count, 0), " of ", n, ")");
  SimilarityEstimate out;
  out.transform = best;
  for (int round = 0; round < 2; ++round) {
    std::vector<int> inl;
    for (int i = 0; i < n; ++i)
      if ((out.transform.apply(src[i]) - dst[i]).squaredNorm() < thr2) inl.push_back(i);
    Similarity3d refit;
    if (inl.size() >= 2 && fit_upright(x, dst, inl, level, refit)) out.transform = refit;
  }
  fill_residuals(src, dst, options.inlier_threshold, out);
  return out;
}

SimilarityEstimate estimate_street_similarity_ransac(const std::vector<Eigen::Vector3d>& src,
                                                     const std::vector<Eigen::Vector3d>& dst,
                                                     const Eigen::Vector3d& src_up,
                                                     const SimilarityRansacOptions& options) {
  SimilarityEstimate best = estimate_upright_similarity_ransac(src, dst, src_up, options);
  if (src.size() < 4) return best;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : src) mean += p;
  mean /= static_cast<double>(src.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : src) cov += (p - mean) * (p - mean).transpose();
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues();  // ascending
  if (!(std::sqrt(ev[1]) >= 0.1 * std::sqrt(ev[2]))) return best;
  try {
    SimilarityEstimate full = estimate_similarity_ransac(src, dst, options);
    // The upright model is nested in the full one, so the full fit always
    // has the lower RMS: require a clear gain, not a fit to GPS noise.
    if (full.inlier_count >= best.inlier_count && full.rms_residual < 0.8 * best.rms_residual) best = std::move(full);
  } catch (const Error&) {
    // degenerate for the full fit: keep the upright one
  }
  return best;
}


}  // namespace visloc
