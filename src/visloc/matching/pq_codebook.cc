#include "visloc/matching/pq_codebook.h"

#include <cmath>

#include <faiss/impl/ProductAdditiveQuantizer.h>
#include <faiss/impl/ProductQuantizer.h>
#include <faiss/impl/ResidualQuantizer.h>

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

size_t residual_floats(int splits) { return size_t(kAdditiveCodebooks) * kPqCentroids * size_t(kDim / splits); }

void configure(faiss::ResidualQuantizer& rq, int beam, uint64_t seed, int iterations, bool progressive_dim) {
  rq.verbose = false;
  rq.train_type =
      progressive_dim ? faiss::ResidualQuantizer::Train_progressive_dim : faiss::ResidualQuantizer::Train_default;
  rq.max_beam_size = beam;
  rq.cp.niter = iterations;
  rq.cp.seed = static_cast<int>(seed & 0x7fffffff);
  rq.cp.verbose = false;
  rq.cp.min_points_per_centroid = 16;
}

// FAISS's quantizer of S splits (S = 1: a ResidualQuantizer; else a
// ProductResidualQuantizer of S), with the given codebooks when not empty.
std::unique_ptr<faiss::AdditiveQuantizer> make_faiss_residual(int splits, int beam, uint64_t seed, int iterations,
                                                              bool progressive_dim,
                                                              const std::vector<float>& codebooks) {
  const size_t books = size_t(kAdditiveCodebooks) / size_t(splits), dims = size_t(kDim) / size_t(splits);
  const auto load = [&](faiss::ResidualQuantizer& rq, size_t split) {
    configure(rq, beam, seed, iterations, progressive_dim);
    if (codebooks.empty()) return;
    const size_t floats = books * kPqCentroids * dims;
    rq.codebooks.assign(codebooks.begin() + std::ptrdiff_t(split * floats),
                        codebooks.begin() + std::ptrdiff_t((split + 1) * floats));
    rq.is_trained = true;
  };
  if (splits == 1) {
    auto rq = std::make_unique<faiss::ResidualQuantizer>(kDim, books, 8);
    load(*rq, 0);
    return rq;
  }
  auto prq = std::make_unique<faiss::ProductResidualQuantizer>(kDim, size_t(splits), books, 8);
  prq->verbose = false;
  VISLOC_CHECK(prq->quantizers.size() == size_t(splits));
  for (size_t s = 0; s < prq->quantizers.size(); ++s) {
    auto* rq = dynamic_cast<faiss::ResidualQuantizer*>(prq->quantizers[s]);
    VISLOC_CHECK(rq != nullptr);
    load(*rq, s);
  }
  if (!codebooks.empty()) prq->is_trained = true;
  return prq;
}

// The codebooks of a trained quantizer from make_faiss_residual, split after split.
std::vector<float> residual_codebooks(const faiss::AdditiveQuantizer& q, int splits) {
  std::vector<float> out;
  if (splits == 1) {
    out = q.codebooks;
  } else {
    const auto& prq = dynamic_cast<const faiss::ProductResidualQuantizer&>(q);
    for (const faiss::AdditiveQuantizer* sub : prq.quantizers)
      out.insert(out.end(), sub->codebooks.begin(), sub->codebooks.end());
  }
  VISLOC_CHECK(out.size() == residual_floats(splits), "FAISS's residual codebooks have ", out.size(), " floats");
  return out;
}
}  // namespace

const char* to_string(PqQuantizer quantizer) { return quantizer == PqQuantizer::kResidual ? "residual" : "product"; }

void PqTrainingOptions::validate() const {
  if (!valid_pq_subvectors(subvectors))
    throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.subvectors must be 16 or 32 (bytes per PQ code), got ",
                subvectors);
  if (iterations < 1) throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.iterations must be >= 1");
  if (max_training < size_t(kPqCentroids))
    throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.max_training must be >= ", kPqCentroids);
  if (quantizer == PqQuantizer::kResidual) {
    if (subvectors != kPqSubvectors)
      throw_error(ErrorCode::kInvalidArgument, "a residual codebook has 16-byte codes, not ", subvectors);
    if (!valid_residual_splits(residual_splits))
      throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.residual_splits must be 1, 2 or 4, got ",
                  residual_splits);
    if (residual_beam < 1 || residual_beam > kResidualMaxBeam)
      throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.residual_beam must be in [1, ", kResidualMaxBeam,
                  "], got ", residual_beam);
    if (residual_max_training < size_t(kPqCentroids))
      throw_error(ErrorCode::kInvalidArgument, "PqTrainingOptions.residual_max_training must be >= ", kPqCentroids);
  }
}

size_t PqTrainingOptions::training_rows(size_t n) const {
  return std::min({n, max_training, quantizer == PqQuantizer::kResidual ? residual_max_training : SIZE_MAX});
}

PqCodebook PqCodebook::residual(std::vector<float> codebooks, int splits, int beam) {
  if (!valid_residual_splits(splits))
    throw_error(ErrorCode::kInvalidArgument, "a residual codebook has 1, 2 or 4 splits, got ", splits);
  if (beam < 1 || beam > kResidualMaxBeam)
    throw_error(ErrorCode::kInvalidArgument, "a residual codebook's beam must be in [1, ", kResidualMaxBeam, "], got ",
                beam);
  if (codebooks.size() != residual_floats(splits))
    throw_error(ErrorCode::kFormat, "a residual codebook of ", splits, " splits has ", residual_floats(splits),
                " floats, got ", codebooks.size());
  PqCodebook c;
  c.quantizer_ = PqQuantizer::kResidual;
  c.subvectors_ = kAdditiveCodebooks;
  c.residual_splits_ = splits;
  c.residual_beam_ = beam;
  c.centroids_ = std::move(codebooks);
  return c;
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
  const bool residual_kind = options.quantizer == PqQuantizer::kResidual;
  const size_t max_training = options.training_rows(SIZE_MAX);
  if (n > max_training) {
    RandomGenerator rng(options.seed);
    const std::vector<size_t> idx = sample_sorted_indices(n, max_training, rng);
    sample.resize(idx.size() * kDim);
    for (size_t i = 0; i < idx.size(); ++i) std::copy_n(x + idx[i] * kDim, kDim, sample.data() + i * kDim);
    data = sample.data();
    rows = idx.size();
  }
  if (residual_kind) {
    auto rq = make_faiss_residual(options.residual_splits, options.residual_beam, options.seed, options.iterations,
                                  options.residual_progressive_dim, {});
    rq->train(rows, data);
    return residual(residual_codebooks(*rq, options.residual_splits), options.residual_splits, options.residual_beam);
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
  if (is_residual()) {
    const auto rq = make_faiss_residual(residual_splits_, residual_beam_, 1, 1, false, centroids_);
    VISLOC_CHECK(rq->code_size == size_t(kAdditiveCodebooks), "FAISS's residual codes have ", rq->code_size, " bytes");
    // In blocks: FAISS's beam search holds ~8 KB per row at a beam of 5 and
    // one split (growing with the beam), and batches only near 5 GiB.
    const size_t block = std::max<size_t>(1, 8192 * kFaissResidualBeam / size_t(residual_beam_));
    for (size_t i = 0; i < n; i += block)
      rq->compute_codes(x + i * kDim, codes + i * kAdditiveCodebooks, std::min(block, n - i));
    return;
  }
  make_faiss_pq(centroids_, subvectors_).compute_codes(x, codes, n);
}

void PqCodebook::decode(const uint8_t* code, float* out) const {
  VISLOC_CHECK(!empty());
  if (!is_residual()) {
    const int dims = sub_dimension();
    for (int m = 0; m < subvectors_; ++m)
      std::copy_n(centroids_.data() + (size_t(m) * kPqCentroids + code[m]) * dims, dims, out + m * dims);
    return;
  }
  const int books = kAdditiveCodebooks / residual_splits_, dims = kDim / residual_splits_;
  for (int s = 0; s < residual_splits_; ++s) {
    float* split = out + s * dims;
    for (int t = 0; t < books; ++t) {
      const int m = s * books + t;
      const float* entry = centroids_.data() + (size_t(m) * kPqCentroids + code[m]) * dims;
      for (int j = 0; j < dims; ++j) split[j] = t == 0 ? entry[j] : split[j] + entry[j];
    }
  }
}

void PqCodebook::distance_table(const float* q, float* table) const {
  VISLOC_CHECK(!is_residual(), "a residual codebook has no ADC table");
  // The scalar search kernel: compiled without fused multiply-add, so every
  // SIMD level's table equals this one bit for bit.
  search_kernels(SimdLevel::kScalar).adc(subvectors_).table(transposed_.data(), q, table);
}

double PqCodebook::reconstruction_sqdist(const uint8_t* code, const float* x) const {
  if (is_residual()) {
    float decoded[kDim];
    decode(code, decoded);
    double d = 0;
    for (int j = 0; j < kDim; ++j) d += (double(x[j]) - decoded[j]) * (double(x[j]) - decoded[j]);
    return d;
  }
  double d = 0;
  const int dims = sub_dimension();
  for (int m = 0; m < subvectors_; ++m)
    for (int j = 0; j < dims; ++j) {
      const double e = x[m * dims + j] - centroids_[(size_t(m) * kPqCentroids + code[m]) * dims + j];
      d += e * e;
    }
  return d;
}

std::string PqCodebook::quantizer_json() const {
  std::string out = std::string(R"({"quantizer":")") + to_string(quantizer_) + "\"";
  if (is_residual()) out += ",\"residual_splits\":" + std::to_string(residual_splits_);
  return out + "}";
}

void PqCodebook::write(const std::filesystem::path& path, const std::string& meta_json) const {
  VISLOC_CHECK(!empty());
  const bool default_layout = subvectors_ == kPqSubvectors;
  const uint32_t version = is_residual()    ? kPqCodebookFileVersion
                           : default_layout ? kPqCodebook16FileVersion
                                            : kPqCodebook32FileVersion;
  SectionFileWriter w(path, "PQCB", version);
  w.add_text("META", meta_json);
  w.add_array<float>("CENT", centroids_);
  if (is_residual()) {
    const uint32_t m = static_cast<uint32_t>(subvectors_);
    const uint32_t resid[2] = {static_cast<uint32_t>(residual_splits_), static_cast<uint32_t>(residual_beam_)};
    w.add_array<uint32_t>("SUBVEC", std::span<const uint32_t>(&m, 1));
    w.add_array<uint32_t>("RESID", std::span<const uint32_t>(resid, 2));
  } else if (!default_layout) {
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
  int splits = 0, beam = kResidualBeam;  // splits 0: a PQ
  if (r.kind_version() >= 3) {
    const auto resid = r.array<uint32_t>("RESID", 2);
    const uint32_t s = resid[0];
    if (resid[1] < 1 || resid[1] > uint32_t(kResidualMaxBeam))
      throw_error(ErrorCode::kFormat, path.string(), ": section 'RESID': a beam of ", resid[1], " (1 to ",
                  kResidualMaxBeam, ")");
    beam = static_cast<int>(resid[1]);
    if (subvectors != kAdditiveCodebooks)
      throw_error(ErrorCode::kFormat, path.string(), ": a residual codebook (version 3) has 16 codebooks, not ",
                  subvectors);
    if (s != 1 && s != 2 && s != 4)
      throw_error(ErrorCode::kFormat, path.string(), ": section 'RESID': ", s,
                  " splits; a residual codebook has 1, 2 or 4");
    splits = static_cast<int>(s);
  } else if (r.has("RESID")) {
    throw_error(ErrorCode::kFormat, path.string(), ": a version ", r.kind_version(),
                " codebook has no section 'RESID' (a product quantizer)");
  }
  // A PQ's M sub-vectors of 128 / M dimensions, or a residual codebook's 16
  // codebooks of 128 / S.
  const int dims = splits > 0 ? kDim / splits : 128 / subvectors;
  auto c = r.array<float>("CENT", splits > 0 ? int64_t(residual_floats(splits)) : int64_t(kPqCentroidFloats));
  // Descriptor entries and their residuals lie within ±512: a value far
  // beyond (or not finite) is damage, and would overflow the encoder's
  // squared distances (FAISS's beam search then reads out of bounds).
  for (size_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(c[i]) || std::abs(c[i]) > kPqMaxAbsCentroid)
      throw_error(ErrorCode::kFormat, path.string(), ": section 'CENT': centroid ", i / dims % kPqCentroids,
                  " of subspace ", i / (size_t(kPqCentroids) * dims), " is ", c[i], ", not finite or beyond ±",
                  kPqMaxAbsCentroid);
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
  if (splits > 0) return residual(std::vector<float>(c.begin(), c.end()), splits, beam);
  return PqCodebook(std::vector<float>(c.begin(), c.end()), subvectors);
}

}  // namespace visloc
