#include "visloc/matching/exact_matcher.h"

#include <faiss/IndexFlat.h>

#include <cmath>

#include "visloc/util/error.h"

namespace visloc {

void ExactMatcherOptions::validate() const {
  if (!(ratio > 0 && ratio <= 1))
    throw_error(ErrorCode::kInvalidArgument, "ratio must be in (0, 1], got ", ratio);
}

namespace {
std::vector<float> to_float(const DescriptorMatrix& d) {
  std::vector<float> out(d.size_bytes());
  for (size_t i = 0; i < out.size(); ++i) out[i] = d.data()[i];
  return out;
}
}  // namespace

struct ExactMatcher::Impl {
  faiss::IndexFlatL2 index{kDescriptorDim};
};

ExactMatcher::ExactMatcher(const DescriptorMatrix& database) : impl_(std::make_unique<Impl>()), size_(database.rows()) {
  if (size_ > 0) {
    auto f = to_float(database);
    impl_->index.add(static_cast<faiss::Index::idx_t>(size_), f.data());
  }
}

ExactMatcher::~ExactMatcher() = default;

void ExactMatcher::knn(const DescriptorMatrix& queries, int k, std::vector<int64_t>& out_index,
                       std::vector<float>& out_sqdist) const {
  VISLOC_CHECK(k >= 1, "knn: k must be at least 1");
  const size_t n = queries.rows(), kk = static_cast<size_t>(k);
  out_index.assign(n * kk, -1);
  out_sqdist.assign(n * kk, INFINITY);
  if (n == 0 || size_ == 0) return;
  auto q = to_float(queries);
  std::vector<faiss::Index::idx_t> labels(n * kk);
  impl_->index.search(static_cast<faiss::Index::idx_t>(n), q.data(), k, out_sqdist.data(), labels.data());
  for (size_t i = 0; i < labels.size(); ++i) out_index[i] = labels[i];
}

void ExactMatcher::knn2(const DescriptorMatrix& queries, std::vector<int64_t>& out_index,
                        std::vector<float>& out_sqdist) const {
  knn(queries, 2, out_index, out_sqdist);
}

std::vector<RatioMatch> ExactMatcher::match(const DescriptorMatrix& queries, const ExactMatcherOptions& options) const {
  options.validate();
  std::vector<int64_t> idx;
  std::vector<float> d2;
  knn2(queries, idx, d2);
  std::vector<RatioMatch> out;
  const double r2 = options.ratio * options.ratio;
  for (size_t i = 0; i < queries.rows(); ++i) {
    if (idx[2 * i] < 0) continue;
    if (idx[2 * i + 1] >= 0 && !(d2[2 * i] < r2 * d2[2 * i + 1])) continue;
    out.push_back({static_cast<uint32_t>(i), static_cast<uint32_t>(idx[2 * i]),
                   std::sqrt(std::max(0.0f, d2[2 * i]))});
  }
  return out;
}

}  // namespace visloc
