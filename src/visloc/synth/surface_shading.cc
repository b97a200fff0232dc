#include "visloc/synth/surface_shading.h"

#include <algorithm>
#include <cmath>

namespace visloc::synth {
namespace {

inline double fract(double x) { return x - std::floor(x); }
inline float luminance(Rgb c) { return 0.299f * c.r + 0.587f * c.g + 0.114f * c.b; }

// Glyph-like lettering: a row of 5×7 bitmaps whose bits come from a hash,
// in a box of width w and height h (x right, y up, metres). Returns the ink
// coverage in [0, 1]; detail finer than the footprint fades to the mean ink.
float lettering(uint64_t seed, double x, double y, double w, double h, double footprint) {
  const double glyph_h = h, cell = glyph_h / 7.0, glyph_w = 6.0 * cell;  // 5 columns + 1 gap
  const int max_glyphs = static_cast<int>(w / glyph_w);
  if (max_glyphs < 1) return 0.0f;
  const int glyphs = std::max(1, static_cast<int>(max_glyphs * (0.5 + 0.5 * hash_unit(seed, 1))));
  const double x0 = (w - glyphs * glyph_w + cell) / 2;
  if (x < x0 || y < 0 || y >= h) return 0.0f;
  const int gi = static_cast<int>((x - x0) / glyph_w);
  if (gi >= glyphs) return 0.0f;
  const double gx = x - x0 - gi * glyph_w;
  const int col = static_cast<int>(gx / cell);
  if (col >= 5) return 0.0f;
  const int row = std::min(6, static_cast<int>((h - y) / cell));
  const uint64_t bits = hash_keys(seed, 200 + static_cast<uint64_t>(gi));
  // Mirror-symmetric glyphs (columns 0-1 mirror 3-4) look more letter-like.
  const int c = col <= 2 ? col : 4 - col;
  const float ink = static_cast<float>((bits >> (row * 3 + c)) & 1u);
  const float keep = detail_weight(cell, footprint);
  return 0.5f + (ink - 0.5f) * keep;
}

Rgb wall_colour(const BuildingStyle& s, double u, double v, double fp) {
  Rgb c = s.wall;
  switch (s.material) {
    case FacadeMaterial::kPlaster: {
      const float n = fractal_noise(u, v, 1.6, 5, fp, s.seed);
      c = c * (0.82f + 0.36f * n);
      break;
    }
    case FacadeMaterial::kBrick: {
      const double bh = 0.16, bw = 0.48;
      const double row = std::floor(v / bh);
      const double uu = u + (static_cast<int64_t>(row) & 1 ? bw / 2 : 0.0);
      const double col = std::floor(uu / bw);
      const float tone = static_cast<float>(hash_unit(s.seed, static_cast<uint64_t>(static_cast<int64_t>(row)),
                                                      static_cast<uint64_t>(static_cast<int64_t>(col))));
      const float wt = detail_weight(bh, fp);
      c = c * (1.0f + (tone - 0.5f) * 0.3f * wt);
      const double mu = fract(uu / bw) * bw, mv = fract(v / bh) * bh;
      const float mortar = std::max(box_coverage(mu, 0.0, 0.025, fp), box_coverage(mv, 0.0, 0.025, fp));
      const float wm = detail_weight(0.05, fp);
      c = mix(c, Rgb{0.78f, 0.76f, 0.72f}, mortar * wm + (1 - wm) * 0.2f);
      break;
    }
    case FacadeMaterial::kConcretePanels: {
      const double pw = 1.5, ph = 1.6;
      const float tone = static_cast<float>(hash_unit(s.seed, static_cast<uint64_t>(static_cast<int64_t>(std::floor(u / pw))),
                                                      static_cast<uint64_t>(static_cast<int64_t>(std::floor(v / ph)))));
      c = c * (0.9f + 0.2f * tone) * (0.9f + 0.2f * fractal_noise(u, v, 0.8, 3, fp, s.seed + 5));
      const float joint = std::max(box_coverage(fract(u / pw) * pw, 0.0, 0.04, fp),
                                   box_coverage(fract(v / ph) * ph, 0.0, 0.04, fp));
      const float wj = detail_weight(0.08, fp);
      c = c * (1.0f - 0.45f * (joint * wj + (1 - wj) * 0.05f));
      break;
    }
    case FacadeMaterial::kStone: {
      const double bh = 0.4, bw = 0.8;
      const double row = std::floor(v / bh);
      const double uu = u + (static_cast<int64_t>(row) & 1 ? bw * 0.37 : 0.0);
      const float tone = static_cast<float>(hash_unit(s.seed, static_cast<uint64_t>(static_cast<int64_t>(row)),
                                                      static_cast<uint64_t>(static_cast<int64_t>(std::floor(uu / bw)))));
      c = c * (0.88f + 0.24f * tone) * (0.9f + 0.2f * fractal_noise(u, v, 0.5, 3, fp, s.seed + 9));
      const float joint = std::max(box_coverage(fract(uu / bw) * bw, 0.0, 0.03, fp),
                                   box_coverage(fract(v / bh) * bh, 0.0, 0.03, fp));
      const float wj = detail_weight(0.06, fp);
      c = c * (1.0f - 0.35f * (joint * wj + (1 - wj) * 0.08f));
      break;
    }
  }
  // Weathering: large, unique stains.
  const float stain = fractal_noise(u, v * 1.6, 5.0, 2, fp, s.seed + 77);
  return c * (0.8f + 0.35f * stain);
}

// Glass of one window: reflections (facade-space noise, so consistent across
// views), blinds, curtains or a lit room chosen per window.
Rgb window_glass(const BuildingStyle& s, uint64_t window_seed, double wu, double wv, double w, double h,
                 double face_u, double face_v, double fp) {
  const float refl = fractal_noise(face_u, face_v, 2.5, 2, fp, s.seed + 31);
  Rgb c = s.glass * (0.7f + 0.7f * refl + 0.25f * static_cast<float>(wv / h));
  const double p = hash_unit(window_seed, 1);
  if (p < 0.45) {  // blinds from the top
    const double frac = 0.15 + 0.75 * hash_unit(window_seed, 2);
    if (wv > h * (1.0 - frac)) {
      const Rgb blind = hashed_colour(hash_keys(window_seed, 3), 0.0f, 0.25f, 0.62f, 0.9f);
      const float slat = box_coverage(fract(wv / 0.06) * 0.06, 0.0, 0.012, fp) * detail_weight(0.06, fp);
      return blind * (1.0f - 0.25f * slat);
    }
  } else if (p < 0.65) {  // curtains on both sides
    const double cw = w * (0.15 + 0.3 * hash_unit(window_seed, 4));
    if (wu < cw || wu > w - cw) {
      const Rgb curtain = hashed_colour(hash_keys(window_seed, 5), 0.2f, 0.7f, 0.4f, 0.85f);
      const float fold = 0.85f + 0.15f * static_cast<float>(std::sin(wu * 40.0)) * detail_weight(0.08, fp);
      return curtain * fold;
    }
  } else if (p > 0.96) {  // lit room
    return Rgb{0.95f, 0.85f, 0.55f} * (0.85f + 0.15f * refl);
  }
  return c;
}

Rgb shade_poster(const ShadingContext& ctx, uint64_t ps, double s, double t, double pw, double ph, double fp) {
  const double edge = 0.04;
  if (s * pw < edge || (1 - s) * pw < edge || t * ph < edge || (1 - t) * ph < edge)
    return hash_unit(ps, 9) < 0.5 ? Rgb{0.92f, 0.92f, 0.9f} : Rgb{0.1f, 0.1f, 0.1f};
  if (ctx.photos && !ctx.photos->empty() && hash_unit(ps, 1) < ctx.photo_fraction)
    return ctx.photos->sample(hash_keys(ps, 2) % ctx.photos->size(), s, 1.0 - t);
  Rgb c = hashed_colour(hash_keys(ps, 3), 0.2f, 0.9f, 0.3f, 0.95f);
  const double fs = fp / std::min(pw, ph);  // footprint in poster units
  const int shapes = 4 + static_cast<int>(hash_unit(ps, 4) * 5);
  for (int i = 0; i < shapes; ++i) {
    const uint64_t h = hash_keys(ps, 10 + static_cast<uint64_t>(i));
    const double cx = hash_unit(h, 1), cy = 0.1 + 0.65 * hash_unit(h, 2), r = 0.06 + 0.25 * hash_unit(h, 3);
    const Rgb sc = hashed_colour(hash_keys(h, 4), 0.3f, 1.0f, 0.15f, 1.0f);
    const int type = static_cast<int>(hash_unit(h, 5) * 3);
    float cov = 0;
    if (type == 0) {  // disc
      cov = box_coverage(std::hypot((s - cx) * pw / ph, t - cy), -1.0, r, fs);
    } else if (type == 1) {  // rectangle
      const double rw = r * (0.5 + hash_unit(h, 6));
      cov = std::min(box_coverage(s, cx - rw, cx + rw, fs), box_coverage(t, cy - r * 0.6, cy + r * 0.6, fs));
    } else {  // stripe
      cov = box_coverage(t + (s - 0.5) * (hash_unit(h, 7) - 0.5), cy - r * 0.2, cy + r * 0.2, fs);
    }
    c = mix(c, sc, cov);
  }
  // Title lettering across the top.
  if (t > 0.8 && t < 0.93) {
    const Rgb ink = luminance(c) > 0.5f ? Rgb{0.05f, 0.05f, 0.08f} : Rgb{0.97f, 0.97f, 0.95f};
    c = mix(c, ink, lettering(hash_keys(ps, 7), (s - 0.05) * pw, (t - 0.8) * ph, 0.9 * pw, 0.13 * ph, fp));
  }
  return c;
}

// A shop sign: coloured board, border, lettering, sometimes a round logo.
Rgb shade_sign(uint64_t sign_seed, double x, double y, double w, double h, double fp) {
  const Rgb bg = hashed_colour(hash_keys(sign_seed, 1), 0.45f, 0.95f, 0.3f, 0.95f);
  if (x < 0.05 || y < 0.05 || x > w - 0.05 || y > h - 0.05) return bg * 0.45f;
  const Rgb ink = luminance(bg) > 0.5f ? hashed_colour(hash_keys(sign_seed, 2), 0.3f, 0.9f, 0.05f, 0.3f)
                                       : hashed_colour(hash_keys(sign_seed, 2), 0.0f, 0.3f, 0.85f, 1.0f);
  double text_x = x, text_w = w;
  if (hash_unit(sign_seed, 3) < 0.5 && w > 2 * h) {  // logo at the left
    const double r = h * 0.35;
    const Rgb logo = hashed_colour(hash_keys(sign_seed, 4), 0.6f, 1.0f, 0.4f, 1.0f);
    const float cov = box_coverage(std::hypot(x - h * 0.5, y - h * 0.5), -1.0, r, fp);
    if (cov > 0) {
      const float inner = box_coverage(std::hypot(x - h * 0.5, y - h * 0.5), -1.0, r * 0.45, fp);
      return mix(bg, mix(logo, ink, inner), cov);
    }
    text_x = x - h;
    text_w = w - h;
  }
  const float cov = lettering(hash_keys(sign_seed, 5), text_x, y - h * 0.2, text_w - 0.1, h * 0.6, fp);
  return mix(bg, ink, cov);
}

// Blank wall: up to two posters or murals.
Rgb blank_wall(const ShadingContext& ctx, uint64_t face_seed, double u, double v, double W, double H, double fp,
               Rgb wall) {
  for (uint64_t k = 0; k < 2; ++k) {
    const uint64_t ps = hash_keys(face_seed, 300 + k);
    if (hash_unit(ps, 20) > 0.85) continue;
    const double pw = 1.4 + 2.6 * hash_unit(ps, 21), ph = pw * (1.15 + 0.35 * hash_unit(ps, 22));
    if (W < pw + 1.0 || H < ph + 2.0) continue;
    const double u0 = 0.5 + (W - pw - 1.0) * hash_unit(ps, 23);
    const double v0 = 1.0 + std::max(0.0, std::min(H - ph - 1.5, 5.0)) * hash_unit(ps, 24);
    if (u >= u0 && u < u0 + pw && v >= v0 && v < v0 + ph)
      return shade_poster(ctx, ps, (u - u0) / pw, (v - v0) / ph, pw, ph, fp);
  }
  return wall;
}

Rgb shop_ground_floor(const ShadingContext& ctx, const BuildingStyle& s, uint64_t face_seed, double u, double v,
                      double W, double fp, Rgb wall) {
  const double gf = s.ground_floor_height;
  const int shops = std::max(1, static_cast<int>(W / (2.0 * s.bay_width)));
  const double sw = W / shops;
  const int si = std::min(shops - 1, static_cast<int>(u / sw));
  const double su = u - si * sw;
  const uint64_t shop_seed = hash_keys(face_seed, 101, static_cast<uint64_t>(si));
  const double pillar = 0.35;
  if (su < pillar || su > sw - pillar) return mix(wall, s.trim, 0.5f);
  const double x = su - pillar, inner_w = sw - 2 * pillar;
  // Sign board.
  if (v > gf - 1.05 && v < gf - 0.2) return shade_sign(shop_seed, x, v - (gf - 1.05), inner_w, 0.85, fp);
  if (v >= gf - 0.2) return s.trim;
  // Door at one end.
  const bool door_left = hash_unit(shop_seed, 7) < 0.5;
  const double dx = door_left ? x : inner_w - x;
  const Rgb frame = hashed_colour(hash_keys(shop_seed, 8), 0.0f, 0.6f, 0.1f, 0.5f);
  if (dx >= 0.15 && dx < 1.25 && v < 2.4) {
    if (dx < 0.23 || dx > 1.17 || v > 2.32) return frame;
    return s.glass * (0.6f + 0.5f * static_cast<float>(v / 2.4));
  }
  // Shop window with a display.
  if (v < 0.5) return s.trim * 0.55f;
  const double wx0 = door_left ? 1.35 : 0.1, wx1 = door_left ? inner_w - 0.1 : inner_w - 1.35;
  if (x < wx0 || x > wx1 || v > gf - 1.2) return frame;
  if (x < wx0 + 0.07 || x > wx1 - 0.07 || v < 0.57 || v > gf - 1.27) return frame;
  // Display: one item per 0.45 m cell (or none), each of its own shape,
  // size, place and colour, so that shop windows differ from one another.
  const double cell = 0.45;
  const int cx = static_cast<int>((x - wx0) / cell), cy = static_cast<int>((v - 0.5) / cell);
  const uint64_t item = hash_keys(shop_seed, 50, static_cast<uint64_t>(cx), static_cast<uint64_t>(cy));
  Rgb inside = s.glass * (0.7f + 0.3f * static_cast<float>(hash_unit(shop_seed, 51)));
  if (hash_unit(item, 1) < 0.6) {
    const double ix = fract((x - wx0) / cell), iy = fract((v - 0.5) / cell);
    const double w = 0.15 + 0.3 * hash_unit(item, 3), h = 0.15 + 0.35 * hash_unit(item, 4);
    const double ox = w + (1 - 2 * w) * hash_unit(item, 5), oy = h + (1 - 2 * h) * hash_unit(item, 6);
    const double fs = fp / cell;
    float cov;
    switch (static_cast<int>(hash_unit(item, 7) * 4)) {
      case 0: cov = box_coverage(std::hypot((ix - ox) / w, (iy - oy) / h), -1.0, 1.0, fs / std::min(w, h)); break;
      case 1: cov = std::min(box_coverage(ix, ox - w, ox + w, fs), box_coverage(iy, oy - h, oy + h, fs)); break;
      case 2: cov = std::min(box_coverage(ix - ox, -w * (oy + h - iy) / (2 * h), w * (oy + h - iy) / (2 * h), fs),
                             box_coverage(iy, oy - h, oy + h, fs)); break;  // triangle
      default: cov = std::min(box_coverage(ix, ox - w, ox + w, fs), box_coverage(iy, oy - h, oy + h, fs)) *
                     (0.5f + 0.5f * static_cast<float>(std::abs(ix - ox) < w * 0.3)); break;  // two-tone box
    }
    inside = mix(inside, hashed_colour(hash_keys(item, 2), 0.2f, 1.0f, 0.15f, 1.0f), cov * detail_weight(cell * 0.2, fp));
  }
  return mix(inside, Rgb{0.8f, 0.85f, 0.9f}, 0.15f * fractal_noise(u, v, 2.0, 1, fp, s.seed + 41));
}

}  // namespace

Rgb hsv_to_rgb(float h, float s, float v) {
  h = (h - std::floor(h)) * 6.0f;
  const int i = static_cast<int>(h) % 6;
  const float f = h - std::floor(h);
  const float p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  switch (i) {
    case 0: return {v, t, p};
    case 1: return {q, v, p};
    case 2: return {p, v, t};
    case 3: return {p, q, v};
    case 4: return {t, p, v};
    default: return {v, p, q};
  }
}

Rgb hashed_colour(uint64_t hash, float sat_lo, float sat_hi, float val_lo, float val_hi) {
  const float h = static_cast<float>(hash_unit(hash, 1));
  const float s = sat_lo + (sat_hi - sat_lo) * static_cast<float>(hash_unit(hash, 2));
  const float v = val_lo + (val_hi - val_lo) * static_cast<float>(hash_unit(hash, 3));
  return hsv_to_rgb(h, s, v);
}

Rgb horizon_colour() { return {0.80f, 0.84f, 0.89f}; }

float sun_light(const ShadingContext& ctx, const Eigen::Vector3d& normal) {
  return 0.62f + 0.45f * static_cast<float>(std::max(0.0, normal.dot(ctx.sun)));
}

namespace {
Rgb facade_pattern(const ShadingContext& ctx, const BuildingStyle& s, uint64_t face_seed, double u, double v,
                   double W, double H, double fp) {
  const Rgb wall = wall_colour(s, u, v, fp);
  float occlusion = v < 0.6 ? 0.85f + 0.15f * static_cast<float>(v / 0.6) : 1.0f;
  if (v > H - 0.6) {  // parapet and cornice
    return (v < H - 0.45 ? s.trim * 0.75f : s.trim) * (0.95f + 0.1f * fractal_noise(u, v, 1.0, 2, fp, s.seed + 3));
  }
  if (W < 5.0 || hash_unit(face_seed, 11) < s.blank_face_probability)
    return blank_wall(ctx, face_seed, u, v, W, H, fp, wall) * occlusion;
  const double gf = s.ground_floor_height;
  if (v < gf) {
    if (s.shop_front) return shop_ground_floor(ctx, s, face_seed, u, v, W, fp, wall) * occlusion;
  } else if (v < gf + 0.25) {
    return s.trim;
  }
  // Window grid: bays centred on the face.
  const double bay = s.bay_width;
  const int bays = std::max(1, static_cast<int>((W - 1.0) / bay));
  const double off = (W - bays * bay) / 2;
  const int bi = static_cast<int>(std::floor((u - off) / bay));
  if (bi < 0 || bi >= bays) return wall * occlusion;
  const double bu = u - off - (bi + 0.5) * bay;  // centred in the bay
  const double hw = s.window_width / 2;
  int floor_index;
  double fv;
  if (v < gf) {  // residential ground floor: a door in one bay, windows in the others
    floor_index = -1;
    fv = v;
    const int door_bay = static_cast<int>(hash_unit(face_seed, 12) * bays);
    if (bi == door_bay) {
      if (std::abs(bu) < 0.7 && v < 2.5) {
        if (std::abs(bu) > 0.6 || v > 2.4) return s.frame;
        const float panel = box_coverage(std::abs(bu), 0.1, 0.45, fp) * box_coverage(v, 0.3, 2.1, fp);
        return s.door * (1.0f - 0.25f * panel);
      }
      if (std::abs(bu) < 0.8 && v < 2.65) return s.trim;
      return wall * occlusion;
    }
  } else {
    floor_index = static_cast<int>((v - gf - 0.25) / s.floor_height);
    fv = v - gf - 0.25 - floor_index * s.floor_height;
  }
  const bool balcony = floor_index >= 0 && s.balconies && floor_index % s.balcony_period == 0;
  const double wb = balcony ? 0.1 : (floor_index < 0 ? 1.1 : s.sill_height);
  const double wt = (floor_index < 0 ? 1.1 : s.sill_height) + s.window_height;
  const uint64_t window_seed = hash_keys(face_seed, 13, static_cast<uint64_t>(floor_index + 1), static_cast<uint64_t>(bi));
  float railing_shade = 1.0f;
  if (balcony && std::abs(bu) < hw + 0.45 && fv < 1.1) {
    if (fv < 0.18) return s.trim * 0.8f;
    if (fv > 1.0) return s.frame * 0.8f;
    const float bar = box_coverage(fract(bu / 0.14) * 0.14, 0.0, 0.03, fp);
    const float wbar = detail_weight(0.14, fp);
    const float ink = bar * wbar + (1 - wbar) * 0.21f;
    if (ink > 0.5f) return s.frame * 0.8f;
    railing_shade = 1.0f - 0.6f * ink;
  }
  if (std::abs(bu) < hw && fv >= wb && fv < wt) {
    const double fw = 0.08;
    if (std::abs(bu) > hw - fw || fv < wb + fw || fv > wt - fw || (s.mullion && std::abs(bu) < 0.035))
      return s.frame * railing_shade;
    return window_glass(s, window_seed, bu + hw, fv - wb, 2 * hw, wt - wb, u, v, fp) * railing_shade;
  }
  if (!balcony && std::abs(bu) < hw + 0.08 && fv >= wb - 0.1 && fv < wb) return s.trim;  // sill
  if (std::abs(bu) < hw + 0.12 && fv >= wt && fv < wt + 0.18) return s.trim * 0.92f;   // lintel
  return wall * (railing_shade * occlusion);
}

}  // namespace

Rgb shade_facade(const ShadingContext& ctx, const BuildingStyle& s, uint64_t face_seed, double u, double v,
                 double W, double H, double fp) {
  // Fine grime over every element (frames, signs, glass included): real
  // surfaces are never flat-coloured, and it makes small SIFT features of
  // repeated elements differ from one another.
  const float grime = fractal_noise(u, v, 0.3, 2, fp, face_seed + 0x61);
  return facade_pattern(ctx, s, face_seed, u, v, W, H, fp) * (0.88f + 0.24f * grime);
}

Rgb shade_roof(const BuildingStyle& style, double x, double y, double fp) {
  return Rgb{0.42f, 0.41f, 0.40f} * (0.8f + 0.4f * fractal_noise(x, y, 2.0, 3, fp, style.seed + 101));
}

Rgb shade_ground(const ShadingContext& ctx, double x, double y, double fp) {
  const CityScene& scene = *ctx.scene;
  double best = 1e300, lat = 0, along = 0;
  const RoadSegment* seg = nullptr;
  for (size_t i = 0; i < ctx.road_count; ++i) {
    const RoadSegment& r = *ctx.roads[i];
    const double px = x - r.a.x(), py = y - r.a.y();
    const double t = std::clamp(px * r.direction.x() + py * r.direction.y(), 0.0, r.length);
    const double l = -px * r.direction.y() + py * r.direction.x();
    const double dx = px - t * r.direction.x(), dy = py - t * r.direction.y();
    const double d = dx * dx + dy * dy;
    if (d < best) {
      best = d;
      lat = l;
      along = t;
      seg = &r;
    }
  }
  const double hw = scene.road_half_width, sw = scene.sidewalk_width;
  const double dist = seg ? std::sqrt(best) : 1e300;
  const uint64_t seed = hash_keys(scene.layout.seed, 0x9707);
  if (dist < hw) {
    const double arc = seg->arc_start + along;
    Rgb c = Rgb{0.30f, 0.30f, 0.31f} * (0.78f + 0.44f * fractal_noise(x, y, 3.0, 6, fp, seed));
    const float lane = box_coverage(std::abs(lat), -1.0, 0.075, fp) * box_coverage(std::fmod(arc, 9.0), 0.0, 4.5, fp);
    const float edge = box_coverage(std::abs(lat), hw - 0.45, hw - 0.3, fp);
    c = mix(c, Rgb{0.86f, 0.86f, 0.8f}, std::max(lane, edge));
    // Manhole covers: one per 13 m cell of a road, at a hashed place.
    const double cell = 13.0;
    const auto ci = static_cast<int64_t>(std::floor(arc / cell));
    const uint64_t mh = hash_keys(seed, static_cast<uint64_t>(seg->road), static_cast<uint64_t>(ci));
    if (hash_unit(mh, 1) < 0.6) {
      const double ma = (static_cast<double>(ci) + 0.2 + 0.6 * hash_unit(mh, 2)) * cell;
      const double ml = (hash_unit(mh, 3) - 0.5) * 2.0 * (hw - 1.0);
      const double r = std::hypot(arc - ma, lat - ml);
      if (r < 0.4) {
        const float ring = box_coverage(std::fmod(r, 0.1), 0.0, 0.03, fp) * detail_weight(0.1, fp);
        return Rgb{0.22f, 0.21f, 0.2f} * (1.0f + 0.5f * ring) * (r > 0.35 ? 1.3f : 1.0f);
      }
    }
    return c;
  }
  if (dist < hw + 0.25) return Rgb{0.66f, 0.65f, 0.62f} * (0.9f + 0.2f * fractal_noise(x, y, 0.5, 2, fp, seed + 1));
  if (dist < hw + sw) {
    const double arc = seg->arc_start + along, tile = 0.5;
    const auto ta = static_cast<int64_t>(std::floor(arc / tile)), tl = static_cast<int64_t>(std::floor(std::abs(lat) / tile));
    const float tone = static_cast<float>(hash_unit(seed + 2, static_cast<uint64_t>(ta), static_cast<uint64_t>(tl)));
    const float wt = detail_weight(tile, fp);
    Rgb c = Rgb{0.58f, 0.55f, 0.52f} * (1.0f + (tone - 0.5f) * 0.22f * wt);
    const float joint = std::max(box_coverage(fract(arc / tile) * tile, 0.0, 0.02, fp),
                                 box_coverage(fract(std::abs(lat) / tile) * tile, 0.0, 0.02, fp));
    const float wj = detail_weight(0.05, fp);
    return c * (1.0f - 0.3f * (joint * wj + (1 - wj) * 0.08f)) *
           (0.85f + 0.3f * fractal_noise(x, y, 2.0, 2, fp, seed + 3));
  }
  const float n = fractal_noise(x, y, 2.0, 5, fp, seed + 4);
  return mix(Rgb{0.45f, 0.42f, 0.36f}, Rgb{0.33f, 0.45f, 0.25f}, fractal_noise(x, y, 8.0, 2, fp, seed + 5)) *
         (0.75f + 0.5f * n);
}

Rgb shade_sky(const Eigen::Vector3d& d) {
  const double dz = d.z();
  const Rgb zenith{0.33f, 0.52f, 0.84f};
  Rgb c = mix(horizon_colour(), zenith, static_cast<float>(std::sqrt(std::max(dz, 0.0))));
  if (dz > 0.03) {
    const double px = d.x() / dz, py = d.y() / dz;
    const float n = fractal_noise(px, py, 1.5, 2, 0.0, 0x5c1);
    const float cloud = smoothstep01((n - 0.5f) / 0.25f) * std::min(1.0f, static_cast<float>(dz) * 4.0f);
    c = mix(c, Rgb{0.95f, 0.95f, 0.96f}, 0.85f * cloud);
  }
  return c;
}

Rgb shade_car_body(const BoxPrimitive& car, double u, double v, double fp) {
  Rgb c = car.colour * (0.9f + 0.2f * fractal_noise(u, v, 0.5, 2, fp, car.seed));
  if (v < 0.25) return Rgb{0.08f, 0.08f, 0.08f};  // wheels and shadow band
  if (std::abs(v - 0.55) < 0.02) return c * 0.6f;   // door line
  return c;
}

Rgb shade_car_cabin(const BoxPrimitive& car, double u, double v, double fp) {
  const double h = car.z_max - car.z_min;
  if (v > 0.08 && v < h - 0.06) return Rgb{0.12f, 0.14f, 0.17f} * (0.8f + 0.5f * fractal_noise(u, v, 0.7, 2, fp, car.seed + 1));
  return car.colour;
}

Rgb shade_trunk(const CylinderPrimitive& trunk, double angle_m, double z, double fp) {
  return trunk.colour * (0.7f + 0.6f * fractal_noise(angle_m * 3.0, z, 0.4, 3, fp, trunk.seed));
}

Rgb shade_canopy(const SpherePrimitive& canopy, const Eigen::Vector3d& p, double fp) {
  const float n = fractal_noise(p.x() + p.z() * 0.7, p.y() - p.z() * 0.5, 0.6, 4, fp, canopy.seed);
  return canopy.colour * (0.55f + 0.8f * n);
}

}  // namespace visloc::synth
