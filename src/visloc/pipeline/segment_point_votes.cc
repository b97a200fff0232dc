#include "visloc/pipeline/segment_point_votes.h"

#include <algorithm>
#include <concepts>

#include "visloc/util/error.h"

namespace visloc {

void SegmentPointVoteOptions::validate() const {
  if (points_per_segment < 0)
    throw_error(ErrorCode::kInvalidArgument, "vote_points (points indexed per segment) must be >= 0 (0: all), got ",
                points_per_segment);
  if (max_hamming < 0 || max_hamming > kHashBits)
    throw_error(ErrorCode::kInvalidArgument, "max_hamming must be in [0, ", kHashBits, "], got ", max_hamming);
  if (max_bucket < 1) throw_error(ErrorCode::kInvalidArgument, "max_bucket must be >= 1, got ", max_bucket);
  if (max_points > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kInvalidArgument, "vote_max_points must be at most ", CascadeLookup::kMaxPoints,
                " (0: no bound), got ", max_points);
  if (probe_radius < 0 || probe_radius > 1)
    throw_error(ErrorCode::kInvalidArgument, "vote_radius (probe radius) must be 0 or 1, got ", probe_radius);
  if (!(distinct_ratio >= 0.01f && distinct_ratio <= 1))
    throw_error(ErrorCode::kInvalidArgument, "vote_ratio (distinct_ratio) must be in [0.01, 1], got ", distinct_ratio);
}

SegmentPointVotes::SegmentPointVotes(const SegmentPointVoteOptions& options) : options_(options) {
  options_.validate();
}

std::vector<size_t> point_vote_counts(std::span<const size_t> segment_points, const SegmentPointVoteOptions& options) {
  std::vector<size_t> keep(segment_points.begin(), segment_points.end());
  size_t total = 0;
  for (size_t& k : keep) {
    if (options.points_per_segment > 0) k = std::min(k, size_t(options.points_per_segment));
    total += k;
  }
  if (options.max_points > 0 && total > options.max_points)
    for (size_t& k : keep) k = static_cast<size_t>((static_cast<unsigned __int128>(k) * options.max_points) / total);
  return keep;
}

void SegmentPointVotes::add_segment(uint32_t segment, std::span<const HashCode> codes, size_t at_most) {
  if (finalized_) throw_error(ErrorCode::kInternal, "SegmentPointVotes: add_segment after finalize");
  const size_t n = codes.size();
  size_t keep = options_.points_per_segment > 0 ? std::min(n, size_t(options_.points_per_segment)) : n;
  keep = std::min(keep, at_most);
  if (codes_.size() + keep > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kInvalidArgument, "SegmentPointVotes: more than ", CascadeLookup::kMaxPoints,
                " points; lower points_per_segment or max_points (--vote-points, --vote-max-points)");
  for (size_t k = 0; k < keep; ++k) {
    // Evenly strided: point floor(k·n / keep).
    const size_t i = keep == n ? k : static_cast<size_t>((static_cast<unsigned __int128>(k) * n) / keep);
    codes_.push_back(codes[i]);
    segment_of_.push_back(segment);
  }
  max_segment_plus_one_ = std::max(max_segment_plus_one_, segment + 1);
}

void SegmentPointVotes::finalize(const std::vector<std::vector<uint32_t>>& related) {
  codes_.shrink_to_fit();
  segment_of_.shrink_to_fit();
  lookup_ = CascadeLookup(codes_, /*neighbourhood_sizes=*/false);  // votes probe buckets, they do not order by size
  related_.assign(options_.distinct_ratio < 1.0f ? max_segment_plus_one_ : 0, {});
  for (size_t s = 0; s < related.size() && s < related_.size(); ++s) {
    related_[s] = related[s];
    std::sort(related_[s].begin(), related_[s].end());
    related_[s].erase(std::unique(related_[s].begin(), related_[s].end()), related_[s].end());
    related_[s].shrink_to_fit();
  }
  weight_.assign(max_segment_plus_one_, 1.0f);
  if (options_.normalize_by_chance) compute_chance_weights(related);
  finalized_ = true;
}

size_t SegmentPointVotes::memory_bytes() const {
  size_t related_entries = 0;
  for (const auto& r : related_) related_entries += r.capacity();
  return codes_.capacity() * sizeof(HashCode) + segment_of_.capacity() * sizeof(uint32_t) + lookup_.memory_bytes() +
         related_entries * sizeof(uint32_t);
}

bool SegmentPointVotes::related(uint32_t a, uint32_t b) const {
  return a < related_.size() && std::binary_search(related_[a].begin(), related_[a].end(), b);
}

namespace {
// The distinctiveness test, one definition for the test and for the cut that
// bounds which rivals are looked for: the nearest at d0 bits is distinctive
// against a rival at d1 when d0 < ratio × d1 (float arithmetic).
inline bool passes_ratio_test(uint32_t d0, uint32_t d1, float ratio) {
  return static_cast<float>(d0) < ratio * static_cast<float>(d1);
}
}  // namespace

// The nearest points of one query feature: their distance and the distinct
// segments that hold one at that distance (at most kMaxTies; more are a
// feature seen everywhere, and its vote is split among those kept; with the
// distinctiveness test, a tie between unrelated segments is no vote); and,
// for that test, each segment's nearest point within the cut (the
// kMaxSegments nearest segments).
struct SegmentPointVotes::Nearest {
  static constexpr int kMaxTies = 16;
  static constexpr int kMaxSegments = 32;
  uint32_t bound = 0;
  uint32_t distance = 0;
  // Points farther than this need not be offered: the nearest so far; with
  // the distinctiveness test, the farthest rival that could still fail it
  // (rival_cut).
  uint32_t cut = 0;
  bool per_segment = false;
  float ratio = 1;
  int count = 0;
  uint32_t segments[kMaxTies];
  int listed = 0;
  uint32_t listed_segment[kMaxSegments], listed_distance[kMaxSegments];
  // The nearest distance a full list dropped (a segment it could not keep,
  // whose relation to the nearest is then unknown): counted as a rival, so a
  // feature within reach of more than kMaxSegments segments is not
  // distinctive (overlap relates a segment to a few neighbours only).
  uint32_t dropped = UINT32_MAX;
  // Radius 1's candidate ids, reused from feature to feature.
  std::vector<uint32_t> gathered;

  void reset(uint32_t max_distance, float distinct_ratio) {
    bound = distance = cut = max_distance;
    ratio = distinct_ratio;
    per_segment = distinct_ratio < 1.0f;
    count = listed = 0;
    dropped = UINT32_MAX;
  }
  // The farthest rival distance d1 ≤ bound that fails the test at d0, i.e.
  // !passes_ratio_test(d0, d1), the test itself (d1 = d0 always
  // fails it, as ratio ≤ 1): floor(d0 / ratio), stepped to where the float
  // test turns, so no distance that could fail it is cut and none that
  // cannot is probed for.
  uint32_t rival_cut(uint32_t d0) const {
    if (!passes_ratio_test(d0, bound, ratio)) return bound;
    auto fails = [&](uint32_t d1) { return !passes_ratio_test(d0, d1, ratio); };
    uint32_t c = std::max(d0, static_cast<uint32_t>(static_cast<float>(d0) / ratio));
    while (c < bound && fails(c + 1)) ++c;
    while (c > d0 && !fails(c)) --c;
    return c;
  }
  void offer(uint32_t d, uint32_t segment) {
    if (d > bound) return;
    if (per_segment) list(d, segment);
    if (d > distance) return;
    if (d < distance) {
      distance = d;
      count = 0;
      cut = !per_segment ? d : rival_cut(d);
    }
    for (int i = 0; i < count; ++i)
      if (segments[i] == segment) return;
    if (count < kMaxTies) segments[count++] = segment;
  }
  void list(uint32_t d, uint32_t segment) {
    for (int i = 0; i < listed; ++i)
      if (listed_segment[i] == segment) {
        listed_distance[i] = std::min(listed_distance[i], d);
        return;
      }
    if (listed < kMaxSegments) {
      listed_segment[listed] = segment;
      listed_distance[listed++] = d;
      return;
    }
    int farthest = 0;
    for (int i = 1; i < kMaxSegments; ++i)
      if (listed_distance[i] > listed_distance[farthest]) farthest = i;
    if (d < listed_distance[farthest]) {
      dropped = std::min(dropped, listed_distance[farthest]);
      listed_segment[farthest] = segment;
      listed_distance[farthest] = d;
    } else {
      dropped = std::min(dropped, d);
    }
  }
};

bool SegmentPointVotes::distinctive(const Nearest& n) const {
  if (options_.distinct_ratio >= 1.0f) return true;
  // d1: the nearest rival, a point of a segment related to none of the
  // nearest's other segments (ties at d0), nor one of them itself unless the
  // tie is with unrelated segments; none within the bound passes. A dropped
  // entry of a full list may have been a rival.
  bool rival = n.dropped != UINT32_MAX;
  uint32_t d1 = n.dropped;
  for (int i = 0; i < n.listed; ++i) {
    const uint32_t s = n.listed_segment[i];
    bool winner = false, linked = false;
    for (int k = 0; k < n.count; ++k) {
      if (s == n.segments[k])
        winner = true;
      else if (related(n.segments[k], s))
        linked = true;
    }
    if (linked || (winner && n.count == 1) || (rival && n.listed_distance[i] >= d1)) continue;
    rival = true;
    d1 = n.listed_distance[i];
  }
  return !rival || passes_ratio_test(n.distance, d1, options_.distinct_ratio);
}

// VISLOC_POPCNT_CLONES (binary_hasher.h): the Hamming distances' popcount is
// one instruction where the CPU has POPCNT, as in the cascade search.

VISLOC_POPCNT_CLONES
bool SegmentPointVotes::nearest(const HashCode& q, const uint8_t* excluded, Nearest& out, size_t& compared) const {
  out.reset(static_cast<uint32_t>(options_.max_hamming), excluded ? 1.0f : options_.distinct_ratio);
  bool skipped_a_bucket = false;
  for (int t = 0; t < kHashTables; ++t)
    skipped_a_bucket |= !probe_bucket(t, hash_subcode(q, t), q, excluded, out, compared, options_.max_bucket);
  if (options_.probe_radius == 0) return out.count > 0;
  // Radius 1 only when radius 0 may have missed a point that matters: a point
  // within 7 bits shares a sub-code with the feature (pigeonhole over 8
  // tables), so once every exact bucket was read and the cut (the nearest
  // found, the farthest rival that matters to the distinctiveness test, or
  // the bound itself) is under 8 bits, radius 1 can only offer points beyond it.
  if (!skipped_a_bucket && out.cut < static_cast<uint32_t>(kHashTables)) return out.count > 0;
  // Radius 1's 128 buckets in three passes, so that the loads of each pass
  // are independent and the CPU overlaps them (bucket by bucket, each
  // offset, id and code load waited on the one before): the buckets' ranges,
  // their ids prefetched; the ids gathered, their codes prefetched; the
  // codes compared, in the same order as bucket by bucket, so the same
  // points are offered in the same order.
  const uint32_t radius1_max_bucket = static_cast<uint32_t>(std::max(1, options_.max_bucket / 16));
  constexpr int kProbes = kHashTables * kHashTableBits;
  uint32_t begins[kProbes], ends[kProbes];
  uint8_t tables[kProbes];
  int probes = 0;
  const bool ids16 = lookup_.uses_16bit_ids();
  for (int t = 0; t < kHashTables; ++t) {
    const uint32_t key = hash_subcode(q, t);
    for (int bit = 0; bit < kHashTableBits; ++bit) {
      uint32_t begin, end;
      lookup_.bucket_range(t, key ^ (1u << bit), begin, end);
      if (end - begin > radius1_max_bucket || begin == end) continue;
      if (ids16)
        __builtin_prefetch(lookup_.ids16(t) + begin);
      else
        __builtin_prefetch(lookup_.ids32(t) + begin);
      begins[probes] = begin;
      ends[probes] = end;
      tables[probes++] = static_cast<uint8_t>(t);
    }
  }
  std::vector<uint32_t>& gathered = out.gathered;
  gathered.clear();
  for (int k = 0; k < probes; ++k) {
    if (ids16) {
      const uint16_t* ids = lookup_.ids16(tables[k]);
      for (uint32_t i = begins[k]; i < ends[k]; ++i) gathered.push_back(ids[i]);
    } else {
      const uint32_t* ids = lookup_.ids32(tables[k]);
      for (uint32_t i = begins[k]; i < ends[k]; ++i) gathered.push_back(ids[i]);
    }
  }
  for (const uint32_t id : gathered) __builtin_prefetch(&codes_[id]);
  compared += gathered.size();
  const HashCode* codes = codes_.data();
  const uint32_t* segment_of = segment_of_.data();
  for (const uint32_t id : gathered) {
    const uint32_t d = hamming_distance(q, codes[id]);
    if (d > out.cut) continue;
    const uint32_t segment = segment_of[id];
    if (excluded && excluded[segment]) continue;
    out.offer(d, segment);
  }
  return out.count > 0;
}

// A point's segment is read only when its distance could be offered (the
// nearest so far or a tie; within the bound for the distinctiveness test):
// most points of a bucket are farther.
template <typename Id>
inline void offer_bucket(const Id* ids, uint32_t begin, uint32_t end, const HashCode& q, const HashCode* codes,
                         const uint32_t* segment_of, const uint8_t* excluded, const uint32_t& cut,
                         std::invocable<uint32_t, uint32_t> auto&& offer) {
  for (uint32_t i = begin; i < end; ++i) {
    const uint32_t id = ids[i];
    const uint32_t d = hamming_distance(q, codes[id]);
    if (d > cut) continue;
    const uint32_t segment = segment_of[id];
    if (excluded && excluded[segment]) continue;
    offer(d, segment);
  }
}

inline bool SegmentPointVotes::probe_bucket(int table, uint32_t key, const HashCode& q, const uint8_t* excluded,
                                            Nearest& out, size_t& compared, int max_bucket) const {
  uint32_t begin, end;
  lookup_.bucket_range(table, key, begin, end);
  if (end - begin > static_cast<uint32_t>(max_bucket)) return false;
  compared += end - begin;
  auto offer = [&out](uint32_t d, uint32_t segment) { out.offer(d, segment); };
  if (lookup_.uses_16bit_ids())
    offer_bucket(lookup_.ids16(table), begin, end, q, codes_.data(), segment_of_.data(), excluded, out.cut, offer);
  else
    offer_bucket(lookup_.ids32(table), begin, end, q, codes_.data(), segment_of_.data(), excluded, out.cut, offer);
  return true;
}

void SegmentPointVotes::compute_chance_weights(const std::vector<std::vector<uint32_t>>& related) {
  // Pseudo-queries: up to 1,024 indexed points of each segment, evenly strided.
  constexpr size_t kProbesPerSegment = 1024;
  const uint32_t n_segments = max_segment_plus_one_;
  std::vector<std::vector<uint32_t>> members(n_segments);
  for (uint32_t id = 0; id < segment_of_.size(); ++id) members[segment_of_[id]].push_back(id);
  std::vector<double> chance(n_segments, 0.0);
  std::vector<uint8_t> excluded(n_segments, 0);
  Nearest best;
  size_t compared = 0;
  for (uint32_t u = 0; u < n_segments; ++u) {
    const std::vector<uint32_t>& ids = members[u];
    if (ids.empty()) continue;
    std::fill(excluded.begin(), excluded.end(), uint8_t(0));
    excluded[u] = 1;
    if (u < related.size())
      for (uint32_t r : related[u])
        if (r < n_segments) excluded[r] = 1;
    const size_t probes = std::min(ids.size(), kProbesPerSegment);
    for (size_t k = 0; k < probes; ++k) {
      const uint32_t id = ids[k * ids.size() / probes];
      if (!nearest(codes_[id], excluded.data(), best, compared)) continue;
      for (int i = 0; i < best.count; ++i) chance[best.segments[i]] += 1.0 / best.count;
    }
  }
  double sum = 0;
  size_t populated = 0;
  for (uint32_t s = 0; s < n_segments; ++s)
    if (!members[s].empty()) {
      sum += chance[s];
      ++populated;
    }
  const double mean = populated ? sum / double(populated) : 0.0;
  for (uint32_t s = 0; s < n_segments; ++s) {
    if (members[s].empty() || mean <= 0) continue;
    const double rate = std::clamp(chance[s] / mean, 0.25, 4.0);
    weight_[s] = static_cast<float>(1.0 / rate);
  }
}

void SegmentPointVotes::vote(std::span<const HashCode> query, std::vector<float>& scratch,
                             SegmentPointVoteResult& out) const {
  if (!finalized_) throw_error(ErrorCode::kInternal, "SegmentPointVotes: vote before finalize");
  out.segments.clear();
  out.total_votes = 0;
  out.candidates_compared = 0;
  out.feature_offsets.clear();
  out.feature_offsets.reserve(query.size() + 1);
  out.feature_offsets.push_back(0);
  out.feature_segments.clear();
  // scratch: the votes per segment, then the nearest points' shares of every
  // feature, voted or not.
  const size_t n_segments = max_segment_plus_one_;
  scratch.assign(2 * n_segments, 0.0f);
  float* nearest_shares = scratch.data() + n_segments;
  size_t compared = 0;
  Nearest best;
  best.gathered.reserve(4096);  // radius 1's candidates of one feature; grows at most a few times per query
  for (const HashCode& q : query) {
    if (nearest(q, nullptr, best, compared)) {
      out.feature_segments.insert(out.feature_segments.end(), best.segments, best.segments + best.count);
      const float share = 1.0f / static_cast<float>(best.count);
      for (int i = 0; i < best.count; ++i) nearest_shares[best.segments[i]] += share;
      if (distinctive(best)) {
        for (int i = 0; i < best.count; ++i) scratch[best.segments[i]] += share;
        out.total_votes += 1.0f;
      }
    }
    out.feature_offsets.push_back(static_cast<uint32_t>(out.feature_segments.size()));
  }
  out.candidates_compared = compared;
  for (uint32_t s = 0; s < n_segments; ++s)
    if (scratch[s] > 0) out.segments.push_back({s, scratch[s] * weight_[s]});
  const auto by_votes = [](const SegmentPointVote& a, const SegmentPointVote& b) {
    return a.votes != b.votes ? a.votes > b.votes : a.segment < b.segment;
  };
  std::sort(out.segments.begin(), out.segments.end(), by_votes);
  // The segments with nearest points but no vote, ranked by those points'
  // shares (held in `votes` for the sort, then 0).
  const size_t voted = out.segments.size();
  for (uint32_t s = 0; s < n_segments; ++s)
    if (scratch[s] == 0 && nearest_shares[s] > 0) out.segments.push_back({s, nearest_shares[s] * weight_[s]});
  std::sort(out.segments.begin() + static_cast<std::ptrdiff_t>(voted), out.segments.end(), by_votes);
  for (size_t i = voted; i < out.segments.size(); ++i) out.segments[i].votes = 0;
}

}  // namespace visloc
