#include <gtest/gtest.h>

#include <random>

#include "visloc/matching/exact_matcher.h"
#include "visloc/util/error.h"

using namespace visloc;

TEST(ExactMatcher, FindsPerturbedCopiesAndAppliesRatio) {
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> u(0, 60), noise(-2, 2);
  DescriptorMatrix db(500);
  for (size_t i = 0; i < db.size_bytes(); ++i) db.data()[i] = static_cast<uint8_t>(u(rng));
  DescriptorMatrix q(100);
  for (size_t i = 0; i < 100; ++i)
    for (int k = 0; k < kDescriptorDim; ++k)
      q.row(i)[k] = static_cast<uint8_t>(std::clamp(db.row(i * 5)[k] + noise(rng), 0, 255));
  // Query 0 is made ambiguous: the exact midpoint of two database rows.
  for (int k = 0; k < kDescriptorDim; ++k) q.row(0)[k] = static_cast<uint8_t>((db.row(1)[k] + db.row(2)[k]) / 2);
  ExactMatcher m(db);
  auto matches = m.match(q, {.ratio = 0.8});
  int correct = 0;
  bool zero_matched = false;
  for (const auto& r : matches) {
    if (r.query == 0) zero_matched = true;
    else if (r.database == r.query * 5) ++correct;
  }
  EXPECT_EQ(correct, 99);
  EXPECT_FALSE(zero_matched);
  EXPECT_THROW(m.match(q, {.ratio = 1.5}), Error);
}
