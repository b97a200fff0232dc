#include "visloc/matching/cascade_index.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

void CascadeIndexView::validate(const std::string& what) const {
  if (num_points > 0 && (!codes || !pq_codes || !lut_offsets || !lut_ids || !hasher.mean || !hasher.projection))
    throw_error(ErrorCode::kFormat, what, ": cascade index has missing arrays");
  if (num_points >= std::numeric_limits<uint32_t>::max())
    throw_error(ErrorCode::kFormat, what, ": too many points (", num_points, ")");
  for (int k = 0; k < kHashTables; ++k) {
    const uint32_t* off = lut_offsets + k * kLutOffsetsPerTable;
    if (off[0] != 0 || off[kHashBuckets] != num_points)
      throw_error(ErrorCode::kFormat, what, ": lookup table ", k, " offsets do not span 0..", num_points);
    for (uint32_t v = 0; v < kHashBuckets; ++v)
      if (off[v] > off[v + 1]) throw_error(ErrorCode::kFormat, what, ": lookup table ", k, " offsets decrease at ", v);
  }
  for (size_t i = 0; i < size_t(kHashTables) * num_points; ++i)
    if (lut_ids[i] >= num_points) throw_error(ErrorCode::kFormat, what, ": lookup table id out of range at ", i);
}

CascadeTables build_cascade_tables(std::span<const HashCode> codes) {
  const size_t n = codes.size();
  VISLOC_CHECK(n < std::numeric_limits<uint32_t>::max());
  CascadeTables t;
  t.offsets.assign(size_t(kHashTables) * kLutOffsetsPerTable, 0);
  t.ids.resize(size_t(kHashTables) * n);
  for (int k = 0; k < kHashTables; ++k) {
    uint32_t* off = t.offsets.data() + k * kLutOffsetsPerTable;
    for (size_t i = 0; i < n; ++i) ++off[hash_subcode(codes[i], k) + 1];
    for (uint32_t v = 0; v < kHashBuckets; ++v) off[v + 1] += off[v];
    std::vector<uint32_t> fill(off, off + kHashBuckets);
    uint32_t* ids = t.ids.data() + k * n;
    for (size_t i = 0; i < n; ++i) ids[fill[hash_subcode(codes[i], k)]++] = static_cast<uint32_t>(i);
  }
  return t;
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
  if (early_stop < 0)
    throw_error(ErrorCode::kInvalidArgument, "CascadeSearchOptions.early_stop must be >= 0, got ", early_stop);
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

CascadeMatcher::CascadeMatcher(CascadeIndexView index, const PqCodebook& codebook)
    : index_(index), codebook_(&codebook), stamp_(index.num_points, 0), table_(kPqTableSize) {
  VISLOC_CHECK(!codebook.empty());
}

void CascadeMatcher::coarse_sizes(std::span<const HashCode> codes, int radius, std::vector<uint32_t>& sizes) const {
  sizes.resize(codes.size());
  for (size_t f = 0; f < codes.size(); ++f) {
    uint32_t s = 0;
    for (int k = 0; k < kHashTables; ++k) {
      const uint32_t* off = index_.lut_offsets + k * kLutOffsetsPerTable;
      const uint32_t key = hash_subcode(codes[f], k);
      s += off[key + 1] - off[key];
      if (radius == 1)
        for (int b = 0; b < kHashTableBits; ++b) {
          const uint32_t nb = key ^ (1u << b);
          s += off[nb + 1] - off[nb];
        }
    }
    sizes[f] = s;
  }
}

CascadeMatches CascadeMatcher::match(const DescriptorMatrix& queries, const CascadeSearchOptions& options) {
  CascadeMatches out;
  match(queries, options, out);
  return out;
}

void CascadeMatcher::match(const DescriptorMatrix& queries, const CascadeSearchOptions& options, CascadeMatches& out) {
  options.validate();
  out.clear();
  Timer total;
  const size_t nq = queries.rows();
  const size_t np = index_.num_points;
  out.stats.features = nq;
  if (nq == 0 || np == 0) return;

  // 1. Hash every query feature (one GEMM per block).
  Timer t;
  query_codes_.resize(nq);
  encode_hash(index_.hasher, queries.data(), nq, query_codes_.data(), encode_ws_);
  out.stats.ms_hash = t.elapsed_ms();

  // 2. Search order: all features in index order, or by increasing coarse size.
  t.reset();
  coarse_sizes(query_codes_, options.lut_radius, sizes_);
  order_.clear();
  for (size_t f = 0; f < nq; ++f)
    if (sizes_[f] >= 2) order_.push_back((uint64_t(sizes_[f]) << 32) | f);
  if (options.prioritize) std::sort(order_.begin(), order_.end());
  out.stats.ms_order = t.elapsed_ms();

  // 3. Per feature: coarse → refined → precise.
  t.reset();
  const int keep = std::max(options.max_one_to_many, 1) + 1;  // ranks needed by both rules
  std::vector<float> best_d(keep);                              // per query, not per feature
  std::vector<uint32_t> best_id(keep);
  const float r11 = options.ratio_one_to_one * options.ratio_one_to_one;
  const float r1m = options.ratio_one_to_many * options.ratio_one_to_many;
  const size_t early = options.prioritize && options.early_stop > 0 ? size_t(options.early_stop) : SIZE_MAX;
  float qf[kDescriptorDim];
  uint32_t hist[kHashBits + 1];

  for (uint64_t entry : order_) {
    if (out.query.size() >= early) {
      out.stats.early_stopped = true;
      break;
    }
    const uint32_t f = static_cast<uint32_t>(entry & 0xffffffffu);
    const HashCode code = query_codes_[f];
    // Coarse: union of the probed buckets, deduplicated by a per-point stamp.
    if (++stamp_value_ == 0) {  // wrapped: reset the stamps once every 2^32 features
      std::fill(stamp_.begin(), stamp_.end(), 0);
      stamp_value_ = 1;
    }
    const uint32_t s = stamp_value_;
    candidates_.clear();
    for (int k = 0; k < kHashTables; ++k) {
      const uint32_t* off = index_.lut_offsets + k * kLutOffsetsPerTable;
      const uint32_t* ids = index_.lut_ids + k * np;
      const uint32_t key = hash_subcode(code, k);
      const int probes = options.lut_radius == 1 ? kHashTableBits + 1 : 1;
      for (int b = 0; b < probes; ++b) {
        const uint32_t bucket = b == 0 ? key : key ^ (1u << (b - 1));
        for (uint32_t i = off[bucket], e = off[bucket + 1]; i < e; ++i) {
          const uint32_t id = ids[i];
          if (stamp_[id] != s) {
            stamp_[id] = s;
            candidates_.push_back(id);
          }
        }
      }
    }
    out.stats.coarse_candidates += candidates_.size();
    ++out.stats.features_searched;
    if (candidates_.size() < 2) continue;

    // Refined: top L_R by Hamming distance, counting sort over 0..128.
    const std::vector<uint32_t>* ranked = &candidates_;
    if (options.refined && candidates_.size() > size_t(options.refined_list)) {
      hamming_.resize(candidates_.size());
      std::fill(std::begin(hist), std::end(hist), 0u);
      for (size_t i = 0; i < candidates_.size(); ++i) {
        const uint32_t d = hamming_distance(code, index_.codes[candidates_[i]]);
        hamming_[i] = static_cast<uint8_t>(d);
        ++hist[d];
      }
      uint32_t cut = 0, below = 0;  // distances < cut all fit; some of distance == cut
      while (below + hist[cut] < uint32_t(options.refined_list)) below += hist[cut++];
      uint32_t at_cut = uint32_t(options.refined_list) - below;
      shortlist_.clear();
      for (size_t i = 0; i < candidates_.size(); ++i) {
        if (hamming_[i] < cut) shortlist_.push_back(candidates_[i]);
        else if (hamming_[i] == cut && at_cut > 0) {
          shortlist_.push_back(candidates_[i]);
          --at_cut;
        }
      }
      ranked = &shortlist_;
    }
    out.stats.ranked_candidates += ranked->size();

    // Precise: PQ asymmetric distances, the `keep` nearest by insertion.
    const uint8_t* q = queries.row(f);
    for (int j = 0; j < kDescriptorDim; ++j) qf[j] = q[j];
    codebook_->distance_table(qf, table_.data());
    int filled = 0;
    for (uint32_t id : *ranked) {
      const float d = adc_distance(table_.data(), index_.pq_codes + size_t(id) * kPqCodeBytes);
      if (filled == keep && d >= best_d[keep - 1]) continue;
      int pos = filled < keep ? filled++ : keep - 1;
      while (pos > 0 && best_d[pos - 1] > d) {
        best_d[pos] = best_d[pos - 1];
        best_id[pos] = best_id[pos - 1];
        --pos;
      }
      best_d[pos] = d;
      best_id[pos] = id;
    }
    // Ratio tests on squared distances: d0/d1 < ν ⇔ d0² < ν² d1².
    const float d0 = best_d[0], d1 = best_d[1];
    if (d0 < r11 * d1) {
      out.query.push_back(f);
      out.point.push_back(best_id[0]);
      out.distance.push_back(std::sqrt(std::max(0.0f, d0)));
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
        out.many_distances.push_back(std::sqrt(std::max(0.0f, best_d[i])));
      }
      out.many_offsets.push_back(static_cast<uint32_t>(out.many_points.size()));
    }
  }
  out.stats.ms_search = t.elapsed_ms();
  out.stats.ms_total = total.elapsed_ms();
}

}  // namespace visloc
