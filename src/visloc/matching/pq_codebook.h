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
// Residual codebooks (PqQuantizer::kResidual, `map build --pq-quantizer
// residual`): the same 16-byte codes, each byte one of 256 entries of 16
// codebooks that are added (an additive quantizer: Babenko & Lempitsky's
// residual vector quantization, trained and encoded with FAISS's residual
// quantizer, beam search): the vector is cut into S = 1, 2 or 4 splits of
// 128 / S dimensions, each the sum of its 16 / S codebooks' entries. bench
// matching measured 0.86-0.90 of exact matching's 1-1 matches on the Strecha
// scenes against 0.755 for the PQ, at the same bytes per point (S = 1 / 2;
// S = 4: 0.819; FAISS's quantizers trained on every point of the scene, `bench
// matching --method rerank-faiss-rq16 / prq2x8 / prq4x4`); a candidate's
// distance reads 16 rows of 128 / S floats where the PQ's reads 16 of 8. A
// table per query feature would take 4096 × 128 / S multiply-adds, more than
// the ~40 candidates it ranks, so the search measures directly
// (search_kernels.h, additive).
// Layout: centroids[(m · 256 + k) · (128 / S) + j], codebook m of split
// m / (16 / S).
//
// Codebook files (.vlpq): SectionFile kind "PQCB", sections META (JSON:
// dimension, sub-vectors, bits, training count and source; informative) and
// CENT (M × 256 × D float32). Version 1: M = 16. Version 2 adds section SUBVEC
// (one uint32: M); the writer writes version 1 for M = 16, so 16-byte maps
// stay readable by older readers. Version 3 (residual codebooks only) adds
// section RESID (two uint32: S and the encoder's beam), CENT then holding
// 16 × 256 × 128 / S floats. Every version: values beyond ±65,536 (damage)
// are refused.
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
inline constexpr uint32_t kPqCodebookFileVersion = 3;         // newest read and written (residual)
inline constexpr uint32_t kPqCodebook32FileVersion = 2;       // written for M = 32
inline constexpr uint32_t kPqCodebook16FileVersion = 1;       // written for M = 16

enum class PqQuantizer {
  kProduct,   // PQ: M sub-vectors, a centroid each (the paper's)
  kResidual,  // 16 added codebooks over S splits of the vector
};
const char* to_string(PqQuantizer quantizer);
// The beam of a residual codebook's training and encoding: 1 by default. On
// the four Strecha scenes (`map import --holdout S/queries.txt --pq-quantizer
// residual`, then `bench matching --method exact --method ccs-full-r1`) a beam
// of 1 kept 0.872 of exact matching's 1-1 matches against 0.869 with FAISS's
// default of 5 (fountain-P11 0.942 / 0.939, castle-P19 0.863 / 0.857,
// castle-P30 0.829 / 0.827, entry-P10 0.898 / 0.892), and fountain-P11's
// training took 234 against 847 s in the same conditions.
inline constexpr int kResidualBeam = 1;
// FAISS's default beam: the encoder's memory per row is sized at it.
inline constexpr int kFaissResidualBeam = 5;
inline constexpr int kResidualMaxBeam = 64;
// Any codebook value beyond this magnitude is refused by the reader.
inline constexpr float kPqMaxAbsCentroid = 65536.f;
// Whether S is a supported split count of a residual codebook (1, 2 or 4).
inline bool valid_residual_splits(int s) { return s == 1 || s == 2 || s == 4; }

// Whether M is a supported sub-vector count (16 or 32).
inline bool valid_pq_subvectors(int m) { return m == kPqSubvectors || m == kPqFineSubvectors; }

struct PqTrainingOptions {
  PqQuantizer quantizer = PqQuantizer::kProduct;
  int subvectors = kPqSubvectors;  // M: 16 (16-byte codes) or 32 (32-byte codes); 16 with kResidual
  int residual_splits = 2;         // S with kResidual: 1, 2 or 4
  // kResidual trains on at most this many descriptors (16 k-means over 128 / S
  // dimensions each, where the PQ's 16 are over 8).
  size_t residual_max_training = 30000;
  // kResidual's k-means per codebook: progressive in the dimensions (FAISS's
  // default) or plain, one run (the default). On the four Strecha scenes,
  // beam 1 (as kResidualBeam), plain kept 0.871 of exact matching's 1-1
  // matches against 0.872 progressive, and fountain-P11's training took 6.1
  // against 234 s.
  bool residual_progressive_dim = false;
  // kResidual's beam in training and in the codebook's encoding (stored in
  // its file, so a resumed build encodes as the first run did).
  int residual_beam = kResidualBeam;
  // The descriptors training uses of n given: the seeded sample's size.
  size_t training_rows(size_t n) const;
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
  // Residual: 16 × 256 × 128 / S floats in the layout above; S 1, 2 or 4,
  // else Error(kInvalidArgument). `beam`: the encoder's.
  static PqCodebook residual(std::vector<float> codebooks, int splits, int beam = kResidualBeam);

  // Trains on n float rows of 128. Needs at least 256 rows.
  static PqCodebook train(const float* descriptors, size_t n, const PqTrainingOptions& options = {});

  bool empty() const { return centroids_.empty(); }
  PqQuantizer quantizer() const { return quantizer_; }
  bool is_residual() const { return quantizer_ == PqQuantizer::kResidual; }
  int residual_splits() const { return residual_splits_; }       // S (1 for a PQ)
  int residual_beam() const { return residual_beam_; }           // the encoder's beam (a residual codebook's)
  int subvectors() const { return subvectors_; }                 // M
  int code_bytes() const { return subvectors_; }                 // bytes per code (8-bit sub-codes)
  int sub_dimension() const { return 128 / subvectors_; }        // D
  int table_size() const { return subvectors_ * kPqCentroids; }  // floats per ADC table (PQ)
  // The PQ's centroids, or the residual codebooks (the layouts above).
  std::span<const float> centroids() const { return centroids_; }
  // The PQ's centroids as [m][j][k] (M × D × 256): the layout of the SIMD ADC
  // table kernel (empty for a residual codebook).
  const float* centroids_transposed() const { return transposed_.data(); }
  // PQ: the nearest centroid per sub-vector; residual: FAISS's beam search
  // per split. n × M bytes.
  void encode(const float* descriptors, size_t n, uint8_t* codes) const;
  // The query's M × 256 table of squared sub-distances (table[m·256 + k]);
  // the scalar reference of the search kernels' adc_table. PQ only.
  void distance_table(const float* query, float* table) const;
  // A code's decoded vector (128 floats; residual: each split's codebook
  // entries added in increasing codebook, as the kernels do).
  void decode(const uint8_t* code, float* out) const;
  // Squared distance between a code's reconstruction and x (reference, slow).
  double reconstruction_sqdist(const uint8_t* code, const float* x) const;

  // The quantizer as a map's manifest and codebook META record it:
  // {"quantizer": "product"|"residual"[, "residual_splits": S]}.
  std::string quantizer_json() const;

  // Files (atomic write; the reader validates sizes, CRCs and version).
  void write(const std::filesystem::path& path, const std::string& meta_json) const;
  static PqCodebook read(const std::filesystem::path& path, std::string* meta_json = nullptr);

 private:
  PqQuantizer quantizer_ = PqQuantizer::kProduct;
  int subvectors_ = kPqSubvectors;
  int residual_splits_ = 1;
  int residual_beam_ = kResidualBeam;
  std::vector<float> centroids_;   // PQ: M × 256 × D; residual: 16 × 256 × 128 / S
  std::vector<float> transposed_;  // PQ: M × D × 256
};

// ADC distance of one code: the sum of M table entries, in increasing m.
inline float adc_distance(const float* table, const uint8_t* code, int subvectors) {
  float d = 0;
  for (int m = 0; m < subvectors; ++m) d += table[m * kPqCentroids + code[m]];
  return d;
}

}  // namespace visloc
