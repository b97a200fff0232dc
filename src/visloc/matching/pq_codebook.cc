#include "visloc/matching/pq_codebook.h"

#include <cmath>

#include <faiss/impl/ProductQuantizer.h>

#include <algorithm>
#include <numeric>

#include "visloc/matching/search_kernels.h"
#include "visloc/util/error.h"
#include "visloc/util/section_file.h"
#include "visloc/util/random.h"

namespace visloc {
namespace {
constexpr int kDim = kPqSubvectors * kPqSubDim;
static_assert(kDim == 128);

faiss::ProductQuantizer make_faiss_pq(const std::vector<float>& centroids) {
  faiss::ProductQuantizer pq(kDim, kPqSubvectors, 8);
  VISLOC_CHECK(pq.centroids.size() == centroids.size());
  pq.centroids = centroids;
  return pq;
}
}  // namespace

void PqTrainingOptions::validate() const {
  if (iterations < 1) throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.iterations must be >= 1");
  if (max_training < size_t(kPqCentroids))
    throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.max_training must be >= ", kPqCentroids);
}

PqCodebook::PqCodebook(std::vector<float> centroids) : centroids_(std::move(centroids)) {
  if (centroids_.size() != size_t(kPqTableSize) * kPqSubDim)
    throw_error(ErrorCode::kFormat, "a PQ codebook has ", kPqTableSize * kPqSubDim, " floats, got ", centroids_.size());
  transposed_.resize(centroids_.size());
  for (int m = 0; m < kPqSubvectors; ++m)
    for (int k = 0; k < kPqCentroids; ++k)
      for (int j = 0; j < kPqSubDim; ++j)
        transposed_[(size_t(m) * kPqSubDim + j) * kPqCentroids + k] = centroids_[(size_t(m) * kPqCentroids + k) * kPqSubDim + j];
}

PqCodebook PqCodebook::train(const float* x, size_t n, const PqTrainingOptions& options) {
  options.validate();
  if (n < size_t(kPqCentroids))
    throw_error(ErrorCode::kInvalidArgument, "PQ training needs at least ", kPqCentroids, " descriptors, got ", n);
  std::vector<float> sample;
  const float* data = x;
  size_t rows = n;
  if (n > options.max_training) {
    RandomGenerator rng(options.seed);
    const std::vector<size_t> idx = sample_sorted_indices(n, options.max_training, rng);
    sample.resize(idx.size() * kDim);
    for (size_t i = 0; i < idx.size(); ++i) std::copy_n(x + idx[i] * kDim, kDim, sample.data() + i * kDim);
    data = sample.data();
    rows = idx.size();
  }
  faiss::ProductQuantizer pq(kDim, kPqSubvectors, 8);
  pq.cp.niter = options.iterations;
  pq.cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  pq.cp.verbose = false;
  pq.cp.min_points_per_centroid = 16;  // maps of ~10K points are normal: no warning above 4096
  pq.verbose = false;
  pq.train(rows, data);
  return PqCodebook(pq.centroids);
}

void PqCodebook::encode(const float* x, size_t n, uint8_t* codes) const {
  VISLOC_CHECK(!empty());
  if (n == 0) return;
  make_faiss_pq(centroids_).compute_codes(x, codes, n);
}

void PqCodebook::distance_table(const float* q, float* table) const {
  // The scalar search kernel: compiled without fused multiply-add, so every
  // SIMD level's table equals this one bit for bit.
  search_kernels(SimdLevel::kScalar).adc_table(transposed_.data(), q, table);
}

double PqCodebook::reconstruction_sqdist(const uint8_t* code, const float* x) const {
  double d = 0;
  for (int m = 0; m < kPqSubvectors; ++m)
    for (int j = 0; j < kPqSubDim; ++j) {
      const double e = x[m * kPqSubDim + j] - centroids_[(size_t(m) * kPqCentroids + code[m]) * kPqSubDim + j];
      d += e * e;
    }
  return d;
}

void PqCodebook::write(const std::filesystem::path& path, const std::string& meta_json) const {
  VISLOC_CHECK(!empty());
  SectionFileWriter w(path, "PQCB", kPqCodebookFileVersion);
  w.add_text("META", meta_json);
  w.add_array<float>("CENT", centroids_);
  w.commit();
}

PqCodebook PqCodebook::read(const std::filesystem::path& path, std::string* meta_json) {
  SectionFileReader r(path, "PQCB", kPqCodebookFileVersion, kPqCodebookFileVersion);
  auto c = r.array<float>("CENT", int64_t(kPqTableSize) * kPqSubDim);
  for (size_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(c[i]))
      throw_error(ErrorCode::kFormat, path.string(), ": section 'CENT': centroid ", i / kPqSubDim % kPqCentroids,
                  " of subspace ", i / (size_t(kPqCentroids) * kPqSubDim), " is not finite");
  // A subspace whose centroids are all equal cannot tell codes apart (every
  // ADC distance the same): the codebook was never trained.
  for (int m = 0; m < kPqSubvectors; ++m) {
    const float* first = c.data() + size_t(m) * kPqCentroids * kPqSubDim;
    bool distinct = false;
    for (int k = 1; k < kPqCentroids && !distinct; ++k)
      distinct = !std::equal(first, first + kPqSubDim, first + size_t(k) * kPqSubDim);
    if (!distinct)
      throw_error(ErrorCode::kFormat, path.string(), ": section 'CENT': the ", kPqCentroids, " centroids of subspace ",
                  m, " are all equal (an untrained or zeroed codebook)");
  }
  if (meta_json) *meta_json = std::string(r.text("META"));
  return PqCodebook(std::vector<float>(c.begin(), c.end()));
}

}  // namespace visloc
