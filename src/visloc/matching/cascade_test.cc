#include <gtest/gtest.h>

#include <limits>

#include <Eigen/Dense>
#include <algorithm>
#include <bit>
#include <filesystem>
#include <optional>
#include <random>
#include <set>
#include <tuple>

#include <faiss/impl/ProductAdditiveQuantizer.h>
#include <faiss/impl/ResidualQuantizer.h>

#include "visloc/baselines/faiss_baselines.h"
#include "visloc/matching/binary_hasher.h"
#include "visloc/matching/cascade_correspondences.h"
#include "visloc/matching/cascade_index.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/matching/pq_codebook.h"
#include "visloc/matching/search_kernels.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/section_file.h"
#include "visloc/util/test_support.h"

using namespace visloc;
namespace fs = std::filesystem;

namespace {

// FAISS searches and k-means run on one thread in tests: OpenMP threads
// spinning on a loaded machine make them slow, not faster.
const int kOneThread = (set_faiss_threads(1), 1);

// SIFT-like synthetic descriptors: a mixture of clusters in [0, 255].
DescriptorMatrix clustered_descriptors(size_t n, uint64_t seed, int clusters = 24) {
  std::mt19937 rng(static_cast<uint32_t>(seed));
  std::uniform_int_distribution<int> centre(0, 110), noise(-35, 35), pick(0, clusters - 1);
  std::vector<std::array<int, 128>> c(clusters);
  std::mt19937 crng(7);  // same centres for every call
  for (auto& a : c)
    for (int& v : a) v = std::uniform_int_distribution<int>(0, 110)(crng);
  DescriptorMatrix d(n);
  for (size_t i = 0; i < n; ++i) {
    const auto& a = c[pick(rng)];
    for (int j = 0; j < 128; ++j) d.row(i)[j] = static_cast<uint8_t>(std::clamp(a[j] + noise(rng), 0, 255));
  }
  return d;
}

std::vector<float> to_float(const DescriptorMatrix& d) {
  return std::vector<float>(d.data(), d.data() + d.size_bytes());
}

DescriptorMatrix perturbed(const DescriptorMatrix& db, const std::vector<size_t>& rows, int amplitude, uint64_t seed) {
  std::mt19937 rng(static_cast<uint32_t>(seed));
  std::uniform_int_distribution<int> noise(-amplitude, amplitude);
  DescriptorMatrix q(rows.size());
  for (size_t i = 0; i < rows.size(); ++i)
    for (int j = 0; j < 128; ++j) q.row(i)[j] = static_cast<uint8_t>(std::clamp(db.row(rows[i])[j] + noise(rng), 0, 255));
  return q;
}

// A complete in-memory index over a database.
struct TestIndex {
  BinaryHasher hasher;
  PqCodebook codebook;
  std::vector<HashCode> codes;
  std::vector<uint8_t> pq;
  CascadeLookup lookup;
  CascadeIndexView view() const {
    return {codes.size(), hasher.view(), codes.data(), pq.data(), &lookup, codebook.subvectors()};
  }
};

// The hasher and codebook are trained on the first `train_rows` rows (0: all);
// PQ codes of `pq_subvectors` bytes.
TestIndex make_index(const DescriptorMatrix& db, bool lsh = false, size_t train_rows = 0,
                     int pq_subvectors = kPqSubvectors, int residual_splits = 0) {
  TestIndex t;
  auto f = to_float(db);
  const size_t n_train = train_rows > 0 ? std::min(train_rows, db.rows()) : db.rows();
  t.hasher = lsh ? make_lsh_hasher(f.data(), n_train, 5) : train_itq(f.data(), n_train, {.iterations = 10}).hasher;
  PqTrainingOptions pq{.subvectors = pq_subvectors, .iterations = 10};
  if (residual_splits > 0) {
    pq.quantizer = PqQuantizer::kResidual;
    pq.residual_splits = residual_splits;
    pq.residual_progressive_dim = false;  // faster, as a beam of 1
    pq.residual_beam = 1;
  }
  t.codebook = PqCodebook::train(f.data(), n_train, pq);
  t.codes.resize(db.rows());
  HashWorkspace ws;
  encode_hash(t.hasher.view(), db.data(), db.rows(), t.codes.data(), ws);
  t.pq.resize(db.rows() * size_t(pq_subvectors));
  t.codebook.encode(f.data(), db.rows(), t.pq.data());
  t.lookup = CascadeLookup(t.codes);
  return t;
}

}  // namespace

TEST(Itq, IsOrthogonalAndBeatsARandomRotation) {
  DescriptorMatrix d = clustered_descriptors(3000, 1);
  auto f = to_float(d);
  auto itq = train_itq(f.data(), d.rows(), {.iterations = 30, .seed = 3});
  Eigen::Map<const Eigen::Matrix<float, 128, 128, Eigen::RowMajor>> w(itq.hasher.projection.data());
  EXPECT_LT((w * w.transpose() - Eigen::Matrix<float, 128, 128>::Identity()).cwiseAbs().maxCoeff(), 1e-4);
  ASSERT_EQ(itq.quantization_error.size(), 30u);
  // ITQ's alternating minimisation never increases the objective (up to rounding).
  for (size_t i = 1; i < itq.quantization_error.size(); ++i)
    EXPECT_LE(itq.quantization_error[i], itq.quantization_error[i - 1] + 1e-6);
  const double e_itq = hash_quantization_error(itq.hasher.view(), f.data(), d.rows());
  EXPECT_NEAR(e_itq, itq.quantization_error.back(), 1e-3 * e_itq);
  for (uint64_t seed : {3u, 11u, 12u}) {
    BinaryHasher r = make_random_rotation_hasher(f.data(), d.rows(), seed);
    const double e_rand = hash_quantization_error(r.view(), f.data(), d.rows());
    EXPECT_LT(e_itq, 0.97 * e_rand) << "seed " << seed;
  }
  EXPECT_THROW(train_itq(f.data(), 1), Error);
}

// uint8 rows are hashed in integers with W rounded to int16, float rows in
// float: each is the sign of W(x − μ) wherever the projection is clear of its
// rounding bound, and the two agree nearly everywhere.
TEST(Itq, EncodeMatchesTheProjectionsSign) {
  DescriptorMatrix d = clustered_descriptors(1500, 2);  // more than one encode block
  auto f = to_float(d);
  for (const BinaryHasher& h : {make_lsh_hasher(f.data(), d.rows(), 9), train_itq(f.data(), d.rows()).hasher}) {
    std::vector<HashCode> codes(d.rows()), codes_f(d.rows());
    HashWorkspace ws;
    encode_hash(h.view(), d.data(), d.rows(), codes.data(), ws);
    encode_hash(h.view(), f.data(), d.rows(), codes_f.data(), ws);
    const float scale = ws.quantized.scale;
    ASSERT_GT(scale, 0.f);
    // The SIMD kernels read the pairs layout, the scalar reference (and every
    // tail) the transposed one: both must hold the same Wq.
    const QuantizedHashProjection& q = ws.quantized;
    for (int i = 0; i < 128; ++i)
      for (int j = 0; j < 128; ++j)
        ASSERT_EQ(q.weights_transposed[j * 128 + i], q.weight_pairs[(j / 2) * 256 + 2 * i + (j & 1)]) << i << " " << j;
    std::vector<HashCode> scalar_codes(d.rows());
    search_kernels(SimdLevel::kScalar).hash_codes_u8(q, d.data(), d.rows(), scalar_codes.data(), nullptr);
    for (size_t i = 0; i < d.rows(); ++i) {
      ASSERT_EQ(scalar_codes[i].w[0], codes[i].w[0]) << i;
      ASSERT_EQ(scalar_codes[i].w[1], codes[i].w[1]) << i;
    }
    double mean_l1 = 0;
    for (int j = 0; j < 128; ++j) mean_l1 += std::abs(h.mean[j]);
    int near_zero = 0, disagreements = 0, float_near_zero = 0;
    for (size_t i = 0; i < d.rows(); ++i) {
      double x_l1 = 0;
      for (int j = 0; j < 128; ++j) x_l1 += f[i * 128 + j];
      const double bound = (x_l1 + mean_l1) / (2.0 * scale) + 1.0 / scale;
      for (int b = 0; b < 128; ++b) {
        double s = 0;
        for (int j = 0; j < 128; ++j) s += double(h.projection[b * 128 + j]) * (f[i * 128 + j] - h.mean[j]);
        const bool bit = (codes[i].w[b / 64] >> (b % 64)) & 1;
        const bool bit_f = (codes_f[i].w[b / 64] >> (b % 64)) & 1;
        if (std::abs(s) > bound)
          ASSERT_EQ(bit, s > 0) << i << " " << b;
        else
          ++near_zero;
        if (std::abs(s) > 1e-2)
          ASSERT_EQ(bit_f, s > 0) << i << " " << b;
        else
          float_near_zero += bit_f != (s > 0);
        disagreements += bit != bit_f;
      }
    }
    EXPECT_LE(float_near_zero, 5);
    // The bound is a worst case: few projections fall within it, fewer flip.
    EXPECT_LE(disagreements, near_zero);
    EXPECT_LE(near_zero, int(d.rows()));  // under 1 in 128 bits
  }
}

// Hashers that no file passes (check_hash_rotation) still quantize to
// something defined: a zero projection, a NaN weight, a NaN mean.
TEST(Itq, QuantizedProjectionOfDegenerateHashers) {
  std::vector<float> mean(128, 10.f), w(128 * 128, 0.f);
  QuantizedHashProjection q;
  quantize_hash_projection({mean.data(), w.data()}, q);
  EXPECT_EQ(q.scale, 1.f);
  for (int16_t v : q.weight_pairs) ASSERT_EQ(v, 0);
  for (int32_t t : q.thresholds) ASSERT_EQ(t, 0);  // no sum exceeds it: every bit 0
  for (int i = 0; i < 128; ++i) w[i * 128 + i] = 0.5f;
  w[3 * 128 + 7] = std::numeric_limits<float>::quiet_NaN();
  w[5 * 128 + 9] = -std::numeric_limits<float>::infinity();
  quantize_hash_projection({mean.data(), w.data()}, q);
  EXPECT_EQ(q.scale, 65534.f);                                  // from the finite entries
  EXPECT_EQ(q.weight_pairs[(7 / 2) * 256 + 2 * 3 + 1], 0);      // the NaN weight
  EXPECT_EQ(q.weight_pairs[(9 / 2) * 256 + 2 * 5 + 1], 0);      // the infinite one
  EXPECT_EQ(q.weight_pairs[(3 / 2) * 256 + 2 * 3 + 1], 32767);  // the largest weight
  EXPECT_EQ(q.thresholds[3], 327670);                           // ⌊32,767 · 10⌋
  std::fill(w.begin(), w.end(), 1e-44f);                        // subnormal: the scale would overflow
  quantize_hash_projection({mean.data(), w.data()}, q);
  EXPECT_EQ(q.scale, 1.f);
  for (int16_t v : q.weight_pairs) ASSERT_EQ(v, 0);
  for (int i = 0; i < 128; ++i) w[i * 128 + i] = 0.5f;
  mean[0] = std::numeric_limits<float>::quiet_NaN();
  quantize_hash_projection({mean.data(), w.data()}, q);
  for (int32_t t : q.thresholds) ASSERT_EQ(t, 1 << 30);  // above every sum: never set
  mean[0] = 1e30f;                                       // finite, but the sums are far out of range
  quantize_hash_projection({mean.data(), w.data()}, q);
  EXPECT_EQ(q.thresholds[0], 1 << 30);
  mean[0] = -1e30f;
  quantize_hash_projection({mean.data(), w.data()}, q);
  EXPECT_EQ(q.thresholds[0], -(1 << 30));  // below every sum: always set
}

TEST(Hamming, PopcountAndSubcodesMatchScalarReference) {
  std::mt19937_64 rng(4);
  for (int t = 0; t < 2000; ++t) {
    HashCode a{{rng(), rng()}}, b{{rng(), rng()}};
    if (t % 3 == 0) b = a, b.w[t % 2] ^= 1ull << (t % 64);
    uint32_t ref = 0;
    for (int i = 0; i < 128; ++i) ref += ((a.w[i / 64] >> (i % 64)) & 1) != ((b.w[i / 64] >> (i % 64)) & 1);
    ASSERT_EQ(hamming_distance(a, b), ref);
    for (int k = 0; k < 8; ++k) {
      uint32_t sub = 0;
      for (int i = 0; i < 16; ++i) sub |= uint32_t((a.w[(16 * k + i) / 64] >> ((16 * k + i) % 64)) & 1) << i;
      ASSERT_EQ(hash_subcode(a, k), sub);
    }
  }
}

TEST(ProductQuantizer, AdcEqualsBruteForceDistanceAndFileRoundTrips) {
  DescriptorMatrix d = clustered_descriptors(3000, 3);
  auto f = to_float(d);
  PqCodebook cb = PqCodebook::train(f.data(), d.rows(), {.iterations = 8});
  std::vector<uint8_t> codes(d.rows() * 16);
  cb.encode(f.data(), d.rows(), codes.data());
  std::vector<float> table(kPqTableSize);
  DescriptorMatrix q = clustered_descriptors(20, 99);
  auto qf = to_float(q);
  for (size_t i = 0; i < q.rows(); ++i) {
    cb.distance_table(&qf[i * 128], table.data());
    for (size_t p = 0; p < d.rows(); p += 37) {
      const double ref = cb.reconstruction_sqdist(&codes[p * 16], &qf[i * 128]);
      EXPECT_NEAR(adc_distance(table.data(), &codes[p * 16], kPqSubvectors), ref, 1e-4 * ref + 1e-3);
    }
  }
  // Encoding picks the nearest centroid: the reconstruction error is below
  // the error of any other code on a sample.
  for (size_t p = 0; p < 50; ++p) {
    const double own = cb.reconstruction_sqdist(&codes[p * 16], &f[p * 128]);
    const double other = cb.reconstruction_sqdist(&codes[(p + 1) * 16], &f[p * 128]);
    EXPECT_LE(own, other + 1e-3);
  }
  fs::path path = unique_temp_path("visloc_cascade_test.vlpq");
  cb.write(path, R"({"test":1})");
  std::string meta;
  PqCodebook back = PqCodebook::read(path, &meta);
  EXPECT_EQ(meta, R"({"test":1})");
  ASSERT_EQ(back.centroids().size(), cb.centroids().size());
  EXPECT_TRUE(std::equal(back.centroids().begin(), back.centroids().end(), cb.centroids().begin()));
  std::string bytes = read_file(path);
  bytes[bytes.size() / 2] ^= 0x10;
  write_file_atomic(path, bytes);
  EXPECT_THROW(PqCodebook::read(path), Error);
}

// 32-byte codes: 32 sub-vectors of 4 dimensions. Encoding, ADC and the file
// as with 16, the codes closer to the data than 16-byte ones, the file
// version 2 with the sub-vector count (16-byte codebooks stay version 1).
TEST(ProductQuantizer, ThirtyTwoByteCodesEncodeCloserAndRoundTrip) {
  DescriptorMatrix d = clustered_descriptors(3000, 5);
  auto f = to_float(d);
  const PqCodebook cb16 = PqCodebook::train(f.data(), d.rows(), {.iterations = 8});
  const PqCodebook cb32 = PqCodebook::train(f.data(), d.rows(), {.subvectors = 32, .iterations = 8});
  ASSERT_EQ(cb32.subvectors(), 32);
  EXPECT_EQ(cb32.code_bytes(), 32);
  EXPECT_EQ(cb32.sub_dimension(), 4);
  EXPECT_EQ(cb32.table_size(), 32 * 256);
  std::vector<uint8_t> c16(d.rows() * 16), c32(d.rows() * 32);
  cb16.encode(f.data(), d.rows(), c16.data());
  cb32.encode(f.data(), d.rows(), c32.data());
  double e16 = 0, e32 = 0;
  for (size_t p = 0; p < d.rows(); ++p) {
    e16 += cb16.reconstruction_sqdist(&c16[p * 16], &f[p * 128]);
    e32 += cb32.reconstruction_sqdist(&c32[p * 32], &f[p * 128]);
  }
  EXPECT_LT(e32, 0.8 * e16) << "32 sub-quantizers reconstruct no better than 16";
  // ADC with the 32 × 256 table equals the reconstruction distance; encoding
  // picks each sub-space's nearest centroid (changing any byte is no closer).
  std::vector<float> table(cb32.table_size());
  cb32.distance_table(&f[0], table.data());
  for (size_t p = 0; p < d.rows(); p += 41) {
    const double ref = cb32.reconstruction_sqdist(&c32[p * 32], &f[0]);
    EXPECT_NEAR(adc_distance(table.data(), &c32[p * 32], 32), ref, 1e-4 * ref + 1e-3);
  }
  for (size_t p = 0; p < 20; ++p)
    for (int m : {0, 17, 31}) {
      std::vector<uint8_t> other(c32.begin() + p * 32, c32.begin() + p * 32 + 32);
      other[m] = static_cast<uint8_t>(other[m] + 1);
      EXPECT_LE(cb32.reconstruction_sqdist(&c32[p * 32], &f[p * 128]),
                cb32.reconstruction_sqdist(other.data(), &f[p * 128]) + 1e-3);
    }
  const fs::path path = unique_temp_path("visloc_cascade_test32.vlpq");
  cb32.write(path, "{}");
  EXPECT_EQ(SectionFileReader(path, "PQCB", 1, 2).kind_version(), 2u);
  const PqCodebook back = PqCodebook::read(path);
  EXPECT_EQ(back.subvectors(), 32);
  EXPECT_TRUE(std::equal(back.centroids().begin(), back.centroids().end(), cb32.centroids().begin()));
  cb16.write(path, "{}");
  EXPECT_EQ(SectionFileReader(path, "PQCB", 1, 2).kind_version(), 1u);
  EXPECT_EQ(PqCodebook::read(path).subvectors(), 16);
  // Bad sub-vector counts, in the options, the constructor and the file.
  EXPECT_THROW(PqCodebook::train(f.data(), d.rows(), {.subvectors = 8}), Error);
  EXPECT_THROW(PqCodebook(std::vector<float>(kPqCentroidFloats, 1.f), 64), Error);
  // A codebook file of kind version `version` with cb32's centroids and, when given, a SUBVEC of `m`.
  auto write_codebook = [&](uint32_t version, std::optional<uint32_t> m) {
    SectionFileWriter w(path, "PQCB", version);
    w.add_text("META", "{}");
    w.add_array<float>("CENT", cb32.centroids());
    if (m) w.add_array<uint32_t>("SUBVEC", std::span<const uint32_t>(&*m, 1));
    w.commit();
  };
  for (uint32_t m : {0u, 8u, 64u}) {
    write_codebook(2, m);
    try {
      PqCodebook::read(path);
      ADD_FAILURE() << m << " sub-vectors accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kFormat);
      EXPECT_NE(std::string(e.what()).find("SUBVEC"), std::string::npos) << e.what();
    }
  }
  write_codebook(2, std::nullopt);  // version 2 without SUBVEC
  EXPECT_THROW(PqCodebook::read(path), Error);
  {
    write_codebook(1, 32);  // version 1 is 16 sub-vectors: a SUBVEC there is refused, not read
    try {
      PqCodebook::read(path);
      ADD_FAILURE() << "a version 1 codebook with SUBVEC accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("version 1 codebook has no section 'SUBVEC'"), std::string::npos)
          << e.what();
    }
  }
}

// A residual code decoded by FAISS's own quantizer of the same codebooks.
void decode_with_faiss(const PqCodebook& cb, const uint8_t* code, float* out) {
  const int splits = cb.residual_splits();
  const std::vector<float> books(cb.centroids().begin(), cb.centroids().end());
  const size_t per_split = books.size() / size_t(splits);
  if (splits == 1) {
    faiss::ResidualQuantizer rq(128, 16, 8);
    rq.codebooks = books;
    rq.is_trained = true;
    rq.decode(code, out, 1);
    return;
  }
  faiss::ProductResidualQuantizer prq(128, size_t(splits), size_t(16 / splits), 8);
  for (int s = 0; s < splits; ++s) {
    prq.quantizers[size_t(s)]->codebooks.assign(books.begin() + std::ptrdiff_t(size_t(s) * per_split),
                                                books.begin() + std::ptrdiff_t(size_t(s + 1) * per_split));
    prq.quantizers[size_t(s)]->is_trained = true;
  }
  prq.codebooks = books;  // its decode reads the splits' codebooks from here, concatenated
  prq.is_trained = true;
  prq.decode(code, out, 1);
}

// Residual codebooks (16 added codebooks over 1, 2 or 4 splits): the codes
// decode closer to the data than the PQ's of as many bytes, FAISS's codes and
// our decoding agree (the beam search picks a code at least as close as its
// greedy neighbours: one byte changed is no closer, on a sample), and the
// file (version 3, section RESID) round-trips; bad split counts are refused
// in the options, the constructor and the file.
TEST(ResidualQuantizer, EncodesCloserThanThePqAndRoundTrips) {
  DescriptorMatrix d = clustered_descriptors(4200, 5);
  auto f = to_float(d);
  const PqCodebook pq = PqCodebook::train(f.data(), d.rows(), {.iterations = 8});
  std::vector<uint8_t> codes(d.rows() * 16);
  pq.encode(f.data(), d.rows(), codes.data());
  double e_pq = 0;
  for (size_t p = 0; p < d.rows(); ++p) e_pq += pq.reconstruction_sqdist(&codes[p * 16], &f[p * 128]);
  const fs::path path = unique_temp_path("visloc_cascade_test_residual.vlpq");
  for (const int splits : {1, 2, 4}) {
    SCOPED_TRACE(std::to_string(splits) + " splits");
    const PqCodebook cb = PqCodebook::train(f.data(), d.rows(),
                                            {.quantizer = PqQuantizer::kResidual,
                                             .residual_splits = splits,
                                             .residual_progressive_dim = false,
                                             .residual_beam = 1,
                                             .iterations = 8});
    ASSERT_TRUE(cb.is_residual());
    EXPECT_EQ(cb.residual_splits(), splits);
    EXPECT_EQ(cb.code_bytes(), 16);
    EXPECT_EQ(cb.centroids().size(), size_t(16) * 256 * (128 / splits));
    cb.encode(f.data(), d.rows(), codes.data());
    double e = 0;
    for (size_t p = 0; p < d.rows(); ++p) e += cb.reconstruction_sqdist(&codes[p * 16], &f[p * 128]);
    EXPECT_LT(e, 0.9 * e_pq) << "the PQ's " << e_pq;
    size_t closer = 0;
    for (size_t p = 0; p < 30; ++p)
      for (int m : {0, 7, 15}) {
        std::vector<uint8_t> other(codes.begin() + p * 16, codes.begin() + p * 16 + 16);
        other[m] = static_cast<uint8_t>(other[m] + 1);
        closer += cb.reconstruction_sqdist(other.data(), &f[p * 128]) <
                  cb.reconstruction_sqdist(&codes[p * 16], &f[p * 128]) - 1e-3;
      }
    EXPECT_LE(closer, 9u) << "of 90 codes with a byte changed";
    cb.write(path, "{}");
    EXPECT_EQ(SectionFileReader(path, "PQCB", 1, 3).kind_version(), 3u);
    const PqCodebook back = PqCodebook::read(path);
    EXPECT_TRUE(back.is_residual());
    EXPECT_EQ(back.residual_splits(), splits);
    EXPECT_TRUE(std::equal(back.centroids().begin(), back.centroids().end(), cb.centroids().begin()));
    // The file keeps the encoder's beam (cb's is 1): the codebook read back
    // encodes as cb did.
    std::vector<uint8_t> again(200 * 16);
    back.encode(f.data(), 200, again.data());
    EXPECT_TRUE(std::equal(again.begin(), again.end(), codes.begin()));
    const std::vector<float> books(cb.centroids().begin(), cb.centroids().end());
    PqCodebook::residual(books, splits, 3).write(path, "{}");
    EXPECT_EQ(PqCodebook::read(path).residual_beam(), 3) << "a beam unlike the default";
    // Our decoding (each byte m one entry of codebook m, added into part
    // m / (16 / S)) is FAISS's: the byte layout the kernels assume.
    std::vector<float> ours(128), theirs(128);
    for (size_t p = 0; p < 50; ++p) {
      cb.decode(&codes[p * 16], ours.data());
      decode_with_faiss(cb, &codes[p * 16], theirs.data());
      for (int j = 0; j < 128; ++j) ASSERT_NEAR(ours[j], theirs[j], 1e-3f) << "point " << p << " dimension " << j;
    }
  }
  EXPECT_THROW(PqCodebook::train(f.data(), d.rows(), {.quantizer = PqQuantizer::kResidual, .residual_splits = 3}),
               Error);
  EXPECT_THROW(PqCodebook::train(f.data(), d.rows(), {.quantizer = PqQuantizer::kResidual, .subvectors = 32}), Error);
  EXPECT_THROW(PqCodebook::residual(std::vector<float>(16 * 256 * 64, 1.f), 4), Error);  // 2 splits' floats
  const PqCodebook cb = PqCodebook::train(f.data(), d.rows(),
                                          {.quantizer = PqQuantizer::kResidual,
                                           .residual_splits = 4,
                                           .residual_progressive_dim = false,
                                           .residual_beam = 1,
                                           .iterations = 4});
  // A version 3 file with cb's codebooks (`huge` at one value), a SUBVEC of
  // `m` and, when given, a RESID of `s` and `beam`.
  auto write_codebook = [&](uint32_t version, uint32_t m, std::optional<uint32_t> s, uint32_t beam, float huge) {
    SectionFileWriter w(path, "PQCB", version);
    w.add_text("META", "{}");
    std::vector<float> c(cb.centroids().begin(), cb.centroids().end());
    if (huge != 0) c[c.size() / 3] = huge;
    w.add_array<float>("CENT", c);
    w.add_array<uint32_t>("SUBVEC", std::span<const uint32_t>(&m, 1));
    const uint32_t resid[2] = {s.value_or(0), beam};
    if (s) w.add_array<uint32_t>("RESID", std::span<const uint32_t>(resid, 2));
    w.commit();
  };
  write_codebook(3, 16, 4, 3, 0);
  EXPECT_EQ(PqCodebook::read(path).residual_splits(), 4);
  for (const auto& [version, m, s, beam, huge, message] :
       {std::tuple{3u, 16u, std::optional<uint32_t>(3), 5u, 0.f, "section 'RESID': 3 splits"},
        std::tuple{3u, 16u, std::optional<uint32_t>(4), 0u, 0.f, "section 'RESID': a beam of 0"},
        std::tuple{3u, 16u, std::optional<uint32_t>(4), 65u, 0.f, "section 'RESID': a beam of 65"},
        std::tuple{3u, 16u, std::optional<uint32_t>(2), 5u, 0.f, "section 'CENT'"},  // 4 splits' floats
        std::tuple{3u, 32u, std::optional<uint32_t>(4), 5u, 0.f, "has 16 codebooks, not 32"},
        std::tuple{3u, 16u, std::optional<uint32_t>(), 5u, 0.f, "RESID"},
        std::tuple{2u, 16u, std::optional<uint32_t>(4), 5u, 0.f, "no section 'RESID'"},
        // Finite but huge: FAISS's beam search would overflow and read out of bounds.
        std::tuple{3u, 16u, std::optional<uint32_t>(4), 5u, 1e20f, "beyond"},
        std::tuple{3u, 16u, std::optional<uint32_t>(4), 5u, -7e4f, "beyond"}}) {
    write_codebook(version, m, s, beam, huge);
    try {
      PqCodebook::read(path);
      ADD_FAILURE() << "accepted: " << message;
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kFormat);
      EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
    }
  }
  fs::remove(path);
}

// Every point once per table, in the bucket of its sub-code, ids increasing
// within a bucket (the counting sort's order, which fixes the search order).
template <typename Id>
void expect_csr_of_subcodes(const CascadeLookup& lookup, const std::vector<HashCode>& codes,
                            const Id* (CascadeLookup::*ids)(int) const) {
  for (int k = 0; k < 8; ++k) {
    std::vector<int> seen(codes.size(), 0);
    for (uint32_t b = 0; b < kHashBuckets; ++b) {
      uint32_t begin, end;
      lookup.bucket_range(k, b, begin, end);
      ASSERT_EQ(lookup.bucket_empty(k, b), begin == end);
      for (uint32_t i = begin; i < end; ++i) {
        const uint32_t id = (lookup.*ids)(k)[i];
        ASSERT_EQ(hash_subcode(codes[id], k), b);
        if (i > begin) {
          ASSERT_LT((lookup.*ids)(k)[i - 1], id);
        }
        ++seen[id];
      }
    }
    ASSERT_TRUE(std::all_of(seen.begin(), seen.end(), [](int s) { return s == 1; }));
  }
}

TEST(CascadeIndex, TablesAreCsrOfSubcodes) {
  DescriptorMatrix d = clustered_descriptors(2000, 4);
  TestIndex t = make_index(d);
  CascadeIndexView v = t.view();
  v.validate("test");
  ASSERT_TRUE(t.lookup.uses_16bit_ids());
  expect_csr_of_subcodes(t.lookup, t.codes, &CascadeLookup::ids16);
  // The compact tables take far less than the 2 MiB of full offset tables;
  // the radius-1 neighbourhood sizes add one byte per bucket.
  const CascadeLookup plain(t.codes, /*neighbourhood_sizes=*/false);
  EXPECT_LT(plain.memory_bytes(), size_t(8 * 65537 * 4) / 4);
  EXPECT_EQ(t.lookup.memory_bytes(), plain.memory_bytes() + size_t(8) * kHashBuckets * 2);
  // Every stored neighbourhood size is the saturated sum of the 17 buckets'
  // sizes, counted from the codes.
  const std::span<const uint16_t> stored = t.lookup.stored_neighbourhood_sizes();
  ASSERT_EQ(stored.size(), size_t(kHashTables) * kHashBuckets);
  EXPECT_TRUE(plain.stored_neighbourhood_sizes().empty());
  size_t non_empty = 0;
  for (int k = 0; k < kHashTables; ++k) {
    std::vector<uint32_t> size(kHashBuckets, 0);
    for (const HashCode& c : t.codes) ++size[hash_subcode(c, k)];
    for (uint32_t key = 0; key < kHashBuckets; ++key) {
      uint32_t sum = size[key];
      for (int b = 0; b < kHashTableBits; ++b) sum += size[key ^ (1u << b)];
      ASSERT_EQ(stored[size_t(k) * kHashBuckets + key], std::min<uint32_t>(sum, CascadeLookup::kNeighbourhoodSaturated))
          << "table " << k << " key " << key;
      non_empty += sum > 0;
    }
  }
  EXPECT_GT(non_empty, 10000u);
  // A lookup of another size is caught.
  CascadeLookup other(std::span<const HashCode>(t.codes.data(), 10));
  v.lookup = &other;
  EXPECT_THROW(v.validate("test"), Error);
  // ... and by a matcher given it without validation.
  EXPECT_THROW(CascadeMatcher(v, t.codebook), Error);
  CascadeWorkspace workspace;
  EXPECT_THROW(CascadeMatcher(v, t.codebook, workspace), Error);
}

TEST(CascadeIndex, LargeSegmentsUse32BitIds) {
  std::mt19937_64 rng(3);
  std::vector<HashCode> codes(70000);
  for (auto& c : codes) c = {{rng(), rng() & 0xFFFF00FF00FFull}};  // some tables crowded, some sparse
  CascadeLookup lookup(codes);
  ASSERT_FALSE(lookup.uses_16bit_ids());
  expect_csr_of_subcodes(lookup, codes, &CascadeLookup::ids32);
}

// The coarse list of a feature is exactly the set of points that share a
// probed bucket with it: checked against brute force over every point, one
// feature at a time, for 16-bit and 32-bit point ids, both radii, and buckets
// crowded and sparse (so that empty, single and multi-point buckets and the
// last bucket of a table are all probed).
TEST(CascadeSearch, CoarseListsAreTheUnionOfTheProbedBuckets) {
  std::mt19937_64 rng(12);
  std::vector<float> train(300 * 128);
  for (auto& x : train) x = float(rng() % 200);
  const PqCodebook codebook = PqCodebook::train(train.data(), 300, {.iterations = 2});
  for (size_t points : {3000u, 70000u}) {
    std::vector<HashCode> codes(points);
    for (auto& c : codes) {  // table 3's last bucket crowded; tables 4-7 crowded or sparse
      c = {{rng(), rng() & 0xFFFF00FF00FFull}};
      if (rng() % 8 == 0) c.w[0] |= 0xFFFF000000000000ull;
    }
    std::vector<uint8_t> pq(points * kPqCodeBytes);
    for (auto& b : pq) b = static_cast<uint8_t>(rng());
    const CascadeLookup lookup(codes);
    ASSERT_EQ(lookup.uses_16bit_ids(), points <= 65536);
    ASSERT_TRUE(lookup.has_neighbourhood_sizes());
    // Table 7 holds every point in bucket 0: with 70K points its
    // neighbourhood sizes saturate there, so both the stored sums and the
    // probed fallback are checked.
    if (points > CascadeLookup::kNeighbourhoodSaturated)
      ASSERT_GE(lookup.neighbourhood_size(7, 0), uint32_t(CascadeLookup::kNeighbourhoodSaturated));
    const CascadeLookup plain(codes, /*neighbourhood_sizes=*/false);
    ASSERT_FALSE(plain.has_neighbourhood_sizes());
    BinaryHasher unused;
    CascadeWorkspace workspace;
    CascadeMatcher matcher({points, unused.view(), codes.data(), pq.data(), &lookup}, codebook, workspace);
    CascadeMatcher plain_matcher({points, unused.view(), codes.data(), pq.data(), &plain}, codebook);
    std::vector<uint32_t> sizes;
    DescriptorMatrix one(1);
    size_t complete_lists = 0;
    for (int q = 0; q < 60; ++q) {
      HashCode code = codes[rng() % points];
      code.w[0] ^= uint64_t(1) << (rng() % 64);
      if (q % 3 == 0) code = {{rng(), rng()}};
      for (int radius : {0, 1}) {
        size_t listed = 0;
        std::vector<uint32_t> expected;
        for (uint32_t p = 0; p < points; ++p) {
          size_t tables = 0;
          for (int k = 0; k < kHashTables; ++k)
            tables += std::popcount(hash_subcode(codes[p], k) ^ hash_subcode(code, k)) <= radius;
          listed += tables;
          if (tables > 0) expected.push_back(p);
        }
        const size_t distinct = expected.size();
        // Ratios 1 and M = 64: the 1-M list holds the 64 nearest candidates
        // (all of them when there are at most 64), which must be listed points.
        CascadeSearchOptions o;
        o.lut_radius = radius;
        o.refined = false;
        o.prioritize = false;
        o.ratio_one_to_one = o.ratio_one_to_many = 1.0f;
        o.max_one_to_many = 64;
        CascadeMatches m;
        matcher.match_hashed(one, std::span<const HashCode>(&code, 1), o, m);
        SCOPED_TRACE(::testing::Message() << points << " points, query " << q << ", radius " << radius);
        // The coarse size (the prioritized order's key) is the listed count,
        // from the neighbourhood sums and from the probes alike.
        matcher.coarse_sizes(std::span<const HashCode>(&code, 1), radius, sizes);
        EXPECT_EQ(sizes[0], listed);
        plain_matcher.coarse_sizes(std::span<const HashCode>(&code, 1), radius, sizes);
        EXPECT_EQ(sizes[0], listed);
        EXPECT_EQ(m.stats.features_searched, listed >= 2 ? 1u : 0u);
        EXPECT_EQ(m.stats.coarse_candidates, listed >= 2 ? distinct : 0u);
        EXPECT_EQ(m.stats.ranked_candidates, listed >= 2 && distinct >= 2 ? distinct : 0u);
        // The deduplication bytes are all clear again, whatever the list's size.
        EXPECT_TRUE(std::all_of(workspace.seen.begin(), workspace.seen.end(), [](uint8_t b) { return b == 0; }));
        std::vector<uint32_t> found = m.many_points;
        std::sort(found.begin(), found.end());
        EXPECT_TRUE(std::includes(expected.begin(), expected.end(), found.begin(), found.end()));
        if (!m.many_query.empty() && distinct <= 64) EXPECT_EQ(found, expected);
        if (listed >= 2 && distinct >= 2 && distinct <= 64) ++complete_lists;
      }
    }
    EXPECT_GE(complete_lists, 10u) << "too few queries whose whole coarse list is checked";
  }
}

TEST(CascadeSearch, AFeatureWithOneDistinctCandidateLeavesNoByteSet) {
  // Two points that differ in every bit: a query equal to one of them lists it
  // in all 8 tables (8 listed, 1 distinct), so it is searched but not ranked.
  std::mt19937_64 rng(5);
  std::vector<float> train(300 * 128);
  for (auto& x : train) x = float(rng() % 200);
  const PqCodebook codebook = PqCodebook::train(train.data(), 300, {.iterations = 2});
  const HashCode a{{rng(), rng()}};
  const std::vector<HashCode> codes{a, HashCode{{~a.w[0], ~a.w[1]}}};
  std::vector<uint8_t> pq(codes.size() * kPqCodeBytes, 7);
  const CascadeLookup lookup(codes);
  BinaryHasher unused;
  CascadeWorkspace workspace;
  CascadeMatcher matcher({codes.size(), unused.view(), codes.data(), pq.data(), &lookup}, codebook, workspace);
  DescriptorMatrix one(1);
  for (int radius : {0, 1})
    for (const HashCode& code : codes) {
      CascadeSearchOptions o;
      o.lut_radius = radius;
      o.prioritize = false;
      CascadeMatches m;
      matcher.match_hashed(one, std::span<const HashCode>(&code, 1), o, m);
      EXPECT_EQ(m.stats.features_searched, 1u);
      EXPECT_EQ(m.stats.coarse_candidates, 1u);
      EXPECT_EQ(m.stats.ranked_candidates, 0u);
      EXPECT_TRUE(std::all_of(workspace.seen.begin(), workspace.seen.end(), [](uint8_t b) { return b == 0; }))
          << "radius " << radius;
    }
}

TEST(CascadeSearch, FindsPlantedMatches) {
  DescriptorMatrix db = clustered_descriptors(6000, 5);
  std::vector<size_t> planted;
  for (size_t i = 0; i < 400; ++i) planted.push_back(i * 13 % 6000);
  DescriptorMatrix q = perturbed(db, planted, 4, 6);
  DescriptorMatrix distractors = clustered_descriptors(400, 77);
  q.append(distractors);
  for (bool lsh : {false, true}) {
    TestIndex t = make_index(db, lsh);
    CascadeMatcher matcher(t.view(), t.codebook);
    for (int radius : {0, 1}) {
      for (bool refined : {true, false}) {
        CascadeSearchOptions o;
        o.lut_radius = radius;
        o.refined = refined;
        o.prioritize = false;
        CascadeMatches m = matcher.match(q, o);
        size_t correct = 0, wrong = 0;
        for (size_t i = 0; i < m.query.size(); ++i) {
          if (m.query[i] < planted.size()) (m.point[i] == planted[m.query[i]] ? correct : wrong)++;
        }
        SCOPED_TRACE(::testing::Message() << "lsh " << lsh << " radius " << radius << " refined " << refined);
        EXPECT_GE(correct, 340u);
        EXPECT_LE(wrong, 10u);
        EXPECT_EQ(m.stats.features, q.rows());
        EXPECT_FALSE(m.stats.early_stopped);
        // 1-M: nearest first, the 1-1 point first, at most M entries.
        ASSERT_EQ(m.many_offsets.size(), m.many_query.size() + 1);
        for (size_t r = 0; r < m.many_query.size(); ++r) {
          ASSERT_LE(m.many_offsets[r + 1] - m.many_offsets[r], 5u);
          for (uint32_t k = m.many_offsets[r] + 1; k < m.many_offsets[r + 1]; ++k)
            EXPECT_LE(m.many_distances[k - 1], m.many_distances[k]);
        }
      }
    }
  }
}

TEST(CascadeSearch, PrioritizationOrderAndEarlyStop) {
  DescriptorMatrix db = clustered_descriptors(5000, 8);
  std::vector<size_t> planted;
  for (size_t i = 0; i < 600; ++i) planted.push_back(i * 7 % 5000);
  DescriptorMatrix q = perturbed(db, planted, 4, 9);
  TestIndex t = make_index(db);
  CascadeMatcher matcher(t.view(), t.codebook);
  CascadeSearchOptions full;
  full.prioritize = false;
  CascadeMatches all = matcher.match(q, full);
  ASSERT_GT(all.query.size(), 300u);
  CascadeSearchOptions pri;
  pri.early_stop = 50;
  CascadeMatches early = matcher.match(q, pri);
  EXPECT_TRUE(early.stats.early_stopped);
  EXPECT_EQ(early.query.size(), 50u);
  EXPECT_LT(early.stats.features_searched, all.stats.features_searched);
  // Matches come out in increasing coarse list size.
  std::vector<HashCode> qc(q.rows());
  HashWorkspace ws;
  encode_hash(t.hasher.view(), q.data(), q.rows(), qc.data(), ws);
  std::vector<uint32_t> sizes;
  matcher.coarse_sizes(qc, pri.lut_radius, sizes);
  for (size_t i = 1; i < early.query.size(); ++i) EXPECT_LE(sizes[early.query[i - 1]], sizes[early.query[i]]);
  // Every early match is one the full search also finds (same ranking per feature).
  for (size_t i = 0; i < early.query.size(); ++i) {
    auto it = std::find(all.query.begin(), all.query.end(), early.query[i]);
    ASSERT_NE(it, all.query.end());
    EXPECT_EQ(all.point[it - all.query.begin()], early.point[i]);
  }
  // With early stop 0 the prioritized search is complete, and its matches
  // come in the order of a full sort by (coarse size, feature index), at both
  // radii.
  pri.early_stop = 0;
  for (int radius : {0, 1}) {
    pri.lut_radius = radius;
    full.lut_radius = radius;
    const CascadeMatches complete = matcher.match(q, pri);
    const CascadeMatches unordered = matcher.match(q, full);
    EXPECT_EQ(complete.query.size(), unordered.query.size());
    matcher.coarse_sizes(qc, radius, sizes);
    std::vector<uint32_t> expected = unordered.query;
    std::sort(expected.begin(), expected.end(),
              [&](uint32_t a, uint32_t b) { return std::pair(sizes[a], a) < std::pair(sizes[b], b); });
    EXPECT_EQ(complete.query, expected) << "radius " << radius;
  }
  pri.refined_list = 1;
  EXPECT_THROW(matcher.match(q, pri), Error);
}

TEST(CascadeSearch, OneToManyRulesAndCorrespondenceSet) {
  DescriptorMatrix db = clustered_descriptors(4000, 10);
  // Near-duplicate points (repetitive structure): pairs of rows almost equal.
  for (size_t i = 0; i < 200; ++i)
    for (int j = 0; j < 128; ++j) db.row(2000 + i)[j] = static_cast<uint8_t>(std::min(255, db.row(i)[j] + (j % 7 == 0)));
  std::vector<size_t> rows;
  for (size_t i = 0; i < 300; ++i) rows.push_back(i);
  DescriptorMatrix q = perturbed(db, rows, 3, 11);
  TestIndex t = make_index(db);
  CascadeMatcher matcher(t.view(), t.codebook);
  CascadeSearchOptions o;
  o.prioritize = false;
  CascadeMatches best = matcher.match(q, o);
  o.one_to_many_rule = OneToManyRule::kGroupRatio;
  CascadeMatches group = matcher.match(q, o);
  EXPECT_EQ(best.query, group.query);  // the 1-1 set does not depend on the rule
  const float nu2 = 0.9f * 0.9f;
  for (size_t r = 0; r < group.many_query.size(); ++r) {
    const uint32_t b = group.many_offsets[r], e = group.many_offsets[r + 1];
    const float d0 = group.many_distances[b];
    for (uint32_t k = b + 1; k < e; ++k)  // every accepted candidate is a near-tie of the best
      EXPECT_GE(d0 * d0, nu2 * group.many_distances[k] * group.many_distances[k] * 0.999f);
  }
  // The near-duplicates make 2-candidate groups: features of the first 200
  // rows keep both copies under the group rule.
  size_t pairs = 0;
  for (size_t r = 0; r < group.many_query.size(); ++r)
    if (group.many_query[r] < 200 && group.many_offsets[r + 1] - group.many_offsets[r] == 2) ++pairs;
  EXPECT_GT(pairs, 100u);
  for (size_t r = 0; r < best.many_query.size(); ++r) EXPECT_EQ(best.many_offsets[r + 1] - best.many_offsets[r], 5u);

  // The correspondence set one-many RANSAC consumes: one row per 1-M feature,
  // floats widened to double exactly.
  std::vector<Keypoint> kp(q.rows());
  for (size_t i = 0; i < kp.size(); ++i) kp[i] = {float(i) + 0.1f, float(2 * i) + 0.7f, 1, 0};
  std::vector<float> xyz(db.rows() * 3);
  for (size_t i = 0; i < xyz.size(); ++i) xyz[i] = float(i) * 0.01f;
  CorrespondenceSet c = make_correspondence_set(best, kp, xyz);
  c.validate();
  ASSERT_EQ(c.num_features(), best.many_query.size());
  ASSERT_EQ(c.candidate_offsets.size(), c.points2d.size() + 1);
  EXPECT_EQ(c.candidate_offsets, best.many_offsets);
  EXPECT_EQ(c.candidate_point_ids, best.many_points);
  EXPECT_EQ(c.query_feature, best.many_query);
  EXPECT_EQ(c.candidates.size(), best.many_points.size());
  size_t hyp = 0;
  for (size_t r = 0; r < c.points2d.size(); ++r) {
    const uint32_t f = best.many_query[r];
    EXPECT_EQ(c.points2d[r].x(), double(kp[f].x));
    EXPECT_EQ(c.points2d[r].y(), double(kp[f].y));
    for (uint32_t k = c.candidate_offsets[r]; k < c.candidate_offsets[r + 1]; ++k) {
      const uint32_t p = c.candidate_point_ids[k];
      EXPECT_EQ(c.candidates[k], Eigen::Vector3d(double(xyz[3 * p]), double(xyz[3 * p + 1]), double(xyz[3 * p + 2])));
    }
    const auto it = std::find(best.query.begin(), best.query.end(), f);
    EXPECT_EQ(c.in_hypothesis_set[r], it != best.query.end() ? 1 : 0);
    if (it != best.query.end()) {
      EXPECT_EQ(best.point[it - best.query.begin()], c.candidate_point_ids[c.candidate_offsets[r]]);
    }
    hyp += c.in_hypothesis_set[r];
  }
  EXPECT_EQ(hyp, best.query.size());
  EXPECT_EQ(c.num_hypothesis_features(), best.query.size());
  // Filling a used set replaces its content.
  CorrespondenceSet reused = make_correspondence_set(group, kp, xyz);
  fill_correspondence_set(best, kp, xyz, reused);
  EXPECT_EQ(reused.points2d, c.points2d);
  EXPECT_EQ(reused.candidate_offsets, c.candidate_offsets);
  EXPECT_EQ(reused.candidates, c.candidates);
  EXPECT_EQ(reused.candidate_point_ids, c.candidate_point_ids);
  EXPECT_EQ(reused.in_hypothesis_set, c.in_hypothesis_set);
  EXPECT_EQ(reused.query_feature, c.query_feature);
  EXPECT_TRUE(c.candidate_uncertainty.empty());
  // With the segment's point uncertainty: each candidate's code; and cleared
  // again when a later fill has none.
  std::vector<PointUncertaintyCode> codes(db.rows());
  for (size_t i = 0; i < codes.size(); ++i) codes[i] = {uint8_t(i), uint8_t(i >> 8), uint8_t(7 + i % 200), 3};
  fill_correspondence_set(best, kp, xyz, reused, codes);
  reused.validate();
  ASSERT_EQ(reused.candidate_uncertainty.size(), reused.candidates.size());
  for (size_t k = 0; k < reused.candidates.size(); ++k)
    EXPECT_EQ(reused.candidate_uncertainty[k], codes[reused.candidate_point_ids[k]]);
  fill_correspondence_set(best, kp, xyz, reused);
  EXPECT_TRUE(reused.candidate_uncertainty.empty());
  EXPECT_THROW(fill_correspondence_set(best, kp, xyz, reused, std::span(codes).first(codes.size() - 1)), Error);
  // Matches that are not a search's result are an internal error.
  ASSERT_FALSE(best.query.empty());
  CascadeMatches broken = best;
  broken.point[0] ^= 1;  // not the first 1-M candidate
  EXPECT_THROW(make_correspondence_set(broken, kp, xyz), Error);
  broken = best;
  std::reverse(broken.query.begin(), broken.query.end());  // not in search order
  std::reverse(broken.point.begin(), broken.point.end());
  if (best.query.size() > 1) {
    EXPECT_THROW(make_correspondence_set(broken, kp, xyz), Error);
  }
  EXPECT_THROW(make_correspondence_set(best, std::span<const Keypoint>(kp).first(1), xyz), Error);
  c.validate();  // what it fills is a valid set (geometry_test.cc tests validate() itself)
}

// The search gives the same matches, distances and statistics with every
// kernel level this CPU supports, and with a workspace reused across two
// segments of different sizes and across calls.
// (and software prefetching, whose pipeline runs two features ahead of the
// search and must not change it, early stop included)
TEST(CascadeSearch, EveryKernelLevelAndAReusedWorkspaceGiveTheSameMatches) {
  DescriptorMatrix db = clustered_descriptors(5000, 21);
  DescriptorMatrix small_db = clustered_descriptors(700, 22);
  TestIndex t = make_index(db), small = make_index(small_db);
  std::vector<size_t> rows;
  for (size_t i = 0; i < 600; ++i) rows.push_back(i * 7 % db.rows());
  DescriptorMatrix q = perturbed(db, rows, 6, 23);
  // Also without the refined step and with a longer L_R: 49-160 ranked
  // candidates, where the direct ADC path must be taken at every level.
  struct Config {
    bool prioritize, refined;
    int refined_list;
  };
  for (const Config& config :
       {Config{false, true, 40}, Config{true, true, 40}, Config{false, false, 40}, Config{false, true, 100}}) {
    CascadeSearchOptions o;
    o.prioritize = config.prioritize;
    o.refined = config.refined;
    o.refined_list = config.refined_list;
    o.simd = SimdLevel::kScalar;
    o.prefetch = false;  // the reference; every level below prefetches
    const CascadeMatches ref = CascadeMatcher(t.view(), t.codebook).match(q, o);
    o.prefetch = true;
    EXPECT_EQ(ref.stats.early_stopped, config.prioritize);  // the prioritized search stops early here
    ASSERT_GT(ref.query.size(), 50u);
    CascadeWorkspace shared;
    for (SimdLevel level : supported_simd_levels()) {
      o.simd = level;
      CascadeMatches m, other;
      // The shared workspace saw a smaller and a larger segment before.
      CascadeMatcher(small.view(), small.codebook, shared).match(q, o, other);
      CascadeMatcher(t.view(), t.codebook, shared).match(q, o, m);
      EXPECT_EQ(m.query, ref.query) << to_string(level);
      EXPECT_EQ(m.point, ref.point) << to_string(level);
      EXPECT_EQ(m.distance, ref.distance) << to_string(level);
      EXPECT_EQ(m.many_query, ref.many_query) << to_string(level);
      EXPECT_EQ(m.many_offsets, ref.many_offsets) << to_string(level);
      EXPECT_EQ(m.many_points, ref.many_points) << to_string(level);
      EXPECT_EQ(m.many_distances, ref.many_distances) << to_string(level);
      EXPECT_EQ(m.stats.coarse_candidates, ref.stats.coarse_candidates);
      EXPECT_EQ(m.stats.ranked_candidates, ref.stats.ranked_candidates);
      EXPECT_EQ(m.stats.features_searched, ref.stats.features_searched);
      EXPECT_EQ(m.stats.early_stopped, ref.stats.early_stopped);
      // The deduplication's bytes are all cleared again after every feature.
      EXPECT_TRUE(std::all_of(shared.seen.begin(), shared.seen.end(), [](uint8_t b) { return b == 0; }));
      EXPECT_GE(shared.seen.size(), t.view().num_points);
      // (The query codes come from the best kernel at every level: encode_hash
      // does not take a level; the hash kernels' equality is tested on its own.)
      // Codes hashed once by the caller give the same result.
      std::vector<HashCode> codes(q.rows());
      HashWorkspace ws;
      encode_hash(t.hasher.view(), q.data(), q.rows(), codes.data(), ws);
      CascadeMatcher(t.view(), t.codebook, shared).match_hashed(q, codes, o, other);
      EXPECT_EQ(other.point, ref.point);
      EXPECT_EQ(other.many_points, ref.many_points);
    }
    // Queries of 1-4 features: the prefetching pipeline's first steps alone.
    for (size_t n = 1; n <= 4; ++n) {
      DescriptorMatrix few(n);
      for (size_t i = 0; i < n; ++i) std::copy(q.row(i), q.row(i) + kDescriptorDim, few.row(i));
      CascadeSearchOptions with = o, without = o;
      without.prefetch = false;
      const CascadeMatches a = CascadeMatcher(t.view(), t.codebook).match(few, with);
      const CascadeMatches b = CascadeMatcher(t.view(), t.codebook).match(few, without);
      EXPECT_EQ(a.point, b.point) << n << " features";
      EXPECT_EQ(a.many_points, b.many_points) << n << " features";
      EXPECT_EQ(a.stats.coarse_candidates, b.stats.coarse_candidates) << n << " features";
      EXPECT_GT(b.stats.coarse_candidates, 0u) << n << " features";
    }
    // Once grown, the workspace does not grow for the same segments.
    const size_t bytes = shared.capacity_bytes();
    CascadeMatches again;
    CascadeMatcher(t.view(), t.codebook, shared).match(q, o, again);
    EXPECT_EQ(shared.capacity_bytes(), bytes);
  }
}

namespace {

// The bits one table flips, nearest its hyperplane first: query-directed
// probing (`lut_flips` of them; margins saturated at 2^27 − 1, ties by bit)
// or every bit in order.
std::vector<int> reference_flips(const CascadeSearchOptions& o, const int32_t* margins, int table) {
  std::vector<int> bits(kHashTableBits);
  for (int b = 0; b < kHashTableBits; ++b) bits[b] = b;
  if (o.lut_flips == kHashTableBits) return bits;
  auto margin = [&](int b) { return std::min(margins[table * kHashTableBits + b], (1 << 27) - 1); };
  std::stable_sort(bits.begin(), bits.end(), [&](int a, int b) { return margin(a) < margin(b); });
  bits.resize(size_t(o.lut_flips));
  return bits;
}

// The cascade search of one feature written plainly, from its definition:
// the probed buckets' points (table 0..7; the exact bucket, then the one-bit
// neighbours by increasing bit, or query-directed by reference_flips;
// increasing id within a bucket) without
// repeats; when there are more than L_R, the candidates below the L_R-th
// Hamming distance and the first ones at it, in candidate order; the scalar
// ADC distances (direct up to 160 ranked, by the table above); a stable sort;
// the best-ratio rule. Appends to `out` as the search does, with its
// statistics; `most_ranked` is the longest ranked list. The ADC distances come
// from the library's scalar kernels, and the 160 is the search's switch to
// the table path: floats must agree to the bit, and the two paths round
// differently. `keyed[k]` holds (subcode << 32 | point) of every point for
// table k, sorted.
// `margins`: the feature's 128 (query-directed probing only).
void reference_search(const TestIndex& t, const std::vector<std::vector<uint64_t>>& keyed, const DescriptorMatrix& q,
                      uint32_t f, const HashCode& code, const CascadeSearchOptions& o, CascadeMatches& out,
                      size_t& most_ranked, const int32_t* margins) {
  std::vector<uint32_t> candidates;
  std::vector<bool> seen(t.codes.size());
  size_t listed = 0;
  // Directed only above lut_flips_min_list points in the 136 radius-1 buckets.
  size_t radius1_size = 0;
  for (int k = 0; k < kHashTables; ++k)
    for (const uint64_t entry : keyed[k])
      radius1_size += std::popcount(uint32_t(entry >> 32) ^ hash_subcode(code, k)) <= 1;
  CascadeSearchOptions every_bit = o;
  every_bit.lut_flips = kHashTableBits;
  const bool directed = radius1_size > size_t(o.lut_flips_min_list);
  for (int k = 0; k < kHashTables; ++k) {
    const uint32_t key = hash_subcode(code, k);
    const std::vector<int> flips = reference_flips(directed ? o : every_bit, margins, k);
    for (int b = 0; b <= (o.lut_radius == 1 ? int(flips.size()) : 0); ++b) {
      const uint64_t bucket = b == 0 ? key : key ^ (1u << flips[b - 1]);
      auto it = std::lower_bound(keyed[k].begin(), keyed[k].end(), bucket << 32);
      for (; it != keyed[k].end() && (*it >> 32) == bucket; ++it) {
        const uint32_t p = static_cast<uint32_t>(*it & 0xffffffffu);
        ++listed;
        if (!seen[p]) seen[p] = true, candidates.push_back(p);
      }
    }
  }
  if (listed < 2) return;
  ++out.stats.features_searched;
  out.stats.coarse_candidates += candidates.size();
  if (candidates.size() < 2) return;
  std::vector<uint32_t> ranked = candidates;
  if (o.refined && candidates.size() > size_t(o.refined_list)) {
    std::vector<uint32_t> h;
    for (uint32_t p : candidates) h.push_back(hamming_distance(code, t.codes[p]));
    std::vector<uint32_t> sorted_h = h;
    std::sort(sorted_h.begin(), sorted_h.end());
    const uint32_t cut = sorted_h[o.refined_list - 1];
    size_t at_cut = o.refined_list - size_t(std::count_if(h.begin(), h.end(), [&](uint32_t x) { return x < cut; }));
    ranked.clear();
    for (size_t i = 0; i < candidates.size(); ++i)
      if (h[i] < cut || (h[i] == cut && at_cut > 0 && at_cut--)) ranked.push_back(candidates[i]);
  }
  out.stats.ranked_candidates += ranked.size();
  most_ranked = std::max(most_ranked, ranked.size());
  float qf[kDescriptorDim];
  for (int j = 0; j < kDescriptorDim; ++j) qf[j] = q.row(f)[j];
  std::vector<float> d(ranked.size());
  const AdcKernels& scalar = search_kernels(SimdLevel::kScalar).adc(t.codebook.subvectors());
  if (ranked.size() <= 160) {
    scalar.direct(t.codebook.centroids().data(), qf, t.pq.data(), ranked.data(), ranked.size(), d.data());
  } else {
    std::vector<float> table(t.codebook.table_size());
    scalar.table(t.codebook.centroids_transposed(), qf, table.data());
    scalar.distances(table.data(), t.pq.data(), ranked.data(), ranked.size(), d.data());
  }
  std::vector<size_t> order(ranked.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return d[a] < d[b]; });
  const float d0 = d[order[0]], d1 = d[order[1]];
  if (d0 < o.ratio_one_to_one * o.ratio_one_to_one * d1) {
    out.query.push_back(f);
    out.point.push_back(ranked[order[0]]);
    out.distance.push_back(std::sqrt(d0));
  }
  if (d0 < o.ratio_one_to_many * o.ratio_one_to_many * d1) {
    out.many_query.push_back(f);
    for (size_t i = 0; i < std::min(order.size(), size_t(o.max_one_to_many)); ++i) {
      out.many_points.push_back(ranked[order[i]]);
      out.many_distances.push_back(std::sqrt(d[order[i]]));
    }
    out.many_offsets.push_back(static_cast<uint32_t>(out.many_points.size()));
  }
}

}  // namespace

// The optimized search (branch-free gather, byte deduplication, counting-sort
// shortlist, insertion into the nearest) returns exactly what the plain
// definition does, in index order with the best-ratio rule (the prioritized
// order, early stop and group rule are tested above): the guard for any later
// change of the search loop that is meant to be lossless. Segments with
// crowded buckets (clustered descriptors, LSH codes) and with 32-bit ids, and
// one with 32-byte PQ codes, at both radii (and query-directed probing of 5
// and of no one-bit neighbours, and of 3 for the features above the median
// coarse size, with the margins given and computed by the matcher), with and without the refined step (so both ADC
// paths), at every kernel level.
TEST(CascadeSearch, SameMatchesAsThePlainDefinition) {
  struct Case {
    size_t points;
    bool lsh;
    int pq_subvectors;
  };
  for (const auto& [points, lsh, pq_subvectors] :
       {Case{5000, false, 16}, Case{4500, true, 16}, Case{66000, false, 16}, Case{5000, false, 32}}) {
    DescriptorMatrix db = clustered_descriptors(points, 31, 12);
    TestIndex t = make_index(db, lsh, 5000, pq_subvectors);
    std::vector<std::vector<uint64_t>> keyed(kHashTables);
    for (int k = 0; k < kHashTables; ++k) {
      for (uint32_t p = 0; p < t.codes.size(); ++p) keyed[k].push_back(uint64_t(hash_subcode(t.codes[p], k)) << 32 | p);
      std::sort(keyed[k].begin(), keyed[k].end());
    }
    std::vector<size_t> rows;
    for (size_t i = 0; i < 150; ++i) rows.push_back(i * 11 % db.rows());
    const DescriptorMatrix q = perturbed(db, rows, 12, 32);
    std::vector<HashCode> codes(q.rows()), scalar_codes(q.rows());
    std::vector<int32_t> margins(q.rows() * kHashBits);
    HashWorkspace hws;
    encode_hash(t.hasher.view(), q.data(), q.rows(), codes.data(), hws);
    search_kernels(SimdLevel::kScalar)
        .hash_codes_u8(hws.quantized, q.data(), q.rows(), scalar_codes.data(), margins.data());
    for (size_t f = 0; f < codes.size(); ++f) ASSERT_EQ(hamming_distance(codes[f], scalar_codes[f]), 0u);
    // The median radius-1 coarse size: directed probing above it only.
    std::vector<uint32_t> sizes;
    CascadeMatcher(t.view(), t.codebook).coarse_sizes(codes, 1, sizes);
    std::nth_element(sizes.begin(), sizes.begin() + sizes.size() / 2, sizes.end());
    const int median_size = int(sizes[sizes.size() / 2]);
    for (auto [radius, flips, min_list] : {std::tuple{0, 16, 0}, std::tuple{1, 16, 0}, std::tuple{1, 5, 0},
                                           std::tuple{1, 0, 0}, std::tuple{1, 3, median_size}})
      for (bool refined : {true, false}) {
        SCOPED_TRACE(::testing::Message()
                     << points << " points, lsh " << lsh << ", " << pq_subvectors << "-byte PQ, radius " << radius
                     << ", flips " << flips << " above " << min_list << ", refined " << refined);
        CascadeSearchOptions o;
        o.lut_radius = radius;
        o.lut_flips = flips;
        o.lut_flips_min_list = min_list;
        o.refined = refined;
        o.prioritize = false;
        CascadeMatches expected;
        expected.clear();
        size_t most_ranked = 0;
        for (uint32_t f = 0; f < q.rows(); ++f)
          reference_search(t, keyed, q, f, codes[f], o, expected, most_ranked, margins.data() + f * kHashBits);
        ASSERT_GT(expected.query.size(), 20u);
        // Not vacuous: the refined step trims lists, and without it some
        // feature ranks more than 160 candidates (the ADC table path).
        if (refined && flips > 0) EXPECT_LT(expected.stats.ranked_candidates, expected.stats.coarse_candidates);
        if (!refined && radius == 1 && flips == 16) EXPECT_GT(most_ranked, 160u);
        for (SimdLevel level : supported_simd_levels())
          for (bool prefetch : {true, false}) {
            SCOPED_TRACE(::testing::Message() << to_string(level) << ", prefetch " << prefetch);
            o.simd = level;
            o.prefetch = prefetch;
            CascadeMatches m;
            // The margins given (prefetching) or computed by the matcher.
            CascadeMatcher(t.view(), t.codebook)
                .match_hashed(q, codes, o, m,
                              prefetch ? std::span<const int32_t>(margins) : std::span<const int32_t>());
            EXPECT_EQ(m.query, expected.query);
            EXPECT_EQ(m.point, expected.point);
            EXPECT_EQ(m.distance, expected.distance);
            EXPECT_EQ(m.many_query, expected.many_query);
            EXPECT_EQ(m.many_offsets, expected.many_offsets);
            EXPECT_EQ(m.many_points, expected.many_points);
            EXPECT_EQ(m.many_distances, expected.many_distances);
            EXPECT_EQ(m.stats.features_searched, expected.stats.features_searched);
            EXPECT_EQ(m.stats.coarse_candidates, expected.stats.coarse_candidates);
            EXPECT_EQ(m.stats.ranked_candidates, expected.stats.ranked_candidates);
          }
      }
  }
}

// 32-byte codes find the planted matches as 16-byte ones do, with no fewer
// correct ones; an index and a codebook of different code sizes are refused.
TEST(CascadeSearch, ThirtyTwoByteCodesFindPlantedMatchesAndMustMatchTheCodebook) {
  DescriptorMatrix db = clustered_descriptors(6000, 5);
  std::vector<size_t> planted;
  for (size_t i = 0; i < 400; ++i) planted.push_back(i * 13 % 6000);
  const DescriptorMatrix q = perturbed(db, planted, 4, 6);
  size_t correct_by_size[2] = {0, 0};
  for (int s = 0; s < 2; ++s) {
    const TestIndex t = make_index(db, false, 0, s == 0 ? 16 : 32);
    CascadeSearchOptions o;
    o.prioritize = false;
    const CascadeMatches m = CascadeMatcher(t.view(), t.codebook).match(q, o);
    size_t wrong = 0;
    for (size_t i = 0; i < m.query.size(); ++i) (m.point[i] == planted[m.query[i]] ? correct_by_size[s] : wrong)++;
    EXPECT_LE(wrong, 10u);
  }
  EXPECT_GE(correct_by_size[0], 340u);
  EXPECT_GE(correct_by_size[1], correct_by_size[0]);
  const TestIndex t16 = make_index(clustered_descriptors(1000, 6));
  const TestIndex t32 = make_index(clustered_descriptors(1000, 6), false, 0, 32);
  try {
    CascadeMatcher(t16.view(), t32.codebook);
    ADD_FAILURE() << "a 16-byte index searched with a 32-byte codebook";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
    EXPECT_NE(std::string(e.what()).find("16 bytes, the codebook's 32"), std::string::npos) << e.what();
  }
  EXPECT_THROW(CascadeMatcher(t32.view(), t16.codebook), Error);
  CascadeIndexView bad = t16.view();
  bad.pq_subvectors = 24;
  EXPECT_THROW(bad.validate("test"), Error);
}

// A residual codebook's index finds the planted matches with no fewer correct
// ones than the PQ's of as many bytes, every kernel level the same matches.
TEST(CascadeSearch, ResidualCodesFindPlantedMatchesAtEveryLevel) {
  DescriptorMatrix db = clustered_descriptors(6000, 5);
  std::vector<size_t> planted;
  for (size_t i = 0; i < 400; ++i) planted.push_back(i * 13 % 6000);
  const DescriptorMatrix q = perturbed(db, planted, 4, 6);
  CascadeSearchOptions o;
  o.prioritize = false;
  size_t correct_pq = 0;
  {
    const TestIndex t = make_index(db);
    const CascadeMatches m = CascadeMatcher(t.view(), t.codebook).match(q, o);
    for (size_t i = 0; i < m.query.size(); ++i) correct_pq += m.point[i] == planted[m.query[i]];
  }
  for (const int splits : {1, 4}) {
    SCOPED_TRACE(std::to_string(splits) + " splits");
    const TestIndex t = make_index(db, false, 0, kPqSubvectors, splits);
    ASSERT_TRUE(t.codebook.is_residual());
    o.simd = SimdLevel::kScalar;
    const CascadeMatches m = CascadeMatcher(t.view(), t.codebook).match(q, o);
    size_t correct = 0, wrong = 0;
    for (size_t i = 0; i < m.query.size(); ++i) (m.point[i] == planted[m.query[i]] ? correct : wrong)++;
    EXPECT_LE(wrong, 10u);
    EXPECT_GE(correct, correct_pq);
    for (SimdLevel level : supported_simd_levels()) {
      o.simd = level;
      const CascadeMatches l = CascadeMatcher(t.view(), t.codebook).match(q, o);
      EXPECT_EQ(l.point, m.point) << to_string(level);
      EXPECT_EQ(l.distance, m.distance) << to_string(level);
      EXPECT_EQ(l.many_points, m.many_points) << to_string(level);
    }
  }
}

TEST(FaissBaselines, IvfAdcAndImiFindPlantedMatches) {
  DescriptorMatrix db = clustered_descriptors(6000, 12);
  std::vector<size_t> planted;
  for (size_t i = 0; i < 300; ++i) planted.push_back(i * 17 % 6000);
  DescriptorMatrix q = perturbed(db, planted, 4, 13);
  auto f = to_float(db);
  for (auto kind : {FaissPqIndexKind::kIvfAdc, FaissPqIndexKind::kImi}) {
    FaissPqIndexOptions o;
    o.kind = kind;
    FaissPqIndex index(f.data(), db.rows(), o);
    FaissSearchStats st;
    auto m = index.match(q, kind == FaissPqIndexKind::kImi ? 64 : 8, 0.8, &st);
    size_t correct = 0;
    for (const auto& r : m) correct += r.database == planted[r.query];
    EXPECT_GE(correct, 240u);
    EXPECT_GT(st.distances_per_query, 0.0);
  }
}

// Query-directed probing gives each feature the same matches in every path:
// match() (margins hashed there) and match_hashed with the margins given or
// computed by the matcher; and the prioritized search without early stop
// (another order, the sizes from the order's key) the same (feature, point)
// pairs as the full search, at every flip count and bound.
TEST(CascadeSearch, DirectedProbingIsTheSameInEveryPath) {
  DescriptorMatrix db = clustered_descriptors(5000, 31, 12);
  TestIndex t = make_index(db, false, 5000, kPqSubvectors);
  std::vector<size_t> rows;
  for (size_t i = 0; i < 300; ++i) rows.push_back(i * 7 % db.rows());
  const DescriptorMatrix q = perturbed(db, rows, 12, 33);
  std::vector<HashCode> codes(q.rows());
  std::vector<int32_t> margins(q.rows() * kHashBits);
  HashWorkspace hws;
  encode_hash(t.hasher.view(), q.data(), q.rows(), codes.data(), hws, margins.data());
  auto pairs = [](const CascadeMatches& m) {
    std::set<std::pair<uint32_t, uint32_t>> out;
    for (size_t i = 0; i < m.query.size(); ++i) out.insert({m.query[i], m.point[i]});
    return out;
  };
  CascadeWorkspace ws;
  CascadeMatcher matcher(t.view(), t.codebook, ws);
  std::vector<uint32_t> sizes;  // the median radius-1 coarse size: a bound that splits the features
  matcher.coarse_sizes(codes, 1, sizes);
  std::nth_element(sizes.begin(), sizes.begin() + sizes.size() / 2, sizes.end());
  const int median = int(sizes[sizes.size() / 2]);
  for (auto [flips, min_list] : {std::pair{5, 0}, std::pair{2, median}, std::pair{0, 0}, std::pair{0, median}}) {
    SCOPED_TRACE(::testing::Message() << flips << " flips above " << min_list);
    CascadeSearchOptions o;
    o.prioritize = false;
    o.lut_flips = flips;
    o.lut_flips_min_list = min_list;
    CascadeMatches given, computed, hashed, prioritized;
    matcher.match_hashed(q, codes, o, given, margins);
    ASSERT_GT(given.query.size(), 20u);
    matcher.match_hashed(q, codes, o, computed);
    matcher.match(q, o, hashed);
    for (const CascadeMatches* m : {&computed, &hashed}) {
      EXPECT_EQ(m->query, given.query);
      EXPECT_EQ(m->point, given.point);
      EXPECT_EQ(m->many_points, given.many_points);
      EXPECT_EQ(m->stats.coarse_candidates, given.stats.coarse_candidates);
    }
    o.prioritize = true;
    o.early_stop = 0;
    matcher.match_hashed(q, codes, o, prioritized, margins);
    EXPECT_EQ(pairs(prioritized), pairs(given));
    EXPECT_EQ(prioritized.stats.coarse_candidates, given.stats.coarse_candidates);
  }
  // Margins of another length are refused, not read.
  CascadeSearchOptions o;
  o.lut_flips = 4;
  CascadeMatches m;
  EXPECT_THROW(matcher.match_hashed(q, codes, o, m, std::span<const int32_t>(margins).first(kHashBits)), Error);
}

// The sorting network's order: per table, the bits by increasing (margin
// saturated at 2^27 − 1, bit), for margins with ties, zeros and huge values.
TEST(CascadeSearch, DirectedFlipsAreTheBitsNearestTheirHyperplanes) {
  std::mt19937 rng(5);
  std::vector<int32_t> margins(kHashBits);
  std::vector<uint8_t> out(kHashTables * kHashTableBits);
  for (int trial = 0; trial < 2000; ++trial) {
    for (auto& m : margins) {
      switch (rng() % 4) {
        case 0:
          m = int32_t(rng() % 8);
          break;  // ties
        case 1:
          m = int32_t(rng() % 1000000);
          break;
        case 2:
          m = int32_t((1 << 27) + rng() % 1000);
          break;  // saturated: ties by bit
        default:
          m = int32_t(rng() & 0x7fffffff);
          break;
      }
    }
    const int flips = trial % (kHashTableBits + 1);
    directed_flips(margins.data(), flips, out.data());
    CascadeSearchOptions o;
    o.lut_flips = flips;
    for (int k = 0; k < kHashTables; ++k) {
      const std::vector<int> expected = flips == kHashTableBits ? [&] {
        CascadeSearchOptions all_sorted = o;
        all_sorted.lut_flips = kHashTableBits - 1;  // the sorted order, then the last bit
        std::vector<int> v = reference_flips(all_sorted, margins.data(), k);
        for (int b = 0; b < kHashTableBits; ++b)
          if (std::find(v.begin(), v.end(), b) == v.end()) v.push_back(b);
        return v;
      }() : reference_flips(o, margins.data(), k);
      for (int j = 0; j < flips; ++j)
        ASSERT_EQ(out[k * flips + j], expected[j]) << "trial " << trial << " table " << k << " rank " << j;
    }
  }
}

// Both paths of the prioritized order (counting sort below 65,536, std::sort
// from it) give the stable sort by size of the features kept, ties in index
// order, and reuse their scratch across calls.
TEST(CascadeSortBySize, BothPathsEqualAStableSortOfTheKeptFeatures) {
  std::mt19937 rng(5);
  std::vector<uint32_t> counts;
  std::vector<uint64_t> order;
  for (const uint32_t largest : {0u, 1u, 3u, 700u, 65535u, 65536u, 1u << 20, 0xFFFFFFFFu}) {
    for (const uint32_t min_size : {0u, 2u, 500u}) {
      std::vector<uint32_t> sizes(3000);
      // Many ties (sizes from a small set) and the largest value present.
      std::uniform_int_distribution<uint32_t> pick(0, 40);
      for (auto& s : sizes) s = std::min(largest, pick(rng) * (largest / 40 + 1));
      sizes[rng() % sizes.size()] = largest;
      std::vector<uint32_t> kept;
      for (uint32_t f = 0; f < sizes.size(); ++f)
        if (sizes[f] >= min_size) kept.push_back(f);
      std::stable_sort(kept.begin(), kept.end(), [&](uint32_t a, uint32_t b) { return sizes[a] < sizes[b]; });
      sort_by_size(sizes.data(), sizes.size(), min_size, counts, order);
      ASSERT_EQ(order.size(), kept.size()) << "largest " << largest << ", min_size " << min_size;
      for (size_t i = 0; i < kept.size(); ++i) {
        ASSERT_EQ(order[i] >> 32, sizes[kept[i]]) << "largest " << largest << ", rank " << i;
        ASSERT_EQ(order[i] & 0xFFFFFFFFu, kept[i]) << "largest " << largest << ", rank " << i;
      }
    }
  }
  // No features: an empty order, whatever the scratch held before.
  sort_by_size(nullptr, 0, 2, counts, order);
  EXPECT_TRUE(order.empty());
}
