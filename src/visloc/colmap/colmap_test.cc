#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/colmap/colmap_database.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(ColmapDatabase, PairIdIsSymmetric) {
  EXPECT_EQ(colmap_pair_id(1, 2), 2147483647LL + 2);
  EXPECT_EQ(colmap_pair_id(2, 1), colmap_pair_id(1, 2));
}

TEST(ColmapDatabase, RejectsMissingAndNonDatabaseFiles) {
  try {
    ColmapDatabase db("/nonexistent/database.db");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/database.db"), std::string::npos);
  }
  fs::path p = unique_temp_path("visloc_colmap_test_not_db.db");
  write_file_atomic(p, "hello, I am not SQLite");
  try {
    ColmapDatabase db(p);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(p.string()), std::string::npos) << e.what();
  }
}

TEST(ColmapDatabase, ReadsStrechaFountain) {
  fs::path path = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11" / "colmap" / "database.db";
  if (!fs::exists(path)) GTEST_SKIP() << "shared data absent: " << path;
  ColmapDatabase db(path);
  auto images = db.images();
  ASSERT_EQ(images.size(), 11u);
  auto cams = db.cameras();
  ASSERT_GE(cams.size(), 1u);
  EXPECT_EQ(cams[0].width, 1536);
  auto img = db.image_by_name("0001.jpg");
  ASSERT_TRUE(img.has_value());
  FeatureSet f = db.features(img->image_id);
  EXPECT_GT(f.size(), 1000u);
  EXPECT_EQ(f.image, "0001.jpg");
  for (size_t i = 0; i < f.size(); i += 97) {
    EXPECT_GT(f.keypoints[i].x, 0.0f);
    EXPECT_LT(f.keypoints[i].x, 1536.0f);
    EXPECT_GT(f.keypoints[i].scale, 0.0f);
  }
  auto img2 = db.image_by_name("0002.jpg");
  auto m12 = db.verified_matches(img->image_id, img2->image_id);
  auto m21 = db.verified_matches(img2->image_id, img->image_id);
  ASSERT_GT(m12.size(), 100u);
  ASSERT_EQ(m12.size(), m21.size());
  EXPECT_EQ(m12[0].first, m21[0].second);
  auto f2 = db.features(img2->image_id);
  for (auto [a, b] : m12) {
    ASSERT_LT(a, f.size());
    ASSERT_LT(b, f2.size());
  }
}
