// The one random-number scheme of the library: SplitMix64 (seeding) and
// xoshiro256** (Blackman & Vigna), with Lemire's multiply-shift bounded
// integers, Fisher-Yates shuffles and sampling built on them. Identical
// sequences on every platform and standard library for a given seed (unlike
// std::shuffle and the std::*_distribution classes, whose algorithms are
// unspecified), so the same seed gives the same map everywhere; no state
// outside the object.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <numeric>
#include <utility>
#include <vector>

namespace visloc {

class RandomGenerator {
 public:
  explicit RandomGenerator(uint64_t seed) {
    uint64_t z = seed;
    for (auto& w : s_) {
      z += 0x9E3779B97F4A7C15ull;
      uint64_t x = z;
      x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
      x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
      w = x ^ (x >> 31);
    }
  }
  uint64_t next() {
    const uint64_t result = rotl(s_[1] * 5, 7) * 9;
    const uint64_t t = s_[1] << 17;
    s_[2] ^= s_[0];
    s_[3] ^= s_[1];
    s_[1] ^= s_[2];
    s_[0] ^= s_[3];
    s_[2] ^= t;
    s_[3] = rotl(s_[3], 45);
    return result;
  }
  // Uniform integer in [0, n), n > 0.
  uint32_t below(uint32_t n) {
    return static_cast<uint32_t>((static_cast<__uint128_t>(next() >> 32) * n) >> 32);
  }
  // Uniform integer in [0, n), n > 0, for 64-bit ranges.
  uint64_t below64(uint64_t n) { return static_cast<uint64_t>((static_cast<__uint128_t>(next()) * n) >> 64); }
  // Uniform double in [0, 1).
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Standard normal (Box-Muller).
  double normal() {
    double u1 = uniform();
    while (u1 <= 0.0) u1 = uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * uniform());
  }

 private:
  static uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
  uint64_t s_[4];
};

// Fisher-Yates shuffle of a random-access range.
template <typename RandomIt>
void shuffle(RandomIt first, RandomIt last, RandomGenerator& rng) {
  const auto n = static_cast<uint64_t>(last - first);
  for (uint64_t i = n; i > 1; --i) std::swap(first[i - 1], first[static_cast<std::ptrdiff_t>(rng.below64(i))]);
}

// `count` distinct indices drawn uniformly from [0, total), sorted
// (a partial Fisher-Yates); all of them, in order, when count >= total.
inline std::vector<size_t> sample_sorted_indices(size_t total, size_t count, RandomGenerator& rng) {
  std::vector<size_t> idx(total);
  std::iota(idx.begin(), idx.end(), size_t{0});
  if (count >= total) return idx;
  for (size_t i = 0; i < count; ++i) std::swap(idx[i], idx[i + rng.below64(total - i)]);
  idx.resize(count);
  std::sort(idx.begin(), idx.end());
  return idx;
}

}  // namespace visloc
