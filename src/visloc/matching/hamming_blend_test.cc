#include "visloc/matching/hamming_blend.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "visloc/util/error.h"
#include "visloc/util/test_support.h"

using namespace visloc;

namespace {

TEST(HammingBlend, ChordTableGoesFromZeroToTheDiameter) {
  float t[kHashBits + 1];
  hash_chord_table(100.0, t);
  EXPECT_FLOAT_EQ(t[0], 0.0f);
  EXPECT_NEAR(t[kHashBits / 2], 200.0f, 1e-3);  // orthogonal: 2|q − μ|²
  EXPECT_NEAR(t[kHashBits], 400.0f, 1e-3);      // opposite: (2|q − μ|)²
  for (int h = 1; h <= kHashBits; ++h) EXPECT_GT(t[h], t[h - 1]) << h;
  uint8_t d[kDescriptorDim];
  float mean[kDescriptorDim];
  std::fill_n(d, kDescriptorDim, uint8_t(12));
  std::fill_n(mean, kDescriptorDim, 10.0f);
  EXPECT_DOUBLE_EQ(squared_norm_from_mean(d, mean), 4.0 * kDescriptorDim);
}

// The track's mean without one view is the mean of the others.
TEST(HammingBlend, LeaveOneOutMeanIsTheOtherViewsMean) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> byte(0, 255);
  for (const uint32_t t : {2u, 3u, 7u}) {
    std::vector<std::array<uint8_t, kDescriptorDim>> views(t);
    for (auto& v : views)
      for (uint8_t& x : v) x = uint8_t(byte(rng));
    float mean[kDescriptorDim], others[kDescriptorDim], out[kDescriptorDim];
    for (int j = 0; j < kDescriptorDim; ++j) {
      double all = 0, rest = 0;
      for (uint32_t k = 0; k < t; ++k) all += views[k][j], rest += k == 1 ? 0 : views[k][j];
      mean[j] = float(all / t);
      others[j] = float(rest / (t - 1));
    }
    ASSERT_TRUE(leave_one_out_mean(mean, views[1].data(), t, out));
    for (int j = 0; j < kDescriptorDim; ++j) EXPECT_NEAR(out[j], others[j], 1e-3) << "track " << t << ", dim " << j;
  }
  float mean[kDescriptorDim], out[kDescriptorDim];
  uint8_t obs[kDescriptorDim];
  std::fill_n(mean, kDescriptorDim, 3.0f);
  std::fill_n(obs, kDescriptorDim, uint8_t(3));
  std::fill_n(out, kDescriptorDim, 7.0f);
  EXPECT_FALSE(leave_one_out_mean(mean, obs, 1, out));  // a single view: no other
  EXPECT_EQ(out[0], 7.0f);
}

TEST(HammingBlend, OptionsAreValidated) {
  EXPECT_NO_THROW(HammingBlendFitOptions{}.validate());
  const auto bad = [](HammingBlendFitOptions o, const char* field) {
    const std::string e = error_of([&] { o.validate(); });
    EXPECT_NE(e.find(field), std::string::npos) << e;
  };
  bad({.refined_list = 1}, "refined_list");
  bad({.refined_list = 65}, "refined_list");
  bad({.ratio_one_to_one = 0}, "ratio_one_to_one");
  bad({.ratio_one_to_one = 1.5f}, "ratio_one_to_one");
  bad({.weight_steps = 0}, "weight_steps");
}

}  // namespace
