#include "visloc/pipeline/segment_point_votes.h"

#include <algorithm>

#include "visloc/util/error.h"

namespace visloc {

void SegmentPointVoteOptions::validate() const {
  if (points_per_segment < 0)
    throw_error(ErrorCode::kInvalidArgument, "vote_points (points indexed per segment) must be >= 0 (0: all), got ",
                points_per_segment);
  if (max_hamming < 0 || max_hamming > kHashBits)
    throw_error(ErrorCode::kInvalidArgument, "max_hamming must be in [0, ", kHashBits, "], got ", max_hamming);
  if (max_bucket < 1) throw_error(ErrorCode::kInvalidArgument, "max_bucket must be >= 1, got ", max_bucket);
}

SegmentPointVotes::SegmentPointVotes(const SegmentPointVoteOptions& options) : options_(options) {
  options_.validate();
}

void SegmentPointVotes::add_segment(uint32_t segment, std::span<const HashCode> codes) {
  if (finalized_) throw_error(ErrorCode::kInternal, "SegmentPointVotes: add_segment after finalize");
  const size_t n = codes.size();
  const size_t keep = options_.points_per_segment > 0 ? std::min(n, size_t(options_.points_per_segment)) : n;
  if (codes_.size() + keep > CascadeLookup::kMaxPoints)
    throw_error(ErrorCode::kInvalidArgument, "SegmentPointVotes: more than ", CascadeLookup::kMaxPoints,
                " points; lower points_per_segment");
  for (size_t k = 0; k < keep; ++k) {
    // Evenly strided: point floor(k·n / keep).
    const size_t i = keep == n ? k : static_cast<size_t>((static_cast<unsigned __int128>(k) * n) / keep);
    codes_.push_back(codes[i]);
    segment_of_.push_back(segment);
  }
  max_segment_plus_one_ = std::max(max_segment_plus_one_, segment + 1);
}

void SegmentPointVotes::finalize() {
  lookup_ = CascadeLookup(codes_);
  finalized_ = true;
}

size_t SegmentPointVotes::memory_bytes() const {
  return codes_.capacity() * sizeof(HashCode) + segment_of_.capacity() * sizeof(uint32_t) + lookup_.memory_bytes();
}

namespace {

// The nearest points of one query feature: their distance and the distinct
// segments that hold one at that distance (at most kMaxTies; more are a
// feature seen everywhere, and its vote is split among those kept).
struct NearestSegments {
  static constexpr int kMaxTies = 16;
  uint32_t bound;
  uint32_t distance;
  int count = 0;
  uint32_t segments[kMaxTies];

  explicit NearestSegments(uint32_t max_distance) : bound(max_distance), distance(max_distance) {}
  void offer(uint32_t d, uint32_t segment) {
    if (d > distance || d > bound) return;
    if (d < distance) {
      distance = d;
      count = 0;
    }
    for (int i = 0; i < count; ++i)
      if (segments[i] == segment) return;
    if (count < kMaxTies) segments[count++] = segment;
  }
};

}  // namespace

void SegmentPointVotes::vote(std::span<const HashCode> query, std::vector<float>& scratch,
                             SegmentPointVoteResult& out) const {
  if (!finalized_) throw_error(ErrorCode::kInternal, "SegmentPointVotes: vote before finalize");
  out.segments.clear();
  out.total_votes = 0;
  out.candidates_compared = 0;
  scratch.assign(max_segment_plus_one_, 0.0f);
  const uint32_t bound = static_cast<uint32_t>(options_.max_hamming);
  const uint32_t max_bucket = static_cast<uint32_t>(options_.max_bucket);
  const bool ids16 = lookup_.uses_16bit_ids();
  size_t compared = 0;
  for (const HashCode& q : query) {
    NearestSegments nearest(bound);
    for (int t = 0; t < kHashTables; ++t) {
      uint32_t begin, end;
      lookup_.bucket_range(t, hash_subcode(q, t), begin, end);
      if (end - begin > max_bucket) continue;
      compared += end - begin;
      if (ids16) {
        const uint16_t* ids = lookup_.ids16(t);
        for (uint32_t i = begin; i < end; ++i) nearest.offer(hamming_distance(q, codes_[ids[i]]), segment_of_[ids[i]]);
      } else {
        const uint32_t* ids = lookup_.ids32(t);
        for (uint32_t i = begin; i < end; ++i) nearest.offer(hamming_distance(q, codes_[ids[i]]), segment_of_[ids[i]]);
      }
    }
    if (nearest.count == 0) continue;
    const float share = 1.0f / static_cast<float>(nearest.count);
    for (int i = 0; i < nearest.count; ++i) scratch[nearest.segments[i]] += share;
    out.total_votes += 1.0f;
  }
  out.candidates_compared = compared;
  for (uint32_t s = 0; s < max_segment_plus_one_; ++s)
    if (scratch[s] > 0) out.segments.push_back({s, scratch[s]});
  std::sort(out.segments.begin(), out.segments.end(), [](const SegmentPointVote& a, const SegmentPointVote& b) {
    return a.votes != b.votes ? a.votes > b.votes : a.segment < b.segment;
  });
}

}  // namespace visloc
