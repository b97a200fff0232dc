// Seeded pseudo-random numbers for the estimators: SplitMix64 (seeding) and
// xoshiro256** (Blackman & Vigna), with Lemire's multiply-shift bounded
// integers. Identical sequences on every platform for a given seed, unlike
// std::uniform_int_distribution; no state outside the object.
#pragma once

#include <cmath>
#include <cstdint>
#include <numbers>

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

}  // namespace visloc
