#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "visloc/geo/enu_frame.h"
#include "visloc/geo/gps_csv.h"
#include "visloc/geo/similarity_transform.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

fs::path write_temp(const std::string& name, const std::string& content) {
  fs::path p = unique_temp_path("visloc_geo_test_" + name);
  write_file_atomic(p, content);
  return p;
}

std::string read_error(const std::string& content) {
  fs::path p = write_temp("bad.csv", content);
  try {
    read_gps_csv(p);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(EnuFrame, OriginAndRoundTrip) {
  EnuFrame f({46.5188, 6.5668, 400.0});
  EXPECT_NEAR(f.to_enu({46.5188, 6.5668, 400.0}).norm(), 0.0, 1e-9);
  for (Eigen::Vector3d e : {Eigen::Vector3d(10, 20, 3), Eigen::Vector3d(-1500, 800, -20),
                            Eigen::Vector3d(15000, -15000, 100)}) {
    GeoPosition g = f.to_geo(e);
    EXPECT_NEAR((f.to_enu(g) - e).norm(), 0.0, 1e-6);
  }
  // North is +y: a point one arc-minute north is ~1852 m away (nautical mile).
  Eigen::Vector3d n = f.to_enu({46.5188 + 1.0 / 60, 6.5668, 400.0});
  EXPECT_NEAR(n.x(), 0.0, 1e-6);
  EXPECT_NEAR(n.y(), 1852.0, 4.0);
  EXPECT_LT(n.z(), 0.0);  // the ellipsoid curves away
}

TEST(EnuFrame, Heading) {
  EXPECT_NEAR(heading_deg_from_enu({0, 1, 0}), 0.0, 1e-12);
  EXPECT_NEAR(heading_deg_from_enu({1, 0, 0}), 90.0, 1e-12);
  EXPECT_NEAR(heading_deg_from_enu({-1, 0, 5}), 270.0, 1e-12);
}

TEST(EnuFrame, RejectsBadOrigin) { EXPECT_THROW(EnuFrame({95.0, 0.0, 0.0}), Error); }

TEST(GpsCsv, ReadsWithAndWithoutPlacemark) {
  fs::path p = write_temp("ok.csv",
                          "image,lat,lon,alt,placemark\n# comment\n\n"
                          "a.jpg, 46.5, 6.5, 400.5, 3\nb.jpg,46.6,6.4,,\n");
  auto r = read_gps_csv(p);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].image, "a.jpg");
  EXPECT_DOUBLE_EQ(r[0].position.alt, 400.5);
  EXPECT_EQ(r[0].placemark, 3);
  EXPECT_FALSE(r[1].placemark.has_value());
  EXPECT_DOUBLE_EQ(r[1].position.alt, 0.0);
  // Write and read back.
  fs::path q = unique_temp_path("visloc_geo_test_rt.csv");
  write_gps_csv(q, r);
  auto r2 = read_gps_csv(q);
  ASSERT_EQ(r2.size(), 2u);
  EXPECT_DOUBLE_EQ(r2[0].position.lat, 46.5);
  EXPECT_EQ(r2[0].placemark, 3);
}

TEST(GpsCsv, ErrorsNameFileAndLine) {
  std::string msg = read_error("image,lat,lon,alt\na.jpg,46.5,6.5,1\nb.jpg,north,6.5,1\n");
  EXPECT_NE(msg.find("bad.csv:3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("latitude 'north'"), std::string::npos) << msg;
  EXPECT_NE(read_error("a.jpg,46.5\n").find(":1: expected 4 or 5"), std::string::npos);
  EXPECT_NE(read_error("a.jpg,91,6,1\n").find("outside [-90, 90]"), std::string::npos);
  EXPECT_NE(read_error("a.jpg,1,2,3\na.jpg,1,2,3\n").find("listed twice"), std::string::npos);
  EXPECT_NE(read_error("a.jpg,1,2,3,-4\n").find("placemark"), std::string::npos);
  EXPECT_NE(read_error("image,lat,lon,alt\n").find("no GPS records"), std::string::npos);
  try {
    read_gps_csv("/nonexistent/gps.csv");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/gps.csv"), std::string::npos);
  }
}

// Real data: the Strecha gps.csv is the ground-truth centres expressed around a
// fixed origin; converting back must agree to well under a millimetre.
TEST(GpsCsv, StrechaCentresAgreeWithGroundTruth) {
  fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "gps.csv")) GTEST_SKIP() << "shared data absent: " << scene;
  EnuFrame frame({46.5188, 6.5668, 400.0});
  auto records = read_gps_csv(scene / "gps.csv");
  ASSERT_EQ(records.size(), 11u);
  double worst = 0;
  for (const auto& r : records) {
    std::ifstream cam(scene / "cameras" / (r.image + ".camera"));
    ASSERT_TRUE(cam) << r.image;
    double v[24];
    for (double& x : v) cam >> x;
    Eigen::Vector3d c(v[21], v[22], v[23]);
    worst = std::max(worst, (frame.to_enu(r.position) - c).norm());
  }
  EXPECT_LT(worst, 1e-3) << "worst ENU disagreement " << worst << " m";
}

TEST(Similarity, RecoversTransformWithOutliers) {
  Similarity3d truth;
  truth.scale = 3.7;
  truth.rotation = Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.2, -0.4, 1).normalized()).toRotationMatrix();
  truth.translation = {120, -40, 7};
  std::vector<Eigen::Vector3d> src, dst;
  for (int i = 0; i < 40; ++i) {
    Eigen::Vector3d x(std::sin(i * 0.7) * 10, i * 0.5, std::cos(i * 1.3) * 2);
    src.push_back(x);
    dst.push_back(truth.apply(x) + Eigen::Vector3d(0.01 * (i % 3), -0.01 * (i % 2), 0.005));
  }
  for (int i : {3, 17, 29}) dst[i] += Eigen::Vector3d(30, -25, 10);  // gross GPS errors
  SimilarityEstimate e = estimate_similarity_ransac(src, dst, {.inlier_threshold = 1.0});
  EXPECT_EQ(e.inlier_count, 37);
  EXPECT_FALSE(e.inliers[3]);
  EXPECT_NEAR(e.transform.scale, truth.scale, 1e-3);
  EXPECT_LT((e.transform.rotation - truth.rotation).norm(), 1e-3);
  EXPECT_LT(e.rms_residual, 0.05);
  EXPECT_GT(e.max_residual, 20);
  // Inverse composes to identity.
  Eigen::Vector3d x(1, 2, 3);
  EXPECT_LT((e.transform.inverse().apply(e.transform.apply(x)) - x).norm(), 1e-9);
  // Exhaustive path (few points) agrees.
  std::vector<Eigen::Vector3d> s8(src.begin(), src.begin() + 8), d8(dst.begin(), dst.begin() + 8);
  SimilarityEstimate e8 = estimate_similarity_ransac(s8, d8, {.inlier_threshold = 1.0});
  EXPECT_EQ(e8.inlier_count, 7);
  EXPECT_NEAR(e8.transform.scale, truth.scale, 1e-2);
}

TEST(Similarity, RejectsDegenerateInput) {
  std::vector<Eigen::Vector3d> line = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}};
  EXPECT_THROW(estimate_similarity(line, line), Error);
  EXPECT_THROW(estimate_similarity_ransac({{0, 0, 0}}, {{0, 0, 0}}), Error);
  SimilarityRansacOptions o;
  o.inlier_threshold = -1;
  EXPECT_THROW(o.validate(), Error);
}

TEST(Similarity, UprightRecoversCollinearStreet) {
  // Camera centres along one straight street: the full similarity is
  // ill-posed (rotation about the street), the upright one is not.
  Similarity3d truth;
  truth.scale = 0.8;
  const Eigen::Matrix3d tilt = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 0.3, 0).normalized()).toRotationMatrix();
  truth.rotation = Eigen::AngleAxisd(2.0, Eigen::Vector3d::UnitZ()).toRotationMatrix() * tilt;
  truth.translation = {5, -7, 1};
  const Eigen::Vector3d up_src = tilt.transpose() * Eigen::Vector3d::UnitZ();  // src vector mapped to ENU up
  std::vector<Eigen::Vector3d> src, dst;
  for (int i = 0; i < 12; ++i) {
    Eigen::Vector3d x = Eigen::Vector3d(3.0 * i, 0.0, 0.0);
    src.push_back(x);
    dst.push_back(truth.apply(x));
  }
  dst[4] += Eigen::Vector3d(0, 20, 0);
  SimilarityEstimate e = estimate_upright_similarity_ransac(src, dst, up_src, {.inlier_threshold = 1.0});
  EXPECT_EQ(e.inlier_count, 11);
  EXPECT_NEAR(e.transform.scale, 0.8, 1e-9);
  EXPECT_LT((e.transform.rotation - truth.rotation).norm(), 1e-9);
  Eigen::Vector3d off(1, 2, 3);  // a point off the street maps right too
  EXPECT_LT((e.transform.apply(off) - truth.apply(off)).norm(), 1e-9);
}

TEST(Similarity, StreetFitUsesFullSimilarityWhenCentresSpreadIn2D) {
  // An L-shaped route (a turn); the cameras' up axis is off by 1° from the
  // true vertical, so the upright fit leaves residuals, the full fit does not.
  Similarity3d truth;
  truth.scale = 1.3;
  truth.rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                   Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  truth.translation = {1, 2, 3};
  const Eigen::Vector3d true_up_src = truth.rotation.transpose() * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d biased_up = Eigen::AngleAxisd(1.0 * M_PI / 180, Eigen::Vector3d::UnitY()) * true_up_src;
  std::vector<Eigen::Vector3d> src, dst;
  for (int i = 0; i < 10; ++i) src.push_back({4.0 * i, 0, 0});
  for (int i = 1; i < 10; ++i) src.push_back({36, 4.0 * i, 0});
  for (const auto& x : src) dst.push_back(truth.apply(x));
  const SimilarityRansacOptions o{.inlier_threshold = 5.0};
  const SimilarityEstimate upright = estimate_upright_similarity_ransac(src, dst, biased_up, o);
  EXPECT_GT(upright.rms_residual, 0.1);
  const SimilarityEstimate street = estimate_street_similarity_ransac(src, dst, biased_up, o);
  EXPECT_LT(street.rms_residual, 1e-6);
  // Collinear centres: the full fit is ill-posed, the upright one is kept.
  src.resize(10);
  dst.resize(10);
  const SimilarityEstimate line = estimate_street_similarity_ransac(src, dst, true_up_src, o);
  EXPECT_LT(line.rms_residual, 1e-6);
  EXPECT_LT((line.transform.rotation - truth.rotation).norm(), 1e-6);
}

TEST(GpsCsv, AcceptsAUtf8ByteOrderMark) {
  fs::path p = write_temp("bom.csv", "\xEF\xBB\xBFimage,lat,lon,alt\na.jpg,46.5,6.5,400\nb.jpg,46.6,6.4,401\n");
  auto r = read_gps_csv(p);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].image, "a.jpg");
}
