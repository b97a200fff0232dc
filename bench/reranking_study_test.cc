#include "bench/reranking_study.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <set>
#include <utility>

#include "visloc/baselines/faiss_baselines.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/pq_codebook.h"

using namespace visloc;

namespace {

const int kOneThread = (set_faiss_threads(1), 1);

// SIFT-like descriptors: a mixture of clusters in [0, 255]; the queries are
// noisy copies of points.
DescriptorMatrix clustered(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> centre(0, 110), noise(-35, 35);
  std::vector<std::array<int, kDescriptorDim>> c(24);
  for (auto& a : c)
    for (int& v : a) v = centre(rng);
  DescriptorMatrix d(n);
  for (size_t i = 0; i < n; ++i) {
    const auto& a = c[rng() % c.size()];
    for (int j = 0; j < kDescriptorDim; ++j) d.row(i)[j] = static_cast<uint8_t>(std::clamp(a[j] + noise(rng), 0, 255));
  }
  return d;
}

DescriptorMatrix noisy_copies(const DescriptorMatrix& db, size_t n, uint32_t seed, int amplitude = 12) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> noise(-amplitude, amplitude);
  DescriptorMatrix q(n);
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* p = db.row(rng() % db.rows());
    for (int j = 0; j < kDescriptorDim; ++j) q.row(i)[j] = static_cast<uint8_t>(std::clamp(p[j] + noise(rng), 0, 255));
  }
  return q;
}

std::vector<float> to_float(const DescriptorMatrix& d) { return {d.data(), d.data() + d.size_bytes()}; }

}  // namespace

TEST(RerankingStudy, NearestPassingRatioAtWorkedPoints) {
  auto nearest = [](std::vector<float> d) { return nearest_passing_ratio(d, 0.8f); };
  EXPECT_EQ(nearest({}), -1);
  EXPECT_EQ(nearest({1}), -1);
  EXPECT_EQ(nearest({1, 4}), 0);  // 1 < 0.64 · 4
  EXPECT_EQ(nearest({4, 1}), 1);
  EXPECT_EQ(nearest({2, 3}), -1);        // 2 ≥ 0.64 · 3 = 1.92
  EXPECT_EQ(nearest({1, 1}), -1);        // a tie
  EXPECT_EQ(nearest({5, 1, 1.5f}), -1);  // the second smallest, not the second listed: 1 ≥ 0.96
  EXPECT_EQ(nearest({5, 1, 1.6f}), 1);   // 1 < 1.024
  EXPECT_EQ(nearest_passing_ratio(std::vector<float>{1, 1.0001f}, 1.0f), 0);
}

// The quantizer's distances are the squared distances of the (rotated) query
// to the decoded points, with and without OPQ; the rotation is orthogonal, so
// it keeps the query's length.
TEST(RerankingStudy, FaissDistancesAreThoseToTheDecodedPoints) {
  const DescriptorMatrix db = clustered(3000, 5);
  const std::vector<float> points = to_float(db);
  const DescriptorMatrix queries = noisy_copies(db, 20, 9);
  for (const bool opq : {false, true}) {
    SCOPED_TRACE(opq ? "opq16" : "pq32");
    FaissPqReranker reranker(points.data(), db.rows(), opq ? 16 : 32, opq);
    EXPECT_EQ(reranker.code_bytes(), opq ? 16u : 32u);
    std::vector<uint32_t> ids(50);
    for (uint32_t i = 0; i < ids.size(); ++i) ids[i] = i * 59;
    std::vector<float> d(ids.size()), q(kDescriptorDim), qt(kDescriptorDim), x(kDescriptorDim);
    for (size_t r = 0; r < queries.rows(); ++r) {
      for (int j = 0; j < kDescriptorDim; ++j) q[j] = queries.row(r)[j];
      reranker.distances(q.data(), ids.data(), ids.size(), d.data());
      reranker.transform(q.data(), qt.data());
      double len_q = 0, len_qt = 0;
      for (int j = 0; j < kDescriptorDim; ++j) len_q += q[j] * q[j], len_qt += qt[j] * qt[j];
      EXPECT_NEAR(len_qt, len_q, 1e-4 * len_q);
      for (size_t i = 0; i < ids.size(); ++i) {
        reranker.reconstruct(ids[i], x.data());
        double want = 0;
        for (int j = 0; j < kDescriptorDim; ++j) want += (qt[j] - x[j]) * (qt[j] - x[j]);
        EXPECT_NEAR(d[i], want, 1e-3 * want + 1e-2);
      }
    }
    // Finer codes rank nearer to exact L2 than the 16-byte PQ would: a sanity
    // check that codes and table line up (a scrambled code would not).
    std::vector<float> exact(ids.size());
    for (int j = 0; j < kDescriptorDim; ++j) q[j] = queries.row(0)[j];
    reranker.distances(q.data(), ids.data(), ids.size(), d.data());
    for (size_t i = 0; i < ids.size(); ++i) {
      double s = 0;
      for (int j = 0; j < kDescriptorDim; ++j)
        s += (q[j] - points[ids[i] * kDescriptorDim + j]) * (q[j] - points[ids[i] * kDescriptorDim + j]);
      exact[i] = float(s);
    }
    const auto nearest_exact = std::min_element(exact.begin(), exact.end()) - exact.begin();
    const auto nearest_pq = std::min_element(d.begin(), d.end()) - d.begin();
    EXPECT_EQ(nearest_pq, nearest_exact);
  }
}

// The harness's check: the whole shortlists ranked by the search's own PQ
// distances, through the same ratio test, give exactly the search's 1-1 set,
// at both radii and both L_R.
TEST(RerankingStudy, WholeShortlistsRankedByTheSearchsDistancesRepeatTheSearch) {
  const DescriptorMatrix db = clustered(6000, 3);
  const std::vector<float> f = to_float(db);
  const BinaryHasher hasher = train_itq(f.data(), db.rows(), {.iterations = 10}).hasher;
  const PqCodebook codebook = PqCodebook::train(f.data(), db.rows(), {.iterations = 10});
  std::vector<HashCode> codes(db.rows());
  HashWorkspace hw;
  encode_hash(hasher.view(), db.data(), db.rows(), codes.data(), hw);
  std::vector<uint8_t> pq(db.rows() * kPqCodeBytes);
  codebook.encode(f.data(), db.rows(), pq.data());
  const CascadeLookup lookup(codes);
  const CascadeIndexView view{codes.size(), hasher.view(), codes.data(), pq.data(), &lookup};
  CascadeMatcher matcher(view, codebook);
  // Near copies (clear matches) and far ones (ambiguous: their two nearest
  // are close, so ν decides which features have a 1-M set).
  DescriptorMatrix queries(800);
  const DescriptorMatrix near = noisy_copies(db, 400, 4), far = noisy_copies(db, 400, 8, 60);
  std::copy(near.data(), near.data() + near.size_bytes(), queries.data());
  std::copy(far.data(), far.data() + far.size_bytes(), queries.data() + near.size_bytes());
  for (const int radius : {0, 1})
    for (const int list : {40, 64}) {
      SCOPED_TRACE(testing::Message() << "radius " << radius << ", L_R " << list);
      CascadeSearchOptions search;
      search.lut_radius = radius;
      search.prioritize = false;
      search.refined_list = list;
      const CascadeMatches direct = matcher.match(queries, search);
      const CascadeMatches whole = matcher.match(queries, whole_shortlist_options(list, radius));
      std::set<std::pair<uint32_t, uint32_t>> want, got;
      for (size_t i = 0; i < direct.query.size(); ++i) want.emplace(direct.query[i], direct.point[i]);
      size_t longest = 0;
      for (size_t i = 0; i < whole.many_query.size(); ++i) {
        const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
        longest = std::max<size_t>(longest, end - begin);
        std::vector<float> squared;
        for (uint32_t k = begin; k < end; ++k) squared.push_back(whole.many_distances[k] * whole.many_distances[k]);
        const int best = nearest_passing_ratio(squared, search.ratio_one_to_one);
        if (best >= 0) got.emplace(whole.many_query[i], whole.many_points[begin + best]);
      }
      EXPECT_GT(want.size(), 300u);
      EXPECT_EQ(got, want);
      EXPECT_EQ(longest, size_t(list));  // the whole L_R list, not the top M = 5
      // Every feature whose two nearest differ, not only those within ν = 0.9:
      // a finer ranking may pass the 1-1 test where the search's PQ did not.
      EXPECT_GT(whole.many_query.size(), direct.many_query.size() + 20);
    }
}
