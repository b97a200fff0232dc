// FAISS product-quantization indexes used as baselines of the cascade search
// (the paper's Fig. "Comparison on indexing methods for PQ"):
//   IVFADC (Jégou et al., PAMI 2011): a k-means coarse quantizer of K_c = 256
//     cells, residuals PQ-coded with 16 × 8 bits, w cells visited per query;
//   IMI (Babenko & Lempitsky, CVPR 2012): an inverted multi-index of 2 × 8
//     bits (65536 cells), residual PQ 16 × 8 bits, w cells visited.
// Both return the 2 nearest by ADC and apply the ratio test, like the 1-1 set
// of the cascade search. FAISS types stay inside this module.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "visloc/features/feature_set.h"
#include "visloc/matching/exact_matcher.h"

namespace visloc {

enum class FaissPqIndexKind { kIvfAdc, kImi };

struct FaissPqIndexOptions {
  FaissPqIndexKind kind = FaissPqIndexKind::kIvfAdc;
  int ivf_cells = 256;  // K_c (IVFADC)
  int imi_bits = 8;     // bits per half of the multi-index (IMI: 2^(2·bits) cells)
  uint64_t seed = 1;
  void validate() const;
};

struct FaissSearchStats {
  double distances_per_query = 0;  // codes compared per query feature (FAISS's ndis)
};

class FaissPqIndex {
 public:
  // Trains the coarse quantizer and PQ on the database itself, then adds it.
  FaissPqIndex(const float* database, size_t n, const FaissPqIndexOptions& options);
  ~FaissPqIndex();
  FaissPqIndex(const FaissPqIndex&) = delete;
  FaissPqIndex& operator=(const FaissPqIndex&) = delete;

  std::vector<RatioMatch> match(const DescriptorMatrix& queries, int cells_visited, double ratio,
                                FaissSearchStats* stats = nullptr) const;
  size_t size() const { return size_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  size_t size_ = 0;
};

// Threads FAISS may use for searches (OpenMP); benchmarks set 1 to compare
// one-core figures with the single-threaded cascade search.
void set_faiss_threads(int threads);

}  // namespace visloc
