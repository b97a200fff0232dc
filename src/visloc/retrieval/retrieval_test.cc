#include <gtest/gtest.h>
#include <omp.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <random>

#include "visloc/retrieval/image_index.h"
#include "visloc/retrieval/retrieval_map.h"
#include "visloc/util/section_file.h"
#include "visloc/baselines/retrieval_truth.h"
#include "visloc/retrieval/segment_voter.h"
#include "visloc/retrieval/triangulation_embedding.h"
#include "visloc/util/error.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace {

namespace fs = std::filesystem;

// FAISS's OpenMP regions crawl when the machine is oversubscribed (a parallel
// ctest run); these small problems need one thread. Process-wide, tests only.
const int kOneThread = [] {
  omp_set_num_threads(1);
  return 1;
}();

// Synthetic "scenes": each scene has its own set of prototype descriptors;
// an image of a scene draws descriptors near its prototypes (uint8, with
// COLMAP's scale: unit vectors × 512, clamped).
class SyntheticScenes {
 public:
  SyntheticScenes(int scenes, int prototypes_per_scene, uint64_t seed) : rng_(seed) {
    std::normal_distribution<float> g(0, 1);
    for (int s = 0; s < scenes; ++s) {
      std::vector<std::vector<float>> protos;
      for (int p = 0; p < prototypes_per_scene; ++p) {
        std::vector<float> v(kDescriptorDim);
        for (float& x : v) x = std::fabs(g(rng_)) + (g(rng_) > 1.0f ? 2.0f : 0.0f);
        protos.push_back(v);
      }
      scenes_.push_back(protos);
    }
  }
  DescriptorMatrix image(int scene, int count, float noise) {
    std::normal_distribution<float> g(0, 1);
    std::uniform_int_distribution<int> pick(0, static_cast<int>(scenes_[scene].size()) - 1);
    DescriptorMatrix d(static_cast<size_t>(count));
    for (int i = 0; i < count; ++i) {
      const auto& p = scenes_[scene][pick(rng_)];
      std::vector<float> v(kDescriptorDim);
      double n2 = 0;
      for (int t = 0; t < kDescriptorDim; ++t) {
        v[t] = std::max(0.0f, p[t] + noise * g(rng_));
        n2 += v[t] * v[t];
      }
      const float s = static_cast<float>(512.0 / std::sqrt(std::max(n2, 1e-12)));
      for (int t = 0; t < kDescriptorDim; ++t) d.row(i)[t] = static_cast<uint8_t>(std::min(255.0f, std::round(v[t] * s)));
    }
    return d;
  }

 private:
  std::mt19937_64 rng_;
  std::vector<std::vector<std::vector<float>>> scenes_;
};

float dot(const std::vector<float>& a, const std::vector<float>& b) {
  return std::inner_product(a.begin(), a.end(), b.begin(), 0.0f);
}

float norm(const std::vector<float>& a) { return std::sqrt(dot(a, a)); }

TriangulationEmbeddingOptions small_options(int output_dims = 0) {
  TriangulationEmbeddingOptions o;
  o.vocabulary_size = 4;
  o.output_dims = output_dims;
  o.kmeans_iterations = 10;
  return o;
}

struct Fixture {
  SyntheticScenes scenes{12, 40, 7};
  std::vector<DescriptorMatrix> images;
  std::vector<int> scene_of;
  Fixture() {
    for (int s = 0; s < 12; ++s)
      for (int v = 0; v < 3; ++v) {
        images.push_back(scenes.image(s, 150, 0.3f));
        scene_of.push_back(s);
      }
  }
  std::vector<const DescriptorMatrix*> pointers() const {
    std::vector<const DescriptorMatrix*> p;
    for (const auto& d : images) p.push_back(&d);
    return p;
  }
};

const Fixture& fixture() {
  static const Fixture f;
  return f;
}

const TriangulationEmbedding& full_embedding() {
  static const TriangulationEmbedding e = [] {
    auto p = fixture().pointers();
    return TriangulationEmbedding::train(p, small_options());
  }();
  return e;
}

TEST(TriangulationEmbedding, DimensionsAndNormalization) {
  const auto& e = full_embedding();
  EXPECT_EQ(e.vocabulary_size(), 4);
  EXPECT_EQ(e.dims(), 4 * 128);
  EXPECT_EQ(e.vlad_dims(), 4 * 128);
  const auto v = e.embed(fixture().images[0]);
  ASSERT_EQ(v.size(), 512u);
  EXPECT_NEAR(norm(v), 1.0f, 1e-5);
  const auto vl = e.vlad(fixture().images[0]);
  ASSERT_EQ(vl.size(), 512u);
  EXPECT_NEAR(norm(vl), 1.0f, 1e-5);
  // Eigenvalues sorted descending, retained variance 1 for full whitening.
  const auto ev = e.eigenvalues();
  for (size_t i = 1; i < ev.size(); ++i) EXPECT_GE(ev[i - 1], ev[i]);
  EXPECT_NEAR(e.train_stats().retained_variance, 1.0, 1e-3);
  // No descriptors: the zero vector.
  const auto z = e.embed(DescriptorMatrix());
  EXPECT_EQ(norm(z), 0.0f);

  auto p = fixture().pointers();
  const auto pca = TriangulationEmbedding::train(p, small_options(64));
  EXPECT_EQ(pca.dims(), 64);
  const auto w = pca.embed(fixture().images[3]);
  ASSERT_EQ(w.size(), 64u);
  EXPECT_NEAR(norm(w), 1.0f, 1e-5);
  EXPECT_LT(pca.train_stats().retained_variance, 1.0);
  EXPECT_GT(pca.train_stats().retained_variance, 0.0);
}

// Scalar reference of R(x) (double precision) for checking the optimized code.
std::vector<double> reference_residuals(const uint8_t* x, std::span<const float> centroids) {
  const int k = static_cast<int>(centroids.size()) / kDescriptorDim;
  std::vector<double> r(static_cast<size_t>(k) * kDescriptorDim);
  for (int j = 0; j < k; ++j) {
    double n2 = 0;
    for (int t = 0; t < kDescriptorDim; ++t) {
      const double d = x[t] / 512.0 - centroids[j * kDescriptorDim + t];
      r[j * kDescriptorDim + t] = d;
      n2 += d * d;
    }
    for (int t = 0; t < kDescriptorDim; ++t) r[j * kDescriptorDim + t] /= std::sqrt(n2);
  }
  return r;
}

TEST(TriangulationEmbedding, MatchesScalarReferenceAndWhitens) {
  auto o = small_options(16);
  o.power_law_alpha = 1.0;
  o.eigenvalue_floor = 1e-6;
  o.max_whitening_descriptors = 1 << 30;  // all descriptors: Σ is reproducible here
  auto p = fixture().pointers();
  const auto e = TriangulationEmbedding::train(p, o);
  const int in = e.input_dims(), out = e.dims();
  ASSERT_EQ(out, 16);
  // Mean and covariance of R over all descriptors.
  std::vector<double> mean(in, 0.0), cov(static_cast<size_t>(in) * in, 0.0);
  size_t n = 0;
  for (const auto& d : fixture().images)
    for (size_t i = 0; i < d.rows(); ++i, ++n) {
      const auto r = reference_residuals(d.row(i), e.centroids());
      for (int a = 0; a < in; ++a) mean[a] += r[a];
    }
  for (double& m : mean) m /= static_cast<double>(n);
  for (int a = 0; a < in; ++a) EXPECT_NEAR(e.mean()[a], mean[a], 1e-4);
  for (const auto& d : fixture().images)
    for (size_t i = 0; i < d.rows(); ++i) {
      auto r = reference_residuals(d.row(i), e.centroids());
      for (int a = 0; a < in; ++a) r[a] -= mean[a];
      for (int a = 0; a < in; ++a)
        for (int b = 0; b <= a; ++b) cov[static_cast<size_t>(a) * in + b] += r[a] * r[b];
    }
  // P Σ Pᵀ = I for the kept components (λ above the tiny floor).
  const auto P = e.projection();
  std::vector<double> ps(static_cast<size_t>(out) * in, 0.0);  // P Σ
  for (int r = 0; r < out; ++r)
    for (int a = 0; a < in; ++a) {
      double s = 0;
      for (int b = 0; b < in; ++b) {
        const double c = a >= b ? cov[static_cast<size_t>(a) * in + b] : cov[static_cast<size_t>(b) * in + a];
        s += P[static_cast<size_t>(r) * in + b] * c;
      }
      ps[static_cast<size_t>(r) * in + a] = s / static_cast<double>(n);
    }
  for (int r = 0; r < out; ++r)
    for (int c = 0; c < out; ++c) {
      double s = 0;
      for (int a = 0; a < in; ++a) s += ps[static_cast<size_t>(r) * in + a] * P[static_cast<size_t>(c) * in + a];
      EXPECT_NEAR(s, r == c ? 1.0 : 0.0, 2e-2) << r << "," << c;
    }
  // Sum pooling: normalize(P (Σ_x R(x) - n R0)), α = 1.
  const auto& img = fixture().images[7];
  std::vector<double> z(in, 0.0);
  for (size_t i = 0; i < img.rows(); ++i) {
    const auto r = reference_residuals(img.row(i), e.centroids());
    for (int a = 0; a < in; ++a) z[a] += r[a] - e.mean()[a];
  }
  std::vector<double> y(out, 0.0);
  double n2 = 0;
  for (int r = 0; r < out; ++r) {
    for (int a = 0; a < in; ++a) y[r] += P[static_cast<size_t>(r) * in + a] * z[a];
    n2 += y[r] * y[r];
  }
  const auto v = e.embed(img);
  for (int r = 0; r < out; ++r) EXPECT_NEAR(v[r], y[r] / std::sqrt(n2), 2e-3);
}

TEST(TriangulationEmbedding, NearDuplicateBeatsUnrelated) {
  const auto& e = full_embedding();
  const auto a = e.embed(fixture().images[0]);
  for (int other_scene = 1; other_scene < 12; ++other_scene) {
    const auto same = e.embed(fixture().images[1]);  // another view of scene 0
    const auto unrelated = e.embed(fixture().images[3 * other_scene]);
    EXPECT_GT(dot(a, same), dot(a, unrelated)) << "scene " << other_scene;
  }
  // The same with VLAD and with democratic pooling.
  auto o = small_options();
  o.pooling = EmbeddingPooling::kDemocratic;
  auto p = fixture().pointers();
  const auto demo = TriangulationEmbedding::train(p, o);
  const auto da = demo.embed(fixture().images[0]);
  EXPECT_NEAR(norm(da), 1.0f, 1e-5);
  EXPECT_GT(dot(da, demo.embed(fixture().images[2])), dot(da, demo.embed(fixture().images[10])));
  const auto va = e.vlad(fixture().images[0]);
  EXPECT_GT(dot(va, e.vlad(fixture().images[2])), dot(va, e.vlad(fixture().images[10])));
}

std::vector<float> embed_all(const TriangulationEmbedding& e) {
  std::vector<float> all;
  for (const auto& d : fixture().images) {
    const auto v = e.embed(d);
    all.insert(all.end(), v.begin(), v.end());
  }
  return all;
}

TEST(ImageIndex, ImageIsItsOwnNearestNeighbour) {
  const auto& e = full_embedding();
  const auto all = embed_all(e);
  const size_t n = fixture().images.size();
  std::vector<int64_t> ids(n);
  std::iota(ids.begin(), ids.end(), int64_t{100});
  for (auto type : {ImageIndexType::kFlat, ImageIndexType::kIvfPq}) {
    ImageIndexOptions o;
    o.type = type;
    o.pq_bytes = 16;
    const auto index = ImageIndex::build(all, ids, e.dims(), o);
    EXPECT_EQ(index.size(), n);
    int self = 0, same_scene_second = 0;
    for (size_t i = 0; i < n; ++i) {
      const auto r = index.search(std::span<const float>(all.data() + i * e.dims(), e.dims()), 3);
      ASSERT_EQ(r.size(), 3u);
      self += r[0].image == ids[i];
      same_scene_second += fixture().scene_of[r[1].image - 100] == fixture().scene_of[i];
      EXPECT_LE(r[0].distance, r[1].distance);
    }
    if (type == ImageIndexType::kFlat) {
      EXPECT_EQ(self, static_cast<int>(n));
      EXPECT_GE(same_scene_second, static_cast<int>(n) * 9 / 10);
    } else {
      // 36 images: PQ bits reduced to floor(log2 36) = 5, nlist to 1.
      EXPECT_EQ(index.effective_pq_bits(), 5);
      EXPECT_EQ(index.effective_nlist(), 1);
      EXPECT_GE(self, static_cast<int>(n) * 9 / 10);
      EXPECT_EQ(index.bytes_per_image(), static_cast<size_t>(16 * 5 + 7) / 8 + 8);
    }
  }
}

TEST(SegmentVoter, VotesOrderAndCap) {
  // 8 images; image i belongs to segment i/2, odd images also to the next.
  std::vector<std::vector<int32_t>> of_image;
  for (int i = 0; i < 8; ++i) {
    std::vector<int32_t> s{i / 2};
    if (i % 2 == 1) s.push_back(i / 2 + 1);
    of_image.push_back(s);
  }
  SegmentTable table(of_image);
  EXPECT_EQ(table.segment_count(), 5);
  SegmentVoterOptions o;
  o.top_images = 5;
  o.max_candidates = 2;
  o.weighting = VoteWeighting::kOnePerImage;
  SegmentVoter voter(table, o);
  // Ranked: 6 (seg 3), 1 (0,1), 3 (1,2), 7 (3,4), 0 (0), then 5 (beyond top 5).
  std::vector<ImageSearchResult> ranked{{6, 0}, {1, 0}, {3, 0}, {7, 0}, {0, 0}, {5, 0}};
  auto c = voter.candidates(ranked);
  ASSERT_EQ(c.size(), 2u);
  // Votes: seg0: 2 (ranks 1, 4), seg1: 2 (ranks 1, 2), seg3: 2 (ranks 0, 3), seg2: 1, seg4: 1.
  EXPECT_EQ(c[0].segment, 3);  // ties broken by best rank
  EXPECT_EQ(c[1].segment, 0);
  EXPECT_EQ(c[0].votes, 2.0f);
  // all_votes: every voted segment (5), the candidates first.
  const auto all = voter.all_votes(ranked);
  ASSERT_EQ(all.size(), 5u);
  EXPECT_EQ(all[0].segment, 3);
  EXPECT_EQ(all[1].segment, 0);
  EXPECT_EQ(all[3].votes, 1.0f);
  EXPECT_EQ(all[4].votes, 1.0f);
  o.max_candidates = 4;
  o.weighting = VoteWeighting::kReciprocalRank;
  SegmentVoter weighted(table, o);
  c = weighted.candidates(ranked);
  ASSERT_EQ(c.size(), 4u);
  EXPECT_EQ(c[0].segment, 3);  // 1 + 1/4
  EXPECT_EQ(c[1].segment, 1);  // 1/2 + 1/3
  EXPECT_EQ(c[2].segment, 0);  // 1/2 + 1/5
  EXPECT_EQ(c[3].segment, 2);  // 1/3
  // Only top_images count; padding (-1) ignored; unknown ids rejected.
  o.top_images = 1;
  SegmentVoter one(table, o);
  c = one.candidates(ranked);
  ASSERT_EQ(c.size(), 1u);
  EXPECT_EQ(c[0].segment, 3);
  std::vector<ImageSearchResult> padded{{-1, 0}, {2, 0}};
  EXPECT_EQ(voter.candidates(padded).size(), 1u);
  std::vector<ImageSearchResult> unknown{{8, 0}};
  EXPECT_THROW(voter.candidates(unknown), Error);
}

TEST(SegmentVoter, PlacemarkSegmentsOverlap) {
  std::vector<int> placemark;
  for (int p = 0; p < 20; ++p)
    for (int v = 0; v < 2; ++v) placemark.push_back(100 + 3 * p);  // any increasing ids
  const auto t = make_placemark_segments(placemark, {});
  // size 10, overlap 2: [0,10) [8,18) [16,20)
  EXPECT_EQ(t.segment_count(), 3);
  EXPECT_EQ(std::vector<int32_t>(t.segments(0).begin(), t.segments(0).end()), std::vector<int32_t>{0});
  EXPECT_EQ(std::vector<int32_t>(t.segments(2 * 8).begin(), t.segments(2 * 8).end()), (std::vector<int32_t>{0, 1}));
  EXPECT_EQ(std::vector<int32_t>(t.segments(2 * 9 + 1).begin(), t.segments(2 * 9 + 1).end()),
            (std::vector<int32_t>{0, 1}));
  EXPECT_EQ(std::vector<int32_t>(t.segments(2 * 10).begin(), t.segments(2 * 10).end()), std::vector<int32_t>{1});
  EXPECT_EQ(std::vector<int32_t>(t.segments(2 * 17).begin(), t.segments(2 * 17).end()), (std::vector<int32_t>{1, 2}));
  EXPECT_EQ(std::vector<int32_t>(t.segments(39).begin(), t.segments(39).end()), std::vector<int32_t>{2});
  // Exactly 10 placemarks: one segment.
  std::vector<int> ten(10);
  std::iota(ten.begin(), ten.end(), 0);
  EXPECT_EQ(make_placemark_segments(ten, {}).segment_count(), 1);
}

TEST(RetrievalTruth, NearestFacingImageDefinesCorrectSegments) {
  std::vector<ImagePlacement> map(4);
  map[0].center = {0, 0, 0};
  map[0].viewing_direction = Eigen::Vector3d(0, 0, 1);
  map[1].center = {1, 0, 0};
  map[1].viewing_direction = Eigen::Vector3d(0, 0, -1);  // faces away
  map[2].center = {3, 0, 0};
  map[2].viewing_direction = Eigen::Vector3d(0, 0, 1);
  map[3].center = {3.2, 0, 0};
  map[3].viewing_direction = Eigen::Vector3d(1, 0, 1);
  SegmentTable table(std::vector<std::vector<int32_t>>{{0}, {1}, {2}, {3, 4}});
  ImagePlacement q;
  q.center = {1.1, 0, 0};
  q.viewing_direction = Eigen::Vector3d(0, 0, 1);
  CorrectSegmentOptions o;
  EXPECT_EQ(correct_segments(q, map, table, o), std::vector<int32_t>{0});  // 1 faces away
  q.viewing_direction.reset();
  EXPECT_EQ(correct_segments(q, map, table, o), std::vector<int32_t>{1});
  q.center = {3.05, 0, 0};
  q.viewing_direction = Eigen::Vector3d(0, 0, 1);
  EXPECT_EQ(correct_segments(q, map, table, o), (std::vector<int32_t>{2, 3, 4}));  // tie within 0.5 m
  o.distance_tolerance_m = 0.0;
  EXPECT_EQ(correct_segments(q, map, table, o), std::vector<int32_t>{2});
}

fs::path temp_path(const std::string& name) {
  return unique_temp_path("visloc_retrieval_test_" + name);
}

void flip_byte(const fs::path& p, size_t offset) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(static_cast<std::streamoff>(offset));
  char c;
  f.read(&c, 1);
  c = static_cast<char>(c ^ 0x10);
  f.seekp(static_cast<std::streamoff>(offset));
  f.write(&c, 1);
}

TEST(TriangulationEmbedding, SaveLoadRoundTripAndCorruption) {
  const auto& e = full_embedding();
  const fs::path path = temp_path("emb.vltemb");
  e.save(path);
  const auto loaded = TriangulationEmbedding::load(path);
  EXPECT_EQ(loaded.dims(), e.dims());
  EXPECT_EQ(loaded.parameter_bytes(), e.parameter_bytes());
  EXPECT_EQ(loaded.embed(fixture().images[5]), e.embed(fixture().images[5]));
  EXPECT_EQ(loaded.vlad(fixture().images[5]), e.vlad(fixture().images[5]));
  const auto size = fs::file_size(path);
  // Bit flip inside the projection matrix.
  const fs::path flipped = temp_path("flipped.vltemb");
  fs::copy_file(path, flipped, fs::copy_options::overwrite_existing);
  flip_byte(flipped, size / 2);
  try {
    TriangulationEmbedding::load(flipped);
    ADD_FAILURE() << "corrupted file accepted";
  } catch (const Error& ex) {
    EXPECT_EQ(ex.code(), ErrorCode::kFormat) << ex.what();
  }
  // Truncated.
  fs::resize_file(path, size - 100);
  try {
    TriangulationEmbedding::load(path);
    ADD_FAILURE() << "truncated file accepted";
  } catch (const Error& ex) {
    EXPECT_EQ(ex.code(), ErrorCode::kFormat) << ex.what();
  }
  fs::remove(path);
  fs::remove(flipped);
}

TEST(ImageIndex, SaveLoadRoundTripAndCorruption) {
  const auto& e = full_embedding();
  const auto all = embed_all(e);
  const size_t n = fixture().images.size();
  std::vector<int64_t> ids(n);
  std::iota(ids.begin(), ids.end(), int64_t{0});
  for (auto type : {ImageIndexType::kFlat, ImageIndexType::kIvfPq}) {
    ImageIndexOptions o;
    o.type = type;
    o.pq_bytes = 32;
    const auto index = ImageIndex::build(all, ids, e.dims(), o);
    const fs::path path = temp_path("index.vlidx");
    index.save(path);
    const auto loaded = ImageIndex::load(path);
    EXPECT_EQ(loaded.size(), n);
    EXPECT_EQ(loaded.bytes_per_image(), index.bytes_per_image());
    EXPECT_EQ(loaded.fixed_bytes(), index.fixed_bytes());
    for (size_t i = 0; i < n; i += 5) {
      const std::span<const float> q(all.data() + i * e.dims(), e.dims());
      const auto a = index.search(q, 5), b = loaded.search(q, 5);
      ASSERT_EQ(a.size(), b.size());
      for (size_t j = 0; j < a.size(); ++j) {
        EXPECT_EQ(a[j].image, b[j].image);
        EXPECT_FLOAT_EQ(a[j].distance, b[j].distance);
      }
    }
    flip_byte(path, fs::file_size(path) - 200);
    EXPECT_THROW(ImageIndex::load(path), Error);
    fs::remove(path);
  }
}

TEST(RetrievalMap, BuildSaveLoadQuery) {
  auto p = fixture().pointers();
  std::vector<std::string> names;
  std::vector<int> placemark;
  for (size_t i = 0; i < p.size(); ++i) names.push_back("img" + std::to_string(i) + ".jpg"), placemark.push_back(int(i) / 3);
  ImageIndexOptions io;
  io.pq_bytes = 16;
  const auto map = RetrievalMap::build(p, names, make_placemark_segments(placemark, {4, 1}), small_options(64), io);
  EXPECT_EQ(map.segments().segment_count(), 4);  // 12 placemarks, stride 3: [0,4) [3,7) [6,10) [9,12)
  const fs::path dir = temp_path("map");
  map.save(dir);
  const auto loaded = RetrievalMap::load(dir);
  EXPECT_EQ(loaded.image_names(), names);
  EXPECT_EQ(loaded.segments().offsets(), map.segments().offsets());
  EXPECT_EQ(loaded.segments().segment_ids(), map.segments().segment_ids());
  SegmentVoterOptions vo;
  vo.top_images = 5;
  int top_scene_correct = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    const auto a = map.query(fixture().images[i], vo), b = loaded.query(fixture().images[i], vo);
    ASSERT_EQ(a.images.size(), b.images.size());
    for (size_t j = 0; j < a.images.size(); ++j) EXPECT_EQ(a.images[j].image, b.images[j].image);
    ASSERT_EQ(a.candidates.size(), b.candidates.size());
    EXPECT_LE(a.candidates.size(), 4u);
    top_scene_correct += fixture().scene_of[a.images[0].image] == fixture().scene_of[i];
  }
  EXPECT_GE(top_scene_correct, static_cast<int>(p.size()) * 9 / 10);
  // A META count that does not fit an integer (found by fuzzing: 1.6e102 was
  // converted with get<size_t>, undefined behaviour) is refused naming the field.
  for (const std::string count : {"1.61111e+102", "-3", "\"12\"", "2.5"}) {
    SectionFileWriter w(dir / "images.vlimg", "RIMG", kRetrievalImagesFileVersion);
    w.add_text("META", "{\"count\": " + count + ", \"segments\": 4}");
    w.add_text("NAME", "a");
    w.add_array<uint32_t>("SOFF", map.segments().offsets());
    w.add_array<int32_t>("SIDS", map.segments().segment_ids());
    w.commit();
    try {
      RetrievalMap::load(dir);
      ADD_FAILURE() << "count " << count << " accepted";
    } catch (const Error& ex) {
      EXPECT_EQ(ex.code(), ErrorCode::kFormat) << ex.what();
      EXPECT_NE(std::string(ex.what()).find("images.vlimg: field 'META.count'"), std::string::npos) << ex.what();
    }
  }
  map.save(dir);  // valid again
  // A map missing its index is rejected naming the file.
  fs::remove(dir / "index.vlidx");
  try {
    RetrievalMap::load(dir);
    ADD_FAILURE() << "incomplete map accepted";
  } catch (const Error& ex) {
    EXPECT_NE(std::string(ex.what()).find("index.vlidx"), std::string::npos) << ex.what();
  }
  fs::remove_all(dir);
}

template <typename F>
void expect_invalid(F&& f, const std::string& field) {
  try {
    f();
    ADD_FAILURE() << "accepted a bad " << field;
  } catch (const Error& ex) {
    EXPECT_EQ(ex.code(), ErrorCode::kInvalidArgument);
    EXPECT_NE(std::string(ex.what()).find(field), std::string::npos) << ex.what();
  }
}

TEST(RetrievalOptions, BadOptionsNameTheField) {
  expect_invalid([] { TriangulationEmbeddingOptions o; o.vocabulary_size = 0; o.validate(); }, "vocabulary_size");
  expect_invalid([] { TriangulationEmbeddingOptions o; o.output_dims = 5000; o.validate(); }, "output_dims");
  expect_invalid([] { TriangulationEmbeddingOptions o; o.power_law_alpha = 0; o.validate(); }, "power_law_alpha");
  expect_invalid([] { TriangulationEmbeddingOptions o; o.eigenvalue_floor = -1; o.validate(); }, "eigenvalue_floor");
  expect_invalid([] { ImageIndexOptions o; o.nprobe = 0; o.validate(); }, "nprobe");
  expect_invalid([] { ImageIndexOptions o; o.pq_bits = 17; o.validate(); }, "pq_bits");
  expect_invalid([] { SegmentVoterOptions o; o.max_candidates = 0; o.validate(); }, "max_candidates");
  expect_invalid([] { SegmentVoterOptions o; o.top_images = 0; o.validate(); }, "top_images");
  expect_invalid([] { SegmentRuleOptions o; o.overlap = 10; o.validate(); }, "overlap");
  expect_invalid([] { CorrectSegmentOptions o; o.max_view_angle_deg = 0; o.validate(); }, "max_view_angle_deg");
  // pq_bytes must divide the dimension.
  const auto all = embed_all(full_embedding());
  std::vector<int64_t> ids(fixture().images.size());
  std::iota(ids.begin(), ids.end(), int64_t{0});
  expect_invalid([&] { ImageIndexOptions o; o.pq_bytes = 100; ImageIndex::build(all, ids, 512, o); }, "pq_bytes");
  // Too few descriptors for the vocabulary.
  std::vector<const DescriptorMatrix*> one{&fixture().images[0]};
  expect_invalid([&] { TriangulationEmbeddingOptions o; TriangulationEmbedding::train(one, o); }, "descriptors");
}

}  // namespace
}  // namespace visloc
