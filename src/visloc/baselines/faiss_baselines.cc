#include "visloc/baselines/faiss_baselines.h"

#include <faiss/IndexFlat.h>
#include <faiss/IndexIVFPQ.h>
#include <faiss/IndexPQ.h>
#include <omp.h>

#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

void FaissPqIndexOptions::validate() const {
  if (ivf_cells < 1) throw_error(ErrorCode::kInvalidArgument, "FaissPqIndexOptions.ivf_cells must be >= 1");
  if (imi_bits < 1 || imi_bits > 12)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqIndexOptions.imi_bits must be in [1, 12]");
}

struct FaissPqIndex::Impl {
  std::unique_ptr<faiss::Index> quantizer;
  std::unique_ptr<faiss::IndexIVFPQ> index;
};

FaissPqIndex::FaissPqIndex(const float* x, size_t n, const FaissPqIndexOptions& options)
    : impl_(std::make_unique<Impl>()), size_(n) {
  options.validate();
  if (n < 256) throw_error(ErrorCode::kInvalidArgument, "a FAISS PQ index needs at least 256 points, got ", n);
  size_t nlist;
  if (options.kind == FaissPqIndexKind::kIvfAdc) {
    impl_->quantizer = std::make_unique<faiss::IndexFlatL2>(kDescriptorDim);
    nlist = static_cast<size_t>(options.ivf_cells);
  } else {
    impl_->quantizer = std::make_unique<faiss::MultiIndexQuantizer>(kDescriptorDim, 2, options.imi_bits);
    nlist = size_t(1) << (2 * options.imi_bits);
  }
  impl_->index = std::make_unique<faiss::IndexIVFPQ>(impl_->quantizer.get(), kDescriptorDim, nlist, 16, 8);
  if (options.kind == FaissPqIndexKind::kImi) {
    impl_->index->quantizer_trains_alone = 1;
    // FAISS's compact table for a multi-index (use_precomputed_table = 2):
    // 256 × 16 × 256 floats instead of one per cell.
    impl_->index->use_precomputed_table = 2;
  }
  impl_->index->cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  impl_->index->pq.cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  impl_->index->verbose = false;
  impl_->index->train(static_cast<faiss::Index::idx_t>(n), x);
  impl_->index->add(static_cast<faiss::Index::idx_t>(n), x);
}

FaissPqIndex::~FaissPqIndex() = default;

std::vector<RatioMatch> FaissPqIndex::match(const DescriptorMatrix& queries, int cells_visited, double ratio,
                                            FaissSearchStats* stats) const {
  if (cells_visited < 1) throw_error(ErrorCode::kInvalidArgument, "cells visited must be >= 1");
  const size_t nq = queries.rows();
  std::vector<RatioMatch> out;
  if (nq == 0) return out;
  std::vector<float> q(queries.size_bytes());
  for (size_t i = 0; i < q.size(); ++i) q[i] = queries.data()[i];
  std::vector<float> d(nq * 2);
  std::vector<faiss::Index::idx_t> l(nq * 2);
  impl_->index->nprobe = static_cast<size_t>(cells_visited);
  faiss::indexIVF_stats.reset();
  impl_->index->search(static_cast<faiss::Index::idx_t>(nq), q.data(), 2, d.data(), l.data());
  if (stats) stats->distances_per_query = double(faiss::indexIVF_stats.ndis) / double(nq);
  const double r2 = ratio * ratio;
  for (size_t i = 0; i < nq; ++i) {
    if (l[2 * i] < 0 || l[2 * i + 1] < 0) continue;  // fewer than 2 candidates: no ratio test
    if (!(d[2 * i] < r2 * d[2 * i + 1])) continue;
    out.push_back({static_cast<uint32_t>(i), static_cast<uint32_t>(l[2 * i]), std::sqrt(std::max(0.0f, d[2 * i]))});
  }
  return out;
}

void set_faiss_threads(int threads) { omp_set_num_threads(std::max(1, threads)); }

}  // namespace visloc
