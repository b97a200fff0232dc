#include "visloc/geometry/point_uncertainty.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace visloc {

namespace {

constexpr double kLogMin = -24.0;  // log2 σ of code 0's successor's base
constexpr double kStepsPerOctave = 8.0;

uint8_t sigma_code(double sigma) {
  if (!(sigma > 0)) return sigma == 0 ? 0 : 255;  // NaN: unknown, the largest
  if (!std::isfinite(sigma)) return 255;
  const double level = std::round((std::log2(sigma) - kLogMin) * kStepsPerOctave);
  return static_cast<uint8_t>(std::clamp(level, 1.0, 255.0));
}

// Octahedral mapping of an axis (d and −d alike) to [-1, 1]²: d on the upper
// hemisphere, projected onto the diamond |x| + |y| ≤ 1, which the 45° turn
// (u, v) = (x + y, x − y) spreads over the whole square.
Eigen::Vector2d octahedral(Eigen::Vector3d d) {
  if (d.z() < 0) d = -d;
  const double l1 = std::abs(d.x()) + std::abs(d.y()) + std::abs(d.z());
  const double x = d.x() / l1, y = d.y() / l1;
  return Eigen::Vector2d(x + y, x - y);
}

uint8_t unit_code(double v) { return static_cast<uint8_t>(std::clamp(std::round((v + 1.0) * 127.5), 0.0, 255.0)); }
double unit_value(uint8_t c) { return static_cast<double>(c) / 127.5 - 1.0; }

}  // namespace

double point_sigma_from_code(uint8_t code) {
  if (code == 0) return 0;
  return std::exp2(static_cast<double>(code) / kStepsPerOctave + kLogMin);
}

PointUncertaintyCode encode_point_covariance(const Eigen::Matrix3d& covariance) {
  PointUncertaintyCode out{0, 0, 0, 0};
  if (!covariance.allFinite()) {
    // Unknown: the largest σ, along z.
    const Eigen::Vector2d o = octahedral(Eigen::Vector3d::UnitZ());
    return {unit_code(o.x()), unit_code(o.y()), 255, 255};
  }
  const Eigen::Matrix3d sym = 0.5 * (covariance + covariance.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(sym);
  const Eigen::Vector3d values = es.eigenvalues();  // ascending
  const Eigen::Vector3d axis = es.eigenvectors().col(2).normalized();
  if (values(2) < 0) {  // not a covariance: unknown, never "exact"
    const Eigen::Vector2d o = octahedral(axis.allFinite() ? axis : Eigen::Vector3d::UnitZ());
    return {unit_code(o.x()), unit_code(o.y()), 255, 255};
  }
  const Eigen::Vector2d o = octahedral(axis.allFinite() ? axis : Eigen::Vector3d::UnitZ());
  out[0] = unit_code(o.x());
  out[1] = unit_code(o.y());
  out[2] = sigma_code(std::sqrt(std::max(0.0, values(2))));
  out[3] = sigma_code(std::sqrt(std::max(0.0, values(1))));
  if (out[3] > out[2]) out[3] = out[2];
  return out;
}

Eigen::Matrix3d decode_point_covariance(const PointUncertaintyCode& code) {
  const double u = unit_value(code[0]), v = unit_value(code[1]);
  const double x = 0.5 * (u + v), y = 0.5 * (u - v);
  Eigen::Vector3d d(x, y, std::max(0.0, 1.0 - std::abs(x) - std::abs(y)));
  d.normalize();
  const double major = point_sigma_from_code(code[2]);
  const double minor = std::min(major, point_sigma_from_code(code[3]));
  return minor * minor * Eigen::Matrix3d::Identity() + (major * major - minor * minor) * d * d.transpose();
}

Eigen::Matrix3d triangulation_covariance(const Eigen::Vector3d& X, std::span<const TrackCamera> cameras,
                                         double noise_px) {
  Eigen::Matrix3d info = Eigen::Matrix3d::Zero();
  int views = 0;
  for (const TrackCamera& c : cameras) {
    const Eigen::Vector3d p = c.R * X + c.t;
    if (!(p.z() > 0)) continue;
    const double iz = 1.0 / p.z();
    Eigen::Matrix<double, 2, 3> B;
    B << c.fx * iz, 0, -c.fx * p.x() * iz * iz, 0, c.fy * iz, -c.fy * p.y() * iz * iz;
    const Eigen::Matrix<double, 2, 3> BR = B * c.R;
    info.noalias() += BR.transpose() * BR;
    ++views;
  }
  const double noise2 = noise_px * noise_px;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(info);
  const Eigen::Vector3d values = es.eigenvalues();  // ascending: values(0) the least-known direction's
  const double unknown = kMaxPointSigma * kMaxPointSigma;
  Eigen::Vector3d variances;
  for (int k = 0; k < 3; ++k) variances(k) = values(k) > 0 ? std::min(unknown, noise2 / values(k)) : unknown;
  if (views < 2 || !(values(0) > 1e-12 * values(2))) variances(0) = unknown;
  return es.eigenvectors() * variances.asDiagonal() * es.eigenvectors().transpose();
}

double keypoint_noise_from_reprojection_errors(std::span<const double> errors,
                                               std::span<const uint32_t> track_lengths) {
  const size_t n = std::min(errors.size(), track_lengths.size());
  double sum_sq = 0, dof = 0;
  for (size_t i = 0; i < n; ++i) {
    const double e = errors[i];
    const uint32_t k = track_lengths[i];
    if (k < 2 || !std::isfinite(e) || e < 0) continue;
    sum_sq += static_cast<double>(k) * (4.0 / std::numbers::pi) * e * e;
    dof += 2.0 * static_cast<double>(k) - 3.0;
  }
  return dof > 0 ? std::sqrt(sum_sq / dof) : 0.0;
}

}  // namespace visloc
