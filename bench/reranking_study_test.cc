#include "bench/reranking_study.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <string_view>
#include <tuple>
#include <utility>

#include "visloc/baselines/faiss_baselines.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/hamming_blend.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/util/error.h"
#include "visloc/util/test_support.h"

using namespace visloc;

namespace {

const int kOneThread = (set_faiss_threads(1), 1);

// SIFT-like descriptors: a mixture of clusters in [0, 255].
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

// Noisy copies of random points: rows `first`.. of `out`, their sources into `sources`.
void add_noisy_copies(const DescriptorMatrix& db, size_t first, size_t n, uint32_t seed, int amplitude,
                      DescriptorMatrix& out, std::vector<uint32_t>& sources) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> noise(-amplitude, amplitude);
  for (size_t i = 0; i < n; ++i) {
    const auto source = static_cast<uint32_t>(rng() % db.rows());
    sources.push_back(source);
    for (int j = 0; j < kDescriptorDim; ++j)
      out.row(first + i)[j] = static_cast<uint8_t>(std::clamp(db.row(source)[j] + noise(rng), 0, 255));
  }
}

std::vector<float> to_float(const DescriptorMatrix& d) { return {d.data(), d.data() + d.size_bytes()}; }

// A segment's search over clustered points, and queries: 400 near copies
// (clear matches) then 400 far ones (ambiguous: their two nearest are close).
struct SearchFixture {
  DescriptorMatrix db = clustered(6000, 3);
  BinaryHasher hasher;
  PqCodebook codebook;
  std::vector<HashCode> codes;
  std::vector<uint8_t> pq;
  CascadeLookup lookup;
  DescriptorMatrix queries{800};
  std::vector<uint32_t> sources;
  SearchFixture() {
    const std::vector<float> f = to_float(db);
    hasher = train_itq(f.data(), db.rows(), {.iterations = 10}).hasher;
    codebook = PqCodebook::train(f.data(), db.rows(), {.iterations = 10});
    codes.resize(db.rows());
    HashWorkspace hw;
    encode_hash(hasher.view(), db.data(), db.rows(), codes.data(), hw);
    pq.resize(db.rows() * kPqCodeBytes);
    codebook.encode(f.data(), db.rows(), pq.data());
    lookup = CascadeLookup(codes);
    add_noisy_copies(db, 0, 400, 4, 12, queries, sources);
    add_noisy_copies(db, 400, 400, 8, 60, queries, sources);
  }
  CascadeIndexView view() const { return {codes.size(), hasher.view(), codes.data(), pq.data(), &lookup}; }
};

// Ranks 50 points for each query (its source among them) by `reranker`:
// every distance is that from the query as the quantizer sees it (rotated
// by OPQ, else unchanged, its length kept) to the decoded point. Returns how
// many queries found their source nearest; adds |rotated − query| to `moved`.
size_t expect_distances_to_decoded_points(FaissPqReranker& reranker, const DescriptorMatrix& queries,
                                          const std::vector<uint32_t>& sources, size_t points, double& moved) {
  std::vector<float> d, q(kDescriptorDim), qt(kDescriptorDim), x(kDescriptorDim);
  size_t found = 0;
  for (size_t r = 0; r < queries.rows(); ++r) {
    std::vector<uint32_t> ids(50);
    for (uint32_t i = 0; i < ids.size(); ++i) ids[i] = (i * 59 + 7 * uint32_t(r)) % uint32_t(points);
    ids[r % ids.size()] = sources[r];
    d.resize(ids.size());
    for (int j = 0; j < kDescriptorDim; ++j) q[j] = queries.row(r)[j];
    reranker.distances(q.data(), ids, d.data());
    reranker.transform(q.data(), qt.data());
    double len_q = 0, len_qt = 0;
    for (int j = 0; j < kDescriptorDim; ++j) {
      len_q += q[j] * q[j], len_qt += qt[j] * qt[j];
      moved += std::abs(double(qt[j]) - q[j]);
    }
    EXPECT_NEAR(len_qt, len_q, 1e-4 * len_q);
    for (size_t i = 0; i < ids.size(); ++i) {
      reranker.reconstruct(ids[i], x.data());
      double want = 0;
      for (int j = 0; j < kDescriptorDim; ++j) want += (qt[j] - x[j]) * (qt[j] - x[j]);
      EXPECT_NEAR(d[i], want, 1e-3 * want + 1e-2);
    }
    found += ids[std::min_element(d.begin(), d.end()) - d.begin()] == sources[r];
  }
  return found;
}

// A reranker of the first `count` points under `options` is refused
// (kInvalidArgument) with `message` in its error.
void expect_refused(const std::vector<float>& points, size_t count, const FaissPqReranker::Options& options,
                    const std::string& message) {
  try {
    FaissPqReranker(points.data(), count, options);
    ADD_FAILURE() << "no error: " << message;
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
    EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
  }
}

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
// to the decoded points, with and without OPQ; the rotation is orthogonal (it
// keeps lengths) and not the identity; a query's nearest by the codes is the
// point it copies.
TEST(RerankingStudy, FaissDistancesAreThoseToTheDecodedPoints) {
  const DescriptorMatrix db = clustered(4200, 5);
  const std::vector<float> points = to_float(db);
  DescriptorMatrix queries(20);
  std::vector<uint32_t> sources;
  add_noisy_copies(db, 0, 20, 9, 12, queries, sources);
  for (const bool opq : {false, true}) {
    SCOPED_TRACE(opq ? "opq16" : "pq32");
    FaissPqReranker reranker(points.data(), db.rows(),
                             {.subquantizers = opq ? 16 : 32, .opq_rotation = opq, .opq_iterations = 8});
    EXPECT_EQ(reranker.code_bytes(), opq ? 16u : 32u);
    double moved = 0;
    const size_t found = expect_distances_to_decoded_points(reranker, queries, sources, db.rows(), moved);
    if (opq)
      EXPECT_GT(moved, 100.0);  // rotated
    else
      EXPECT_EQ(moved, 0.0);
    EXPECT_GE(found, 18u);
  }
  for (const auto& [points_given, options, message] :
       {std::tuple{size_t(255), FaissPqReranker::Options{}, "at least 256"},
        std::tuple{db.rows(), FaissPqReranker::Options{.subquantizers = 12}, "a divisor of 128"},
        std::tuple{db.rows(), FaissPqReranker::Options{.opq_rotation = true, .opq_iterations = 0}, "opq_iterations"}})
    expect_refused(points, points_given, options, message);
}

// The residual encodings (coarse centroids, then PQ of the residual; FAISS's
// residual quantizer) decode the points closer than the plain PQ of as many
// codes does, their distances are those to the decoded points, and a noisy
// copy's nearest is the point it copies.
TEST(RerankingStudy, ResidualEncodingsDecodeCloserThanThePlainPq) {
  const DescriptorMatrix db = clustered(4200, 5);
  const std::vector<float> points = to_float(db);
  DescriptorMatrix queries(20);
  std::vector<uint32_t> sources;
  add_noisy_copies(db, 0, 20, 9, 12, queries, sources);
  double plain_error = 0;
  for (const auto& [name, options, bytes] :
       {std::tuple{"pq16", FaissPqReranker::Options{}, size_t(16)},
        std::tuple{"ivf256-pq16", FaissPqReranker::Options{.coarse_centroids = 256}, size_t(17)},
        std::tuple{
            "rq16",
            FaissPqReranker::Options{.residual_splits = 1, .residual_beam = 1, .residual_progressive_dim = false},
            size_t(16)},
        std::tuple{
            "prq4x4",
            FaissPqReranker::Options{.residual_splits = 4, .residual_beam = 1, .residual_progressive_dim = false},
            size_t(16)}}) {
    SCOPED_TRACE(name);
    FaissPqReranker reranker(points.data(), db.rows(), options);
    EXPECT_EQ(reranker.code_bytes(), bytes);
    std::vector<float> x(kDescriptorDim);
    double error = 0;
    for (uint32_t i = 0; i < db.rows(); ++i) {
      reranker.reconstruct(i, x.data());
      for (int j = 0; j < kDescriptorDim; ++j)
        error += (x[j] - points[size_t(i) * kDescriptorDim + j]) * (x[j] - points[size_t(i) * kDescriptorDim + j]);
    }
    error /= double(db.rows());
    if (std::string_view(name) == "pq16")
      plain_error = error;
    else
      EXPECT_LT(error, 0.9 * plain_error) << "plain PQ's " << plain_error;
    double moved = 0;
    EXPECT_GE(expect_distances_to_decoded_points(reranker, queries, sources, db.rows(), moved), 18u);
  }
  for (const auto& [points_given, options, message] :
       {std::tuple{db.rows(), FaissPqReranker::Options{.coarse_centroids = 1}, "coarse_centroids"},
        std::tuple{db.rows(), FaissPqReranker::Options{.coarse_centroids = 70000}, "coarse_centroids"},
        std::tuple{size_t(300), FaissPqReranker::Options{.coarse_centroids = 512}, "fewer than the 512"},
        std::tuple{db.rows(), FaissPqReranker::Options{.opq_rotation = true, .residual_splits = 1},
                   "exclude one another"},
        std::tuple{db.rows(), FaissPqReranker::Options{.coarse_centroids = 256, .residual_splits = 2},
                   "exclude one another"},
        std::tuple{db.rows(), FaissPqReranker::Options{.residual_splits = 1, .residual_beam = 0}, "residual_beam"},
        std::tuple{db.rows(), FaissPqReranker::Options{.residual_splits = 3}, "residual_splits"},
        std::tuple{db.rows(), FaissPqReranker::Options{.subquantizers = 8, .residual_splits = 16}, "residual_splits"}})
    expect_refused(points, points_given, options, message);
}

// The harness's check: the whole short lists ranked by the search's own PQ
// distances, through the same ratio test, give exactly the search's 1-1 set,
// at both radii and both L_R; each list is the whole L_R list, of which the
// search's 1-M set is the head, for every feature whose two nearest differ.
TEST(RerankingStudy, WholeShortlistsRankedByTheSearchsDistancesRepeatTheSearch) {
  const SearchFixture fx;
  CascadeMatcher matcher(fx.view(), fx.codebook);
  for (const int radius : {0, 1})
    for (const int list : {40, 64}) {
      SCOPED_TRACE(testing::Message() << "radius " << radius << ", L_R " << list);
      CascadeSearchOptions search;
      search.lut_radius = radius;
      search.prioritize = false;
      search.refined_list = list;
      const CascadeMatches direct = matcher.match(fx.queries, search);
      const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(list, radius));
      std::vector<uint32_t> f, p;
      rank_whole_shortlists(whole, search_pq_distances(whole), search.ratio_one_to_one, f, p);
      std::set<std::pair<uint32_t, uint32_t>> want, got;
      for (size_t i = 0; i < direct.query.size(); ++i) want.emplace(direct.query[i], direct.point[i]);
      for (size_t i = 0; i < f.size(); ++i) got.emplace(f[i], p[i]);
      EXPECT_GT(want.size(), 300u);
      EXPECT_EQ(got, want);
      std::map<uint32_t, size_t> whole_list;
      size_t longest = 0;
      for (size_t i = 0; i < whole.many_query.size(); ++i) {
        whole_list[whole.many_query[i]] = i;
        longest = std::max<size_t>(longest, whole.many_offsets[i + 1] - whole.many_offsets[i]);
      }
      EXPECT_EQ(longest, size_t(list));  // the whole L_R list, not the top M = 5
      // Every feature whose two nearest differ, not only those within ν = 0.9.
      EXPECT_GT(whole.many_query.size(), direct.many_query.size() + 20);
      for (size_t i = 0; i < direct.many_query.size(); ++i) {
        const auto it = whole_list.find(direct.many_query[i]);
        ASSERT_NE(it, whole_list.end());
        const uint32_t w = whole.many_offsets[it->second], n = direct.many_offsets[i + 1] - direct.many_offsets[i];
        ASSERT_GE(whole.many_offsets[it->second + 1] - w, n);
        for (uint32_t k = 0; k < n; ++k)
          EXPECT_EQ(whole.many_points[w + k], direct.many_points[direct.many_offsets[i] + k]);
      }
    }
}

// Exact ranking: the squared L2 of the query's and the points' descriptors;
// on the same short lists it finds at least as many of the copied points as
// the search's PQ does.
TEST(RerankingStudy, ExactDistancesAndTheirRanking) {
  const SearchFixture fx;
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(40));
  ASSERT_GT(whole.many_query.size(), 100u);
  const ShortlistDistances exact = exact_distances(whole, fx.queries, fx.db);
  for (size_t i = 0; i < whole.many_query.size(); i += 37) {
    const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
    const std::span<const uint32_t> ids(whole.many_points.data() + begin, end - begin);
    std::vector<float> d(ids.size());
    exact(i, ids, d.data());
    for (size_t k = 0; k < ids.size(); ++k) {
      int64_t want = 0;
      for (int j = 0; j < kDescriptorDim; ++j) {
        const int64_t x = int64_t(fx.queries.row(whole.many_query[i])[j]) - int64_t(fx.db.row(ids[k])[j]);
        want += x * x;
      }
      EXPECT_EQ(d[k], float(want));
    }
  }
  // A near copy (the first 400 queries: ±12 per dimension, where points of a
  // cluster lie ±35 from its centre) is nearer its point than any other, so
  // exact ranking picks the point wherever the short list holds it.
  std::vector<uint32_t> f, p;
  rank_whole_shortlists(whole, exact, 0.8f, f, p);
  std::map<uint32_t, uint32_t> matched;
  for (size_t i = 0; i < f.size(); ++i) matched[f[i]] = p[i];
  size_t lists_with_source = 0;
  for (size_t i = 0; i < whole.many_query.size(); ++i) {
    const uint32_t feature = whole.many_query[i];
    if (feature >= 400) continue;
    const auto first = whole.many_points.begin() + whole.many_offsets[i],
               last = whole.many_points.begin() + whole.many_offsets[i + 1];
    if (std::find(first, last, fx.sources[feature]) == last) continue;
    ++lists_with_source;
    EXPECT_EQ(matched.count(feature) ? matched[feature] : UINT32_MAX, fx.sources[feature]) << "feature " << feature;
  }
  EXPECT_GT(lists_with_source, 300u);
}

// pq_hamming_distances: at weight 0 the search's own squared distances; at
// weight 1 the distance the codes suggest, 2|q − μ|²(1 − cos(π h / 128)) with
// the list's own feature's code and descriptor, μ the hasher's mean; between,
// the blend, computed here from the descriptors and codes.
TEST(RerankingStudy, PqHammingDistancesBlendTheSearchsWithTheCodes) {
  const SearchFixture fx;
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(40));
  ASSERT_GT(whole.many_query.size(), 100u);
  std::vector<HashCode> query_codes(fx.queries.rows());
  HashWorkspace hw;
  encode_hash(fx.hasher.view(), fx.queries.data(), fx.queries.rows(), query_codes.data(), hw);
  const ShortlistDistances pq = search_pq_distances(whole);
  size_t lists_not_in_order = 0;  // so that a list's index is not its feature
  for (size_t i = 0; i < whole.many_query.size(); i += 29) lists_not_in_order += whole.many_query[i] != i;
  EXPECT_GT(lists_not_in_order, 0u);
  size_t checked = 0, differing = 0;
  for (const double w : {0.0, 0.35, 1.0}) {
    const ShortlistDistances blend =
        pq_hamming_distances(whole, fx.queries, query_codes, fx.codes.data(), fx.hasher.mean.data(), w);
    for (size_t i = 0; i < whole.many_query.size(); i += 29) {
      const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
      const std::span<const uint32_t> ids(whole.many_points.data() + begin, end - begin);
      std::vector<float> d(ids.size()), d_pq(ids.size());
      blend(i, ids, d.data());
      pq(i, ids, d_pq.data());
      const uint32_t f = whole.many_query[i];
      double norm2 = 0;
      for (int j = 0; j < kDescriptorDim; ++j) {
        const double x = double(fx.queries.row(f)[j]) - fx.hasher.mean[j];
        norm2 += x * x;
      }
      for (size_t k = 0; k < ids.size(); ++k) {
        int h = 0;
        for (int b = 0; b < kHashBits; ++b)
          h += ((query_codes[f].w[b / 64] >> (b % 64)) & 1) != ((fx.codes[ids[k]].w[b / 64] >> (b % 64)) & 1);
        const double from_codes = 2 * norm2 * (1 - std::cos(3.14159265358979323846 * h / 128.0));
        const double want = (1 - w) * d_pq[k] + w * from_codes;
        EXPECT_NEAR(d[k], want, 1e-4 * std::max(1.0, want)) << "weight " << w << ", list " << i << ", point " << k;
        if (w == 0) {
          EXPECT_EQ(d[k], d_pq[k]);
        }
        differing += w == 1 && std::abs(d[k] - d_pq[k]) > 1e-3 * d_pq[k];
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000u);
  EXPECT_GT(differing, 100u);  // the codes' distance is not the PQ's
}

// faiss_distances gives a short list the reranker's distances of its own
// feature's descriptor (whole.many_query, not the list's index).
TEST(RerankingStudy, FaissDistancesOfAShortListAreItsFeatures) {
  const SearchFixture fx;
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(40));
  ASSERT_GT(whole.many_query.size(), 100u);
  const std::vector<float> points = to_float(fx.db);
  FaissPqReranker reranker(points.data(), fx.db.rows(), {.subquantizers = 32});
  const ShortlistDistances faiss = faiss_distances(whole, fx.queries, reranker);
  size_t lists_not_in_order = 0;
  for (size_t i = 0; i < whole.many_query.size(); i += 23) {
    lists_not_in_order += whole.many_query[i] != i;
    const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
    const std::span<const uint32_t> ids(whole.many_points.data() + begin, end - begin);
    std::vector<float> got(ids.size()), want(ids.size()), q(kDescriptorDim);
    faiss(i, ids, got.data());
    const uint8_t* row = fx.queries.row(whole.many_query[i]);
    std::copy(row, row + kDescriptorDim, q.begin());
    reranker.distances(q.data(), ids, want.data());
    EXPECT_EQ(got, want);
  }
  EXPECT_GT(lists_not_in_order, 0u);  // the test tells a list's index from its feature
}

// fit_hamming_blend's counts are those of the study's blend ranker: at each
// grid weight, the views whose 1-1 match (the blend's nearest, passing ν_h)
// is their own point or another; its weight is the first best grid weight.
TEST(RerankingStudy, FitHammingBlendCountsWhatTheBlendRanks) {
  const SearchFixture fx;
  const HammingBlendFit fit = fit_hamming_blend(fx.view(), fx.codebook, fx.queries, fx.sources, {.weight_steps = 4});
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(40));
  EXPECT_EQ(fit.queries, fx.queries.rows());
  EXPECT_EQ(fit.listed, whole.many_query.size());
  ASSERT_EQ(fit.correct.size(), 5u);
  ASSERT_EQ(fit.wrong.size(), 5u);
  std::vector<HashCode> query_codes(fx.queries.rows());
  HashWorkspace hw;
  encode_hash(fx.hasher.view(), fx.queries.data(), fx.queries.rows(), query_codes.data(), hw);
  for (size_t k = 0; k <= 4; ++k) {
    std::vector<uint32_t> f, p;
    rank_whole_shortlists(
        whole, pq_hamming_distances(whole, fx.queries, query_codes, fx.codes.data(), fx.hasher.mean.data(), k / 4.0),
        0.8f, f, p);
    size_t correct = 0;
    for (size_t i = 0; i < f.size(); ++i) correct += p[i] == fx.sources[f[i]];
    const size_t wrong = f.size() - correct;
    if (k == 0) {  // the same float distances
      EXPECT_EQ(fit.correct[k], correct);
      EXPECT_EQ(fit.wrong[k], wrong);
    } else {  // the blend rounds in float here, in double there
      EXPECT_NEAR(double(fit.correct[k]), double(correct), 2.0) << "weight " << k / 4.0;
      EXPECT_NEAR(double(fit.wrong[k]), double(wrong), 2.0) << "weight " << k / 4.0;
    }
    EXPECT_GT(correct, 300u);
  }
  size_t best = 0;  // the first with the most right less wrong matches
  for (size_t k = 1; k <= 4; ++k)
    if (double(fit.correct[k]) - double(fit.wrong[k]) > double(fit.correct[best]) - double(fit.wrong[best])) best = k;
  EXPECT_DOUBLE_EQ(fit.weight, best / 4.0);
  EXPECT_EQ(fit.distractors, 0u);
  EXPECT_EQ(fit.distractor_matched, std::vector<size_t>(5, 0));
  // Mismatched counts are the caller's error.
  const std::vector<uint32_t> short_truth(fx.sources.begin(), fx.sources.begin() + 10);
  const std::string e = error_of([&] { fit_hamming_blend(fx.view(), fx.codebook, fx.queries, short_truth); });
  EXPECT_NE(e.find("800 views for 10 points"), std::string::npos) << e;
}

// Distractors: points' own descriptors with their point left out of their
// short lists; any 1-1 match of theirs counts, and the weight is the first
// with the most right matches less wrong ones and matched distractors.
TEST(RerankingStudy, FitHammingBlendCountsMatchedDistractors) {
  const SearchFixture fx;
  std::vector<uint32_t> left_out;
  DescriptorMatrix distractors(300);
  for (uint32_t k = 0; k < 300; ++k) {
    left_out.push_back(k * 19 + 5);
    std::copy_n(fx.db.row(left_out.back()), kDescriptorDim, distractors.row(k));
  }
  const HammingBlendFit fit =
      fit_hamming_blend(fx.view(), fx.codebook, fx.queries, fx.sources, {.weight_steps = 2}, &distractors, left_out);
  EXPECT_EQ(fit.distractors, 300u);
  ASSERT_EQ(fit.distractor_matched.size(), 3u);
  // The distractors' lists without their own point, ranked by the study's blend.
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(distractors, whole_shortlist_options(40));
  CascadeMatches pruned;
  pruned.many_offsets = {0};
  for (size_t i = 0; i < whole.many_query.size(); ++i) {
    const uint32_t f = whole.many_query[i];
    const size_t before = pruned.many_points.size();
    for (uint32_t k = whole.many_offsets[i]; k < whole.many_offsets[i + 1]; ++k)
      if (whole.many_points[k] != left_out[f]) {
        pruned.many_points.push_back(whole.many_points[k]);
        pruned.many_distances.push_back(whole.many_distances[k]);
      }
    if (pruned.many_points.size() - before < 2) {
      pruned.many_points.resize(before);
      pruned.many_distances.resize(before);
      continue;
    }
    pruned.many_query.push_back(f);
    pruned.many_offsets.push_back(uint32_t(pruned.many_points.size()));
  }
  std::vector<HashCode> codes(distractors.rows());
  HashWorkspace hw;
  encode_hash(fx.hasher.view(), distractors.data(), distractors.rows(), codes.data(), hw);
  size_t matched_somewhere = 0;
  for (size_t k = 0; k <= 2; ++k) {
    std::vector<uint32_t> f, p;
    rank_whole_shortlists(
        pruned, pq_hamming_distances(pruned, distractors, codes, fx.codes.data(), fx.hasher.mean.data(), k / 2.0), 0.8f,
        f, p);
    EXPECT_NEAR(double(fit.distractor_matched[k]), double(f.size()), k == 0 ? 0.0 : 2.0) << "weight " << k / 2.0;
    for (size_t i = 0; i < f.size(); ++i) EXPECT_NE(p[i], left_out[f[i]]);
    matched_somewhere += f.size();
  }
  EXPECT_GT(matched_somewhere, 0u);  // the counts are not trivially zero
  size_t best = 0;
  const auto net = [&](size_t k) {
    return double(fit.correct[k]) - double(fit.wrong[k]) - double(fit.distractor_matched[k]);
  };
  for (size_t k = 1; k <= 2; ++k)
    if (net(k) > net(best)) best = k;
  EXPECT_DOUBLE_EQ(fit.weight, best / 2.0);
  const std::string e = error_of(
      [&] { fit_hamming_blend(fx.view(), fx.codebook, fx.queries, fx.sources, {}, &distractors, fx.sources); });
  EXPECT_NE(e.find("300 distractors for 800 points"), std::string::npos) << e;
}

// CascadeSearchOptions::hash_blend_weight: the search's own 1-1 matches are
// those of the study's blend ranker on the same short lists (up to float
// rounding at near ties), and they differ from the PQ's alone.
TEST(RerankingStudy, SearchWithHashBlendMatchesTheStudysBlend) {
  const SearchFixture fx;
  CascadeMatcher matcher(fx.view(), fx.codebook);
  const CascadeMatches whole = matcher.match(fx.queries, whole_shortlist_options(40));
  std::vector<HashCode> query_codes(fx.queries.rows());
  HashWorkspace hw;
  encode_hash(fx.hasher.view(), fx.queries.data(), fx.queries.rows(), query_codes.data(), hw);
  CascadeSearchOptions plain;
  plain.prioritize = false;
  plain.refined_list = 40;
  const CascadeMatches pq_only = matcher.match(fx.queries, plain);
  std::set<std::pair<uint32_t, uint32_t>> pq_pairs;
  for (size_t i = 0; i < pq_only.query.size(); ++i) pq_pairs.emplace(pq_only.query[i], pq_only.point[i]);
  for (const float w : {0.25f, 0.5f, 1.0f}) {
    SCOPED_TRACE(testing::Message() << "weight " << w);
    CascadeSearchOptions o = plain;
    o.hash_blend_weight = w;
    const CascadeMatches direct = matcher.match(fx.queries, o);
    std::vector<uint32_t> f, p;
    rank_whole_shortlists(
        whole, pq_hamming_distances(whole, fx.queries, query_codes, fx.codes.data(), fx.hasher.mean.data(), w), 0.8f, f,
        p);
    std::set<std::pair<uint32_t, uint32_t>> got, want;
    for (size_t i = 0; i < direct.query.size(); ++i) got.emplace(direct.query[i], direct.point[i]);
    for (size_t i = 0; i < f.size(); ++i) want.emplace(f[i], p[i]);
    size_t common = 0, changed = 0;
    for (const auto& x : got) common += want.count(x), changed += !pq_pairs.count(x);
    EXPECT_GE(common + 3, std::max(got.size(), want.size()));
    EXPECT_GT(want.size(), 300u);
    EXPECT_GT(changed, 0u);  // the blend changes matches
    // The distances it reports are the PQ's (the guided confirmation compares
    // PQ distances with them), those of the same pairs in the PQ's lists.
    std::map<std::pair<uint32_t, uint32_t>, float> pq_distance;
    for (size_t i = 0; i < whole.many_query.size(); ++i)
      for (uint32_t k = whole.many_offsets[i]; k < whole.many_offsets[i + 1]; ++k)
        pq_distance[{whole.many_query[i], whole.many_points[k]}] = whole.many_distances[k];
    size_t compared = 0;
    for (size_t i = 0; i < direct.many_query.size(); ++i)
      for (uint32_t k = direct.many_offsets[i]; k < direct.many_offsets[i + 1]; ++k) {
        const auto it = pq_distance.find({direct.many_query[i], direct.many_points[k]});
        if (it == pq_distance.end()) continue;
        ASSERT_EQ(direct.many_distances[k], it->second);
        ++compared;
      }
    for (size_t i = 0; i < direct.query.size(); ++i) {
      const auto it = pq_distance.find({direct.query[i], direct.point[i]});
      if (it != pq_distance.end()) ASSERT_EQ(direct.distance[i], it->second);
    }
    EXPECT_GT(compared, 1000u);
  }
  CascadeSearchOptions bad = plain;
  bad.hash_blend_weight = 1.5f;
  EXPECT_NE(error_of([&] { bad.validate(); }).find("hash_blend_weight"), std::string::npos);
}
