// The SIMD search kernels against their scalar reference: bit-identical
// results for every level this CPU supports, at every tail length.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <random>
#include <utility>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#include <unistd.h>
#endif

#include "visloc/matching/pq_codebook.h"
#include "visloc/matching/search_kernels.h"
#include "visloc/util/error.h"

using namespace visloc;

namespace {

PqCodebook random_codebook(uint32_t seed, int subvectors = kPqSubvectors) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0, 120);
  std::vector<float> c(kPqCentroidFloats);
  for (auto& x : c) x = u(rng);
  return PqCodebook(c, subvectors);
}

const size_t kLengths[] = {0, 1, 7, 8, 9, 15, 16, 17, 31, 40, 100, 257};
// Both PQ layouts: 16-byte and 32-byte codes.
const int kLayouts[] = {kPqSubvectors, kPqFineSubvectors};

}  // namespace

TEST(SearchKernels, LevelsAreNamedAndTheScalarOneAlwaysExists) {
  EXPECT_EQ(parse_simd_level("avx512"), SimdLevel::kAvx512);
  EXPECT_EQ(parse_simd_level("scalar"), SimdLevel::kScalar);
  EXPECT_THROW(parse_simd_level("sse9"), Error);
  const auto levels = supported_simd_levels();
  ASSERT_FALSE(levels.empty());
  EXPECT_EQ(levels.front(), SimdLevel::kScalar);
  EXPECT_EQ(search_kernels(SimdLevel::kScalar).level, SimdLevel::kScalar);
  // The best level is one of the supported ones.
  const SimdLevel best = search_kernels(SimdLevel::kBest).level;
  EXPECT_NE(std::find(levels.begin(), levels.end(), best), levels.end());
  for (SimdLevel l : {SimdLevel::kAvx2, SimdLevel::kAvx512})
    if (!cpu_supports(l)) {
      EXPECT_THROW(search_kernels(l), Error);
    }
  std::cout << "[          ] best search kernels on this CPU: " << to_string(best) << "\n";
}

TEST(SearchKernels, HammingMatchesTheReference) {
  std::mt19937_64 rng(1);
  std::vector<HashCode> codes(500);
  for (auto& c : codes) c = {{rng(), rng()}};
  codes[3] = {{~0ull, ~0ull}};  // distance 128 from the zero code
  const HashCode q{{0, 0}};
  std::vector<uint32_t> ids(300);
  for (auto& i : ids) i = static_cast<uint32_t>(rng() % codes.size());
  ids[0] = 3;
  const SearchKernels& ref = search_kernels(SimdLevel::kScalar);
  for (SimdLevel level : supported_simd_levels()) {
    const SearchKernels& k = search_kernels(level);
    for (size_t n : kLengths) {
      n = std::min(n, ids.size());
      std::vector<uint8_t> a(n + 1, 0xAB), b(n + 1, 0xAB);
      uint32_t ha[129] = {}, hb[129] = {};
      ref.hamming_distances(q, codes.data(), ids.data(), n, a.data(), ha);
      k.hamming_distances(q, codes.data(), ids.data(), n, b.data(), hb);
      ASSERT_EQ(a, b) << to_string(level) << " n=" << n;
      ASSERT_EQ(0, std::memcmp(ha, hb, sizeof ha)) << to_string(level);
      if (n > 0) {
        EXPECT_EQ(a[0], 128);
      }
      EXPECT_EQ(b[n], 0xAB) << "wrote past the end";
      for (size_t i = 0; i < n; ++i) ASSERT_EQ(a[i], hamming_distance(q, codes[ids[i]]));
    }
  }
}

// The refined step's selection: every level takes the same ids as the
// reference and as the plain definition (the `list` nearest by distance, ties
// by candidate order, listed in candidate order), stops at `list` and writes
// nothing at or past out[list + kShortlistSlack].
namespace {

constexpr uint32_t kCanary = 0xDEADBEEF;

// One level's selection into a buffer with canaries past its slack: the count
// and the ids taken.
std::vector<uint32_t> shortlist_checked(const SearchKernels& k, const std::vector<uint8_t>& d,
                                        const std::vector<uint32_t>& ids, uint32_t cut, uint32_t at_cut, uint32_t list,
                                        size_t& taken) {
  std::vector<uint32_t> out(list + kShortlistSlack + 4, kCanary);
  taken = k.shortlist(d.data(), ids.data(), d.size(), cut, at_cut, list, out.data());
  for (size_t i = list + kShortlistSlack; i < out.size(); ++i)
    EXPECT_EQ(out[i], kCanary) << to_string(k.level) << " wrote past the slack";
  EXPECT_LE(taken, list) << to_string(k.level);
  out.resize(std::min<size_t>(taken, list));
  return out;
}

}  // namespace

TEST(SearchKernels, ShortlistMatchesTheReferenceAndThePlainDefinition) {
  std::mt19937 rng(3);
  const SearchKernels& ref = search_kernels(SimdLevel::kScalar);
  for (int spread : {2, 3, 6, 40}) {  // few distinct distances (many ties) to many; 3: from 0
    for (size_t n : kLengths) {
      if (n == 0) continue;  // no list to take; the search never asks
      std::vector<uint8_t> d(n);
      std::vector<uint32_t> ids(n);
      for (size_t i = 0; i < n; ++i) {
        d[i] = static_cast<uint8_t>(spread == 40  ? 40 + rng() % spread
                                    : spread == 3 ? rng() % spread
                                                  : 128 - rng() % spread);
        ids[i] = static_cast<uint32_t>(rng() % 100000);
      }
      for (uint32_t list : {uint32_t(1), uint32_t(5), uint32_t(40), uint32_t(n)}) {
        if (list > n) continue;
        uint32_t hist[kHashBits + 1] = {};
        for (uint8_t x : d) ++hist[x];
        uint32_t cut = 0, below = 0;
        while (below + hist[cut] < list) below += hist[cut++];
        std::vector<size_t> order(n);
        for (size_t i = 0; i < n; ++i) order[i] = i;
        std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return d[a] < d[b]; });
        order.resize(list);
        std::sort(order.begin(), order.end());
        std::vector<uint32_t> plain;
        for (size_t i : order) plain.push_back(ids[i]);
        size_t taken = 0;
        const std::vector<uint32_t> expected = shortlist_checked(ref, d, ids, cut, list - below, list, taken);
        ASSERT_EQ(taken, list);
        ASSERT_EQ(expected, plain) << "n=" << n << " list=" << list;
        for (SimdLevel level : supported_simd_levels()) {
          ASSERT_EQ(shortlist_checked(search_kernels(level), d, ids, cut, list - below, list, taken), expected)
              << to_string(level) << " n=" << n << " list=" << list << " spread=" << spread;
          ASSERT_EQ(taken, list) << to_string(level);
        }
        // Inputs the counting sort never gives, where every level must still
        // agree with the reference, count included: a cut that admits more
        // than `list` (the first `list` are taken), more ties allowed than
        // there are (fewer than `list` taken), a cut below every distance.
        const uint32_t odd[][2] = {{kHashBits + 1, 0}, {cut, hist[cut] + 3}, {0, 0}, {0x80000000u, 0}};
        for (const auto& [c, at] : odd) {
          size_t ref_taken = 0;
          const std::vector<uint32_t> ref_out = shortlist_checked(ref, d, ids, c, at, list, ref_taken);
          for (SimdLevel level : supported_simd_levels()) {
            size_t level_taken = 0;
            ASSERT_EQ(shortlist_checked(search_kernels(level), d, ids, c, at, list, level_taken), ref_out)
                << to_string(level) << " cut=" << c << " at_cut=" << at;
            ASSERT_EQ(level_taken, ref_taken) << to_string(level) << " cut=" << c << " at_cut=" << at;
          }
        }
      }
    }
  }
}

#if defined(__linux__)
// The kernels read nothing past n (ASan does not check masked loads): the
// distances and ids end right before a page that may not be read.
TEST(SearchKernels, ShortlistReadsNothingPastItsInput) {
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
  auto guarded = [&](size_t bytes) {
    void* p = mmap(nullptr, 2 * page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED || mprotect(static_cast<char*>(p) + page, page, PROT_NONE) != 0)
      return std::pair<char*, char*>(nullptr, nullptr);
    return std::pair<char*, char*>(static_cast<char*>(p), static_cast<char*>(p) + page - bytes);
  };
  std::mt19937 rng(5);
  for (size_t n = 1; n <= 40; ++n) {
    auto [d_map, d_at] = guarded(n);
    auto [id_map, id_at] = guarded(n * sizeof(uint32_t));
    ASSERT_TRUE(d_map && id_map) << "mmap or mprotect failed";
    uint8_t* d = reinterpret_cast<uint8_t*>(d_at);
    uint32_t* ids = reinterpret_cast<uint32_t*>(id_at);
    for (size_t i = 0; i < n; ++i) {
      d[i] = static_cast<uint8_t>(rng() % 4);
      ids[i] = static_cast<uint32_t>(i);
    }
    for (SimdLevel level : supported_simd_levels()) {
      std::vector<uint32_t> out(n + kShortlistSlack);
      // Every candidate below the cut: each level reads all n and no more.
      EXPECT_EQ(search_kernels(level).shortlist(d, ids, n, 4, 0, uint32_t(n), out.data()), n) << to_string(level);
      for (size_t i = 0; i < n; ++i) ASSERT_EQ(out[i], i) << to_string(level);
    }
    munmap(d_map, 2 * page);
    munmap(id_map, 2 * page);
  }
}
#endif

TEST(SearchKernels, AdcTableIsBitIdenticalToTheCodebooksTable) {
  for (const int subvectors : kLayouts) {
    SCOPED_TRACE(std::to_string(subvectors) + "-byte codes");
    const PqCodebook cb = random_codebook(2, subvectors);
    const int dims = 128 / subvectors;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0, 160);
    std::vector<float> q(128), reference(cb.table_size()), table(cb.table_size() + 1);
    for (int trial = 0; trial < 5; ++trial) {
      for (auto& x : q) x = std::round(u(rng));  // SIFT is integer-valued
      if (trial == 4) q.assign(128, 0.37f);
      cb.distance_table(q.data(), reference.data());
      // An independent reference from the codebook's own layout, in double.
      const auto c = cb.centroids();
      for (int m = 0; m < subvectors; ++m)
        for (int k = 0; k < kPqCentroids; ++k) {
          double d = 0;
          for (int j = 0; j < dims; ++j) {
            const double e = double(q[m * dims + j]) - c[(size_t(m) * kPqCentroids + k) * dims + j];
            d += e * e;
          }
          ASSERT_NEAR(reference[m * kPqCentroids + k], d, 1e-5 * d + 1e-3);
        }
      for (SimdLevel level : supported_simd_levels()) {
        std::fill(table.begin(), table.end(), -1.f);
        search_kernels(level).adc(subvectors).table(cb.centroids_transposed(), q.data(), table.data());
        ASSERT_EQ(0, std::memcmp(reference.data(), table.data(), reference.size() * 4)) << to_string(level);
        EXPECT_EQ(table.back(), -1.f) << "wrote past the table";
      }
    }
  }
}

TEST(SearchKernels, AdcDistancesAreBitIdenticalToTheReference) {
  for (const int subvectors : kLayouts) {
    SCOPED_TRACE(std::to_string(subvectors) + "-byte codes");
    std::mt19937 rng(4);
    std::uniform_real_distribution<float> u(0, 1e4f);
    std::vector<float> table(size_t(subvectors) * kPqCentroids);
    for (auto& t : table) t = u(rng);
    const size_t points = 1000;
    std::vector<uint8_t> pq(points * subvectors);
    for (auto& b : pq) b = static_cast<uint8_t>(rng());
    std::vector<uint32_t> ids(300);
    for (auto& i : ids) i = rng() % points;
    ids[1] = points - 1;  // the last code: no read past the array
    for (SimdLevel level : supported_simd_levels()) {
      for (size_t n : kLengths) {
        n = std::min(n, ids.size());
        std::vector<float> out(n + 1, -7.f);
        search_kernels(level).adc(subvectors).distances(table.data(), pq.data(), ids.data(), n, out.data());
        for (size_t i = 0; i < n; ++i) {
          // The sum of every one of the code's bytes' entries, in increasing m.
          float ref = 0;
          for (int m = 0; m < subvectors; ++m) ref += table[m * kPqCentroids + pq[size_t(ids[i]) * subvectors + m]];
          ASSERT_EQ(0, std::memcmp(&ref, &out[i], 4)) << to_string(level) << " n=" << n << " i=" << i;
        }
        EXPECT_EQ(out[n], -7.f) << "wrote past the end";
      }
    }
  }
}

TEST(SearchKernels, AdcKernelsAreChosenByTheCodeSize) {
  const SearchKernels& k = search_kernels(SimdLevel::kScalar);
  EXPECT_EQ(k.adc(16).table, k.adc16.table);
  EXPECT_EQ(k.adc(32).direct, k.adc32.direct);
  EXPECT_NE(k.adc16.distances, k.adc32.distances);
  try {
    k.adc(24);
    ADD_FAILURE() << "24 sub-vectors accepted";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
    EXPECT_NE(std::string(e.what()).find("24 PQ sub-vectors"), std::string::npos) << e.what();
  }
}

TEST(SearchKernels, HashCodesMatchTheReference) {
  std::mt19937 rng(5);
  std::normal_distribution<float> g(0, 1);
  std::vector<float> wt(128 * 128), x(37 * 128);
  for (auto& w : wt) w = g(rng);
  for (auto& v : x) v = std::round(g(rng) * 40);
  for (int j = 0; j < 128; ++j) x[5 * 128 + j] = 0;  // all projections exactly 0: every bit 0
  const SearchKernels& ref = search_kernels(SimdLevel::kScalar);
  std::vector<HashCode> a(37), b(37);
  ref.hash_codes(wt.data(), x.data(), 37, a.data());
  EXPECT_EQ(a[5].w[0], 0u);
  EXPECT_EQ(a[5].w[1], 0u);
  // The reference is the sign of the projection (checked in double away from 0).
  for (size_t r = 0; r < 37; ++r)
    for (int i = 0; i < 128; ++i) {
      double p = 0;
      for (int j = 0; j < 128; ++j) p += double(wt[j * 128 + i]) * x[r * 128 + j];
      if (std::abs(p) > 1e-3) {
        ASSERT_EQ(((a[r].w[i / 64] >> (i % 64)) & 1) != 0, p > 0) << r << " " << i;
      }
    }
  for (SimdLevel level : supported_simd_levels())
    for (size_t n : kLengths) {
      n = std::min<size_t>(n, 37);
      std::fill(b.begin(), b.end(), HashCode{{7, 7}});
      search_kernels(level).hash_codes(wt.data(), x.data(), n, b.data());
      for (size_t r = 0; r < n; ++r) {
        ASSERT_EQ(a[r].w[0], b[r].w[0]) << to_string(level) << " row " << r;
        ASSERT_EQ(a[r].w[1], b[r].w[1]) << to_string(level) << " row " << r;
      }
      if (n < 37) {
        EXPECT_EQ(b[n].w[0], 7u) << "wrote past the end";
      }
    }
}

// The integer hash: the reference is checked against an independent int64
// sum, with weights and descriptors at their extremes (±32,767, 255: the
// largest sums) and thresholds at both ends of int32; every level equals it.
TEST(SearchKernels, HashCodesU8AndTheirMarginsMatchTheReference) {
  std::mt19937 rng(9);
  constexpr size_t kRows = 41;  // blocks of 8 and 4 rows, and a tail
  // Wq[i][j] in both layouts of QuantizedHashProjection.
  std::vector<int16_t> wq(128 * 128);
  for (auto& w : wq) w = static_cast<int16_t>(int(rng() % 65535) - 32767);
  for (int j = 0; j < 128; ++j) wq[3 * 128 + j] = 32767, wq[70 * 128 + j] = -32767;
  QuantizedHashProjection q;
  q.weight_pairs.resize(128 * 128);
  q.weights_transposed.resize(128 * 128);
  for (int i = 0; i < 128; ++i)
    for (int j = 0; j < 128; ++j) {
      q.weight_pairs[(j / 2) * 256 + 2 * i + (j & 1)] = wq[i * 128 + j];
      q.weights_transposed[j * 128 + i] = wq[i * 128 + j];
    }
  std::vector<int32_t>& t = q.thresholds;
  t.resize(128);
  for (auto& v : t) v = static_cast<int32_t>(int(rng() % 2000001) - 1000000);
  t[5] = -(1 << 30), t[6] = 1 << 30, t[7] = 0;  // quantize_hash_projection's extremes: always, never
  std::vector<uint8_t> x(kRows * 128);
  for (auto& v : x) v = static_cast<uint8_t>(rng());
  for (int j = 0; j < 128; ++j) x[2 * 128 + j] = 255, x[4 * 128 + j] = 0;
  const SearchKernels& ref = search_kernels(SimdLevel::kScalar);
  std::vector<HashCode> a(kRows), b(kRows + 1), c(kRows);
  std::vector<int32_t> margins(kRows * 128), other_margins((kRows + 1) * 128);
  ref.hash_codes_u8(q, x.data(), kRows, a.data(), margins.data());
  ref.hash_codes_u8(q, x.data(), kRows, c.data(), nullptr);
  int set = 0;
  for (size_t r = 0; r < kRows; ++r) {
    ASSERT_EQ(a[r].w[0], c[r].w[0]);  // the margins change no bit
    ASSERT_EQ(a[r].w[1], c[r].w[1]);
    for (int i = 0; i < 128; ++i) {
      int64_t p = 0;
      for (int j = 0; j < 128; ++j) p += int64_t(wq[i * 128 + j]) * x[r * 128 + j];
      const bool bit = (a[r].w[i / 64] >> (i % 64)) & 1;
      ASSERT_EQ(bit, p > t[i]) << "row " << r << " bit " << i;
      ASSERT_EQ(int64_t(margins[r * 128 + i]), std::llabs(p - t[i])) << "row " << r << " bit " << i;
      set += bit;
    }
  }
  EXPECT_GT(set, 1000);  // both values occur
  EXPECT_LT(set, int(kRows * 128) - 1000);
  EXPECT_EQ((a[2].w[0] >> 3) & 1, 1u);  // 128 × 32,767 × 255: no overflow
  EXPECT_EQ((a[2].w[1] >> 6) & 1, 0u);  // -128 × 32,767 × 255
  for (SimdLevel level : supported_simd_levels())
    for (size_t n : kLengths) {
      n = std::min(n, kRows);
      std::fill(b.begin(), b.end(), HashCode{{7, 7}});
      std::fill(other_margins.begin(), other_margins.end(), -7);
      search_kernels(level).hash_codes_u8(q, x.data(), n, b.data(), nullptr);
      for (size_t r = 0; r < n; ++r) {
        ASSERT_EQ(a[r].w[0], b[r].w[0]) << to_string(level) << " n=" << n << " row " << r;
        ASSERT_EQ(a[r].w[1], b[r].w[1]) << to_string(level) << " n=" << n << " row " << r;
      }
      EXPECT_EQ(b[n].w[0], 7u) << "wrote past the end";
      std::fill(b.begin(), b.end(), HashCode{{7, 7}});
      search_kernels(level).hash_codes_u8(q, x.data(), n, b.data(), other_margins.data());
      for (size_t r = 0; r < n; ++r) {
        ASSERT_EQ(a[r].w[0], b[r].w[0]) << to_string(level) << " n=" << n << " row " << r;
        for (int i = 0; i < 128; ++i)
          ASSERT_EQ(margins[r * 128 + i], other_margins[r * 128 + i])
              << to_string(level) << " n=" << n << " row " << r << " bit " << i;
      }
      EXPECT_EQ(other_margins[n * 128], -7) << "wrote margins past the end";
    }
}

// The direct distances: every level equals the scalar reference bit for bit;
// they are the table's distances summed in another order, so equal to them
// within float rounding (relative 1e-5).
TEST(SearchKernels, AdcDirectEqualsItsReferenceAndTheTableWithinRounding) {
  for (const int subvectors : kLayouts) {
    SCOPED_TRACE(std::to_string(subvectors) + "-byte codes");
    const PqCodebook cb = random_codebook(7, subvectors);
    std::mt19937 rng(8);
    std::uniform_real_distribution<float> u(0, 160);
    std::vector<float> q(128), table(cb.table_size());
    for (auto& x : q) x = std::round(u(rng));
    const size_t points = 700;
    std::vector<uint8_t> pq(points * subvectors);
    for (auto& b : pq) b = static_cast<uint8_t>(rng());
    for (int m = 0; m < subvectors; ++m)
      pq[m] = 255, pq[subvectors + m] = 0;  // the last and first centroid of every sub-space
    std::vector<uint32_t> ids(120);
    for (auto& i : ids) i = rng() % points;
    ids[0] = 0, ids[1] = 1, ids[2] = points - 1;
    const AdcKernels& ref = search_kernels(SimdLevel::kScalar).adc(subvectors);
    ref.table(cb.centroids_transposed(), q.data(), table.data());
    std::vector<float> via_table(ids.size()), direct(ids.size());
    ref.distances(table.data(), pq.data(), ids.data(), ids.size(), via_table.data());
    ref.direct(cb.centroids().data(), q.data(), pq.data(), ids.data(), ids.size(), direct.data());
    for (size_t i = 0; i < ids.size(); ++i) {
      ASSERT_GT(via_table[i], 0.f);
      EXPECT_NEAR(direct[i], via_table[i], 1e-5 * via_table[i]) << "candidate " << i;
      // The codebook's own reconstruction distance, in double.
      const double exact = cb.reconstruction_sqdist(pq.data() + size_t(ids[i]) * subvectors, q.data());
      EXPECT_NEAR(direct[i], exact, 1e-5 * exact) << "candidate " << i;
    }
    for (SimdLevel level : supported_simd_levels())
      for (size_t n : kLengths) {
        n = std::min(n, ids.size());
        std::vector<float> out(n + 1, -3.f);
        search_kernels(level)
            .adc(subvectors)
            .direct(cb.centroids().data(), q.data(), pq.data(), ids.data(), n, out.data());
        ASSERT_EQ(0, std::memcmp(direct.data(), out.data(), n * 4)) << to_string(level) << " n=" << n;
        EXPECT_EQ(out[n], -3.f) << "wrote past the end";
      }
  }
}

// The residual codes' direct distances: every level equals the scalar
// reference bit for bit, at every split count and tail length, and the
// reference is the distance to the codebook's decoded vector (in double,
// within float rounding). Codebook entries of either sign, as a residual
// quantizer's later codebooks have.
TEST(SearchKernels, AdditiveDirectEqualsItsReferenceAndTheDecodedDistance) {
  for (const int splits : {1, 2, 4}) {
    SCOPED_TRACE(std::to_string(splits) + " splits");
    std::mt19937 rng(20 + splits);
    std::uniform_real_distribution<float> u(-40, 40);
    std::vector<float> books(size_t(kAdditiveCodebooks) * kPqCentroids * (128 / splits));
    for (auto& x : books) x = u(rng);
    const PqCodebook cb = PqCodebook::residual(books, splits);
    std::uniform_real_distribution<float> uq(0, 160);
    std::vector<float> q(128);
    for (auto& x : q) x = std::round(uq(rng));
    const size_t points = 700;
    std::vector<uint8_t> codes(points * kAdditiveCodebooks);
    for (auto& b : codes) b = static_cast<uint8_t>(rng());
    for (int m = 0; m < kAdditiveCodebooks; ++m) codes[m] = 255, codes[kAdditiveCodebooks + m] = 0;
    std::vector<uint32_t> ids(120);
    for (auto& i : ids) i = rng() % points;
    ids[0] = 0, ids[1] = 1, ids[2] = points - 1;
    std::vector<float> direct(ids.size());
    search_kernels(SimdLevel::kScalar)
        .additive.direct(splits)(cb.centroids().data(), q.data(), codes.data(), ids.data(), ids.size(), direct.data());
    for (size_t i = 0; i < ids.size(); ++i) {
      const double exact = cb.reconstruction_sqdist(codes.data() + size_t(ids[i]) * kAdditiveCodebooks, q.data());
      ASSERT_GT(exact, 0.0);
      EXPECT_NEAR(direct[i], exact, 1e-5 * exact) << "candidate " << i;
    }
    for (SimdLevel level : supported_simd_levels())
      for (size_t n : kLengths) {
        n = std::min(n, ids.size());
        std::vector<float> out(n + 1, -3.f);
        search_kernels(level).additive.direct(splits)(cb.centroids().data(), q.data(), codes.data(), ids.data(), n,
                                                      out.data());
        ASSERT_EQ(0, std::memcmp(direct.data(), out.data(), n * 4)) << to_string(level) << " n=" << n;
        EXPECT_EQ(out[n], -3.f) << "wrote past the end";
      }
  }
  EXPECT_THROW(search_kernels(SimdLevel::kScalar).additive.direct(3), Error);
}
