#include "visloc/matching/binary_hasher.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>

#include "visloc/matching/search_kernels.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/error.h"
#include "visloc/util/section_file.h"
#include "visloc/util/random.h"

namespace visloc {
namespace {

using RowMatrixF = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using ConstRowMapF = Eigen::Map<const RowMatrixF>;

// Centres a block of rows, then the kernel (search_kernels.h; the best SIMD
// level, bit-identical to the scalar reference) takes the projection's signs.
void encode_float(BinaryHasherView h, const float* x, size_t n, HashCode* codes, HashWorkspace& ws) {
  if (n == 0) return;
  constexpr size_t kBlock = 256;  // rows per block: bounded workspace
  ws.projection_transposed.resize(kHashBits * kDescriptorDim);
  ws.centred.resize(kBlock * kDescriptorDim);
  float* wt = ws.projection_transposed.data();
  for (int i = 0; i < kHashBits; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) wt[j * kHashBits + i] = h.projection[i * kDescriptorDim + j];
  float* centred = ws.centred.data();
  const SearchKernels& kernels = search_kernels();
  for (size_t start = 0; start < n; start += kBlock) {
    const size_t rows = std::min(kBlock, n - start);
    for (size_t i = 0; i < rows; ++i) {
      const float* r = x + (start + i) * kDescriptorDim;
      float* c = centred + i * kDescriptorDim;
      for (int j = 0; j < kDescriptorDim; ++j) c[j] = r[j] - h.mean[j];
    }
    kernels.hash_codes(wt, centred, rows, codes + start);
  }
}

// Centred training rows (subsampled to at most max_rows, seeded) as a double
// matrix, and the mean.
Eigen::MatrixXd centred_training(const float* x, size_t n, size_t max_rows, uint64_t seed, Eigen::VectorXd& mean) {
  RandomGenerator rng(seed);
  const std::vector<size_t> rows = sample_sorted_indices(n, max_rows, rng);
  Eigen::MatrixXd m(rows.size(), kDescriptorDim);
  for (size_t i = 0; i < rows.size(); ++i)
    for (int j = 0; j < kDescriptorDim; ++j) m(i, j) = x[rows[i] * kDescriptorDim + j];
  mean = m.colwise().mean().transpose();
  m.rowwise() -= mean.transpose();
  return m;
}

Eigen::MatrixXd pca_basis(const Eigen::MatrixXd& centred) {
  Eigen::MatrixXd cov = (centred.transpose() * centred) / std::max<double>(1.0, double(centred.rows()));
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(cov);
  // Columns sorted by decreasing eigenvalue.
  return es.eigenvectors().rowwise().reverse();
}

Eigen::MatrixXd random_orthogonal(int d, uint64_t seed) {
  RandomGenerator rng(seed);
  Eigen::MatrixXd a(d, d);
  for (int i = 0; i < d; ++i)
    for (int j = 0; j < d; ++j) a(i, j) = rng.normal();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU() * svd.matrixV().transpose();
}

BinaryHasher to_hasher(const Eigen::VectorXd& mean, const Eigen::MatrixXd& w_columns) {
  BinaryHasher h;
  h.mean.resize(kDescriptorDim);
  h.projection.resize(kHashBits * kDescriptorDim);
  for (int j = 0; j < kDescriptorDim; ++j) h.mean[j] = static_cast<float>(mean(j));
  for (int i = 0; i < kHashBits; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) h.projection[i * kDescriptorDim + j] = static_cast<float>(w_columns(j, i));
  return h;
}

// RMS of the centred entries: the ITQ objective is evaluated on data scaled
// to unit RMS so that its value does not depend on the descriptor scale.
double rms(const Eigen::MatrixXd& centred) {
  return std::sqrt(centred.squaredNorm() / std::max<double>(1.0, double(centred.size())));
}

double objective(const Eigen::MatrixXd& v) {
  return (v.array().sign() - v.array()).matrix().squaredNorm() / std::max<double>(1.0, double(v.rows()));
}

}  // namespace

namespace {

// round(w) half away from zero, for |w| ≤ 32,767: truncation and the fraction
// are exact, so this is lround without its library call.
inline int16_t round_to_int16(double w) {
  const int32_t t = static_cast<int32_t>(w);
  const double fraction = w - static_cast<double>(t);
  return static_cast<int16_t>(t + (fraction >= 0.5f) - (fraction <= -0.5f));
}

}  // namespace

void quantize_hash_projection(BinaryHasherView h, QuantizedHashProjection& out) {
  constexpr int kEntries = kHashBits * kDescriptorDim;
  float largest = 0;
  bool finite = true;
  for (int k = 0; k < kEntries; ++k) {
    const float p = h.projection[k];
    const bool ok = std::isfinite(p);
    finite &= ok;
    largest = std::max(largest, ok ? std::abs(p) : 0.0f);
  }
  // Non-finite entries count as 0; an all-zero projection, or one so small
  // that the scale overflows, keeps scale 1 (every bit from its threshold).
  const double scale = 32767.0 / double(largest);
  out.scale = largest > 0 && scale <= 3.0e38 ? static_cast<float>(scale) : 1.0f;
  out.weight_pairs.resize(kEntries);
  out.weights_transposed.resize(kEntries);
  out.thresholds.resize(kHashBits);
  // Column by column, so that the 128 threshold sums are independent chains.
  // The products p · scale are exact in double (24 × 24 bits), so each entry
  // is rounded once: |Wq − scale · W| ≤ 1/2.
  const double s = out.scale;
  double c[kHashBits] = {};
  for (int j = 0; j < kDescriptorDim; ++j) {
    const double mean = h.mean[j];
    int16_t* pairs = out.weight_pairs.data() + (j / 2) * 2 * kHashBits + (j & 1);
    int16_t* column = out.weights_transposed.data() + j * kHashBits;
    for (int i = 0; i < kHashBits; ++i) {
      const float p = h.projection[i * kDescriptorDim + j];
      const double w = finite || std::isfinite(p) ? std::min(32767.0, std::max(-32767.0, double(p) * s)) : 0.0;
      const int16_t q = round_to_int16(w);
      pairs[2 * i] = q;
      column[i] = q;
      c[i] += double(q) * mean;
    }
  }
  // Any sum of 128 products of |Wq| ≤ 32,767 and x ≤ 255 lies within
  // ±1,069,514,880 < 2^30, so a threshold clamped to ±2^30 sets the same bits
  // (at 2^30 never, at −2^30 always) and keeps Σ − t_i within int32 (the
  // margins of query-directed probing).
  constexpr double kBound = 1073741824.0;  // 2^30
  for (int i = 0; i < kHashBits; ++i) {
    const double t = std::floor(c[i]);
    // NaN (a non-finite mean) or above every sum: the bit is never set.
    out.thresholds[i] = !(t < kBound) ? int32_t(kBound) : t < -kBound ? -int32_t(kBound) : static_cast<int32_t>(t);
  }
}

void encode_hash(BinaryHasherView h, const uint8_t* x, size_t n, HashCode* codes, HashWorkspace& ws, int32_t* margins) {
  if (n == 0) return;
  quantize_hash_projection(h, ws.quantized);
  search_kernels().hash_codes_u8(ws.quantized, x, n, codes, margins);
}
void encode_hash(BinaryHasherView h, const float* x, size_t n, HashCode* codes, HashWorkspace& ws) {
  encode_float(h, x, n, codes, ws);
}

void ItqOptions::validate() const {
  if (iterations < 0) throw_error(ErrorCode::kInvalidArgument, "ItqOptions.iterations must be >= 0, got ", iterations);
  if (max_training < 2) throw_error(ErrorCode::kInvalidArgument, "ItqOptions.max_training must be >= 2");
}

ItqResult train_itq(const float* x, size_t n, const ItqOptions& options) {
  options.validate();
  if (n < 2) throw_error(ErrorCode::kInvalidArgument, "ITQ needs at least 2 descriptors, got ", n);
  Eigen::VectorXd mean;
  Eigen::MatrixXd c = centred_training(x, n, options.max_training, options.seed, mean);
  const double s = rms(c);
  if (s > 0) c /= s;
  const Eigen::MatrixXd p = pca_basis(c);
  // The n × 128 products run in float (the hot part); the 128 × 128
  // Procrustes solve in double.
  const Eigen::MatrixXf v = (c * p).cast<float>();
  Eigen::MatrixXd r = random_orthogonal(kHashBits, options.seed);
  ItqResult out;
  Eigen::MatrixXf vr(v.rows(), kHashBits), b(v.rows(), kHashBits);
  vr.noalias() = v * r.cast<float>();
  for (int it = 0; it < options.iterations; ++it) {
    // vr = V R for the current R (computed at the end of the previous iteration).
    b = vr.array().sign().matrix();
    // Orthogonal Procrustes: R = argmin ||B − V R|| = S Ŝᵀ with Vᵀ B = S Ω Ŝᵀ.
    const Eigen::MatrixXd vtb = (v.transpose() * b).cast<double>();
    Eigen::BDCSVD<Eigen::MatrixXd> svd(vtb, Eigen::ComputeFullU | Eigen::ComputeFullV);
    r = svd.matrixU() * svd.matrixV().transpose();
    vr.noalias() = v * r.cast<float>();
    out.quantization_error.push_back(objective(vr.cast<double>()));
  }
  out.hasher = to_hasher(mean, p * r);
  return out;
}

BinaryHasher make_random_rotation_hasher(const float* x, size_t n, uint64_t seed) {
  if (n < 2) throw_error(ErrorCode::kInvalidArgument, "a PCA rotation needs at least 2 descriptors, got ", n);
  Eigen::VectorXd mean;
  Eigen::MatrixXd c = centred_training(x, n, 200000, seed, mean);
  return to_hasher(mean, pca_basis(c) * random_orthogonal(kHashBits, seed));
}

BinaryHasher make_lsh_hasher(const float* x, size_t n, uint64_t seed) {
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(kDescriptorDim);
  for (size_t i = 0; i < n; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) mean(j) += x[i * kDescriptorDim + j];
  if (n > 0) mean /= double(n);
  RandomGenerator rng(seed);
  Eigen::MatrixXd w(kDescriptorDim, kHashBits);
  for (int i = 0; i < kHashBits; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) w(j, i) = rng.normal();
  return to_hasher(mean, w);
}

double hash_quantization_error(BinaryHasherView h, const float* x, size_t n) {
  if (n == 0) return 0;
  Eigen::MatrixXd c(n, kDescriptorDim);
  for (size_t i = 0; i < n; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) c(i, j) = x[i * kDescriptorDim + j] - h.mean[j];
  const double s = rms(c);
  if (s > 0) c /= s;
  Eigen::MatrixXd w(kDescriptorDim, kHashBits);
  for (int i = 0; i < kHashBits; ++i)
    for (int j = 0; j < kDescriptorDim; ++j) w(j, i) = h.projection[i * kDescriptorDim + j];
  return objective(c * w);
}

const char* to_string(HashRotationScope scope) { return scope == HashRotationScope::kMap ? "map" : "segment"; }

HashRotationScope parse_hash_rotation_scope(const std::string& name) {
  if (name == "segment") return HashRotationScope::kSegment;
  if (name == "map") return HashRotationScope::kMap;
  throw_error(ErrorCode::kInvalidArgument, "unknown hash rotation scope '", name, "' (segment or map)");
}

void write_hash_rotation_file(const std::filesystem::path& path, const BinaryHasher& h, const std::string& meta_json) {
  VISLOC_CHECK(h.mean.size() == size_t(kDescriptorDim) && h.projection.size() == size_t(kHashBits) * kDescriptorDim);
  SectionFileWriter w(path, "ITQR", kHashRotationFileVersion);
  w.add_text("META", meta_json);
  w.add_array<float>("MEAN", h.mean);
  w.add_array<float>("W", h.projection);
  w.commit();
}

uint32_t hash_rotation_fingerprint(const BinaryHasher& h) {
  const uint32_t crc = crc32c(h.mean.data(), h.mean.size() * sizeof(float));
  return crc32c(h.projection.data(), h.projection.size() * sizeof(float), crc);
}

void check_hash_rotation(BinaryHasherView h, const std::string& file) {
  for (int i = 0; i < kDescriptorDim; ++i)
    if (!std::isfinite(h.mean[i])) throw_error(ErrorCode::kFormat, file, ": hash rotation mean is not finite");
  // ITQ's projection is a rotation of the PCA basis: rows orthonormal.
  Eigen::Map<const RowMatrixF> p(h.projection, kHashBits, kDescriptorDim);
  if (!p.allFinite()) throw_error(ErrorCode::kFormat, file, ": hash rotation is not finite");
  const double off = ((p * p.transpose()).cast<double>() - Eigen::MatrixXd::Identity(kHashBits, kHashBits)).cwiseAbs().maxCoeff();
  if (!(off <= 1e-3))
    throw_error(ErrorCode::kFormat, file, ": hash rotation is not orthonormal (|W Wᵀ − I| up to ", off, ")");
}

BinaryHasher read_hash_rotation_file(const std::filesystem::path& path) {
  SectionFileReader r(path, "ITQR", kHashRotationFileVersion, kHashRotationFileVersion);
  auto mean = r.array<float>("MEAN", kDescriptorDim);
  auto w = r.array<float>("W", int64_t(kHashBits) * kDescriptorDim);
  BinaryHasher h;
  h.mean.assign(mean.begin(), mean.end());
  h.projection.assign(w.begin(), w.end());
  check_hash_rotation(h.view(), path.string());
  return h;
}

}  // namespace visloc
