#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <numeric>
#include <random>

#include "visloc/features/feature_set.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/section_file.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

// Random blobs on a gradient: plenty of SIFT extrema, deterministic.
GrayImage blob_image(int w, int h, int seed = 1) {
  GrayImage img{w, h, std::vector<uint8_t>(size_t(w) * h)};
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(0, w), uy(0, h), ur(2, 12), ua(-90, 90);
  std::vector<std::array<double, 4>> blobs(300);
  for (auto& b : blobs) b = {ux(rng), uy(rng), ur(rng), ua(rng)};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double v = 80 + 40.0 * x / w;
      for (const auto& b : blobs) {
        double d2 = (x - b[0]) * (x - b[0]) + (y - b[1]) * (y - b[1]);
        if (d2 < 9 * b[2] * b[2]) v += b[3] * std::exp(-d2 / (2 * b[2] * b[2]));
      }
      img.pixels[size_t(y) * w + x] = static_cast<uint8_t>(std::clamp(v, 0.0, 255.0));
    }
  return img;
}

GrayImage upsample2(const GrayImage& in) {
  GrayImage out{in.width * 2, in.height * 2, std::vector<uint8_t>(size_t(in.width) * in.height * 4)};
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) out.pixels[size_t(y) * out.width + x] = in.pixels[size_t(y / 2) * in.width + x / 2];
  return out;
}

}  // namespace

TEST(SiftToUint8, RootSiftMatchesColmapScaling) {
  float d[kDescriptorDim] = {};
  d[0] = 9;
  d[1] = 16;
  d[2] = 75;  // L1 = 100 → sqrt(0.09, 0.16, 0.75) = 0.3, 0.4, 0.866
  uint8_t out[kDescriptorDim];
  sift_to_uint8(d, true, out);
  EXPECT_EQ(out[0], 154);  // round(512 * 0.3) = 153.6
  EXPECT_EQ(out[1], 205);  // round(512 * 0.4) = 204.8
  EXPECT_EQ(out[2], 255);  // 443 clamped
  EXPECT_EQ(out[3], 0);
  sift_to_uint8(d, false, out);  // L2: 9/77.11 = 0.1167 → 60
  EXPECT_EQ(out[0], static_cast<uint8_t>(std::round(512 * 9 / std::sqrt(81.0 + 256 + 5625))));
}

TEST(SiftExtractor, DeterministicAndInsideImage) {
  GrayImage img = blob_image(400, 300);
  SiftOptions o;
  SiftExtractor sift(o);
  FeatureSet a = sift.extract(img);
  FeatureSet b = sift.extract(img);
  ASSERT_GT(a.size(), 50u);
  a.check_consistent();
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.keypoints.data(), b.keypoints.data(), a.size() * sizeof(Keypoint)));
  EXPECT_EQ(0, std::memcmp(a.descriptors.data(), b.descriptors.data(), a.descriptors.size_bytes()));
  for (const auto& k : a.keypoints) {
    EXPECT_GE(k.x, 0);
    EXPECT_LE(k.x, 400);
    EXPECT_GE(k.y, 0);
    EXPECT_LE(k.y, 300);
    EXPECT_GT(k.scale, 0);
  }
  o.max_features = 20;
  FeatureSet c = SiftExtractor(o).extract(img);
  EXPECT_EQ(c.size(), 20u);
}

TEST(SiftExtractor, DownscaledKeypointsInOriginalPixels) {
  GrayImage small = blob_image(300, 200, 7);
  GrayImage big = upsample2(small);
  SiftOptions o;
  o.max_image_side = 300;  // the big image is downscaled back to 300×200
  FeatureSet fs_small = SiftExtractor(o).extract(small);
  FeatureSet fs_big = SiftExtractor(o).extract(big);
  ASSERT_GT(fs_small.size(), 30u);
  // Most keypoints of the small image reappear at twice their coordinates.
  int found = 0;
  for (const auto& k : fs_small.keypoints) {
    for (const auto& kb : fs_big.keypoints)
      if (std::hypot(kb.x - 2 * k.x, kb.y - 2 * k.y) < 2.0) {
        ++found;
        break;
      }
  }
  EXPECT_GT(found, 0.7 * fs_small.size()) << found << " of " << fs_small.size();
}

// Pixel convention: a symmetric blob centred at (cx, cy), where the centre of
// the top-left pixel is (0.5, 0.5), yields a keypoint at (cx, cy). OpenCV's
// SIFT reports positions 0.25 px too far right and down (its first octave is
// upsampled with a half-pixel shift); the extractor must correct it.
TEST(SiftExtractor, BlobCentreInColmapPixelConvention) {
  const int w = 320, h = 240;
  struct Blob { double x, y; };
  std::vector<Blob> blobs;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> frac(0, 1);
  for (int gy = 0; gy < 4; ++gy)
    for (int gx = 0; gx < 5; ++gx) blobs.push_back({40 + 60.0 * gx + frac(rng), 40 + 55.0 * gy + frac(rng)});
  GrayImage img{w, h, std::vector<uint8_t>(size_t(w) * h)};
  const double r = 3.0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double v = 40;
      for (const auto& b : blobs) {
        const double dx = x + 0.5 - b.x, dy = y + 0.5 - b.y;
        v += 180 * std::exp(-(dx * dx + dy * dy) / (2 * r * r));
      }
      img.pixels[size_t(y) * w + x] = static_cast<uint8_t>(std::clamp(std::round(v), 0.0, 255.0));
    }
  FeatureSet f = SiftExtractor().extract(img);
  std::vector<double> ex, ey;
  for (const auto& b : blobs) {
    const Keypoint* best = nullptr;
    for (const auto& k : f.keypoints)
      if (std::hypot(k.x - b.x, k.y - b.y) < 2 && (!best || std::abs(k.scale - r) < std::abs(best->scale - r))) best = &k;
    if (best) {
      ex.push_back(best->x - b.x);
      ey.push_back(best->y - b.y);
    }
  }
  ASSERT_GE(ex.size(), 15u) << "blobs found: " << ex.size() << " of " << blobs.size();
  const double mx = std::accumulate(ex.begin(), ex.end(), 0.0) / ex.size();
  const double my = std::accumulate(ey.begin(), ey.end(), 0.0) / ey.size();
  EXPECT_NEAR(mx, 0.0, 0.08);
  EXPECT_NEAR(my, 0.0, 0.08);
}

TEST(SiftOptions, ValidateNamesField) {
  SiftOptions o;
  o.max_features = 0;
  try {
    o.validate();
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("max_features"), std::string::npos);
  }
  o = {};
  o.contrast_threshold = 2;
  EXPECT_THROW(SiftExtractor{o}, Error);
}

TEST(FeatureFile, RoundTripAndTruncation) {
  FeatureSet f = SiftExtractor().extract(blob_image(200, 160));
  f.image = "blobs.png";
  fs::path p = unique_temp_path("visloc_features_test.vlfeat");
  write_feature_file(p, f);
  FeatureSet g = read_feature_file(p);
  EXPECT_EQ(g.image, "blobs.png");
  EXPECT_EQ(g.image_width, 200);
  ASSERT_EQ(g.size(), f.size());
  EXPECT_EQ(0, std::memcmp(g.keypoints.data(), f.keypoints.data(), f.size() * sizeof(Keypoint)));
  EXPECT_EQ(0, std::memcmp(g.descriptors.data(), f.descriptors.data(), f.descriptors.size_bytes()));
  EXPECT_FALSE(g.extractor.empty());
  std::string bytes = read_file(p);
  write_file_atomic(p, bytes.substr(0, bytes.size() - 100));
  EXPECT_THROW(read_feature_file(p), Error);
}

// Found by fuzzing: without a count in META, a DESC section shorter than
// 128 bytes per keypoint was read past its end. The same with a META
// dimension that is not an integer.
TEST(FeatureFile, SectionsThatDisagreeAreRefused) {
  const fs::path p = unique_temp_path("visloc_features_short_desc.vlfeat");
  auto write = [&](const std::string& meta, size_t keypoints, size_t desc_bytes) {
    SectionFileWriter w(p, "FEAT", kFeatureFileVersion);
    w.add_text("META", meta);
    const std::vector<Keypoint> k(keypoints);
    const std::vector<uint8_t> d(desc_bytes, 7);
    w.add("KPTS", k.data(), k.size() * sizeof(Keypoint));
    w.add("DESC", d.data(), d.size());
    w.commit();
  };
  const std::string meta = R"({"image": "a.png", "width": 64, "height": 48, "extractor": null})";
  write(meta, 3, 3 * kDescriptorDim);
  EXPECT_EQ(read_feature_file(p).size(), 3u);
  write(meta, 3, 2 * kDescriptorDim);
  EXPECT_NE(error_of([&] { read_feature_file(p); }).find("DESC holds 256 bytes for 3 keypoints"), std::string::npos);
  write(R"({"image": "a.png", "width": 1e73, "height": 48, "extractor": null})", 1, kDescriptorDim);
  EXPECT_NE(error_of([&] { read_feature_file(p); }).find(p.string()), std::string::npos);
  fs::remove(p);
}

TEST(SiftExtractor, RealPhoto) {
  fs::path img = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11" / "images" / "0000.jpg";
  if (!fs::exists(img)) GTEST_SKIP() << "shared data absent: " << img;
  SiftOptions o;
  o.max_image_side = 1024;
  ImageMetadata m;
  FeatureSet f = SiftExtractor(o).extract_file(img, &m);
  EXPECT_EQ(f.image, "0000.jpg");
  EXPECT_EQ(f.image_width, 1536);
  EXPECT_GT(f.size(), 2000u);
  float max_x = 0;
  for (const auto& k : f.keypoints) max_x = std::max(max_x, k.x);
  EXPECT_GT(max_x, 1400.f);  // coordinates in the original 1536-wide frame
}
