// Deterministic randomness for the synthetic city. Two tools, no global
// state: a seeded sequential generator (SplitMix64, Steele et al., "Fast
// splittable pseudorandom number generators", OOPSLA 2014) for the layout,
// and stateless hashes of integer keys for everything evaluated per pixel
// (texture cells, window variants, sign glyphs), so that the colour of a
// world point never depends on the order in which pixels or images are
// rendered, nor on the number of threads.
#pragma once

#include <cmath>
#include <cstdint>

namespace visloc::synth {

// SplitMix64 finaliser: a bijective 64-bit mix with full avalanche.
inline constexpr uint64_t mix64(uint64_t z) {
  z += 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

// Hash of a sequence of integer keys.
inline constexpr uint64_t hash_keys(uint64_t a) { return mix64(a); }
template <typename... Rest>
inline constexpr uint64_t hash_keys(uint64_t a, uint64_t b, Rest... rest) {
  return hash_keys(mix64(a) ^ (b + 0x632be59bd9b4e019ULL), static_cast<uint64_t>(rest)...);
}

// Uniform in [0, 1) from the top 53 bits of a hash.
inline double unit_from_hash(uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

template <typename... Keys>
inline double hash_unit(Keys... keys) {
  return unit_from_hash(hash_keys(static_cast<uint64_t>(keys)...));
}

// Sequential generator for layout decisions.
class SplitMix64 {
 public:
  explicit SplitMix64(uint64_t seed) : state_(seed) {}
  uint64_t next() {
    state_ += 0x9e3779b97f4a7c15ULL;
    uint64_t z = state_;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  double uniform() { return unit_from_hash(next()); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Integer in [lo, hi] inclusive.
  int uniform_int(int lo, int hi) {
    return lo + static_cast<int>(uniform() * static_cast<double>(hi - lo + 1));
  }
  bool bernoulli(double p) { return uniform() < p; }
  // Standard normal (Box-Muller; one value per call for simplicity).
  double normal() {
    const double u1 = 1.0 - uniform();  // (0, 1]
    const double u2 = uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
  }

 private:
  uint64_t state_;
};

}  // namespace visloc::synth
