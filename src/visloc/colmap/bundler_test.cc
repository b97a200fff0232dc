#include "visloc/colmap/bundler.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "visloc/colmap/point_descriptors.h"
#include "visloc/features/sift_extractor.h"
#include "visloc/image/image_io.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path temp_dir(const std::string& name) { return unique_temp_dir("visloc_bundler_test_" + name); }

std::string num(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.17g", v);
  return b;
}

// A Bundler camera as the test writes it, and its projection by Bundler's
// own formula (manual: P = R X + t, p = −P/P.z, f (1 + k1|p|² + k2|p|⁴) p).
struct TestCamera {
  double f = 0, k1 = 0, k2 = 0;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  Eigen::Vector2d project(const Eigen::Vector3d& X) const {
    const Eigen::Vector3d P = R * X + t;
    const Eigen::Vector2d p = -P.head<2>() / P.z();
    const double r2 = p.squaredNorm();
    return f * (1 + k1 * r2 + k2 * r2 * r2) * p;
  }
};

struct TestKey {
  double row = 0, col = 0, scale = 2, orientation = 0.5;
  std::array<int, 128> desc{};
};

std::string key_text(const std::vector<TestKey>& keys, size_t announced) {
  std::ostringstream s;
  s << announced << " 128\n";
  for (const auto& k : keys) {
    s << num(k.row) << ' ' << num(k.col) << ' ' << k.scale << ' ' << k.orientation << '\n';
    for (int j = 0; j < 128; ++j) s << ' ' << k.desc[j] << ((j % 20 == 19 || j == 127) ? "\n" : "");
  }
  return s.str();
}

void write_gzip(const fs::path& path, const std::string& text) {
  gzFile f = gzopen(path.c_str(), "wb");
  ASSERT_TRUE(f);
  ASSERT_EQ(gzwrite(f, text.data(), unsigned(text.size())), int(text.size()));
  ASSERT_EQ(gzclose(f), Z_OK);
}

// Image size 640 × 480: Bundler centres a key at (col, row) as
// x = col − 319.5, y = 239.5 − row.
constexpr int kWidth = 640, kHeight = 480;

// Three cameras: A (registered, distorted), B (f = 0), C (registered).
// Points: P0 seen by A (key 2), B, C (key 0); P1 by A (key 0) and B; P2 by B only.
struct Scene {
  fs::path dir, bundle, list;
  TestCamera A, B, C;
  std::vector<Eigen::Vector3d> X;
  std::vector<TestKey> keys_a, keys_c;
  std::string bundle_text, list_text;
};

Scene make_scene(const std::string& name) {
  Scene s;
  s.dir = temp_dir(name);
  fs::create_directories(s.dir / "images");
  s.bundle = s.dir / "bundle.out";
  s.list = s.dir / "list.txt";
  s.A.f = 500;
  s.A.k1 = 0.01;
  s.A.k2 = -0.002;
  s.A.R = Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  s.A.t = {0.1, -0.2, 0.3};
  s.C.f = 600;
  s.C.R = Eigen::AngleAxisd(-5 * M_PI / 180, Eigen::Vector3d::UnitX()).toRotationMatrix() *
          Eigen::AngleAxisd(3 * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  s.C.t = {-0.5, 0.05, 0.2};
  s.X = {{0.2, 0.1, -5}, {-0.3, 0.4, -6}, {1, 1, -7}};

  auto key_at = [](const Eigen::Vector2d& xy, int fill) {
    TestKey k;
    k.col = xy.x() + 0.5 * (kWidth - 1);
    k.row = 0.5 * (kHeight - 1) - xy.y();
    for (int j = 0; j < 128; ++j) k.desc[j] = (j * 7 + fill) % 60;
    return k;
  };
  s.keys_a = {key_at(s.A.project(s.X[1]), 1), key_at({10, 20}, 2), key_at(s.A.project(s.X[0]), 3)};
  s.keys_c = {key_at(s.C.project(s.X[0]), 4)};

  std::ostringstream b;
  b << "# Bundle file v0.3\n3 3\n";
  for (const TestCamera* c : {&s.A, &s.B, &s.C}) {
    b << num(c->f) << ' ' << num(c->k1) << ' ' << num(c->k2) << '\n';
    const Eigen::Matrix3d R = c == &s.B ? Eigen::Matrix3d::Zero() : c->R;
    for (int r = 0; r < 3; ++r) b << num(R(r, 0)) << ' ' << num(R(r, 1)) << ' ' << num(R(r, 2)) << '\n';
    b << num(c->t.x()) << ' ' << num(c->t.y()) << ' ' << num(c->t.z()) << '\n';
  }
  auto view = [&](int cam, int key, const Eigen::Vector2d& xy) {
    b << ' ' << cam << ' ' << key << ' ' << num(xy.x()) << ' ' << num(xy.y());
  };
  b << num(s.X[0].x()) << ' ' << num(s.X[0].y()) << ' ' << num(s.X[0].z()) << "\n10 20 30\n3";
  view(0, 2, s.A.project(s.X[0]));
  view(1, 0, {1, 1});
  view(2, 0, s.C.project(s.X[0]));
  b << '\n' << num(s.X[1].x()) << ' ' << num(s.X[1].y()) << ' ' << num(s.X[1].z()) << "\n40 50 60\n2";
  view(0, 0, s.A.project(s.X[1]));
  view(1, 1, {2, 2});
  b << '\n' << num(s.X[2].x()) << ' ' << num(s.X[2].y()) << ' ' << num(s.X[2].z()) << "\n70 80 90\n1";
  view(1, 2, {3, 3});
  b << '\n';
  s.bundle_text = b.str();
  s.list_text = "images/a.png\nimages/b.png 0 400\nimages/c.png\n";
  write_file_atomic(s.bundle, s.bundle_text);
  write_file_atomic(s.list, s.list_text);
  write_file_atomic(s.dir / "images/a.key", key_text(s.keys_a, s.keys_a.size()));
  write_gzip(s.dir / "images/c.key.gz", key_text(s.keys_c, s.keys_c.size()));
  // No key file for B: unregistered cameras need none.
  return s;
}

// COLMAP's RADIAL projection of a world point through an imported image.
Eigen::Vector2d colmap_project(const ColmapModel& m, const ColmapImage& im, const Eigen::Vector3d& X) {
  const auto& q = im.cam_from_world_q_wxyz;
  const Eigen::Quaterniond rot(q[0], q[1], q[2], q[3]);
  const Eigen::Vector3d P = rot * X + Eigen::Vector3d(im.cam_from_world_t[0], im.cam_from_world_t[1],
                                                      im.cam_from_world_t[2]);
  const auto& c = m.cameras[m.camera_index(im.camera_id)];
  EXPECT_EQ(c.model_id, colmap_camera_model_id("RADIAL"));
  const double f = c.params[0], cx = c.params[1], cy = c.params[2], k1 = c.params[3], k2 = c.params[4];
  const double u = P.x() / P.z(), v = P.y() / P.z(), r2 = u * u + v * v;
  const double d = 1 + k1 * r2 + k2 * r2 * r2;
  return {f * d * u + cx, f * d * v + cy};
}

}  // namespace

TEST(Bundler, ConvertsPosesPointsAndObservations) {
  Scene s = make_scene("convert");
  BundlerModel bm = read_bundler_model(s.bundle, s.list);
  const ColmapModel& m = bm.model;
  EXPECT_EQ(bm.stats.cameras, 3u);
  EXPECT_EQ(bm.stats.cameras_unregistered, 1u);
  EXPECT_EQ(bm.stats.observations_dropped, 3u);
  EXPECT_EQ(bm.stats.points_read, 3u);
  EXPECT_EQ(bm.stats.principal_point, "key files");
  EXPECT_EQ(bm.stats.observations_off_key, 0u);
  ASSERT_EQ(m.images.size(), 2u);  // B dropped
  EXPECT_EQ(m.images[0].name, "images/a.png");
  EXPECT_EQ(m.images[1].name, "images/c.png");
  EXPECT_EQ(m.images[1].image_id, 3u);  // image id = list line
  ASSERT_EQ(m.points.size(), 2u);       // P2 had only B's view
  EXPECT_EQ(m.points[0].track.size(), 2u);
  EXPECT_EQ(m.points[1].track.size(), 1u);
  EXPECT_EQ(m.points[1].rgb, (std::array<uint8_t, 3>{40, 50, 60}));
  EXPECT_EQ(m.images[0].points2d.size(), 3u);  // every key of a.key is a 2D point
  EXPECT_EQ(m.images[0].point3d_ids[2], m.points[0].point3d_id);
  EXPECT_EQ(m.images[0].point3d_ids[1], kColmapInvalidPoint3DId);

  const TestCamera* cams[] = {&s.A, &s.C};
  for (size_t i = 0; i < 2; ++i) {
    const ColmapImage& im = m.images[i];
    const TestCamera& bc = *cams[i];
    // Same camera centre as Bundler's: −Rᵀ t.
    const auto& q = im.cam_from_world_q_wxyz;
    const Eigen::Quaterniond rot(q[0], q[1], q[2], q[3]);
    const Eigen::Vector3d t(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]);
    EXPECT_LT((-(rot.conjugate() * t) - (-bc.R.transpose() * bc.t)).norm(), 1e-12);
    // The viewing direction is Bundler's −z axis.
    EXPECT_LT((rot.conjugate() * Eigen::Vector3d::UnitZ() - bc.R.transpose() * -Eigen::Vector3d::UnitZ()).norm(),
              1e-12);
    // Principal point from the keys: the image centre, (w/2, h/2) in COLMAP pixels.
    const auto& c = m.cameras[m.camera_index(im.camera_id)];
    EXPECT_NEAR(c.params[1], kWidth / 2.0, 1e-3);
    EXPECT_NEAR(c.params[2], kHeight / 2.0, 1e-3);
    EXPECT_EQ(c.width, uint64_t(kWidth));
    EXPECT_EQ(c.height, uint64_t(kHeight));
    EXPECT_EQ(c.params[0], bc.f);
  }
  // A point projects onto its observation, which is its key (col + 0.5, row + 0.5).
  for (const auto& p : m.points)
    for (const auto& e : p.track) {
      const ColmapImage& im = m.images[m.image_index(e.image_id)];
      const Eigen::Vector2d uv = colmap_project(m, im, Eigen::Vector3d(p.xyz[0], p.xyz[1], p.xyz[2]));
      EXPECT_NEAR(uv.x(), im.points2d[e.point2d_idx][0], 1e-3);
      EXPECT_NEAR(uv.y(), im.points2d[e.point2d_idx][1], 1e-3);
      const TestKey& key = e.image_id == 1 ? s.keys_a[e.point2d_idx] : s.keys_c[e.point2d_idx];
      EXPECT_NEAR(uv.x(), key.col + 0.5, 1e-3);
      EXPECT_NEAR(uv.y(), key.row + 0.5, 1e-3);
    }
}

TEST(Bundler, PrincipalPointFromImageSizes) {
  Scene s = make_scene("images");
  std::vector<uint8_t> pixels(kWidth * kHeight, 128);
  write_image(s.dir / "images/a.png", kWidth, kHeight, 1, pixels.data());
  write_image(s.dir / "images/c.png", kWidth, kHeight, 1, pixels.data());
  BundlerConversionOptions o;
  o.images_dir = s.dir;  // names in the list carry "images/"
  BundlerModel bm = read_bundler_model(s.bundle, s.list, o);
  EXPECT_EQ(bm.stats.principal_point, "image size");
  for (const auto& c : bm.model.cameras) {
    EXPECT_EQ(c.params[1], 320.0);
    EXPECT_EQ(c.params[2], 240.0);
  }
  EXPECT_EQ(bm.stats.observations_off_key, 0u);
  // The image's folder, and a missing image.
  o.images_dir = s.dir / "images";
  EXPECT_NO_THROW(read_bundler_model(s.bundle, s.list, o));
  fs::remove(s.dir / "images/c.png");
  EXPECT_NE(error_of([&] { read_bundler_model(s.bundle, s.list, o); }).find("images/c.png"), std::string::npos);
}

TEST(Bundler, KeyFilesAndDescriptors) {
  Scene s = make_scene("keys");
  // gzip key file: positions, orientation sign, stem.
  FeatureSet f = read_lowe_key_file(s.dir / "images/c.key.gz", /*root_sift=*/false);
  EXPECT_EQ(f.image, "c");
  ASSERT_EQ(f.size(), 1u);
  EXPECT_NEAR(f.keypoints[0].x, s.keys_c[0].col + 0.5, 1e-3);
  EXPECT_NEAR(f.keypoints[0].y, s.keys_c[0].row + 0.5, 1e-3);
  EXPECT_FLOAT_EQ(f.keypoints[0].orientation, -0.5f);
  EXPECT_FLOAT_EQ(f.keypoints[0].scale, 2.0f);
  for (int j = 0; j < 128; ++j) EXPECT_EQ(f.descriptors.row(0)[j], s.keys_c[0].desc[j]);  // raw: as written

  // RootSIFT: a flat descriptor becomes sqrt(1/128) · 512 = 45.25 → 45 everywhere,
  // and any descriptor's RootSIFT has an L2 norm of ≈ 512 like our extractor's.
  uint8_t flat[128], out[128];
  std::fill(flat, flat + 128, 37);
  lowe_descriptor_to_root_sift(flat, out);
  for (int j = 0; j < 128; ++j) EXPECT_EQ(out[j], 45);
  FeatureSet r = read_lowe_key_file(s.dir / "images/a.key");
  ASSERT_EQ(r.size(), 3u);
  for (size_t i = 0; i < r.size(); ++i) {
    double l2 = 0;
    for (int j = 0; j < 128; ++j) l2 += double(r.descriptors.row(i)[j]) * r.descriptors.row(i)[j];
    EXPECT_NEAR(std::sqrt(l2), 512.0, 4.0);
  }

  // Mean descriptors through the Bundler descriptor source.
  BundlerModel bm = read_bundler_model(s.bundle, s.list);
  PointDescriptors pd = compute_point_descriptors(
      bm.model, [&](const ColmapImage& im) { return bm.descriptors(im); }, "bundler");
  ASSERT_EQ(pd.num_points, 2u);
  EXPECT_EQ(pd.track_size[0], 2u);
  FeatureSet c = read_lowe_key_file(s.dir / "images/c.key.gz");
  for (int j = 0; j < 128; ++j)
    EXPECT_FLOAT_EQ(pd.mean[j], 0.5f * (float(r.descriptors.row(2)[j]) + float(c.descriptors.row(0)[j])));
  for (int j = 0; j < 128; ++j) EXPECT_FLOAT_EQ(pd.mean[128 + j], float(r.descriptors.row(0)[j]));
}

TEST(Bundler, KeyFileSearch) {
  Scene s = make_scene("search");
  EXPECT_EQ(find_lowe_key_file(s.dir, {}, "images/a.png"), s.dir / "images/a.key");
  EXPECT_EQ(find_lowe_key_file(s.dir, {}, "images/c.png"), s.dir / "images/c.key.gz");
  EXPECT_EQ(find_lowe_key_file({}, s.dir / "images", "images/a.png"), s.dir / "images/a.key");  // file name alone
  const std::string e = error_of([&] { find_lowe_key_file(s.dir, {}, "images/b.png"); });
  EXPECT_NE(e.find("images/b.key"), std::string::npos) << e;
  // --keys: a separate folder.
  fs::create_directories(s.dir / "keys");
  fs::copy_file(s.dir / "images/a.key", s.dir / "keys/a.key");
  fs::copy_file(s.dir / "images/c.key.gz", s.dir / "keys/c.key.gz");
  fs::remove(s.dir / "images/a.key");
  BundlerConversionOptions o;
  o.keys_dir = s.dir / "keys";
  EXPECT_EQ(read_bundler_model(s.bundle, s.list, o).model.points.size(), 2u);
}

TEST(Bundler, ErrorsNameTheFileAndLine) {
  Scene s = make_scene("errors");
  auto expect_error = [&](const std::string& what, const std::vector<std::string>& parts) {
    const std::string e = error_of([&] { read_bundler_model(s.bundle, s.list); });
    for (const auto& p : parts) EXPECT_NE(e.find(p), std::string::npos) << what << ": " << e;
  };
  const std::string bundle = s.bundle.string();
  // Bad header.
  write_file_atomic(s.bundle, "# Bundle file v0.2\n" + s.bundle_text.substr(s.bundle_text.find('\n') + 1));
  expect_error("header", {bundle + ":1:", "v0.3"});
  // Truncated: the last point's view list is missing.
  write_file_atomic(s.bundle, s.bundle_text.substr(0, s.bundle_text.rfind("\n1 ")));
  expect_error("truncated", {bundle + ":", "point 2", "truncated"});
  // A view naming a key beyond a.key's 3 keys (line 20: the first point's views).
  {
    std::string t = s.bundle_text;
    const size_t at = t.find("\n3 0 2 ");
    t.replace(at, 7, "\n3 0 5 ");
    write_file_atomic(s.bundle, t);
    expect_error("key range", {bundle + ":20:", "key 5", "a.key", "3 keys"});
  }
  // A view naming a camera that does not exist.
  {
    std::string t = s.bundle_text;
    t.replace(t.find("\n3 0 2 "), 7, "\n3 7 2 ");
    write_file_atomic(s.bundle, t);
    expect_error("camera range", {bundle + ":20:", "camera 7"});
  }
  // A view list shorter than announced.
  {
    std::string t = s.bundle_text;
    t.replace(t.find("\n3 0 2 "), 3, "\n4 ");
    write_file_atomic(s.bundle, t);
    expect_error("view count", {bundle + ":20:", "announces 4 views"});
  }
  write_file_atomic(s.bundle, s.bundle_text);
  // The list does not match the cameras.
  write_file_atomic(s.list, "images/a.png\nimages/b.png\n");
  expect_error("list", {s.list.string(), "2 images", "3 cameras"});
  write_file_atomic(s.list, s.list_text);
  // Truncated key file: the header announces more keys than it holds.
  write_file_atomic(s.dir / "images/a.key", key_text(s.keys_a, 4));
  expect_error("truncated key file", {(s.dir / "images/a.key").string(), "keypoint 3", "truncated"});
  // A bad key header and a descriptor value out of range.
  write_file_atomic(s.dir / "images/a.key", "3 64\n");
  expect_error("key header", {(s.dir / "images/a.key").string() + ":1:", "128"});
  {
    auto keys = s.keys_a;
    keys[1].desc[5] = 300;
    write_file_atomic(s.dir / "images/a.key", key_text(keys, keys.size()));
    expect_error("key value", {(s.dir / "images/a.key").string(), "keypoint 1", "0..255", "300"});
  }
  write_file_atomic(s.dir / "images/a.key", key_text(s.keys_a, s.keys_a.size()));
  // A truncated gzip key file.
  {
    std::string gz = read_file(s.dir / "images/c.key.gz");
    write_file_atomic(s.dir / "images/c.key.gz", gz.substr(0, gz.size() / 2));
    expect_error("truncated gzip", {(s.dir / "images/c.key.gz").string()});
  }
  write_gzip(s.dir / "images/c.key.gz", key_text(s.keys_c, 1));
  EXPECT_NO_THROW(read_bundler_model(s.bundle, s.list));
  // A rotation that is not one.
  {
    std::string t = s.bundle_text;
    size_t line4 = 0;  // first row of A's R (line 3 holds f k1 k2)
    for (int i = 0; i < 3; ++i) line4 = t.find('\n', line4) + 1;
    t.insert(line4, "2");
    write_file_atomic(s.bundle, t);
    expect_error("rotation", {bundle + ":3:", "camera 0", "not a rotation"});
  }
}
