// Pair matching rules on planted descriptors, and `match_image_pair` on a real
// pair with repeated windows when ../shared/data is present.
#include <gtest/gtest.h>

#include <array>
#include <filesystem>
#include <set>
#include <utility>

#include <Eigen/Core>

#include "visloc/twoview/image_pair.h"
#include "visloc/twoview/pair_benchmark.h"
#include "visloc/util/error.h"
#include "visloc/util/random.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace {

// A descriptor: `base` everywhere, plus `bump` on element `k`.
std::array<uint8_t, kDescriptorDim> descriptor(uint8_t base, int k = -1, int bump = 0) {
  std::array<uint8_t, kDescriptorDim> d;
  d.fill(base);
  if (k >= 0) d[static_cast<size_t>(k)] = static_cast<uint8_t>(base + bump);
  return d;
}

FeatureSet features(const std::vector<std::array<uint8_t, kDescriptorDim>>& descriptors) {
  FeatureSet f;
  f.descriptors = DescriptorMatrix(descriptors.size());
  for (size_t i = 0; i < descriptors.size(); ++i) {
    f.keypoints.push_back({static_cast<float>(10 * i), static_cast<float>(i), 1, 0});
    std::copy(descriptors[i].begin(), descriptors[i].end(), f.descriptors.row(i));
  }
  return f;
}

TEST(PairMatching, OneToOneAndGroupRatio) {
  // b: two near-identical "windows" (0, 1), then clearly different ones.
  const FeatureSet b = features({descriptor(100, 0, 10), descriptor(100, 0, 12), descriptor(60), descriptor(20),
                                 descriptor(180), descriptor(220), descriptor(240)});
  // a0 matches b0 and b1 about equally (repeated window): no 1-1, a group of 2.
  // a1 matches b2 clearly: 1-1.
  const FeatureSet a = features({descriptor(100, 0, 11), descriptor(61)});
  PairMatchingOptions o;
  const TwoViewCorrespondences m = match_feature_sets(a, b, o);
  ASSERT_EQ(m.size(), 2u);
  EXPECT_EQ(m.feature1[0], 0u);
  EXPECT_EQ(m.in_hypothesis_set[0], 0);
  EXPECT_EQ(m.candidate_offsets[1] - m.candidate_offsets[0], 2u);  // both windows
  EXPECT_EQ(m.in_hypothesis_set[1], 1);
  EXPECT_EQ(m.candidate_feature2[m.candidate_offsets[1]], 2u);
  // The best-ratio rule drops the ambiguous feature (d0/d1 ≈ 1 > 0.9).
  o.rule = OneToManyRule::kBestRatio;
  const TwoViewCorrespondences best = match_feature_sets(a, b, o);
  ASSERT_EQ(best.size(), 1u);
  EXPECT_EQ(best.feature1[0], 1u);
  o.ratio_one_to_many = 0.5f;  // below the 1-1 ratio
  EXPECT_THROW(match_feature_sets(a, b, o), Error);
}

// Two views of a planted scene for verify_image_pair: cameras 1 m apart
// along x (epipolar lines horizontal), 150 distinct points, and 8 columns
// of 3 identical "windows" stacked vertically (only the 1-M set keeps
// them: each has 3 equal candidates, one on its own epipolar line), plus
// 60 unrelated features per view.
struct PlantedPair {
  FeatureSet a, b;
  size_t distinct = 150, windows = 24;  // features 0..149 and 150..173 correspond by index
  Eigen::Matrix3d K;
};

PlantedPair planted_pair() {
  PlantedPair p;
  p.K << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  RandomGenerator rng(7);
  // b_from_a: a translation along the camera's x axis, no rotation, as two
  // same-heading street views (the 5-point solver's hard case, see
  // pose/two_view_test.cc).
  const Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  const Eigen::Vector3d baseline(-1.0, 0, 0);
  std::vector<Eigen::Vector3d> points;
  for (size_t i = 0; i < p.distinct; ++i)
    points.emplace_back(rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(5, 12));
  for (int column = 0; column < 8; ++column)
    for (int row = 0; row < 3; ++row) points.emplace_back(-2.5 + 0.7 * column, -1.5 + 1.2 * row, 8.0);
  std::vector<std::array<uint8_t, kDescriptorDim>> da, db;
  auto random_descriptor = [&] {
    std::array<uint8_t, kDescriptorDim> d;
    for (auto& v : d) v = static_cast<uint8_t>(rng.below(200));
    return d;
  };
  auto noisy = [&](std::array<uint8_t, kDescriptorDim> d, bool window) {
    if (!window)  // windows are exact copies: three candidates at distance 0, no 1-1 match
      for (auto& v : d) v = static_cast<uint8_t>(v + rng.below(3));
    return d;
  };
  std::array<uint8_t, kDescriptorDim> column_descriptor{};
  for (size_t i = 0; i < points.size(); ++i) {
    const bool window = i >= p.distinct;
    if (!window || (i - p.distinct) % 3 == 0) column_descriptor = random_descriptor();
    for (FeatureSet* f : {&p.a, &p.b}) {
      const Eigen::Vector3d x = p.K * (f == &p.a ? points[i] : Eigen::Vector3d(rotation * points[i] + baseline));
      f->keypoints.push_back({static_cast<float>(x.x() / x.z()), static_cast<float>(x.y() / x.z()), 2, 0});
      (f == &p.a ? da : db).push_back(noisy(column_descriptor, window));
    }
  }
  for (int k = 0; k < 60; ++k)
    for (FeatureSet* f : {&p.a, &p.b}) {
      f->keypoints.push_back({static_cast<float>(rng.uniform(0, 640)), static_cast<float>(rng.uniform(0, 480)), 2, 0});
      (f == &p.a ? da : db).push_back(random_descriptor());
    }
  for (auto [f, d] : {std::pair{&p.a, &da}, std::pair{&p.b, &db}}) {
    f->descriptors = DescriptorMatrix(d->size());
    for (size_t i = 0; i < d->size(); ++i) std::copy((*d)[i].begin(), (*d)[i].end(), f->descriptors.row(i));
  }
  return p;
}

TEST(PairVerification, OneManyKeepsRepeatedWindowsWithTheirTruePartner) {
  const PlantedPair p = planted_pair();
  const size_t corresponding = p.distinct + p.windows;
  for (const bool essential : {false, true}) {
    PairVerificationOptions o;
    if (essential) {
      o.estimation.model = TwoViewModel::kEssential;
      o.estimation.calibration1 = o.estimation.calibration2 = p.K;
    }
    const VerifiedPair one_many = verify_image_pair(p.a, p.b, o);
    ASSERT_TRUE(one_many.verified) << essential;
    size_t true_inliers = 0, window_inliers = 0;
    for (const auto& [i, j] : one_many.inliers) {
      EXPECT_LT(i, corresponding) << "an unrelated feature is an inlier";
      if (i == j) ++true_inliers;
      if (i == j && i >= p.distinct && i < corresponding) ++window_inliers;
    }
    EXPECT_EQ(true_inliers, one_many.inliers.size()) << "every inlier is its feature's true partner";
    EXPECT_GE(true_inliers, corresponding - 5);
    EXPECT_EQ(window_inliers, p.windows) << "1-M verification picks the window on the epipolar line";
    EXPECT_EQ(one_many.estimate.extra_inliers, one_many.estimate.inliers - one_many.estimate.one_to_one_inliers);
    std::set<uint32_t> in_image2;
    for (const auto& inlier : one_many.inliers)
      EXPECT_TRUE(in_image2.insert(inlier.second).second) << "one per feature";
    EXPECT_GE(one_many.matches.size(), one_many.inliers.size());
    // Classical RANSAC sees only the 1-1 set: the windows (three equal
    // candidates each) fail its ratio test.
    o.estimation.variant = RansacVariant::kClassic11;
    const VerifiedPair classic = verify_image_pair(p.a, p.b, o);
    ASSERT_TRUE(classic.verified);
    for (const auto& [i, j] : classic.inliers) EXPECT_TRUE(i < p.distinct && i == j) << i << " " << j;
  }
}

TEST(PairVerification, UnrelatedImagesAreNotVerified) {
  PlantedPair p = planted_pair();
  PlantedPair other = planted_pair();
  // The same keypoints with descriptors that match nothing of `a`.
  RandomGenerator rng(99);
  for (size_t i = 0; i < other.b.size(); ++i)
    for (size_t k = 0; k < kDescriptorDim; ++k) other.b.descriptors.row(i)[k] = static_cast<uint8_t>(rng.below(256));
  const VerifiedPair v = verify_image_pair(p.a, other.b, PairVerificationOptions{});
  EXPECT_FALSE(v.verified);
  EXPECT_TRUE(v.inliers.empty());
  PairVerificationOptions bad;
  bad.min_inliers = 7;
  EXPECT_THROW(verify_image_pair(p.a, p.b, bad), Error);
  bad = {};
  bad.min_inlier_ratio = 1.5;
  EXPECT_THROW(verify_image_pair(p.a, p.b, bad), Error);
  // Most 1-1 matches wrong: 120 of the 150 distinct points of `b` moved to
  // random places (still each feature's clear nearest neighbour). 30 + 24
  // windows fit, enough inliers, but 30 of 150 1-1 matches is under 25 %.
  PlantedPair moved = planted_pair();
  RandomGenerator place(5);
  for (size_t i = 0; i < 120; ++i)
    moved.b.keypoints[i] = {static_cast<float>(place.uniform(0, 640)), static_cast<float>(place.uniform(0, 480)), 2, 0};
  const VerifiedPair low = verify_image_pair(moved.a, moved.b, PairVerificationOptions{});
  EXPECT_FALSE(low.verified);
  EXPECT_GE(low.estimate.inliers, 15u);
  // Repeated windows only, and no overlap: `b`'s distinct features are
  // other ones, its windows elsewhere. Plenty of 1-M candidates, no 1-1
  // support: not verified (the windows alone must not verify a pair).
  PlantedPair apart = planted_pair();
  for (size_t i = 0; i < apart.distinct + apart.windows; ++i) {
    apart.b.keypoints[i] = {static_cast<float>(place.uniform(0, 640)), static_cast<float>(place.uniform(0, 480)), 2, 0};
    if (i < apart.distinct)
      for (size_t k = 0; k < kDescriptorDim; ++k)
        apart.b.descriptors.row(i)[k] = static_cast<uint8_t>(place.below(256));
  }
  EXPECT_FALSE(verify_image_pair(apart.a, apart.b, PairVerificationOptions{}).verified);
  PairVerificationOptions any_ratio;
  any_ratio.min_inlier_ratio = 0;
  EXPECT_TRUE(verify_image_pair(moved.a, moved.b, any_ratio).verified);
}

TEST(ImagePair, RepeatedWindowsOfCastleP19) {
  const std::filesystem::path scene = std::filesystem::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "castle-P19" / "images";
  if (!std::filesystem::exists(scene / "0005.jpg")) GTEST_SKIP() << "../shared/data/strecha/castle-P19 is absent";
  ImagePairOptions o;
  o.sift.max_image_side = 1024;
  o.sift.max_features = 4096;
  o.estimation.variant = RansacVariant::kClassic11;
  const ImagePairResult classic = match_image_pair(scene / "0005.jpg", scene / "0006.jpg", o);
  o.estimation.variant = RansacVariant::kOneManySprt;
  const ImagePairResult one_many = match_image_pair(scene / "0005.jpg", scene / "0006.jpg", o);
  ASSERT_TRUE(classic.estimate.found);
  ASSERT_TRUE(one_many.estimate.found);
  EXPECT_GT(one_many.estimate.inliers, classic.estimate.inliers);
  EXPECT_GT(one_many.estimate.extra_inliers, 0u);
  const std::filesystem::path png = unique_temp_path("visloc_pair.png");
  draw_pair_inliers(scene / "0005.jpg", scene / "0006.jpg", one_many, png, 400);
  EXPECT_GT(std::filesystem::file_size(png), 1000u);
  std::filesystem::remove(png);
}

}  // namespace
}  // namespace visloc

namespace visloc {
namespace {

TEST(PairBenchmark, StrechaTruthFundamentalFitsColmapFreeMatches) {
  const std::filesystem::path strecha = std::filesystem::path(VISLOC_SHARED_DATA_DIR) / "strecha";
  if (!std::filesystem::exists(strecha / "fountain-P11" / "cameras" / "0000.jpg.camera"))
    GTEST_SKIP() << "../shared/data/strecha is absent";
  // The truth F of the first fountain pair puts the 1-1 matches that 1m-sprt
  // keeps within a pixel or two of its epipolar lines (the truth is right).
  PairBenchmarkOptions o;
  o.strecha_dir = strecha;
  o.scenes = {"fountain-P11"};
  o.max_pairs_per_scene = 1;
  o.sift.max_features = 2048;
  o.opencv = false;
  const PairBenchmarkResult r = run_pair_benchmark(o);
  ASSERT_EQ(r.rows.size(), 3u);
  for (const auto& row : r.rows) {
    EXPECT_TRUE(row.success) << row.method << " median error " << row.median_error_px;
    EXPECT_GT(row.truth_correspondences, 100u);
    EXPECT_GT(row.true_inliers, row.inliers * 8 / 10) << row.method;
  }
  EXPECT_THROW(read_strecha_camera(strecha / "fountain-P11" / "images" / "0000.jpg"), Error);
}

}  // namespace
}  // namespace visloc
