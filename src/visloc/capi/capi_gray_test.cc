// The C API's in-memory pixel path and concurrent calls on one handle, on
// fountain-P11 held-out photos (decoding JPEG is easier from C++). The map is
// imported by the ctest fixture capi.import_fountain_map.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "visloc/capi/visloc.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"

namespace fs = std::filesystem;

namespace {

const fs::path kScene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
const fs::path kMap = VISLOC_CAPI_TEST_MAP_DIR;

class CapiFountain : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kScene / "images")) GTEST_SKIP() << "shared data absent: " << kScene;
    if (!fs::exists(kMap / "manifest.json"))
      GTEST_SKIP() << "no map at " << kMap << " (the ctest fixture capi.import_fountain_map imports it)";
    for (const auto& p : visloc::read_pose_list(kScene / "truth.txt")) truth_[p.name] = p.cam_from_world.center();
    ASSERT_TRUE(read_pinhole()) << "no PINHOLE camera in " << kScene / "colmap" / "sparse" / "cameras.txt";
    visloc_options o;
    visloc_options_init(&o);
    o.max_features = 16384;
    char error[256];
    ASSERT_EQ(visloc_localizer_open(kMap.c_str(), &o, &loc_, error, sizeof(error)), VISLOC_OK) << error;
  }
  void TearDown() override { visloc_localizer_close(loc_); }

  // PINHOLE fx fy cx cy from the model's cameras.txt (one camera).
  bool read_pinhole() {
    std::ifstream in(kScene / "colmap" / "sparse" / "cameras.txt");
    std::string line, model;
    while (std::getline(in, line)) {
      if (line.empty() || line[0] == '#') continue;
      std::istringstream s(line);
      int id, w, h;
      if (s >> id >> model >> w >> h >> k_.fx >> k_.fy >> k_.cx >> k_.cy && model == "PINHOLE") return true;
    }
    return false;
  }

  double center_error(const visloc_result& r, const std::string& name) {
    const Eigen::Vector3d c(r.center[0], r.center[1], r.center[2]);
    return (c - truth_.at(name)).norm();
  }

  visloc_localizer* loc_ = nullptr;
  visloc_intrinsics k_{};
  std::map<std::string, Eigen::Vector3d> truth_;
};

}  // namespace

// Pixels in a buffer whose rows are padded (a camera's row stride) give
// exactly the result of the file.
TEST_F(CapiFountain, GrayPixelsWithRowStrideMatchTheFile) {
  const fs::path image = kScene / "images" / "0002.jpg";
  const visloc::GrayImage gray = visloc::read_gray_image(image);
  const int stride = gray.width + 37;
  std::vector<uint8_t> buffer(static_cast<size_t>(stride) * gray.height, 255);  // padding: white
  for (int y = 0; y < gray.height; ++y) std::copy_n(gray.row(y), gray.width, buffer.data() + size_t(y) * stride);

  visloc_result from_pixels, from_file;
  ASSERT_EQ(visloc_localize_gray(loc_, buffer.data(), gray.width, gray.height, stride, &k_, &from_pixels), VISLOC_OK)
      << from_pixels.error;
  ASSERT_EQ(visloc_localize_file(loc_, image.c_str(), &k_, &from_file), VISLOC_OK) << from_file.error;
  EXPECT_TRUE(from_pixels.registered);
  EXPECT_LT(center_error(from_pixels, "0002.jpg"), 0.25);
  EXPECT_EQ(from_pixels.features, from_file.features);
  EXPECT_EQ(from_pixels.inliers, from_file.inliers);
  for (int i = 0; i < 3; ++i) EXPECT_DOUBLE_EQ(from_pixels.center[i], from_file.center[i]);
  for (int i = 0; i < 4; ++i) EXPECT_DOUBLE_EQ(from_pixels.rotation_wxyz[i], from_file.rotation_wxyz[i]);
  EXPECT_FALSE(from_pixels.focal_estimated);
}

// Two threads on one handle: one calibrated, one with the focal length
// estimated (no intrinsics, no EXIF in these files).
TEST_F(CapiFountain, ConcurrentCallsOnOneHandle) {
  visloc_result calibrated, uncalibrated;
  visloc_status s1 = VISLOC_INTERNAL_ERROR, s2 = VISLOC_INTERNAL_ERROR;
  const std::string a = (kScene / "images" / "0006.jpg").string(), b = (kScene / "images" / "0010.jpg").string();
  std::thread t1([&] { s1 = visloc_localize_file(loc_, a.c_str(), &k_, &calibrated); });
  std::thread t2([&] { s2 = visloc_localize_file(loc_, b.c_str(), nullptr, &uncalibrated); });
  t1.join();
  t2.join();
  ASSERT_EQ(s1, VISLOC_OK) << calibrated.error;
  ASSERT_EQ(s2, VISLOC_OK) << uncalibrated.error;
  EXPECT_TRUE(calibrated.registered);
  EXPECT_LT(center_error(calibrated, "0006.jpg"), 0.25);
  EXPECT_TRUE(uncalibrated.registered);
  EXPECT_TRUE(uncalibrated.focal_estimated);
  EXPECT_NEAR(uncalibrated.focal_px, 0.5 * (k_.fx + k_.fy), 0.05 * k_.fx);
  EXPECT_LT(center_error(uncalibrated, "0010.jpg"), 0.5);
}
