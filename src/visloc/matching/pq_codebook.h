// Product quantization of SIFT descriptors (Jégou, Douze, Schmid, PAMI 2011):
// 128 dimensions split into M sub-vectors of 128 / M, each quantized to one of
// 256 centroids (8 bits): an M-byte code per descriptor. M is 16 (the paper's
// and the default: 16-byte codes, sub-vectors of 8) or 32 (32-byte codes,
// sub-vectors of 4: 16 bytes more per point for a finer ranking; bench
// matching measured 0.90 of exact matching's 1-1 matches against 0.755 with
// 16). Trained with FAISS's ProductQuantizer (k-means per sub-space). The
// paper's precise step ranks candidates by the asymmetric distance (ADC)
//   d²(q, c) = Σ_m ||q_m − centroid_m[c_m]||²
// read from an M × 256 table computed once per query feature.
//
// Layout (D = 128 / M): centroids[(m · 256 + k) · D + j], m sub-vector, k
// centroid, j dim: 128 × 256 floats for either M.
// Codebook files (.vlpq): SectionFile kind "PQCB", sections META (JSON:
// dimension, sub-vectors, bits, training count and source; informative) and
// CENT (M × 256 × D float32). Version 1: M = 16. Version 2 adds section SUBVEC
// (one uint32: M); the writer writes version 1 for M = 16, so 16-byte maps
// stay readable by older readers.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace visloc {

// The default layout, 16-byte codes (M = 16, D = 8).
inline constexpr int kPqSubvectors = 16;
inline constexpr int kPqCentroids = 256;
inline constexpr int kPqSubDim = 8;
inline constexpr int kPqCodeBytes = kPqSubvectors;
inline constexpr int kPqTableSize = kPqSubvectors * kPqCentroids;  // floats per ADC table
// The finer layout, 32-byte codes (M = 32, D = 4).
inline constexpr int kPqFineSubvectors = 32;
inline constexpr int kPqMaxSubvectors = kPqFineSubvectors;
inline constexpr int kPqMaxTableSize = kPqMaxSubvectors * kPqCentroids;
inline constexpr int kPqCentroidFloats = 128 * kPqCentroids;  // M × 256 × D for either M
inline constexpr uint32_t kPqCodebookFileVersion = 2;         // newest read and written (M = 32)
inline constexpr uint32_t kPqCodebook16FileVersion = 1;       // written for M = 16

// Whether M is a supported sub-vector count (16 or 32).
inline bool valid_pq_subvectors(int m) { return m == kPqSubvectors || m == kPqFineSubvectors; }

struct PqTrainingOptions {
  int subvectors = kPqSubvectors;  // M: 16 (16-byte codes) or 32 (32-byte codes)
  int iterations = 25;          // k-means iterations per sub-space (FAISS's default)
  uint64_t seed = 1;
  size_t max_training = 100000; // larger sets are subsampled (seeded)
  void validate() const;
};

class PqCodebook {
 public:
  PqCodebook() = default;
  // 128 × 256 centroids in the layout above; `subvectors` 16 or 32, else
  // Error(kInvalidArgument).
  explicit PqCodebook(std::vector<float> centroids, int subvectors = kPqSubvectors);

  // Trains on n float rows of 128. Needs at least 256 rows.
  static PqCodebook train(const float* descriptors, size_t n, const PqTrainingOptions& options = {});

  bool empty() const { return centroids_.empty(); }
  int subvectors() const { return subvectors_; }                 // M
  int code_bytes() const { return subvectors_; }                 // bytes per code (8-bit sub-codes)
  int sub_dimension() const { return 128 / subvectors_; }        // D
  int table_size() const { return subvectors_ * kPqCentroids; }  // floats per ADC table
  std::span<const float> centroids() const { return centroids_; }
  // The centroids as [m][j][k] (M × D × 256): the layout of the SIMD ADC table kernel.
  const float* centroids_transposed() const { return transposed_.data(); }
  // Nearest centroid per sub-vector: n × M bytes.
  void encode(const float* descriptors, size_t n, uint8_t* codes) const;
  // The query's M × 256 table of squared sub-distances (table[m·256 + k]);
  // the scalar reference of the search kernels' adc_table.
  void distance_table(const float* query, float* table) const;
  // Squared distance between a code's reconstruction and x (reference, slow).
  double reconstruction_sqdist(const uint8_t* code, const float* x) const;

  // Files (atomic write; the reader validates sizes, CRCs and version).
  void write(const std::filesystem::path& path, const std::string& meta_json) const;
  static PqCodebook read(const std::filesystem::path& path, std::string* meta_json = nullptr);

 private:
  int subvectors_ = kPqSubvectors;
  std::vector<float> centroids_;   // M × 256 × D
  std::vector<float> transposed_;  // M × D × 256
};

// ADC distance of one code: the sum of M table entries, in increasing m.
inline float adc_distance(const float* table, const uint8_t* code, int subvectors) {
  float d = 0;
  for (int m = 0; m < subvectors; ++m) d += table[m * kPqCentroids + code[m]];
  return d;
}

}  // namespace visloc
