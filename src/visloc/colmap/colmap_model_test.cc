#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <functional>
#include <limits>
#include <set>

#include "visloc/colmap/colmap_database.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/colmap/point_descriptors.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_colmap_model_test_" + name); }

// Three images, four points: point 10 seen by images 1,2,3; point 11 by 1,2;
// point 12 by 2,3; point 13 by 1,2,3.
ColmapModel small_model() {
  ColmapModel m;
  m.cameras.push_back({1, 1, 640, 480, {500, 510, 320, 240}});
  for (uint32_t i = 1; i <= 3; ++i) {
    ColmapImage im;
    im.image_id = i;
    im.name = "img " + std::to_string(i) + ".jpg";  // a space in the name, as COLMAP allows
    im.camera_id = 1;
    im.cam_from_world_q_wxyz = {0.5, 0.5, -0.5, 0.5};
    im.cam_from_world_t = {0.1 * i, -0.2, 3.0};
    for (int k = 0; k < 5; ++k) {
      im.points2d.push_back({10.5 + k, 20.25 * i});
      im.point3d_ids.push_back(kColmapInvalidPoint3DId);
    }
    m.images.push_back(im);
  }
  auto add = [&](int64_t id, std::vector<uint32_t> images) {
    ColmapPoint3D p;
    p.point3d_id = id;
    p.xyz = {1.0 * id, 2.0, -3.5};
    p.rgb = {10, 20, 30};
    p.error = 0.75;
    for (uint32_t im : images) {
      const uint32_t k = static_cast<uint32_t>(id - 10);
      p.track.push_back({im, k});
      m.images[im - 1].point3d_ids[k] = id;
    }
    m.points.push_back(p);
  };
  add(10, {1, 2, 3});
  add(11, {1, 2});
  add(12, {2, 3});
  add(13, {1, 2, 3});
  return m;
}

void expect_same(const ColmapModel& a, const ColmapModel& b) {
  ASSERT_EQ(a.cameras.size(), b.cameras.size());
  EXPECT_EQ(a.cameras[0].model_id, b.cameras[0].model_id);
  EXPECT_EQ(a.cameras[0].params, b.cameras[0].params);
  ASSERT_EQ(a.images.size(), b.images.size());
  for (size_t i = 0; i < a.images.size(); ++i) {
    EXPECT_EQ(a.images[i].name, b.images[i].name);
    EXPECT_EQ(a.images[i].cam_from_world_q_wxyz, b.images[i].cam_from_world_q_wxyz);
    EXPECT_EQ(a.images[i].cam_from_world_t, b.images[i].cam_from_world_t);
    EXPECT_EQ(a.images[i].points2d, b.images[i].points2d);
    EXPECT_EQ(a.images[i].point3d_ids, b.images[i].point3d_ids);
  }
  ASSERT_EQ(a.points.size(), b.points.size());
  for (size_t i = 0; i < a.points.size(); ++i) {
    EXPECT_EQ(a.points[i].point3d_id, b.points[i].point3d_id);
    EXPECT_EQ(a.points[i].xyz, b.points[i].xyz);
    EXPECT_EQ(a.points[i].rgb, b.points[i].rgb);
    ASSERT_EQ(a.points[i].track.size(), b.points[i].track.size());
    for (size_t k = 0; k < a.points[i].track.size(); ++k) {
      EXPECT_EQ(a.points[i].track[k].image_id, b.points[i].track[k].image_id);
      EXPECT_EQ(a.points[i].track[k].point2d_idx, b.points[i].track[k].point2d_idx);
    }
  }
}

}  // namespace

TEST(ColmapModel, TextRoundTrip) {
  auto dir = temp_dir("text");
  ColmapModel m = small_model();
  write_colmap_model_text(m, dir);
  ColmapModel r = read_colmap_model(dir);  // picks text: no .bin files
  expect_same(m, r);
}

TEST(ColmapModel, ReadsHandWrittenText) {
  auto dir = temp_dir("handwritten");
  write_file_atomic(dir / "cameras.txt", "# comment\n1 SIMPLE_RADIAL 100 80 90 50 40 0.01\n");
  write_file_atomic(dir / "images.txt",
                    "# two lines per image\n"
                    "1 1 0 0 0 0 0 0 1 a.jpg\n"
                    "5 5 -1 6 6 -1 7 7 3\n"
                    "2 1 0 0 0 1 0 0 1 b.jpg\n"
                    "\n");
  write_file_atomic(dir / "points3D.txt", "3 1 2 3 255 0 0 0.5 1 2\n");
  ColmapModel m = read_colmap_model(dir);
  ASSERT_EQ(m.images.size(), 2u);
  EXPECT_EQ(m.cameras[0].model_id, 2);
  EXPECT_EQ(m.images[0].points2d.size(), 3u);
  EXPECT_EQ(m.images[0].point3d_ids[1], kColmapInvalidPoint3DId);
  EXPECT_EQ(m.images[0].point3d_ids[2], 3);
  EXPECT_TRUE(m.images[1].points2d.empty());
  EXPECT_DOUBLE_EQ(m.images[0].points2d[2][0], 7.0);
  ASSERT_EQ(m.points.size(), 1u);
  EXPECT_EQ(m.points[0].track.size(), 1u);
  // A track naming a missing 2D point is rejected with the file's directory in the message.
  write_file_atomic(dir / "points3D.txt", "3 1 2 3 255 0 0 0.5 1 2 2\n");  // odd track
  EXPECT_THROW(read_colmap_model(dir), Error);
  write_file_atomic(dir / "points3D.txt", "3 1 2 3 255 0 0 0.5 1 9\n");
  try {
    read_colmap_model(dir);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("2D point 9"), std::string::npos) << e.what();
  }
}

TEST(ColmapModel, BinaryRoundTripAndTruncation) {
  auto dir = temp_dir("binary");
  ColmapModel m = small_model();
  write_colmap_model_binary(m, dir);
  expect_same(m, read_colmap_model(dir));
  std::string bytes = read_file(dir / "points3D.bin");
  write_file_atomic(dir / "points3D.bin", bytes.substr(0, bytes.size() - 5));
  try {
    read_colmap_model(dir);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("points3D.bin"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
}

TEST(ColmapModel, HoldoutRemovesObservationsAndShortTracks) {
  ColmapModel m = small_model();
  const size_t obs_before = m.num_observations();
  auto st = remove_images(m, {"img 3.jpg"});
  EXPECT_EQ(st.images_removed, 1u);
  EXPECT_EQ(st.observations_removed, 3u);  // points 10, 12, 13
  EXPECT_EQ(st.points_dropped, 1u);        // point 12 keeps only image 2
  EXPECT_EQ(m.num_observations(), obs_before - 3 - 1);
  ASSERT_EQ(m.images.size(), 2u);
  EXPECT_EQ(m.image_index_by_name("img 3.jpg"), -1);
  ASSERT_EQ(m.points.size(), 3u);
  for (const auto& p : m.points) {
    EXPECT_NE(p.point3d_id, 12);
    EXPECT_GE(p.track.size(), 2u);
    for (const auto& e : p.track) EXPECT_NE(e.image_id, 3u);
  }
  // Image 2's 2D point that referred to the dropped point is unassigned.
  EXPECT_EQ(m.images[1].point3d_ids[2], kColmapInvalidPoint3DId);
  EXPECT_EQ(m.images[1].point3d_ids[0], 10);
  // Unknown names are reported.
  EXPECT_THROW(remove_images(m, {"nope.jpg"}), Error);
  // Removing a second image drops every point seen by only one remaining image.
  remove_images(m, {"img 2.jpg"});
  EXPECT_TRUE(m.points.empty());
}

TEST(ColmapModel, ReadsStrechaFountainBinaryModelAndMeanDescriptors) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "sparse" / "points3D.bin")) GTEST_SKIP() << "shared data absent: " << scene;
  ColmapModel m = read_colmap_model(scene / "colmap" / "sparse");
  EXPECT_EQ(m.images.size(), 11u);
  EXPECT_GT(m.points.size(), 10000u);
  ASSERT_EQ(m.cameras.size(), 1u);
  EXPECT_EQ(m.cameras[0].width, 1536u);
  // Every track element's 2D point links back to the 3D point.
  for (size_t p = 0; p < m.points.size(); p += 101)
    for (const auto& e : m.points[p].track)
      EXPECT_EQ(m.images[m.image_index(e.image_id)].point3d_ids[e.point2d_idx], m.points[p].point3d_id);
  ColmapDatabase db(scene / "colmap" / "database.db");
  ColmapModel small = m;
  small.points.resize(200);
  auto d = compute_point_descriptors(small, db);
  ASSERT_EQ(d.mean.size(), 200u * 128);
  // The mean of one point, recomputed from its track by hand.
  const auto& p0 = small.points[0];
  std::vector<float> ref(128, 0);
  for (const auto& e : p0.track) {
    auto im = db.image_by_name(small.images[small.image_index(e.image_id)].name);
    auto desc = db.descriptors(im->image_id);
    for (int j = 0; j < 128; ++j) ref[j] += desc.row(e.point2d_idx)[j] / float(p0.track.size());
  }
  for (int j = 0; j < 128; ++j) EXPECT_NEAR(d.mean[j], ref[j], 1e-3);
  EXPECT_EQ(d.track_size[0], p0.track.size());
  // RootSIFT descriptors have a roughly constant L2 norm; the mean's is not zero.
  double n2 = 0;
  for (int j = 0; j < 128; ++j) n2 += double(d.mean[j]) * d.mean[j];
  EXPECT_GT(n2, 100.0);
}

// Well-formed models whose values mean nothing valid are rejected naming the
// file and the camera, image or point (robustness issue: NaN, zero or infinite
// poses, NaN points, focal NaN or −1000, width 0).
TEST(ColmapModelValidation, RejectsMeaninglessValuesInBothFormats) {
  const auto nan = std::numeric_limits<double>::quiet_NaN();
  const auto inf = std::numeric_limits<double>::infinity();
  const std::vector<std::pair<std::string, std::function<void(ColmapModel&)>>> cases = {
      {"unit quaternion", [&](ColmapModel& m) { m.images[0].cam_from_world_q_wxyz = {nan, 0, 0, 0}; }},
      {"unit quaternion", [&](ColmapModel& m) { m.images[1].cam_from_world_q_wxyz = {0, 0, 0, 0}; }},
      {"translation", [&](ColmapModel& m) { m.images[2].cam_from_world_t = {inf, 0, 0}; }},
      {"non-finite position", [&](ColmapModel& m) { m.points[1].xyz = {nan, 0, 0}; }},
      {"not finite", [&](ColmapModel& m) { m.cameras[0].params[0] = nan; }},
      {"focal length", [&](ColmapModel& m) { m.cameras[0].params = {-1000, -1000, 320, 240}; }},
      {"image size", [&](ColmapModel& m) { m.cameras[0].width = 0; }},
      {"principal point", [&](ColmapModel& m) { m.cameras[0].params[2] = 6400; }},
  };
  const auto dir = temp_dir("validation");
  for (const auto& [expected, edit] : cases)
    for (bool binary : {true, false}) {
      ColmapModel m = small_model();
      edit(m);
      fs::remove_all(dir);
      binary ? write_colmap_model_binary(m, dir) : write_colmap_model_text(m, dir);
      try {
        read_colmap_model(dir);
        ADD_FAILURE() << "accepted a model with a bad value (" << expected << ")";
      } catch (const Error& e) {
        EXPECT_EQ(e.code(), ErrorCode::kFormat);
        // The text reader already refuses "nan" and "inf" as numbers ("bad image line ...").
        const bool text_number = !binary && (std::string(e.what()).find("bad ") != std::string::npos ||
                                             std::string(e.what()).find("not a number") != std::string::npos);
        EXPECT_TRUE(text_number || std::string(e.what()).find(expected) != std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find(dir.string()), std::string::npos) << e.what();
      }
    }
}

// The observation sample: evenly spaced points, each one of its own track's
// views (not always the track's first), whatever order the images are read in.
TEST(PointDescriptors, SamplesOneOwnViewOfEvenlySpacedPoints) {
  ColmapModel m;
  for (uint32_t id : {1u, 2u, 3u}) {
    ColmapImage im;
    im.image_id = id;
    im.name = "im" + std::to_string(id);
    im.points2d.resize(10);
    im.point3d_ids.assign(10, kColmapInvalidPoint3DId);
    m.images.push_back(im);
  }
  // Point p: seen by images 2 then 3 then 1 (not the images' order), as 2D point p.
  for (int p = 0; p < 10; ++p) {
    ColmapPoint3D pt;
    pt.point3d_id = p + 1;
    pt.track = {{2, uint32_t(p)}, {3, uint32_t(p)}, {1, uint32_t(p)}};
    m.points.push_back(pt);
  }
  // Image i's descriptor of 2D point k: every byte 10·i + k.
  const ImageDescriptorSource source = [](const ColmapImage& im) {
    DescriptorMatrix d(10);
    for (size_t k = 0; k < 10; ++k) std::fill_n(d.row(k), kDescriptorDim, uint8_t(10 * im.image_id + k));
    return d;
  };
  const PointDescriptors none = compute_point_descriptors(m, source, "test");
  EXPECT_TRUE(none.sampled_points.empty());
  EXPECT_TRUE(none.sampled_observations.empty());
  const PointDescriptors d = compute_point_descriptors(m, source, "test", 4);
  EXPECT_EQ(d.sampled_points, (std::vector<uint32_t>{0, 2, 5, 7}));
  ASSERT_EQ(d.sampled_observations.rows(), 4u);
  for (size_t k = 0; k < 4; ++k) {
    const uint8_t v = d.sampled_observations.row(k)[0];
    const uint32_t p = d.sampled_points[k];
    EXPECT_TRUE(v == 10 + p || v == 20 + p || v == 30 + p) << "sample " << k << ": " << int(v);  // its own views
    for (int j = 1; j < kDescriptorDim; ++j) ASSERT_EQ(d.sampled_observations.row(k)[j], v) << "sample " << k;
  }
  EXPECT_FLOAT_EQ(d.mean[5 * kDescriptorDim], (25.0f + 35.0f + 15.0f) / 3);
  const PointDescriptors all = compute_point_descriptors(m, source, "test", 50);  // more than the points: all
  EXPECT_EQ(all.sampled_points.size(), 10u);
  EXPECT_EQ(all.sampled_observations.rows(), 10u);
  std::set<int> images;  // the views come from more than one track position
  for (size_t k = 0; k < 10; ++k) images.insert(all.sampled_observations.row(k)[0] / 10);
  EXPECT_GT(images.size(), 1u);
}
