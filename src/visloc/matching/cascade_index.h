// Cascade Correspondence Search (CCS; Tran et al., section III-B): 2D-3D
// matching of one query image against one segment whose 3D points keep only
// compressed descriptors.
//
//   coarse   the 128-bit hash code of a query feature is split into m = 8
//            sub-codes of b = 16 bits; each names a bucket of one of 8 lookup
//            tables (pigeonhole principle, Norouzi et al. CVPR 2012). Radius 0
//            probes the exact bucket (the paper); radius 1 also probes the 16
//            buckets one bit away (multi-index hashing). The union of the
//            buckets' point ids, deduplicated, is the list L_C.
//   refined  Hamming distance (XOR + popcount) on the full 128-bit code;
//            the L_R = 40 nearest by a counting sort over distances 0..128.
//   precise  PQ asymmetric distance (16 × 256 table per query feature) to the
//            L_R candidates; Lowe's ratio test on distances (not squared).
//
// Output, per query feature that passed:
//   1-1 set (RANSAC hypotheses): the nearest point when d0/d1 < ν_h = 0.8;
//   1-M set (RANSAC verification), rule kBestRatio (default, the paper's
//   "accept M top candidates in L_R where d0/d1 < ν"): the top M = 5 when
//   d0/d1 < ν = 0.9; rule kGroupRatio (the other reading, "d_i0/d_ij < ν"):
//   the candidates before the first j ≥ 1 with d0/dj < ν, provided j ≤ M
//   (a group of near-equal candidates followed by a clearly worse one).
// A feature whose short list has fewer than 2 candidates has no ratio test
// and is rejected.
//
// Prioritization (section III-B-2): features are searched in increasing
// order of the size of their coarse list (the sum of their buckets' sizes,
// known before deduplication), and the search stops once N_early = 100 1-1
// matches are found. Without prioritization every feature is searched.
//
// Index layout (CascadeIndexView; arrays usually in a mapped segment file):
//   codes        N × HashCode (16 bytes)
//   pq_codes     N × 16 bytes
//   lut_offsets  8 × (65536 + 1) uint32: table k's bucket v holds
//                lut_ids[k·N + offsets[k·65537 + v] .. k·N + offsets[k·65537 + v + 1])
//   lut_ids      8 × N uint32 point ids (CSR), each table a permutation of 0..N−1
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"

namespace visloc {

inline constexpr size_t kLutOffsetsPerTable = size_t(kHashBuckets) + 1;

struct CascadeIndexView {
  size_t num_points = 0;
  BinaryHasherView hasher;
  const HashCode* codes = nullptr;
  const uint8_t* pq_codes = nullptr;
  const uint32_t* lut_offsets = nullptr;
  const uint32_t* lut_ids = nullptr;
  // Full structural check (offsets monotone, ending at N, ids < N); O(8·2^16 + 8·N).
  // Throws Error(kFormat) with `what` (e.g. a file name) in the message.
  void validate(const std::string& what) const;
};

// Owning lookup tables built from codes by a counting sort per table.
struct CascadeTables {
  std::vector<uint32_t> offsets;  // 8 × 65537
  std::vector<uint32_t> ids;      // 8 × N
};
CascadeTables build_cascade_tables(std::span<const HashCode> codes);

enum class OneToManyRule {
  kBestRatio,   // top M when d0/d1 < ν (default)
  kGroupRatio,  // candidates before the first j with d0/dj < ν, if j ≤ M
};

struct CascadeSearchOptions {
  int lut_radius = 1;               // 0: exact buckets (paper); 1: also the 16 one-bit-away buckets
  bool refined = true;              // the Hamming step; off: PQ ranks the whole coarse list
  int refined_list = 40;            // L_R
  float ratio_one_to_one = 0.8f;    // ν_h
  float ratio_one_to_many = 0.9f;   // ν
  int max_one_to_many = 5;          // M
  OneToManyRule one_to_many_rule = OneToManyRule::kBestRatio;
  bool prioritize = true;           // shortest coarse lists first + early stop
  int early_stop = 100;             // N_early: stop at this many 1-1 matches (prioritized only)
  void validate() const;
};

struct CascadeMatchStats {
  size_t features = 0;
  size_t features_searched = 0;     // went through refined + precise
  size_t coarse_candidates = 0;     // Σ |L_C| over searched features (deduplicated)
  size_t ranked_candidates = 0;     // Σ candidates ranked by PQ
  bool early_stopped = false;
  double ms_hash = 0, ms_order = 0, ms_search = 0, ms_total = 0;
};

// Data-oriented result; vectors are reused when the same object is passed again.
struct CascadeMatches {
  // 1-1 set, in search order.
  std::vector<uint32_t> query;      // query feature index
  std::vector<uint32_t> point;      // point index in the segment
  std::vector<float> distance;      // ADC distance (not squared)
  // 1-M set, CSR over the features that passed ν (a superset of the 1-1 features
  // under both rules): feature many_query[i] has candidates
  // many_points[many_offsets[i] .. many_offsets[i+1]), nearest first.
  std::vector<uint32_t> many_query;
  std::vector<uint32_t> many_offsets{0};
  std::vector<uint32_t> many_points;
  std::vector<float> many_distances;
  CascadeMatchStats stats;
  void clear();
};

// Searches one segment. Holds a workspace sized to the segment (a stamp per
// point for deduplication, candidate buffers, the ADC table), so nothing is
// allocated per feature; not thread-safe: one matcher per thread.
class CascadeMatcher {
 public:
  CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook);
  void match(const DescriptorMatrix& queries, const CascadeSearchOptions& options, CascadeMatches& out);
  CascadeMatches match(const DescriptorMatrix& queries, const CascadeSearchOptions& options = {});
  // Coarse list sizes (Σ bucket sizes) of already-encoded codes; exposed for tests.
  void coarse_sizes(std::span<const HashCode> codes, int lut_radius, std::vector<uint32_t>& sizes) const;

 private:
  CascadeIndexView index_;
  const PqCodebook* codebook_;
  std::vector<uint32_t> stamp_;
  uint32_t stamp_value_ = 0;
  std::vector<HashCode> query_codes_;
  std::vector<uint32_t> sizes_;
  std::vector<uint64_t> order_;
  std::vector<uint32_t> candidates_;
  std::vector<uint8_t> hamming_;
  std::vector<uint32_t> shortlist_;
  std::vector<float> encode_ws_;
  std::vector<float> table_;
};

}  // namespace visloc
