// The re-ranking study of `visloc bench matching` (its rerank-* methods, run
// when asked for with --method rerank; the cheap recall levers of #15): the
// full cascade search's short list (the L_R nearest points by Hamming
// distance, or every candidate of a shorter coarse list) ranked by another
// distance, then Lowe's 1-1 ratio test, scored against the exact method's 1-1
// matches. The rankers (ShortlistRanker):
//   search-pq16  the search's own 16-byte PQ distances: repeats ccs-full-r1,
//                the check of the harness
//   exact        L2 on the points' descriptors: the bound of any re-ranking
//                of the same short lists
//   faiss-pq16   FAISS PQ 16 × 8 bits, trained here: the control of faiss-opq16
//   faiss-pq32   FAISS PQ 32 × 8 bits (16 bytes per point more)
//   faiss-opq16  FAISS OPQ, a learnt 128 × 128 rotation (64 KiB per map),
//                before PQ 16 × 8 bits (no byte per point more)
//   faiss-ivf256-pq16  k-means into 256 coarse centroids (a byte per point
//                more, 128 KiB per map), then PQ 16 × 8 bits of each point's
//                residual from its centroid (IVFADC's residual encoding,
//                Jégou et al. 2011, with every cell searched)
//   faiss-rq16   FAISS's residual (additive) quantizer, 16 codebooks of 256
//                over the whole vector, beam search at encoding; the
//                distances are to the decoded points (a kernel would decode
//                the 16 rows of 128 and measure: no byte per point more)
//   faiss-prq2x8, faiss-prq4x4  the same per half (8 codebooks of 64
//                dimensions) or per quarter (4 of 32) of the vector: a
//                candidate's distance reads 1/2 or 1/4 of the rows' floats
//   pq16-hamWW   the search's PQ distance blended with the one the hash
//                codes suggest, weight WW/100 on the codes'
//                (pq_hamming_distances): two estimates of one distance from
//                two codes of the same descriptor (the 16-byte PQ code, and
//                the 128-bit sign code that already chose the short list),
//                whose errors are only partly correlated; no byte per point
//                more
// A feature whose two nearest search PQ distances tie has no short list here
// (the search's 1-1 test rejects it as well), so every ranker misses it: the
// finer rankers' recall is, if anything, slightly low.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/cascade_index.h"

namespace faiss {
struct OPQMatrix;
struct ProductQuantizer;
struct AdditiveQuantizer;
}  // namespace faiss

namespace visloc {

// Options under which CascadeMatcher returns, as a feature's 1-M set, its
// whole ranked list (M = L_R, ν = 1, the best-ratio rule, the refined step
// on, every feature in order): every feature with at least 2 candidates
// whose two nearest PQ distances differ. `refined_list` in [2, 64] (M's
// range); `ratio_one_to_one` is the search's ν_h.
CascadeSearchOptions whole_shortlist_options(int refined_list, int lut_radius = 1, float ratio_one_to_one = 0.8f);

// The position in `squared` (squared distances) of the nearest when it passes
// Lowe's ratio test, d0 < ratio² · d1 with d1 the second smallest; -1 when it
// fails or there are fewer than 2 distances. The first of equal minima is the
// nearest (a tie fails).
int nearest_passing_ratio(std::span<const float> squared, float ratio);

// Squared distances of short list `list` (an index into whole.many_query) to
// its points `ids`, into `out`.
using ShortlistDistances = std::function<void(size_t list, std::span<const uint32_t> ids, float* out)>;

// The 1-1 matches of the short lists in `whole` (a search with
// whole_shortlist_options) ranked by `distances`: (feature, point) pairs into
// `features` / `points` (cleared first), in the lists' order.
void rank_whole_shortlists(const CascadeMatches& whole, const ShortlistDistances& distances, float ratio,
                           std::vector<uint32_t>& features, std::vector<uint32_t>& points);

// The returned functions keep references to their arguments, which must
// outlive them.
// The search's own distances, squared back (the search reports their roots).
ShortlistDistances search_pq_distances(const CascadeMatches& whole);
// The search's squared PQ distance blended with the one the 128-bit hash codes
// suggest: (1 − w) d²_PQ + w · 2|q − μ|² (1 − cos(π h / 128)), h the Hamming
// distance of the query's code (query_codes, by feature) and the point's
// (point_codes, by id), μ the hasher's mean (the codes are signs of
// W(x − μ)); the point's |x − μ| taken as the query's. For random hyperplanes
// π h / 128 would estimate the angle between q − μ and x − μ; ITQ's learnt
// rotation makes it a heuristic. No byte per point more.
ShortlistDistances pq_hamming_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                        std::span<const HashCode> query_codes, const HashCode* point_codes,
                                        const float* hash_mean, double weight);
// Exact squared L2 between query features (rows of `queries`, by
// whole.many_query) and points (rows of `points`, by id).
ShortlistDistances exact_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                   const DescriptorMatrix& points);

// A FAISS product quantizer over a segment's point descriptors (128 floats
// each), optionally after an OPQ rotation or on the residuals from coarse
// k-means centroids, or FAISS's residual quantizer instead; trained and
// encoded on them. Not thread-safe: `distances` uses the object's scratch.
class FaissPqReranker {
 public:
  struct Options {
    int subquantizers = 16;     // 8 bits each; divides 128
    bool opq_rotation = false;  // learn an OPQ rotation first
    int opq_iterations = 50;    // OPQ's outer iterations (FAISS's default)
    // > 0: that many k-means centroids first (at most 65,536); the PQ encodes
    // each point's residual from its nearest one (not with OPQ).
    int coarse_centroids = 0;
    // > 0: FAISS's residual quantizer in place of the PQ (neither OPQ nor
    // coarse centroids), `subquantizers` codebooks of 256 entries in all: 1,
    // over the whole vector (ResidualQuantizer); S > 1, S residual quantizers
    // of subquantizers / S codebooks over 128 / S dimensions each
    // (ProductResidualQuantizer). S divides 128 and subquantizers.
    int residual_splits = 0;
    int residual_beam = 5;  // the residual quantizer's beam at encoding (FAISS's default)
    // Its training: progressive-dimension k-means (FAISS's default) or plain
    // k-means per codebook (faster).
    bool residual_progressive_dim = true;
    void validate() const;
  };
  // Needs at least 256 points (one per centroid) and at least
  // coarse_centroids; throws kInvalidArgument.
  FaissPqReranker(const float* points, size_t n, const Options& options);
  ~FaissPqReranker();
  FaissPqReranker(const FaissPqReranker&) = delete;
  FaissPqReranker& operator=(const FaissPqReranker&) = delete;

  // Per point: the codes, plus the coarse centroid's id (1 byte up to 256
  // centroids, 2 above).
  size_t code_bytes() const;
  // Squared distances of `query` (128 floats) to the points `ids`: the sum of
  // the query's table of sub-distances over each point's code.
  void distances(const float* query, std::span<const uint32_t> ids, float* out);
  // The query as the quantizer sees it (rotated with OPQ), and a point's
  // decoded code in that space; 128 floats each.
  void transform(const float* query, float* out) const;
  void reconstruct(uint32_t id, float* out) const;

 private:
  std::unique_ptr<faiss::OPQMatrix> rotation_;
  std::unique_ptr<faiss::ProductQuantizer> pq_;
  std::unique_ptr<faiss::AdditiveQuantizer> rq_;
  size_t num_points_ = 0;
  size_t coarse_centroids_ = 0;
  std::vector<uint8_t> codes_;
  std::vector<float> table_, rotated_;
  // With coarse centroids or the residual quantizer: every point decoded
  // (N × 128), which `distances` measures against.
  std::vector<float> decoded_;
};

// The reranker's distances for the short lists of `whole`.
ShortlistDistances faiss_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                   FaissPqReranker& reranker);

}  // namespace visloc
