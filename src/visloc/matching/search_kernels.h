// The per-candidate kernels of the cascade search, each in a portable scalar
// reference and in SIMD variants chosen at run time from what the CPU has
// (x86-64: POPCNT + AVX2, AVX-512F + BW + VL; any other CPU, e.g. aarch64: the
// reference, whose std::popcount is already a hardware instruction there).
// The default build targets baseline x86-64, so only the variant functions
// are compiled for the newer instruction sets (GCC target attributes).
//
// Every variant returns bit-identical results to the reference: the ADC sums
// are accumulated in the reference's order with separate multiplies and adds
// (no fused multiply-add), so a SIMD search returns the same matches as the
// scalar one.
//
//   hamming_distances  d_i = popcount(q ⊕ codes[ids_i]) over 2 × 64-bit words,
//                      and a histogram of d over 0..128 (the refined step's
//                      counting sort)
//   shortlist          the refined step's selection from those distances: in
//                      candidate order, the ids whose distance is below `cut`
//                      and the first `at_cut` of those at it, until `list`
//                      are taken (the counting sort's cut: `list` of them
//                      exist); returns how many. May overwrite
//                      out[returned, list + kShortlistSlack) (whole vectors).
//   adc(M)             the PQ kernels for M = 16 or 32 sub-vectors (M-byte
//                      codes, pq_codebook.h), one set per M:
//     .table           the query's M × 256 table of squared sub-distances,
//                      from centroids transposed to [m][j][k] (PqCodebook)
//     .distances       d_i = Σ_m table[m·256 + pq_codes[ids_i·M + m]]
//     .direct          the same distances as table + distances, up to float
//                      rounding, without the table: per candidate, its
//                      centroids ([m][k][j]) are loaded as 16 rows of 8
//                      floats and the squares summed over the rows per lane,
//                      then over the 8 lanes (adc_direct_scalar gives the
//                      order). Cheaper when a feature ranks fewer than ~100
//                      candidates.
//   additive(S)        the residual codes' distance (pq_codebook.h, kind
//                      residual; 16-byte codes, S = 1, 2 or 4 splits of the
//                      vector, 16 / S codebooks of 256 entries of 128 / S
//                      dimensions each, [m][k][j]): d_i = |q − x̂_i|², x̂_i's
//                      split s the sum of its codebooks' rows, in increasing
//                      codebook. In adc_direct's order (16 rows of 8 lanes,
//                      even and odd rows, the same tree); per candidate it
//                      reads 16 × 128 / S floats of codebook where the PQ's
//                      reads 128.
//   hash_codes         bit i of row r = [Σ_j Wᵀ[j][i] · x_rj > 0] over j = 0..127
//                      in order (x centred): the ITQ/LSH projection's signs
//   hash_codes_u8      the same signs for uint8 descriptors in exact integer
//                      arithmetic: bit i of row r = [Σ_j Wq[i][j] · x_rj > t_i]
//                      in int32, with Wq the projection rounded to int16 and
//                      t_i the integer threshold of the mean (binary_hasher.h).
//                      The reference reads Wq transposed ([j][i]), a loop a
//                      compiler vectorizes well (SSE2, NEON: as fast as the
//                      float reference); the SIMD variants read it in pairs.
//                      No rounding in the sums, so every level agrees by
//                      construction, and a multiply-add of int16 pairs does
//                      twice the work of a float multiply and add per lane.
//                      With `margins`, also each bit's |Σ_j Wq[i][j] · x_rj − t_i|
//                      (its projection's distance from the hyperplane, in the
//                      integer scale; exact in int32 since |t_i| ≤ 2^30), for
//                      query-directed probing (cascade_index.h).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "visloc/matching/binary_hasher.h"

namespace visloc {

enum class SimdLevel {
  kBest,    // the best level this CPU supports (chosen once, at first use)
  kScalar,  // portable reference
  kAvx2,    // x86-64 with POPCNT, AVX2
  kAvx512,  // x86-64 with POPCNT, AVX-512F, AVX-512BW and AVX-512VL
};
const char* to_string(SimdLevel level);
// Parses "best", "scalar", "avx2", "avx512"; throws kInvalidArgument.
SimdLevel parse_simd_level(const std::string& name);
bool cpu_supports(SimdLevel level);
// kScalar first, then every SIMD level this CPU supports, in increasing order.
std::vector<SimdLevel> supported_simd_levels();

// The ADC kernels of one PQ layout (M sub-vectors).
struct AdcKernels {
  void (*table)(const float* centroids_transposed, const float* query, float* table) = nullptr;
  void (*distances)(const float* table, const uint8_t* pq_codes, const uint32_t* ids, size_t n,
                    float* distances) = nullptr;
  void (*direct)(const float* centroids /* [m][k][j] */, const float* query, const uint8_t* pq_codes,
                 const uint32_t* ids, size_t n, float* distances) = nullptr;
};

// Codebooks of a residual code (the additive kernels): 16, each code 16 bytes.
inline constexpr int kAdditiveCodebooks = 16;

// The direct distances of residual codes, one per split count S.
struct AdditiveKernels {
  using Direct = void (*)(const float* codebooks /* [m][k][j] */, const float* query, const uint8_t* codes,
                          const uint32_t* ids, size_t n, float* distances);
  Direct direct1 = nullptr, direct2 = nullptr, direct4 = nullptr;
  // By S (1, 2 or 4); else Error(kInvalidArgument).
  Direct direct(int splits) const;
};

// Entries a shortlist kernel may write past the ones it takes.
inline constexpr size_t kShortlistSlack = 16;

struct SearchKernels {
  SimdLevel level = SimdLevel::kScalar;
  void (*hamming_distances)(const HashCode& query, const HashCode* codes, const uint32_t* ids, size_t n,
                            uint8_t* distances, uint32_t* histogram /* 129 bins, added to */) = nullptr;
  size_t (*shortlist)(const uint8_t* distances, const uint32_t* ids, size_t n, uint32_t cut, uint32_t at_cut,
                      uint32_t list, uint32_t* out /* room for list + kShortlistSlack */) = nullptr;
  AdcKernels adc16;  // 16-byte codes
  AdcKernels adc32;  // 32-byte codes
  AdditiveKernels additive;  // 16-byte residual codes
  void (*hash_codes)(const float* projection_transposed /* [j][i], 128 × 128 */, const float* centred /* n × 128 */,
                     size_t n, HashCode* codes) = nullptr;
  void (*hash_codes_u8)(const QuantizedHashProjection& projection, const uint8_t* descriptors /* n × 128 */, size_t n,
                        HashCode* codes, int32_t* margins /* n × 128, or null */) = nullptr;
  // adc16 or adc32 by the codes' sub-vector count; else Error(kInvalidArgument).
  const AdcKernels& adc(int subvectors) const;
};

// The kernels of one level; throws kInvalidArgument when the CPU lacks it.
const SearchKernels& search_kernels(SimdLevel level = SimdLevel::kBest);

}  // namespace visloc
