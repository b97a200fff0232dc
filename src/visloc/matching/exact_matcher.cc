#include "visloc/matching/exact_matcher.h"

#include <faiss/IndexFlat.h>
#include <opencv2/calib3d.hpp>

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

std::vector<bool> fundamental_inliers(const std::vector<Keypoint>& points1, const std::vector<Keypoint>& points2,
                                      const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                      double threshold_px) {
  std::vector<bool> inlier(matches.size(), false);
  if (matches.size() < 8) return inlier;
  std::vector<cv::Point2f> a, b;
  for (auto [i, j] : matches) {
    VISLOC_CHECK(i < points1.size() && j < points2.size());
    a.emplace_back(points1[i].x, points1[i].y);
    b.emplace_back(points2[j].x, points2[j].y);
  }
  cv::Mat mask;
  cv::Mat F = cv::findFundamentalMat(a, b, cv::FM_RANSAC, threshold_px, 0.999, 10000, mask);
  if (F.empty() || mask.empty()) return inlier;
  for (size_t k = 0; k < matches.size(); ++k) inlier[k] = mask.at<uchar>(static_cast<int>(k)) != 0;
  return inlier;
}

}  // namespace visloc
