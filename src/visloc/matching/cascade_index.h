// Cascade Correspondence Search (CCS; Tran et al., section III-B): 2D-3D
// matching of one query image against one segment whose 3D points keep only
// compressed descriptors.
//
//   coarse   the 128-bit hash code of a query feature is split into m = 8
//            sub-codes of b = 16 bits; each names a bucket of one of 8 lookup
//            tables (pigeonhole principle, Norouzi et al. CVPR 2012). Radius 0
//            probes the exact bucket (the paper); radius 1 also probes the 16
//            buckets one bit away (multi-index hashing), or only the
//            `lut_flips` of them whose flipped bits' projections lie nearest
//            their hyperplanes (query-directed probing, Lv et al. VLDB 2007:
//            a near neighbour more likely differs in a bit the query barely
//            set). The union of the buckets' point ids, deduplicated, is the
//            list L_C.
//   refined  Hamming distance (XOR + popcount) on the full 128-bit code;
//            the L_R = 40 nearest by a counting sort over distances 0..128.
//   precise  PQ asymmetric distance (M × 256 table per query feature) to the
//            L_R candidates; Lowe's ratio test on distances (not squared).
//            With a residual codebook (pq_codebook.h), the distance to each
//            candidate's decoded vector, computed directly.
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
// Index layout (CascadeIndexView): codes (N × 16 bytes) and pq_codes
// (N × M bytes, M = 16 or 32), usually in a mapped segment file, and a CascadeLookup built
// from the codes when the segment is opened (the lookup tables are not stored:
// they are a function of the codes).
//
// Kernels (search_kernels.h): Hamming with hardware popcount, the ADC table and
// lookups with SIMD, chosen at run time; the search runs in a CascadeWorkspace
// reused across queries and segments, so a query allocates nothing once the
// workspace has grown to the largest segment.
#pragma once

#include <bit>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/matching/search_kernels.h"

namespace visloc {

// The 8 lookup tables of one segment, built from its codes by a counting sort
// per table (ids within a bucket in increasing point order). Per table: a
// bitmap of the non-empty buckets (8 KiB), the number of non-empty buckets
// before each 64-bit bitmap word, CSR offsets of the non-empty buckets only,
// and the point ids: uint16 when the segment has at most 65,536 points,
// uint32 otherwise. For a 5K-point segment this is ~250 KiB (against 2 MiB
// of full offset tables), so a probe of an empty bucket touches one bit.
//
// With `neighbourhood_sizes`, also per table and bucket the size of its
// radius-1 neighbourhood (the bucket and the 16 one bit away) as uint16,
// saturated at 65,535 (1 MiB): the prioritized search at radius 1 orders the
// features by these sums, one read per table where it took 17 probes; a
// saturated entry is summed from the probes, so the sizes are exact either
// way. (One byte per bucket saturated on 7% of the lookups of a 25K-point
// street map already; the sums grow with the points.)
class CascadeLookup {
 public:
  static constexpr size_t kMaxPoints = size_t(1) << 28;
  static constexpr size_t kBitmapWords = kHashBuckets / 64;
  static constexpr uint16_t kNeighbourhoodSaturated = 65535;

  CascadeLookup() = default;
  explicit CascadeLookup(std::span<const HashCode> codes, bool neighbourhood_sizes = true);

  size_t num_points() const { return num_points_; }
  bool uses_16bit_ids() const { return !ids16_.empty() || num_points_ == 0; }
  bool bucket_empty(int table, uint32_t key) const {
    return ((bitmap_[table * kBitmapWords + (key >> 6)] >> (key & 63)) & 1u) == 0;
  }
  // [begin, end) of bucket `key` into ids16(table) / ids32(table); empty
  // (begin == end) for an empty bucket. Branch-free: an empty bucket's rank
  // is that of the next non-empty one (at most the table's last offset, N),
  // and it reads o[r] twice.
  void bucket_range(int table, uint32_t key, uint32_t& begin, uint32_t& end) const {
    const size_t w = table * kBitmapWords + (key >> 6);
    const uint64_t word = bitmap_[w];
    const uint32_t bit = static_cast<uint32_t>((word >> (key & 63)) & 1u);
    const uint32_t r = rank_[w] + static_cast<uint32_t>(std::popcount(word & ((uint64_t(1) << (key & 63)) - 1)));
    const uint32_t* o = offsets_.data() + table_start_[table];
    begin = o[r];
    end = o[r + bit];
  }
  // Whether bucket `key` holds points (1) or not (0), and its rank among the
  // table's non-empty buckets: a non-empty bucket is [o[rank], o[rank + 1])
  // of table_offsets(table). Touches only the bitmap and the ranks (12 KiB
  // per table), so a probe of an empty bucket costs no offset load.
  uint32_t bucket_rank(int table, uint32_t key, uint32_t& rank) const {
    const size_t w = table * kBitmapWords + (key >> 6);
    const uint64_t word = bitmap_[w];
    rank = rank_[w] + static_cast<uint32_t>(std::popcount(word & ((uint64_t(1) << (key & 63)) - 1)));
    return static_cast<uint32_t>((word >> (key & 63)) & 1u);
  }
  const uint32_t* table_offsets(int table) const { return offsets_.data() + table_start_[table]; }
  uint32_t bucket_size(int table, uint32_t key) const {
    uint32_t b, e;
    bucket_range(table, key, b, e);
    return e - b;
  }
  // Σ of the sizes of bucket `key` and its 16 one-bit neighbours.
  uint32_t neighbourhood_size(int table, uint32_t key) const {
    if (!neighbourhood_.empty()) {
      const uint16_t s = neighbourhood_[(size_t(table) << kHashTableBits) | key];
      if (s != kNeighbourhoodSaturated) return s;
    }
    uint32_t sum = bucket_size(table, key);
    for (int b = 0; b < kHashTableBits; ++b) sum += bucket_size(table, key ^ (1u << b));
    return sum;
  }
  bool has_neighbourhood_sizes() const { return !neighbourhood_.empty(); }
  // The stored sums, table-major (8 × 65,536), saturated; empty without them.
  std::span<const uint16_t> stored_neighbourhood_sizes() const { return neighbourhood_; }
  const uint16_t* ids16(int table) const { return ids16_.data() + size_t(table) * num_points_; }
  const uint32_t* ids32(int table) const { return ids32_.data() + size_t(table) * num_points_; }
  // Resident bytes of the tables.
  size_t memory_bytes() const;

 private:
  size_t num_points_ = 0;
  std::vector<uint64_t> bitmap_;  // 8 × 1024
  std::vector<uint32_t> rank_;    // 8 × 1024: non-empty buckets before the word
  std::vector<uint32_t> offsets_; // per table: non-empty buckets + 1
  size_t table_start_[kHashTables + 1] = {};
  std::vector<uint16_t> ids16_;   // 8 × N (N ≤ 65,536)
  std::vector<uint32_t> ids32_;   // 8 × N otherwise
  std::vector<uint16_t> neighbourhood_;  // 8 × 65,536 radius-1 sizes, saturated; or empty
};

struct CascadeIndexView {
  size_t num_points = 0;
  BinaryHasherView hasher;
  const HashCode* codes = nullptr;
  const uint8_t* pq_codes = nullptr;      // N × pq_subvectors bytes
  const CascadeLookup* lookup = nullptr;  // built from `codes`
  int pq_subvectors = kPqSubvectors;      // bytes per PQ code, 16 or 32: must equal the codebook's
  // Checks that the arrays are present and the lookup matches the codes' count.
  // Throws Error(kFormat) with `what` (e.g. a file name) in the message.
  void validate(const std::string& what) const;
};

enum class OneToManyRule {
  kBestRatio,   // top M when d0/d1 < ν (default)
  kGroupRatio,  // candidates before the first j with d0/dj < ν, if j ≤ M
};

struct CascadeSearchOptions {
  int lut_radius = 1;               // 0: exact buckets (paper); 1: also the 16 one-bit-away buckets
  // At radius 1 (no effect at 0), how many of a table's 16 one-bit-away
  // buckets are probed: all 16 (in bit order), or the k whose bits'
  // projections lie nearest their hyperplanes, nearest first (0: the exact
  // buckets alone). Applies to the prioritized and the full search alike;
  // the prioritized order keeps the radius-1 neighbourhood's size as its
  // key whatever k. The margins compare across bits because ITQ's (and a
  // random rotation's) projection rows are orthonormal; with LSH's Gaussian
  // rows they are only roughly comparable.
  int lut_flips = kHashTableBits;
  // With lut_flips < 16: query-directed probing only for the features whose
  // radius-1 coarse size (Σ of their 136 buckets' sizes, the prioritized
  // order's key) exceeds this; the others probe every one-bit neighbour
  // (0: every feature directed).
  int lut_flips_min_list = 0;
  // Whether the search reads the query bits' margins (encode_hash).
  bool needs_margins() const { return lut_radius == 1 && lut_flips > 0 && lut_flips < kHashTableBits; }
  bool refined = true;              // the Hamming step; off: PQ ranks the whole coarse list
  int refined_list = 40;            // L_R
  float ratio_one_to_one = 0.8f;    // ν_h
  float ratio_one_to_many = 0.9f;   // ν
  int max_one_to_many = 5;          // M
  OneToManyRule one_to_many_rule = OneToManyRule::kBestRatio;
  bool prioritize = true;           // shortest coarse lists first + early stop
  int early_stop = 100;             // N_early: stop at this many 1-1 matches (prioritized only)
  SimdLevel simd = SimdLevel::kBest;  // kernels (search_kernels.h); every level gives the same matches
  // Software prefetching: the next features' buckets are located one and two
  // features ahead, and the candidates' hash and PQ codes are prefetched
  // before they are read. The same matches either way; off is the baseline
  // of the benchmarks that measure it.
  bool prefetch = true;
  // > 0: the precise step ranks by (1 − w) d²_PQ + w · 2|q − μ|²(1 − cos(π h
  // / 128)), blending in the distance the 128-bit codes imply (h their
  // Hamming distance; hamming_blend.h), where w is this weight in [0, 1]
  // (`visloc map fit-blend` fits one on a map's own data). The reported
  // distances stay the PQ's (a 1-M list is then in the blend's order, not
  // theirs). 0: the PQ distance alone (the paper's).
  float hash_blend_weight = 0.0f;
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
  // many_points[many_offsets[i] .. many_offsets[i+1]), nearest first (by the
  // ranking distance: with the hash blend, the blend's, not many_distances').
  std::vector<uint32_t> many_query;
  std::vector<uint32_t> many_offsets{0};
  std::vector<uint32_t> many_points;
  std::vector<float> many_distances;
  CascadeMatchStats stats;
  void clear();
};

// Reusable buffers of the search: grown to the largest segment and query
// seen, then reused, so a search allocates nothing. One per thread.
struct CascadeWorkspace {
  // One byte per point: set while a feature's coarse list is gathered, for the
  // deduplication, and cleared right after (all zero between features); a
  // bit per point measured slower (see gather_candidates), a uint32 stamp
  // per point took 4 bytes.
  std::vector<uint8_t> seen;
  std::vector<HashCode> query_codes;
  std::vector<uint32_t> sizes;
  std::vector<uint64_t> order;
  std::vector<uint32_t> counts;  // the counting sort of the search order
  std::vector<uint32_t> candidates;
  std::vector<int32_t> margins;        // query-directed probing: 128 per feature
  std::vector<HashCode> margin_codes;  // their codes, when the caller's codes came without margins
  std::vector<uint8_t> hamming;
  std::vector<uint32_t> shortlist;
  std::vector<float> ranked_distances;
  std::vector<float> ranked_blend;  // with CascadeSearchOptions::hash_blend_weight: the blended distances
  HashWorkspace encode;
  std::vector<float> table;
  size_t capacity_bytes() const;
};

// The prioritized search order: the features whose size is ≥ min_size, as
// size << 32 | index, sorted by (size, index). A counting sort over the sizes
// (stable, so ties stay in index order; `counts` is its reusable scratch), or
// std::sort when a size reaches 65,536. Exposed for tests.
void sort_by_size(const uint32_t* sizes, size_t n, uint32_t min_size, std::vector<uint32_t>& counts,
                  std::vector<uint64_t>& order);

// Query-directed probing's order (flips in [0, 16]): per table k, the `flips` bits of its 16
// (16k .. 16k + 15) with the smallest margins (128 of one feature), by
// increasing (margin, bit), as bit indices 0..15 into out[k * flips ..].
// A sorting network over the 8 tables at once. Exposed for tests.
void directed_flips(const int32_t* margins, int flips, uint8_t* out);

// Searches one segment. Not thread-safe: one matcher (or workspace) per thread.
class CascadeMatcher {
 public:
  // With its own workspace.
  CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook);
  // With a caller's workspace, e.g. one per thread reused across segments.
  CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook, CascadeWorkspace& workspace);

  // Hashes the queries with the index's hasher, then searches.
  void match(const DescriptorMatrix& queries, const CascadeSearchOptions& options, CascadeMatches& out);
  CascadeMatches match(const DescriptorMatrix& queries, const CascadeSearchOptions& options = {});
  // Searches with codes already computed by the same hasher (a map with one
  // hash rotation hashes a query once for all its segments). Query-directed
  // probing (options.needs_margins()) reads the codes' margins (encode_hash,
  // 128 per feature, from the same hasher); without them (an empty span),
  // each call hashes the queries once more to compute them, so a caller
  // that searches several segments should pass them.
  void match_hashed(const DescriptorMatrix& queries, std::span<const HashCode> codes,
                    const CascadeSearchOptions& options, CascadeMatches& out, std::span<const int32_t> margins = {});
  // Coarse list sizes (Σ bucket sizes) of already-encoded codes; exposed for tests.
  void coarse_sizes(std::span<const HashCode> codes, int lut_radius, std::vector<uint32_t>& sizes) const;

 private:
  CascadeIndexView index_;
  const PqCodebook* codebook_;
  std::unique_ptr<CascadeWorkspace> own_workspace_;
  CascadeWorkspace* ws_;
};

}  // namespace visloc
