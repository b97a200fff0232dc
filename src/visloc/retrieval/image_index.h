// ImageIndex: nearest-neighbour search over the global descriptors of the
// map's images. The system's index is FAISS IndexIVFPQ (IVFADC, Jégou et al.,
// PAMI 2011; the paper's section III-A): a coarse k-means quantizer of
// `nlist` cells, residuals product-quantized into `pq_bytes` sub-codes of
// `pq_bits` bits. The flat (exact, uncompressed) index is the reference.
// Distances are squared L2 between L2-normalized vectors, so ranking equals
// ranking by cosine similarity. Image ids are the caller's (e.g. map image
// numbers); results are ordered nearest first.
//
// Small maps: a PQ sub-quantizer of 2^b centroids needs at least 2^b training
// vectors and each coarse cell about 39, so with n images the index uses
// b = min(pq_bits, floor(log2 n)) and nlist = min(nlist, max(1, n / 39)); the
// values used are reported by effective_*() and stored with the index.
//
// File: a SectionFile of kind "IIDX" (docs/formats.md), written to a
// temporary name and renamed, with sections META (JSON: options, effective
// parameters, count, dims) and FAIS (the bytes of faiss::write_index, so the
// container's CRC32C covers FAISS's own serialization; it is checked before
// faiss::read_index parses it).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace visloc {

inline constexpr uint32_t kImageIndexFileVersion = 1;

enum class ImageIndexType { kIvfPq, kFlat };

struct ImageIndexOptions {
  ImageIndexType type = ImageIndexType::kIvfPq;
  int nlist = 256;             // coarse cells (IVF); reduced for small maps (see above)
  int nprobe = 16;             // cells visited per query
  int pq_bytes = 256;          // sub-quantizers M (paper: g = 256); must divide dims
  int pq_bits = 8;             // bits per sub-code (paper: 8); reduced for small maps
  bool precomputed_tables = false;  // FAISS's nlist × M × 2^b residual tables: faster, more memory
  int max_training_vectors = 20000;  // vectors sampled for the coarse and PQ k-means
  uint64_t seed = 1234;

  void validate() const;  // throws Error(kInvalidArgument) naming the field
};

struct ImageSearchResult {
  int64_t image = -1;   // caller's image id
  float distance = 0;   // squared L2 (approximate for IVF-PQ)
};

class ImageIndex {
 public:
  ImageIndex();
  ~ImageIndex();
  ImageIndex(ImageIndex&&) noexcept;
  ImageIndex& operator=(ImageIndex&&) noexcept;

  // Trains on a sample of `vectors` (n × dims, row-major) and adds them with
  // their ids. Throws Error(kInvalidArgument) naming the option when the
  // options do not fit the data (pq_bytes not dividing dims, ...).
  static ImageIndex build(std::span<const float> vectors, std::span<const int64_t> ids, int dims,
                          const ImageIndexOptions& options);
  // Trains on `training` without adding (for adding in batches).
  static ImageIndex train(std::span<const float> training, int dims, const ImageIndexOptions& options);
  void add(std::span<const float> vectors, std::span<const int64_t> ids);

  // The `top` nearest images of one query vector (fewer if the index is smaller).
  std::vector<ImageSearchResult> search(std::span<const float> query, int top) const;
  // Batch form: queries n × dims; out is n × top (image -1 where fewer).
  void search(std::span<const float> queries, int top, std::vector<ImageSearchResult>& out) const;

  void set_nprobe(int nprobe);
  int dims() const { return dims_; }
  size_t size() const;
  const ImageIndexOptions& options() const { return options_; }
  int effective_nlist() const { return effective_nlist_; }
  int effective_pq_bits() const { return effective_pq_bits_; }
  // Memory: bytes per stored image (code + id) and fixed bytes (quantizer
  // centroids, PQ codebooks, precomputed tables), computed from the
  // structure's sizes.
  size_t bytes_per_image() const;
  size_t fixed_bytes() const;

  void save(const std::filesystem::path& path) const;
  static ImageIndex load(const std::filesystem::path& path);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  ImageIndexOptions options_;
  int dims_ = 0;
  int effective_nlist_ = 0;
  int effective_pq_bits_ = 0;
};

}  // namespace visloc
