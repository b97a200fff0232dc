// 128-bit binary codes of SIFT descriptors by a linear sign hash:
//   h(x) = sign(W (x − μ)),  W ∈ R^{128×128}, bit i = [w_iᵀ(x − μ) > 0]
// learned by Iterative Quantization (ITQ, Gong & Lazebnik, CVPR 2011; the
// paper's eq. (2): min_{B,R} ||B − V R||_F², V the PCA projection of the
// centred descriptors, R orthogonal) or drawn at random (LSH, Charikar 2002;
// the CasHash baseline of Cheng et al., CVPR 2014).
//
// Code layout: 2 × uint64 words, bit i of the code in word i/64, bit i%64.
// The k-th 16-bit sub-code (k = 0..7, the k-th lookup table of the cascade)
// is bits [16k, 16k+16): (word[k/4] >> 16·(k%4)) & 0xFFFF.
#pragma once

#include <bit>
#include <cstdint>
#include <filesystem>
#include <string>
#include <span>
#include <vector>

#include "visloc/features/feature_set.h"

namespace visloc {

inline constexpr int kHashBits = 128;
inline constexpr int kHashTables = 8;      // m
inline constexpr int kHashTableBits = 16;  // b
inline constexpr uint32_t kHashBuckets = 1u << kHashTableBits;

struct HashCode {
  uint64_t w[2];
};
static_assert(sizeof(HashCode) == 16);

// Marks a function whose std::popcount should be one instruction: on x86-64
// with GCC it is compiled twice, with POPCNT and for baseline x86-64, and the
// loader picks the clone the CPU supports. Elsewhere it is a plain function.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define VISLOC_POPCNT_CLONES __attribute__((target_clones("popcnt", "default")))
#else
#define VISLOC_POPCNT_CLONES
#endif

inline uint32_t hamming_distance(const HashCode& a, const HashCode& b) {
  return static_cast<uint32_t>(std::popcount(a.w[0] ^ b.w[0]) + std::popcount(a.w[1] ^ b.w[1]));
}
inline uint32_t hash_subcode(const HashCode& c, int table) {
  return static_cast<uint32_t>((c.w[table >> 2] >> (16 * (table & 3))) & 0xFFFFu);
}

// Non-owning view of the hash parameters (e.g. into a mapped segment file):
// mean[128] and projection[128 × 128] row-major (row i = w_i).
struct BinaryHasherView {
  const float* mean = nullptr;
  const float* projection = nullptr;
};

// Owning hash parameters.
struct BinaryHasher {
  std::vector<float> mean;        // 128
  std::vector<float> projection;  // 128 × 128 row-major
  BinaryHasherView view() const { return {mean.data(), projection.data()}; }
};

// The integer form of a hasher, for uint8 descriptors:
//   Wq[i][j] = round(scale · W[i][j]), scale = 32,767 / max|W| (int16; the
//              product in double, so |Wq − scale · W| ≤ 1/2),
//   threshold_i = ⌊Σ_j Wq[i][j] · μ_j⌋ (summed in double, clamped to ±2^30,
//                 beyond every sum, so that Σ − threshold_i fits in int32),
//   bit i = [Σ_j Wq[i][j] · x_j > threshold_i], summed exactly in int32.
// For an integer sum P, P > c ⇔ P > ⌊c⌋, so this is the sign of Wq(x − μ)
// (up to the double rounding of the threshold's sum, exact for SIFT-range
// means). It differs from the sign of W(x − μ) only where
// |W(x − μ)| ≤ (Σ_j x_j + Σ_j |μ_j|) / (2 · scale) + 1 / scale, about 1e-3 of
// a typical projection's spread on SIFT. Non-finite weights count as 0.
struct QuantizedHashProjection {
  float scale = 1;
  std::vector<int16_t> weight_pairs;        // [p][i][e] = Wq[i][2p + e]: 64 × 128 × 2 (the SIMD kernels)
  std::vector<int16_t> weights_transposed;  // [j][i] = Wq[i][j]: 128 × 128 (the scalar reference)
  std::vector<int32_t> thresholds;          // 128, within ±2^30 (the kernels' margins need it)
};
void quantize_hash_projection(BinaryHasherView hasher, QuantizedHashProjection& out);

// Reusable buffers of encode_hash, once grown: 192 KiB for float rows (Wᵀ and
// a block of 256 centred rows), 64.5 KiB for uint8 rows.
struct HashWorkspace {
  std::vector<float> projection_transposed;  // float descriptors: Wᵀ
  std::vector<float> centred;                // and a block of centred rows
  QuantizedHashProjection quantized;         // uint8 descriptors
};

// Encodes n descriptors (rows of 128) into codes with the best kernel for this
// CPU (search_kernels.h): uint8 rows (query features) in exact integer
// arithmetic with the QuantizedHashProjection, float rows (e.g. a map point's
// mean descriptor) in float. The two agree except where a projection is
// within the rounding bound above of 0.
// With `margins` (n × 128), the uint8 form also writes each bit's distance
// from its hyperplane in the integer scale (search_kernels.h, hash_codes_u8):
// the smaller, the likelier a near neighbour has the bit flipped.
void encode_hash(BinaryHasherView hasher, const uint8_t* descriptors, size_t n, HashCode* codes,
                 HashWorkspace& workspace, int32_t* margins = nullptr);
void encode_hash(BinaryHasherView hasher, const float* descriptors, size_t n, HashCode* codes,
                 HashWorkspace& workspace);

struct ItqOptions {
  int iterations = 50;     // Gong & Lazebnik use 50
  uint64_t seed = 1;       // initial random rotation
  size_t max_training = 200000;  // a larger set is subsampled (seeded)
  void validate() const;
};

struct ItqResult {
  BinaryHasher hasher;
  std::vector<double> quantization_error;  // ||B − V R||_F² / n after each iteration
};

// Learns ITQ on n float descriptors (rows of 128): centring, full PCA
// (128 → 128), then alternating B = sign(V R) and the orthogonal Procrustes
// update R = S Ŝᵀ from the SVD Vᵀ B = S Ω Ŝᵀ. projection = (P R)ᵀ.
ItqResult train_itq(const float* descriptors, size_t n, const ItqOptions& options = {});

// Random hyperplanes (i.i.d. Gaussian rows) through the data mean: LSH.
BinaryHasher make_lsh_hasher(const float* descriptors, size_t n, uint64_t seed);

// A random orthogonal rotation of the PCA basis (the ITQ initialisation;
// the reference that ITQ must improve on).
BinaryHasher make_random_rotation_hasher(const float* descriptors, size_t n, uint64_t seed);

// Where a map's hash rotation lives: learned per segment on its points'
// descriptors and stored in the segment (64.5 KiB each), or learned once per
// map and stored beside the PQ codebook (a query is then hashed once for all
// the segments it searches).
enum class HashRotationScope { kSegment, kMap };
const char* to_string(HashRotationScope scope);
HashRotationScope parse_hash_rotation_scope(const std::string& name);  // "segment" | "map"
inline constexpr const char* kHashRotationFileName = "hash_rotation.vlitq";

// Hash rotation files (.vlitq): SectionFile kind "ITQR", version 1, sections
// META (JSON: training count and source), MEAN (128 float32), W (128 × 128
// float32, row-major). Written atomically; the reader checks sizes, CRCs,
// finite values and a near-orthonormal projection.
inline constexpr uint32_t kHashRotationFileVersion = 1;
void write_hash_rotation_file(const std::filesystem::path& path, const BinaryHasher& hasher,
                              const std::string& meta_json);
BinaryHasher read_hash_rotation_file(const std::filesystem::path& path);
// Throws Error(kFormat) naming `file` unless the mean is finite and the
// projection finite and orthonormal (|W Wᵀ − I| ≤ 1e-3), as ITQ makes it.
void check_hash_rotation(BinaryHasherView hasher, const std::string& file);
// CRC32C of the mean and projection bytes: segments made with a map's
// rotation record it, so that codes are never searched with another one.
uint32_t hash_rotation_fingerprint(const BinaryHasher& hasher);

// Mean over the descriptors of ||sign(W(x−μ)) − W(x−μ)||² (the ITQ objective).
double hash_quantization_error(BinaryHasherView hasher, const float* descriptors, size_t n);

}  // namespace visloc
