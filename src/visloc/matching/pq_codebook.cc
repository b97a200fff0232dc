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
static_assert(kDim == 128 && kPqCentroidFloats == kDim * kPqCentroids);

faiss::ProductQuantizer make_faiss_pq(const std::vector<float>& centroids, int subvectors) {
  faiss::ProductQuantizer pq(kDim, subvectors, 8);
  VISLOC_CHECK(pq.centroids.size() == centroids.size());
  pq.centroids = centroids;
  return pq;
}
}  // namespace

void PqTrainingOptions::validate() const {
  if (!valid_pq_subvectors(subvectors))
    throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.subvectors must be 16 or 32 (bytes per PQ code), got ",
                subvectors);
  if (iterations < 1) throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.iterations must be >= 1");
  if (max_training < size_t(kPqCentroids))
    throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.max_training must be >= ", kPqCentroids);
}

PqCodebook::PqCodebook(std::vector<float> centroids, int subvectors)
    : subvectors_(subvectors), centroids_(std::move(centroids)) {
  if (!valid_pq_subvectors(subvectors))
    throw_error(ErrorCode::kInvalidArgument, "a PQ codebook has 16 or 32 sub-vectors, got ", subvectors);
  if (centroids_.size() != size_t(kPqCentroidFloats))
    throw_error(ErrorCode::kFormat, "a PQ codebook has ", kPqCentroidFloats, " floats, got ", centroids_.size());
  const int dims = sub_dimension();
  transposed_.resize(centroids_.size());
  for (int m = 0; m < subvectors_; ++m)
    for (int k = 0; k < kPqCentroids; ++k)
      for (int j = 0; j < dims; ++j)
        transposed_[(size_t(m) * dims + j) * kPqCentroids + k] = centroids_[(size_t(m) * kPqCentroids + k) * dims + j];
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
  faiss::ProductQuantizer pq(kDim, options.subvectors, 8);
  pq.cp.niter = options.iterations;
  pq.cp.seed = static_cast<int>(options.seed & 0x7fffffff);
  pq.cp.verbose = false;
  pq.cp.min_points_per_centroid = 16;  // maps of ~10K points are normal: no warning above 4096
  pq.verbose = false;
  pq.train(rows, data);
  return PqCodebook(pq.centroids, options.subvectors);
}

void PqCodebook::encode(const float* x, size_t n, uint8_t* codes) const {
  VISLOC_CHECK(!empty());
  if (n == 0) return;
  make_faiss_pq(centroids_, subvectors_).compute_codes(x, codes, n);
}

void PqCodebook::distance_table(const float* q, float* table) const {
  // The scalar search kernel: compiled without fused multiply-add, so every
  // SIMD level's table equals this one bit for bit.
  search_kernels(SimdLevel::kScalar).adc(subvectors_).table(transposed_.data(), q, table);
}

double PqCodebook::reconstruction_sqdist(const uint8_t* code, const float* x) const {
  double d = 0;
  const int dims = sub_dimension();
  for (int m = 0; m < subvectors_; ++m)
    for (int j = 0; j < dims; ++j) {
      const double e = x[m * dims + j] - centroids_[(size_t(m) * kPqCentroids + code[m]) * dims + j];
      d += e * e;
    }
  return d;
}

void PqCodebook::write(const std::filesystem::path& path, const std::string& meta_json) const {
  VISLOC_CHECK(!empty());
  const bool default_layout = subvectors_ == kPqSubvectors;
  SectionFileWriter w(path, "PQCB", default_layout ? kPqCodebook16FileVersion : kPqCodebookFileVersion);
  w.add_text("META", meta_json);
  w.add_array<float>("CENT", centroids_);
  if (!default_layout) {
    const uint32_t m = static_cast<uint32_t>(subvectors_);
    w.add_array<uint32_t>("SUBVEC", std::span<const uint32_t>(&m, 1));
  }
  w.commit();
}

PqCodebook PqCodebook::read(const std::filesystem::path& path, std::string* meta_json) {
  SectionFileReader r(path, "PQCB", kPqCodebook16FileVersion, kPqCodebookFileVersion);
  int subvectors = kPqSubvectors;
  if (r.kind_version() >= 2) {
    const uint32_t m = r.array<uint32_t>("SUBVEC", 1)[0];
    if (m != uint32_t(kPqSubvectors) && m != uint32_t(kPqFineSubvectors))
      throw_error(ErrorCode::kFormat, path.string(), ": section 'SUBVEC': ", m,
                  " sub-vectors (bytes per code); a codebook has 16 or 32");
    subvectors = static_cast<int>(m);
  } else if (r.has("SUBVEC")) {
    throw_error(ErrorCode::kFormat, path.string(), ": a version 1 codebook has no section 'SUBVEC' (16 sub-vectors)");
  }
  const int dims = 128 / subvectors;
  auto c = r.array<float>("CENT", kPqCentroidFloats);
  for (size_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(c[i]))
      throw_error(ErrorCode::kFormat, path.string(), ": section 'CENT': centroid ", i / dims % kPqCentroids,
                  " of subspace ", i / (size_t(kPqCentroids) * dims), " is not finite");
  // A subspace whose centroids are all equal cannot tell codes apart (every
  // ADC distance the same): the codebook was never trained.
  for (int m = 0; m < subvectors; ++m) {
    const float* first = c.data() + size_t(m) * kPqCentroids * dims;
    bool distinct = false;
    for (int k = 1; k < kPqCentroids && !distinct; ++k)
      distinct = !std::equal(first, first + dims, first + size_t(k) * dims);
    if (!distinct)
      throw_error(ErrorCode::kFormat, path.string(), ": section 'CENT': the ", kPqCentroids, " centroids of subspace ",
                  m, " are all equal (an untrained or zeroed codebook)");
  }
  if (meta_json) *meta_json = std::string(r.text("META"));
  return PqCodebook(std::vector<float>(c.begin(), c.end()), subvectors);
}

}  // namespace visloc
