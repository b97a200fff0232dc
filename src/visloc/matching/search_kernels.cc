#include "visloc/matching/search_kernels.h"

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <cstring>

#include "visloc/features/feature_set.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/util/error.h"

#if defined(__x86_64__) && defined(__GNUC__)
#define VISLOC_X86_KERNELS 1
#include <immintrin.h>
#endif

namespace visloc {
namespace {

// ---- Scalar reference --------------------------------------------------------

void hamming_scalar(const HashCode& q, const HashCode* codes, const uint32_t* ids, size_t n, uint8_t* out,
                    uint32_t* hist) {
  for (size_t i = 0; i < n; ++i) {
    const HashCode& c = codes[ids[i]];
    const uint32_t d = static_cast<uint32_t>(std::popcount(q.w[0] ^ c.w[0]) + std::popcount(q.w[1] ^ c.w[1]));
    out[i] = static_cast<uint8_t>(d);
    ++hist[d];
  }
}

// Branch-free: every candidate is written, and counted when it is below the
// cut or among the first `at_cut` at it.
size_t shortlist_scalar(const uint8_t* distances, const uint32_t* ids, size_t n, uint32_t cut, uint32_t at_cut,
                        uint32_t list, uint32_t* out) {
  size_t taken = 0;
  for (size_t i = 0; i < n && taken < list; ++i) {
    const uint32_t h = distances[i];
    const uint32_t tie = static_cast<uint32_t>(h == cut) & static_cast<uint32_t>(at_cut > 0);
    out[taken] = ids[i];
    taken += static_cast<uint32_t>(h < cut) | tie;
    at_cut -= tie;
  }
  return taken;
}

// M sub-vectors of D = 128 / M dimensions (pq_codebook.h).
template <int M>
constexpr int kSubDim = kDescriptorDim / M;

template <int M>
void adc_table_scalar(const float* ct, const float* q, float* table) {
  constexpr int D = kSubDim<M>;
  for (int m = 0; m < M; ++m)
    for (int k = 0; k < kPqCentroids; ++k) {
      float d = 0;
      for (int j = 0; j < D; ++j) {
        const float e = q[m * D + j] - ct[(m * D + j) * kPqCentroids + k];
        d += e * e;
      }
      table[m * kPqCentroids + k] = d;
    }
}

template <int M>
void adc_distances_scalar(const float* table, const uint8_t* pq, const uint32_t* ids, size_t n, float* out) {
  for (size_t i = 0; i < n; ++i) out[i] = adc_distance(table, pq + size_t(ids[i]) * M, M);
}

// The direct distance's own order, which its SIMD variants follow lane for
// lane. The 128 dimensions are 16 rows of 8 lanes (row r = dimensions 8r ..
// 8r + 7): with M = 16 a row is one sub-vector's centroid, with M = 32 the
// centroids of sub-vectors 2r and 2r + 1 side by side. Per lane, two partial
// sums of squared differences over the rows (even r, odd r, each in
// increasing r), added; then the 8 lanes by a fixed tree
// ((0+4)+(2+6)) + ((1+5)+(3+7)).
template <int M>
void adc_direct_scalar(const float* c, const float* q, const uint8_t* pq, const uint32_t* ids, size_t n, float* out) {
  constexpr int D = kSubDim<M>;
  constexpr int kRows = 16, kLanes = 8, kPerRow = kLanes / D;  // sub-vectors per row
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* code = pq + size_t(ids[i]) * M;
    float even[kLanes] = {}, odd[kLanes] = {};
    // Row r's 8 lanes: the centroid rows of its kPerRow sub-vectors, side by side.
    auto add_row = [&](int r, float* acc) {
      float row[kLanes];
      for (int h = 0; h < kPerRow; ++h) {
        const int m = r * kPerRow + h;
        const float* centroid = c + (size_t(m) * kPqCentroids + code[m]) * D;
        for (int j = 0; j < D; ++j) row[h * D + j] = centroid[j];
      }
      for (int l = 0; l < kLanes; ++l) {
        const float e = q[r * kLanes + l] - row[l];
        acc[l] = acc[l] + e * e;
      }
    };
    for (int r = 0; r < kRows; r += 2) {
      add_row(r, even);
      add_row(r + 1, odd);
    }
    float s[kLanes];
    for (int l = 0; l < kLanes; ++l) s[l] = even[l] + odd[l];
    const float h0 = s[0] + s[4], h1 = s[1] + s[5], h2 = s[2] + s[6], h3 = s[3] + s[7];
    out[i] = (h0 + h2) + (h1 + h3);
  }
}

// The residual (additive) codes' direct distance (search_kernels.h), in
// adc_direct_scalar's order: the 128 dimensions are 16 rows of 8 lanes; a
// row of the decoded point is the sum of its split's codebook rows in
// increasing codebook (the first row as it is, then each next one added); per
// lane, the even and odd rows' squared differences summed apart, added; then
// the 8 lanes by the same tree.
template <int S>
void additive_direct_scalar(const float* c, const float* q, const uint8_t* codes, const uint32_t* ids, size_t n,
                            float* out) {
  constexpr int kBooks = kAdditiveCodebooks / S;  // codebooks per split
  constexpr int D = kDescriptorDim / S;           // their dimensions
  constexpr int kRowsPerSplit = D / 8, kLanes = 8;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* code = codes + size_t(ids[i]) * kAdditiveCodebooks;
    float even[kLanes] = {}, odd[kLanes] = {};
    for (int r = 0; r < 16; ++r) {
      const int split = r / kRowsPerSplit, row = r % kRowsPerSplit;
      const int m0 = split * kBooks;
      float x[kLanes];
      const float* first = c + (size_t(m0) * kPqCentroids + code[m0]) * D + row * kLanes;
      for (int l = 0; l < kLanes; ++l) x[l] = first[l];
      for (int t = 1; t < kBooks; ++t) {
        const int m = m0 + t;
        const float* entry = c + (size_t(m) * kPqCentroids + code[m]) * D + row * kLanes;
        for (int l = 0; l < kLanes; ++l) x[l] = x[l] + entry[l];
      }
      float* acc = r % 2 == 0 ? even : odd;
      for (int l = 0; l < kLanes; ++l) {
        const float e = q[r * kLanes + l] - x[l];
        acc[l] = acc[l] + e * e;
      }
    }
    float s[kLanes];
    for (int l = 0; l < kLanes; ++l) s[l] = even[l] + odd[l];
    const float h0 = s[0] + s[4], h1 = s[1] + s[5], h2 = s[2] + s[6], h3 = s[3] + s[7];
    out[i] = (h0 + h2) + (h1 + h3);
  }
}

void hash_codes_scalar(const float* wt, const float* x, size_t n, HashCode* codes) {
  float p[kHashBits];
  for (size_t r = 0; r < n; ++r) {
    const float* xr = x + r * kDescriptorDim;
    for (int i = 0; i < kHashBits; ++i) p[i] = 0;
    for (int j = 0; j < kDescriptorDim; ++j) {
      const float xj = xr[j];
      const float* w = wt + j * kHashBits;
      for (int i = 0; i < kHashBits; ++i) p[i] += w[i] * xj;
    }
    HashCode c{{0, 0}};
    for (int i = 0; i < kHashBits; ++i) c.w[i >> 6] |= static_cast<uint64_t>(p[i] > 0.0f) << (i & 63);
    codes[r] = c;
  }
}

// Exact int32 sums: |Wq| ≤ 32,767 and x ≤ 255 bound any sum of 128 products by
// 1.07e9 < 2^31, so the order of the additions does not matter. Wq is read
// transposed: per dimension j, a contiguous row of 128 int16 times one x_j,
// which compilers turn into widening multiply-adds (SSE2, NEON).
void hash_codes_u8_scalar(const QuantizedHashProjection& q, const uint8_t* x, size_t n, HashCode* codes,
                          int32_t* margins) {
  const int16_t* wt = q.weights_transposed.data();
  const int32_t* t = q.thresholds.data();
  int32_t p[kHashBits];
  for (size_t r = 0; r < n; ++r) {
    const uint8_t* xr = x + r * kDescriptorDim;
    for (int i = 0; i < kHashBits; ++i) p[i] = 0;
    for (int j = 0; j < kDescriptorDim; ++j) {
      const int32_t xj = xr[j];
      const int16_t* w = wt + j * kHashBits;
      for (int i = 0; i < kHashBits; ++i) p[i] += w[i] * xj;
    }
    HashCode c{{0, 0}};
    for (int i = 0; i < kHashBits; ++i) c.w[i >> 6] |= static_cast<uint64_t>(p[i] > t[i]) << (i & 63);
    codes[r] = c;
    if (margins)
      for (int i = 0; i < kHashBits; ++i)  // in int64: no overflow whatever the thresholds
        margins[r * kHashBits + i] =
            static_cast<int32_t>(std::min<int64_t>(std::llabs(int64_t(p[i]) - t[i]), INT32_MAX));
  }
}

#ifdef VISLOC_X86_KERNELS

// ---- x86-64: POPCNT + AVX2 -----------------------------------------------------

// Two candidates per step into two histograms, added at the end: neighbouring
// candidates often share a distance, and one histogram would chain their
// increments through memory.
__attribute__((target("popcnt"))) void hamming_popcnt(const HashCode& q, const HashCode* codes, const uint32_t* ids,
                                                       size_t n, uint8_t* out, uint32_t* hist) {
  const uint64_t q0 = q.w[0], q1 = q.w[1];
  uint32_t odd_hist[kHashBits + 1] = {};
  size_t i = 0;
  for (; i + 2 <= n; i += 2) {
    const HashCode& a = codes[ids[i]];
    const HashCode& b = codes[ids[i + 1]];
    const uint32_t da = static_cast<uint32_t>(__builtin_popcountll(q0 ^ a.w[0]) + __builtin_popcountll(q1 ^ a.w[1]));
    const uint32_t db = static_cast<uint32_t>(__builtin_popcountll(q0 ^ b.w[0]) + __builtin_popcountll(q1 ^ b.w[1]));
    out[i] = static_cast<uint8_t>(da);
    out[i + 1] = static_cast<uint8_t>(db);
    ++hist[da];
    ++odd_hist[db];
  }
  if (i < n) {
    const HashCode& c = codes[ids[i]];
    const uint32_t d = static_cast<uint32_t>(__builtin_popcountll(q0 ^ c.w[0]) + __builtin_popcountll(q1 ^ c.w[1]));
    out[i] = static_cast<uint8_t>(d);
    ++hist[d];
  }
  for (int d = 0; d <= kHashBits; ++d) hist[d] += odd_hist[d];
}

// The first `count` set bits of `mask` (count < popcount(mask)).
inline uint32_t lowest_set_bits(uint32_t mask, uint32_t count) {
  uint32_t rest = mask;
  for (uint32_t k = 0; k < count; ++k) rest &= rest - 1;
  return mask ^ rest;
}

// 8 candidates per step: their distances compared with the cut in a vector,
// the taken ids moved to the front by a permutation from a table indexed by
// the 8-bit mask, all 8 stored. Each step's ties are cut to their lowest
// `at_cut` bits (none once at_cut is 0). The cut is compared as a signed
// int32: clamped to 256, above every uint8 distance, it selects the same.
struct CompressTable8 {
  uint64_t index[256];  // byte j: the lane of the j-th set bit
  constexpr CompressTable8() : index() {
    for (uint32_t m = 0; m < 256; ++m) {
      uint64_t v = 0;
      int j = 0;
      for (uint32_t lane = 0; lane < 8; ++lane)
        if (m & (1u << lane)) v |= uint64_t(lane) << (8 * j++);
      index[m] = v;
    }
  }
};
constexpr CompressTable8 kCompress8;

__attribute__((target("popcnt,avx2"))) size_t shortlist_avx2(const uint8_t* distances, const uint32_t* ids, size_t n,
                                                             uint32_t cut, uint32_t at_cut, uint32_t list,
                                                             uint32_t* out) {
  const __m256i cut_v = _mm256_set1_epi32(static_cast<int>(std::min(cut, 256u)));
  size_t taken = 0, i = 0;
  for (; i + 8 <= n && taken < list; i += 8) {
    uint64_t d8;
    std::memcpy(&d8, distances + i, 8);
    const __m256i d = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(d8)));
    const uint32_t below = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(cut_v, d))));
    uint32_t at = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(cut_v, d))));
    const uint32_t ties = static_cast<uint32_t>(__builtin_popcount(at));
    if (ties > at_cut) at = lowest_set_bits(at, at_cut);
    at_cut -= std::min(ties, at_cut);
    const uint32_t take = below | at;
    const __m256i lanes = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kCompress8.index[take])));
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(ids + i));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + taken), _mm256_permutevar8x32_epi32(v, lanes));
    taken += static_cast<size_t>(__builtin_popcount(take));
  }
  if (taken < list)
    taken +=
        shortlist_scalar(distances + i, ids + i, n - i, cut, at_cut, static_cast<uint32_t>(list - taken), out + taken);
  return std::min<size_t>(taken, list);
}

// Four blocks of 8 centroids at a time: independent sums, so the adds of
// different blocks overlap (one block alone waits on its add chain).
template <int M>
__attribute__((target("avx2"))) void adc_table_avx2(const float* ct, const float* q, float* table) {
  constexpr int D = kSubDim<M>;
  for (int m = 0; m < M; ++m) {
    __m256 qj[D];
    for (int j = 0; j < D; ++j) qj[j] = _mm256_set1_ps(q[m * D + j]);
    for (int k = 0; k < kPqCentroids; k += 32) {
      __m256 acc[4];
      for (auto& a : acc) a = _mm256_setzero_ps();
      for (int j = 0; j < D; ++j) {
        const float* c = ct + (m * D + j) * kPqCentroids + k;
        for (int u = 0; u < 4; ++u) {
          const __m256 e = _mm256_sub_ps(qj[j], _mm256_loadu_ps(c + 8 * u));
          acc[u] = _mm256_add_ps(acc[u], _mm256_mul_ps(e, e));
        }
      }
      for (int u = 0; u < 4; ++u) _mm256_storeu_ps(table + m * kPqCentroids + k + 8 * u, acc[u]);
    }
  }
}

// Eight candidates at a time: their codes' 32-bit words and then the table
// entries are gathered; the sum runs over m = 0..M-1 in order, as the reference.
template <int M>
__attribute__((target("avx2"))) void adc_distances_avx2(const float* table, const uint8_t* pq, const uint32_t* ids,
                                                        size_t n, float* out) {
  static_assert(M == 16 || M == 32);
  constexpr int kWordShift = M == 16 ? 2 : 3;  // a code is M / 4 32-bit words
  // The word indices id · M / 4 + w are int32 lanes (< 2^31 while ids stay
  // below CascadeLookup::kMaxPoints: a static_assert in cascade_index.cc).
  const int* words = reinterpret_cast<const int*>(pq);
  const __m256i byte_mask = _mm256_set1_epi32(0xFF);
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256i base = _mm256_slli_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(ids + i)), kWordShift);
    __m256 acc = _mm256_setzero_ps();
    for (int w = 0; w < M / 4; ++w) {
      const __m256i code_word = _mm256_i32gather_epi32(words, _mm256_add_epi32(base, _mm256_set1_epi32(w)), 4);
      for (int b = 0; b < 4; ++b) {
        const int m = 4 * w + b;
        const __m256i idx = _mm256_add_epi32(_mm256_and_si256(_mm256_srli_epi32(code_word, 8 * b), byte_mask),
                                             _mm256_set1_epi32(m * kPqCentroids));
        acc = _mm256_add_ps(acc, _mm256_i32gather_ps(table, idx, 4));
      }
    }
    _mm256_storeu_ps(out + i, acc);
  }
  adc_distances_scalar<M>(table, pq, ids + i, n - i, out + i);
}

// One row at a time: 16 accumulators of 8 outputs, the sum over j in order.
__attribute__((target("avx2"))) void hash_codes_avx2_rows(const float* wt, const float* x, size_t n,
                                                           HashCode* codes) {
  for (size_t r = 0; r < n; ++r) {
    const float* xr = x + r * kDescriptorDim;
    __m256 acc[16];
    for (auto& a : acc) a = _mm256_setzero_ps();
    for (int j = 0; j < kDescriptorDim; ++j) {
      const __m256 xj = _mm256_set1_ps(xr[j]);
      const float* w = wt + j * kHashBits;
      for (int t = 0; t < 16; ++t) acc[t] = _mm256_add_ps(acc[t], _mm256_mul_ps(_mm256_loadu_ps(w + 8 * t), xj));
    }
    HashCode c{{0, 0}};
    const __m256 zero = _mm256_setzero_ps();
    for (int t = 0; t < 16; ++t) {
      const uint64_t bits = static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(acc[t], zero, _CMP_GT_OQ)));
      c.w[t >> 3] |= bits << (8 * (t & 7));
    }
    codes[r] = c;
  }
}

// Blocks of 4 rows × 32 outputs (16 accumulators): the 16 KiB slice of W for
// 32 outputs stays in L1 while 4 rows pass over it; same order as the reference.
__attribute__((target("avx2"))) void hash_codes_avx2(const float* wt, const float* x, size_t n, HashCode* codes) {
  constexpr int kRows = 4;
  size_t r0 = 0;
  for (; r0 + kRows <= n; r0 += kRows) {
    HashCode c[kRows] = {};
    for (int ib = 0; ib < kHashBits / 32; ++ib) {
      __m256 acc[kRows][4];
      for (auto& a : acc)
        for (auto& v : a) v = _mm256_setzero_ps();
      for (int j = 0; j < kDescriptorDim; ++j) {
        __m256 w[4];
        for (int t = 0; t < 4; ++t) w[t] = _mm256_loadu_ps(wt + j * kHashBits + 32 * ib + 8 * t);
        for (int r = 0; r < kRows; ++r) {
          const __m256 b = _mm256_set1_ps(x[(r0 + r) * kDescriptorDim + j]);
          for (int t = 0; t < 4; ++t) acc[r][t] = _mm256_add_ps(acc[r][t], _mm256_mul_ps(w[t], b));
        }
      }
      const __m256 zero = _mm256_setzero_ps();
      for (int r = 0; r < kRows; ++r) {
        uint64_t bits = 0;
        for (int t = 0; t < 4; ++t)
          bits |= uint64_t(static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(acc[r][t], zero, _CMP_GT_OQ))))
                  << (8 * t);
        c[r].w[ib >> 1] |= bits << (32 * (ib & 1));
      }
    }
    for (int r = 0; r < kRows; ++r) codes[r0 + r] = c[r];
  }
  hash_codes_avx2_rows(wt, x + r0 * kDescriptorDim, n - r0, codes + r0);
}

// Row r of the centroids of one code (adc_direct_scalar's rows): with
// M = 16 one 8-float load, with M = 32 two 4-float loads side by side.
template <int M>
__attribute__((target("avx2"), always_inline)) inline __m256 centroid_row(const float* c, const uint8_t* code, int r) {
  if constexpr (M == 16) {
    return _mm256_loadu_ps(c + (size_t(r) * kPqCentroids + code[r]) * 8);
  } else {
    static_assert(M == 32);
    const int m = 2 * r;
    const __m128 lo = _mm_loadu_ps(c + (size_t(m) * kPqCentroids + code[m]) * 4);
    const __m128 hi = _mm_loadu_ps(c + (size_t(m + 1) * kPqCentroids + code[m + 1]) * 4);
    return _mm256_insertf128_ps(_mm256_castps128_ps256(lo), hi, 1);
  }
}

// Lanes are the 8 dimensions of a row: each row of centroids is one 8-float
// register, the rows accumulate into two registers (even and odd r), and one
// horizontal sum per candidate follows adc_direct_scalar's tree.
// The body of adc_direct_avx2, also compiled into the AVX-512 level's
// function, where 32 vector registers hold the query's rows and the
// accumulators with at most one reload per candidate (AVX2 has 16 registers,
// and reloads most of the 16 rows from the stack).
template <int M>
__attribute__((target("avx2"), always_inline)) inline void adc_direct_ymm(const float* c, const float* q,
                                                                          const uint8_t* pq, const uint32_t* ids,
                                                                          size_t n, float* out) {
  constexpr int kRows = 16;
  __m256 qm[kRows];
  for (int r = 0; r < kRows; ++r) qm[r] = _mm256_loadu_ps(q + r * 8);
  constexpr size_t kAhead = 4;  // the codes of a later candidate are fetched while this one is summed
  for (size_t i = 0; i < n; ++i) {
    if (i + kAhead < n) _mm_prefetch(reinterpret_cast<const char*>(pq + size_t(ids[i + kAhead]) * M), _MM_HINT_T0);
    const uint8_t* code = pq + size_t(ids[i]) * M;
    __m256 even = _mm256_setzero_ps(), odd = _mm256_setzero_ps();
    for (int r = 0; r < kRows; r += 2) {
      const __m256 e0 = _mm256_sub_ps(qm[r], centroid_row<M>(c, code, r));
      const __m256 e1 = _mm256_sub_ps(qm[r + 1], centroid_row<M>(c, code, r + 1));
      even = _mm256_add_ps(even, _mm256_mul_ps(e0, e0));
      odd = _mm256_add_ps(odd, _mm256_mul_ps(e1, e1));
    }
    const __m256 s = _mm256_add_ps(even, odd);
    const __m128 h = _mm_add_ps(_mm256_castps256_ps128(s), _mm256_extractf128_ps(s, 1));  // s_j + s_{j+4}
    const __m128 g = _mm_add_ps(h, _mm_movehl_ps(h, h));                                  // (h0+h2, h1+h3)
    out[i] = _mm_cvtss_f32(_mm_add_ss(g, _mm_shuffle_ps(g, g, 1)));
  }
}

template <int M>
__attribute__((target("avx2"))) void adc_direct_avx2(const float* c, const float* q, const uint8_t* pq,
                                                     const uint32_t* ids, size_t n, float* out) {
  adc_direct_ymm<M>(c, q, pq, ids, n, out);
}

// additive_direct_scalar lane for lane: a row of the decoded point is one
// register, its codebook rows added in increasing codebook.
template <int S>
__attribute__((target("avx2"), always_inline)) inline void additive_direct_ymm(const float* c, const float* q,
                                                                               const uint8_t* codes,
                                                                               const uint32_t* ids, size_t n,
                                                                               float* out) {
  constexpr int kBooks = kAdditiveCodebooks / S, D = kDescriptorDim / S, kRowsPerSplit = D / 8;
  constexpr size_t kAhead = 2;
  for (size_t i = 0; i < n; ++i) {
    if (i + kAhead < n)
      _mm_prefetch(reinterpret_cast<const char*>(codes + size_t(ids[i + kAhead]) * kAdditiveCodebooks), _MM_HINT_T0);
    const uint8_t* code = codes + size_t(ids[i]) * kAdditiveCodebooks;
    const float* entry[kAdditiveCodebooks];
    for (int m = 0; m < kAdditiveCodebooks; ++m) entry[m] = c + (size_t(m) * kPqCentroids + code[m]) * D;
    __m256 even = _mm256_setzero_ps(), odd = _mm256_setzero_ps();
    for (int r = 0; r < 16; r += 2) {
      __m256 x[2];
      for (int h = 0; h < 2; ++h) {
        const int split = (r + h) / kRowsPerSplit, row = (r + h) % kRowsPerSplit;
        x[h] = _mm256_loadu_ps(entry[split * kBooks] + row * 8);
        for (int t = 1; t < kBooks; ++t)
          x[h] = _mm256_add_ps(x[h], _mm256_loadu_ps(entry[split * kBooks + t] + row * 8));
      }
      const __m256 e0 = _mm256_sub_ps(_mm256_loadu_ps(q + r * 8), x[0]);
      const __m256 e1 = _mm256_sub_ps(_mm256_loadu_ps(q + (r + 1) * 8), x[1]);
      even = _mm256_add_ps(even, _mm256_mul_ps(e0, e0));
      odd = _mm256_add_ps(odd, _mm256_mul_ps(e1, e1));
    }
    const __m256 s = _mm256_add_ps(even, odd);
    const __m128 h = _mm_add_ps(_mm256_castps256_ps128(s), _mm256_extractf128_ps(s, 1));
    const __m128 g = _mm_add_ps(h, _mm_movehl_ps(h, h));
    out[i] = _mm_cvtss_f32(_mm_add_ss(g, _mm_shuffle_ps(g, g, 1)));
  }
}

template <int S>
__attribute__((target("avx2"))) void additive_direct_avx2(const float* c, const float* q, const uint8_t* codes,
                                                          const uint32_t* ids, size_t n, float* out) {
  additive_direct_ymm<S>(c, q, codes, ids, n, out);
}

// Blocks of 4 rows × 16 outputs (8 accumulators of 8 int32): per pair of
// dimensions, one multiply-add of int16 pairs (vpmaddwd) and one add per
// accumulator. The rows are widened to int16 once, so that a pair (x_2p,
// x_2p+1) is one 32-bit broadcast. Exact, so equal to the reference.
__attribute__((target("avx2"))) void hash_codes_u8_avx2(const QuantizedHashProjection& q, const uint8_t* x, size_t n,
                                                        HashCode* codes, int32_t* margins) {
  const int16_t* wp = q.weight_pairs.data();
  const int32_t* t = q.thresholds.data();
  constexpr int kRows = 4;
  alignas(32) int16_t widened[kRows][kDescriptorDim];
  size_t r0 = 0;
  for (; r0 + kRows <= n; r0 += kRows) {
    for (int r = 0; r < kRows; ++r)
      for (int j = 0; j < kDescriptorDim; j += 16)
        _mm256_store_si256(
            reinterpret_cast<__m256i*>(&widened[r][j]),
            _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(x + (r0 + r) * kDescriptorDim + j))));
    HashCode c[kRows] = {};
    for (int ib = 0; ib < kHashBits / 16; ++ib) {
      __m256i acc[kRows][2];
      for (auto& a : acc) a[0] = a[1] = _mm256_setzero_si256();
      for (int pair = 0; pair < kDescriptorDim / 2; ++pair) {
        const int16_t* w = wp + (pair * kHashBits + 16 * ib) * 2;
        const __m256i w0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(w));
        const __m256i w1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(w + 16));
        for (int r = 0; r < kRows; ++r) {
          int32_t xx;
          std::memcpy(&xx, &widened[r][2 * pair], 4);
          const __m256i b = _mm256_set1_epi32(xx);
          acc[r][0] = _mm256_add_epi32(acc[r][0], _mm256_madd_epi16(w0, b));
          acc[r][1] = _mm256_add_epi32(acc[r][1], _mm256_madd_epi16(w1, b));
        }
      }
      const __m256i t0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(t + 16 * ib));
      const __m256i t1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(t + 16 * ib + 8));
      for (int r = 0; r < kRows; ++r) {
        const uint64_t lo =
            static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(acc[r][0], t0))));
        const uint64_t hi =
            static_cast<uint32_t>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(acc[r][1], t1))));
        c[r].w[ib >> 2] |= (lo | (hi << 8)) << (16 * (ib & 3));
        if (margins) {
          int32_t* m = margins + (r0 + r) * kHashBits + 16 * ib;
          _mm256_storeu_si256(reinterpret_cast<__m256i*>(m), _mm256_abs_epi32(_mm256_sub_epi32(acc[r][0], t0)));
          _mm256_storeu_si256(reinterpret_cast<__m256i*>(m + 8), _mm256_abs_epi32(_mm256_sub_epi32(acc[r][1], t1)));
        }
      }
    }
    for (int r = 0; r < kRows; ++r) codes[r0 + r] = c[r];
  }
  hash_codes_u8_scalar(q, x + r0 * kDescriptorDim, n - r0, codes + r0, margins ? margins + r0 * kHashBits : nullptr);
}

// ---- x86-64: AVX-512F ------------------------------------------------------------

// adc_direct_avx2's code with AVX-512VL's 32 vector registers.
template <int M>
__attribute__((target("avx512f,avx512vl"))) void adc_direct_avx512(const float* c, const float* q, const uint8_t* pq,
                                                                   const uint32_t* ids, size_t n, float* out) {
  adc_direct_ymm<M>(c, q, pq, ids, n, out);
}

template <int S>
__attribute__((target("avx512f,avx512vl"))) void additive_direct_avx512(const float* c, const float* q,
                                                                        const uint8_t* codes, const uint32_t* ids,
                                                                        size_t n, float* out) {
  additive_direct_ymm<S>(c, q, codes, ids, n, out);
}

// 16 candidates per step, as shortlist_avx2 with AVX-512's compress (into a
// register, then one store: the compressing store is slow on some CPUs); the
// last step's lanes loaded under a mask, so nothing past n is read.
__attribute__((target("popcnt,avx512f,avx512bw,avx512vl"))) size_t shortlist_avx512(const uint8_t* distances,
                                                                                    const uint32_t* ids, size_t n,
                                                                                    uint32_t cut, uint32_t at_cut,
                                                                                    uint32_t list, uint32_t* out) {
  const __m512i cut_v = _mm512_set1_epi32(static_cast<int>(cut));
  size_t taken = 0;
  for (size_t i = 0; i < n && taken < list; i += 16) {
    const size_t lanes = std::min<size_t>(16, n - i);
    const __mmask16 valid = static_cast<__mmask16>((1u << lanes) - 1);
    const __m512i d = _mm512_cvtepu8_epi32(_mm_maskz_loadu_epi8(valid, distances + i));
    const uint32_t below = _mm512_mask_cmplt_epu32_mask(valid, d, cut_v);
    uint32_t at = _mm512_mask_cmpeq_epu32_mask(valid, d, cut_v);
    const uint32_t ties = static_cast<uint32_t>(__builtin_popcount(at));
    if (ties > at_cut) at = lowest_set_bits(at, at_cut);
    at_cut -= std::min(ties, at_cut);
    const __mmask16 take = static_cast<__mmask16>(below | at);
    const __m512i v = _mm512_maskz_loadu_epi32(valid, ids + i);
    _mm512_storeu_si512(out + taken, _mm512_maskz_compress_epi32(take, v));
    taken += static_cast<size_t>(__builtin_popcount(take));
  }
  return std::min<size_t>(taken, list);
}

template <int M>
__attribute__((target("avx512f"))) void adc_table_avx512(const float* ct, const float* q, float* table) {
  constexpr int D = kSubDim<M>;
  for (int m = 0; m < M; ++m) {
    __m512 qj[D];
    for (int j = 0; j < D; ++j) qj[j] = _mm512_set1_ps(q[m * D + j]);
    for (int k = 0; k < kPqCentroids; k += 64) {
      __m512 acc[4];
      for (auto& a : acc) a = _mm512_setzero_ps();
      for (int j = 0; j < D; ++j) {
        const float* c = ct + (m * D + j) * kPqCentroids + k;
        for (int u = 0; u < 4; ++u) {
          const __m512 e = _mm512_sub_ps(qj[j], _mm512_loadu_ps(c + 16 * u));
          acc[u] = _mm512_add_ps(acc[u], _mm512_mul_ps(e, e));
        }
      }
      for (int u = 0; u < 4; ++u) _mm512_storeu_ps(table + m * kPqCentroids + k + 16 * u, acc[u]);
    }
  }
}

template <int M>
__attribute__((target("avx512f"))) void adc_distances_avx512(const float* table, const uint8_t* pq, const uint32_t* ids,
                                                             size_t n, float* out) {
  static_assert(M == 16 || M == 32);
  constexpr int kWordShift = M == 16 ? 2 : 3;  // a code is M / 4 32-bit words
  const __m512i byte_mask = _mm512_set1_epi32(0xFF);
  size_t i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512i base = _mm512_slli_epi32(_mm512_loadu_si512(ids + i), kWordShift);
    __m512 acc = _mm512_setzero_ps();
    for (int w = 0; w < M / 4; ++w) {
      const __m512i code_word = _mm512_i32gather_epi32(_mm512_add_epi32(base, _mm512_set1_epi32(w)), pq, 4);
      for (int b = 0; b < 4; ++b) {
        const int m = 4 * w + b;
        const __m512i idx = _mm512_add_epi32(_mm512_and_si512(_mm512_srli_epi32(code_word, 8 * b), byte_mask),
                                             _mm512_set1_epi32(m * kPqCentroids));
        acc = _mm512_add_ps(acc, _mm512_i32gather_ps(idx, table, 4));
      }
    }
    _mm512_storeu_ps(out + i, acc);
  }
  adc_distances_avx2<M>(table, pq, ids + i, n - i, out + i);
}

// Blocks of 8 rows × 32 outputs (16 accumulators): the 16 KiB slice of W
// for 32 outputs stays in L1 while 8 rows pass over it; each output is still
// summed over j = 0..127 in order, as the reference.
__attribute__((target("avx512f"))) void hash_codes_avx512(const float* wt, const float* x, size_t n,
                                                           HashCode* codes) {
  constexpr int kRows = 8;
  size_t r0 = 0;
  for (; r0 + kRows <= n; r0 += kRows) {
    HashCode c[kRows] = {};
    for (int ib = 0; ib < kHashBits / 32; ++ib) {
      __m512 acc[kRows][2];
      for (auto& a : acc) a[0] = a[1] = _mm512_setzero_ps();
      for (int j = 0; j < kDescriptorDim; ++j) {
        const __m512 w0 = _mm512_loadu_ps(wt + j * kHashBits + 32 * ib);
        const __m512 w1 = _mm512_loadu_ps(wt + j * kHashBits + 32 * ib + 16);
        for (int r = 0; r < kRows; ++r) {
          const __m512 b = _mm512_set1_ps(x[(r0 + r) * kDescriptorDim + j]);
          acc[r][0] = _mm512_add_ps(acc[r][0], _mm512_mul_ps(w0, b));
          acc[r][1] = _mm512_add_ps(acc[r][1], _mm512_mul_ps(w1, b));
        }
      }
      const __m512 zero = _mm512_setzero_ps();
      for (int r = 0; r < kRows; ++r) {
        const uint64_t lo = _mm512_cmp_ps_mask(acc[r][0], zero, _CMP_GT_OQ);
        const uint64_t hi = _mm512_cmp_ps_mask(acc[r][1], zero, _CMP_GT_OQ);
        c[r].w[ib >> 1] |= (lo | (hi << 16)) << (32 * (ib & 1));
      }
    }
    for (int r = 0; r < kRows; ++r) codes[r0 + r] = c[r];
  }
  hash_codes_avx2(wt, x + r0 * kDescriptorDim, n - r0, codes + r0);
}

// Blocks of 8 rows × 32 outputs (16 accumulators of 16 int32), as
// hash_codes_u8_avx2 with twice the lanes; exact, so equal to the reference.
__attribute__((target("avx512f,avx512bw"))) void hash_codes_u8_avx512(const QuantizedHashProjection& q,
                                                                      const uint8_t* x, size_t n, HashCode* codes,
                                                                      int32_t* margins) {
  const int16_t* wp = q.weight_pairs.data();
  const int32_t* t = q.thresholds.data();
  constexpr int kRows = 8;
  alignas(64) int16_t widened[kRows][kDescriptorDim];
  size_t r0 = 0;
  for (; r0 + kRows <= n; r0 += kRows) {
    for (int r = 0; r < kRows; ++r)
      for (int j = 0; j < kDescriptorDim; j += 32)
        _mm512_store_si512(&widened[r][j], _mm512_cvtepu8_epi16(_mm256_loadu_si256(
                                               reinterpret_cast<const __m256i*>(x + (r0 + r) * kDescriptorDim + j))));
    HashCode c[kRows] = {};
    for (int ib = 0; ib < kHashBits / 32; ++ib) {
      __m512i acc[kRows][2];
      for (auto& a : acc) a[0] = a[1] = _mm512_setzero_si512();
      for (int pair = 0; pair < kDescriptorDim / 2; ++pair) {
        const int16_t* w = wp + (pair * kHashBits + 32 * ib) * 2;
        const __m512i w0 = _mm512_loadu_si512(w);
        const __m512i w1 = _mm512_loadu_si512(w + 32);
        for (int r = 0; r < kRows; ++r) {
          int32_t xx;
          std::memcpy(&xx, &widened[r][2 * pair], 4);
          const __m512i b = _mm512_set1_epi32(xx);
          acc[r][0] = _mm512_add_epi32(acc[r][0], _mm512_madd_epi16(w0, b));
          acc[r][1] = _mm512_add_epi32(acc[r][1], _mm512_madd_epi16(w1, b));
        }
      }
      const __m512i t0 = _mm512_loadu_si512(t + 32 * ib);
      const __m512i t1 = _mm512_loadu_si512(t + 32 * ib + 16);
      for (int r = 0; r < kRows; ++r) {
        const uint64_t lo = _mm512_cmpgt_epi32_mask(acc[r][0], t0);
        const uint64_t hi = _mm512_cmpgt_epi32_mask(acc[r][1], t1);
        c[r].w[ib >> 1] |= (lo | (hi << 16)) << (32 * (ib & 1));
        if (margins) {
          int32_t* m = margins + (r0 + r) * kHashBits + 32 * ib;
          _mm512_storeu_si512(m, _mm512_abs_epi32(_mm512_sub_epi32(acc[r][0], t0)));
          _mm512_storeu_si512(m + 16, _mm512_abs_epi32(_mm512_sub_epi32(acc[r][1], t1)));
        }
      }
    }
    for (int r = 0; r < kRows; ++r) codes[r0 + r] = c[r];
  }
  hash_codes_u8_avx2(q, x + r0 * kDescriptorDim, n - r0, codes + r0, margins ? margins + r0 * kHashBits : nullptr);
}

#endif  // VISLOC_X86_KERNELS

constexpr SearchKernels kScalarKernels{
    SimdLevel::kScalar,
    hamming_scalar,
    shortlist_scalar,
    {adc_table_scalar<16>, adc_distances_scalar<16>, adc_direct_scalar<16>},
    {adc_table_scalar<32>, adc_distances_scalar<32>, adc_direct_scalar<32>},
    {additive_direct_scalar<1>, additive_direct_scalar<2>, additive_direct_scalar<4>},
    hash_codes_scalar,
    hash_codes_u8_scalar};
#ifdef VISLOC_X86_KERNELS
constexpr SearchKernels kAvx2Kernels{SimdLevel::kAvx2,
                                     hamming_popcnt,
                                     shortlist_avx2,
                                     {adc_table_avx2<16>, adc_distances_avx2<16>, adc_direct_avx2<16>},
                                     {adc_table_avx2<32>, adc_distances_avx2<32>, adc_direct_avx2<32>},
                                     {additive_direct_avx2<1>, additive_direct_avx2<2>, additive_direct_avx2<4>},
                                     hash_codes_avx2,
                                     hash_codes_u8_avx2};
constexpr SearchKernels kAvx512Kernels{
    SimdLevel::kAvx512,
    hamming_popcnt,
    shortlist_avx512,
    {adc_table_avx512<16>, adc_distances_avx512<16>, adc_direct_avx512<16>},
    {adc_table_avx512<32>, adc_distances_avx512<32>, adc_direct_avx512<32>},
    {additive_direct_avx512<1>, additive_direct_avx512<2>, additive_direct_avx512<4>},
    hash_codes_avx512,
    hash_codes_u8_avx512};
#endif

SimdLevel best_level() {
  if (cpu_supports(SimdLevel::kAvx512)) return SimdLevel::kAvx512;
  if (cpu_supports(SimdLevel::kAvx2)) return SimdLevel::kAvx2;
  return SimdLevel::kScalar;
}

}  // namespace

const AdcKernels& SearchKernels::adc(int subvectors) const {
  if (subvectors == kPqSubvectors) return adc16;
  if (subvectors == kPqFineSubvectors) return adc32;
  throw_error(ErrorCode::kInvalidArgument, "no ADC kernels for ", subvectors, " PQ sub-vectors (16 or 32)");
}

AdditiveKernels::Direct AdditiveKernels::direct(int splits) const {
  switch (splits) {
    case 1:
      return direct1;
    case 2:
      return direct2;
    case 4:
      return direct4;
    default:
      throw_error(ErrorCode::kInvalidArgument, "no additive kernels for ", splits, " splits (1, 2 or 4)");
  }
}

const char* to_string(SimdLevel level) {
  switch (level) {
    case SimdLevel::kBest: return "best";
    case SimdLevel::kScalar: return "scalar";
    case SimdLevel::kAvx2: return "avx2";
    case SimdLevel::kAvx512: return "avx512";
  }
  return "?";
}

SimdLevel parse_simd_level(const std::string& name) {
  for (SimdLevel l : {SimdLevel::kBest, SimdLevel::kScalar, SimdLevel::kAvx2, SimdLevel::kAvx512})
    if (name == to_string(l)) return l;
  throw_error(ErrorCode::kInvalidArgument, "unknown SIMD level '", name, "' (best, scalar, avx2, avx512)");
}

bool cpu_supports(SimdLevel level) {
  switch (level) {
    case SimdLevel::kBest:
    case SimdLevel::kScalar: return true;
#ifdef VISLOC_X86_KERNELS
    case SimdLevel::kAvx2: return __builtin_cpu_supports("popcnt") && __builtin_cpu_supports("avx2");
    case SimdLevel::kAvx512:
      return __builtin_cpu_supports("popcnt") && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("avx512f") &&
             __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl");
#else
    default: return false;
#endif
  }
  return false;
}

std::vector<SimdLevel> supported_simd_levels() {
  std::vector<SimdLevel> out;
  for (SimdLevel l : {SimdLevel::kScalar, SimdLevel::kAvx2, SimdLevel::kAvx512})
    if (cpu_supports(l)) out.push_back(l);
  return out;
}

const SearchKernels& search_kernels(SimdLevel level) {
  if (level == SimdLevel::kBest) {
    static const SimdLevel best = best_level();  // a CPU property, decided once
    level = best;
  }
  if (!cpu_supports(level))
    throw_error(ErrorCode::kInvalidArgument, "this CPU does not support the ", to_string(level), " search kernels");
  switch (level) {
#ifdef VISLOC_X86_KERNELS
    case SimdLevel::kAvx2: return kAvx2Kernels;
    case SimdLevel::kAvx512: return kAvx512Kernels;
#endif
    default: return kScalarKernels;
  }
}

}  // namespace visloc
