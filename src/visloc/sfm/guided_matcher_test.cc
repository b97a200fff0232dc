#include "visloc/sfm/guided_matcher.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>

#include "visloc/util/error.h"

namespace visloc {
namespace {

// A random uint8 RootSIFT-like descriptor: non-negative, norm ~512.
void random_descriptor(std::mt19937& rng, uint8_t* out) {
  std::gamma_distribution<double> g(0.5, 1.0);
  double v[kDescriptorDim], n = 0;
  for (double& x : v) n += (x = g(rng)) * x;
  for (int d = 0; d < kDescriptorDim; ++d) out[d] = static_cast<uint8_t>(std::min(255.0, std::round(512 * v[d] / std::sqrt(n))));
}

void noisy_copy(std::mt19937& rng, const uint8_t* in, double sigma, uint8_t* out) {
  std::normal_distribution<double> noise(0, sigma);
  double v[kDescriptorDim], n = 0;
  for (int d = 0; d < kDescriptorDim; ++d) n += (v[d] = std::max(0.0, in[d] + noise(rng))) * v[d];
  for (int d = 0; d < kDescriptorDim; ++d) out[d] = static_cast<uint8_t>(std::min(255.0, std::round(512 * v[d] / std::sqrt(n))));
}

struct TwoViews {
  PinholeCamera camera_a, camera_b;
  CameraPose pose_a, pose_b;
  FeatureSet a, b;
  std::map<uint32_t, uint32_t> truth;  // a index → b index
};

// Points on a plane 10 m in front of camera A, seen by B from 1 m to the
// right; B also sees as many distractors (other points, other descriptors).
TwoViews make_views(int n_points, double k1 = 0.0) {
  std::mt19937 rng(7);
  TwoViews v;
  v.camera_a = PinholeCamera::centered(1024, 768, 800.0);
  v.camera_b = PinholeCamera::centered(1280, 960, 1000.0);
  v.camera_a.k1 = v.camera_b.k1 = k1;
  v.pose_b = CameraPose::from_matrix(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                                     Eigen::Vector3d(-1, 0.05, 0.2));
  std::uniform_real_distribution<double> u(-1, 1);
  v.a.descriptors.resize(0);
  std::vector<Keypoint> ka, kb;
  DescriptorMatrix da(n_points), db(2 * n_points);
  size_t nb = 0;
  for (int i = 0; i < n_points; ++i) {
    const Eigen::Vector3d X(5 * u(rng), 3 * u(rng), 10 + 2 * u(rng));
    const Eigen::Vector2d pa = v.camera_a.project(v.pose_a.transform(X));
    const Eigen::Vector2d pb = v.camera_b.project(v.pose_b.transform(X));
    if (!v.camera_a.contains(pa) || !v.camera_b.contains(pb)) continue;
    const uint32_t ia = static_cast<uint32_t>(ka.size());
    ka.push_back({float(pa.x()), float(pa.y()), 2, 0});
    random_descriptor(rng, da.row(ia));
    kb.push_back({float(pb.x() + 0.3 * u(rng)), float(pb.y() + 0.3 * u(rng)), 2, 0});
    noisy_copy(rng, da.row(ia), 4, db.row(nb));
    v.truth[ia] = static_cast<uint32_t>(nb++);
    // A distractor anywhere in B.
    kb.push_back({float(640 + 600 * u(rng)), float(480 + 450 * u(rng)), 2, 0});
    random_descriptor(rng, db.row(nb++));
  }
  da.resize(ka.size());
  db.resize(kb.size());
  v.a.keypoints = ka;
  v.a.descriptors = da;
  v.b.keypoints = kb;
  v.b.descriptors = db;
  return v;
}

// The rules of GuidedMatcher written plainly (pairs of loops, doubles): the
// optimized search must give exactly the same matches.
std::vector<FeatureMatch> reference_matches(const TwoViews& v, const GuidedMatchOptions& o) {
  const TwoViewGeometry g = two_view_geometry(v.camera_a, v.pose_a, v.camera_b, v.pose_b);
  auto undistorted = [](const PinholeCamera& c, const Keypoint& k) {
    const Eigen::Vector2d n = c.normalize({k.x, k.y});
    return Eigen::Vector3d(c.focal * n.x() + c.cx, c.focal * n.y() + c.cy, 1);
  };
  auto sampson = [&](const Eigen::Vector3d& xa, const Eigen::Vector3d& xb) {
    const Eigen::Vector3d l = g.F * xa, m = g.F.transpose() * xb;
    const double e = xb.dot(l);
    return std::sqrt(e * e / (l.head<2>().squaredNorm() + m.head<2>().squaredNorm()));
  };
  auto angle = [](const uint8_t* p, const uint8_t* q) {
    double dot = 0;
    for (int d = 0; d < kDescriptorDim; ++d) dot += double(p[d]) * q[d];
    return std::acos(std::clamp(dot / (512.0 * 512.0), -1.0, 1.0));
  };
  const size_t na = v.a.size(), nb = v.b.size();
  std::vector<double> best_of_b(nb, 1e9);
  std::vector<uint32_t> best_a_of_b(nb, 0);
  std::vector<FeatureMatch> tentative;
  for (size_t i = 0; i < na; ++i) {
    const Eigen::Vector3d xa = undistorted(v.camera_a, v.a.keypoints[i]);
    double best = 1e9, second = 1e9;
    uint32_t best_j = 0;
    for (size_t j = 0; j < nb; ++j) {
      if (sampson(xa, undistorted(v.camera_b, v.b.keypoints[j])) > o.max_sampson_px) continue;
      const double d = angle(v.a.descriptors.row(i), v.b.descriptors.row(j));
      if (d < best) {
        second = best;
        best = d;
        best_j = static_cast<uint32_t>(j);
      } else if (d < second) {
        second = d;
      }
      if (d < best_of_b[j]) {
        best_of_b[j] = d;
        best_a_of_b[j] = static_cast<uint32_t>(i);
      }
    }
    if (best > o.max_angle_rad) continue;
    if (second < 1e9 && best >= o.max_ratio * second) continue;
    tentative.emplace_back(static_cast<uint32_t>(i), best_j);
  }
  std::vector<FeatureMatch> out;
  for (const auto& m : tentative)
    if (!o.cross_check || best_a_of_b[m.second] == m.first) out.push_back(m);
  if (out.size() < static_cast<size_t>(o.min_matches)) out.clear();
  return out;
}

TEST(GuidedMatcher, FindsTheTrueCorrespondencesAndNothingElse) {
  const TwoViews v = make_views(1500);
  ASSERT_GT(v.truth.size(), 500u);
  const TwoViewGeometry g = two_view_geometry(v.camera_a, v.pose_a, v.camera_b, v.pose_b);
  CenteredKeypoints ca, cb;
  ca.assign(v.a, v.camera_a);
  cb.assign(v.b, v.camera_b);
  GuidedMatcher matcher;
  const auto& m = matcher.match(v.a, ca, v.b, cb, g);
  size_t correct = 0;
  for (const auto& [i, j] : m) correct += v.truth.at(i) == j;
  EXPECT_GE(correct, v.truth.size() * 95 / 100) << m.size() << " matches";
  EXPECT_EQ(correct, m.size());
  // The band holds a small share of B: the point of guided matching.
  EXPECT_LT(matcher.last_band_candidates(), v.a.size() * v.b.size() / 20);
}

TEST(GuidedMatcher, SameMatchesAsThePlainReference) {
  for (double k1 : {0.0, -0.08}) {
    TwoViews v = make_views(600, k1);
    // Repetition: a copy of feature 0's descriptor on its epipolar line in B
    // (the true point shifted along the line) must be rejected by the ratio test.
    const TwoViewGeometry g = two_view_geometry(v.camera_a, v.pose_a, v.camera_b, v.pose_b);
    const uint32_t j0 = v.truth.at(0);
    Keypoint twin = v.b.keypoints[j0];
    twin.x += 30;
    twin.y += static_cast<float>(-30 * (g.F * Eigen::Vector3d(v.a.keypoints[0].x, v.a.keypoints[0].y, 1)).x() /
                                 (g.F * Eigen::Vector3d(v.a.keypoints[0].x, v.a.keypoints[0].y, 1)).y());
    v.b.keypoints.push_back(twin);
    DescriptorMatrix d = v.b.descriptors;
    d.resize(d.rows() + 1);
    std::copy(v.b.descriptors.row(j0), v.b.descriptors.row(j0) + kDescriptorDim, d.row(d.rows() - 1));
    v.b.descriptors = d;
    for (bool cross : {true, false}) {
      GuidedMatchOptions o;
      o.cross_check = cross;
      CenteredKeypoints ca, cb;
      ca.assign(v.a, v.camera_a);
      cb.assign(v.b, v.camera_b);
      GuidedMatcher matcher(o);
      const std::vector<FeatureMatch> fast = matcher.match(v.a, ca, v.b, cb, g);
      const std::vector<FeatureMatch> plain = reference_matches(v, o);
      EXPECT_EQ(fast, plain) << "k1 " << k1 << " cross_check " << cross;
      EXPECT_FALSE(fast.empty());
      if (k1 == 0.0)
        for (const auto& [i, j] : fast) EXPECT_NE(i, 0u) << "feature 0 has a twin on its epipolar line";
    }
  }
}

TEST(GuidedMatcher, FeaturesOffTheEpipolarLineDoNotMatch) {
  TwoViews v = make_views(600);
  for (auto& k : v.b.keypoints) k.y += 12;  // every B feature 12 px off (band: 4 px)
  const TwoViewGeometry g = two_view_geometry(v.camera_a, v.pose_a, v.camera_b, v.pose_b);
  CenteredKeypoints ca, cb;
  ca.assign(v.a, v.camera_a);
  cb.assign(v.b, v.camera_b);
  GuidedMatcher matcher;
  size_t correct = 0;
  for (const auto& [i, j] : matcher.match(v.a, ca, v.b, cb, g)) correct += v.truth.at(i) == j;
  EXPECT_LT(correct, v.truth.size() / 10);
}

TEST(GuidedMatcher, GeometryFromPosesSatisfiesTheEpipolarConstraint) {
  const TwoViews v = make_views(50);
  const TwoViewGeometry g = two_view_geometry(v.camera_a, v.pose_a, v.camera_b, v.pose_b);
  EXPECT_NEAR(g.b_from_a_direction.norm(), 1.0, 1e-12);
  const Eigen::Vector3d X(0.5, -0.3, 9);
  const Eigen::Vector2d pa = v.camera_a.project(v.pose_a.transform(X));
  const Eigen::Vector2d pb = v.camera_b.project(v.pose_b.transform(X));
  const Eigen::Vector3d l = g.F * pa.homogeneous();
  EXPECT_LT(std::abs(pb.homogeneous().dot(l)) / l.head<2>().norm(), 1e-6);
}

TEST(GuidedMatcher, OptionsAreValidated) {
  GuidedMatchOptions o;
  o.max_sampson_px = 0;
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.max_ratio = 1.5;
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.min_matches = 0;
  EXPECT_THROW(GuidedMatcher{o}, Error);
}

TEST(GuidedMatcher, OverlappingPairsFollowDistanceAndAngle) {
  std::vector<CameraPose> poses(3);
  poses[1] = CameraPose::from_world_from_cam(Eigen::Matrix3d::Identity(), Eigen::Vector3d(10, 0, 0));
  poses[2] = CameraPose::from_world_from_cam(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                                             Eigen::Vector3d(5, 0, 0));
  const auto pairs = overlapping_pairs(poses, 30, 60);
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0], std::make_pair(size_t{0}, size_t{1}));
  EXPECT_TRUE(overlapping_pairs(poses, 5, 60).empty());
}

}  // namespace
}  // namespace visloc
