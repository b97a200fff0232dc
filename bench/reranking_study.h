// The re-ranking study of `visloc bench matching` (its rerank-* methods; the
// cheap recall levers of #15): the full cascade search's shortlist (the L_R
// nearest points by Hamming distance, or every candidate of a shorter coarse
// list) ranked by another distance, then Lowe's 1-1 ratio test, against the
// exact method's 1-1 matches. The rankers:
//   the segment's own PQ (16 bytes per point): the search itself, the check
//   of the harness; exact L2 on the points' descriptors: the bound of any
//   re-ranking of the same shortlist; FAISS PQ with 32 sub-quantizers (16
//   bytes per point more); FAISS OPQ, a learnt 128 × 128 rotation (64 KiB
//   per map) before 16 sub-quantizers (no byte per point more).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "visloc/matching/cascade_index.h"

namespace faiss {
struct OPQMatrix;
struct ProductQuantizer;
}  // namespace faiss

namespace visloc {

// Options under which CascadeMatcher returns, as a feature's 1-M set, its
// whole ranked list (M = L_R, ν = 1, the best-ratio rule, every feature in
// order): every feature whose two nearest PQ distances differ; one with an
// exact tie is left out, as the search's own 1-1 test rejects it too.
// `refined_list` in [2, 64] (M's range).
CascadeSearchOptions whole_shortlist_options(int refined_list, int lut_radius = 1);

// The position in `squared` (squared distances) of the nearest when it passes
// Lowe's ratio test, d0 < ratio² · d1 with d1 the second smallest; -1 when it
// fails or there are fewer than 2 distances. The first of equal minima is the
// nearest (a tie fails).
int nearest_passing_ratio(std::span<const float> squared, float ratio);

// A FAISS product quantizer over a segment's point descriptors (128 floats
// each), optionally after an OPQ rotation, trained and encoded on them.
class FaissPqReranker {
 public:
  FaissPqReranker(const float* points, size_t n, int subquantizers, bool opq_rotation);
  ~FaissPqReranker();
  FaissPqReranker(const FaissPqReranker&) = delete;
  FaissPqReranker& operator=(const FaissPqReranker&) = delete;

  size_t code_bytes() const;  // per point
  // Squared distances of `query` (128 floats) to the points `ids`: the sum of
  // the query's table of sub-distances over each point's code.
  void distances(const float* query, const uint32_t* ids, size_t n, float* out);
  // For tests: the query as the quantizer sees it (rotated with OPQ), and a
  // point's decoded code in that space; 128 floats each.
  void transform(const float* query, float* out) const;
  void reconstruct(uint32_t id, float* out) const;

 private:
  std::unique_ptr<faiss::OPQMatrix> rotation_;
  std::unique_ptr<faiss::ProductQuantizer> pq_;
  std::vector<uint8_t> codes_;
  std::vector<float> table_, rotated_;
};

}  // namespace visloc
