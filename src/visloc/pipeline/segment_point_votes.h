// Candidate segments from the query's local features (issue #13): every
// query feature looks up its nearest map point among all segments by the
// hash codes that the map's one ITQ rotation makes comparable across
// segments, and votes for that point's segment.
//
// Why: the global image descriptors (T-embedding, VLAD) top out at ~0.86 of
// queries with a correct segment among 4 candidates on the synthetic city,
// whatever N_t or the descriptor (session-4 measurement, `bench retrieval`);
// searching all segments registered most of the misses. Local features keep
// the evidence that a global descriptor averages away.
//
// Index: the hash codes of every point of every segment, up to max_points
// over the map (each segment its share beyond, evenly strided; ~65 B per
// point with the segment ids and the lookup tables), one CascadeLookup over
// all of them (the 8 lookup tables of 16-bit sub-codes, as the cascade's
// coarse step).
//
// Vote of one query feature: among the points whose sub-code equals one of
// its 8 sub-codes (radius 0) or, with probe_radius 1, differs from it in one
// bit (16 more buckets per table, probed only when radius 0 found no point
// within 7 bits, or skipped an overfull bucket: every point that near shares a
// sub-code with the feature, by the pigeonhole principle, so radius 0 has then
// found the nearest), the
// nearest by Hamming distance d0 on the 128 bits. Why radius 1: a query
// photographed by another camera differs from the map's descriptors in ~10-25
// bits, and at 20 bits a 16-bit sub-code is intact with probability
// (1 - 20/128)^16 ≈ 0.07 per table, against ≈ 0.26 for "at most one bit off".
// Each of radius 1's 16 buckets per table is skipped above max(1,
// max_bucket / 16) points, so that they cost at most what the exact bucket may.
// When d0 ≤ max_hamming it gives one vote, split equally among the distinct
// segments that hold a point at d0. The bound comes from the null
// distribution, not from data: two unrelated codes differ in ~Binomial(128,
// ½) bits (mean 64, σ 5.7); a candidate already shares 16 bits, so the other
// 112 differ by 56 ± 5.3; d0 ≤ 32 is 4.5 σ below that, while matching SIFT
// descriptors differ by ~10-25 bits under ITQ.
// Buckets larger than `max_bucket` points are skipped: such a sub-code is
// shared by a large part of the map and says little, and it would dominate
// the time.
//
// Distinctive votes only (`distinct_ratio`, Lowe's ratio test across
// segments): a feature votes only when its nearest point, at d0 bits, is
// clearly nearer than the nearest point, at d1, of every segment unrelated to
// the nearest's (sharing no image with it: overlapping segments hold the same
// physical points), d0 < distinct_ratio × d1; a tie between unrelated
// segments is no vote, and a feature with no rival within max_hamming votes.
// Rivals are found in the probed buckets: at radius 0 those that share a
// sub-code with the feature (every point within 7 bits), at radius 1, which
// then runs whenever a rival within reach could still fail the test, also
// those within 15 bits. A facade that
// looks like those of other streets (windows, doors, generic texture) gives
// near-equal distances in several unrelated segments and no vote, where it
// gave one to whichever happened to be nearest: votes that make the ranking
// of a query with few distinctive features a lottery.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/cascade_index.h"

namespace visloc {

struct SegmentPointVoteOptions {
  // Points indexed per segment (0: all, the default) and over the whole map
  // (0: no bound): a map of more points indexes each segment's share of
  // max_points, evenly strided (point_vote_counts). Every point votes where
  // the memory allows: indexing all points rather than 8,192 per segment put
  // the true segment among the first 4 candidates for 378 against 375 of 384
  // positives on the 13-segment city of `bench city --grid-blocks-x 3`
  // (190,488 points) and 259 against 255 of 261 on a city of copied
  // buildings (99,436 points), registrations unchanged but one (`bench city`
  // beside a CI build, session 37). 262,144 points take about 16 MiB (65
  // bytes each), a sixteenth of the city benchmark's 256 MiB budget.
  int points_per_segment = 0;
  size_t max_points = size_t(1) << 18;
  int max_hamming = 32;           // a vote needs a point at most this far (bits of 128)
  int max_bucket = 4096;          // buckets with more points are not probed (radius 1's: max(1, max_bucket / 16))
  // Per table, the feature's sub-code's bucket (0), also the 16 1 bit off (1).
  // 1 by default: on the 13-segment city it puts the true segment
  // among the candidates for 95.4% of positives against 93.3% and registers
  // 474/495 against 465, for 28 ms per query against 11 (excluding features).
  int probe_radius = 1;
  // Divide each segment's votes by its rate of chance votes: how often the
  // points of unrelated segments (sharing no image with it) find their
  // nearest point in it, relative to the mean over segments, clamped to
  // [1/4, 4]. A segment whose codes are near everything (a hub) otherwise
  // collects votes from every query.
  bool normalize_by_chance = false;
  // A vote needs d0 < distinct_ratio × d1 (above); 1: every feature with a
  // point within max_hamming votes (as before). 0.8 is the 1-1 ratio of the
  // cascade search (ν_h, Lowe's), not fitted here.
  float distinct_ratio = 0.8f;
  void validate() const;          // throws Error(kInvalidArgument) naming the field
};

struct SegmentPointVote {
  uint32_t segment = 0;  // as given to add_segment (e.g. a manifest position)
  float votes = 0;
};

struct SegmentPointVoteResult {
  // Every segment with a vote, most votes first (ties: lower id); then, with
  // votes 0, those where only features that were not distinctive had their
  // nearest point, most such features first (so that they can still be
  // candidates after the voted ones).
  std::vector<SegmentPointVote> segments;
  float total_votes = 0;                   // query features that voted
  size_t candidates_compared = 0;          // Hamming distances computed
  // Per query feature i, the segments of its nearest points (the ties at the
  // nearest distance), where its vote went if it was distinctive:
  // feature_segments[feature_offsets[i] .. feature_offsets[i + 1]), empty
  // when no point is within max_hamming. For the confidence's "elsewhere"
  // input (confidence.h): a pose's inlier whose feature's nearest map point
  // lies in an unrelated segment (a copied building: such a feature is
  // seldom distinctive, so the nearest is kept whether or not it voted).
  std::vector<uint32_t> feature_offsets;
  std::vector<uint32_t> feature_segments;
  std::span<const uint32_t> segments_of_feature(size_t i) const {
    return {feature_segments.data() + feature_offsets[i], feature_segments.data() + feature_offsets[i + 1]};
  }
};

// How many points of each segment to index (for add_segment's `at_most`):
// min(points, points_per_segment) each, scaled down in proportion (floor)
// when their sum exceeds max_points.
std::vector<size_t> point_vote_counts(std::span<const size_t> segment_points, const SegmentPointVoteOptions& options);

class SegmentPointVotes {
 public:
  explicit SegmentPointVotes(const SegmentPointVoteOptions& options = {});
  // Adds a segment's point codes (subsampled to points_per_segment and to
  // `at_most`, evenly strided). Call finalize() once every segment is added;
  // segment ids need not be dense.
  void add_segment(uint32_t segment, std::span<const HashCode> codes, size_t at_most = SIZE_MAX);
  // `related[s]`: segments that may hold the same physical points as s (they
  // share images): left out of s's chance votes (normalize_by_chance) and of
  // the distinctiveness test's d1 for a feature nearest to s.
  void finalize(const std::vector<std::vector<uint32_t>>& related = {});
  // Per segment: the factor its votes are multiplied by (1 without normalization).
  const std::vector<float>& segment_weights() const { return weight_; }

  // Votes of a query hashed with the map's rotation. `scratch` is reused
  // across calls (one per thread); `out`'s vectors are reused too.
  void vote(std::span<const HashCode> query, std::vector<float>& scratch, SegmentPointVoteResult& out) const;

  size_t num_points() const { return codes_.size(); }
  size_t num_segments() const { return max_segment_plus_one_; }
  size_t memory_bytes() const;
  const SegmentPointVoteOptions& options() const { return options_; }

 private:
  SegmentPointVoteOptions options_;
  std::vector<HashCode> codes_;
  std::vector<uint32_t> segment_of_;
  uint32_t max_segment_plus_one_ = 0;
  CascadeLookup lookup_;
  std::vector<float> weight_;
  std::vector<std::vector<uint32_t>> related_;  // per segment, sorted
  // The nearest indexed points' distance and segments (ties) of one code, and
  // each segment's nearest within max_hamming, skipping segments with
  // excluded[s] != 0 (null: none); false when none is within max_hamming.
  struct Nearest;
  bool nearest(const HashCode& q, const uint8_t* excluded, Nearest& out, size_t& compared) const;
  // Offers the points of bucket `key` of `table`; false (nothing offered) when
  // it holds more than max_bucket points.
  inline bool probe_bucket(int table, uint32_t key, const HashCode& q, const uint8_t* excluded, Nearest& out,
                           size_t& compared, int max_bucket) const;
  // Whether the nearest point of `n` is distinctive (distinct_ratio).
  bool distinctive(const Nearest& n) const;
  bool related(uint32_t a, uint32_t b) const;
  void compute_chance_weights(const std::vector<std::vector<uint32_t>>& related);
  bool finalized_ = false;
};

}  // namespace visloc
