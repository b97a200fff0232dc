// The full search's PQ distance blended with the distance its 128-bit hash
// codes imply (#15's recall lever at no byte per point more). A point x and
// a query q have two estimates of |q − x|² in the index: the PQ distance
// d²_PQ of the precise step, and, from the Hamming distance h of their codes
// (signs of W(x − μ), W orthonormal, μ the hasher's mean),
//   d²_H = 2 |q − μ|² (1 − cos(π h / 128)),
// the squared chord between q − μ and a point as far from μ at the angle
// π h / 128, which random hyperplanes would estimate (Charikar 2002); ITQ's
// learnt rotation makes it a heuristic. The two codes quantize the same
// descriptor differently, so their errors are only partly correlated, and
// a blend (1 − w) d²_PQ + w d²_H ranks a short list closer to the exact
// order than either.
//
// The weight w is a property of the map (its codebook, its hasher, its
// descriptors), fitted on the map's own data, never on queries (`visloc map
// fit-blend`, map_building/hash_blend_fit.h; not stored in the map: pass it
// to the search). Its queries are held-out views: for a sample of points,
// one observation of the point in a map image (points of 2 views or more), searched against the map
// with that point re-encoded from its track's mean without the observation
// (leave_one_out_mean), so that the view is to its point as a new view is
// (map_building re-encodes a twentieth of the points at a time, the others
// as the map has them). Its distractors are query features
// with no point in the map: points' own descriptors, each with its point
// left out of its short list. fit_hamming_blend searches both and takes the
// weight, on a grid, with the most net right 1-1 matches (a 1-1 match: the
// blend's nearest, passing the search's ratio test): views matched to their
// own point, less views matched to another and distractors matched at all;
// the smallest such weight on ties. Taking as many distractors as views is
// a prior (about half a query's features see a mapped point), not a fit.
//
// Measured and not kept: the map's own points as queries (each left out of
// its own short list), with the weight from a regression of the exact
// distance on the two estimates within each list. It gave w 0.04 on
// fountain-P11, where the study's w 0.5 found more matches: those lists hold
// no true match, and the codes' estimate helps at the small distances of
// true matches. And the views alone, the weight with the most right
// matches: 0.5-0.95 on the four Strecha scenes, whose queries then kept
// 0.817 of exact's 1-1 matches but only 79% of them right (89% at w 0).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/cascade_index.h"

namespace visloc {

// 1 − cos(π h / 128) for h = 0..128: d²_H / (2|q − μ|²).
const std::array<float, kHashBits + 1>& unit_chord_table();
// d²_H for each Hamming distance 0..128 of a query with |q − μ|² = norm2.
void hash_chord_table(double norm2, float* out /* kHashBits + 1 */);
// |q − μ|² of a descriptor.
double squared_norm_from_mean(const uint8_t* descriptor, const float* hash_mean);

// The mean of a point's track without one of its views: (t · mean −
// observation) / (t − 1), t = track_size. False (out untouched) when t < 2.
bool leave_one_out_mean(const float* mean, const uint8_t* observation, uint32_t track_size, float* out);

struct HammingBlendFitOptions {
  int refined_list = 40;          // L_R of the short lists, as the search's; in [2, 64]
  float ratio_one_to_one = 0.8f;  // ν_h, as the search's; in (0, 1]
  int weight_steps = 20;          // the grid: w = k / weight_steps, k = 0..weight_steps; in [1, 1000]
  void validate() const;          // throws kInvalidArgument
};

struct HammingBlendFit {
  double weight = 0;   // w in [0, 1]
  size_t queries = 0;  // held-out views searched
  size_t listed = 0;   // of them, with a short list (at least 2 candidates, the two nearest PQ distances apart)
  // Per grid weight k / weight_steps: views whose 1-1 match is their own
  // point (correct) or another (wrong).
  std::vector<size_t> correct, wrong;
  // With distractors: how many (of `distractors`) found a 1-1 match, each
  // one wrong (their own point is left out of their short lists).
  size_t distractors = 0;
  std::vector<size_t> distractor_matched;
};

// Sets fit.weight: the grid weight (k / (correct.size() − 1)) with the most
// net right 1-1 matches, correct − wrong − distractor_matched; the smallest
// on ties; 0 when no view was listed.
void choose_hamming_blend_weight(HammingBlendFit& fit);

// `queries` (held-out views, searched in `index`: the caller's index with
// each view's point re-encoded without it) and `true_points` (each one's
// point id) have equal counts (no view at all only with distractors),
// else Error(kInvalidArgument). With no view listed, the weight is 0. Optional distractors: query features with no
// point in the map, here points' own descriptors (`distractors`, rows) with
// their point (`distractor_points`, equal counts) left out of their lists
// (after the refined step: their own point, almost always the nearest by
// Hamming distance, takes one of the L_R places, so they rank L_R − 1
// others).
HammingBlendFit fit_hamming_blend(const CascadeIndexView& index, const PqCodebook& codebook,
                                  const DescriptorMatrix& queries, std::span<const uint32_t> true_points,
                                  const HammingBlendFitOptions& options = {},
                                  const DescriptorMatrix* distractors = nullptr,
                                  std::span<const uint32_t> distractor_points = {});

}  // namespace visloc
