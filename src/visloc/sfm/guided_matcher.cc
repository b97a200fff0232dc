#include "visloc/sfm/guided_matcher.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "visloc/util/error.h"

namespace visloc {

void GuidedMatchOptions::validate() const {
  if (!(max_sampson_px > 0) || !std::isfinite(max_sampson_px))
    throw_error(ErrorCode::kInvalidArgument, "guided matching: max_sampson_px must be positive, got ", max_sampson_px);
  if (!(max_ratio > 0 && max_ratio <= 1))
    throw_error(ErrorCode::kInvalidArgument, "guided matching: max_ratio must be in (0, 1], got ", max_ratio);
  if (!(max_angle_rad > 0 && max_angle_rad <= M_PI))
    throw_error(ErrorCode::kInvalidArgument, "guided matching: max_angle_rad must be in (0, pi], got ", max_angle_rad);
  if (min_matches < 1)
    throw_error(ErrorCode::kInvalidArgument, "guided matching: min_matches must be >= 1, got ", min_matches);
}

namespace {

Eigen::Matrix3d cross_matrix(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

// Dot product of two 128-byte descriptors (the compiler vectorizes it).
inline int32_t descriptor_dot(const uint8_t* a, const uint8_t* b) {
  int32_t s = 0;
  for (int d = 0; d < kDescriptorDim; ++d) s += int32_t(a[d]) * int32_t(b[d]);
  return s;
}

// Angle between two uint8 RootSIFT descriptors of norm ~512 from their dot.
inline double descriptor_angle(int32_t dot) {
  constexpr double kNorm = 1.0 / (512.0 * 512.0);
  return std::acos(std::clamp(dot * kNorm, -1.0, 1.0));
}

}  // namespace

TwoViewGeometry two_view_geometry(const PinholeCamera& camera_a, const CameraPose& a_from_world,
                                  const PinholeCamera& camera_b, const CameraPose& b_from_world) {
  if (!camera_a.has_focal || !camera_b.has_focal)
    throw_error(ErrorCode::kInvalidArgument, "guided matching needs known focal lengths");
  TwoViewGeometry g;
  const CameraPose b_from_a = b_from_world * a_from_world.inverse();
  g.b_from_a_rotation = b_from_a.rotation;
  g.baseline = b_from_a.translation.norm();
  if (g.baseline > 0) g.b_from_a_direction = b_from_a.translation / g.baseline;
  g.E = cross_matrix(g.b_from_a_direction) * b_from_a.rotation_matrix();
  Eigen::Matrix3d Ka_inv = Eigen::Matrix3d::Identity(), Kb_inv = Eigen::Matrix3d::Identity();
  Ka_inv(0, 0) = 1.0 / camera_a.focal;
  Ka_inv(1, 1) = 1.0 / camera_a.focal_y();
  Ka_inv(0, 2) = -camera_a.cx / camera_a.focal;
  Ka_inv(1, 2) = -camera_a.cy / camera_a.focal_y();
  Kb_inv(0, 0) = 1.0 / camera_b.focal;
  Kb_inv(1, 1) = 1.0 / camera_b.focal_y();
  Kb_inv(0, 2) = -camera_b.cx / camera_b.focal;
  Kb_inv(1, 2) = -camera_b.cy / camera_b.focal_y();
  g.F = Kb_inv.transpose() * g.E * Ka_inv;
  return g;
}

void CenteredKeypoints::assign(const FeatureSet& features, const PinholeCamera& camera) {
  if (!camera.has_focal) throw_error(ErrorCode::kInvalidArgument, "guided matching needs known focal lengths");
  focal = camera.focal;
  x.resize(features.size());
  y.resize(features.size());
  for (size_t i = 0; i < features.size(); ++i) {
    const auto& k = features.keypoints[i];
    const Eigen::Vector2d n = camera.normalize({k.x, k.y});
    x[i] = static_cast<float>(n.x() * focal);
    y[i] = static_cast<float>(n.y() * focal);
  }
}

GuidedMatcher::GuidedMatcher(const GuidedMatchOptions& options) : options_(options) { options_.validate(); }

const std::vector<FeatureMatch>& GuidedMatcher::match(const FeatureSet& features_a, const CenteredKeypoints& a,
                                                      const FeatureSet& features_b, const CenteredKeypoints& b,
                                                      const TwoViewGeometry& geometry) {
  matches_.clear();
  tentative_.clear();
  band_candidates_ = 0;
  const size_t na = a.size(), nb = b.size();
  if (na != features_a.size() || nb != features_b.size())
    throw_error(ErrorCode::kInternal, "guided matching: keypoints and features disagree");
  if (na == 0 || nb == 0 || geometry.baseline == 0) return matches_;

  // E in centred pixel coordinates (u = f · normalized): F_c = diag(1/fb,1/fb,1) E diag(1/fa,1/fa,1).
  // Scaled to unit norm: only ratios matter in the Sampson distance.
  Eigen::Matrix3d F = Eigen::Vector3d(1 / b.focal, 1 / b.focal, 1).asDiagonal() * geometry.E *
                      Eigen::Vector3d(1 / a.focal, 1 / a.focal, 1).asDiagonal();
  F /= F.norm();

  gb2_.resize(nb);
  band_.resize(nb + 8);  // tail padding read by the word-wise scan
  std::fill(band_.begin() + static_cast<std::ptrdiff_t>(nb), band_.end(), uint8_t{0});
  candidates_.resize(nb);
  best_dot_of_b_.assign(nb, -1);
  best_a_of_b_.assign(nb, 0);
  for (size_t j = 0; j < nb; ++j) {
    // F^T x_b, first two components.
    const double gx = F(0, 0) * b.x[j] + F(1, 0) * b.y[j] + F(2, 0);
    const double gy = F(0, 1) * b.x[j] + F(1, 1) * b.y[j] + F(2, 1);
    gb2_[j] = static_cast<float>(gx * gx + gy * gy);
  }

  const float t2 = static_cast<float>(options_.max_sampson_px * options_.max_sampson_px);
  const float* xb = b.x.data();
  const float* yb = b.y.data();
  const float* gb2 = gb2_.data();
  uint8_t* band = band_.data();
  const double cos_max = std::cos(options_.max_angle_rad);

  for (size_t i = 0; i < na; ++i) {
    const double lx = F(0, 0) * a.x[i] + F(0, 1) * a.y[i] + F(0, 2);
    const double ly = F(1, 0) * a.x[i] + F(1, 1) * a.y[i] + F(1, 2);
    const double lz = F(2, 0) * a.x[i] + F(2, 1) * a.y[i] + F(2, 2);
    const float l0 = static_cast<float>(lx), l1 = static_cast<float>(ly), l2 = static_cast<float>(lz);
    const float la2 = static_cast<float>(lx * lx + ly * ly);
    // Sampson: (x_b^T F x_a)^2 / (|F x_a|_12^2 + |F^T x_b|_12^2) <= t^2.
    for (size_t j = 0; j < nb; ++j) {
      const float e = l0 * xb[j] + l1 * yb[j] + l2;
      band[j] = static_cast<uint8_t>(e * e <= t2 * (la2 + gb2[j]));
    }
    size_t n = 0;
    for (size_t j = 0; j < nb; j += 8) {
      uint64_t word;
      std::memcpy(&word, band + j, 8);
      if (word == 0) continue;
      for (size_t k = j; k < std::min(j + 8, nb); ++k) {
        candidates_[n] = static_cast<uint32_t>(k);
        n += band[k];
      }
    }
    band_candidates_ += n;
    if (n == 0) continue;
    const uint8_t* da = features_a.descriptors.row(i);
    int32_t best = -1, second = -1;
    uint32_t best_j = 0;
    for (size_t c = 0; c < n; ++c) {
      const uint32_t j = candidates_[c];
      const int32_t dot = descriptor_dot(da, features_b.descriptors.row(j));
      if (dot > best) {
        second = best;
        best = dot;
        best_j = j;
      } else if (dot > second) {
        second = dot;
      }
      if (dot > best_dot_of_b_[j]) {
        best_dot_of_b_[j] = dot;
        best_a_of_b_[j] = static_cast<uint32_t>(i);
      }
    }
    const double best_angle = descriptor_angle(best);
    if (best * (1.0 / (512.0 * 512.0)) < cos_max) continue;
    if (second >= 0 && best_angle >= options_.max_ratio * descriptor_angle(second)) continue;
    tentative_.emplace_back(static_cast<uint32_t>(i), best_j);
  }
  for (const FeatureMatch& m : tentative_)
    if (!options_.cross_check || best_a_of_b_[m.second] == m.first) matches_.push_back(m);
  if (matches_.size() < static_cast<size_t>(options_.min_matches)) matches_.clear();
  return matches_;
}

std::vector<std::pair<size_t, size_t>> overlapping_pairs(const std::vector<CameraPose>& cam_from_world,
                                                         double max_distance, double max_angle_deg) {
  std::vector<std::pair<size_t, size_t>> pairs;
  const double cos_max = std::cos(max_angle_deg * M_PI / 180);
  for (size_t i = 0; i < cam_from_world.size(); ++i)
    for (size_t j = i + 1; j < cam_from_world.size(); ++j) {
      const CameraPose& a = cam_from_world[i];
      const CameraPose& b = cam_from_world[j];
      if ((a.center() - b.center()).norm() > max_distance) continue;
      if (a.viewing_direction().dot(b.viewing_direction()) < cos_max) continue;
      pairs.emplace_back(i, j);
    }
  return pairs;
}

}  // namespace visloc
