#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/geo/gps_csv.h"
#include "visloc/image/image_io.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_path(const std::string& name) {
  return unique_temp_path("visloc_image_test_" + name);
}

}  // namespace

TEST(ImageIo, PngRoundTripGray) {
  const int w = 37, h = 21;
  std::vector<uint8_t> px(w * h);
  for (int i = 0; i < w * h; ++i) px[i] = static_cast<uint8_t>(i * 7);
  fs::path p = temp_path("rt.png");
  write_image(p, w, h, 1, px.data());
  ImageMetadata m;
  GrayImage g = read_gray_image(p, {}, &m);
  EXPECT_EQ(g.width, w);
  EXPECT_EQ(g.height, h);
  EXPECT_EQ(m.width, w);
  EXPECT_EQ(g.pixels, px);
  EXPECT_FALSE(m.focal_px().has_value());
  EXPECT_FALSE(m.gps.has_value());
}

TEST(ImageIo, RefusesOverPixelLimitBeforeDecoding) {
  std::vector<uint8_t> px(100 * 50, 128);
  fs::path p = temp_path("big.png");
  write_image(p, 100, 50, 1, px.data());
  ImageReadOptions o;
  o.max_pixels = 4999;
  std::string msg = error_of([&] { read_gray_image(p, o); });
  EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("exceeds the limit"), std::string::npos) << msg;
  o.max_pixels = 5000;
  EXPECT_NO_THROW(read_gray_image(p, o));
}

TEST(ImageIo, RefusesNonImagesAndMissingFiles) {
  fs::path p = temp_path("not_an_image.jpg");
  write_file_atomic(p, "this is plain text, not a JPEG\n");
  std::string msg = error_of([&] { read_gray_image(p); });
  EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("not a"), std::string::npos) << msg;
  msg = error_of([&] { read_image_metadata(temp_path("missing.png")); });
  EXPECT_NE(msg.find("missing.png"), std::string::npos) << msg;
  // A truncated JPEG: valid header, no pixels.
  fs::path t = temp_path("truncated.jpg");
  std::vector<uint8_t> px(64 * 64, 200);
  write_image(t, 64, 64, 1, px.data());
  std::string jpg = read_file(t);
  write_file_atomic(t, jpg.substr(0, jpg.size() / 3));
  EXPECT_THROW(read_gray_image(t), Error);
}

// Real phone photos: EXIF GPS must agree with the published CSV, focal 4.3 mm.
TEST(ImageIo, LundExifGpsAndFocal) {
  fs::path dir = fs::path(VISLOC_SHARED_DATA_DIR) / "opensfm-lund";
  if (!fs::exists(dir / "gps.csv")) GTEST_SKIP() << "shared data absent: " << dir;
  auto records = read_gps_csv(dir / "gps.csv");
  int checked = 0;
  for (const auto& r : records) {
    ImageMetadata m = read_image_metadata(dir / "images" / r.image);
    EXPECT_EQ(m.width, 1024);
    EXPECT_EQ(m.height, 768);
    ASSERT_TRUE(m.focal_mm.has_value()) << r.image;
    EXPECT_NEAR(*m.focal_mm, 4.3, 1e-6);
    ASSERT_TRUE(m.gps.has_value()) << r.image;
    EXPECT_NEAR(m.gps->lat, r.position.lat, 1e-6) << r.image;
    EXPECT_NEAR(m.gps->lon, r.position.lon, 1e-6) << r.image;
    EXPECT_NEAR(m.gps->alt, r.position.alt, 0.01) << r.image;
    ++checked;
  }
  EXPECT_EQ(checked, 29);
}
