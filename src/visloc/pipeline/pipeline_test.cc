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

#include "visloc/map/map_builder.h"
#include "visloc/sfm/process.h"
#include "visloc/synth/city_writer.h"

// The whole system on a small synthetic street: render, build a map with
// COLMAP from the known poses, localize queries from other cameras. Skips
// when the colmap binary is absent.
TEST(Localizer, EndToEndOnSyntheticStreet) {
  if (!program_exists("colmap")) GTEST_SKIP() << "colmap is not installed";
  const fs::path dir = fs::temp_directory_path() / "visloc_pipeline_test_city";
  fs::remove_all(dir);
  synth::CityOptions city;
  city.layout.road_length_m = 60;
  city.views.headings = 8;
  city.views.elevations_deg = {10};
  city.views.width = city.views.height = 400;
  city.queries.count = 4;
  city.queries.fov_min_deg = 60;
  city.queries.fov_max_deg = 70;
  city.queries.resolutions = {{640, 480}};
  city.queries.pitch_min_deg = 0;
  city.queries.pitch_max_deg = 10;
  city.queries.roll_max_deg = 0;
  city.queries.exposure_min = city.queries.exposure_max = 1.0;
  city.queries.gamma_min = city.queries.gamma_max = 1.0;
  city.queries.blur_max_px = 0;
  city.queries.noise_max = 0;
  city.queries.cars_max = city.queries.trees_max = 0;
  city.queries.side_view_probability = 1.0;
  city.jobs = 2;
  synth::write_city(city, dir / "city");

  MapBuildOptions mb;
  mb.images_dir = dir / "city" / "images";
  mb.gps_csv = dir / "city" / "gps.csv";
  mb.poses = PoseSource::kKnown;
  mb.known_poses = dir / "city" / "sparse";
  mb.jobs = 2;
  mb.itq.iterations = 10;
  mb.pq.iterations = 10;
  mb.pq_training_descriptors = 20000;
  mb.build_retrieval = false;
  mb.exhaustive_max_images = 0;  // pairs of overlapping views (the known-pose path)
  MapBuildResult built = build_map(dir / "map", mb);
  ASSERT_EQ(built.failed(), 0u) << built.segments[0].error;
  ASSERT_GE(built.segments.size(), 1u);
  EXPECT_GT(built.segments[0].points, 500u);
  EXPECT_LT(built.segments[0].registration_max_m, 0.01);  // known poses are ENU exactly
  // A second run reuses the finished segments.
  MapBuildResult again = build_map(dir / "map", mb);
  EXPECT_TRUE(again.segments[0].reused);

  std::map<std::string, CameraPose> truth;
  for (const auto& p : read_pose_list(dir / "city" / "queries" / "truth.txt")) truth[p.name] = p.cam_from_world;
  std::map<std::string, PinholeCamera> cams;
  for (const auto& c : read_intrinsics_list(dir / "city" / "queries" / "intrinsics.txt")) cams[c.name] = c.camera;
  Localizer loc(dir / "map");
  int accurate = 0;
  for (const auto& [name, pose] : truth) {
    LocalizationResult r = loc.localize_file(dir / "city" / "queries" / "images" / name, cams.at(name));
    EXPECT_TRUE(r.error.empty()) << r.error;
    if (!r.registered) continue;
    const double err = position_error(r.cam_from_segment, pose);
    EXPECT_LT(err, 0.5) << name << " registered with " << r.inliers << " inliers but " << err << " m off";
    // Geo-registration: the WGS84 position, expressed in the city's ENU frame
    // (the map's own ENU origin is its first image), is the true centre.
    ASSERT_TRUE(r.position.has_value());
    EXPECT_LT((EnuFrame(city.origin).to_enu(*r.position) - pose.center()).norm(), 0.5);
    accurate += err < 0.5;
  }
  EXPECT_GE(accurate, 2) << "of " << truth.size() << " queries";
}
