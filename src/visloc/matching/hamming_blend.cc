#include "visloc/matching/hamming_blend.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>

#include "visloc/util/error.h"

namespace visloc {

const std::array<float, kHashBits + 1>& unit_chord_table() {
  static const std::array<float, kHashBits + 1> table = [] {
    std::array<float, kHashBits + 1> t{};
    for (int h = 0; h <= kHashBits; ++h) t[h] = float(1 - std::cos(std::numbers::pi * h / double(kHashBits)));
    return t;
  }();
  return table;
}

void hash_chord_table(double norm2, float* out) {
  const std::array<float, kHashBits + 1>& unit = unit_chord_table();
  for (int h = 0; h <= kHashBits; ++h) out[h] = float(2 * norm2 * unit[h]);
}

double squared_norm_from_mean(const uint8_t* descriptor, const float* hash_mean) {
  double s = 0;
  for (int j = 0; j < kDescriptorDim; ++j) {
    const double x = double(descriptor[j]) - hash_mean[j];
    s += x * x;
  }
  return s;
}

bool leave_one_out_mean(const float* mean, const uint8_t* observation, uint32_t track_size, float* out) {
  if (track_size < 2) return false;
  const double t = track_size;
  for (int j = 0; j < kDescriptorDim; ++j) out[j] = float((t * mean[j] - observation[j]) / (t - 1));
  return true;
}

void HammingBlendFitOptions::validate() const {
  if (refined_list < 2 || refined_list > 64)
    throw_error(ErrorCode::kInvalidArgument, "HammingBlendFitOptions.refined_list must be in [2, 64], got ",
                refined_list);
  if (!(ratio_one_to_one > 0 && ratio_one_to_one <= 1))
    throw_error(ErrorCode::kInvalidArgument, "HammingBlendFitOptions.ratio_one_to_one must be in (0, 1], got ",
                ratio_one_to_one);
  if (weight_steps < 1 || weight_steps > 1000)
    throw_error(ErrorCode::kInvalidArgument, "HammingBlendFitOptions.weight_steps must be in [1, 1000], got ",
                weight_steps);
}

void choose_hamming_blend_weight(HammingBlendFit& fit) {
  VISLOC_CHECK(!fit.correct.empty() && fit.wrong.size() == fit.correct.size() &&
                   fit.distractor_matched.size() == fit.correct.size(),
               "a blend fit's counts per grid weight");
  // Net right 1-1 matches: each wrong match, a view's or a distractor's,
  // costs what a right one gains.
  const auto net = [&fit](size_t s) {
    return double(fit.correct[s]) - double(fit.wrong[s]) - double(fit.distractor_matched[s]);
  };
  const size_t steps = fit.correct.size() - 1;
  if (fit.listed == 0) {  // no view to gain: the PQ alone
    fit.weight = 0;
    return;
  }
  size_t best_step = 0;
  for (size_t s = 1; s <= steps; ++s)
    if (net(s) > net(best_step)) best_step = s;
  fit.weight = steps == 0 ? 0.0 : double(best_step) / double(steps);
}

HammingBlendFit fit_hamming_blend(const CascadeIndexView& index, const PqCodebook& codebook,
                                  const DescriptorMatrix& queries, std::span<const uint32_t> true_points,
                                  const HammingBlendFitOptions& options, const DescriptorMatrix* distractors,
                                  std::span<const uint32_t> distractor_points) {
  options.validate();
  index.validate("fit_hamming_blend");
  if (queries.rows() != true_points.size())
    throw_error(ErrorCode::kInvalidArgument, "fit_hamming_blend: ", queries.rows(), " views for ", true_points.size(),
                " points (equal counts)");
  const size_t nd = distractors ? distractors->rows() : 0;
  if (nd != distractor_points.size())
    throw_error(ErrorCode::kInvalidArgument, "fit_hamming_blend: ", nd, " distractors for ", distractor_points.size(),
                " points");
  if (queries.empty() && nd == 0)
    throw_error(ErrorCode::kInvalidArgument, "fit_hamming_blend: no view and no distractor");
  HammingBlendFit fit;
  fit.queries = queries.rows();
  fit.distractors = nd;
  const size_t nv = queries.rows();
  DescriptorMatrix all = queries;
  if (nd > 0) all.append(*distractors);
  const auto steps = size_t(options.weight_steps);
  fit.correct.assign(steps + 1, 0);
  fit.wrong.assign(steps + 1, 0);
  fit.distractor_matched.assign(steps + 1, 0);

  // Every view's whole short list with its PQ distances (M = L_R, ν = 1).
  CascadeSearchOptions o;
  o.lut_radius = 1;
  o.prioritize = false;
  o.refined = true;
  o.refined_list = options.refined_list;
  o.max_one_to_many = options.refined_list;
  o.ratio_one_to_one = options.ratio_one_to_one;
  o.ratio_one_to_many = 1.0f;
  o.one_to_many_rule = OneToManyRule::kBestRatio;
  o.validate();
  CascadeMatcher matcher(index, codebook);
  CascadeMatches whole;
  std::vector<HashCode> codes(all.rows());
  HashWorkspace hash_ws;
  encode_hash(index.hasher, all.data(), all.rows(), codes.data(), hash_ws);
  matcher.match_hashed(all, codes, o, whole);

  const float r2 = options.ratio_one_to_one * options.ratio_one_to_one;
  float chord[kHashBits + 1];
  std::vector<float> pq, hash;
  std::vector<uint32_t> ids;
  for (size_t i = 0; i < whole.many_query.size(); ++i) {
    const uint32_t f = whole.many_query[i];
    const bool view = f < nv;
    const uint32_t left_out = view ? UINT32_MAX : distractor_points[f - nv];
    const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
    ids.clear(), pq.clear(), hash.clear();
    hash_chord_table(squared_norm_from_mean(all.row(f), index.hasher.mean), chord);
    for (uint32_t k = begin; k < end; ++k) {
      if (whole.many_points[k] == left_out) continue;
      ids.push_back(whole.many_points[k]);
      const HashCode& pc = index.codes[whole.many_points[k]];
      const int h = std::popcount(codes[f].w[0] ^ pc.w[0]) + std::popcount(codes[f].w[1] ^ pc.w[1]);
      pq.push_back(whole.many_distances[k] * whole.many_distances[k]);
      hash.push_back(chord[h]);
    }
    if (ids.size() < 2) continue;
    fit.listed += view;
    for (size_t s = 0; s <= steps; ++s) {
      const float w = float(double(s) / double(steps));
      float d0 = INFINITY, d1 = INFINITY;
      size_t best = 0;
      for (size_t k = 0; k < pq.size(); ++k) {
        const float d = (1 - w) * pq[k] + w * hash[k];
        if (d < d0) {
          d1 = d0, d0 = d, best = k;
        } else if (d < d1) {
          d1 = d;
        }
      }
      if (!(d0 < r2 * d1)) continue;
      if (!view) {
        ++fit.distractor_matched[s];
      } else if (ids[best] == true_points[f]) {
        ++fit.correct[s];
      } else {
        ++fit.wrong[s];
      }
    }
  }
  choose_hamming_blend_weight(fit);
  return fit;
}

}  // namespace visloc
