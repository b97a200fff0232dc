// Micro-benchmarks of the per-candidate distance kernels of the cascade
// search, each beside its baseline in the same run:
//   Hamming distance of 128-bit codes (XOR + popcount) vs L2 on raw uint8 SIFT;
//   PQ asymmetric distance (16 table lookups) vs L2 on float descriptors;
//   CRC32C throughput (segment files are verified at open);
//   the search kernels (search_kernels.h) at every SIMD level this CPU has,
//   the scalar reference first (argument: 0 scalar, 1 avx2, 2 avx512);
//   the full and prioritized cascade search of 10K query features on a
//   synthetic 100K-point segment (the paper's segment size);
//   that segment written as a segment file with float32 and with int16 point
//   coordinates (counters: bytes per point of the whole file);
//   the guided confirmation of a pose on a 100K-point segment with 10K query
//   keypoints, beside the explained fraction's pass over the same points.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <array>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <algorithm>

#include "visloc/map/segment_file.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/matching/search_kernels.h"
#include "visloc/pipeline/confidence.h"
#include "visloc/pipeline/guided_confirmation.h"
#include "visloc/util/crc32c.h"

namespace {

constexpr size_t kPoints = 4096;

std::vector<uint8_t> random_bytes(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<uint8_t> v(n);
  for (auto& b : v) b = static_cast<uint8_t>(rng());
  return v;
}

void BM_HammingPopcount(benchmark::State& state) {
  auto bytes = random_bytes(kPoints * sizeof(visloc::HashCode), 1);
  const auto* codes = reinterpret_cast<const visloc::HashCode*>(bytes.data());
  const visloc::HashCode q = codes[7];
  for (auto _ : state) {
    uint32_t sum = 0;
    for (size_t i = 0; i < kPoints; ++i) sum += visloc::hamming_distance(q, codes[i]);
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_HammingPopcount);

void BM_RawSiftL2Baseline(benchmark::State& state) {
  auto desc = random_bytes(kPoints * 128, 2);
  auto q = random_bytes(128, 3);
  for (auto _ : state) {
    uint64_t sum = 0;
    for (size_t i = 0; i < kPoints; ++i) {
      uint32_t d = 0;
      const uint8_t* p = desc.data() + i * 128;
      for (int k = 0; k < 128; ++k) {
        const int x = int(p[k]) - int(q[k]);
        d += static_cast<uint32_t>(x * x);
      }
      sum += d;
    }
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_RawSiftL2Baseline);

void BM_PqAdcLookup(benchmark::State& state) {
  auto codes = random_bytes(kPoints * visloc::kPqCodeBytes, 4);
  std::vector<float> table(visloc::kPqTableSize);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1000);
  for (auto& t : table) t = u(rng);
  for (auto _ : state) {
    float sum = 0;
    for (size_t i = 0; i < kPoints; ++i)
      sum += visloc::adc_distance(table.data(), codes.data() + i * visloc::kPqCodeBytes, visloc::kPqSubvectors);
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_PqAdcLookup);

void BM_FloatL2Baseline(benchmark::State& state) {
  std::vector<float> desc(kPoints * 128), q(128);
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> u(0, 255);
  for (auto& x : desc) x = u(rng);
  for (auto& x : q) x = u(rng);
  for (auto _ : state) {
    float sum = 0;
    for (size_t i = 0; i < kPoints; ++i) {
      float d = 0;
      const float* p = desc.data() + i * 128;
      for (int k = 0; k < 128; ++k) d += (p[k] - q[k]) * (p[k] - q[k]);
      sum += d;
    }
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_FloatL2Baseline);

void BM_Crc32c(benchmark::State& state) {
  auto data = random_bytes(1 << 20, 7);
  for (auto _ : state) benchmark::DoNotOptimize(visloc::crc32c(data.data(), data.size()));
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(data.size()));
}
BENCHMARK(BM_Crc32c);

const visloc::SearchKernels* kernels_or_skip(benchmark::State& state, int64_t index = -1) {
  const visloc::SimdLevel levels[] = {visloc::SimdLevel::kScalar, visloc::SimdLevel::kAvx2, visloc::SimdLevel::kAvx512};
  const visloc::SimdLevel level = levels[index >= 0 ? index : state.range(0)];
  if (!visloc::cpu_supports(level)) {
    state.SkipWithError("this CPU lacks the level");
    return nullptr;
  }
  state.SetLabel(visloc::to_string(level));
  return &visloc::search_kernels(level);
}

// Hamming of one query code against 4096 codes gathered by id (the refined step).
void BM_KernelHamming(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  auto bytes = random_bytes(kPoints * sizeof(visloc::HashCode), 1);
  const auto* codes = reinterpret_cast<const visloc::HashCode*>(bytes.data());
  std::vector<uint32_t> ids(kPoints);
  std::mt19937 rng(2);
  for (auto& i : ids) i = rng() % kPoints;
  std::vector<uint8_t> out(kPoints);
  uint32_t hist[129] = {};
  for (auto _ : state) {
    k->hamming_distances(codes[7], codes, ids.data(), kPoints, out.data(), hist);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_KernelHamming)->DenseRange(0, 2);

// The refined step's selection (L_R = 40) from 233 candidates, the full
// search's mean on the synthetic 100K-point segment; distances drawn
// binomial(128, ½), which real candidates (sharing a table key with the
// query) skew below; the kernels' time hardly depends on them. Items: every
// candidate, though the kernels stop at the 40th taken (near the end).
void BM_KernelShortlist(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  constexpr size_t kCandidates = 233, kLists = 256;
  constexpr uint32_t kList = 40;
  std::mt19937 rng(4);
  std::binomial_distribution<int> binomial(128, 0.5);
  std::vector<uint8_t> d(kCandidates * kLists);
  std::vector<uint32_t> ids(kCandidates * kLists), cut(kLists), at_cut(kLists);
  for (auto& x : d) x = static_cast<uint8_t>(binomial(rng));
  for (auto& i : ids) i = rng() % 100000;
  for (size_t l = 0; l < kLists; ++l) {
    uint32_t hist[129] = {}, c = 0, below = 0;
    for (size_t i = 0; i < kCandidates; ++i) ++hist[d[l * kCandidates + i]];
    while (below + hist[c] < kList) below += hist[c++];
    cut[l] = c;
    at_cut[l] = kList - below;
  }
  std::vector<uint32_t> out(kList + visloc::kShortlistSlack);
  size_t l = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(k->shortlist(d.data() + l * kCandidates, ids.data() + l * kCandidates, kCandidates, cut[l],
                                          at_cut[l], kList, out.data()));
    benchmark::ClobberMemory();
    l = (l + 1) % kLists;
  }
  state.SetItemsProcessed(state.iterations() * kCandidates);
}
BENCHMARK(BM_KernelShortlist)->DenseRange(0, 2);

// Centroids and a query with values in [0, 120), drawn from `rng` in that order.
// `subvectors`: 16 or 32 (bytes per code).
visloc::PqCodebook random_codebook_and_query(std::mt19937& rng, std::vector<float>& query,
                                             int subvectors = visloc::kPqSubvectors) {
  std::uniform_real_distribution<float> u(0, 120);
  std::vector<float> c(visloc::kPqCentroidFloats);
  for (auto& x : c) x = u(rng);
  query.resize(128);
  for (auto& x : query) x = u(rng);
  return visloc::PqCodebook(c, subvectors);
}

// One query's 16 × 256 ADC table (once per searched feature).
void BM_KernelAdcTable(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  std::mt19937 rng(3);
  std::vector<float> q;
  const visloc::PqCodebook cb = random_codebook_and_query(rng, q);
  std::vector<float> table(visloc::kPqTableSize);
  for (auto _ : state) {
    k->adc16.table(cb.centroids_transposed(), q.data(), table.data());
    benchmark::DoNotOptimize(table.data());
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_KernelAdcTable)->DenseRange(0, 2);

// ADC distances of 4096 codes gathered by id.
void BM_KernelAdcDistances(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  auto codes = random_bytes(kPoints * visloc::kPqCodeBytes, 4);
  std::vector<float> table(visloc::kPqTableSize), out(kPoints);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1000);
  for (auto& t : table) t = u(rng);
  std::vector<uint32_t> ids(kPoints);
  for (auto& i : ids) i = rng() % kPoints;
  for (auto _ : state) {
    k->adc16.distances(table.data(), codes.data(), ids.data(), kPoints, out.data());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * kPoints);
}
BENCHMARK(BM_KernelAdcDistances)->DenseRange(0, 2);

// ADC distances of 40 candidates (L_R) without a table, against the table
// and its lookups (argument 3..5: the same levels, table path); second
// argument: bytes per code (16 or 32).
void BM_KernelAdcDirect40(benchmark::State& state) {
  const bool table_path = state.range(0) >= 3;
  const auto* k = kernels_or_skip(state, state.range(0) % 3);
  if (!k) return;
  const int subvectors = static_cast<int>(state.range(1));
  state.SetLabel(std::string(visloc::to_string(k->level)) + (table_path ? " table+lookups" : " direct") + " " +
                 std::to_string(subvectors) + " B");
  std::mt19937 rng(9);
  std::vector<float> q;
  const visloc::PqCodebook cb = random_codebook_and_query(rng, q, subvectors);
  const visloc::AdcKernels& adc = k->adc(subvectors);
  std::vector<float> table(cb.table_size());
  auto codes = random_bytes(kPoints * size_t(subvectors), 10);
  std::vector<uint32_t> ids(40);
  for (auto& i : ids) i = rng() % kPoints;
  std::vector<float> out(40);
  for (auto _ : state) {
    if (table_path) {
      adc.table(cb.centroids_transposed(), q.data(), table.data());
      adc.distances(table.data(), codes.data(), ids.data(), ids.size(), out.data());
    } else {
      adc.direct(cb.centroids().data(), q.data(), codes.data(), ids.data(), ids.size(), out.data());
    }
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * 40);
}
BENCHMARK(BM_KernelAdcDirect40)->ArgsProduct({{0, 1, 2, 3, 4, 5}, {16, 32}});

// Residual codes' direct distances of 40 candidates (argument 0..2: scalar,
// AVX2, AVX-512; second: the split count S), against BM_KernelAdcDirect40's
// 16-byte PQ: the same bytes per candidate, 16 rows of 128 / S codebook
// floats read where the PQ reads 16 of 8.
void BM_KernelAdditiveDirect40(benchmark::State& state) {
  const auto* k = kernels_or_skip(state, state.range(0));
  if (!k) return;
  const int splits = static_cast<int>(state.range(1));
  state.SetLabel(std::string(visloc::to_string(k->level)) + " residual S=" + std::to_string(splits));
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-40, 40), uq(0, 160);
  std::vector<float> books(size_t(16) * 256 * size_t(128 / splits)), q(128);
  for (auto& x : books) x = u(rng);
  for (auto& x : q) x = uq(rng);
  const visloc::PqCodebook cb = visloc::PqCodebook::residual(books, splits);
  auto codes = random_bytes(kPoints * size_t(16), 10);
  std::vector<uint32_t> ids(40);
  for (auto& i : ids) i = rng() % kPoints;
  std::vector<float> out(40);
  const auto direct = k->additive.direct(splits);
  for (auto _ : state) {
    direct(cb.centroids().data(), q.data(), codes.data(), ids.data(), ids.size(), out.data());
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * 40);
}
BENCHMARK(BM_KernelAdditiveDirect40)->ArgsProduct({{0, 1, 2}, {1, 2, 4}});

// Hash codes of 1024 centred descriptors.
void BM_KernelHashCodes(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  constexpr size_t kRows = 1024;
  std::mt19937 rng(6);
  std::normal_distribution<float> g(0, 30);
  std::vector<float> wt(128 * 128), x(kRows * 128);
  for (auto& w : wt) w = g(rng) / 300;
  for (auto& v : x) v = g(rng);
  std::vector<visloc::HashCode> codes(kRows);
  for (auto _ : state) {
    k->hash_codes(wt.data(), x.data(), kRows, codes.data());
    benchmark::DoNotOptimize(codes.data());
  }
  state.SetItemsProcessed(state.iterations() * kRows);
}
BENCHMARK(BM_KernelHashCodes)->DenseRange(0, 2);

// The same 1024 rows as uint8 descriptors through the integer kernel (the
// query path: W rounded to int16, exact int32 sums), against the float one above.
void BM_KernelHashCodesU8(benchmark::State& state) {
  const auto* k = kernels_or_skip(state);
  if (!k) return;
  constexpr size_t kRows = 1024;
  std::mt19937 rng(6);
  std::normal_distribution<float> g(0, 30);
  std::vector<float> w(128 * 128), mean(128, 40.f);
  for (auto& v : w) v = g(rng) / 300;
  std::vector<uint8_t> x(kRows * 128);
  for (auto& v : x) v = static_cast<uint8_t>(std::clamp(40.f + g(rng), 0.f, 255.f));
  visloc::QuantizedHashProjection q;
  visloc::quantize_hash_projection({mean.data(), w.data()}, q);
  std::vector<visloc::HashCode> codes(kRows);
  for (auto _ : state) {
    k->hash_codes_u8(q, x.data(), kRows, codes.data(), nullptr);
    benchmark::DoNotOptimize(codes.data());
  }
  state.SetItemsProcessed(state.iterations() * kRows);
}
BENCHMARK(BM_KernelHashCodesU8)->DenseRange(0, 2);

// The integer form of a projection, made once per encode_hash call of uint8 rows.
void BM_QuantizeHashProjection(benchmark::State& state) {
  std::mt19937 rng(6);
  std::normal_distribution<float> g(0, 30);
  std::vector<float> w(128 * 128), mean(128, 40.f);
  for (auto& v : w) v = g(rng) / 300;
  visloc::QuantizedHashProjection q;
  for (auto _ : state) {
    visloc::quantize_hash_projection({mean.data(), w.data()}, q);
    benchmark::DoNotOptimize(q.thresholds.data());
  }
}
BENCHMARK(BM_QuantizeHashProjection)->Unit(benchmark::kMicrosecond);

// A synthetic 100K-point segment: SIFT-like descriptors around 3000 centres;
// 10K query features, each a noisy copy of a segment point.
struct SyntheticSegment {
  static constexpr size_t kSegmentPoints = 100000, kQueryFeatures = 10000;
  visloc::BinaryHasher hasher;
  visloc::PqCodebook codebook;
  std::vector<visloc::HashCode> codes;
  std::vector<uint8_t> pq;
  visloc::CascadeLookup lookup;
  visloc::CascadeLookup plain_lookup;  // without the radius-1 neighbourhood sizes: the ordering's baseline
  visloc::DescriptorMatrix queries;
  visloc::CascadeIndexView view(bool neighbourhood_sizes = true) const {
    return {codes.size(), hasher.view(), codes.data(), pq.data(), neighbourhood_sizes ? &lookup : &plain_lookup};
  }
  static const SyntheticSegment& get() {
    static const SyntheticSegment s = make();
    return s;
  }
  static SyntheticSegment make() {
    std::mt19937 rng(11);
    std::uniform_int_distribution<int> centre(0, 120), noise(-30, 30), small(-8, 8);
    std::vector<std::array<int, 128>> centres(3000);
    for (auto& c : centres)
      for (int& v : c) v = centre(rng);
    std::vector<float> db(kSegmentPoints * 128);
    for (size_t i = 0; i < kSegmentPoints; ++i) {
      const auto& c = centres[rng() % centres.size()];
      for (int j = 0; j < 128; ++j) db[i * 128 + j] = float(std::clamp(c[j] + noise(rng), 0, 255));
    }
    SyntheticSegment s;
    s.hasher = visloc::train_itq(db.data(), kSegmentPoints, {.iterations = 20}).hasher;
    s.codebook = visloc::PqCodebook::train(db.data(), kSegmentPoints, {.iterations = 10});
    s.codes.resize(kSegmentPoints);
    visloc::HashWorkspace ws;
    visloc::encode_hash(s.hasher.view(), db.data(), kSegmentPoints, s.codes.data(), ws);
    s.pq.resize(kSegmentPoints * visloc::kPqCodeBytes);
    s.codebook.encode(db.data(), kSegmentPoints, s.pq.data());
    s.lookup = visloc::CascadeLookup(s.codes);
    s.plain_lookup = visloc::CascadeLookup(s.codes, /*neighbourhood_sizes=*/false);
    s.queries = visloc::DescriptorMatrix(kQueryFeatures);
    for (size_t i = 0; i < kQueryFeatures; ++i) {
      const size_t p = rng() % kSegmentPoints;
      for (int j = 0; j < 128; ++j)
        s.queries.row(i)[j] = static_cast<uint8_t>(std::clamp(int(db[p * 128 + j]) + small(rng), 0, 255));
    }
    return s;
  }
};

// Arguments: LUT radius, prioritized (0/1), neighbourhood sizes (0/1; the
// prioritized order at radius 1 from the lookup's stored sums, or from 136
// probes per feature). Time per query of 10K features, hashing included; one
// workspace reused across iterations.
void BM_CascadeSearch100KPoints(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::CascadeSearchOptions o;
  o.lut_radius = static_cast<int>(state.range(0));
  o.prioritize = state.range(1) != 0;
  visloc::CascadeWorkspace ws;
  visloc::CascadeMatcher matcher(s.view(state.range(2) != 0), s.codebook, ws);
  visloc::CascadeMatches m;
  matcher.match(s.queries, o, m);
  for (auto _ : state) {
    matcher.match(s.queries, o, m);
    benchmark::DoNotOptimize(m.query.data());
  }
  state.counters["matches_1to1"] = double(m.query.size());
  state.counters["candidates_per_feature"] =
      double(m.stats.coarse_candidates) / double(std::max<size_t>(1, m.stats.features_searched));
  state.counters["ms_hash"] = m.stats.ms_hash;
  state.counters["ms_order"] = m.stats.ms_order;
  state.counters["lookup_bytes_per_point"] =
      double(s.view(state.range(2) != 0).lookup->memory_bytes()) / double(s.codes.size());
}
BENCHMARK(BM_CascadeSearch100KPoints)
    ->Args({0, 0, 1})
    ->Args({1, 0, 1})
    ->Args({0, 1, 1})
    ->Args({1, 1, 0})
    ->Args({1, 1, 1})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);

// Query-directed probing (CascadeSearchOptions::lut_flips): the full search
// at radius 1 probing, per table, the exact bucket and the k one-bit-away
// buckets whose bits lie nearest their hyperplanes. Argument: k (16 is the
// plain radius-1 search). Time per query of 10K features, hashing included.
// The counters give the 1-1 matches, and how many of them are also the
// plain radius-1 search's (same feature and point), so that speed is read
// against what the fewer probes miss.
void BM_CascadeSearch100KPointsDirected(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::CascadeSearchOptions o, all;
  o.lut_radius = all.lut_radius = 1;
  o.prioritize = all.prioritize = false;
  o.lut_flips = static_cast<int>(state.range(0));
  visloc::CascadeWorkspace ws;
  visloc::CascadeMatcher matcher(s.view(), s.codebook, ws);
  visloc::CascadeMatches m, reference;
  matcher.match(s.queries, all, reference);
  matcher.match(s.queries, o, m);
  for (auto _ : state) {
    matcher.match(s.queries, o, m);
    benchmark::DoNotOptimize(m.query.data());
  }
  std::set<std::pair<uint32_t, uint32_t>> plain;
  for (size_t i = 0; i < reference.query.size(); ++i) plain.insert({reference.query[i], reference.point[i]});
  size_t shared = 0;
  for (size_t i = 0; i < m.query.size(); ++i) shared += plain.count({m.query[i], m.point[i]});
  state.counters["matches_1to1"] = double(m.query.size());
  state.counters["shared_with_all_flips"] = double(shared);
  state.counters["candidates_per_feature"] =
      double(m.stats.coarse_candidates) / double(std::max<size_t>(1, m.stats.features_searched));
  state.counters["ms_hash"] = m.stats.ms_hash;
}
BENCHMARK(BM_CascadeSearch100KPointsDirected)
    ->Arg(16)
    ->Arg(8)
    ->Arg(6)
    ->Arg(4)
    ->Arg(2)
    ->Arg(0)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(5);

// Query-directed probing's order alone: the sorting network over the 8
// tables' 16 margins of 10K features (their margins from the hash kernel).
// Argument: bits kept per table.
void BM_DirectedFlips10KFeatures(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  std::vector<visloc::HashCode> codes(s.queries.rows());
  std::vector<int32_t> margins(s.queries.rows() * visloc::kHashBits);
  visloc::HashWorkspace ws;
  visloc::encode_hash(s.hasher.view(), s.queries.data(), s.queries.rows(), codes.data(), ws, margins.data());
  const int flips = static_cast<int>(state.range(0));
  std::vector<uint8_t> out(size_t(visloc::kHashTables) * visloc::kHashTableBits);
  for (auto _ : state) {
    for (size_t f = 0; f < s.queries.rows(); ++f) {
      visloc::directed_flips(margins.data() + f * visloc::kHashBits, flips, out.data());
      benchmark::DoNotOptimize(out.data());
    }
  }
}
BENCHMARK(BM_DirectedFlips10KFeatures)->Arg(4)->Arg(16)->Unit(benchmark::kMillisecond);

// Two searches of the same matcher timed alternately in one process (ABBA:
// each order once per two pairs, two pairs per benchmark iteration), this
// machine's noise moving whole runs by tens of percent; their last matches
// into a and b, and the medians of their ms_total.
struct AlternatedMedians {
  double ms_a = 0, ms_b = 0;
};
AlternatedMedians time_alternately(benchmark::State& state, visloc::CascadeMatcher& matcher,
                                   const visloc::DescriptorMatrix& queries,
                                   const visloc::CascadeSearchOptions& a_options,
                                   const visloc::CascadeSearchOptions& b_options, visloc::CascadeMatches& a,
                                   visloc::CascadeMatches& b) {
  std::vector<double> ms_a, ms_b;
  for (auto _ : state) {
    for (int pair = 0; pair < 2; ++pair) {
      const bool b_first = (ms_a.size() % 2) == 0;
      if (b_first) {
        matcher.match(queries, b_options, b);
        ms_b.push_back(b.stats.ms_total);
      }
      matcher.match(queries, a_options, a);
      ms_a.push_back(a.stats.ms_total);
      if (!b_first) {
        matcher.match(queries, b_options, b);
        ms_b.push_back(b.stats.ms_total);
      }
    }
  }
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  return {median(ms_a), median(ms_b)};
}

// Software prefetching in the full search at radius 1 (10K features, the
// 100K-point segment), as the ratio of the search without it to the search
// with it, timed alternately (time_alternately); medians over the pairs. The
// same matches either way (checked).
void BM_CascadeSearch100KPointsPrefetch(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::CascadeWorkspace ws;
  visloc::CascadeMatcher matcher(s.view(), s.codebook, ws);
  visloc::CascadeSearchOptions with, without;
  with.lut_radius = without.lut_radius = 1;
  with.prioritize = without.prioritize = false;
  without.prefetch = false;
  visloc::CascadeMatches a, b;
  const AlternatedMedians t = time_alternately(state, matcher, s.queries, with, without, a, b);
  if (a.query != b.query || a.point != b.point || a.many_points != b.many_points)
    state.SkipWithError("the search with prefetching found other matches");
  state.counters["ms_with"] = t.ms_a;
  state.counters["ms_without"] = t.ms_b;
  state.counters["speedup"] = t.ms_b / t.ms_a;
}
BENCHMARK(BM_CascadeSearch100KPointsPrefetch)->Unit(benchmark::kMillisecond)->Iterations(10);

// The hash-code blend (CascadeSearchOptions::hash_blend_weight, 0.5 here)
// against the PQ alone, in the full search at radius 1 (10K features, the
// 100K-point segment), timed alternately (time_alternately); medians over
// the pairs. Its cost per feature: |q − μ|² (128 dimensions), then per
// ranked candidate a Hamming distance and a table lookup.
void BM_CascadeSearch100KPointsHashBlend(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::CascadeWorkspace ws;
  visloc::CascadeMatcher matcher(s.view(), s.codebook, ws);
  visloc::CascadeSearchOptions plain, blend;
  plain.lut_radius = blend.lut_radius = 1;
  plain.prioritize = blend.prioritize = false;
  blend.hash_blend_weight = 0.5f;
  visloc::CascadeMatches a, b;
  const AlternatedMedians t = time_alternately(state, matcher, s.queries, blend, plain, a, b);
  state.counters["ms_blend"] = t.ms_a;
  state.counters["ms_plain"] = t.ms_b;
  state.counters["cost_ratio"] = t.ms_a / t.ms_b;
  state.counters["matches_blend"] = double(a.query.size());
  state.counters["matches_plain"] = double(b.query.size());
}
BENCHMARK(BM_CascadeSearch100KPointsHashBlend)->Unit(benchmark::kMillisecond)->Iterations(10);

// The prioritized order's key alone: the coarse sizes of 10K features at
// radius 1, from 136 probes per feature (argument 0) or from the lookup's
// neighbourhood sizes (1); the same sizes either way.
void BM_CoarseSizesRadius1(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::CascadeMatcher matcher(s.view(state.range(0) != 0), s.codebook);
  std::vector<visloc::HashCode> codes(s.queries.rows());
  visloc::HashWorkspace encode;
  visloc::encode_hash(s.hasher.view(), s.queries.data(), s.queries.rows(), codes.data(), encode);
  std::vector<uint32_t> sizes;
  for (auto _ : state) {
    matcher.coarse_sizes(codes, 1, sizes);
    benchmark::DoNotOptimize(sizes.data());
  }
  size_t saturated = 0;
  for (const auto& c : codes)
    for (int k = 0; k < visloc::kHashTables; ++k) {
      const uint32_t key = visloc::hash_subcode(c, k);
      saturated += s.lookup.neighbourhood_size(k, key) >= visloc::CascadeLookup::kNeighbourhoodSaturated;
    }
  state.counters["saturated_share"] = double(saturated) / double(codes.size() * visloc::kHashTables);
}
BENCHMARK(BM_CoarseSizesRadius1)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// Building a 100K-point segment's lookup tables (done when a segment is
// opened): without (0) and with (1) the neighbourhood sizes.
void BM_CascadeLookupBuild100KPoints(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  for (auto _ : state) {
    visloc::CascadeLookup lookup(s.codes, state.range(0) != 0);
    benchmark::DoNotOptimize(&lookup);
  }
}
BENCHMARK(BM_CascadeLookupBuild100KPoints)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Argument: 0 float32, 1 int16 coordinates. The synthetic segment's codes
// and rotation, 100K points uniform in a 100 × 20 × 15 m street box
// (metric: enu_from_segment scale 1) seen by 100 images; time per write +
// open (checksums, lookup tables, decoding).
void BM_SegmentFile100KPoints(benchmark::State& state) {
  const SyntheticSegment& s = SyntheticSegment::get();
  visloc::SegmentData data;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> along(0, 100), across(-10, 10), up(0, 15);
  for (size_t i = 0; i < s.codes.size(); ++i) data.xyz.insert(data.xyz.end(), {along(rng), across(rng), up(rng)});
  data.hasher = s.hasher;
  data.codes = s.codes;
  data.pq_codes = s.pq;
  for (int i = 0; i < 100; ++i)
    data.images.push_back(
        {"img" + std::to_string(i) + ".jpg", 1, 1600, 1200, {1900, 1900, 800, 600}, {1, 0, 0, 0}, {float(i), 0, 0}});
  data.extra_meta["enu_from_segment"] = {
      {"scale", 1.0}, {"rotation_row_major", {1, 0, 0, 0, 1, 0, 0, 0, 1}}, {"translation", {0, 0, 0}}};
  visloc::SegmentWriteOptions options;
  options.coordinates = state.range(0) ? visloc::PointCoordinates::kInt16 : visloc::PointCoordinates::kFloat32;
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() / ("visloc_micro_bench_" + std::to_string(getpid()) + ".vlseg");
  std::unique_ptr<visloc::Segment> segment;
  for (auto _ : state) {
    visloc::write_segment_file(path, data, options);
    segment = visloc::Segment::open(path);
    benchmark::DoNotOptimize(segment->xyz().data());
  }
  const double n = double(segment->num_points());
  state.counters["file_bytes_per_point"] = segment->bytes().file_bytes_per_point(segment->num_points());
  state.counters["per_point_section_bytes_per_point"] =
      segment->bytes().per_point_bytes_per_point(segment->num_points());
  state.counters["decoded_xyz_bytes_per_point"] = double(segment->bytes().xyz_memory) / n;
  state.counters["format_version"] = segment->format_version();
  state.counters["worst_rounding_error_mm"] =
      segment->xyz_quantization() ? 1000 * segment->xyz_quantization()->max_rounding_error() : 0.0;
  std::filesystem::remove(path);
}
BENCHMARK(BM_SegmentFile100KPoints)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(3);

// A pose's guided confirmation (argument 1) against the explained fraction's
// pass over the same points (argument 0), the baseline: 100K points in front
// of a 1226 × 370 camera at 5-60 m, half of them within the inliers' depth,
// 10K keypoints spread over the image, a random PQ codebook.
void BM_GuidedConfirmation100KPoints(benchmark::State& state) {
  constexpr size_t kSegmentPoints = 100000, kKeypoints = 10000;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f), depth(5.0f, 60.0f), uniform(0.0f, 1.0f);
  visloc::PinholeCamera camera = visloc::PinholeCamera::centered(1226, 370, 707.0);
  std::vector<float> xyz;
  xyz.reserve(3 * kSegmentPoints);
  for (size_t i = 0; i < kSegmentPoints; ++i) {
    const float z = depth(rng);
    xyz.push_back(unit(rng) * z * 0.9f);
    xyz.push_back(unit(rng) * z * 0.27f);
    xyz.push_back(z);
  }
  const std::vector<uint8_t> codes = random_bytes(kSegmentPoints * visloc::kPqSubvectors, 12);
  std::vector<float> centroids(size_t(visloc::kPqSubvectors) * visloc::kPqCentroids *
                               (visloc::kDescriptorDim / visloc::kPqSubvectors));
  for (float& c : centroids) c = 60.0f * uniform(rng);
  const visloc::PqCodebook codebook(centroids);
  std::vector<visloc::Keypoint> keypoints(kKeypoints);
  for (auto& k : keypoints) k = {1226.0f * uniform(rng), 370.0f * uniform(rng), 2.0f, 0.0f};
  const std::vector<uint8_t> desc = random_bytes(kKeypoints * visloc::kDescriptorDim, 13);
  const visloc::DescriptorMatrix descriptors(desc.data(), kKeypoints);
  visloc::GuidedConfirmationInput in;
  in.xyz = xyz;
  in.codes = codes.data();
  in.codebook = &codebook;
  in.camera = &camera;
  in.focal = 707.0;
  in.max_depth = 32.5;
  in.keypoints = keypoints;
  in.descriptors = &descriptors;
  in.inlier_cells = 0x00ff00ff00ff00ffull;
  in.radius_px = 8;
  in.max_distance = 250;
  visloc::GuidedConfirmer confirmer;
  visloc::GuidedConfirmation g;
  double explained = 0;
  for (auto _ : state) {
    if (state.range(0) == 1) {
      g = confirmer.measure(in);
      benchmark::DoNotOptimize(g);
    } else {
      explained = visloc::explained_fraction(xyz, {}, camera, 707.0, Eigen::Vector2d::Zero(), 32.5, 100);
      benchmark::DoNotOptimize(explained);
    }
  }
  if (state.range(0) == 1) {
    state.counters["predicted"] = double(g.predicted);
    state.counters["examined"] = double(g.examined);
  }
}
BENCHMARK(BM_GuidedConfirmation100KPoints)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace
