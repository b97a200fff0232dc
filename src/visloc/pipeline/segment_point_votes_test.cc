#include "visloc/pipeline/segment_point_votes.h"

#include <gtest/gtest.h>

#include <bit>
#include <tuple>

#include "visloc/util/error.h"
#include "visloc/util/random.h"

namespace visloc {
namespace {

std::vector<HashCode> random_codes(size_t n, RandomGenerator& rng) {
  std::vector<HashCode> codes(n);
  for (HashCode& c : codes) c = {{rng.next(), rng.next()}};
  return codes;
}

// `code` with `bits` distinct bits flipped.
HashCode flipped(HashCode code, int bits, RandomGenerator& rng) {
  std::vector<uint32_t> order(kHashBits);
  for (uint32_t i = 0; i < order.size(); ++i) order[i] = i;
  shuffle(order.begin(), order.end(), rng);
  for (int k = 0; k < bits; ++k) code.w[order[k] >> 6] ^= uint64_t(1) << (order[k] & 63);
  return code;
}

// `code` with bit `bit` of table `table`'s 16-bit sub-code flipped.
HashCode flip_subcode_bit(HashCode code, int table, int bit) {
  code.w[table / 4] ^= uint64_t(1) << (16 * (table % 4) + bit);
  return code;
}

float votes_of(const SegmentPointVoteResult& r, uint32_t segment) {
  for (const SegmentPointVote& v : r.segments)
    if (v.segment == segment) return v.votes;
  return 0;
}

// An index of segments 0 (`a`) and 1 (`b`), finalized with `related`.
SegmentPointVotes two_segments(const SegmentPointVoteOptions& options, const std::vector<HashCode>& a,
                               const std::vector<HashCode>& b, const std::vector<std::vector<uint32_t>>& related = {}) {
  SegmentPointVotes votes(options);
  votes.add_segment(0, a);
  votes.add_segment(1, b);
  votes.finalize(related);
  return votes;
}

TEST(SegmentPointVotes, QueryFeaturesVoteForTheSegmentOfTheirNearestPoint) {
  RandomGenerator rng(11);
  const std::vector<HashCode> a = random_codes(3000, rng), b = random_codes(5000, rng);
  SegmentPointVotes votes({.points_per_segment = 0});
  votes.add_segment(3, a);
  votes.add_segment(7, b);
  votes.finalize();
  EXPECT_EQ(votes.num_points(), 8000u);
  EXPECT_EQ(votes.num_segments(), 8u);
  EXPECT_GT(votes.memory_bytes(), 8000u * sizeof(HashCode));

  // 300 features seen in segment 3 (≤ 7 bits off: found through some
  // 16-bit table by the pigeonhole principle), 100 in segment 7, 200 that
  // match nothing (random codes: ~64 bits from every point).
  std::vector<HashCode> query;
  for (int i = 0; i < 300; ++i) query.push_back(flipped(a[rng.below(static_cast<uint32_t>(a.size()))], i % 8, rng));
  for (int i = 0; i < 100; ++i) query.push_back(flipped(b[rng.below(static_cast<uint32_t>(b.size()))], i % 8, rng));
  for (const HashCode& c : random_codes(200, rng)) query.push_back(c);

  std::vector<float> scratch;
  SegmentPointVoteResult r;
  votes.vote(query, scratch, r);
  ASSERT_EQ(r.segments.size(), 2u);
  EXPECT_EQ(r.segments[0].segment, 3u);
  EXPECT_FLOAT_EQ(r.segments[0].votes, 300);
  EXPECT_EQ(r.segments[1].segment, 7u);
  EXPECT_FLOAT_EQ(r.segments[1].votes, 100);
  EXPECT_FLOAT_EQ(r.total_votes, 400);
  EXPECT_GT(r.candidates_compared, 0u);
  // Per feature, the segment its vote went to; none for the 200 unmatched.
  ASSERT_EQ(r.feature_offsets.size(), query.size() + 1);
  for (size_t i = 0; i < query.size(); ++i) {
    const std::span<const uint32_t> s = r.segments_of_feature(i);
    if (i < 300) {
      ASSERT_EQ(s.size(), 1u) << i;
      EXPECT_EQ(s[0], 3u);
    } else if (i < 400) {
      ASSERT_EQ(s.size(), 1u) << i;
      EXPECT_EQ(s[0], 7u);
    } else {
      EXPECT_TRUE(s.empty()) << i;
    }
  }

  // The same call again gives the same votes (the scratch is reset).
  SegmentPointVoteResult again;
  votes.vote(query, scratch, again);
  EXPECT_FLOAT_EQ(votes_of(again, 3), 300);
  EXPECT_FLOAT_EQ(again.total_votes, 400);
}

TEST(SegmentPointVotes, FarFeaturesDoNotVoteAndTiesAreSplit) {
  RandomGenerator rng(12);
  const std::vector<HashCode> a = random_codes(1000, rng);
  std::vector<HashCode> b = random_codes(1000, rng);
  b[17] = a[5];  // the same point in two segments (an overlap placemark)
  SegmentPointVotes votes({.points_per_segment = 0, .max_hamming = 32});
  votes.add_segment(0, a);
  votes.add_segment(1, b);
  votes.finalize({{1}, {0}});  // the segments share the placemark's images
  std::vector<float> scratch;
  SegmentPointVoteResult r;

  const HashCode shared[] = {a[5]};
  votes.vote(shared, scratch, r);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 0.5f);
  EXPECT_FLOAT_EQ(votes_of(r, 1), 0.5f);
  EXPECT_FLOAT_EQ(r.total_votes, 1);

  // The same tie between segments that share no image is ambiguous: no vote,
  // and both segments follow the voted ones (none here) with votes 0.
  const SegmentPointVotes unrelated = two_segments({.points_per_segment = 0, .max_hamming = 32}, a, b);
  unrelated.vote(shared, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 0);
  ASSERT_EQ(r.segments.size(), 2u);
  EXPECT_EQ(r.segments[0].segment, 0u);
  EXPECT_EQ(r.segments[1].segment, 1u);
  EXPECT_FLOAT_EQ(r.segments[0].votes, 0);
  EXPECT_FLOAT_EQ(r.segments[1].votes, 0);

  // 40 bits off, with the flips kept out of the first 16-bit sub-code so
  // that the point is still a candidate: beyond max_hamming, no vote.
  HashCode far = a[9];
  for (int bit = 16; bit < 56; ++bit) far.w[bit >> 6] ^= uint64_t(1) << (bit & 63);
  const HashCode far_query[] = {far};
  votes.vote(far_query, scratch, r);
  EXPECT_GT(r.candidates_compared, 0u);
  EXPECT_TRUE(r.segments.empty());
  EXPECT_FLOAT_EQ(r.total_votes, 0);

  SegmentPointVotes strict({.points_per_segment = 0, .max_hamming = 45});
  strict.add_segment(0, a);
  strict.finalize();
  strict.vote(far_query, scratch, r);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 1);
}

// `code` with bits [from, to) flipped (outside table 0's sub-code, bits 0-15,
// the point stays in the feature's table-0 bucket).
HashCode flip_bits(HashCode code, int from, int to) {
  for (int bit = from; bit < to; ++bit) code.w[bit >> 6] ^= uint64_t(1) << (bit & 63);
  return code;
}

TEST(SegmentPointVotes, OnlyDistinctiveFeaturesVote) {
  RandomGenerator rng(13);
  std::vector<HashCode> a = random_codes(500, rng), b = random_codes(500, rng);
  // A facade of segment 0 with a look-alike in segment 1: the feature is 10
  // bits from a[3] and 12 from b[7] (10 < 0.8 × 12 fails), while a[4]'s
  // feature, 4 bits off, has no point of another segment within the bound.
  b[7] = flip_bits(a[3], 100, 102);
  const HashCode look_alike = flip_bits(a[3], 16, 26);
  const HashCode distinct = flip_bits(a[4], 16, 20);
  const HashCode query[] = {look_alike, distinct};
  std::vector<float> scratch;
  SegmentPointVoteResult r;

  const SegmentPointVotes votes = two_segments({.points_per_segment = 0}, a, b);
  EXPECT_FLOAT_EQ(votes.options().distinct_ratio, 0.8f);  // the default
  votes.vote(query, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 1);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 1);
  EXPECT_FLOAT_EQ(votes_of(r, 1), 0);
  // Both features keep their nearest point's segment (the confidence's
  // 'elsewhere' input reads it), voted or not.
  ASSERT_EQ(r.feature_offsets.size(), 3u);
  for (size_t f : {0, 1}) {
    ASSERT_EQ(r.segments_of_feature(f).size(), 1u) << f;
    EXPECT_EQ(r.segments_of_feature(f)[0], 0u) << f;
  }

  // Without the test, the look-alike votes for its nearest point's segment.
  const SegmentPointVotes every = two_segments({.points_per_segment = 0, .distinct_ratio = 1.0f}, a, b);
  every.vote(query, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 2);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 2);

  // Segments that share images may hold the same point: a look-alike there
  // is not a rival (the look-alike's vote is back).
  const SegmentPointVotes overlapping = two_segments({.points_per_segment = 0}, a, b, {{1}, {0}});
  overlapping.vote(query, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 2);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 2);

  // A rival farther by the ratio passes: 10 bits against 13 (10 < 10.4); at
  // the boundary it does not: 8 against 10 (8 < 8 fails).
  b[7] = flip_bits(a[3], 100, 103);
  b[8] = flip_bits(a[6], 100, 102);
  const HashCode boundary = flip_bits(a[6], 16, 24);
  const SegmentPointVotes farther = two_segments({.points_per_segment = 0}, a, b);
  const HashCode farther_query[] = {look_alike}, boundary_query[] = {boundary};
  farther.vote(farther_query, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 1);
  EXPECT_FLOAT_EQ(votes_of(r, 0), 1);
  farther.vote(boundary_query, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 0);

  // A rival that shares no sub-code with the feature (one bit off in each
  // table, 8 bits away) is found by radius 1, which runs because it could
  // still fail the test (7 < 0.8 × 8 fails), though the nearest is 7 bits off.
  const HashCode q = a[9];
  HashCode seven = q, eight = q;
  for (int table = 0; table < 7; ++table) seven = flip_subcode_bit(seven, table, 4);
  for (int table = 0; table < 8; ++table) eight = flip_subcode_bit(eight, table, 9);
  const HashCode radius_query[] = {q};
  for (int radius : {0, 1}) {
    SegmentPointVotes by_radius({.points_per_segment = 0, .probe_radius = radius});
    by_radius.add_segment(0, std::vector<HashCode>{seven});
    by_radius.add_segment(1, std::vector<HashCode>{eight});
    by_radius.finalize();
    by_radius.vote(radius_query, scratch, r);
    EXPECT_FLOAT_EQ(r.total_votes, radius == 0 ? 1.0f : 0.0f) << radius;
  }

  // A feature within reach of more segments than its list keeps (32) is not
  // distinctive, even when they all overlap one another (the dropped ones'
  // relations are unknown): 32 such segments at 6 bits still vote, split;
  // 40 give no vote.
  const HashCode six = flip_bits(q, 16, 22);
  for (uint32_t n : {32u, 40u}) {
    SegmentPointVotes crowded({.points_per_segment = 0});
    std::vector<std::vector<uint32_t>> related(n);
    for (uint32_t s = 0; s < n; ++s) {
      crowded.add_segment(s, std::vector<HashCode>{six});
      for (uint32_t t = 0; t < n; ++t)
        if (t != s) related[s].push_back(t);
    }
    crowded.finalize(related);
    crowded.vote(radius_query, scratch, r);
    EXPECT_FLOAT_EQ(r.total_votes, n == 32 ? 1.0f : 0.0f) << n;
  }

  EXPECT_THROW(SegmentPointVotes({.distinct_ratio = 0.0f}), Error);
  EXPECT_THROW(SegmentPointVotes({.distinct_ratio = 1.5f}), Error);
}

// The test's boundary at every ratio, in its own float arithmetic: a
// feature d0 bits from segment 0's point and d1 from segment 1's (unrelated)
// votes, for the nearer one, exactly when min < ratio × max. The rival is
// placed two ways: inside one sub-code (found at radius 0) and one bit off
// in every sub-code, plus more in some (found only at radius 1, which the
// search must decide to run), so a rival cut one bit too tight or a skipped
// radius 1 shows here.
TEST(SegmentPointVotes, DistinctivenessBoundaryAtEveryRatio) {
  RandomGenerator rng(17);
  const HashCode q = random_codes(1, rng)[0];
  const HashCode query[] = {q};
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  int checked = 0, voted = 0;  // below ratio 1
  for (float ratio : {0.5f, 0.6f, 0.7f, 0.75f, 0.8f, 0.9f, 0.95f, 1.0f}) {
    for (int d0 = 1; d0 <= 12; ++d0) {
      for (int d1 = 1; d1 <= 20; ++d1) {
        for (bool spread : {false, true}) {
          if (spread && (d1 < 8 || d1 > 15)) continue;
          HashCode rival = q;
          if (spread) {
            for (int table = 0; table < 8; ++table) rival = flip_subcode_bit(rival, table, 3);
            for (int table = 0; table < d1 - 8; ++table) rival = flip_subcode_bit(rival, table, 11);
          } else {
            rival = flip_bits(q, 64, 64 + d1);  // sub-codes 4 and 5 only
          }
          const HashCode nearest = flip_bits(q, 16, 16 + d0);  // sub-code 1 only
          ASSERT_EQ(hamming_distance(rival, q), uint32_t(d1));
          ASSERT_EQ(hamming_distance(nearest, q), uint32_t(d0));
          const SegmentPointVotes votes = two_segments({.points_per_segment = 0, .distinct_ratio = ratio},
                                                       std::vector<HashCode>{nearest}, std::vector<HashCode>{rival});
          votes.vote(query, scratch, r);
          const int lo = std::min(d0, d1), hi = std::max(d0, d1);
          const bool expect = static_cast<float>(lo) < ratio * static_cast<float>(hi);
          const uint32_t winner = d0 < d1 ? 0u : 1u;
          SCOPED_TRACE(::testing::Message()
                       << "ratio " << ratio << ", d0 " << d0 << ", d1 " << d1 << (spread ? ", spread" : ""));
          if (ratio >= 1.0f) {  // every feature votes for its nearest; a tie is split
            EXPECT_FLOAT_EQ(r.total_votes, 1);
            EXPECT_FLOAT_EQ(votes_of(r, winner), d0 == d1 ? 0.5f : 1.0f);
            continue;
          }
          EXPECT_FLOAT_EQ(r.total_votes, expect ? 1.0f : 0.0f);
          if (expect) EXPECT_FLOAT_EQ(votes_of(r, winner), 1);
          voted += expect;
          ++checked;
        }
      }
    }
  }
  EXPECT_GT(voted, 100);  // both outcomes are exercised
  EXPECT_LT(voted, checked - 100);
  // The predicate itself at a few worked points: 3 < 0.6 × 5 = 3 fails,
  // 3 < 0.6 × 6 = 3.6 passes; 9 < 0.75 × 12 = 9 fails, 9 < 0.75 × 13 passes.
  for (auto [ratio, d0, d1, votes_expected] :
       {std::tuple{0.6f, 3, 5, false}, {0.6f, 3, 6, true}, {0.75f, 9, 12, false}, {0.75f, 9, 13, true}}) {
    const SegmentPointVotes votes = two_segments({.points_per_segment = 0, .distinct_ratio = ratio},
                                                 std::vector<HashCode>{flip_bits(q, 16, 16 + d0)},
                                                 std::vector<HashCode>{flip_bits(q, 64, 64 + d1)});
    votes.vote(query, scratch, r);
    EXPECT_FLOAT_EQ(r.total_votes, votes_expected ? 1.0f : 0.0f) << ratio << " " << d0 << " " << d1;
  }
}

TEST(SegmentPointVotes, RadiusOneFindsPointsThatDifferInEverySubCode) {
  RandomGenerator rng(29);
  const std::vector<HashCode> a = random_codes(1000, rng);
  // One bit off in each of the 8 sub-codes: no bucket of radius 0 holds a[7].
  HashCode q = a[7];
  for (int table = 0; table < kHashTables; ++table) q.w[table / 4] ^= uint64_t(1) << (16 * (table % 4) + 3);
  const HashCode query[] = {q};
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  for (int radius : {0, 1}) {
    SegmentPointVotes votes({.points_per_segment = 0, .probe_radius = radius});
    votes.add_segment(2, a);
    votes.finalize();
    votes.vote(query, scratch, r);
    EXPECT_FLOAT_EQ(votes_of(r, 2), radius == 0 ? 0.0f : 1.0f) << radius;
  }
  // A feature within 7 bits of a point: radius 0 has found its nearest (every
  // point that near shares a sub-code), and radius 1 probes nothing more. A
  // far point sits in one of the feature's radius-1 buckets (table 1's
  // sub-code 1 bit off, every other bit complemented), so radius 1 would
  // compare it, and only it, if it ran.
  HashCode near = a[9];
  near.w[0] ^= 0x5;
  HashCode far = {{~near.w[0], ~near.w[1]}};
  far.w[0] = (far.w[0] & ~(uint64_t(0xFFFF) << 16)) | (near.w[0] & (uint64_t(0xFFFF) << 16));
  far = flip_subcode_bit(far, 1, 0);
  const std::vector<HashCode> two_points = {a[9], far};
  // The same at 6 bits with the distinctiveness test (0.8): a rival fails it
  // only within 7 bits (6 < 0.8 × 7 fails, 6 < 0.8 × 8 passes), within
  // radius 0's reach, so radius 1 is still not run.
  HashCode six = a[9];
  six.w[0] ^= 0x3F;
  for (const HashCode& feature : {near, six}) {
    const HashCode feature_query[] = {feature};
    size_t compared[2] = {0, 0};
    for (int radius : {0, 1}) {
      SegmentPointVotes votes({.points_per_segment = 0, .probe_radius = radius});
      votes.add_segment(2, two_points);
      votes.finalize();
      votes.vote(feature_query, scratch, r);
      EXPECT_FLOAT_EQ(votes_of(r, 2), 1.0f);
      compared[radius] = r.candidates_compared;
    }
    EXPECT_EQ(compared[0], 7u);  // a[9], in the 7 tables whose sub-code the flipped bits left intact
    EXPECT_EQ(compared[1], compared[0]);
  }
  // 8 bits from a[9] (it shares only table 1's sub-code), radius 1 runs and compares `far` too.
  HashCode farther = near;
  for (int table = 2; table < kHashTables; ++table) farther = flip_subcode_bit(farther, table, 5);
  const HashCode farther_query[] = {farther};
  SegmentPointVotes radius1({.points_per_segment = 0, .probe_radius = 1});
  radius1.add_segment(2, two_points);
  radius1.finalize();
  radius1.vote(farther_query, scratch, r);
  EXPECT_FLOAT_EQ(votes_of(r, 2), 1.0f);
  // a[9] in table 1 and in the radius-1 buckets of tables 2-7 (6), `far` in one of table 1.
  EXPECT_EQ(r.candidates_compared, 8u);
}

// More than 65,536 points: the lookup's 32-bit ids, radius 1's gathered
// path. Every query is a point with one bit off in each sub-code (8 bits),
// so radius 1 runs and finds it; the candidates compared are those of the
// plain definition, every point in the query's exact and one-bit-off buckets.
TEST(SegmentPointVotes, RadiusOneOnAMapOfMoreThan65536Points) {
  RandomGenerator rng(31);
  const std::vector<HashCode> a = random_codes(70000, rng);
  SegmentPointVotes votes({.points_per_segment = 0, .max_points = 0, .distinct_ratio = 1.0f});
  constexpr size_t kSegments = 4, kPerSegment = 17500;
  for (size_t s = 0; s < kSegments; ++s)
    votes.add_segment(static_cast<uint32_t>(s), std::span(a).subspan(s * kPerSegment, kPerSegment));
  votes.finalize();
  ASSERT_EQ(votes.num_points(), a.size());
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  for (size_t i = 11; i < a.size(); i += 2917) {
    HashCode q = a[i];
    for (int table = 0; table < kHashTables; ++table) q = flip_subcode_bit(q, table, (table * 5 + int(i)) % 16);
    const HashCode query[] = {q};
    votes.vote(query, scratch, r);
    EXPECT_FLOAT_EQ(votes_of(r, static_cast<uint32_t>(i / kPerSegment)), 1.0f) << i;
    size_t expected = 0;
    for (const HashCode& p : a)
      for (int table = 0; table < kHashTables; ++table) {
        const uint32_t diff = hash_subcode(p, table) ^ hash_subcode(q, table);
        expected += std::popcount(diff) <= 1;
      }
    EXPECT_EQ(r.candidates_compared, expected) << i;
  }
}

TEST(SegmentPointVotes, RadiusOneStillRunsWhenAnExactBucketWasSkipped) {
  // q's nearest points, both 7 bits away: `one` (segment 1) shares only
  // table 7's sub-code with q, `two` (segment 2) only table 0's, whose bucket
  // is overfull (60 fillers share it). Radius 0 finds `one` within 7 bits, but
  // having skipped a bucket it cannot know it found every nearest point;
  // radius 1 finds `two` in table 1 (1 bit off) and the vote is split.
  RandomGenerator rng(31);
  const HashCode q = random_codes(1, rng)[0];
  HashCode one = q, two = q;
  for (int table = 0; table < 7; ++table) one = flip_subcode_bit(one, table, 2);
  for (int table = 1; table < 8; ++table) two = flip_subcode_bit(two, table, 2);
  std::vector<HashCode> fillers = random_codes(60, rng);
  for (HashCode& f : fillers) f.w[0] = (f.w[0] & ~uint64_t(0xFFFF)) | (q.w[0] & 0xFFFF);
  std::vector<HashCode> segment2 = fillers;
  segment2.push_back(two);
  const HashCode query[] = {q};
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  for (int radius : {0, 1}) {
    // (Segments 1 and 2 share no image: the distinctiveness test would turn
    // their tie into no vote; this test is about the probing.)
    SegmentPointVotes votes({.points_per_segment = 0, .max_bucket = 50, .probe_radius = radius, .distinct_ratio = 1});
    votes.add_segment(1, std::vector<HashCode>{one});
    votes.add_segment(2, segment2);
    votes.finalize();
    votes.vote(query, scratch, r);
    EXPECT_FLOAT_EQ(votes_of(r, 1), radius == 0 ? 1.0f : 0.5f) << radius;
    EXPECT_FLOAT_EQ(votes_of(r, 2), radius == 0 ? 0.0f : 0.5f) << radius;
  }
}

TEST(SegmentPointVotes, KeepsAnEvenStrideOfEachSegmentsPoints) {
  RandomGenerator rng(13);
  const std::vector<HashCode> a = random_codes(100, rng);
  SegmentPointVotes votes({.points_per_segment = 10});
  votes.add_segment(0, a);
  votes.finalize();
  EXPECT_EQ(votes.num_points(), 10u);
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  const HashCode kept[] = {a[0], a[10], a[90]};
  votes.vote(kept, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 3);
  const HashCode dropped[] = {a[5], a[55]};
  votes.vote(dropped, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 0);
}

TEST(SegmentPointVotes, IndexesEveryPointUpToTheMapsBound) {
  const std::vector<size_t> points = {1000, 3000, 0, 6000};
  SegmentPointVoteOptions all;  // the defaults: every point, up to 262,144 over the map
  EXPECT_EQ(point_vote_counts(points, all), points);
  SegmentPointVoteOptions bounded{.points_per_segment = 0, .max_points = 5000};
  EXPECT_EQ(point_vote_counts(points, bounded), (std::vector<size_t>{500, 1500, 0, 3000}));  // each its share
  SegmentPointVoteOptions both{.points_per_segment = 2000, .max_points = 2500};  // 1000 + 2000 + 2000 capped
  EXPECT_EQ(point_vote_counts(points, both), (std::vector<size_t>{500, 1000, 0, 1000}));
  SegmentPointVoteOptions unbounded{.points_per_segment = 0, .max_points = 0};
  EXPECT_EQ(point_vote_counts(points, unbounded), points);
  // add_segment keeps an even stride of at most `at_most` points.
  RandomGenerator rng(17);
  const std::vector<HashCode> a = random_codes(100, rng);
  SegmentPointVotes votes(bounded);
  votes.add_segment(0, a, 20);
  votes.finalize();
  EXPECT_EQ(votes.num_points(), 20u);
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  const HashCode kept[] = {a[0], a[5], a[95]};
  votes.vote(kept, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 3);
  const HashCode dropped[] = {a[3], a[51]};
  votes.vote(dropped, scratch, r);
  EXPECT_FLOAT_EQ(r.total_votes, 0);
}

TEST(SegmentPointVotes, SkipsOverfullBuckets) {
  // 50 copies of one code fill one bucket of every table.
  std::vector<HashCode> same(50, HashCode{{0x0123456789ABCDEFull, 0xFEDCBA9876543210ull}});
  SegmentPointVotes capped({.points_per_segment = 0, .max_bucket = 49});
  capped.add_segment(0, same);
  capped.finalize();
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  const HashCode query[] = {same[0]};
  capped.vote(query, scratch, r);
  EXPECT_EQ(r.candidates_compared, 0u);
  EXPECT_FLOAT_EQ(r.total_votes, 0);

  SegmentPointVotes open({.points_per_segment = 0, .max_bucket = 50});
  open.add_segment(0, same);
  open.finalize();
  open.vote(query, scratch, r);
  EXPECT_EQ(r.candidates_compared, 8u * 50u);
  EXPECT_FLOAT_EQ(r.total_votes, 1);

  // Radius 1's buckets (16 per table) get a sixteenth of the bound each: a
  // feature one bit off in every sub-code finds the 50 points only when
  // max_bucket / 16 ≥ 50.
  HashCode off = same[0];
  for (int table = 0; table < kHashTables; ++table) off.w[table / 4] ^= uint64_t(1) << (16 * (table % 4));
  const HashCode off_query[] = {off};
  for (int bound : {799, 800}) {
    SegmentPointVotes radius1({.points_per_segment = 0, .max_bucket = bound, .probe_radius = 1});
    radius1.add_segment(0, same);
    radius1.finalize();
    radius1.vote(off_query, scratch, r);
    EXPECT_FLOAT_EQ(r.total_votes, bound == 800 ? 1.0f : 0.0f) << bound;
  }
}

TEST(SegmentPointVotes, ChanceNormalizationDiscountsAHubSegment) {
  // Segments 1-3 hold random codes; segment 0 (a hub) holds near copies of a
  // third of each of theirs (bits 3 and 70 flipped), so their points find it
  // when their own segment is left out.
  RandomGenerator rng(14);
  std::vector<std::vector<HashCode>> segments = {
      {}, random_codes(900, rng), random_codes(900, rng), random_codes(900, rng)};
  const auto flip = [](HashCode c, int bit) {
    c.w[bit >> 6] ^= uint64_t(1) << (bit & 63);
    return c;
  };
  for (int s = 1; s < 4; ++s)
    for (size_t i = 0; i < 900; i += 3) segments[0].push_back(flip(flip(segments[s][i], 3), 70));
  const auto build = [&](bool normalize, const std::vector<std::vector<uint32_t>>& related) {
    // (The queries tie between unrelated segments, which the distinctiveness
    // test would turn into no vote; this test is about the weights.)
    SegmentPointVotes votes({.points_per_segment = 0, .normalize_by_chance = normalize, .distinct_ratio = 1});
    for (uint32_t s = 0; s < 4; ++s) votes.add_segment(s, segments[s]);
    votes.finalize(related);
    return votes;
  };
  // Queries 1 bit from a point of segment 1 and 1 bit from its hub copy.
  std::vector<HashCode> query;
  for (size_t i = 0; i < 900; i += 3) query.push_back(flip(segments[1][i], 3));
  std::vector<float> scratch;
  SegmentPointVoteResult r;

  const SegmentPointVotes plain = build(false, {});
  for (float w : plain.segment_weights()) EXPECT_EQ(w, 1.0f);
  plain.vote(query, scratch, r);
  ASSERT_EQ(r.segments.size(), 2u);
  EXPECT_EQ(r.segments[0].segment, 0u);  // a tie, the lower id first: the hub
  EXPECT_FLOAT_EQ(r.segments[0].votes, 150);
  EXPECT_FLOAT_EQ(r.segments[1].votes, 150);

  const SegmentPointVotes normalized = build(true, {});
  const std::vector<float>& w = normalized.segment_weights();
  ASSERT_EQ(w.size(), 4u);
  EXPECT_LE(w[0], 0.5f);  // 900 chance votes against 300 for each other segment
  for (int s = 1; s < 4; ++s) EXPECT_GT(w[s], 1.0f) << s;
  normalized.vote(query, scratch, r);
  ASSERT_EQ(r.segments.size(), 2u);
  EXPECT_EQ(r.segments[0].segment, 1u);
  EXPECT_FLOAT_EQ(r.segments[0].votes, 150 * w[1]);
  EXPECT_FLOAT_EQ(r.total_votes, 300);

  // Related segments (sharing images) do not count as chance: with the hub
  // and segment 1 related, segment 1 receives no chance vote (its rate is
  // clamped at 1/4: weight 4) and the hub's come from segments 2 and 3 only.
  const SegmentPointVotes related = build(true, {{1}, {0}, {}, {}});
  EXPECT_FLOAT_EQ(related.segment_weights()[1], 4.0f);
  EXPECT_FLOAT_EQ(w[1], 1.5f);  // unrelated: 300 chance votes, the mean 450
}

TEST(SegmentPointVotes, RejectsBadOptionsAndMisuse) {
  EXPECT_THROW(SegmentPointVotes({.points_per_segment = -1}), Error);
  EXPECT_THROW(SegmentPointVotes({.max_hamming = 129}), Error);
  EXPECT_THROW(SegmentPointVotes({.max_hamming = -1}), Error);
  EXPECT_THROW(SegmentPointVotes({.max_bucket = 0}), Error);
  EXPECT_THROW(SegmentPointVotes({.probe_radius = 2}), Error);
  EXPECT_THROW(SegmentPointVotes({.probe_radius = -1}), Error);
  SegmentPointVotes votes;
  std::vector<float> scratch;
  SegmentPointVoteResult r;
  EXPECT_THROW(votes.vote({}, scratch, r), Error);
  votes.finalize();
  EXPECT_THROW(votes.add_segment(0, {}), Error);
  votes.vote({}, scratch, r);
  EXPECT_TRUE(r.segments.empty());
}

}  // namespace
}  // namespace visloc
