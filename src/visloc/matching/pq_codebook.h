// Product quantization of SIFT descriptors (Jégou, Douze, Schmid, PAMI 2011):
// 128 dimensions split into 16 sub-vectors of 8, each quantized to one of
// 256 centroids (8 bits): a 16-byte code per descriptor. Trained with FAISS's
// ProductQuantizer (k-means per sub-space). The paper's precise step ranks
// candidates by the asymmetric distance (ADC)
//   d²(q, c) = Σ_m ||q_m − centroid_m[c_m]||²
// read from a 16 × 256 table computed once per query feature.
//
// Layout: centroids[(m · 256 + k) · 8 + j], m sub-vector, k centroid, j dim.
// Codebook files (.vlpq): SectionFile kind "PQCB", sections META (JSON:
// dimension, sub-vectors, bits, training count and source) and CENT
// (16 × 256 × 8 float32).
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

namespace visloc {

inline constexpr int kPqSubvectors = 16;
inline constexpr int kPqCentroids = 256;
inline constexpr int kPqSubDim = 8;
inline constexpr int kPqCodeBytes = kPqSubvectors;
inline constexpr int kPqTableSize = kPqSubvectors * kPqCentroids;  // floats per ADC table
inline constexpr uint32_t kPqCodebookFileVersion = 1;

struct PqTrainingOptions {
  int iterations = 25;          // k-means iterations per sub-space (FAISS's default)
  uint64_t seed = 1;
  size_t max_training = 100000; // larger sets are subsampled (seeded)
  void validate() const;
};

class PqCodebook {
 public:
  PqCodebook() = default;
  explicit PqCodebook(std::vector<float> centroids);

  // Trains on n float rows of 128. Needs at least 256 rows.
  static PqCodebook train(const float* descriptors, size_t n, const PqTrainingOptions& options = {});

  bool empty() const { return centroids_.empty(); }
  std::span<const float> centroids() const { return centroids_; }
  // The centroids as [m][j][k] (16 × 8 × 256): the layout of the SIMD ADC table kernel.
  const float* centroids_transposed() const { return transposed_.data(); }
  // Nearest centroid per sub-vector: n × 16 bytes.
  void encode(const float* descriptors, size_t n, uint8_t* codes) const;
  // The query's 16 × 256 table of squared sub-distances (table[m·256 + k]);
  // the scalar reference of the search kernels' adc_table.
  void distance_table(const float* query, float* table) const;
  // Squared distance between a code's reconstruction and x (reference, slow).
  double reconstruction_sqdist(const uint8_t* code, const float* x) const;

  // Files (atomic write; the reader validates sizes, CRCs and version).
  void write(const std::filesystem::path& path, const std::string& meta_json) const;
  static PqCodebook read(const std::filesystem::path& path, std::string* meta_json = nullptr);

 private:
  std::vector<float> centroids_;  // 16 × 256 × 8
  std::vector<float> transposed_; // 16 × 8 × 256
};

// ADC distance of one code: the sum of 16 table entries.
inline float adc_distance(const float* table, const uint8_t* code) {
  float d = 0;
  for (int m = 0; m < kPqSubvectors; ++m) d += table[m * kPqCentroids + code[m]];
  return d;
}

}  // namespace visloc
