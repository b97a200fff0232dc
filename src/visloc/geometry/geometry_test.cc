#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <numbers>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/correspondence_set.h"
#include "visloc/geometry/pose.h"
#include "visloc/util/error.h"

using namespace visloc;

TEST(PinholeCamera, ProjectNormalizeRoundTrip) {
  for (double k1 : {0.0, -0.15, 0.08}) {
    PinholeCamera c = PinholeCamera::centered(1536, 1024, 1380.0);
    c.k1 = k1;
    c.validate();
    for (double x : {-0.4, 0.0, 0.3})
      for (double y : {-0.25, 0.1}) {
        Eigen::Vector3d p(x * 5, y * 5, 5);
        Eigen::Vector2d px = c.project(p);
        Eigen::Vector2d n = c.normalize(px);
        EXPECT_NEAR(n.x(), x, 1e-10) << "k1=" << k1;
        EXPECT_NEAR(n.y(), y, 1e-10) << "k1=" << k1;
      }
  }
}

// Non-square pixels (COLMAP's PINHOLE fx ≠ fy, OPENCV with k1 only): x is
// scaled by fx and y by fy, both ways; colmap_model() names the model that
// gives the same camera back.
TEST(PinholeCamera, NonSquarePixelsAndTheirColmapModel) {
  const PinholeCamera pinhole = PinholeCamera::from_colmap("PINHOLE", 1536, 1024, {1379.74, 1382.08, 760.3, 503.4});
  EXPECT_DOUBLE_EQ(pinhole.focal, 1379.74);
  EXPECT_DOUBLE_EQ(pinhole.focal_y(), 1382.08);
  const Eigen::Vector2d px = pinhole.project({1, -2, 10});
  EXPECT_NEAR(px.x(), 1379.74 * 0.1 + 760.3, 1e-9);
  EXPECT_NEAR(px.y(), 1382.08 * -0.2 + 503.4, 1e-9);
  const PinholeCamera opencv =
      PinholeCamera::from_colmap("OPENCV", 1536, 1024, {1379.74, 1382.08, 760.3, 503.4, -0.12, 0, 0, 0});
  EXPECT_DOUBLE_EQ(opencv.k1, -0.12);
  for (const PinholeCamera& c :
       {pinhole, opencv, PinholeCamera::from_colmap("SIMPLE_RADIAL", 640, 480, {500, 320, 240, 0.05}),
        PinholeCamera::from_colmap("SIMPLE_PINHOLE", 640, 480, {500, 320, 240})}) {
    for (double x : {-0.4, 0.0, 0.3})
      for (double y : {-0.25, 0.1}) {
        const Eigen::Vector2d n = c.normalize(c.project({x * 5, y * 5, 5}));
        EXPECT_NEAR(n.x(), x, 1e-10);
        EXPECT_NEAR(n.y(), y, 1e-10);
      }
    const auto [model, params] = c.colmap_model();
    const PinholeCamera back = PinholeCamera::from_colmap(model, c.width, c.height, params);
    EXPECT_EQ(back.focal, c.focal) << model;
    EXPECT_EQ(back.aspect, c.aspect) << model;
    EXPECT_EQ(back.k1, c.k1) << model;
    EXPECT_EQ(back.cx, c.cx) << model;
  }
  EXPECT_EQ(pinhole.colmap_model().first, "PINHOLE");
  EXPECT_EQ(opencv.colmap_model().first, "OPENCV");
  // OPENCV's other terms are not modelled; an absurd aspect is refused.
  EXPECT_THROW(PinholeCamera::from_colmap("OPENCV", 640, 480, {500, 500, 320, 240, 0, 0.01, 0, 0}), Error);
  EXPECT_THROW(PinholeCamera::from_colmap("PINHOLE", 640, 480, {500, 0, 320, 240}), Error);
  try {
    PinholeCamera::from_colmap("PINHOLE", 640, 480, {500, 1500, 320, 240});
    FAIL() << "accepted fy = 3 fx";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("aspect"), std::string::npos) << e.what();
  }
}

TEST(PinholeCamera, PrincipalPointAndFov) {
  PinholeCamera c = PinholeCamera::centered(640, 640, 320.0);
  Eigen::Vector2d px = c.project({0, 0, 3});
  EXPECT_DOUBLE_EQ(px.x(), 320.0);
  EXPECT_DOUBLE_EQ(px.y(), 320.0);
  EXPECT_NEAR(c.horizontal_fov_deg(), 90.0, 1e-12);
  EXPECT_TRUE(c.contains({0.5, 0.5}));
  EXPECT_FALSE(c.contains({-1, 3}));
}

TEST(PinholeCamera, ValidateNamesField) {
  PinholeCamera c = PinholeCamera::centered(0, 10, 100.0);
  try {
    c.validate();
    FAIL() << "accepted zero width";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("width"), std::string::npos);
  }
  c = PinholeCamera::centered(10, 10, -3.0);
  EXPECT_THROW(c.validate(), Error);
  c = PinholeCamera::centered(10, 10);  // unknown focal is valid
  EXPECT_NO_THROW(c.validate());
  EXPECT_FALSE(c.has_focal);
}

TEST(PinholeCamera, FocalFrom35mm) {
  // A 35 mm-equivalent 36 mm lens spans exactly the long side: 90° would be 18 mm.
  EXPECT_DOUBLE_EQ(focal_px_from_35mm(36.0, 4000, 3000), 4000.0);
  PinholeCamera c = PinholeCamera::centered(1000, 750, focal_px_from_35mm(18.0, 1000, 750));
  EXPECT_NEAR(c.horizontal_fov_deg(), 90.0, 1e-9);
}

TEST(CameraPose, CenterAndTransform) {
  Eigen::Matrix3d R = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  Eigen::Vector3d C(4, -1, 2);
  CameraPose p = CameraPose::from_world_from_cam(R, C);
  EXPECT_NEAR((p.center() - C).norm(), 0, 1e-12);
  EXPECT_NEAR(p.transform(C).norm(), 0, 1e-12);  // the centre maps to the camera origin
  // A point along the viewing direction has positive depth.
  EXPECT_GT(p.transform(C + p.viewing_direction()).z(), 0.99);
  EXPECT_NEAR((p.rotation_matrix() - R.transpose()).norm(), 0, 1e-12);
}

TEST(CameraPose, QuaternionWxyzRoundTripAndInverse) {
  CameraPose p = CameraPose::from_wxyz({0.7, 0.1, -0.5, 0.3}, {1, 2, 3});
  auto q = p.q_wxyz();
  const double n = std::sqrt(0.49 + 0.01 + 0.25 + 0.09);
  EXPECT_NEAR(q[0], 0.7 / n, 1e-12);
  EXPECT_NEAR(q[2], -0.5 / n, 1e-12);
  CameraPose id = p * p.inverse();
  EXPECT_NEAR(rotation_error_deg(id, CameraPose{}), 0, 1e-6);
  EXPECT_NEAR(id.translation.norm(), 0, 1e-12);
  EXPECT_NEAR(position_error(p, p), 0, 1e-12);
}

TEST(CameraPose, RotationErrorDegrees) {
  CameraPose a;
  CameraPose b = CameraPose::from_matrix(Eigen::AngleAxisd(10 * std::numbers::pi / 180, Eigen::Vector3d::UnitY()).toRotationMatrix(), Eigen::Vector3d::Zero());
  EXPECT_NEAR(rotation_error_deg(a, b), 10.0, 1e-9);
  // q and -q are the same rotation
  CameraPose c = b;
  c.rotation.coeffs() *= -1;
  EXPECT_NEAR(rotation_error_deg(b, c), 0.0, 1e-6);
}

#include <filesystem>

#include "visloc/geometry/pose_list.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

TEST(PoseList, RoundTripAndErrors) {
  namespace fs = std::filesystem;
  fs::path p = unique_temp_path("visloc_geometry_test_poses.txt");
  std::vector<NamedPose> poses = {{"a.jpg", CameraPose::from_wxyz({0.5, 0.5, -0.5, 0.5}, {1, 2, 3})},
                                  {"b.png", CameraPose{}}};
  write_pose_list(p, poses);
  auto back = read_pose_list(p);
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[0].name, "a.jpg");
  EXPECT_NEAR(rotation_error_deg(back[0].cam_from_world, poses[0].cam_from_world), 0, 1e-6);
  EXPECT_NEAR(position_error(back[0].cam_from_world, poses[0].cam_from_world), 0, 1e-9);
  write_file_atomic(p, "# c\na.jpg 1 0 0 0 1 2 3\nb.jpg 1 0 0\n");
  try {
    read_pose_list(p);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(":3:"), std::string::npos) << e.what();
  }
  write_file_atomic(p, "a.jpg 2 0 0 0 1 2 3\n");
  EXPECT_THROW(read_pose_list(p), Error);
  write_file_atomic(p, "# header\n 0001.jpg \n\n0003.jpg\n");
  EXPECT_EQ(read_name_list(p), (std::vector<std::string>{"0001.jpg", "0003.jpg"}));
}

TEST(PoseList, ReadsColmapImagesTxt) {
  namespace fs = std::filesystem;
  fs::path p = unique_temp_path("visloc_geometry_test_images.txt");
  // Second image has no 2D points: its POINTS2D line is empty.
  write_file_atomic(p,
                    "# Image list with two lines of data per image:\n"
                    "1 0.5 0.5 -0.5 0.5 1 2 3 1 a.jpg\n"
                    "10.5 20.5 -1 30 40 7\n"
                    "2 1 0 0 0 0 0 0 1 b.jpg\n"
                    "\n"
                    "3 1 0 0 0 4 5 6 1 c.jpg\n"
                    "1 1 -1\n");
  const auto poses = read_colmap_images_txt_poses(p);
  ASSERT_EQ(poses.size(), 3u);
  EXPECT_EQ(poses[0].name, "a.jpg");
  EXPECT_EQ(poses[2].name, "c.jpg");
  EXPECT_NEAR(poses[2].cam_from_world.translation.z(), 6.0, 1e-12);
  EXPECT_NEAR(rotation_error_deg(poses[0].cam_from_world, CameraPose::from_wxyz({0.5, 0.5, -0.5, 0.5}, {1, 2, 3})), 0,
              1e-6);
  write_file_atomic(p, "1 1 0 0 0 0 0 0 a.jpg\n\n");
  EXPECT_THROW(read_colmap_images_txt_poses(p), Error);
}

TEST(PoseList, ReadsStrechaTruth) {
  namespace fs = std::filesystem;
  fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "truth.txt")) GTEST_SKIP() << "shared data absent: " << scene;
  auto poses = read_pose_list(scene / "truth.txt");
  ASSERT_EQ(poses.size(), 11u);
  // The aligned COLMAP pose agrees with Strecha's laser camera within centimetres.
  std::ifstream cam(scene / "cameras" / (poses[0].name + ".camera"));
  double v[24];
  for (double& x : v) cam >> x;
  Eigen::Vector3d c(v[21], v[22], v[23]);
  EXPECT_LT((poses[0].cam_from_world.center() - c).norm(), 0.05);
}

TEST(IntrinsicsList, ReadsModelsAndRejectsBadLines) {
  namespace fs = std::filesystem;
  fs::path p = unique_temp_path("visloc_geometry_test_intrinsics.txt");
  write_file_atomic(p, "# q\nq1.jpg PINHOLE 800 600 500 502 400 300\nq2.jpg SIMPLE_RADIAL 640 480 400 320 240 -0.1\n");
  auto cams = read_intrinsics_list(p);
  ASSERT_EQ(cams.size(), 2u);
  EXPECT_DOUBLE_EQ(cams[0].camera.focal, 500);
  EXPECT_DOUBLE_EQ(cams[0].camera.focal_y(), 502);
  EXPECT_TRUE(cams[0].camera.has_focal);
  EXPECT_DOUBLE_EQ(cams[1].camera.k1, -0.1);
  write_file_atomic(p, "q1.jpg OPENCV 800 600 500 502 400 300 0.1 0 0 0\n");
  EXPECT_DOUBLE_EQ(read_intrinsics_list(p)[0].camera.k1, 0.1);
  write_file_atomic(p, "q1.jpg OPENCV 800 600 1 2 3 4 5 6 7 8\n");
  EXPECT_THROW(read_intrinsics_list(p), Error);
  write_file_atomic(p, "q1.jpg PINHOLE 800 600 500\n");
  try {
    read_intrinsics_list(p);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(":1:"), std::string::npos) << e.what();
  }
}

TEST(IntrinsicsList, AnImageWithoutALineOfItsOwnTakesTheStarLine) {
  namespace fs = std::filesystem;
  fs::path p = unique_temp_path("visloc_geometry_test_intrinsics_star.txt");
  write_file_atomic(p, "* PINHOLE 1226 370 707 707 601 183\nq1.png PINHOLE 800 600 500 500 400 300\n");
  const CamerasByName cams = read_intrinsics_by_name(p);
  ASSERT_EQ(cams.size(), 2u);
  const PinholeCamera* own = find_listed_camera(cams, "q1.png");
  ASSERT_NE(own, nullptr);
  EXPECT_EQ(own->width, 800);  // its own line, though '*' comes first
  const PinholeCamera* star = find_listed_camera(cams, "000100.png");
  ASSERT_NE(star, nullptr);
  EXPECT_EQ(star->width, 1226);
  EXPECT_DOUBLE_EQ(star->focal, 707);
  const PinholeCamera* by_file_name = find_listed_camera(cams, "query/day/q1.png");
  ASSERT_NE(by_file_name, nullptr);
  EXPECT_EQ(by_file_name->width, 800);  // listed as 'q1.png', asked as a path
  write_file_atomic(p, "q1.png PINHOLE 800 600 500 500 400 300\nday/q1.png PINHOLE 640 480 400 400 320 240\n");
  EXPECT_EQ(find_listed_camera(read_intrinsics_by_name(p), "day/q1.png")->width, 640);  // the exact name first
  EXPECT_EQ(find_listed_camera(read_intrinsics_by_name(p), "000100.png"), nullptr);  // no '*': none
  write_file_atomic(p, "* PINHOLE 800 600 500 500 400 300\n* PINHOLE 800 600 600 600 400 300\n");
  EXPECT_THROW(read_intrinsics_by_name(p), Error);  // two '*' lines conflict like any other name
}

TEST(IntrinsicsList, RejectsConflictingLinesAndPrincipalPointsOutside) {
  namespace fs = std::filesystem;
  fs::path p = unique_temp_path("visloc_geometry_test_intrinsics_conflict.txt");
  write_file_atomic(p, "q1.jpg PINHOLE 800 600 500 502 400 300\nq1.jpg PINHOLE 800 600 700 702 400 300\n");
  try {
    read_intrinsics_list(p);
    FAIL() << "two lines for one image were accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(":2: image 'q1.jpg' already has intrinsics on line 1"), std::string::npos)
        << e.what();
  }
  write_file_atomic(p, "q1.jpg PINHOLE 800 600 500 502 4000 300\n");
  EXPECT_THROW(read_intrinsics_list(p), Error);
  write_file_atomic(p, "q1.jpg PINHOLE 800 600 nan 502 400 300\n");
  EXPECT_THROW(read_intrinsics_list(p), Error);
}

TEST(CorrespondenceSet, ValidateNamesTheProblem) {
  CorrespondenceSet c;
  c.validate();  // empty is valid
  c.add_feature({10, 10}, {Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(2, 3, 4)}, true);
  c.add_feature({20, 20}, {Eigen::Vector3d(1, 2, 5)}, false);
  c.validate();
  EXPECT_EQ(c.num_features(), 2u);
  EXPECT_EQ(c.num_candidates(0), 2u);
  EXPECT_EQ(c.num_hypothesis_features(), 1u);
  CorrespondenceSet bad = c;
  bad.candidate_offsets[1] = 0;
  try {
    bad.validate();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no candidates"), std::string::npos) << e.what();
  }
  bad = c;
  bad.in_hypothesis_set.pop_back();
  EXPECT_THROW(bad.validate(), Error);
  bad = c;
  bad.candidate_point_ids = {1};
  EXPECT_THROW(bad.validate(), Error);
  bad = c;
  bad.candidates[0].x() = std::nan("");
  EXPECT_THROW(bad.validate(), Error);
  c.query_feature = {7, 3};  // optional: empty or one per feature
  c.validate();
  bad = c;
  bad.query_feature.pop_back();
  try {
    bad.validate();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("query_feature"), std::string::npos) << e.what();
  }
  bad.clear();
  bad.validate();
  bad.query_feature = {1};  // a row for a feature that is not there
  EXPECT_THROW(bad.validate(), Error);
  EXPECT_THROW(c.add_feature({1, 1}, {}, true), Error);
}
