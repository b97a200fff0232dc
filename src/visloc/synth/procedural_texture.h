// Procedural texture primitives evaluated analytically at a surface point
// (metres in a face's own coordinates). Every function is a pure function of
// its arguments and a seed, so a world point has the same colour in every
// view. Band-limiting: `footprint` is the size in metres of one render sample
// on the surface; detail finer than the footprint is faded to its mean (the
// analytic counterpart of mip-mapping), which keeps distant and grazing
// facades free of aliasing noise that SIFT would otherwise detect.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "visloc/synth/random.h"

namespace visloc::synth {

struct Rgb {
  float r = 0, g = 0, b = 0;
};
inline Rgb operator+(Rgb a, Rgb b) { return {a.r + b.r, a.g + b.g, a.b + b.b}; }
inline Rgb operator*(Rgb a, float s) { return {a.r * s, a.g * s, a.b * s}; }
inline Rgb operator*(Rgb a, Rgb b) { return {a.r * b.r, a.g * b.g, a.b * b.b}; }
inline Rgb mix(Rgb a, Rgb b, float t) { return {a.r + (b.r - a.r) * t, a.g + (b.g - a.g) * t, a.b + (b.b - a.b) * t}; }

// Colour from a hash: hue anywhere, saturation and value in the given ranges.
Rgb hashed_colour(uint64_t hash, float sat_lo, float sat_hi, float val_lo, float val_hi);
Rgb hsv_to_rgb(float h, float s, float v);

inline float smoothstep01(float t) {
  t = std::clamp(t, 0.0f, 1.0f);
  return t * t * (3.0f - 2.0f * t);
}

// Weight in [0, 1] that keeps a detail of size `feature_m` when the sample
// footprint is smaller than it and fades it out as the footprint grows.
inline float detail_weight(double feature_m, double footprint_m) {
  return 1.0f - smoothstep01(static_cast<float>((footprint_m / feature_m - 0.35) / 0.65));
}

// Value noise on an integer lattice of period 1 (hashed corner values in
// [0, 1], smoothstep interpolation). Mean 0.5.
inline float value_noise(double x, double y, uint64_t seed) {
  const double fx = std::floor(x), fy = std::floor(y);
  const auto ix = static_cast<int64_t>(fx), iy = static_cast<int64_t>(fy);
  const float tx = smoothstep01(static_cast<float>(x - fx));
  const float ty = smoothstep01(static_cast<float>(y - fy));
  // One SplitMix64 finaliser per lattice corner (the key combines seed and
  // corner by multiplication with odd constants).
  const uint64_t base = mix64(seed);
  const auto v = [&](int64_t a, int64_t b) {
    const uint64_t h = mix64(base ^ (static_cast<uint64_t>(a) * 0x9e3779b97f4a7c15ULL) ^
                             (static_cast<uint64_t>(b) * 0xd1b54a32d192ed03ULL));
    return static_cast<float>(h >> 40) * 0x1.0p-24f;
  };
  const float v00 = v(ix, iy), v10 = v(ix + 1, iy), v01 = v(ix, iy + 1), v11 = v(ix + 1, iy + 1);
  const float a = v00 + (v10 - v00) * tx;
  const float b = v01 + (v11 - v01) * tx;
  return a + (b - a) * ty;
}

// Fractal noise: `octaves` octaves from `base_scale_m` metres down, each
// half the size; octaves finer than the footprint are replaced by their
// mean. Result in about [0, 1], mean 0.5.
inline float fractal_noise(double u, double v, double base_scale_m, int octaves, double footprint_m,
                           uint64_t seed) {
  float sum = 0.0f, norm = 0.0f, amplitude = 1.0f;
  double scale = base_scale_m;
  for (int o = 0; o < octaves; ++o) {
    const float w = detail_weight(scale, footprint_m);
    const float n = w > 0.0f ? value_noise(u / scale, v / scale, seed + 977u * static_cast<uint64_t>(o)) : 0.5f;
    sum += amplitude * (0.5f + (n - 0.5f) * w);
    norm += amplitude;
    amplitude *= 0.55f;
    scale *= 0.5;
  }
  return sum / norm;
}

// Soft-edged membership of x in [lo, hi] with an edge width of `soft` metres
// (anti-aliased box function).
inline float box_coverage(double x, double lo, double hi, double soft) {
  const double s = std::max(soft, 1e-6);
  const double a = std::clamp((x - lo) / s + 0.5, 0.0, 1.0);
  const double b = std::clamp((hi - x) / s + 0.5, 0.0, 1.0);
  return static_cast<float>(std::min(a, b));
}

}  // namespace visloc::synth
