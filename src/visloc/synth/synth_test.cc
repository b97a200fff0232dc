// Tests of the synthetic city: layout, option validation, renderer geometry
// against PinholeCamera/CameraPose projection, the pose files written by
// write_city against the renderer, determinism independent of threads,
// resume, and SIFT matches between neighbouring placemarks under the true
// relative pose.
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <set>
#include <sstream>
#include <tuple>

#include "visloc/features/sift_extractor.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/synth/city_scene.h"
#include "visloc/synth/city_writer.h"
#include "visloc/synth/ray_renderer.h"
#include "visloc/synth/view_pair_check.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace visloc::synth {
namespace {

namespace fs = std::filesystem;

fs::path fresh_dir(const std::string& name) {
  const fs::path p = unique_temp_path("visloc_synth_test_" + name);
  fs::remove_all(p);
  return p;
}

// Expects `fn` to throw Error(kInvalidArgument) whose message contains `field`.
template <typename Fn>
void expect_rejected(Fn fn, const std::string& field) {
  try {
    fn();
    ADD_FAILURE() << "no error for " << field;
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

// Coverage-weighted centroid of a red marker: alpha per pixel from the
// image with the marker and the same view without it (box-filtered
// supersampling makes a pixel alpha·red + (1 - alpha)·background).
std::optional<Eigen::Vector2d> marker_centroid(const uint8_t* with, const uint8_t* without, int w, int h) {
  double sx = 0, sy = 0, sa = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const uint8_t* a = with + (static_cast<size_t>(y) * w + x) * 3;
      const uint8_t* b = without + (static_cast<size_t>(y) * w + x) * 3;
      const double d[3] = {255.0 - b[0], -double(b[1]), -double(b[2])};
      const double n2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
      if (n2 < 400) continue;
      const double alpha = ((a[0] - b[0]) * d[0] + (a[1] - b[1]) * d[1] + (a[2] - b[2]) * d[2]) / n2;
      if (alpha < 0.02) continue;
      sx += alpha * (x + 0.5);
      sy += alpha * (y + 0.5);
      sa += alpha;
    }
  if (sa < 1.0) return std::nullopt;
  return Eigen::Vector2d(sx / sa, sy / sa);
}

CityOptions tiny_city() {
  CityOptions o;
  o.layout.road_length_m = 40;
  o.layout.seed = 7;
  o.views.headings = 2;
  o.views.elevations_deg = {10};
  o.views.width = 64;
  o.views.height = 48;
  o.queries.count = 3;
  o.queries.resolutions = {{80, 60}, {60, 80}};
  o.image_format = "png";
  return o;
}

TEST(CityLayout, DeterministicWithPlacemarksEvery10To12Metres) {
  CityLayoutOptions o;
  o.road_length_m = 300;
  const CityScene a = generate_city_scene(o), b = generate_city_scene(o);
  ASSERT_EQ(a.objects.boxes.size(), b.objects.boxes.size());
  for (size_t i = 0; i < a.objects.boxes.size(); ++i) {
    EXPECT_EQ(a.objects.boxes[i].cx, b.objects.boxes[i].cx);
    EXPECT_EQ(a.objects.boxes[i].seed, b.objects.boxes[i].seed);
  }
  EXPECT_GT(a.buildings, 20);
  ASSERT_GE(a.placemarks.size(), 25u);
  for (size_t i = 1; i < a.placemarks.size(); ++i) {
    const double d = (a.placemarks[i].position - a.placemarks[i - 1].position).norm();
    EXPECT_GE(d, 10.0 - 1e-9);
    EXPECT_LE(d, 12.0 + 1e-9);
  }
  // No building stands on the road or sidewalk, and no camera is inside one.
  for (const auto& box : a.objects.boxes) {
    for (double x = -150; x <= 150; x += 0.5)
      EXPECT_GE(footprint_distance(box, Eigen::Vector2d(x, 0.0)), o.road_half_width_m + o.sidewalk_width_m - 1e-6);
  }
  // Headings are clockwise from north, as GPS headings: heading 63° at
  // pitch 0 looks along (sin 63°, cos 63°, 0); image y points down.
  const CameraPose view = street_view_pose(a.placemarks[0].position, 63.0, 0.0);
  EXPECT_NEAR(heading_deg_from_enu(view.viewing_direction()), 63.0, 1e-9);
  EXPECT_NEAR((view.rotation.conjugate() * Eigen::Vector3d::UnitY()).z(), -1.0, 1e-12);
  CityLayoutOptions other = o;
  other.seed = 2;
  EXPECT_NE(generate_city_scene(other).objects.boxes[0].cx, a.objects.boxes[0].cx);
}

TEST(CityLayout, GridAndRandomLayoutsKeepBuildingsOffRoads) {
  for (const RoadLayout layout : {RoadLayout::kGrid, RoadLayout::kRandom}) {
    CityLayoutOptions o;
    o.layout = layout;
    o.road_length_m = 250;
    const CityScene s = generate_city_scene(o);
    EXPECT_GT(s.buildings, 10) << to_string(layout);
    EXPECT_GT(s.placemarks.size(), 20u) << to_string(layout);
    for (const auto& pm : s.placemarks)
      for (const auto& box : s.objects.boxes)
        EXPECT_GE(footprint_distance(box, pm.position.head<2>()), o.road_half_width_m + o.sidewalk_width_m - 1e-6);
  }
}

// With building_designs = N, the buildings repeat N designs: identical
// frontage, height and facade seed (so identical facades); by default every
// building is its own.
TEST(CityLayout, BuildingDesignsRepeatIdenticalFacades) {
  // The main box of each building (a wing follows its main box and copies
  // its style index): its facade seed, frontage, depth, height, style seed
  // and its wing's shape (0 without one).
  const auto main_boxes = [](const CityScene& s) {
    std::set<std::tuple<uint64_t, double, double, double, uint64_t, double, double, double>> designs;
    size_t count = 0;
    const auto& boxes = s.objects.boxes;
    for (size_t i = 0; i < boxes.size(); ++i) {
      const auto& b = boxes[i];
      if (b.kind != ObjectKind::kBuilding || (i > 0 && boxes[i - 1].style == b.style)) continue;
      const bool wing = i + 1 < boxes.size() && boxes[i + 1].style == b.style;
      const BoxPrimitive none{};
      const BoxPrimitive& w = wing ? boxes[i + 1] : none;
      designs.insert({b.seed, b.half_x, b.half_y, b.z_max, s.styles[b.style].seed, w.half_x, w.half_y, w.z_max});
      ++count;
    }
    return std::pair(designs.size(), count);
  };
  CityLayoutOptions o;
  o.road_length_m = 300;
  const auto [unique_designs, unique_count] = main_boxes(generate_city_scene(o));
  EXPECT_GT(unique_count, 20u);
  EXPECT_EQ(unique_designs, unique_count);
  o.building_designs = 3;
  const auto [designs, count] = main_boxes(generate_city_scene(o));
  EXPECT_GT(count, 15u);
  EXPECT_GE(designs, 2u);
  EXPECT_LE(designs, 3u);
  // With a share, the others are their own designs.
  o.building_design_share = 0.3;
  const auto [some_designs, some_count] = main_boxes(generate_city_scene(o));
  EXPECT_GT(some_designs, 5u);
  EXPECT_LT(some_designs, some_count);
  CityLayoutOptions bad;
  bad.building_designs = -1;
  expect_rejected([&] { bad.validate(); }, "building_designs");
  bad.building_designs = 2;
  bad.building_design_share = 1.5;
  expect_rejected([&] { bad.validate(); }, "building_design_share");
  bad.building_designs = 0;
  bad.building_design_share = 0.3;  // without designs it would do nothing
  expect_rejected([&] { bad.validate(); }, "building_design_share");
}

TEST(Options, BadValuesAreRejectedNamingTheField) {
  expect_rejected([] { CityLayoutOptions o; o.floors_max = 1; o.floors_min = 3; o.validate(); }, "floors_max");
  expect_rejected([] { CityLayoutOptions o; o.placemark_spacing_min_m = 0; o.validate(); }, "placemark_spacing_min_m");
  expect_rejected([] { parse_road_layout("spiral"); }, "layout");
  expect_rejected([] { ViewSetOptions o; o.fov_deg = 179; o.validate(); }, "fov_deg");
  expect_rejected([] { ViewSetOptions o; o.elevations_deg.clear(); o.validate(); }, "elevations_deg");
  expect_rejected([] { QueryOptions o; o.resolutions = {{0, 10}}; o.validate(); }, "resolutions");
  expect_rejected([] { QueryOptions o; o.blur_max_px = -1; o.validate(); }, "blur_max_px");
  expect_rejected([] { RenderOptions o; o.supersampling = 0; o.validate(); }, "supersampling");
  expect_rejected([] { CityOptions o; o.image_format = "gif"; o.validate(); }, "image_format");
  expect_rejected([] { CityOptions o; o.jobs = 0; o.validate(); }, "jobs");
  expect_rejected([] { CityOptions o; o.origin.lat = 91; o.validate(); }, "origin.lat");
}

// A marker at a known 3D point appears where the camera model projects it,
// for a rotated camera with an off-centre principal point.
TEST(Renderer, MarkerAppearsAtItsProjection) {
  CityLayoutOptions lo;
  lo.road_length_m = 100;
  CityScene scene = generate_city_scene(lo);
  const CityScene background = scene;
  PinholeCamera camera = PinholeCamera::centered(160, 120, 140.0);
  camera.cx = 70.3;
  camera.cy = 66.8;
  const Eigen::Vector3d center(-3.0, -1.0, 2.5);
  const CameraPose pose = street_view_pose(center, 63.0, 8.0, 4.0);  // heading, pitch, roll
  std::vector<Eigen::Vector3d> markers = {center + Eigen::Vector3d(7.0, 3.0, 0.9),
                                          center + Eigen::Vector3d(8.0, 1.5, -0.4),
                                          center + Eigen::Vector3d(6.0, 5.5, 1.0)};
  RenderOptions ro;
  ro.supersampling = 4;
  RgbImage without;
  ViewRenderer(background, nullptr, ro).render(camera, pose, without);
  for (const auto& m : markers) {
    CityScene with_marker = background;
    SpherePrimitive s;
    s.center = m;
    s.radius = 0.12;
    s.kind = ObjectKind::kMarker;
    s.colour = {1, 0, 0};
    with_marker.objects.spheres.push_back(s);
    RgbImage with;
    ViewRenderer(with_marker, nullptr, ro).render(camera, pose, with);
    const Eigen::Vector2d expected = camera.project(pose.transform(m));
    ASSERT_TRUE(camera.contains(expected));
    const auto seen = marker_centroid(with.pixels.data(), without.pixels.data(), camera.width, camera.height);
    ASSERT_TRUE(seen.has_value());
    EXPECT_LT((*seen - expected).norm(), 0.25) << "expected " << expected.transpose() << " seen " << seen->transpose();
  }
  // The ray caster agrees: a ray towards the marker stops at its surface.
  ViewRenderer r(background, nullptr, ro);
  const Eigen::Vector3d down(0, 0, -1);
  const auto t = r.cast_ray(center, down);
  ASSERT_TRUE(t.has_value());
  EXPECT_NEAR(*t, 2.5, 1e-9);
}

// write_city's COLMAP files and GPS agree with what the images show.
TEST(CityWriter, PoseFilesAgreeWithRenderedImages) {
  CityOptions o = tiny_city();
  o.views.width = 160;
  o.views.height = 120;
  o.queries.count = 0;
  const CityScene scene = generate_city_scene(o.layout);
  const Eigen::Vector3d pm0 = scene.placemarks[0].position;
  // Heading index 0 looks north, heading index 1 south.
  o.markers = {pm0 + Eigen::Vector3d(1.0, 5.0, 1.2), pm0 + Eigen::Vector3d(-0.8, -4.0, 0.9)};
  o.marker_radius_m = 0.1;
  o.render.supersampling = 3;
  const fs::path dir = fresh_dir("poses");
  write_city(o, dir);

  // cameras.txt
  std::ifstream cams(dir / "sparse" / "cameras.txt");
  std::string line;
  PinholeCamera camera;
  while (std::getline(cams, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    int id;
    std::string model;
    double fy;
    s >> id >> model >> camera.width >> camera.height >> camera.focal >> fy >> camera.cx >> camera.cy;
    EXPECT_EQ(model, "PINHOLE");
    EXPECT_EQ(camera.focal, fy);
    camera.has_focal = true;
  }
  EXPECT_EQ(camera.width, 160);
  EXPECT_NEAR(camera.focal, 80.0, 1e-9);  // 90° field of view
  // images.txt
  std::map<std::string, CameraPose> poses;
  std::ifstream images(dir / "sparse" / "images.txt");
  while (std::getline(images, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    int id, cam;
    std::array<double, 4> q;
    Eigen::Vector3d t;
    std::string name;
    s >> id >> q[0] >> q[1] >> q[2] >> q[3] >> t[0] >> t[1] >> t[2] >> cam >> name;
    poses[name] = CameraPose::from_wxyz(q, t);
    std::getline(images, line);  // empty 2D point line
    EXPECT_TRUE(line.empty());
  }
  ASSERT_EQ(poses.size(), scene.placemarks.size() * 2);
  RenderOptions ro = o.render;
  ViewRenderer background(scene, nullptr, ro);
  for (size_t k = 0; k < 2; ++k) {
    const std::string name = database_image_name(0, static_cast<int>(k), 0) + ".png";
    ASSERT_TRUE(poses.count(name)) << name;
    const CameraPose& pose = poses[name];
    EXPECT_LT((pose.center() - pm0).norm(), 1e-9);
    cv::Mat bgr = cv::imread((dir / "images" / name).string(), cv::IMREAD_COLOR);
    ASSERT_FALSE(bgr.empty());
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    RgbImage without;
    background.render(camera, pose, without);
    const auto seen = marker_centroid(rgb.data, without.pixels.data(), camera.width, camera.height);
    const Eigen::Vector2d expected = camera.project(pose.transform(o.markers[k]));
    ASSERT_TRUE(seen.has_value()) << name;
    EXPECT_LT((*seen - expected).norm(), 0.3) << name << ": expected " << expected.transpose() << " seen "
                                              << seen->transpose();
  }
  // gps.csv: every database image at its camera centre.
  const EnuFrame enu(o.origin);
  const auto gps = read_gps_csv(dir / "gps.csv");
  ASSERT_EQ(gps.size(), poses.size());
  for (const auto& r : gps) {
    EXPECT_LT((enu.to_enu(r.position) - poses[r.image].center()).norm(), 1e-4) << r.image;
    ASSERT_TRUE(r.placemark.has_value());
    EXPECT_EQ(r.image.substr(1, 5), (std::ostringstream() << std::setw(5) << std::setfill('0') << *r.placemark).str());
  }
  fs::remove_all(dir);
}

// Same seed, same bytes, whatever the number of threads; --resume keeps
// finished files and refuses other options.
TEST(CityWriter, DeterministicAcrossThreadsAndResumable) {
  CityOptions o = tiny_city();
  o.queries.cars_max = 3;
  o.queries.trees_max = 2;
  const fs::path d1 = fresh_dir("det1"), d2 = fresh_dir("det2");
  const CityStats s1 = write_city(o, d1);
  o.jobs = 2;
  size_t last_done = 0;
  const CityStats s2 = write_city(o, d2, [&](const CityProgress& p) { last_done = p.done; });
  EXPECT_EQ(last_done, s2.database_images + s2.query_images);
  EXPECT_EQ(s1.rendered, s1.database_images + s1.query_images);
  EXPECT_EQ(s1.database_bytes + s1.query_bytes, s2.database_bytes + s2.query_bytes);
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(d1)) {
    if (!e.is_regular_file()) continue;
    const fs::path rel = fs::relative(e.path(), d1);
    EXPECT_EQ(read_file(e.path()), read_file(d2 / rel)) << rel;
    ++files;
  }
  EXPECT_EQ(files, s1.database_images + s1.query_images + 10);  // 10 metadata files
  // Queries: list, truth and intrinsics agree.
  const std::string truth = read_file(d1 / "queries" / "truth.txt");
  const QuerySpec q0 = make_query(generate_city_scene(o.layout), o, 0);
  EXPECT_EQ(truth.substr(0, truth.find(' ')), "q00000.png");
  std::istringstream ts(truth.substr(truth.find(' ')));
  std::array<double, 4> q;
  Eigen::Vector3d t;
  ts >> q[0] >> q[1] >> q[2] >> q[3] >> t[0] >> t[1] >> t[2];
  EXPECT_LT((CameraPose::from_wxyz(q, t).center() - q0.cam_from_world.center()).norm(), 1e-9);

  // Resume: nothing to render again.
  o.resume = true;
  fs::remove(d2 / "images" / (database_image_name(1, 1, 0) + ".png"));
  const CityStats s3 = write_city(o, d2);
  EXPECT_EQ(s3.rendered, 1u);
  EXPECT_EQ(read_file(d1 / "images" / (database_image_name(1, 1, 0) + ".png")),
            read_file(d2 / "images" / (database_image_name(1, 1, 0) + ".png")));
  o.layout.seed = 8;
  expect_rejected([&] { write_city(o, d2); }, "different options");
  o.resume = false;
  expect_rejected([&] { write_city(o, d2); }, "--resume");
  fs::remove_all(d1);
  fs::remove_all(d2);
}

TEST(Queries, PhotometricChangesAndOccludersAreSeeded) {
  CityOptions o;
  o.layout.road_length_m = 120;
  o.queries.cars_max = 3;
  o.queries.trees_max = 2;
  const CityScene scene = generate_city_scene(o.layout);
  int with_occluders = 0;
  for (int i = 0; i < 20; ++i) {
    const QuerySpec q = make_query(scene, o, i);
    const QuerySpec again = make_query(scene, o, i);
    EXPECT_EQ(q.cam_from_world.translation, again.cam_from_world.translation);
    EXPECT_GE(q.fov_deg, o.queries.fov_min_deg);
    EXPECT_LE(q.fov_deg, o.queries.fov_max_deg);
    const Eigen::Vector3d c = q.cam_from_world.center();
    EXPECT_GE(c.z(), o.queries.height_min_m);
    EXPECT_LE(std::abs(c.y()), o.layout.road_half_width_m + o.layout.sidewalk_width_m);
    for (const auto& b : scene.objects.boxes) EXPECT_FALSE(footprint_contains(b, c.head<2>()));
    if (q.cars + q.trees > 0) ++with_occluders;
  }
  EXPECT_GT(with_occluders, 5);
  // Exposure, blur and noise change pixels, the same way each time.
  QuerySpec q = make_query(scene, o, 0);
  q.exposure = 1.4;
  q.blur_px = 1.0;
  q.noise = 4.0;
  RgbImage img;
  img.width = 8;
  img.height = 8;
  img.pixels.assign(8 * 8 * 3, 100);
  RgbImage a = img, b = img;
  apply_photometric(q, a);
  apply_photometric(q, b);
  EXPECT_EQ(a.pixels, b.pixels);
  double mean = 0;
  for (uint8_t v : a.pixels) mean += v;
  mean /= a.pixels.size();
  EXPECT_GT(mean, 100 * std::pow(1.4 * 100 / 255.0, q.gamma) * 255 / 100 - 3);
  EXPECT_NE(a.pixels, img.pixels);
}

// SIFT between views of two neighbouring placemarks (same heading, facing
// the facades) verifies under the true relative pose, and fails under a
// wrong one.
TEST(ViewPairs, SiftMatchesVerifyUnderTrueRelativePose) {
  CityLayoutOptions lo;
  lo.road_length_m = 80;
  const CityScene scene = generate_city_scene(lo);
  RenderOptions ro;
  ViewRenderer renderer(scene, nullptr, ro);
  const PinholeCamera camera = camera_from_fov(640, 640, 90.0);
  const auto& a = scene.placemarks[2];
  const auto& b = scene.placemarks[3];
  const CameraPose pa = street_view_pose(a.position, 0.0, 5.0), pb = street_view_pose(b.position, 0.0, 5.0);
  RgbImage ia, ib;
  renderer.render(camera, pa, ia);
  renderer.render(camera, pb, ib);
  SiftExtractor sift;
  const auto features = [&](const RgbImage& im) {
    GrayImage g;
    g.width = im.width;
    g.height = im.height;
    g.pixels = to_gray(im);
    return sift.extract(g);
  };
  const FeatureSet fa = features(ia), fb = features(ib);
  const ViewPairCheck good = check_view_pair(renderer, fa, camera, pa, fb, camera, pb);
  EXPECT_GT(good.features_a, 300u);
  EXPECT_GT(good.ratio_matches, 100u);
  EXPECT_GT(good.epipolar_precision(), 0.75) << good.epipolar_inliers << " / " << good.ratio_matches;
  EXPECT_GT(good.precision(), 0.7) << good.true_matches << " / " << good.ratio_matches;
  EXPECT_GT(good.true_fraction_of_covisible(), 0.15);
  // A pose 1 m and 3° off: the same matches no longer verify.
  const CameraPose wrong = street_view_pose(b.position + Eigen::Vector3d(0.0, 1.0, 0.0), 3.0, 5.0);
  const ViewPairCheck bad = check_view_pair(renderer, fa, camera, pa, fb, camera, wrong);
  EXPECT_LT(bad.epipolar_precision(), 0.5 * good.epipolar_precision());
  EXPECT_LT(bad.precision(), 0.2);
}

TEST(PhotoCrops, LoadsSeededCropsOrNamesTheMissingFolder) {
  try {
    load_photo_crops("/nonexistent/photos", {});
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/photos"), std::string::npos);
  }
  const fs::path dir = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11" / "images";
  if (!fs::exists(dir)) GTEST_SKIP() << "shared data absent: " << dir;
  PhotoCropOptions po;
  po.count = 3;
  po.size = 32;
  const PhotoCropSet a = load_photo_crops(dir, po), b = load_photo_crops(dir, po);
  ASSERT_EQ(a.size(), 3u);
  const Rgb ca = a.sample(1, 0.3, 0.6), cb = b.sample(1, 0.3, 0.6);
  EXPECT_EQ(ca.r, cb.r);
  EXPECT_EQ(ca.g, cb.g);
  EXPECT_EQ(ca.b, cb.b);
}

}  // namespace
}  // namespace visloc::synth
