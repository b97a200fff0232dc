// Guided confirmation: a map point is confirmed where a query keypoint near
// its projection has a descriptor near its code, and only there.
#include "visloc/pipeline/guided_confirmation.h"

#include "visloc/pipeline/confidence.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "visloc/util/error.h"

namespace visloc {
namespace {

struct Scene {
  PqCodebook codebook;
  std::vector<float> xyz;
  std::vector<uint8_t> codes;
  PinholeCamera camera = PinholeCamera::centered(640, 480, 500.0);
  std::vector<Keypoint> keypoints;
  DescriptorMatrix descriptors;

  // Centroids of small integers, so that a decoded code is an exact uint8 descriptor.
  Scene() {
    std::mt19937 rng(3);
    std::uniform_int_distribution<int> value(0, 60);
    std::vector<float> c(size_t(kPqSubvectors) * kPqCentroids * (kDescriptorDim / kPqSubvectors));
    for (float& v : c) v = float(value(rng));
    codebook = PqCodebook(c);
  }
  // A point at camera coordinates X (identity pose) with code `code_seed`'s code.
  void add_point(const Eigen::Vector3d& X, int code_seed) {
    for (int k = 0; k < 3; ++k) xyz.push_back(float(X[k]));
    for (int m = 0; m < kPqSubvectors; ++m) codes.push_back(uint8_t((code_seed * 31 + m * 7) % kPqCentroids));
  }
  // A keypoint at pixel (x, y) whose descriptor is point p's decoded code
  // plus `noise` on every dimension.
  void add_keypoint(double x, double y, size_t p, int noise) {
    keypoints.push_back(Keypoint{float(x), float(y), 2.0f, 0.0f});
    std::vector<float> d(kDescriptorDim);
    codebook.decode(codes.data() + p * kPqSubvectors, d.data());
    const size_t row = descriptors.rows();
    descriptors.resize(row + 1);
    for (int j = 0; j < kDescriptorDim; ++j)
      descriptors.row(row)[j] = uint8_t(std::clamp(int(std::lround(d[j])) + noise, 0, 255));
  }
  Eigen::Vector2d pixel(size_t p) const {
    return {500.0 * xyz[3 * p] / xyz[3 * p + 2] + camera.cx, 500.0 * xyz[3 * p + 1] / xyz[3 * p + 2] + camera.cy};
  }
  GuidedConfirmationInput input(double max_depth, float max_distance, uint64_t inlier_cells) const {
    GuidedConfirmationInput in;
    in.xyz = xyz;
    in.codes = codes.data();
    in.codebook = &codebook;
    in.camera = &camera;
    in.focal = 500;
    in.max_depth = max_depth;
    in.keypoints = keypoints;
    in.descriptors = &descriptors;
    in.inlier_cells = inlier_cells;
    in.radius_px = 8;
    in.max_distance = max_distance;
    return in;
  }
};

TEST(GuidedConfirmation, ConfirmsPointsSeenAtTheirProjectionAndNoOthers) {
  Scene s;
  s.add_point({-1, -1, 10}, 0);  // 0: a keypoint on it, its descriptor
  s.add_point({1, -1, 10}, 1);   // 1: a keypoint 5 px off, its descriptor plus noise 2
  s.add_point({-1, 1, 10}, 2);   // 2: a keypoint on it, another point's descriptor
  s.add_point({1, 1, 10}, 3);    // 3: its descriptor 12 px off (beyond the radius)
  s.add_point({0, 0, 10}, 4);    // 4: no keypoint
  s.add_point({0, 0, 40}, 5);    // 5: deeper than max_depth
  s.add_point({0, 0, -10}, 6);   // 6: behind the camera
  s.add_point({100, 0, 10}, 7);  // 7: outside the image
  s.add_keypoint(s.pixel(0).x(), s.pixel(0).y(), 0, 0);
  s.add_keypoint(s.pixel(1).x() + 3, s.pixel(1).y() + 4, 1, 2);
  s.add_keypoint(s.pixel(2).x(), s.pixel(2).y(), 4, 0);
  s.add_keypoint(s.pixel(3).x() + 12, s.pixel(3).y(), 3, 0);
  s.add_keypoint(s.pixel(5).x() + 1, s.pixel(5).y(), 5, 0);  // point 5's own, but it is too deep
  // The descriptor bound lets noise 2 on 128 dimensions (2·√128 ≈ 22.6) pass.
  GuidedConfirmer confirmer;
  const GuidedConfirmation g = confirmer.measure(s.input(20, 30, ~uint64_t(0)));
  EXPECT_EQ(g.predicted, 5u);  // 0..4
  EXPECT_EQ(g.examined, 5u);
  EXPECT_EQ(g.confirmed, 2u);  // 0 and 1
  EXPECT_EQ(g.examined_off_inliers, 0u);
  EXPECT_EQ(g.confirmed_off_inliers, 0u);
  EXPECT_DOUBLE_EQ(g.share(), 2.0 / 5.0);
  // A tighter bound than the noise: point 1 is no longer confirmed.
  EXPECT_EQ(confirmer.measure(s.input(20, 20, ~uint64_t(0))).confirmed, 1u);
  // Deeper: point 5 is predicted and confirmed too.
  const GuidedConfirmation deep = confirmer.measure(s.input(50, 30, ~uint64_t(0)));
  EXPECT_EQ(deep.predicted, 6u);
  EXPECT_EQ(deep.confirmed, 3u);
  // Inliers only in the top-left cell of the 8×8 grid: every point here lies
  // in another cell, so all count as off the inliers.
  const GuidedConfirmation off = confirmer.measure(s.input(20, 30, uint64_t(1)));
  EXPECT_EQ(off.examined_off_inliers, 5u);
  EXPECT_EQ(off.confirmed_off_inliers, 2u);
  // The cell of point 0 (pixel 270, 190 of 640 × 480: column 3, row 3) holds inliers.
  const Eigen::Vector2d p0 = s.pixel(0);
  const int cell0 = int(p0.y() / 480 * 8) * 8 + int(p0.x() / 640 * 8);
  const GuidedConfirmation on0 = confirmer.measure(s.input(20, 30, uint64_t(1) << cell0));
  EXPECT_EQ(on0.confirmed_off_inliers, on0.confirmed - 1);
  // At most 2 examined of the 5 predicted: every third (points 0 and 3).
  GuidedConfirmationInput sampled = s.input(20, 30, ~uint64_t(0));
  sampled.max_examined = 2;
  const GuidedConfirmation some = confirmer.measure(sampled);
  EXPECT_EQ(some.predicted, 5u);
  EXPECT_EQ(some.examined, 2u);
  EXPECT_EQ(some.confirmed, 1u);
  EXPECT_DOUBLE_EQ(some.share(), 0.5);
}

TEST(GuidedConfirmation, FollowsThePoseAndTheFocal) {
  Scene s;
  s.add_point({2, 0.2, 10}, 0);  // pixel (420, 250)
  s.add_keypoint(s.pixel(0).x(), s.pixel(0).y(), 0, 0);
  GuidedConfirmer confirmer;
  GuidedConfirmationInput in = s.input(20, 1, ~uint64_t(0));
  EXPECT_EQ(confirmer.measure(in).confirmed, 1u);
  // The camera moved 0.3 m sideways: the projection moves 15 px, beyond the radius.
  in.cam_from_segment.translation = Eigen::Vector3d(0.3, 0, 0);
  EXPECT_EQ(confirmer.measure(in).predicted, 1u);
  EXPECT_EQ(confirmer.measure(in).confirmed, 0u);
  // A principal point estimated 15 px the other way puts it back.
  in.principal_point_offset = Eigen::Vector2d(-15, 0);
  EXPECT_EQ(confirmer.measure(in).confirmed, 1u);
  // A focal 20% longer moves it 20 px outwards.
  in.principal_point_offset.setZero();
  in.cam_from_segment.translation.setZero();
  in.focal = 600;
  EXPECT_EQ(confirmer.measure(in).confirmed, 0u);
}

TEST(GuidedConfirmation, FollowsTheCameraModel) {
  Scene s;
  s.camera.aspect = 1.1;             // fy = 550
  s.add_point({0, 4, 10}, 0);        // pixel (320, 240 + 220)
  s.add_point({25, 0, 10}, 1);       // far to the side: x = 2.5
  s.add_point({10, 19, 10}, 2);      // off the axes: r² = 1 + 3.61 = 4.61
  s.add_keypoint(320, 460, 0, 0);    // at point 0's pixel with fy
  s.add_keypoint(8, 240, 1, 0);      // where k1 = −0.2 would fold point 1 back to (x = −0.625)
  s.add_keypoint(359, 321.5, 2, 0);  // and point 2 to (x = 0.078, y = 0.148)
  GuidedConfirmer confirmer;
  GuidedConfirmationInput in = s.input(20, 1, ~uint64_t(0));
  GuidedConfirmation g = confirmer.measure(in);
  EXPECT_EQ(g.predicted, 1u);  // points 1 and 2 project at u = 1570 and 820, outside
  EXPECT_EQ(g.confirmed, 1u);
  // An estimated focal is solved for square pixels (the keypoints only
  // centred): point 0 then projects 20 px higher, off its keypoint.
  s.camera.has_focal = false;
  EXPECT_EQ(confirmer.measure(in).confirmed, 0u);
  s.camera.has_focal = true;
  // Barrel distortion, k1 = −0.2, folds the image back beyond r² = 1 / 0.6:
  // points 1 (r² = 6.25) and 2 (4.61) stay out of view. Point 0 (r² = 0.16)
  // moves 3.2% inwards, to v = 452.96: confirmed by a keypoint there within
  // 2 px (with k1 = +0.2 it would move 3.2% outwards, to 467.04).
  in.radius_px = 2;
  s.add_keypoint(320, 452.96, 0, 0);
  in.keypoints = s.keypoints;
  s.camera.k1 = -0.2;
  g = confirmer.measure(in);
  EXPECT_EQ(g.predicted, 1u);
  EXPECT_EQ(g.confirmed, 1u);
  s.camera.k1 = 0.2;
  EXPECT_EQ(confirmer.measure(in).confirmed, 0u);
  s.camera.k1 = -0.5;  // 8% inwards: v = 442.4
  EXPECT_EQ(confirmer.measure(in).confirmed, 0u);
  // An estimated focal ignores k1 too: point 0 at v = 440 (433.6 were k1 −0.2 applied).
  s.add_keypoint(320, 440, 0, 0);
  in.keypoints = s.keypoints;
  s.camera.k1 = -0.2;
  s.camera.has_focal = false;
  EXPECT_EQ(confirmer.measure(in).confirmed, 1u);
}

TEST(GuidedConfirmation, TravelsInTheConfidenceFeatures) {
  ConfidenceFeatures f;
  f.inliers = 40;
  EXPECT_FALSE(ConfidenceFeatures::from_json(f.to_json()).guided.has_value());
  f.guided = GuidedConfirmation{100, 60, 20, 40, 5};
  const nlohmann::json j = f.to_json();
  ASSERT_TRUE(j.contains("guided"));
  const ConfidenceFeatures back = ConfidenceFeatures::from_json(j);
  ASSERT_TRUE(back.guided.has_value());
  EXPECT_EQ(back.guided->examined, 60u);
  EXPECT_EQ(back.guided->confirmed_off_inliers, 5u);
  // Reported only: the confidence does not depend on it.
  EXPECT_EQ(ConfidenceModel::builtin().evaluate(back),
            ConfidenceModel::builtin().evaluate(ConfidenceFeatures{f.inliers}));
}

TEST(GuidedConfirmation, NothingToMeasureGivesZeros) {
  Scene s;
  s.add_point({0, 0, 10}, 0);
  GuidedConfirmer confirmer;
  const GuidedConfirmation none = confirmer.measure(s.input(20, 30, 0));  // no keypoints
  EXPECT_EQ(none.predicted, 1u);
  EXPECT_EQ(none.examined, 1u);
  EXPECT_EQ(none.confirmed, 0u);
  EXPECT_EQ(none.share(), 0.0);
  GuidedConfirmationInput nan = s.input(20, 30, 0);
  nan.cam_from_segment.translation.x() = std::nan("");
  EXPECT_EQ(confirmer.measure(nan).predicted, 0u);
  s.add_keypoint(s.pixel(0).x(), s.pixel(0).y(), 0, 0);
  EXPECT_EQ(confirmer.measure(s.input(0, 30, 0)).predicted, 0u);  // no depth
  EXPECT_EQ(confirmer.measure(s.input(20, 30, 0)).confirmed, 1u);
}

TEST(GuidedConfirmation, JsonRoundTripAndRejectsNonsense) {
  GuidedConfirmation g{100, 60, 20, 40, 5};
  const GuidedConfirmation back = GuidedConfirmation::from_json(g.to_json());
  EXPECT_EQ(back.predicted, 100u);
  EXPECT_EQ(back.examined, 60u);
  EXPECT_EQ(back.confirmed, 20u);
  EXPECT_EQ(back.examined_off_inliers, 40u);
  EXPECT_EQ(back.confirmed_off_inliers, 5u);
  // Signed integers are counts too (JSON built in C++ from ints).
  nlohmann::json signed_counts = {
      {"predicted", 3}, {"examined", 2}, {"confirmed", 1}, {"examined_off_inliers", 1}, {"confirmed_off_inliers", 0}};
  EXPECT_EQ(GuidedConfirmation::from_json(signed_counts).examined, 2u);
  auto rejects = [](const nlohmann::json& j, const std::string& why) {
    try {
      GuidedConfirmation::from_json(j);
      ADD_FAILURE() << "accepted " << j.dump();
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  nlohmann::json bad = g.to_json();
  bad["confirmed"] = 61;
  rejects(bad, "do not nest (confirmed <= examined");
  bad = g.to_json();
  bad["examined"] = 101;
  rejects(bad, "do not nest (confirmed <= examined");
  bad = g.to_json();
  bad["predicted"] = -1;
  rejects(bad, "'predicted' must be a count");
  bad = g.to_json();
  bad["examined"] = 2.5;
  rejects(bad, "'examined' must be a count");
  bad = g.to_json();
  bad["confirmed_off_inliers"] = 41;
  rejects(bad, "off-inlier counts");
  // Each pairwise bound holds, but 20 are confirmed on the inliers' cells,
  // where only 5 were examined.
  bad = {{"predicted", 100},
         {"examined", 60},
         {"confirmed", 20},
         {"examined_off_inliers", 55},
         {"confirmed_off_inliers", 0}};
  rejects(bad, "off-inlier counts");
  bad["confirmed_off_inliers"] = 15;  // 5 on the inliers' cells: fine
  EXPECT_NO_THROW(GuidedConfirmation::from_json(bad));
  rejects(nlohmann::json::array(), "expected an object");
  rejects(nlohmann::json::object(), "'predicted' must be a count");
}

}  // namespace
}  // namespace visloc
