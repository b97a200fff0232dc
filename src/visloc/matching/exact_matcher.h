// ExactMatcher: exhaustive nearest-neighbour search on raw SIFT descriptors
// (squared L2 through FAISS's flat index, i.e. BLAS), with Lowe's ratio test.
// The reference that every approximate method is measured against (the
// paper's "kd-tree" row).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "visloc/features/feature_set.h"

namespace visloc {

struct RatioMatch {
  uint32_t query = 0;     // row in the query descriptors
  uint32_t database = 0;  // row in the database descriptors
  float distance = 0;     // L2 distance to the nearest neighbour
};

struct ExactMatcherOptions {
  double ratio = 0.8;  // accept when d0 < ratio * d1 (distances, not squared)
  void validate() const;
};

class ExactMatcher {
 public:
  explicit ExactMatcher(const DescriptorMatrix& database);
  ~ExactMatcher();
  ExactMatcher(const ExactMatcher&) = delete;
  ExactMatcher& operator=(const ExactMatcher&) = delete;

  // Two nearest neighbours of every query row: out_index and out_sqdist
  // are rows × 2 (index -1 when the database has fewer than 2 rows).
  void knn2(const DescriptorMatrix& queries, std::vector<int64_t>& out_index,
            std::vector<float>& out_sqdist) const;
  // k nearest neighbours of every query row, nearest first (rows × k; index
  // -1 and distance ∞ past the database's size).
  void knn(const DescriptorMatrix& queries, int k, std::vector<int64_t>& out_index,
           std::vector<float>& out_sqdist) const;
  std::vector<RatioMatch> match(const DescriptorMatrix& queries, const ExactMatcherOptions& options = {}) const;
  size_t size() const { return size_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  size_t size_ = 0;
};

}  // namespace visloc
