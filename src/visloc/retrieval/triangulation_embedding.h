// Triangulation embedding (T-embedding) of an image's SIFT descriptors into
// one global vector: Jégou & Zisserman, "Triangulation embedding and
// democratic aggregation for image search", CVPR 2014; the paper's retrieval
// stage (Tran et al., section III-A, k = 32, 4096-D, sum pooling).
//
// For a descriptor x (RootSIFT, rescaled to unit L2 norm: our uint8 values
// divided by 512, undoing SiftExtractor's scaling) and a vocabulary
// C = {c_1..c_k} (FAISS k-means):
//   r_j(x) = (x - c_j) / ||x - c_j||,      R(x) = [r_1(x); ...; r_k(x)] (k·128-D)
//   φ(x)   = P (R(x) - R0)                 centring R0 = E[R], P = Λ^{-1/2} Uᵀ
// where Σ = U Λ Uᵀ is the covariance of R over training descriptors; keeping
// only the top `output_dims` eigenvectors makes P a PCA-whitening (the full
// 4096×4096 matrix is 64 MiB). Eigenvalues are regularized before inversion:
// λ_i ← max(λ_i, eigenvalue_floor · mean(λ)).
// Aggregation: sum pooling ψ = Σ_x φ(x) = P (Σ_x R(x) - n R0) (linear, so one
// matrix-vector product per image), or democratic aggregation ψ = Σ_x λ_x φ(x)
// with weights making every λ_x φ(x)ᵀψ equal (Sinkhorn iterations on the
// positive part of the Gram matrix, paper's Algorithm 1, γ = 0.5).
// Then power-law y ← sign(y)|y|^α (α = 0.5) and L2 normalization.
//
// The same vocabulary gives VLAD (Jégou et al., CVPR 2010): per centroid the
// sum of residuals of the descriptors assigned to it, signed square root, L2
// normalization — the baseline of `visloc bench retrieval`.
//
// Parameters are stored as a SectionFile of kind "TEMB" (docs/formats.md):
//   META  JSON: options, dims, training statistics
//   CENT  k × 128 float32 centroids (row-major)
//   MEAN  k·128 float32 R0
//   PROJ  output_dims × k·128 float32 P (row-major, rows = output components)
//   EIGV  output_dims float32 eigenvalues (before regularization, descending)
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "visloc/features/feature_set.h"

namespace visloc {

inline constexpr uint32_t kTriangulationEmbeddingFileVersion = 1;

enum class EmbeddingPooling { kSum, kDemocratic };

struct TriangulationEmbeddingOptions {
  int vocabulary_size = 32;            // k (paper: 32 → 4096-D)
  int output_dims = 0;                 // 0: full whitening (k·128); else PCA-whitening to this many
  EmbeddingPooling pooling = EmbeddingPooling::kSum;  // paper: sum pooling
  double power_law_alpha = 0.5;        // y ← sign(y)|y|^α after pooling; 1 disables
  double eigenvalue_floor = 0.1;       // λ ← max(λ, floor · mean λ) before λ^{-1/2}
  int kmeans_iterations = 25;          // FAISS k-means iterations for the vocabulary
  int max_kmeans_descriptors = 100000; // descriptors sampled for the vocabulary
  int max_whitening_descriptors = 50000;  // descriptors sampled for R0 and Σ
  int democratic_iterations = 10;      // Sinkhorn iterations (democratic pooling)
  double democratic_gamma = 0.5;       // damping exponent of each Sinkhorn update
  uint64_t seed = 1234;                // sampling and k-means seed

  void validate() const;  // throws Error(kInvalidArgument) naming the field
  std::string to_json() const;
};

struct TriangulationEmbeddingTrainStats {
  size_t images = 0;
  size_t kmeans_descriptors = 0;
  size_t whitening_descriptors = 0;
  double kmeans_ms = 0, covariance_ms = 0, eigen_ms = 0, total_ms = 0;
  double retained_variance = 0;  // fraction of trace(Σ) in the kept components
};

// A descriptor matrix is N × 128 uint8 (features/feature_set.h).
class TriangulationEmbedding {
 public:
  TriangulationEmbedding() = default;

  // Learns the vocabulary, centring and (PCA-)whitening from the descriptors
  // of training images (the map's images). Throws Error(kInvalidArgument) when
  // there are too few descriptors (fewer than 39·k or than output dims + 1).
  static TriangulationEmbedding train(std::span<const DescriptorMatrix* const> images,
                                      const TriangulationEmbeddingOptions& options,
                                      TriangulationEmbeddingTrainStats* stats = nullptr);

  // The PCA-whitening to the first `output_dims` components of this one (the
  // same as training with that option: components are nested).
  TriangulationEmbedding reduced(int output_dims) const;
  // The same parameters with another pooling (democratic vs sum).
  TriangulationEmbedding with_pooling(EmbeddingPooling pooling) const {
    TriangulationEmbedding e = *this;
    e.options_.pooling = pooling;
    return e;
  }

  // The L2-normalized embedding of one image (dims() floats). An image
  // without descriptors gives the zero vector.
  std::vector<float> embed(const DescriptorMatrix& descriptors) const;
  void embed(const DescriptorMatrix& descriptors, float* out) const;
  // VLAD with the same vocabulary (vlad_dims() floats), signed sqrt + L2.
  std::vector<float> vlad(const DescriptorMatrix& descriptors) const;

  int vocabulary_size() const { return k_; }
  int input_dims() const { return k_ * kDescriptorDim; }  // k·128
  int dims() const { return out_dims_; }
  int vlad_dims() const { return k_ * kDescriptorDim; }
  const TriangulationEmbeddingOptions& options() const { return options_; }
  const TriangulationEmbeddingTrainStats& train_stats() const { return train_stats_; }
  // Bytes of the learned parameters held in memory (centroids, R0, P, eigenvalues).
  size_t parameter_bytes() const;
  std::span<const float> centroids() const { return centroids_; }
  std::span<const float> eigenvalues() const { return eigenvalues_; }
  std::span<const float> mean() const { return mean_; }              // R0
  std::span<const float> projection() const { return projection_; }  // P, dims × input_dims

  void save(const std::filesystem::path& path) const;
  static TriangulationEmbedding load(const std::filesystem::path& path);

 private:
  // Σ_x R(x) over the descriptors (k·128 floats, out), in one pass:
  // Σ_i (x_i - c_j)/||x_i - c_j|| = Xᵀ w_j - c_j Σ_i w_ij, w_ij = 1/||x_i - c_j||.
  void residual_sum(const DescriptorMatrix& descriptors, float* out) const;
  void finish(std::vector<float>& pooled, float* out) const;  // power law + L2

  TriangulationEmbeddingOptions options_;
  TriangulationEmbeddingTrainStats train_stats_;
  int k_ = 0;
  int out_dims_ = 0;
  std::vector<float> centroids_;     // k × 128
  std::vector<float> centroid_sqnorm_;  // k
  std::vector<float> mean_;          // k·128
  std::vector<float> projection_;    // out_dims × k·128
  std::vector<float> eigenvalues_;   // out_dims
};

// Converts uint8 SIFT (COLMAP scaling, 512 × unit vector) to unit-norm floats.
inline constexpr float kDescriptorToUnit = 1.0f / 512.0f;

}  // namespace visloc
