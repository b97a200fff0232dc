#include "bench/reranking_study.h"

#include <faiss/VectorTransform.h>
#include <faiss/impl/ProductQuantizer.h>

#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

CascadeSearchOptions whole_shortlist_options(int refined_list, int lut_radius) {
  CascadeSearchOptions o;
  o.lut_radius = lut_radius;
  o.prioritize = false;
  o.refined = true;
  o.refined_list = refined_list;
  o.max_one_to_many = refined_list;
  o.ratio_one_to_many = 1.0f;
  o.one_to_many_rule = OneToManyRule::kBestRatio;
  o.validate();
  return o;
}

int nearest_passing_ratio(std::span<const float> squared, float ratio) {
  if (squared.size() < 2) return -1;
  size_t best = 0;
  for (size_t k = 1; k < squared.size(); ++k)
    if (squared[k] < squared[best]) best = k;
  float second = INFINITY;
  for (size_t k = 0; k < squared.size(); ++k)
    if (k != best) second = std::min(second, squared[k]);
  return squared[best] < ratio * ratio * second ? static_cast<int>(best) : -1;
}

FaissPqReranker::FaissPqReranker(const float* points, size_t n, int subquantizers, bool opq_rotation) {
  VISLOC_CHECK(n > 0 && subquantizers > 0 && kDescriptorDim % subquantizers == 0);
  std::vector<float> train(points, points + n * kDescriptorDim);
  const auto count = static_cast<int64_t>(n);
  if (opq_rotation) {
    rotation_ = std::make_unique<faiss::OPQMatrix>(kDescriptorDim, subquantizers);
    rotation_->verbose = false;
    rotation_->train(count, points);
    rotation_->apply_noalloc(count, points, train.data());
  }
  pq_ = std::make_unique<faiss::ProductQuantizer>(kDescriptorDim, subquantizers, 8);
  pq_->verbose = false;
  pq_->train(count, train.data());
  codes_.resize(n * pq_->code_size);
  pq_->compute_codes(train.data(), codes_.data(), count);
  table_.resize(pq_->M * pq_->ksub);
  rotated_.resize(kDescriptorDim);
}

FaissPqReranker::~FaissPqReranker() = default;

size_t FaissPqReranker::code_bytes() const { return pq_->code_size; }

void FaissPqReranker::transform(const float* query, float* out) const {
  if (rotation_) {
    rotation_->apply_noalloc(1, query, out);
  } else {
    std::copy(query, query + kDescriptorDim, out);
  }
}

void FaissPqReranker::reconstruct(uint32_t id, float* out) const {
  VISLOC_CHECK(size_t(id) * pq_->code_size < codes_.size());
  pq_->decode(codes_.data() + size_t(id) * pq_->code_size, out);
}

void FaissPqReranker::distances(const float* query, const uint32_t* ids, size_t n, float* out) {
  transform(query, rotated_.data());
  pq_->compute_distance_table(rotated_.data(), table_.data());
  const size_t m = pq_->M, k = pq_->ksub;
  for (size_t i = 0; i < n; ++i) {
    VISLOC_CHECK(size_t(ids[i]) * m < codes_.size());
    const uint8_t* c = codes_.data() + size_t(ids[i]) * m;
    float d = 0;
    for (size_t j = 0; j < m; ++j) d += table_[j * k + c[j]];
    out[i] = d;
  }
}

}  // namespace visloc
