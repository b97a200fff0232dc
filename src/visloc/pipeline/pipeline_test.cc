#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/colmap/colmap_database.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map/colmap_import.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(PaperSetting, ParsesAndRejects) {
  EXPECT_EQ(parse_paper_setting("3+"), PaperSetting::k3Plus);
  EXPECT_EQ(to_string(parse_paper_setting("2")), "2");
  EXPECT_THROW(parse_paper_setting("4"), Error);
}

TEST(Localizer, MissingMapIsAClearError) {
  try {
    Localizer l("/nonexistent/map");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/map"), std::string::npos) << e.what();
  }
}

// Real photos: fountain-P11 imported with its held-out queries removed; the
// queries' COLMAP features are localized against it and compared with the
// SfM reference poses kept by the import.
TEST(Localizer, LocalizesHeldOutFountainImages) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "database.db")) GTEST_SKIP() << "shared data absent: " << scene;
  const fs::path map_dir = fs::temp_directory_path() / "visloc_pipeline_test_fountain";
  fs::remove_all(map_dir);
  ColmapImportOptions io;
  io.holdout_images = read_name_list(scene / "queries.txt");
  io.itq.iterations = 10;
  io.pq.max_training = 20000;
  io.pq.iterations = 10;
  import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", map_dir, io);
  std::map<std::string, CameraPose> truth;
  for (const auto& p : read_pose_list(map_dir / "holdout.txt")) truth[p.name] = p.cam_from_world;
  ASSERT_FALSE(truth.empty());

  ColmapDatabase db(scene / "colmap" / "database.db");
  const auto cams = db.cameras();
  ASSERT_FALSE(cams.empty());
  PinholeCamera cam = PinholeCamera::centered(static_cast<int>(cams[0].width), static_cast<int>(cams[0].height));
  // PINHOLE fx fy cx cy
  cam.focal = 0.5 * (cams[0].params[0] + cams[0].params[1]);
  cam.cx = cams[0].params[2];
  cam.cy = cams[0].params[3];
  cam.has_focal = true;

  for (PaperSetting setting : {PaperSetting::k1, PaperSetting::k3Plus}) {
    LocalizerOptions o;
    o.setting = setting;
    Localizer loc(map_dir, o);
    EXPECT_FALSE(loc.has_retrieval());
    for (const auto& [name, pose] : truth) {
      auto img = db.image_by_name(name);
      ASSERT_TRUE(img.has_value());
      LocalizationResult r = loc.localize_features(db.features(img->image_id), cam);
      EXPECT_TRUE(r.registered) << name << " setting " << to_string(setting);
      EXPECT_GE(r.inliers, 12u) << name;
      EXPECT_LT(position_error(r.cam_from_segment, pose), 0.10) << name << " setting " << to_string(setting);
      EXPECT_LT(rotation_error_deg(r.cam_from_segment, pose), 1.0) << name;
      nlohmann::json j = to_json(r);
      EXPECT_EQ(j["q_wxyz"].size(), 4u);
      EXPECT_FALSE(j.contains("center_enu"));  // an imported model is not geo-registered
    }
    // Unknown focal: DLT estimates it.
    PinholeCamera uncal = cam;
    uncal.has_focal = false;
    const auto& [name, pose] = *truth.begin();
    LocalizationResult r = loc.localize_features(db.features(db.image_by_name(name)->image_id), uncal);
    EXPECT_TRUE(r.registered) << name;
    EXPECT_NEAR(r.focal_px, cam.focal, 0.02 * cam.focal);
  }
}
