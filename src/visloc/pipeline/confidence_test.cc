// The confidence model's inputs, evaluation and the map-camera plausibility terms.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>

#include "visloc/pipeline/confidence.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"

namespace visloc {
namespace {

ConfidenceFeatures strong_pose() {
  ConfidenceFeatures f;
  f.inliers = 150;
  f.inlier_ratio = 0.6;
  f.coverage = 0.5;
  f.residual = 0.25;
  f.margin = 0.05;
  f.vote_share = 0.6;
  f.explained = 0.1;
  return f;
}

TEST(ConfidenceModel, BuiltinIsMonotoneInEveryInput) {
  const ConfidenceModel& m = ConfidenceModel::builtin();
  const auto& signs = confidence_input_signs();
  for (int k = 0; k < kConfidenceInputs; ++k) {
    SCOPED_TRACE(confidence_input_names()[k]);
    EXPECT_GE(signs[k] * m.weights[k], 0.0);
  }
  EXPECT_GT(m.threshold, 0.0);
  EXPECT_LE(m.threshold, 1.0);
  EXPECT_EQ(kDefaultMinConfidence, m.threshold);
}

TEST(ConfidenceModel, StrongPosesAreConfidentWeakOnesAreNot) {
  const ConfidenceModel& m = ConfidenceModel::builtin();
  const ConfidenceFeatures strong = strong_pose();
  EXPECT_GE(m.evaluate(strong), m.threshold);
  // 12 inliers in one corner, half of them off, far from every map camera.
  ConfidenceFeatures weak;
  weak.inliers = 12;
  weak.inlier_ratio = 0.02;
  weak.coverage = 2.0 / 64;
  weak.residual = 0.7;
  weak.margin = 0.9;
  weak.vote_share = 0.1;
  weak.camera_distance = 4;
  weak.height_excess = 1;
  weak.tilt_excess_deg = 40;
  weak.explained = 0.002;
  EXPECT_LT(m.evaluate(weak), m.threshold);
  EXPECT_LT(m.evaluate(weak), m.evaluate(strong));
}

TEST(ConfidenceModel, EvaluateIsAProbabilityAndJsonRoundTrips) {
  ConfidenceModel m;
  m.bias = -3;
  m.weights[0] = 1;
  m.threshold = 0.7;
  ConfidenceFeatures f = strong_pose();
  const double c = m.evaluate(f);
  EXPECT_NEAR(c, 1 / (1 + std::exp(3 - std::log(150.0))), 1e-12);
  const ConfidenceModel back = ConfidenceModel::from_json(m.to_json());
  EXPECT_EQ(back.evaluate(f), c);
  EXPECT_EQ(back.threshold, 0.7);
  EXPECT_EQ(ConfidenceFeatures::from_json(f.to_json()).inliers, 150);
  // Huge inputs stay in [0, 1].
  m.weights[6] = -1e300;
  f.camera_distance = 1e300;
  EXPECT_GE(m.evaluate(f), 0.0);
  EXPECT_LE(m.evaluate(f), 1.0);
}

TEST(ConfidenceModel, BadJsonIsRejectedNamingTheField) {
  nlohmann::json j = ConfidenceModel::builtin().to_json();
  j["weights"]["coverage"] = "x";
  try {
    ConfidenceModel::from_json(j);
    FAIL() << "accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("coverage"), std::string::npos) << e.what();
  }
  nlohmann::json f = strong_pose().to_json();
  f.erase("residual");
  EXPECT_THROW(ConfidenceFeatures::from_json(f), Error);
  EXPECT_THROW(ConfidenceFeatures::from_json(nlohmann::json::array()), Error);
  f = strong_pose().to_json();
  f["explained"] = "x";
  EXPECT_THROW(ConfidenceFeatures::from_json(f), Error);
}

TEST(ConfidenceModel, JsonFromBeforeTheExplainedInputStillReads) {
  // Reports and models written before `explained` existed.
  nlohmann::json f = strong_pose().to_json();
  f.erase("explained");
  EXPECT_EQ(ConfidenceFeatures::from_json(f).explained, kExplainedWhenUnknown);
  ConfidenceModel m = ConfidenceModel::builtin();
  m.weights[kExplainedInput] = 2;
  nlohmann::json j = m.to_json();
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kExplainedInput], 2);
  j["weights"].erase("log_explained");
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kExplainedInput], 0);
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[0], m.weights[0]);
}

TEST(ConfidenceModel, JsonFromBeforeTheElsewhereInputStillReads) {
  nlohmann::json f = strong_pose().to_json();
  f["elsewhere"] = 0.4;
  EXPECT_EQ(ConfidenceFeatures::from_json(f).elsewhere, 0.4);
  f.erase("elsewhere");
  EXPECT_EQ(ConfidenceFeatures::from_json(f).elsewhere, kElsewhereWhenUnknown);
  ConfidenceModel m = ConfidenceModel::builtin();
  m.weights[kElsewhereInput] = -2;
  nlohmann::json j = m.to_json();
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kElsewhereInput], -2);
  j["weights"].erase("elsewhere_share");
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kElsewhereInput], 0);
}

TEST(ConfidenceModel, JsonFromBeforeTheAmbiguousInputStillReads) {
  nlohmann::json f = strong_pose().to_json();
  f["ambiguous"] = 0.25;
  EXPECT_EQ(ConfidenceFeatures::from_json(f).ambiguous, 0.25);
  f.erase("ambiguous");
  EXPECT_EQ(ConfidenceFeatures::from_json(f).ambiguous, kAmbiguousWhenUnknown);
  f["ambiguous"] = "x";
  EXPECT_THROW(ConfidenceFeatures::from_json(f), Error);
  ConfidenceModel m = ConfidenceModel::builtin();
  m.weights[kAmbiguousInput] = -3;
  nlohmann::json j = m.to_json();
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kAmbiguousInput], -3);
  j["weights"].erase("ambiguous_share");
  EXPECT_EQ(ConfidenceModel::from_json(j).weights[kAmbiguousInput], 0);
  // More ambiguous inliers never raise a confidence (the input's sign).
  ConfidenceFeatures a = strong_pose(), b = strong_pose();
  a.ambiguous = 0.1;
  b.ambiguous = 0.9;
  EXPECT_LT(ConfidenceModel::from_json(m.to_json()).evaluate(b), ConfidenceModel::from_json(m.to_json()).evaluate(a));
}

TEST(ConfidenceModel, SigmaScaleRoundTripsDefaultsToOneAndIsChecked) {
  ConfidenceModel m;
  m.sigma_scale = 1.7;
  nlohmann::json j = m.to_json();
  EXPECT_EQ(ConfidenceModel::from_json(j).sigma_scale, 1.7);
  j.erase("sigma_scale");  // a model written before it
  EXPECT_EQ(ConfidenceModel::from_json(j).sigma_scale, 1.0);
  for (double bad : {0.0, -1.0}) {
    j["sigma_scale"] = bad;
    EXPECT_THROW(ConfidenceModel::from_json(j), Error) << bad;
  }
  j["sigma_scale"] = "x";
  EXPECT_THROW(ConfidenceModel::from_json(j), Error);
  // The builtin model's σ is calibrated: the covariance alone is too small.
  EXPECT_GT(ConfidenceModel::builtin().sigma_scale, 1.0);
}

// Every σ of a pose scales with sigma_scale: position, rotation, and in a
// geo-registered segment the metre and heading σ.
TEST(PoseUncertainty, EverySigmaScalesWithTheModelsScale) {
  PoseCovariance cov;
  cov.valid = true;
  Eigen::Matrix<double, 6, 6> a = Eigen::Matrix<double, 6, 6>::Random();
  cov.omega_t = 1e-4 * (a * a.transpose() + Eigen::Matrix<double, 6, 6>::Identity());
  const CameraPose pose = CameraPose::from_matrix(
      Eigen::AngleAxisd(0.3, Eigen::Vector3d(0.2, 1, 0.1).normalized()).toRotationMatrix(), Eigen::Vector3d(1, 2, 3));
  Similarity3d enu_from_segment;
  enu_from_segment.scale = 2;
  enu_from_segment.rotation = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const PoseUncertainty one = pose_uncertainty(cov, pose, enu_from_segment, 1.0);
  const PoseUncertainty scaled = pose_uncertainty(cov, pose, enu_from_segment, 1.5);
  ASSERT_TRUE(one.position_sigma_m && one.horizontal_sigma_m && one.vertical_sigma_m && one.heading_sigma_deg);
  EXPECT_GT(one.position_sigma, 0);
  EXPECT_NEAR(scaled.position_sigma, 1.5 * one.position_sigma, 1e-12);
  EXPECT_NEAR(scaled.rotation_sigma_deg, 1.5 * one.rotation_sigma_deg, 1e-12);
  EXPECT_NEAR(*scaled.position_sigma_m, 1.5 * *one.position_sigma_m, 1e-12);
  EXPECT_NEAR(*scaled.horizontal_sigma_m, 1.5 * *one.horizontal_sigma_m, 1e-12);
  EXPECT_NEAR(*scaled.vertical_sigma_m, 1.5 * *one.vertical_sigma_m, 1e-12);
  EXPECT_NEAR(*scaled.heading_sigma_deg, 1.5 * *one.heading_sigma_deg, 1e-12);
  // The metre σ is the segment σ times the segment's scale (a rotation keeps the trace).
  EXPECT_NEAR(*one.position_sigma_m, 2 * one.position_sigma, 1e-12);
  EXPECT_FALSE(pose_uncertainty(cov, pose, std::nullopt, 1.0).position_sigma_m);
}

// Map cameras along a street (x), 2 m high (z up), looking along +y, level.
std::vector<SegmentImage> street_cameras() {
  std::vector<SegmentImage> images;
  for (int i = 0; i < 8; ++i) {
    // Camera axes in the world: x → +x, y (down) → −z, z (forward) → +y.
    Eigen::Matrix3d world_from_cam;
    world_from_cam.col(0) = Eigen::Vector3d::UnitX();
    world_from_cam.col(1) = -Eigen::Vector3d::UnitZ();
    world_from_cam.col(2) = Eigen::Vector3d::UnitY();
    const Eigen::Matrix3d R = world_from_cam.transpose();
    const Eigen::Vector3d c(5.0 * i, 0, 2);
    const Eigen::Vector3d t = -R * c;
    const Eigen::Quaterniond q(R);
    SegmentImage im;
    im.name = "m" + std::to_string(i);
    im.cam_from_world_q_wxyz = {q.w(), q.x(), q.y(), q.z()};
    im.cam_from_world_t = {t.x(), t.y(), t.z()};
    images.push_back(im);
  }
  return images;
}

CameraPose pose_at(const Eigen::Vector3d& centre, double pitch_deg) {
  Eigen::Matrix3d world_from_cam;
  world_from_cam.col(0) = Eigen::Vector3d::UnitX();
  world_from_cam.col(1) = -Eigen::Vector3d::UnitZ();
  world_from_cam.col(2) = Eigen::Vector3d::UnitY();
  world_from_cam = Eigen::AngleAxisd(pitch_deg * M_PI / 180, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                   world_from_cam;
  const Eigen::Matrix3d R = world_from_cam.transpose();
  return CameraPose::from_matrix(R, -R * centre);
}

TEST(MapCameraRange, PlausibilityOfPosesAgainstTheMapCameras) {
  for (const bool with_up : {false, true}) {
    SCOPED_TRACE(with_up ? "ENU up given" : "up from the cameras");
    const MapCameraRange range(street_cameras(), with_up ? std::optional<Eigen::Vector3d>(Eigen::Vector3d::UnitZ()) : std::nullopt);
    ASSERT_TRUE(range.valid());
    ConfidenceFeatures near;
    range.assess(pose_at({12, 1, 2}, 0), &near);
    EXPECT_NEAR(near.camera_distance, std::hypot(2.0, 1.0) / 17.5, 1e-9);  // extent: 17.5 m from the mean
    EXPECT_NEAR(near.height_excess, 0, 1e-12);
    EXPECT_NEAR(near.tilt_excess_deg, 0, 1e-9);
    ConfidenceFeatures far;
    range.assess(pose_at({17.5, 35, 12}, 30), &far);
    EXPECT_NEAR(far.height_excess, 10 / 17.5, 1e-9);
    EXPECT_NEAR(far.tilt_excess_deg, 30, 1e-6);
    EXPECT_GT(far.camera_distance, 2.0);
  }
  // The same scene turned (a segment frame that is not ENU-aligned), with the
  // up direction given: the same terms.
  {
    const Eigen::Matrix3d turn =
        (Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(-0.3, Eigen::Vector3d::UnitY()))
            .toRotationMatrix();
    auto turned = [&](const CameraPose& p) {  // world' = turn · world
      const Eigen::Matrix3d R = p.rotation_matrix() * turn.transpose();
      return CameraPose::from_matrix(R, p.translation);
    };
    std::vector<SegmentImage> images = street_cameras();
    for (auto& im : images) {
      const auto& q = im.cam_from_world_q_wxyz;
      const CameraPose p = CameraPose::from_matrix(
          Eigen::Quaterniond(q[0], q[1], q[2], q[3]).toRotationMatrix(),
          Eigen::Vector3d(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]));
      const CameraPose t = turned(p);
      const auto tq = t.q_wxyz();
      im.cam_from_world_q_wxyz = {tq[0], tq[1], tq[2], tq[3]};
      im.cam_from_world_t = {t.translation.x(), t.translation.y(), t.translation.z()};
    }
    const MapCameraRange range(images, std::optional<Eigen::Vector3d>(turn * Eigen::Vector3d::UnitZ()));
    ConfidenceFeatures far;
    range.assess(turned(pose_at({17.5, 35, 12}, 30)), &far);
    EXPECT_NEAR(far.height_excess, 10 / 17.5, 1e-9);
    EXPECT_NEAR(far.tilt_excess_deg, 30, 1e-6);
  }
  // Fewer than two cameras: nothing to compare with, the terms stay 0.
  const MapCameraRange none({}, std::nullopt);
  EXPECT_FALSE(none.valid());
  ConfidenceFeatures f;
  none.assess(pose_at({100, 100, 100}, 80), &f);
  EXPECT_EQ(f.camera_distance, 0);
}

TEST(ExplainedFraction, CountsTheMapPointsInViewUpToTheInliersDepth) {
  // Camera at the origin looking along +z (identity pose), 640 × 480, f 500,
  // principal point at the centre. 40 points in view at depth 10, and points
  // that must not count: behind, beyond the depth bound, left of the image.
  const PinholeCamera camera = PinholeCamera::centered(640, 480, 500.0);
  std::vector<float> xyz;
  const auto add = [&](double x, double y, double z, int n) {
    for (int i = 0; i < n; ++i) xyz.insert(xyz.end(), {float(x + 0.01 * i), float(y), float(z)});
  };
  add(0, 0, 10, 40);    // in view
  add(0, 0, -10, 30);   // behind
  add(0, 0, 30, 20);    // deeper than the bound
  add(-20, 0, 10, 10);  // u = -1000 px: left of the image
  add(0, 6, 10, 5);     // v = 300 px below the centre: under the image
  add(6.5, 0, 10, 8);   // u = 325 px right of the centre: right of the image (645 ≥ 640)
  const CameraPose identity;
  const Eigen::Vector2d no_offset = Eigen::Vector2d::Zero();
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, identity, camera, 500, no_offset, 20.0, 10), 10.0 / 40.0);
  // A deeper bound takes the 20 at 30 m too; more inliers than points in view: 1.
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, identity, camera, 500, no_offset, 35.0, 10), 10.0 / 60.0);
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, identity, camera, 500, no_offset, 20.0, 100), 1.0);
  // The principal-point offset moves the projections: at -350 px the 40 at
  // u ≈ 0 land at pixel ≈ -30 (outside) and the 8 at u = 325 at pixel 295
  // (inside; with the sign flipped they would land at 995).
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, identity, camera, 500, Eigen::Vector2d(-350, 0), 20.0, 4), 4.0 / 8.0);
  // The pose is applied: 15 m back, the 40 are 25 m deep, the 30 that were
  // behind 5 m in front, the 20 at 45 m; the 10 stay left of the image; the
  // 5 below and the 8 to the right come into it (v = 120, u = 130 px).
  const CameraPose back = CameraPose::from_matrix(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 15));
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, back, camera, 500, no_offset, 26.0, 10), 10.0 / 83.0);
  EXPECT_DOUBLE_EQ(explained_fraction(xyz, back, camera, 500, no_offset, 46.0, 10), 10.0 / 103.0);
  // Nothing in view, or no depth: 0.
  EXPECT_EQ(explained_fraction({}, identity, camera, 500, no_offset, 20.0, 10), 0.0);
  EXPECT_EQ(explained_fraction(xyz, identity, camera, 500, no_offset, 0.0, 10), 0.0);
}

TEST(AmbiguousInlierShare, CountsInliersWithADistantRivalAsCloseInDescriptor) {
  // Five features with two or three candidates each (nearest first), ratio
  // 0.8 (a rival counts at distance <= chosen / 0.8), separation 1.
  const std::vector<uint32_t> offsets = {0, 2, 4, 6, 9, 11};
  const Eigen::Vector3d o(0, 0, 0), near(0.5, 0, 0), far(5, 0, 0);
  const std::vector<Eigen::Vector3d> candidates = {
      o,   far,         // 0: rival far and as close (100 vs 110): ambiguous
      o,   far,         // 1: rival far but distinct (100 vs 200): not
      o,   near,        // 2: rival as close but 0.5 away (the same place): not
      far, o,    near,  // 3: chosen the second (o); the first, closer, is far: ambiguous
      o,   far};        // 4: not an inlier
  const std::vector<float> distances = {100, 110, 100, 200, 100, 101, 90, 100, 100, 100, 100};
  const std::vector<int32_t> chosen = {0, 0, 0, 1, -1};
  EXPECT_DOUBLE_EQ(ambiguous_inlier_share(offsets, candidates, distances, chosen, 1.0, 0.8), 2.0 / 4.0);
  // At the bound exactly (125 = 100 / 0.8) a rival counts; just beyond, not.
  std::vector<float> at_bound = distances;
  at_bound[1] = 125;
  EXPECT_DOUBLE_EQ(ambiguous_inlier_share(offsets, candidates, at_bound, chosen, 1.0, 0.8), 2.0 / 4.0);
  at_bound[1] = 125.5f;
  EXPECT_DOUBLE_EQ(ambiguous_inlier_share(offsets, candidates, at_bound, chosen, 1.0, 0.8), 1.0 / 4.0);
  // A larger separation: 5 m away is no longer distant.
  EXPECT_DOUBLE_EQ(ambiguous_inlier_share(offsets, candidates, distances, chosen, 6.0, 0.8), 0.0);
  // No inliers: 0; inconsistent spans and an out-of-list choice: an error.
  EXPECT_EQ(ambiguous_inlier_share(offsets, candidates, distances, std::vector<int32_t>(5, -1), 1.0, 0.8), 0.0);
  EXPECT_THROW(ambiguous_inlier_share(offsets, candidates, distances, std::vector<int32_t>(4, 0), 1.0, 0.8), Error);
  EXPECT_THROW(ambiguous_inlier_share(offsets, candidates, distances, std::vector<int32_t>{0, 0, 0, 3, -1}, 1.0, 0.8),
               Error);
}

TEST(ElsewhereInlierShare, CountsInliersWhoseNearestMapPointIsInAnUnrelatedSegment) {
  // Votes of 6 query features: 0 → segment 2 (the pose's), 1 → 5 (related
  // to 2), 2 → 9 (unrelated), 3 → ties 9 and 2 (here, through the tie), 4 →
  // no vote, 5 → 9 (but not an inlier).
  SegmentPointVoteResult votes;
  votes.feature_offsets = {0, 1, 2, 3, 5, 5, 6};
  votes.feature_segments = {2, 5, 9, 9, 2, 9};
  const std::vector<uint32_t> related = {5, 7};
  // Correspondences in another order than the features, as the search gives them.
  const std::vector<uint32_t> query_feature = {3, 0, 2, 4, 1, 5};
  const std::vector<int32_t> chosen = {0, 1, 0, 2, 0, -1};
  // Inliers that voted: features 3, 0, 2, 1; elsewhere: feature 2.
  const std::optional<double> share = elsewhere_inlier_share(votes, query_feature, chosen, 2, related);
  ASSERT_TRUE(share.has_value());
  EXPECT_DOUBLE_EQ(*share, 1.0 / 4.0);
  // Without the relation, segment 5 is elsewhere too.
  EXPECT_DOUBLE_EQ(*elsewhere_inlier_share(votes, query_feature, chosen, 2, {}), 2.0 / 4.0);
  // Seen from segment 9, features 0 and 1 are elsewhere; 3 and 2 are not.
  EXPECT_DOUBLE_EQ(*elsewhere_inlier_share(votes, query_feature, chosen, 9, {}), 2.0 / 4.0);
  // No inlier voted: no evidence.
  EXPECT_FALSE(elsewhere_inlier_share(votes, query_feature, std::vector<int32_t>{-1, -1, -1, 0, -1, -1}, 2, related));
  // Inconsistent inputs: an error, not a read out of range.
  EXPECT_THROW(elsewhere_inlier_share(votes, std::vector<uint32_t>{3, 0, 6, 4, 1, 5}, chosen, 2, related), Error);
  EXPECT_THROW(elsewhere_inlier_share(votes, query_feature, std::vector<int32_t>{0}, 2, related), Error);
}

// The street_cameras() street's ground (z = 0) and facades (y = 8, up to
// 10 m), as segment points; `scale`: segment units per metre.
std::vector<float> street_points(double units_per_metre) {
  std::vector<float> xyz;
  for (int x = -10; x <= 45; ++x) {
    for (int y = -4; y <= 6; y += 2) {
      for (double v : {double(x), double(y), 0.0}) xyz.push_back(static_cast<float>(v * units_per_metre));
    }
    for (int z = 0; z <= 10; ++z)
      for (double v : {double(x), 8.0, double(z)}) xyz.push_back(static_cast<float>(v * units_per_metre));
  }
  return xyz;
}

// The cameras of street_cameras() in segment units (metres × units_per_metre).
std::vector<SegmentImage> scaled_street_cameras(double units_per_metre, double height_m = 2) {
  std::vector<SegmentImage> images = street_cameras();
  for (auto& im : images) {
    const auto& q = im.cam_from_world_q_wxyz;
    const Eigen::Matrix3d R = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).toRotationMatrix();
    Eigen::Vector3d c =
        -R.transpose() * Eigen::Vector3d(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]);
    c.z() = height_m;
    const Eigen::Vector3d t = -R * (c * units_per_metre);
    im.cam_from_world_t = {t.x(), t.y(), t.z()};
  }
  return images;
}

TEST(UnderStreet, ACameraBelowBothTheStreetsCamerasAndItsGround) {
  std::vector<float> heights;
  const UnderStreetOptions options;
  for (const double units : {1.0, 0.5}) {  // segment units per metre; enu_from_segment scales back
    SCOPED_TRACE("units per metre " + std::to_string(units));
    Similarity3d enu_from_segment;
    enu_from_segment.scale = 1 / units;
    const auto images = scaled_street_cameras(units);
    const auto xyz = street_points(units);
    auto at = [&](const Eigen::Vector3d& centre_m) {
      return assess_under_street(pose_at(centre_m * units, 0), images, xyz, enu_from_segment, options, heights);
    };
    // A phone held on the street: 0.5 m below the map cameras, 1.5 m above the ground.
    const UnderStreetAssessment phone = at({12, 1, 1.5});
    ASSERT_TRUE(phone.assessed);
    EXPECT_NEAR(phone.drop_below_camera_m, 0.5, 1e-9);
    EXPECT_NEAR(phone.camera_plan_distance_m, std::hypot(2.0, 1.0), 1e-9);
    ASSERT_TRUE(phone.above_ground_m);
    EXPECT_NEAR(*phone.above_ground_m, 1.5, 1e-5);
    EXPECT_FALSE(phone.under_street);
    // 6 m under the road: below both.
    const UnderStreetAssessment under = at({12, 1, -6});
    EXPECT_NEAR(under.drop_below_camera_m, 8, 1e-9);
    EXPECT_NEAR(*under.above_ground_m, -6, 1e-5);
    EXPECT_TRUE(under.under_street);
    // 2.5 m under the road, 4.5 m below the cameras (> 3 + 0.35 × 2.2).
    EXPECT_TRUE(at({12, 1, -2.5}).under_street);
    // 0.5 m under the road (a sunken step): not beyond the ground margin.
    EXPECT_FALSE(at({12, 1, -0.5}).under_street);
    // The ground bound alone: map cameras 6 m up (a bus's roof), a camera
    // 5.5 m below them but only 0.5 m under the road.
    const UnderStreetAssessment step =
        assess_under_street(pose_at(Eigen::Vector3d(12, 1, -0.5) * units, 0), scaled_street_cameras(units, 6), xyz,
                            enu_from_segment, options, heights);
    EXPECT_TRUE(step.below_camera_bound);
    EXPECT_NEAR(*step.above_ground_m, -0.5, 1e-5);
    EXPECT_FALSE(step.under_street);
  }
  Similarity3d identity;
  const auto images = scaled_street_cameras(1);
  // 25 m off the street in plan (a lower street down a hill): 8 m below the
  // cameras is within the slope's 3 + 0.35 × 25 m, though below this ground.
  const UnderStreetAssessment downhill =
      assess_under_street(pose_at({12, 25, -6}, 0), images, street_points(1), identity, options, heights);
  EXPECT_NEAR(*downhill.above_ground_m, -6, 1e-5);
  EXPECT_FALSE(downhill.under_street);
  // No map point within 30 m in plan: no ground, never under the street.
  std::vector<float> far_points = street_points(1);
  for (size_t i = 1; i < far_points.size(); i += 3) far_points[i] += 200;
  const UnderStreetAssessment no_ground =
      assess_under_street(pose_at({12, 1, -6}, 0), images, far_points, identity, options, heights);
  EXPECT_TRUE(no_ground.assessed);
  EXPECT_FALSE(no_ground.above_ground_m);
  EXPECT_FALSE(no_ground.under_street);
  // A drone flight's map, its cameras 40 m up: a phone on the ground is far
  // below them, but above the ground.
  const UnderStreetAssessment drone = assess_under_street(pose_at({12, 1, 1.5}, 0), scaled_street_cameras(1, 40),
                                                          street_points(1), identity, options, heights);
  EXPECT_NEAR(drone.drop_below_camera_m, 38.5, 1e-9);
  EXPECT_FALSE(drone.under_street);
  // A few points triangulated under the road (1% of those near) do not lower the ground.
  std::vector<float> noisy = street_points(1);
  const size_t points = noisy.size() / 3;
  for (size_t i = 0; i < points / 100; ++i)
    for (float v : {12.0f, 1.0f, -20.0f}) noisy.push_back(v);
  const UnderStreetAssessment robust =
      assess_under_street(pose_at({12, 1, -2.5}, 0), images, noisy, identity, options, heights);
  EXPECT_NEAR(*robust.above_ground_m, -2.5, 1e-5);
  EXPECT_TRUE(robust.under_street);
  // A segment frame turned against ENU: the up direction comes from enu_from_segment.
  {
    Similarity3d turned;
    turned.rotation =
        (Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(-0.3, Eigen::Vector3d::UnitY()))
            .toRotationMatrix();
    const Eigen::Matrix3d seg_from_enu = turned.rotation.transpose();
    std::vector<SegmentImage> turned_images = images;
    for (auto& im : turned_images) {
      const auto& q = im.cam_from_world_q_wxyz;
      const Eigen::Matrix3d R =
          Eigen::Quaterniond(q[0], q[1], q[2], q[3]).toRotationMatrix() * seg_from_enu.transpose();
      const Eigen::Quaterniond tq(R);
      im.cam_from_world_q_wxyz = {tq.w(), tq.x(), tq.y(), tq.z()};
    }
    std::vector<float> turned_xyz = street_points(1);
    for (size_t i = 0; i + 2 < turned_xyz.size(); i += 3) {
      const Eigen::Vector3d p = seg_from_enu * Eigen::Vector3d(turned_xyz[i], turned_xyz[i + 1], turned_xyz[i + 2]);
      for (int k = 0; k < 3; ++k) turned_xyz[i + k] = static_cast<float>(p[k]);
    }
    const CameraPose enu_pose = pose_at({12, 1, -6}, 0);
    const CameraPose pose =
        CameraPose::from_matrix(enu_pose.rotation_matrix() * seg_from_enu.transpose(), enu_pose.translation);
    const UnderStreetAssessment t = assess_under_street(pose, turned_images, turned_xyz, turned, options, heights);
    EXPECT_NEAR(t.drop_below_camera_m, 8, 1e-6);
    EXPECT_NEAR(*t.above_ground_m, -6, 1e-4);
    EXPECT_TRUE(t.under_street);
  }
  // Without measure_ground the points are read only when the camera bound holds.
  const UnderStreetAssessment quick =
      assess_under_street(pose_at({12, 1, 1.5}, 0), images, street_points(1), identity, options, heights, false);
  EXPECT_TRUE(quick.assessed);
  EXPECT_FALSE(quick.below_camera_bound);
  EXPECT_FALSE(quick.above_ground_m);
  EXPECT_TRUE(assess_under_street(pose_at({12, 1, -6}, 0), images, street_points(1), identity, options, heights, false)
                  .under_street);
  UnderStreetOptions bad;
  bad.ground_quantile = 1.5;
  EXPECT_THROW(bad.validate(), Error);
  bad = {};
  bad.max_drop_m = -1;
  EXPECT_THROW(bad.validate(), Error);
  bad = {};
  bad.ground_radius_m = 0;
  EXPECT_THROW(bad.validate(), Error);
}

}  // namespace
}  // namespace visloc
