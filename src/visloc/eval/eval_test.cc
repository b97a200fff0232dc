#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/eval/evaluation.h"
#include "visloc/eval/evaluation_run.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(Evaluation, ErrorsRatesAndReportFiles) {
  std::map<std::string, QueryTruth> truth;
  std::vector<LocalizationResult> results;
  for (int i = 0; i < 4; ++i) {
    const std::string name = "q" + std::to_string(i) + ".jpg";
    CameraPose t = CameraPose::from_world_from_cam(Eigen::Matrix3d::Identity(), Eigen::Vector3d(i, 0, 0));
    truth[name].cam_from_world = t;
    LocalizationResult r;
    r.image = name;
    r.registered = i < 3;
    r.segment = r.registered ? 0 : -1;
    // Estimates off by i × 0.2 m along y.
    r.cam_from_segment = CameraPose::from_world_from_cam(Eigen::Matrix3d::Identity(), Eigen::Vector3d(i, 0.2 * i, 0));
    r.times.total = 10 + i;
    r.times.features = 4;
    results.push_back(r);
  }
  EvaluationReport rep = evaluate(results, truth);
  EXPECT_EQ(rep.queries, 4u);
  EXPECT_EQ(rep.registered, 3u);
  nlohmann::json j = rep.to_json(results, {{"map", "test"}});
  EXPECT_NEAR(j["position_error_m"]["median"].get<double>(), 0.2, 1e-9);
  EXPECT_EQ(j["count_under_m"]["0.25"].get<int>(), 2);
  EXPECT_NEAR(j["recall"]["0.25m_2deg"].get<double>(), 0.5, 1e-12);
  EXPECT_NEAR(j["recall"]["5m_10deg"].get<double>(), 0.75, 1e-12);
  EXPECT_EQ(j["map"], "test");
  fs::path dir = unique_temp_path("visloc_eval_test_report");
  fs::remove_all(dir);
  write_report(dir, rep, results, {});
  for (const char* f : {"report.json", "report.md", "error_curve.svg", "error_curve.png", "top_view.svg", "top_view.png"})
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  EXPECT_NE(read_file(dir / "report.md").find("| 4 | 3 |"), std::string::npos) << read_file(dir / "report.md");
}

// Protocols on real photos: fountain-P11 (skipped without ../shared/data).
#include "visloc/eval/protocols.h"
#include "visloc/colmap/colmap_database.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/sfm/process.h"

namespace {
fs::path fountain_scene() { return fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11"; }
ColmapImportOptions fast_import() {
  ColmapImportOptions io;
  io.itq.iterations = 10;
  io.pq.max_training = 20000;
  io.pq.iterations = 10;
  return io;
}
}  // namespace

TEST(Protocols, ParsesQueryFeatureSource) {
  EXPECT_EQ(parse_query_feature_source("images"), QueryFeatureSource::kImages);
  EXPECT_EQ(parse_query_feature_source("database"), QueryFeatureSource::kDatabase);
  EXPECT_THROW(parse_query_feature_source("keys"), Error);
}

TEST(Protocols, LeaveOneOutWithDatabaseFeatures) {
  const fs::path scene = fountain_scene();
  if (!fs::exists(scene / "colmap" / "database.db")) GTEST_SKIP() << "shared data absent: " << scene;
  LeaveOneOutOptions o;
  o.import = fast_import();
  o.features = QueryFeatureSource::kDatabase;
  o.images = {"0000.jpg", "0005.jpg"};
  o.work_dir = unique_temp_path("visloc_eval_test_loo");
  size_t progress_calls = 0;
  o.progress = [&](size_t done, size_t total) {
    ++progress_calls;
    EXPECT_EQ(total, 2u);
    EXPECT_LE(done, total);
  };
  const LeaveOneOutResult r = run_leave_one_out(scene / "colmap" / "sparse", scene / "colmap" / "database.db", o);
  ASSERT_EQ(r.results.size(), 2u);
  EXPECT_EQ(progress_calls, 2u);
  EXPECT_FALSE(fs::exists(o.work_dir));
  const EvaluationReport rep = evaluate(r.results, r.truth);
  EXPECT_EQ(rep.registered, 2u);
  for (const auto& q : rep.per_query) {
    EXPECT_LT(q.position_error, 0.1) << q.image;
    EXPECT_LT(q.rotation_error, 1.0) << q.image;
  }
  // An image the model does not have is an error naming it.
  o.images = {"nope.jpg"};
  try {
    run_leave_one_out(scene / "colmap" / "sparse", scene / "colmap" / "database.db", o);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("nope.jpg"), std::string::npos);
  }
}

// A '*' line gives every query a camera; without it, an unlisted query is named in a warning.
TEST(EvaluationLists, StarIntrinsicsCoverEveryQueryAndUnlistedOnesAreWarned) {
  const fs::path dir = unique_temp_path("visloc_eval_test_lists");
  fs::remove_all(dir);
  fs::create_directories(dir);
  write_file_atomic(dir / "queries.txt", "a.png\nb.png\n");
  EvaluationListFiles lists;
  lists.queries = dir / "queries.txt";
  lists.intrinsics = dir / "intrinsics.txt";
  EvaluationRunOptions o;
  o.images_dir = dir;
  o.truth = dir / "truth.txt";
  write_file_atomic(lists.intrinsics, "a.png PINHOLE 800 600 500 500 400 300\n");
  read_list_files(lists, o);
  const std::string warning = unlisted_intrinsics_warning(lists, o);
  EXPECT_NE(warning.find("1 of 2 queries"), std::string::npos) << warning;
  EXPECT_NE(warning.find("intrinsics.txt"), std::string::npos) << warning;
  write_file_atomic(lists.intrinsics, "* PINHOLE 800 600 500 500 400 300\n");
  o = EvaluationRunOptions{};
  o.images_dir = dir;
  o.truth = dir / "truth.txt";
  read_list_files(lists, o);
  EXPECT_EQ(unlisted_intrinsics_warning(lists, o), "");
  for (const std::string& q : o.queries) EXPECT_NE(find_listed_camera(o.intrinsics, q), nullptr) << q;
  EXPECT_EQ(unlisted_intrinsics_warning(EvaluationListFiles{}, o), "");  // no file, no warning
  fs::remove_all(dir);
}

TEST(Protocols, FeatureStoreNeedsAnImportedMap) {
  const fs::path dir = unique_temp_path("visloc_eval_test_nostore");
  fs::remove_all(dir);
  fs::create_directories(dir);
  write_file_atomic(dir / "manifest.json", R"({"format":"visloc map","format_version":1,"segments":[]})");
  EXPECT_THROW(SourceFeatureStore store(dir), Error);
}

// The peer: COLMAP registers a held-out image into the model without it.
TEST(Protocols, ColmapRegistersAHeldOutImage) {
  const fs::path scene = fountain_scene();
  if (!fs::exists(scene / "colmap" / "database.db")) GTEST_SKIP() << "shared data absent: " << scene;
  if (!program_exists("colmap")) GTEST_SKIP() << "colmap is not installed";
  ColmapModel model = read_colmap_model(scene / "colmap" / "sparse");
  const std::string name = "0006.jpg";
  const int64_t k = model.image_index_by_name(name);
  ASSERT_GE(k, 0);
  const ColmapImage truth_image = model.images[static_cast<size_t>(k)];
  remove_images(model, {name});
  // Keep the test short: only three model images to match against.
  std::vector<std::string> drop;
  for (const auto& im : model.images)
    if (im.name != "0005.jpg" && im.name != "0007.jpg" && im.name != "0004.jpg") drop.push_back(im.name);
  remove_images(model, drop);
  ColmapDatabase db(scene / "colmap" / "database.db");
  PreparedQuery q;
  q.name = name;
  q.features = db.features(db.image_by_name(name)->image_id);
  const auto cams = db.cameras();
  q.camera = PinholeCamera::from_colmap("PINHOLE", static_cast<int>(cams[0].width), static_cast<int>(cams[0].height),
                                        cams[0].params);
  PreparedQuery bad;
  bad.name = "broken.jpg";
  bad.error = "not an image";
  const fs::path work = unique_temp_path("visloc_eval_test_colmap");
  ColmapRunnerOptions co;
  const ColmapRegistrationResult r = register_with_colmap(model, scene / "colmap" / "database.db", {q, bad}, co, work);
  ASSERT_EQ(r.results.size(), 2u);
  EXPECT_TRUE(r.results[0].registered);
  EXPECT_GE(r.results[0].inliers, 30u);
  const CameraPose t = CameraPose::from_wxyz(
      truth_image.cam_from_world_q_wxyz,
      Eigen::Vector3d(truth_image.cam_from_world_t[0], truth_image.cam_from_world_t[1], truth_image.cam_from_world_t[2]));
  EXPECT_LT(position_error(r.results[0].cam_from_segment, t), 0.1);
  EXPECT_FALSE(r.results[1].registered);
  EXPECT_EQ(r.results[1].error, "not an image");
  EXPECT_GT(r.seconds_matching, 0);
  // A query still in the model is refused.
  EXPECT_THROW(register_with_colmap(model, scene / "colmap" / "database.db", {[&] {
                                      PreparedQuery p = q;
                                      p.name = "0005.jpg";
                                      return p;
                                    }()},
                                    co, work),
               Error);
}
