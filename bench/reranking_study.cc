#include "bench/reranking_study.h"

#include <faiss/Clustering.h>
#include <faiss/IndexFlat.h>
#include <faiss/VectorTransform.h>
#include <faiss/impl/ProductAdditiveQuantizer.h>
#include <faiss/impl/ProductQuantizer.h>
#include <faiss/impl/ResidualQuantizer.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <numbers>

#include "visloc/util/error.h"

namespace visloc {

CascadeSearchOptions whole_shortlist_options(int refined_list, int lut_radius, float ratio_one_to_one) {
  CascadeSearchOptions o;
  o.lut_radius = lut_radius;
  o.prioritize = false;
  o.refined = true;
  o.refined_list = refined_list;
  o.max_one_to_many = refined_list;
  o.ratio_one_to_one = ratio_one_to_one;
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

void rank_whole_shortlists(const CascadeMatches& whole, const ShortlistDistances& distances, float ratio,
                           std::vector<uint32_t>& features, std::vector<uint32_t>& points) {
  features.clear();
  points.clear();
  std::vector<float> d;
  for (size_t i = 0; i < whole.many_query.size(); ++i) {
    const uint32_t begin = whole.many_offsets[i], end = whole.many_offsets[i + 1];
    const std::span<const uint32_t> ids(whole.many_points.data() + begin, end - begin);
    d.resize(ids.size());
    distances(i, ids, d.data());
    const int best = nearest_passing_ratio(d, ratio);
    if (best >= 0) {
      features.push_back(whole.many_query[i]);
      points.push_back(ids[static_cast<size_t>(best)]);
    }
  }
}

ShortlistDistances search_pq_distances(const CascadeMatches& whole) {
  return [&whole](size_t list, std::span<const uint32_t> ids, float* out) {
    VISLOC_CHECK(ids.data() == whole.many_points.data() + whole.many_offsets[list], "not list's own ids");
    const float* d = whole.many_distances.data() + whole.many_offsets[list];
    for (size_t k = 0; k < ids.size(); ++k) out[k] = d[k] * d[k];
  };
}

ShortlistDistances pq_hamming_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                        std::span<const HashCode> query_codes, const HashCode* point_codes,
                                        const float* hash_mean, double weight) {
  return [&whole, &queries, query_codes, point_codes, hash_mean, weight](size_t list, std::span<const uint32_t> ids,
                                                                         float* out) {
    VISLOC_CHECK(ids.data() == whole.many_points.data() + whole.many_offsets[list], "not list's own ids");
    const uint32_t f = whole.many_query[list];
    VISLOC_CHECK(f < query_codes.size(), "a short list's feature without a hash code");
    const uint8_t* q = queries.row(f);
    double norm2 = 0;  // |q − μ|²: the codes are signs of W(x − μ)
    for (int j = 0; j < kDescriptorDim; ++j) norm2 += (double(q[j]) - hash_mean[j]) * (double(q[j]) - hash_mean[j]);
    const HashCode& qc = query_codes[f];
    const float* d = whole.many_distances.data() + whole.many_offsets[list];
    for (size_t k = 0; k < ids.size(); ++k) {
      const HashCode& pc = point_codes[ids[k]];
      const int h = std::popcount(qc.w[0] ^ pc.w[0]) + std::popcount(qc.w[1] ^ pc.w[1]);
      const double from_codes = 2 * norm2 * (1 - std::cos(std::numbers::pi * h / double(kHashBits)));
      out[k] = float((1 - weight) * double(d[k]) * double(d[k]) + weight * from_codes);
    }
  };
}

ShortlistDistances exact_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                   const DescriptorMatrix& points) {
  return [&whole, &queries, &points](size_t list, std::span<const uint32_t> ids, float* out) {
    const uint8_t* q = queries.row(whole.many_query[list]);
    for (size_t k = 0; k < ids.size(); ++k) {
      VISLOC_CHECK(ids[k] < points.rows(), "short-list point out of the descriptors' range");
      const uint8_t* p = points.row(ids[k]);
      float sum = 0;  // exact: integers below 2^24
      for (int j = 0; j < kDescriptorDim; ++j) {
        const float x = float(q[j]) - float(p[j]);
        sum += x * x;
      }
      out[k] = sum;
    }
  };
}

void FaissPqReranker::Options::validate() const {
  if (subquantizers < 1 || subquantizers > kDescriptorDim || kDescriptorDim % subquantizers != 0)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker.subquantizers must be a divisor of 128, got ",
                subquantizers);
  if (opq_iterations < 1)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker.opq_iterations must be >= 1, got ", opq_iterations);
  if (coarse_centroids < 0 || coarse_centroids == 1 || coarse_centroids > 65536)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker.coarse_centroids must be 0 or in [2, 65536], got ",
                coarse_centroids);
  if (residual_beam < 1)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker.residual_beam must be >= 1, got ", residual_beam);
  if (residual_splits < 0 ||
      (residual_splits > 0 && (kDescriptorDim % residual_splits != 0 || subquantizers % residual_splits != 0)))
    throw_error(ErrorCode::kInvalidArgument,
                "FaissPqReranker.residual_splits must be 0 or divide both 128 and subquantizers (", subquantizers,
                "), got ", residual_splits);
  if (int(opq_rotation) + int(coarse_centroids > 0) + int(residual_splits > 0) > 1)
    throw_error(ErrorCode::kInvalidArgument,
                "FaissPqReranker: opq_rotation, coarse_centroids and residual_splits exclude one another");
}

namespace {

std::unique_ptr<faiss::ProductQuantizer> make_pq(int subquantizers) {
  auto pq = std::make_unique<faiss::ProductQuantizer>(kDescriptorDim, subquantizers, 8);
  pq->verbose = false;
  pq->cp.min_points_per_centroid = 16;  // as PqCodebook: segments of a few thousand points are normal
  return pq;
}

}  // namespace

FaissPqReranker::FaissPqReranker(const float* points, size_t n, const Options& options) : num_points_(n) {
  options.validate();
  if (n < 256)
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker: ", n,
                " points, at least 256 are needed (one per centroid)");
  if (n < size_t(options.coarse_centroids))
    throw_error(ErrorCode::kInvalidArgument, "FaissPqReranker: ", n, " points, fewer than the ",
                options.coarse_centroids, " coarse centroids");
  std::vector<float> train(points, points + n * kDescriptorDim);
  const auto count = static_cast<int64_t>(n);
  if (options.residual_splits > 0) {
    const auto configure = [&options](faiss::ResidualQuantizer& rq) {
      rq.verbose = false;
      rq.cp.min_points_per_centroid = 16;
      rq.max_beam_size = options.residual_beam;
      rq.train_type = options.residual_progressive_dim ? faiss::ResidualQuantizer::Train_progressive_dim
                                                       : faiss::ResidualQuantizer::Train_default;
    };
    if (options.residual_splits == 1) {
      auto rq = std::make_unique<faiss::ResidualQuantizer>(kDescriptorDim, size_t(options.subquantizers), 8);
      configure(*rq);
      rq_ = std::move(rq);
    } else {
      const auto splits = size_t(options.residual_splits);
      auto prq = std::make_unique<faiss::ProductResidualQuantizer>(kDescriptorDim, splits,
                                                                   size_t(options.subquantizers) / splits, 8);
      prq->verbose = false;
      for (faiss::AdditiveQuantizer* q : prq->quantizers) configure(*dynamic_cast<faiss::ResidualQuantizer*>(q));
      rq_ = std::move(prq);
    }
    rq_->train(n, points);
    codes_.resize(n * rq_->code_size);
    rq_->compute_codes(points, codes_.data(), n);
    decoded_.resize(n * kDescriptorDim);
    rq_->decode(codes_.data(), decoded_.data(), n);
    rotated_.resize(kDescriptorDim);
    return;
  }
  std::vector<int64_t> cell;
  std::vector<float> coarse;
  if (options.coarse_centroids > 0) {
    coarse_centroids_ = size_t(options.coarse_centroids);
    faiss::ClusteringParameters cp;
    cp.verbose = false;
    cp.min_points_per_centroid = 16;
    faiss::Clustering clustering(kDescriptorDim, options.coarse_centroids, cp);
    faiss::IndexFlatL2 assign(kDescriptorDim);
    clustering.train(count, points, assign);
    coarse = clustering.centroids;
    cell.resize(n);
    std::vector<float> ignored(n);
    assign.search(count, points, 1, ignored.data(), cell.data());
    for (size_t i = 0; i < n; ++i) {
      VISLOC_CHECK(cell[i] >= 0 && size_t(cell[i]) < coarse_centroids_, "k-means assigned no cell");
      const float* c = coarse.data() + size_t(cell[i]) * kDescriptorDim;
      for (int j = 0; j < kDescriptorDim; ++j) train[i * kDescriptorDim + j] -= c[j];
    }
  }
  if (options.opq_rotation) {
    rotation_ = std::make_unique<faiss::OPQMatrix>(kDescriptorDim, options.subquantizers);
    rotation_->verbose = false;
    rotation_->niter = options.opq_iterations;
    const auto training_pq = make_pq(options.subquantizers);
    rotation_->pq = training_pq.get();  // used by train() only
    rotation_->train(count, points);
    rotation_->pq = nullptr;
    rotation_->apply_noalloc(count, points, train.data());
  }
  pq_ = make_pq(options.subquantizers);
  pq_->train(count, train.data());
  codes_.resize(n * pq_->code_size);
  pq_->compute_codes(train.data(), codes_.data(), count);
  table_.resize(pq_->M * pq_->ksub);
  rotated_.resize(kDescriptorDim);
  if (coarse_centroids_ > 0) {
    decoded_.resize(n * kDescriptorDim);
    pq_->decode(codes_.data(), decoded_.data(), count);
    for (size_t i = 0; i < n; ++i) {
      const float* c = coarse.data() + size_t(cell[i]) * kDescriptorDim;
      for (int j = 0; j < kDescriptorDim; ++j) decoded_[i * kDescriptorDim + j] += c[j];
    }
  }
}

FaissPqReranker::~FaissPqReranker() = default;

size_t FaissPqReranker::code_bytes() const {
  if (rq_) return rq_->code_size;
  return pq_->code_size + (coarse_centroids_ == 0 ? 0 : coarse_centroids_ <= 256 ? 1 : 2);
}

void FaissPqReranker::transform(const float* query, float* out) const {
  if (rotation_) {
    rotation_->apply_noalloc(1, query, out);
  } else {
    std::copy(query, query + kDescriptorDim, out);
  }
}

void FaissPqReranker::reconstruct(uint32_t id, float* out) const {
  VISLOC_CHECK(id < num_points_, "point id out of range");
  if (!decoded_.empty()) {
    std::copy_n(decoded_.data() + size_t(id) * kDescriptorDim, kDescriptorDim, out);
    return;
  }
  pq_->decode(codes_.data() + size_t(id) * pq_->code_size, out);
}

void FaissPqReranker::distances(const float* query, std::span<const uint32_t> ids, float* out) {
  if (!decoded_.empty()) {
    for (size_t i = 0; i < ids.size(); ++i) {
      VISLOC_CHECK(ids[i] < num_points_, "point id out of range");
      const float* x = decoded_.data() + size_t(ids[i]) * kDescriptorDim;
      float d = 0;
      for (int j = 0; j < kDescriptorDim; ++j) d += (query[j] - x[j]) * (query[j] - x[j]);
      out[i] = d;
    }
    return;
  }
  transform(query, rotated_.data());
  pq_->compute_distance_table(rotated_.data(), table_.data());
  const size_t m = pq_->M, k = pq_->ksub;
  for (size_t i = 0; i < ids.size(); ++i) {
    VISLOC_CHECK(ids[i] < num_points_, "point id out of range");
    const uint8_t* c = codes_.data() + size_t(ids[i]) * m;
    float d = 0;
    for (size_t j = 0; j < m; ++j) d += table_[j * k + c[j]];
    out[i] = d;
  }
}

ShortlistDistances faiss_distances(const CascadeMatches& whole, const DescriptorMatrix& queries,
                                   FaissPqReranker& reranker) {
  auto query = std::make_shared<std::vector<float>>(kDescriptorDim);
  return [&whole, &queries, &reranker, query](size_t list, std::span<const uint32_t> ids, float* out) {
    const uint8_t* q = queries.row(whole.many_query[list]);
    std::copy(q, q + kDescriptorDim, query->begin());
    reranker.distances(query->data(), ids, out);
  };
}

}  // namespace visloc
