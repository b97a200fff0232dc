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

TEST(HammingBlend, HeldOutViewLiesAsFarAsANewView) {
  float mean[kDescriptorDim];
  uint8_t obs[kDescriptorDim], out[kDescriptorDim];
  std::fill_n(mean, kDescriptorDim, 100.0f);
  std::fill_n(obs, kDescriptorDim, uint8_t(110));
  std::fill_n(out, kDescriptorDim, uint8_t(7));
  EXPECT_FALSE(held_out_view(mean, obs, 1, out));  // a single view: no spread to scale
  EXPECT_EQ(out[0], 7);
  ASSERT_TRUE(held_out_view(mean, obs, 3, out));  // c = √2
  EXPECT_EQ(out[0], 114);
  ASSERT_TRUE(held_out_view(mean, obs, 1000, out));  // c → 1
  EXPECT_EQ(out[5], 110);
  mean[1] = 250, obs[1] = 255, mean[2] = 5, obs[2] = 0;
  ASSERT_TRUE(held_out_view(mean, obs, 2, out));  // c = √3, clamped
  EXPECT_EQ(out[1], 255);
  EXPECT_EQ(out[2], 0);
  // Statistically: views of a point with i.i.d. noise, t per track; the
  // scaled view's mean squared offset from the track mean matches a new view's.
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0, 8);
  for (const uint32_t t : {2u, 3u, 6u}) {
    double scaled = 0, fresh = 0;
    const int trials = 4000;
    for (int trial = 0; trial < trials; ++trial) {
      std::vector<std::array<double, kDescriptorDim>> views(t + 1);
      for (auto& v : views)
        for (double& x : v) x = 120 + noise(rng);
      float m[kDescriptorDim];
      for (int j = 0; j < kDescriptorDim; ++j) {
        double s = 0;
        for (uint32_t k = 0; k < t; ++k) s += views[k][j];
        m[j] = float(s / t);
      }
      uint8_t o[kDescriptorDim], v[kDescriptorDim];
      for (int j = 0; j < kDescriptorDim; ++j) o[j] = uint8_t(std::lround(views[0][j]));
      ASSERT_TRUE(held_out_view(m, o, t, v));
      for (int j = 0; j < kDescriptorDim; ++j) {
        scaled += (v[j] - m[j]) * (v[j] - m[j]);
        fresh += (views[t][j] - m[j]) * (views[t][j] - m[j]);  // view t is not in the mean
      }
    }
    EXPECT_NEAR(scaled / fresh, 1.0, 0.03) << "track " << t;
  }
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
