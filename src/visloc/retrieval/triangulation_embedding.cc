#include "visloc/retrieval/triangulation_embedding.h"

#include <faiss/Clustering.h>
#include <faiss/IndexFlat.h>

#include <Eigen/Core>
#include <algorithm>
#include <limits>
#include <cmath>
#include <nlohmann/json.hpp>
#include <numeric>

#include "visloc/util/error.h"
#include "visloc/util/section_file.h"
#include "visloc/util/timer.h"
#include "visloc/util/random.h"
#include "visloc/util/json_fields.h"

// LAPACK / BLAS (Fortran interface), linked through FAISS's dependencies.
extern "C" {
void ssyrk_(const char* uplo, const char* trans, const int* n, const int* k, const float* alpha,
            const float* a, const int* lda, const float* beta, float* c, const int* ldc);
void ssyevr_(const char* jobz, const char* range, const char* uplo, const int* n, float* a,
             const int* lda, const float* vl, const float* vu, const int* il, const int* iu,
             const float* abstol, int* m, float* w, float* z, const int* ldz, int* isuppz,
             float* work, const int* lwork, int* iwork, const int* liwork, int* info);
}

namespace visloc {
namespace {

using RowMatrixF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using MapRowF = Eigen::Map<RowMatrixF>;
using ConstMapRowF = Eigen::Map<const RowMatrixF>;

// Descriptors as unit-norm floats, N × 128 row-major.
RowMatrixF to_unit_float(const DescriptorMatrix& d) {
  RowMatrixF x(static_cast<Eigen::Index>(d.rows()), kDescriptorDim);
  const uint8_t* src = d.data();
  float* dst = x.data();
  for (size_t i = 0; i < d.size_bytes(); ++i) dst[i] = static_cast<float>(src[i]) * kDescriptorToUnit;
  return x;
}

// w_ij = 1 / ||x_i - c_j|| (0 when x_i coincides with c_j), N × k.
RowMatrixF inverse_distances(const RowMatrixF& x, const RowMatrixF& c, const Eigen::VectorXf& c_sqnorm) {
  RowMatrixF w = x * c.transpose();  // N × k dot products
  const Eigen::VectorXf x_sqnorm = x.rowwise().squaredNorm();
  for (Eigen::Index i = 0; i < w.rows(); ++i)
    for (Eigen::Index j = 0; j < w.cols(); ++j) {
      const float d2 = x_sqnorm[i] + c_sqnorm[j] - 2.0f * w(i, j);
      w(i, j) = d2 > 1e-12f ? 1.0f / std::sqrt(d2) : 0.0f;
    }
  return w;
}

// Explicit R(x) - R0 for every row: N × k·128 row-major into out.
void centred_residuals(const RowMatrixF& x, const RowMatrixF& c, const Eigen::VectorXf& c_sqnorm,
                       const float* mean, float* out) {
  const RowMatrixF w = inverse_distances(x, c, c_sqnorm);
  const Eigen::Index k = c.rows();
  const size_t in_dims = static_cast<size_t>(k) * kDescriptorDim;
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    float* row = out + static_cast<size_t>(i) * in_dims;
    const float* xi = x.data() + i * kDescriptorDim;
    for (Eigen::Index j = 0; j < k; ++j) {
      const float wij = w(i, j);
      const float* cj = c.data() + j * kDescriptorDim;
      float* r = row + j * kDescriptorDim;
      const float* m = mean + j * kDescriptorDim;
      for (int t = 0; t < kDescriptorDim; ++t) r[t] = (xi[t] - cj[t]) * wij - m[t];
    }
  }
}

// Uniform sample (without replacement) of `count` global descriptor indices
// among `total`, sorted.
std::vector<size_t> sample_indices(size_t total, size_t count, uint64_t seed) {
  RandomGenerator rng(seed);
  return visloc::sample_sorted_indices(total, count, rng);
}

// Gathers the sampled rows of all images into one matrix.
DescriptorMatrix gather(std::span<const DescriptorMatrix* const> images, const std::vector<size_t>& sorted_idx) {
  DescriptorMatrix out(sorted_idx.size());
  size_t image = 0, image_start = 0;
  for (size_t r = 0; r < sorted_idx.size(); ++r) {
    const size_t g = sorted_idx[r];
    while (g >= image_start + images[image]->rows()) image_start += images[image++]->rows();
    std::copy_n(images[image]->row(g - image_start), kDescriptorDim, out.row(r));
  }
  return out;
}

const char* pooling_name(EmbeddingPooling p) { return p == EmbeddingPooling::kSum ? "sum" : "democratic"; }

// Vocabulary: FAISS k-means on a uniform sample of descriptors; k × 128
// centroids. Sets stats->kmeans_descriptors.
std::vector<float> train_vocabulary(std::span<const DescriptorMatrix* const> images, size_t total_rows, int k,
                                    const TriangulationEmbeddingOptions& options,
                                    TriangulationEmbeddingTrainStats* stats) {
  const auto idx = sample_indices(total_rows, static_cast<size_t>(options.max_kmeans_descriptors), options.seed);
  const RowMatrixF x = to_unit_float(gather(images, idx));
  faiss::ClusteringParameters cp;
  cp.niter = options.kmeans_iterations;
  cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  cp.max_points_per_centroid = 1 << 30;  // our sample is the training set
  cp.verbose = false;
  faiss::Clustering clustering(kDescriptorDim, k, cp);
  faiss::IndexFlatL2 assigner(kDescriptorDim);
  clustering.train(static_cast<faiss::Index::idx_t>(x.rows()), x.data(), assigner);
  stats->kmeans_descriptors = idx.size();
  return std::vector<float>(clustering.centroids.begin(), clustering.centroids.end());
}

// Squared norm of each of the k centroids (k × 128 row-major).
std::vector<float> squared_norms(const std::vector<float>& centroids, int k) {
  std::vector<float> sqnorm(k);
  for (int j = 0; j < k; ++j) {
    float s = 0;
    for (int t2 = 0; t2 < kDescriptorDim; ++t2)
      s += centroids[j * kDescriptorDim + t2] * centroids[j * kDescriptorDim + t2];
    sqnorm[j] = s;
  }
  return sqnorm;
}

// Covariance Σ of the centred residuals R(x) − R0 of the descriptors (lower
// triangle, column-major in_dims × in_dims): Aᵀ-chunks accumulated by SYRK,
// then divided by their number.
std::vector<float> residual_covariance(const DescriptorMatrix& descriptors, const std::vector<float>& centroids,
                                       const std::vector<float>& centroid_sqnorm, const std::vector<float>& mean,
                                       int k, size_t chunk_rows) {
  const int in_dims = k * kDescriptorDim;
  const size_t n = descriptors.rows();
  std::vector<float> cov(static_cast<size_t>(in_dims) * in_dims, 0.0f);
  const RowMatrixF c = ConstMapRowF(centroids.data(), k, kDescriptorDim);
  const Eigen::VectorXf c_sqnorm = Eigen::Map<const Eigen::VectorXf>(centroid_sqnorm.data(), k);
  std::vector<float> a(chunk_rows * static_cast<size_t>(in_dims));
  const float one = 1.0f;
  for (size_t s = 0; s < n; s += chunk_rows) {
    const int rows = static_cast<int>(std::min(chunk_rows, n - s));
    const RowMatrixF x = to_unit_float(DescriptorMatrix(descriptors.row(s), static_cast<size_t>(rows)));
    centred_residuals(x, c, c_sqnorm, mean.data(), a.data());
    // a is rows × in_dims row-major = in_dims × rows column-major.
    ssyrk_("L", "N", &in_dims, &rows, &one, a.data(), &in_dims, &one, cov.data(), &in_dims);
  }
  const float inv_n = 1.0f / static_cast<float>(n);
  for (float& v : cov) v *= inv_n;
  return cov;
}

// The whitening projection from the top eigenpairs of the covariance.
struct Whitening {
  std::vector<float> eigenvalues;  // out_dims, largest first
  std::vector<float> projection;   // out_dims × in_dims: eigenvectors scaled by regularized inverse square roots
  double kept_variance = 0;        // sum of the kept eigenvalues (negative ones as 0)
};

// Top out_dims eigenpairs of cov (LAPACK SSYEVR; cov is overwritten), scaled
// by 1 / sqrt(max(λ, floor)).
Whitening top_eigenpairs(std::vector<float>& cov, int in_dims, int out_dims, float floor) {
  Whitening out;
  const int il = in_dims - out_dims + 1, iu = in_dims;
  const char* range = out_dims == in_dims ? "A" : "I";
  const float vl = 0, vu = 0, abstol = 0;
  int m = 0, info = 0;
  std::vector<float> w(in_dims), z(static_cast<size_t>(in_dims) * out_dims);
  std::vector<int> isuppz(2 * static_cast<size_t>(std::max(1, out_dims)));
  float work_query = 0;
  int iwork_query = 0, lwork = -1, liwork = -1;
  ssyevr_("V", range, "L", &in_dims, cov.data(), &in_dims, &vl, &vu, &il, &iu, &abstol, &m, w.data(), z.data(),
          &in_dims, isuppz.data(), &work_query, &lwork, &iwork_query, &liwork, &info);
  VISLOC_CHECK(info == 0, "ssyevr workspace query");
  lwork = static_cast<int>(work_query) + 1;
  liwork = iwork_query;
  std::vector<float> work(lwork);
  std::vector<int> iwork(liwork);
  ssyevr_("V", range, "L", &in_dims, cov.data(), &in_dims, &vl, &vu, &il, &iu, &abstol, &m, w.data(), z.data(),
          &in_dims, isuppz.data(), work.data(), &lwork, iwork.data(), &liwork, &info);
  if (info != 0 || m != out_dims)
    throw_error(ErrorCode::kInternal, "LAPACK ssyevr failed (info ", info, ", ", m, " of ", out_dims,
                " eigenpairs)");
  // Ascending order from LAPACK: output component r is eigenpair m-1-r.
  out.eigenvalues.resize(out_dims);
  out.projection.resize(static_cast<size_t>(out_dims) * in_dims);
  double kept = 0;
  for (int r = 0; r < out_dims; ++r) {
    const int src = m - 1 - r;
    const float lambda = w[src];
    kept += std::max(0.0f, lambda);
    out.eigenvalues[r] = lambda;
    const float scale = 1.0f / std::sqrt(std::max(lambda, floor));
    const float* u = z.data() + static_cast<size_t>(src) * in_dims;
    float* p = out.projection.data() + static_cast<size_t>(r) * in_dims;
    for (int d = 0; d < in_dims; ++d) p[d] = u[d] * scale;
  }
  out.kept_variance = kept;
  return out;
}

}  // namespace

void TriangulationEmbeddingOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "triangulation embedding option ", field, " = ", value,
                ": ", rule);
  };
  if (vocabulary_size < 1 || vocabulary_size > 1024) bad("vocabulary_size", vocabulary_size, "must be in [1, 1024]");
  if (output_dims < 0 || output_dims > vocabulary_size * kDescriptorDim)
    bad("output_dims", output_dims, "must be 0 (full) or in [1, vocabulary_size * 128]");
  if (!(power_law_alpha > 0.0 && power_law_alpha <= 1.0)) bad("power_law_alpha", power_law_alpha, "must be in (0, 1]");
  if (!(eigenvalue_floor > 0.0 && std::isfinite(eigenvalue_floor)))
    bad("eigenvalue_floor", eigenvalue_floor, "must be a positive number");
  if (kmeans_iterations < 1) bad("kmeans_iterations", kmeans_iterations, "must be at least 1");
  if (max_kmeans_descriptors < vocabulary_size)
    bad("max_kmeans_descriptors", max_kmeans_descriptors, "must be at least vocabulary_size");
  if (max_whitening_descriptors < 2) bad("max_whitening_descriptors", max_whitening_descriptors, "must be at least 2");
  if (democratic_iterations < 0) bad("democratic_iterations", democratic_iterations, "must be non-negative");
  if (!(democratic_gamma > 0.0 && democratic_gamma <= 1.0))
    bad("democratic_gamma", democratic_gamma, "must be in (0, 1]");
}

std::string TriangulationEmbeddingOptions::to_json() const {
  nlohmann::json j = {{"vocabulary_size", vocabulary_size},
                      {"output_dims", output_dims},
                      {"pooling", pooling_name(pooling)},
                      {"power_law_alpha", power_law_alpha},
                      {"eigenvalue_floor", eigenvalue_floor},
                      {"kmeans_iterations", kmeans_iterations},
                      {"max_kmeans_descriptors", max_kmeans_descriptors},
                      {"max_whitening_descriptors", max_whitening_descriptors},
                      {"democratic_iterations", democratic_iterations},
                      {"democratic_gamma", democratic_gamma},
                      {"seed", seed}};
  return j.dump();
}

TriangulationEmbedding TriangulationEmbedding::train(std::span<const DescriptorMatrix* const> images,
                                                     const TriangulationEmbeddingOptions& options,
                                                     TriangulationEmbeddingTrainStats* stats_out) {
  options.validate();
  Timer total;
  TriangulationEmbeddingTrainStats stats;
  stats.images = images.size();
  size_t total_rows = 0;
  for (const DescriptorMatrix* d : images) {
    VISLOC_CHECK(d != nullptr);
    total_rows += d->rows();
  }
  const int k = options.vocabulary_size;
  const int in_dims = k * kDescriptorDim;
  const int out_dims = options.output_dims == 0 ? in_dims : options.output_dims;
  const size_t min_kmeans = static_cast<size_t>(39) * k;  // FAISS's minimum for a stable k-means
  if (total_rows < min_kmeans)
    throw_error(ErrorCode::kInvalidArgument, "triangulation embedding training: ", total_rows, " descriptors in ",
                images.size(), " images, need at least ", min_kmeans, " (39 per vocabulary word, k = ", k, ")");

  TriangulationEmbedding e;
  e.options_ = options;
  e.k_ = k;
  e.out_dims_ = out_dims;

  // 1. Vocabulary: FAISS k-means on a uniform sample of descriptors.
  Timer t;
  e.centroids_ = train_vocabulary(images, total_rows, k, options, &stats);
  e.centroid_sqnorm_ = squared_norms(e.centroids_, k);
  stats.kmeans_ms = t.elapsed_ms();

  // 2. Centring R0 and covariance Σ of R(x) over a second sample.
  t.reset();
  const auto widx =
      sample_indices(total_rows, static_cast<size_t>(options.max_whitening_descriptors), options.seed ^ 0x9e3779b97f4a7c15ULL);
  const size_t n = widx.size();
  if (n <= static_cast<size_t>(out_dims) && options.output_dims != 0)
    throw_error(ErrorCode::kInvalidArgument, "triangulation embedding training: ", n,
                " whitening descriptors for ", out_dims, " output dimensions; need more descriptors or fewer dims");
  const DescriptorMatrix wdesc = gather(images, widx);
  e.mean_.assign(in_dims, 0.0f);
  constexpr size_t kChunk = 1024;
  {
    std::vector<double> sum(in_dims, 0.0);
    std::vector<float> part(in_dims);
    for (size_t s = 0; s < n; s += kChunk) {
      const size_t rows = std::min(kChunk, n - s);
      DescriptorMatrix chunk(wdesc.row(s), rows);
      e.residual_sum(chunk, part.data());
      for (int d = 0; d < in_dims; ++d) sum[d] += part[d];
    }
    for (int d = 0; d < in_dims; ++d) e.mean_[d] = static_cast<float>(sum[d] / static_cast<double>(n));
  }
  std::vector<float> cov = residual_covariance(wdesc, e.centroids_, e.centroid_sqnorm_, e.mean_, k, kChunk);
  stats.whitening_descriptors = n;
  stats.covariance_ms = t.elapsed_ms();

  // 3. Top eigenpairs (LAPACK SSYEVR), regularized inverse square roots.
  t.reset();
  double trace = 0;
  for (int d = 0; d < in_dims; ++d) trace += cov[static_cast<size_t>(d) * in_dims + d];
  const double mean_eigenvalue = trace / in_dims;
  if (!(mean_eigenvalue > 0))
    throw_error(ErrorCode::kInvalidArgument, "triangulation embedding training: the residual covariance is zero ",
                "(all training descriptors identical?)");
  const float floor = static_cast<float>(options.eigenvalue_floor * mean_eigenvalue);
  Whitening whitening = top_eigenpairs(cov, in_dims, out_dims, floor);
  e.eigenvalues_ = std::move(whitening.eigenvalues);
  e.projection_ = std::move(whitening.projection);
  stats.retained_variance = whitening.kept_variance / trace;
  stats.eigen_ms = t.elapsed_ms();
  stats.total_ms = total.elapsed_ms();
  e.train_stats_ = stats;
  if (stats_out) *stats_out = stats;
  return e;
}

TriangulationEmbedding TriangulationEmbedding::reduced(int output_dims) const {
  VISLOC_CHECK(k_ > 0, "reducing an untrained embedding");
  if (output_dims < 1 || output_dims > out_dims_)
    throw_error(ErrorCode::kInvalidArgument, "triangulation embedding option output_dims = ", output_dims,
                ": must be in [1, ", out_dims_, "] to reduce this embedding");
  TriangulationEmbedding e = *this;
  e.out_dims_ = output_dims;
  e.options_.output_dims = output_dims == input_dims() ? 0 : output_dims;
  e.projection_.resize(static_cast<size_t>(output_dims) * input_dims());
  e.eigenvalues_.resize(output_dims);
  double kept = 0, all = 0;
  for (float l : eigenvalues_) all += std::max(0.0f, l);
  for (float l : e.eigenvalues_) kept += std::max(0.0f, l);
  if (all > 0) e.train_stats_.retained_variance = train_stats_.retained_variance * kept / all;
  return e;
}

void TriangulationEmbedding::residual_sum(const DescriptorMatrix& descriptors, float* out) const {
  const RowMatrixF x = to_unit_float(descriptors);
  const ConstMapRowF c(centroids_.data(), k_, kDescriptorDim);
  const Eigen::Map<const Eigen::VectorXf> c_sqnorm(centroid_sqnorm_.data(), k_);
  const RowMatrixF w = inverse_distances(x, c, c_sqnorm);       // N × k
  MapRowF s(out, k_, kDescriptorDim);
  s.noalias() = w.transpose() * x;                               // Σ_i w_ij x_i
  const Eigen::VectorXf wsum = w.colwise().sum().transpose();    // Σ_i w_ij
  for (int j = 0; j < k_; ++j) s.row(j) -= wsum[j] * c.row(j);
}

void TriangulationEmbedding::finish(std::vector<float>& y, float* out) const {
  const float alpha = static_cast<float>(options_.power_law_alpha);
  double norm2 = 0;
  for (size_t i = 0; i < y.size(); ++i) {
    float v = y[i];
    if (alpha != 1.0f) v = std::copysign(std::pow(std::fabs(v), alpha), v);
    y[i] = v;
    norm2 += static_cast<double>(v) * v;
  }
  const float inv = norm2 > 0 ? static_cast<float>(1.0 / std::sqrt(norm2)) : 0.0f;
  for (size_t i = 0; i < y.size(); ++i) out[i] = y[i] * inv;
}

std::vector<float> TriangulationEmbedding::embed(const DescriptorMatrix& descriptors) const {
  std::vector<float> out(out_dims_);
  embed(descriptors, out.data());
  return out;
}

void TriangulationEmbedding::embed(const DescriptorMatrix& descriptors, float* out) const {
  VISLOC_CHECK(k_ > 0, "embedding used before training or loading");
  const int in_dims = input_dims();
  const ConstMapRowF proj(projection_.data(), out_dims_, in_dims);
  std::vector<float> y(out_dims_, 0.0f);
  const size_t n = descriptors.rows();
  if (n == 0) {
    std::fill_n(out, out_dims_, 0.0f);
    return;
  }
  if (options_.pooling == EmbeddingPooling::kSum || n == 1) {
    // ψ = P (Σ R(x) - n R0)
    std::vector<float> z(in_dims);
    residual_sum(descriptors, z.data());
    for (int d = 0; d < in_dims; ++d) z[d] -= static_cast<float>(n) * mean_[d];
    Eigen::Map<Eigen::VectorXf>(y.data(), out_dims_).noalias() =
        proj * Eigen::Map<const Eigen::VectorXf>(z.data(), in_dims);
  } else {
    // Democratic: Φ = (R - R0) Pᵀ (n × D'), K = max(ΦΦᵀ, 0), Sinkhorn weights.
    const RowMatrixF x = to_unit_float(descriptors);
    const ConstMapRowF c(centroids_.data(), k_, kDescriptorDim);
    const Eigen::Map<const Eigen::VectorXf> c_sqnorm(centroid_sqnorm_.data(), k_);
    RowMatrixF r(static_cast<Eigen::Index>(n), in_dims);
    centred_residuals(x, c, c_sqnorm, mean_.data(), r.data());
    const RowMatrixF phi = r * proj.transpose();
    RowMatrixF gram = phi * phi.transpose();
    gram = gram.cwiseMax(0.0f);
    Eigen::VectorXf lambda = Eigen::VectorXf::Ones(static_cast<Eigen::Index>(n));
    const float gamma = static_cast<float>(options_.democratic_gamma);
    for (int it = 0; it < options_.democratic_iterations; ++it) {
      const Eigen::VectorXf sigma = lambda.cwiseProduct(gram * lambda);
      for (Eigen::Index i = 0; i < lambda.size(); ++i)
        if (sigma[i] > 0) lambda[i] /= std::pow(sigma[i], gamma);
    }
    Eigen::Map<Eigen::VectorXf>(y.data(), out_dims_).noalias() = phi.transpose() * lambda;
  }
  finish(y, out);
}

std::vector<float> TriangulationEmbedding::vlad(const DescriptorMatrix& descriptors) const {
  VISLOC_CHECK(k_ > 0, "embedding used before training or loading");
  std::vector<float> v(vlad_dims(), 0.0f);
  if (descriptors.rows() == 0) return v;
  const RowMatrixF x = to_unit_float(descriptors);
  const ConstMapRowF c(centroids_.data(), k_, kDescriptorDim);
  const RowMatrixF dots = x * c.transpose();
  for (Eigen::Index i = 0; i < x.rows(); ++i) {
    int best = 0;
    float best_d = centroid_sqnorm_[0] - 2 * dots(i, 0);
    for (int j = 1; j < k_; ++j) {
      const float d = centroid_sqnorm_[j] - 2 * dots(i, j);
      if (d < best_d) best_d = d, best = j;
    }
    float* acc = v.data() + best * kDescriptorDim;
    for (int t = 0; t < kDescriptorDim; ++t) acc[t] += x(i, t) - c(best, t);
  }
  double norm2 = 0;
  for (float& a : v) {
    a = std::copysign(std::sqrt(std::fabs(a)), a);
    norm2 += static_cast<double>(a) * a;
  }
  if (norm2 > 0) {
    const float inv = static_cast<float>(1.0 / std::sqrt(norm2));
    for (float& a : v) a *= inv;
  }
  return v;
}

size_t TriangulationEmbedding::parameter_bytes() const {
  return sizeof(float) *
         (centroids_.size() + centroid_sqnorm_.size() + mean_.size() + projection_.size() + eigenvalues_.size());
}

void TriangulationEmbedding::save(const std::filesystem::path& path) const {
  VISLOC_CHECK(k_ > 0, "saving an untrained embedding");
  const auto& s = train_stats_;
  nlohmann::json meta = {{"vocabulary_size", k_},
                         {"input_dims", input_dims()},
                         {"output_dims", out_dims_},
                         {"options", nlohmann::json::parse(options_.to_json())},
                         {"training",
                          {{"images", s.images},
                           {"kmeans_descriptors", s.kmeans_descriptors},
                           {"whitening_descriptors", s.whitening_descriptors},
                           {"retained_variance", s.retained_variance}}}};
  SectionFileWriter w(path, "TEMB", kTriangulationEmbeddingFileVersion);
  w.add_text("META", meta.dump());
  w.add_array<float>("CENT", centroids_);
  w.add_array<float>("MEAN", mean_);
  w.add_array<float>("PROJ", projection_);
  w.add_array<float>("EIGV", eigenvalues_);
  w.commit();
}

TriangulationEmbedding TriangulationEmbedding::load(const std::filesystem::path& path) {
  SectionFileReader r(path, "TEMB", 1, kTriangulationEmbeddingFileVersion);
  auto fail = [&](const auto&... parts) { throw_error(ErrorCode::kFormat, path.string(), ": ", parts...); };
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(r.text("META"));
  } catch (const nlohmann::json::exception& ex) {
    fail("META is not valid JSON (", ex.what(), ")");
  }
  // Integers only, in range (json_fields.h): get<int>() of 1e73 would convert a
  // double out of range (undefined behaviour; found by fuzzing).
  const JsonField m(meta, path.string(), "META");
  auto as_int = [](const JsonField& f, const char* key) {
    return static_cast<int>(f.at(key).integer(std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
  };
  auto as_size = [](const JsonField& f, const char* key) {
    return static_cast<size_t>(f.at(key).unsigned_integer(std::numeric_limits<size_t>::max()));
  };
  TriangulationEmbedding e;
  try {
    e.k_ = as_int(m, "vocabulary_size");
    e.out_dims_ = as_int(m, "output_dims");
    const JsonField mo = m.at("options"), mt = m.at("training");
    const auto& o = meta.at("options");
    auto& opt = e.options_;
    opt.vocabulary_size = as_int(mo, "vocabulary_size");
    opt.output_dims = as_int(mo, "output_dims");
    const std::string pooling = o.at("pooling").get<std::string>();
    if (pooling != "sum" && pooling != "democratic") fail("unknown pooling '", pooling, "'");
    opt.pooling = pooling == "sum" ? EmbeddingPooling::kSum : EmbeddingPooling::kDemocratic;
    opt.power_law_alpha = o.at("power_law_alpha").get<double>();
    opt.eigenvalue_floor = o.at("eigenvalue_floor").get<double>();
    opt.kmeans_iterations = as_int(mo, "kmeans_iterations");
    opt.max_kmeans_descriptors = as_int(mo, "max_kmeans_descriptors");
    opt.max_whitening_descriptors = as_int(mo, "max_whitening_descriptors");
    opt.democratic_iterations = as_int(mo, "democratic_iterations");
    opt.democratic_gamma = o.at("democratic_gamma").get<double>();
    opt.seed = mo.at("seed").unsigned_integer();
    const auto& tr = meta.at("training");
    e.train_stats_.images = as_size(mt, "images");
    e.train_stats_.kmeans_descriptors = as_size(mt, "kmeans_descriptors");
    e.train_stats_.whitening_descriptors = as_size(mt, "whitening_descriptors");
    e.train_stats_.retained_variance = tr.at("retained_variance").get<double>();
  } catch (const nlohmann::json::exception& ex) {
    fail("META is missing a field or has a wrong type (", ex.what(), ")");
  }
  if (e.k_ < 1 || e.k_ > 1024 || e.k_ != e.options_.vocabulary_size) fail("bad vocabulary size ", e.k_);
  const int in_dims = e.k_ * kDescriptorDim;
  if (e.out_dims_ < 1 || e.out_dims_ > in_dims) fail("bad output dims ", e.out_dims_);
  try {
    e.options_.validate();
  } catch (const Error& ex) {
    fail("stored options are invalid: ", ex.what());
  }
  auto copy = [&](const char* tag, int64_t count, std::vector<float>& dst) {
    auto a = r.array<float>(tag, count);
    dst.assign(a.begin(), a.end());
    for (float v : dst)
      if (!std::isfinite(v)) fail("section ", tag, " holds a non-finite value");
  };
  copy("CENT", static_cast<int64_t>(e.k_) * kDescriptorDim, e.centroids_);
  copy("MEAN", in_dims, e.mean_);
  copy("PROJ", static_cast<int64_t>(e.out_dims_) * in_dims, e.projection_);
  copy("EIGV", e.out_dims_, e.eigenvalues_);
  e.centroid_sqnorm_.resize(e.k_);
  for (int j = 0; j < e.k_; ++j) {
    float s = 0;
    for (int t = 0; t < kDescriptorDim; ++t) s += e.centroids_[j * kDescriptorDim + t] * e.centroids_[j * kDescriptorDim + t];
    e.centroid_sqnorm_[j] = s;
  }
  return e;
}

}  // namespace visloc
