// Point uncertainty: the 4-byte code against the covariance it stands for,
// every code decoding to a valid covariance, the triangulation covariance
// against the stereo formula, and the keypoint noise from reprojection errors.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <numbers>
#include <vector>

#include "visloc/geometry/point_uncertainty.h"
#include "visloc/util/random.h"

using namespace visloc;

namespace {

Eigen::Vector3d random_unit(RandomGenerator& rng) {
  Eigen::Vector3d v(rng.normal(), rng.normal(), rng.normal());
  return v.normalized();
}

// The covariance's major axis and the roots of its largest and middle eigenvalues.
struct Shape {
  Eigen::Vector3d axis;
  double major = 0, minor = 0;
};
Shape shape(const Eigen::Matrix3d& c) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(c);
  return {es.eigenvectors().col(2), std::sqrt(std::max(0.0, es.eigenvalues()(2))),
          std::sqrt(std::max(0.0, es.eigenvalues()(1)))};
}

}  // namespace

TEST(PointUncertainty, CodeKeepsAxisWithinADegreeAndSigmasWithinHalfAStep) {
  RandomGenerator rng(5);
  const double half_step = std::exp2(1.0 / 16.0);  // codes are 1/8 octave apart
  double worst_angle_deg = 0;
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3d d = random_unit(rng);
    const double minor = std::exp2(rng.uniform(-20, -1));         // the major axis stays within the codes' range
    const double major = minor * std::exp2(rng.uniform(0.5, 8));  // a distinct axis
    const Eigen::Matrix3d c =
        minor * minor * Eigen::Matrix3d::Identity() + (major * major - minor * minor) * d * d.transpose();
    const Shape s = shape(decode_point_covariance(encode_point_covariance(c)));
    worst_angle_deg = std::max(worst_angle_deg, std::acos(std::min(1.0, std::abs(s.axis.dot(d)))) * 180 / M_PI);
    EXPECT_LE(std::max(s.major / major, major / s.major), half_step * (1 + 1e-9)) << i;
    EXPECT_LE(std::max(s.minor / minor, minor / s.minor), half_step * (1 + 1e-9)) << i;
  }
  EXPECT_LT(worst_angle_deg, 1.0);
  RecordProperty("worst_axis_error_deg", std::to_string(worst_angle_deg));
}

TEST(PointUncertainty, ExactUnknownAndOutOfRange) {
  const PointUncertaintyCode zero = encode_point_covariance(Eigen::Matrix3d::Zero());
  EXPECT_EQ(zero[2], 0);
  EXPECT_EQ(zero[3], 0);
  EXPECT_TRUE(decode_point_covariance(zero).isZero());
  Eigen::Matrix3d nan = Eigen::Matrix3d::Identity();
  nan(1, 1) = std::nan("");
  const PointUncertaintyCode unknown = encode_point_covariance(nan);
  EXPECT_EQ(unknown[2], 255);
  EXPECT_NEAR(point_sigma_from_code(255), kMaxPointSigma, 0.01 * kMaxPointSigma);
  // Beyond the range: clamped to it, never to "exact".
  EXPECT_EQ(encode_point_covariance(1e12 * Eigen::Matrix3d::Identity())[2], 255);
  const PointUncertaintyCode tiny = encode_point_covariance(1e-40 * Eigen::Matrix3d::Identity());
  EXPECT_EQ(tiny[2], 1);
  EXPECT_EQ(tiny[3], 1);
}

TEST(PointUncertainty, EveryCodeDecodesToAFinitePositiveSemidefiniteCovariance) {
  for (int a = 0; a < 256; ++a)
    for (int b = 0; b < 256; ++b)
      for (const auto& [major, minor] :
           {std::pair{0, 0}, std::pair{255, 255}, std::pair{100, 180}, std::pair{200, 7}}) {
        const PointUncertaintyCode code{uint8_t(a), uint8_t(b), uint8_t(major), uint8_t(minor)};
        const Eigen::Matrix3d c = decode_point_covariance(code);
        ASSERT_TRUE(c.allFinite());
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(c);
        ASSERT_GE(es.eigenvalues()(0), -1e-9 * std::max(1.0, es.eigenvalues()(2)));
      }
}

TEST(PointUncertainty, StereoPairMatchesTheFormula) {
  // Two cameras 2h apart along x, both looking along z, a point on the axis
  // at depth Z: σ_x = σ Z / (f √2), σ_z = σ Z² / (f h √2).
  const double f = 800, h = 0.5, Z = 20, noise = 0.7;
  TrackCamera left, right;
  left.fx = left.fy = right.fx = right.fy = f;
  left.t = Eigen::Vector3d(h, 0, 0);  // centre at (−h, 0, 0)
  right.t = Eigen::Vector3d(-h, 0, 0);
  const std::vector<TrackCamera> cams{left, right};
  const Eigen::Matrix3d c = triangulation_covariance(Eigen::Vector3d(0, 0, Z), cams, noise);
  EXPECT_NEAR(std::sqrt(c(0, 0)), noise * Z / (f * std::sqrt(2.0)), 1e-9);
  EXPECT_NEAR(std::sqrt(c(1, 1)), noise * Z / (f * std::sqrt(2.0)), 1e-9);
  EXPECT_NEAR(std::sqrt(c(2, 2)), noise * Z * Z / (f * h * std::sqrt(2.0)), 1e-9);
  EXPECT_NEAR(c(0, 2), 0, 1e-12);
  // Noise scales the covariance by its square; exact keypoints, an exact point.
  EXPECT_TRUE(triangulation_covariance(Eigen::Vector3d(0, 0, Z), cams, 2 * noise).isApprox(4 * c));
  EXPECT_TRUE(triangulation_covariance(Eigen::Vector3d(0, 0, Z), cams, 0).isZero());
}

TEST(PointUncertainty, OneViewOrOneCentreLeavesTheDepthUnknown) {
  TrackCamera a;
  a.fx = a.fy = 500;
  const Eigen::Vector3d X(1, 0.5, 10);
  std::vector<TrackCamera> one{a};
  Shape s = shape(triangulation_covariance(X, one, 1.0));
  EXPECT_DOUBLE_EQ(s.major, kMaxPointSigma);
  EXPECT_GT(std::abs(s.axis.dot(X.normalized())), 0.999);  // along the ray
  // Two views from the same centre (a turned camera): still no depth.
  TrackCamera turned = a;
  turned.R = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  std::vector<TrackCamera> same_centre{a, turned};
  s = shape(triangulation_covariance(X, same_centre, 1.0));
  EXPECT_NEAR(s.major, kMaxPointSigma, 1e-6 * kMaxPointSigma);
  // A camera behind the point's plane does not count.
  TrackCamera behind = a;
  behind.t = Eigen::Vector3d(0, 0, -20);
  std::vector<TrackCamera> with_behind{a, behind};
  EXPECT_DOUBLE_EQ(shape(triangulation_covariance(X, with_behind, 1.0)).major, kMaxPointSigma);
}

TEST(PointUncertainty, KeypointNoiseFromSimulatedTracks) {
  // Points seen by k cameras on a line, keypoints with Gaussian noise σ,
  // triangulated by Gauss-Newton; their mean |r| as COLMAP reports it.
  RandomGenerator rng(9);
  const double sigma = 0.8, f = 700;
  std::vector<double> errors;
  std::vector<uint32_t> lengths;
  for (int p = 0; p < 3000; ++p) {
    const int k = 2 + p % 5;
    const Eigen::Vector3d X(rng.uniform(-5, 5), rng.uniform(-2, 2), rng.uniform(8, 20));
    std::vector<Eigen::Vector3d> centres;
    std::vector<Eigen::Vector2d> obs;
    for (int c = 0; c < k; ++c) {
      const Eigen::Vector3d C(1.5 * c, 0.1 * c, 0);
      const Eigen::Vector3d q = X - C;
      centres.push_back(C);
      obs.emplace_back(f * q.x() / q.z() + sigma * rng.normal(), f * q.y() / q.z() + sigma * rng.normal());
    }
    Eigen::Vector3d Y = X;
    for (int it = 0; it < 10; ++it) {
      Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
      Eigen::Vector3d g = Eigen::Vector3d::Zero();
      for (int c = 0; c < k; ++c) {
        const Eigen::Vector3d q = Y - centres[c];
        Eigen::Matrix<double, 2, 3> J;
        J << f / q.z(), 0, -f * q.x() / (q.z() * q.z()), 0, f / q.z(), -f * q.y() / (q.z() * q.z());
        const Eigen::Vector2d r(f * q.x() / q.z() - obs[c].x(), f * q.y() / q.z() - obs[c].y());
        H += J.transpose() * J;
        g += J.transpose() * r;
      }
      Y -= H.ldlt().solve(g);
    }
    double sum = 0;
    for (int c = 0; c < k; ++c) {
      const Eigen::Vector3d q = Y - centres[c];
      sum += Eigen::Vector2d(f * q.x() / q.z() - obs[c].x(), f * q.y() / q.z() - obs[c].y()).norm();
    }
    errors.push_back(sum / k);
    lengths.push_back(uint32_t(k));
  }
  const double estimate = keypoint_noise_from_reprojection_errors(errors, lengths);
  EXPECT_NEAR(estimate, sigma, 0.08 * sigma);
  RecordProperty("estimated_noise_px", std::to_string(estimate));
  // Points without a usable error or track are skipped; none: 0.
  errors.push_back(std::nan(""));
  lengths.push_back(4);
  errors.push_back(-1);
  lengths.push_back(4);
  errors.push_back(5);
  lengths.push_back(1);
  EXPECT_DOUBLE_EQ(keypoint_noise_from_reprojection_errors(errors, lengths), estimate);
  EXPECT_EQ(keypoint_noise_from_reprojection_errors(std::vector<double>{1.0}, std::vector<uint32_t>{1}), 0.0);
}

TEST(PointUncertainty, NegativeDefiniteIsUnknownNotExact) {
  const PointUncertaintyCode code = encode_point_covariance(-Eigen::Matrix3d::Identity());
  EXPECT_EQ(code[2], 255);
  EXPECT_EQ(code[3], 255);
  // A rounding-level negative eigenvalue of a real covariance counts as 0.
  Eigen::Matrix3d c = Eigen::Vector3d(4e-4, 1e-4, -1e-20).asDiagonal();
  const PointUncertaintyCode near = encode_point_covariance(c);
  EXPECT_NEAR(point_sigma_from_code(near[2]), 0.02, 0.02 * 0.05);
  EXPECT_NEAR(point_sigma_from_code(near[3]), 0.01, 0.01 * 0.05);
}
