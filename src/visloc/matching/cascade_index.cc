#include "visloc/matching/cascade_index.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "visloc/matching/hamming_blend.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

void CascadeIndexView::validate(const std::string& what) const {
  if (num_points > 0 && (!codes || !pq_codes || !lookup || !hasher.mean || !hasher.projection))
    throw_error(ErrorCode::kFormat, what, ": cascade index has missing arrays");
  if (num_points > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kFormat, what, ": too many points (", num_points, ", at most ", CascadeLookup::kMaxPoints,
                ")");
  if (!valid_pq_subvectors(pq_subvectors))
    throw_error(ErrorCode::kFormat, what, ": PQ codes of ", pq_subvectors, " bytes (16 or 32)");
  if (lookup && lookup->num_points() != num_points)
    throw_error(ErrorCode::kFormat, what, ": lookup tables of ", lookup->num_points(), " points for ", num_points,
                " codes");
}

namespace {

// Radius-1 neighbourhood sums of one table's bucket sizes (`sizes`, 65,536),
// saturated at 65,535, into `out`. Flipping bit b swaps the halves of every
// 2^(b+1)-entry block, so the inner loops run over contiguous runs.
void neighbourhood_sums(const uint32_t* sizes, uint16_t* out) {
  std::vector<uint32_t> sum(sizes, sizes + kHashBuckets);
  for (int b = 0; b < kHashTableBits; ++b) {
    const uint32_t flip = 1u << b;
    for (uint32_t base = 0; base < kHashBuckets; base += 2 * flip) {
      uint32_t* low = sum.data() + base;
      uint32_t* high = low + flip;
      const uint32_t* size_low = sizes + base;
      const uint32_t* size_high = size_low + flip;
      for (uint32_t i = 0; i < flip; ++i) {
        low[i] += size_high[i];
        high[i] += size_low[i];
      }
    }
  }
  for (uint32_t v = 0; v < kHashBuckets; ++v)
    out[v] = static_cast<uint16_t>(std::min<uint32_t>(sum[v], CascadeLookup::kNeighbourhoodSaturated));
}

}  // namespace

CascadeLookup::CascadeLookup(std::span<const HashCode> codes, bool neighbourhood_sizes) : num_points_(codes.size()) {
  const size_t n = codes.size();
  if (n > kMaxPoints)
    throw_error(ErrorCode::kInvalidArgument, "a segment holds at most ", kMaxPoints, " points, got ", n);
  bitmap_.assign(kHashTables * kBitmapWords, 0);
  rank_.assign(kHashTables * kBitmapWords, 0);
  const bool small = n <= 65536;
  // Padding: the search reads a non-empty bucket's second id before it knows
  // the bucket's size, one past the last table's end at most (two are kept).
  (small ? ids16_.resize(kHashTables * n + 2) : ids32_.resize(kHashTables * n + 2));
  std::vector<uint32_t> count(kHashBuckets + 1);
  offsets_.clear();
  if (neighbourhood_sizes) neighbourhood_.resize(size_t(kHashTables) << kHashTableBits);
  for (int k = 0; k < kHashTables; ++k) {
    // Counting sort: bucket sizes, then exclusive prefix sums as fill positions.
    std::fill(count.begin(), count.end(), 0u);
    for (size_t i = 0; i < n; ++i) ++count[hash_subcode(codes[i], k) + 1];
    if (neighbourhood_sizes)
      neighbourhood_sums(count.data() + 1, neighbourhood_.data() + (size_t(k) << kHashTableBits));
    table_start_[k] = offsets_.size();
    uint64_t* bits = bitmap_.data() + k * kBitmapWords;
    uint32_t* rank = rank_.data() + k * kBitmapWords;
    uint32_t non_empty = 0;
    for (uint32_t v = 0; v < kHashBuckets; ++v) {
      if ((v & 63) == 0) rank[v >> 6] = non_empty;
      if (count[v + 1] > 0) {
        bits[v >> 6] |= uint64_t(1) << (v & 63);
        offsets_.push_back(count[v]);  // start, as a running sum below
        ++non_empty;
      }
      count[v + 1] += count[v];
    }
    offsets_.push_back(static_cast<uint32_t>(n));
    // offsets_ now holds, per non-empty bucket in order, count[v] = the number
    // of points in buckets before v: exactly the CSR start of bucket v.
    for (size_t i = 0; i < n; ++i) {
      const uint32_t slot = count[hash_subcode(codes[i], k)]++;
      if (small) ids16_[k * n + slot] = static_cast<uint16_t>(i);
      else ids32_[k * n + slot] = static_cast<uint32_t>(i);
    }
  }
  table_start_[kHashTables] = offsets_.size();
  offsets_.shrink_to_fit();
}

size_t CascadeLookup::memory_bytes() const {
  return bitmap_.size() * sizeof(uint64_t) + rank_.size() * sizeof(uint32_t) + offsets_.size() * sizeof(uint32_t) +
         ids16_.size() * sizeof(uint16_t) + ids32_.size() * sizeof(uint32_t) + neighbourhood_.size() * sizeof(uint16_t);
}

void CascadeSearchOptions::validate() const {
  if (lut_radius != 0 && lut_radius != 1)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.lut_radius must be 0 or 1, got ", lut_radius);
  if (refined_list < 2 || refined_list > 100000)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.refined_list must be in [2, 100000], got ",
                refined_list);
  if (!(ratio_one_to_one > 0 && ratio_one_to_one <= 1))
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.ratio_one_to_one must be in (0, 1], got ",
                ratio_one_to_one);
  if (!(ratio_one_to_many >= ratio_one_to_one && ratio_one_to_many <= 1))
    throw_error(ErrorCode::kInvalidArgument,
                "CascadeSearchOptions.ratio_one_to_many must be in [ratio_one_to_one, 1], got ", ratio_one_to_many);
  if (max_one_to_many < 1 || max_one_to_many > 64)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.max_one_to_many must be in [1, 64], got ",
                max_one_to_many);
  if (lut_flips_min_list < 0)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.lut_flips_min_list must be >= 0, got ",
                lut_flips_min_list);
  if (lut_flips < 0 || lut_flips > kHashTableBits)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.lut_flips must be in [0, ", kHashTableBits,
                "], got ", lut_flips);
  if (early_stop < 0)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.early_stop must be >= 0, got ", early_stop);
  if (!(hash_blend_weight >= 0 && hash_blend_weight <= 1))
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.hash_blend_weight must be in [0, 1], got ",
                hash_blend_weight);
  if (!cpu_supports(simd))
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.simd: this CPU does not support ", to_string(simd));
}

void CascadeMatches::clear() {
  query.clear();
  point.clear();
  distance.clear();
  many_query.clear();
  many_offsets.assign(1, 0);
  many_points.clear();
  many_distances.clear();
  stats = {};
}

size_t CascadeWorkspace::capacity_bytes() const {
  return seen.capacity() + query_codes.capacity() * sizeof(HashCode) + sizes.capacity() * 4 + order.capacity() * 8 +
         candidates.capacity() * 4 + margins.capacity() * 4 + margin_codes.capacity() * sizeof(HashCode) +
         hamming.capacity() + shortlist.capacity() * 4 + ranked_distances.capacity() * 4 + ranked_blend.capacity() * 4 +
         encode.projection_transposed.capacity() * 4 + encode.centred.capacity() * 4 +
         encode.quantized.weight_pairs.capacity() * 2 + encode.quantized.weights_transposed.capacity() * 2 +
         encode.quantized.thresholds.capacity() * 4 + table.capacity() * 4 + counts.capacity() * 4;
}

namespace {

// The search indexes the lookup's ids into the codes and its workspace by the
// point count, so a lookup built for another count would read out of bounds.
void check_searchable(const CascadeIndexView& index, const PqCodebook& codebook) {
  VISLOC_CHECK(!codebook.empty());
  VISLOC_CHECK(index.num_points == 0 || index.lookup != nullptr);
  VISLOC_CHECK(index.lookup == nullptr || index.lookup->num_points() == index.num_points,
               "(lookup tables built for another point count)");
  if (index.pq_subvectors != codebook.subvectors())
    throw_error(ErrorCode::kInvalidArgument, "the index's PQ codes have ", index.pq_subvectors,
                " bytes, the codebook's ", codebook.code_bytes());
}

}  // namespace

CascadeMatcher::CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook)
    : index_(index), codebook_(&codebook), own_workspace_(std::make_unique<CascadeWorkspace>()),
      ws_(own_workspace_.get()) {
  check_searchable(index, codebook);
}

CascadeMatcher::CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook, CascadeWorkspace& workspace)
    : index_(index), codebook_(&codebook), ws_(&workspace) {
  check_searchable(index, codebook);
}

namespace {

// Up to this many ranked candidates the ADC distances are computed without the
// table. Measured (bench/micro_bench BM_KernelAdcDirect40): the table and its
// lookups cost ~1.5 µs with AVX2 or AVX-512 and ~2.5 µs with the scalar
// kernels; a direct distance ~7 ns with AVX2 and ~42 ns scalar. One bound for
// every level: the two paths round differently, and every level must give the
// same matches (so the scalar kernels pay up to ~2× between 60 and 160).
// Measured with 16-byte codes. With 32-byte ones, 40 direct distances took
// 1.6× and the table path 1.3× as long (AVX-512, BM_KernelAdcDirect40/*/32),
// which moves the break-even point down a little; the same bound is kept.
constexpr size_t kDirectAdcMaxCandidates = 160;

// The SIMD ADC kernels gather a code's 32-bit words at int32 indices
// id · M / 4 + w (search_kernels.cc): they must not wrap at 32-byte codes.
static_assert(CascadeLookup::kMaxPoints * (kPqMaxSubvectors / 4) <= (size_t(1) << 31));

// The probes of one table: the exact bucket, then (radius 1) the 16 buckets
// one bit away, in that order; or, query-directed, those of the bits in
// `flips` (directed_flips), in that order.
inline uint32_t probe_bucket(uint32_t key, int b) { return b == 0 ? key : key ^ (1u << (b - 1)); }
inline uint32_t probe_bucket(uint32_t key, int b, const uint8_t* flips) {
  return b == 0 ? key : key ^ (1u << flips[b - 1]);
}

// Batcher's odd-even merge sort of 16 keys (63 compare-exchanges; sorts every
// 0-1 input, so every input).
constexpr uint8_t kSortNetwork16[63][2] = {
    {0, 1},   {2, 3},  {4, 5},  {6, 7},   {8, 9},   {10, 11}, {12, 13}, {14, 15}, {0, 2},   {1, 3},   {4, 6},
    {5, 7},   {8, 10}, {9, 11}, {12, 14}, {13, 15}, {1, 2},   {5, 6},   {9, 10},  {13, 14}, {0, 4},   {1, 5},
    {2, 6},   {3, 7},  {8, 12}, {9, 13},  {10, 14}, {11, 15}, {2, 4},   {3, 5},   {10, 12}, {11, 13}, {1, 2},
    {3, 4},   {5, 6},  {9, 10}, {11, 12}, {13, 14}, {0, 8},   {1, 9},   {2, 10},  {3, 11},  {4, 12},  {5, 13},
    {6, 14},  {7, 15}, {4, 8},  {5, 9},   {6, 10},  {7, 11},  {2, 4},   {3, 5},   {6, 8},   {7, 9},   {10, 12},
    {11, 13}, {1, 2},  {3, 4},  {5, 6},   {7, 8},   {9, 10},  {11, 12}, {13, 14}};

// The rank in CascadeLookup uses std::popcount: VISLOC_POPCNT_CLONES
// (binary_hasher.h) makes it one instruction where the CPU has POPCNT.

VISLOC_POPCNT_CLONES
void coarse_sizes_impl(const CascadeLookup& lookup, const HashCode* codes, size_t n, int radius, uint32_t* sizes) {
  if (radius == 1) {
    for (size_t f = 0; f < n; ++f) {
      uint32_t s = 0;
      for (int k = 0; k < kHashTables; ++k) s += lookup.neighbourhood_size(k, hash_subcode(codes[f], k));
      sizes[f] = s;
    }
    return;
  }
  for (size_t f = 0; f < n; ++f) {
    uint32_t s = 0;
    for (int k = 0; k < kHashTables; ++k) s += lookup.bucket_size(k, hash_subcode(codes[f], k));
    sizes[f] = s;
  }
}

// The probes of one feature that hold points: [begin, end) and the table of
// every non-empty probed bucket, in probe order (table 0..7; the exact bucket,
// then its one-bit neighbours), and the sum of their sizes (while they are
// listed, `begin` holds each bucket's rank until its offsets are read). Empty buckets are
// dropped from the list without a branch (each probe is written, the count
// advances by its bitmap bit) before any offset is read, so they cost neither
// an offset load nor a load of the ids (many at radius 1 on a segment of a few
// thousand points; 28% on a 100K-point one).
struct ProbeRanges {
  static constexpr int kMaxProbes = kHashTables * (kHashTableBits + 1);
  uint32_t begin[kMaxProbes], end[kMaxProbes];
  uint8_t table[kMaxProbes];
  int count = 0;        // non-empty probes
  uint32_t listed = 0;  // Σ bucket sizes (the coarse size, before deduplication)
};

// The probes' first step: the non-empty probed buckets and their ranks, from
// the bitmap and rank words alone (`begin` holds the ranks). With
// kPrefetchOffsets, each bucket's offsets are prefetched for probe_offsets.
// `flips`: query-directed probing's bits, (probes − 1) per table, or null
// (every bit, in order).
template <bool kPrefetchOffsets>
VISLOC_POPCNT_CLONES void probe_ranks(const CascadeLookup& lookup, const HashCode& code, int probes, ProbeRanges& r,
                                      const uint8_t* flips) {
  int c = 0;
  for (int k = 0; k < kHashTables; ++k) {
    const uint32_t key = hash_subcode(code, k);
    [[maybe_unused]] const uint32_t* o = lookup.table_offsets(k);
    const uint8_t* table_flips = flips ? flips + k * (probes - 1) : nullptr;
    for (int b = 0; b < probes; ++b) {
      uint32_t rank;
      const uint32_t bucket = table_flips ? probe_bucket(key, b, table_flips) : probe_bucket(key, b);
      const uint32_t non_empty = lookup.bucket_rank(k, bucket, rank);
      r.begin[c] = rank;
      r.table[c] = static_cast<uint8_t>(k);
      if constexpr (kPrefetchOffsets) __builtin_prefetch(o + rank);
      c += static_cast<int>(non_empty);
    }
  }
  r.count = c;
}

// The second step: the ranks replaced by the buckets' [begin, end), and the
// coarse size.
void probe_offsets(const CascadeLookup& lookup, ProbeRanges& r) {
  uint32_t listed = 0;
  for (int i = 0; i < r.count; ++i) {
    const uint32_t* o = lookup.table_offsets(r.table[i]);
    const uint32_t rank = r.begin[i];
    r.begin[i] = o[rank];
    r.end[i] = o[rank + 1];
    listed += r.end[i] - r.begin[i];
  }
  r.listed = listed;
}

void probe_ranges(const CascadeLookup& lookup, const HashCode& code, int probes, ProbeRanges& r, const uint8_t* flips) {
  probe_ranks<false>(lookup, code, probes, r, flips);
  probe_offsets(lookup, r);
}

// The probes of a feature: radius 0 or 1, every one-bit neighbour, or
// query-directed (`directed`: the bits of `margins`, the feature's 128, or
// none at 0 flips), for every feature or those above `min_list`.
struct ProbePlan {
  int probes = 1;
  bool directed = false;
  int flips = 0;                          // directed: bits probed per table
  const int32_t* margins = nullptr;       // directed with flips > 0: 128 per feature
  uint32_t min_list = 0;                  // directed only above this radius-1 coarse size
  const CascadeLookup* lookup = nullptr;  // the sizes, or
  const uint32_t* sizes = nullptr;        // the prioritized order's (radius 1), by feature
  // The feature's probes per table (`feature_probes`) and its flip bits into
  // `scratch` (kHashTables × flips), or null: every bit in order (or none).
  const uint8_t* flip_bits(uint32_t feature, const HashCode& code, uint8_t* scratch, int& feature_probes) const {
    feature_probes = probes;
    if (!directed) return nullptr;
    if (min_list > 0) {
      uint32_t size = 0;
      if (sizes) {
        size = sizes[feature];
      } else {
        for (int k = 0; k < kHashTables; ++k) size += lookup->neighbourhood_size(k, hash_subcode(code, k));
      }
      if (size <= min_list) {
        feature_probes = kHashTableBits + 1;
        return nullptr;
      }
    }
    if (flips == 0) return nullptr;  // the exact buckets alone
    directed_flips(margins + size_t(feature) * kHashBits, flips, scratch);
    return scratch;
  }
  // The feature's probes without prefetching.
  void probe(const CascadeLookup& lookup, uint32_t feature, const HashCode& code, ProbeRanges& r) const {
    uint8_t scratch[kHashTables * kHashTableBits];
    int feature_probes;
    const uint8_t* bits = flip_bits(feature, code, scratch, feature_probes);
    probe_ranges(lookup, code, feature_probes, r, bits);
  }
};

// The search's probes; query-directed probing without the caller's margins
// computes them into the workspace (a hash of every query feature).
ProbePlan probe_plan(const CascadeIndexView& index, const DescriptorMatrix& queries,
                     const CascadeSearchOptions& options, std::span<const int32_t> margins, CascadeWorkspace& ws) {
  ProbePlan plan;
  if (options.lut_radius == 0) return plan;
  if (options.lut_flips == kHashTableBits) {
    plan.probes = kHashTableBits + 1;
    return plan;
  }
  plan.directed = true;
  plan.probes = 1 + options.lut_flips;
  plan.flips = options.lut_flips;
  plan.min_list = uint32_t(options.lut_flips_min_list);
  plan.lookup = index.lookup;
  if (!options.needs_margins()) return plan;
  const size_t nq = queries.rows();
  VISLOC_CHECK(margins.empty() || margins.size() == nq * kHashBits, "128 hash margins per query feature");
  if (margins.empty()) {
    ws.margins.resize(nq * kHashBits);
    ws.margin_codes.resize(nq);
    encode_hash(index.hasher, queries.data(), nq, ws.margin_codes.data(), ws.encode, ws.margins.data());
    margins = ws.margins;
  }
  plan.margins = margins.data();
  return plan;
}

// The probes of the features in search order, computed two features ahead so
// that their memory is on its way before it is read: ranges(i) returns
// position i's probes (offsets read) after it has read position i + 1's
// offsets and prefetched the first ids of its buckets, and found position
// i + 2's buckets and prefetched their offsets. Positions are asked for in
// increasing order from 0. Measured on a 100K-point segment (10K features,
// radius 1; with the codes' prefetches in the gather and before the ADC): see
// the comment before CascadeMatcher::match_hashed.
class ProbePipeline {
 public:
  ProbePipeline(const CascadeLookup& lookup, const HashCode* codes, std::span<const uint64_t> order, ProbePlan plan)
      : lookup_(lookup), codes_(codes), order_(order), plan_(plan) {
    for (int k = 0; k < kHashTables; ++k) {
      ids16_[k] = lookup.uses_16bit_ids() ? lookup.ids16(k) : nullptr;
      ids32_[k] = lookup.uses_16bit_ids() ? nullptr : lookup.ids32(k);
    }
  }
  const ProbeRanges& ranges(size_t i) {
    if (i == 0) {
      ranks(0);
      probe_offsets(lookup_, slot(0));
      if (order_.size() > 1) ranks(1);
    }
    if (i + 1 < order_.size()) {
      ProbeRanges& next = slot(i + 1);
      probe_offsets(lookup_, next);
      for (int c = 0; c < next.count; ++c)
        __builtin_prefetch(lookup_.uses_16bit_ids() ? static_cast<const void*>(ids16_[next.table[c]] + next.begin[c])
                                                    : static_cast<const void*>(ids32_[next.table[c]] + next.begin[c]));
    }
    if (i + 2 < order_.size()) ranks(i + 2);
    return slot(i);
  }

 private:
  ProbeRanges& slot(size_t i) { return stages_[i % 3]; }
  void ranks(size_t i) {
    const uint32_t f = static_cast<uint32_t>(order_[i] & 0xffffffffu);
    int probes;
    const uint8_t* flips = plan_.flip_bits(f, codes_[f], flips_, probes);
    probe_ranks<true>(lookup_, codes_[f], probes, slot(i), flips);
  }
  const CascadeLookup& lookup_;
  const HashCode* codes_;
  std::span<const uint64_t> order_;
  ProbePlan plan_;
  uint8_t flips_[kHashTables * kHashTableBits];
  const uint16_t* ids16_[kHashTables];
  const uint32_t* ids32_[kHashTables];
  ProbeRanges stages_[3];
};

// Coarse: the union of the probed buckets, deduplicated by the `seen` bytes
// (one per point), in probe order (within a bucket, increasing point id), into
// `out` (room for r.listed + 1). Every listed bucket holds a point; its second
// id is taken without a branch, since most buckets hold 1 or 2 points: it is
// read even past the bucket's end (the lookup's padding makes that safe),
// then counted only if the bucket has it and it is new; its byte is
// rewritten unchanged otherwise. The caller clears the bytes of `out`'s ids
// afterwards. Bytes rather than bits: a bit set read-modify-writes a word
// shared by 64 points, so the loads of nearby candidates waited on one
// another's stores. Measured on fountain-P11's gather (8,192 features, radius
// 1, medians of 3): bytes 10.1 against 12.0 ms for bits; the first two ids
// without a branch (when empty buckets were still listed) 9.1 against 10.1 ms
// for one; empty buckets dropped from the list: fountain-P11's full search at
// radius 1 28.5 against 33.6 ms (`bench matching`, medians of 6 alternated
// runs), but on a 100K-point segment, where 98.5 of a feature's 136 probes
// hold points, no change beyond the noise (micro bench). Not faster, measured:
// computing the Hamming distances here rather than in a pass of their own
// (duplicates cost a distance each). Prefetching the next feature's first ids
// alone measured no faster in separate runs; with the probes two features
// ahead and the codes prefetched (kPrefetchCodes, ProbePipeline), timed
// alternately in one process, it is (see match_hashed).
// Two other layouts were slower or no faster (session 42, on the 100K-point
// segment of the micro bench, the two layouts timed alternately in one
// process, medians of 20 runs). Each non-empty bucket's first 1, 2 or 3 ids
// stored beside its offset (an entry of 8, 12 or 16 bytes per bucket; the
// rest in an id array of their own; the same candidates in the same order),
// so that a bucket of up to 3 points costs one cache line, not two (of a
// feature's 98.5 non-empty probes there, 37.1 hold one point, 24.8 two and
// 14.7 three): the probes, the gather and the Hamming pass alone took
// 1.2-1.7× as long, e.g. 56.7 against 39.2 ms with 3 ids, the entries being
// read in the gather rather than a feature ahead. The points renumbered in
// the order of their hash codes, so that the codes of a bucket share cache
// lines: the whole search 62.0 against 63.1 ms, within this machine's noise.
template <typename Id, bool kPrefetchCodes>
size_t gather_candidates(const Id* const* ids, const ProbeRanges& r, uint8_t* seen, uint32_t* out,
                         [[maybe_unused]] const HashCode* codes) {
  size_t n = 0;
  for (int c = 0; c < r.count; ++c) {
    const Id* table_ids = ids[r.table[c]];
    const uint32_t begin = r.begin[c], end = r.end[c];
    const uint32_t first = table_ids[begin];
    const uint8_t was = seen[first];
    out[n] = first;
    if constexpr (kPrefetchCodes) __builtin_prefetch(codes + first);
    n += static_cast<size_t>(was == 0);
    seen[first] = 1;
    const uint32_t second = table_ids[begin + 1];
    const uint8_t was2 = seen[second];
    const uint8_t two = begin + 1 < end;
    out[n] = second;
    if constexpr (kPrefetchCodes) __builtin_prefetch(codes + second);
    n += static_cast<size_t>(two & (was2 == 0));
    seen[second] = was2 | two;
    for (uint32_t i = begin + 2; i < end; ++i) {
      const uint32_t id = table_ids[i];
      const uint8_t w = seen[id];
      out[n] = id;
      if constexpr (kPrefetchCodes) __builtin_prefetch(codes + id);
      n += static_cast<size_t>(w == 0);
      seen[id] = 1;
    }
  }
  return n;
}

// With `codes`, each listed id's hash code is prefetched for the Hamming pass.
size_t collect_all(const CascadeLookup& lookup, const ProbeRanges& r, uint8_t* seen, uint32_t* out,
                   const HashCode* codes) {
  if (lookup.uses_16bit_ids()) {
    const uint16_t* ids[kHashTables];
    for (int k = 0; k < kHashTables; ++k) ids[k] = lookup.ids16(k);
    return codes ? gather_candidates<uint16_t, true>(ids, r, seen, out, codes)
                 : gather_candidates<uint16_t, false>(ids, r, seen, out, codes);
  }
  const uint32_t* ids[kHashTables];
  for (int k = 0; k < kHashTables; ++k) ids[k] = lookup.ids32(k);
  return codes ? gather_candidates<uint32_t, true>(ids, r, seen, out, codes)
               : gather_candidates<uint32_t, false>(ids, r, seen, out, codes);
}

// Refined: the `list` nearest of the n candidates (more than `list`) by
// Hamming distance, by a counting sort over 0..128, into the first `list`
// entries of ws.shortlist (candidate order kept; of the candidates at the cut
// distance, the first ones). The selection is a kernel: profiled (perf) on
// the 100K-point segment, the branch-free scalar loop, whose count of ties
// left chains one candidate to the next, took 17% of the search's own
// samples; with AVX-512's compress 29.5 against 338 ns per 233 candidates
// (BM_KernelShortlist), and the whole search ~10% faster (six alternated
// pairs of processes, BM_CascadeSearch100KPoints/1/0/1).
inline void refined_shortlist(const SearchKernels& kernels, const HashCode& code, const HashCode* codes, size_t n,
                              uint32_t list, CascadeWorkspace& ws) {
  uint32_t hist[kHashBits + 1];
  if (ws.hamming.size() < n) ws.hamming.resize(n);
  std::fill(std::begin(hist), std::end(hist), 0u);
  kernels.hamming_distances(code, codes, ws.candidates.data(), n, ws.hamming.data(), hist);
  uint32_t cut = 0, below = 0;  // distances < cut all fit; some of distance == cut
  while (below + hist[cut] < list) below += hist[cut++];
  if (ws.shortlist.size() < size_t(list) + kShortlistSlack) ws.shortlist.resize(size_t(list) + kShortlistSlack);
  const size_t taken =
      kernels.shortlist(ws.hamming.data(), ws.candidates.data(), n, cut, list - below, list, ws.shortlist.data());
  VISLOC_CHECK(taken == list, "the refined step's short list holds L_R candidates");
}

// The `keep` smallest of d[0..n) by insertion, nearest first, into best_d
// and best_id (ids[r], or r itself without ids); the first of equal
// distances first. Returns how many (min(n, keep)).
inline int keep_nearest(const float* d, const uint32_t* ids, size_t n, int keep, float* best_d, uint32_t* best_id) {
  int filled = 0;
  for (size_t r = 0; r < n; ++r) {
    const float x = d[r];
    const uint32_t id = ids ? ids[r] : static_cast<uint32_t>(r);
    if (filled == keep && x >= best_d[keep - 1]) continue;
    int pos = filled < keep ? filled++ : keep - 1;
    while (pos > 0 && best_d[pos - 1] > x) {
      best_d[pos] = best_d[pos - 1];
      best_id[pos] = best_id[pos - 1];
      --pos;
    }
    best_d[pos] = x;
    best_id[pos] = id;
  }
  return filled;
}

// The ratio tests on the `filled` nearest (squared distances best_d, at least
// 2): feature f's 1-1 match and 1-M candidates, appended to `out` with the
// distances `reported` (squared; best_d's own, or with the hash blend the
// candidates' PQ distances).
inline void emit_matches(uint32_t f, const float* best_d, const float* reported, const uint32_t* best_id, int filled,
                         const CascadeSearchOptions& options, float r11, float r1m, CascadeMatches& out) {
  // Ratio tests on squared distances: d0/d1 < ν ⇔ d0² < ν² d1².
  const float d0 = best_d[0], d1 = best_d[1];
  if (d0 < r11 * d1) {
    out.query.push_back(f);
    out.point.push_back(best_id[0]);
    out.distance.push_back(std::sqrt(std::max(0.0f, reported[0])));
  }
  int accepted = 0;
  if (options.one_to_many_rule == OneToManyRule::kBestRatio) {
    if (d0 < r1m * d1) accepted = std::min(filled, options.max_one_to_many);
  } else {
    // First j ≥ 1 whose distance is clearly larger than the best; j == filled
    // (no further candidate) counts as infinitely far.
    int j = 1;
    while (j < filled && !(d0 < r1m * best_d[j])) ++j;
    if (j <= options.max_one_to_many) accepted = j;
  }
  if (accepted > 0) {
    out.many_query.push_back(f);
    for (int i = 0; i < accepted; ++i) {
      out.many_points.push_back(best_id[i]);
      out.many_distances.push_back(std::sqrt(std::max(0.0f, reported[i])));
    }
    out.many_offsets.push_back(static_cast<uint32_t>(out.many_points.size()));
  }
}

}  // namespace

// Eight lanes, one per table: GCC's vector extension, so that every
// compare-exchange is one min and one max of 8 int32 (AVX2, or two halves
// with SSE4.1 / NEON; the keys are below 2^31, so signed order is theirs).
#if defined(__GNUC__)
#define VISLOC_DIRECTED_FLIPS_VECTOR 1
typedef int32_t FlipKeys __attribute__((vector_size(32)));
static_assert(kHashTables == 8);
#endif

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("avx2", "sse4.1", "default")))
#endif
void directed_flips(const int32_t* margins, int flips, uint8_t* out) {
  VISLOC_CHECK(flips >= 0 && flips <= kHashTableBits, "directed_flips: 0 to 16 bits per table");
  // key[b][k] = (margin, bit) of table k's bit b, margins saturated at
  // 2^27 − 1 (far beyond any bit worth flipping; ties by bit index).
#ifdef VISLOC_DIRECTED_FLIPS_VECTOR
  FlipKeys key[kHashTableBits];
  for (int b = 0; b < kHashTableBits; ++b)
    for (int k = 0; k < kHashTables; ++k)
      key[b][k] = (std::clamp(margins[k * kHashTableBits + b], 0, (1 << 27) - 1) << 4) | b;
  for (const auto& e : kSortNetwork16) {
    const FlipKeys a = key[e[0]], b = key[e[1]];
    const auto less = a < b;
    key[e[0]] = less ? a : b;
    key[e[1]] = less ? b : a;
  }
#else
  int32_t key[kHashTableBits][kHashTables];
  for (int b = 0; b < kHashTableBits; ++b)
    for (int k = 0; k < kHashTables; ++k)
      key[b][k] = (std::clamp(margins[k * kHashTableBits + b], 0, (1 << 27) - 1) << 4) | b;
  for (const auto& e : kSortNetwork16)
    for (int k = 0; k < kHashTables; ++k) {
      const int32_t a = key[e[0]][k], b = key[e[1]][k];
      key[e[0]][k] = std::min(a, b);
      key[e[1]][k] = std::max(a, b);
    }
#endif
  for (int k = 0; k < kHashTables; ++k)
    for (int j = 0; j < flips; ++j) out[k * flips + j] = static_cast<uint8_t>(key[j][k] & 15);
}

void sort_by_size(const uint32_t* sizes, size_t n, uint32_t min_size, std::vector<uint32_t>& counts,
                  std::vector<uint64_t>& order) {
  order.clear();
  uint32_t largest = 0;
  for (size_t f = 0; f < n; ++f) largest = std::max(largest, sizes[f]);
  constexpr uint32_t kCountingSortMax = 1u << 16;
  if (largest >= kCountingSortMax) {
    for (size_t f = 0; f < n; ++f)
      if (sizes[f] >= min_size) order.push_back((uint64_t(sizes[f]) << 32) | f);
    std::sort(order.begin(), order.end());
    return;
  }
  counts.assign(size_t(largest) + 2, 0u);
  size_t kept = 0;
  for (size_t f = 0; f < n; ++f)
    if (sizes[f] >= min_size) ++counts[sizes[f] + 1], ++kept;
  for (size_t v = 1; v < counts.size(); ++v) counts[v] += counts[v - 1];
  order.resize(kept);
  for (size_t f = 0; f < n; ++f)
    if (sizes[f] >= min_size) order[counts[sizes[f]]++] = (uint64_t(sizes[f]) << 32) | f;
}

void CascadeMatcher::coarse_sizes(std::span<const HashCode> codes, int radius, std::vector<uint32_t>& sizes) const {
  sizes.resize(codes.size());
  if (index_.num_points == 0) {
    std::fill(sizes.begin(), sizes.end(), 0u);
    return;
  }
  coarse_sizes_impl(*index_.lookup, codes.data(), codes.size(), radius, sizes.data());
}

CascadeMatches CascadeMatcher::match(const DescriptorMatrix& queries, const CascadeSearchOptions& options) {
  CascadeMatches out;
  match(queries, options, out);
  return out;
}

void CascadeMatcher::match(const DescriptorMatrix& queries, const CascadeSearchOptions& options, CascadeMatches& out) {
  options.validate();
  Timer t;
  CascadeWorkspace& ws = *ws_;
  ws.query_codes.resize(queries.rows());
  const bool margins = options.needs_margins();
  ws.margins.resize(margins ? queries.rows() * kHashBits : 0);
  if (index_.num_points > 0)
    encode_hash(index_.hasher, queries.data(), queries.rows(), ws.query_codes.data(), ws.encode,
                margins ? ws.margins.data() : nullptr);
  const double ms_hash = t.elapsed_ms();
  // match_hashed reads the codes and margins from the workspace it also
  // uses: copy-free because it only reads them.
  match_hashed(queries, ws.query_codes, options, out, ws.margins);
  out.stats.ms_hash = ms_hash;
  out.stats.ms_total += ms_hash;
}

// Where the full search at radius 1 on a 100K-point segment (10K features,
// micro bench) spends its time, measured on a copy of this search cut after
// each step, all in one process (medians of 6; the copy 43.1 ms, this search
// 46.3 ms in the same run): the probes and offsets 3.4 ms, the gather 14.7,
// the Hamming pass 8.4, the short list and ADC 16.6. Measured there and not
// kept: each table's codes stored beside its ids in bucket order, so the
// gather takes the Hamming distances from contiguous memory (8 × 16 bytes
// per point more; 81.1 against 43.1 ms, presumably as the larger tables
// miss the cache more); the ranked candidates' PQ codes prefetched before the
// ADC (3-9% faster in the copy; in this search inconclusive: 43.0-45.5 with
// against 32.8-37.6 ms without in 3 alternated process pairs, a baseline far
// below this search's other runs); glibc.malloc.hugetlb=1, which puts large
// allocations in transparent huge pages (20-290 MB of them seen in the
// process: no change beyond the noise in 6 alternated pairs).
// Kept: software prefetching (CascadeSearchOptions::prefetch). Profiled
// (perf, cpu-clock samples), 44% of the search's own time waited on the load
// of each bucket's first id; the probes now run two features ahead
// (ProbePipeline), the gather prefetches each candidate's hash code, and the
// short list's PQ codes are prefetched before the ADC. The micro bench
// BM_CascadeSearch100KPointsPrefetch times both in one process, alternated:
// medians 33.0 / 33.1 / 37.8 ms with against 46.9 / 44.3 / 77.1 without in
// three runs (1.3-2.0×: the more the machine's other load contends for the
// cache, the larger the gain), the same matches; on fountain-P11 (`bench
// matching`, ccs-full-r1 against ccs-full-r1-no-prefetch, 6 alternated runs)
// 26.4-28.0 against 26.7-29.0 ms. Tried and not kept: the gather one feature
// ahead as well (slower than the probes alone), and the features sorted by
// their first table's key, so that neighbours share buckets (1.5× slower:
// the next feature's loads of the deduplication bytes then wait on this
// feature's stores to the same bytes).
void CascadeMatcher::match_hashed(const DescriptorMatrix& queries, std::span<const HashCode> codes,
                                  const CascadeSearchOptions& options, CascadeMatches& out,
                                  std::span<const int32_t> margins) {
  options.validate();
  out.clear();
  Timer total;
  const size_t nq = queries.rows();
  const size_t np = index_.num_points;
  out.stats.features = nq;
  if (nq == 0 || np == 0) return;
  VISLOC_CHECK(codes.size() == nq, "one hash code per query feature");
  const SearchKernels& kernels = search_kernels(options.simd);
  CascadeWorkspace& ws = *ws_;
  const CascadeLookup& lookup = *index_.lookup;

  // 1. Search order: by increasing (coarse size, index) when prioritized;
  //    otherwise every feature in index order (its coarse size comes with its
  //    probes below).
  Timer t;
  if (options.prioritize) {
    coarse_sizes(codes, options.lut_radius, ws.sizes);
    sort_by_size(ws.sizes.data(), nq, 2, ws.counts, ws.order);
  } else {
    ws.order.resize(nq);
    for (size_t f = 0; f < nq; ++f) ws.order[f] = f;
  }
  out.stats.ms_order = t.elapsed_ms();

  // 2. Per feature: coarse → refined → precise.
  t.reset();
  if (ws.seen.size() < np) ws.seen.resize(np, 0);
  const bool residual = codebook_->is_residual();
  if (!residual) ws.table.resize(codebook_->table_size());
  const AdcKernels& adc = kernels.adc(codebook_->subvectors());
  const AdditiveKernels::Direct additive = residual ? kernels.additive.direct(codebook_->residual_splits()) : nullptr;
  const int keep = std::max(options.max_one_to_many, 1) + 1;  // ranks needed by both rules
  float best_d[65], best_pq[65];
  uint32_t best_id[65];
  const float r11 = options.ratio_one_to_one * options.ratio_one_to_one;
  const float r1m = options.ratio_one_to_many * options.ratio_one_to_many;
  const size_t early = options.prioritize && options.early_stop > 0 ? size_t(options.early_stop) : SIZE_MAX;
  ProbePlan plan = probe_plan(index_, queries, options, margins, ws);
  if (options.prioritize && options.lut_radius == 1) plan.sizes = ws.sizes.data();
  float qf[kDescriptorDim];
  ProbeRanges plain_ranges;
  ProbePipeline pipeline(lookup, codes.data(), ws.order, plan);
  const HashCode* prefetched_codes = options.prefetch ? index_.codes : nullptr;
  const size_t pq_bytes = size_t(index_.pq_subvectors);
  std::span<const uint32_t> ranked;
  const float blend = options.hash_blend_weight;
  const std::array<float, kHashBits + 1>& unit_chord = unit_chord_table();

  for (size_t position = 0; position < ws.order.size(); ++position) {
    if (out.query.size() >= early) {
      out.stats.early_stopped = true;
      break;
    }
    const uint32_t f = static_cast<uint32_t>(ws.order[position] & 0xffffffffu);
    const HashCode code = codes[f];
    if (!options.prefetch) plan.probe(lookup, f, code, plain_ranges);
    const ProbeRanges& ranges = options.prefetch ? pipeline.ranges(position) : plain_ranges;
    if (ranges.listed < 2) continue;  // not searched: no ratio test possible
    if (ws.candidates.size() < size_t(ranges.listed) + 1) ws.candidates.resize(size_t(ranges.listed) + 1);
    const size_t n_candidates = collect_all(lookup, ranges, ws.seen.data(), ws.candidates.data(), prefetched_codes);
    for (size_t j = 0; j < n_candidates; ++j) ws.seen[ws.candidates[j]] = 0;
    out.stats.coarse_candidates += n_candidates;
    ++out.stats.features_searched;
    if (n_candidates < 2) continue;

    // Refined: top L_R by Hamming distance.
    ranked = std::span<const uint32_t>(ws.candidates.data(), n_candidates);
    if (options.refined && n_candidates > size_t(options.refined_list)) {
      refined_shortlist(kernels, code, index_.codes, n_candidates, uint32_t(options.refined_list), ws);
      ranked = std::span<const uint32_t>(ws.shortlist.data(), size_t(options.refined_list));
    }
    out.stats.ranked_candidates += ranked.size();
    if (options.prefetch)
      for (uint32_t id : ranked) {
        const uint8_t* pq = index_.pq_codes + size_t(id) * pq_bytes;
        __builtin_prefetch(pq);
        __builtin_prefetch(pq + pq_bytes - 1);  // a 32-byte code may straddle two lines
      }

    // Precise: PQ asymmetric distances, the `keep` nearest by insertion.
    const uint8_t* q = queries.row(f);
    for (int j = 0; j < kDescriptorDim; ++j) qf[j] = q[j];
    // A short list (L_R = 40 after the refined step) costs less without the
    // M × 256 table; the two paths' distances differ by float rounding only,
    // and every candidate of a feature takes the same path.
    ws.ranked_distances.resize(ranked.size());
    if (residual) {
      // Residual codes have no table (it would cost 16 × 256 dot products
      // of 128 / S dimensions): always the direct distance.
      additive(codebook_->centroids().data(), qf, index_.pq_codes, ranked.data(), ranked.size(),
               ws.ranked_distances.data());
    } else if (ranked.size() <= kDirectAdcMaxCandidates) {
      adc.direct(codebook_->centroids().data(), qf, index_.pq_codes, ranked.data(), ranked.size(),
                 ws.ranked_distances.data());
    } else {
      adc.table(codebook_->centroids_transposed(), qf, ws.table.data());
      adc.distances(ws.table.data(), index_.pq_codes, ranked.data(), ranked.size(), ws.ranked_distances.data());
    }
    if (blend > 0) {
      // Ranked by the blend with the codes' distance, 2|q − μ|²(1 − cos(π h
      // / 128)); the PQ distances are still the ones reported (the guided
      // confirmation compares PQ distances with them).
      float norm2 = 0;
      for (int j = 0; j < kDescriptorDim; ++j)
        norm2 += (qf[j] - index_.hasher.mean[j]) * (qf[j] - index_.hasher.mean[j]);
      const float scale = 2 * blend * norm2;
      ws.ranked_blend.resize(ranked.size());
      for (size_t r = 0; r < ranked.size(); ++r) {
        const HashCode& pc = index_.codes[ranked[r]];
        const int h = std::popcount(code.w[0] ^ pc.w[0]) + std::popcount(code.w[1] ^ pc.w[1]);
        ws.ranked_blend[r] = (1 - blend) * ws.ranked_distances[r] + scale * unit_chord[h];
      }
      const int filled = keep_nearest(ws.ranked_blend.data(), nullptr, ranked.size(), keep, best_d, best_id);
      for (int i = 0; i < filled; ++i) {
        best_pq[i] = ws.ranked_distances[best_id[i]];
        best_id[i] = ranked[best_id[i]];
      }
      emit_matches(f, best_d, best_pq, best_id, filled, options, r11, r1m, out);
    } else {
      const int filled = keep_nearest(ws.ranked_distances.data(), ranked.data(), ranked.size(), keep, best_d, best_id);
      emit_matches(f, best_d, best_d, best_id, filled, options, r11, r1m, out);
    }
  }
  out.stats.ms_search = t.elapsed_ms();
  out.stats.ms_total = total.elapsed_ms();
}

}  // namespace visloc
