// Pair matching rules on planted descriptors, and `match_image_pair` on a real
// pair with repeated windows when ../shared/data is present.
#include <gtest/gtest.h>

#include <filesystem>

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
