#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <set>
#include <string>

#include "visloc/colmap/colmap_database.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/map_building/colmap_import.h"
#include "visloc/map/map.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/error.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(PaperSetting, ParsesAndRejects) {
  EXPECT_EQ(parse_paper_setting("3+"), PaperSetting::k3Plus);
  EXPECT_EQ(to_string(parse_paper_setting("2")), "2");
  EXPECT_THROW(parse_paper_setting("4"), Error);
}

TEST(LocalizerOptions, MinConfidenceMustBeAProbability) {
  for (double bad : {-0.1, 1.5, std::nan("")}) {
    LocalizerOptions o;
    o.min_confidence = bad;
    EXPECT_THROW(o.validate(), Error) << bad;
  }
  LocalizerOptions o;
  EXPECT_EQ(o.min_confidence, kDefaultMinConfidence);
  o.min_confidence = 0;
  EXPECT_NO_THROW(o.validate());
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
  // 16-byte PQ codes in both paper settings; 32-byte codes (segment format
  // version 4) and 16-byte residual codes (codebook format 3; trained fast:
  // plain k-means, a beam of 1) in the default one.
  for (const auto& [pq_bytes, residual] : {std::pair{16, false}, std::pair{32, false}, std::pair{16, true}}) {
    SCOPED_TRACE(std::to_string(pq_bytes) + "-byte " + (residual ? "residual" : "PQ") + " codes");
    const fs::path map_dir =
        unique_temp_path("visloc_pipeline_test_fountain_pq" + std::to_string(pq_bytes) + (residual ? "_residual" : ""));
    fs::remove_all(map_dir);
    ColmapImportOptions io;
    io.holdout_images = read_name_list(scene / "queries.txt");
    io.itq.iterations = 10;
    io.pq.max_training = 20000;
    io.pq.iterations = 10;
    io.pq.subvectors = pq_bytes;
    if (residual) {
      io.pq.quantizer = PqQuantizer::kResidual;
      io.pq.residual_progressive_dim = false;
      io.pq.residual_beam = 1;
    }
    import_colmap_map(scene / "colmap" / "sparse", scene / "colmap" / "database.db", map_dir, io);
    ASSERT_EQ(Map::open(map_dir).open_segment(0)->index().pq_subvectors, pq_bytes);
    ASSERT_EQ(Map::open(map_dir).codebook().is_residual(), residual);
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
      if ((pq_bytes == 32 || residual) && setting != LocalizerOptions{}.setting) continue;
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
    fs::remove_all(map_dir);
  }
}

#include "visloc/map_building/map_builder.h"
#include "visloc/sfm/process.h"
#include "visloc/synth/city_writer.h"

// The whole system on a small synthetic street: render, build a map with
// COLMAP from the known poses, localize queries from other cameras. Skips
// when the colmap binary is absent.
// Point votes (segment_point_votes.h): the street's map rebuilt with small
// segments, more of them than are searched, and no retrieval index: the
// query features' nearest map points choose the one segment searched.
void expect_point_votes_choose_the_segment(const fs::path& dir, const MapBuildOptions& shared,
                                           const std::map<std::string, CameraPose>& truth,
                                           const std::map<std::string, PinholeCamera>& cams) {
  MapBuildOptions small = shared;
  small.plan.min_placemarks = small.plan.max_placemarks = 3;
  small.plan.overlap = 1;
  const MapBuildResult smaller = build_map(dir / "map", small);
  ASSERT_EQ(smaller.failed(), 0u);
  ASSERT_GE(smaller.segments.size(), 2u);
  LocalizerOptions one;
  one.max_segments = 1;
  one.fallback_segments = 0;
  one.segment_votes = SegmentVoteSource::kPoints;
  Localizer voted(dir / "map", one);
  EXPECT_TRUE(voted.has_point_votes());
  EXPECT_GT(voted.point_vote_bytes(), 0u);
  int voted_accurate = 0, elsewhere_measured = 0;
  std::set<std::string> registered_in_first;
  for (const auto& [name, pose] : truth) {
    const LocalizationResult r = voted.localize_file(dir / "city" / "queries" / "images" / name, cams.at(name));
    if (r.registered) registered_in_first.insert(name);
    ASSERT_EQ(r.retrieval_segments.size(), 1u) << name;
    EXPECT_EQ(r.candidates, r.retrieval_segments) << name;
    EXPECT_GT(r.retrieval_votes[0], 0.0f);
    EXPECT_FLOAT_EQ(r.retrieval_total_votes, 1.0f);  // the point votes' shares
    voted_accurate += r.registered && position_error(r.cam_from_segment, pose) < 0.5;
    // A street of buildings of their own: a right pose's inliers are seen
    // in its segment or a neighbour sharing images with it, rarely elsewhere.
    if (r.registered && position_error(r.cam_from_segment, pose) < 0.5)
      EXPECT_LT(r.confidence_features.elsewhere, 0.5) << name;
    elsewhere_measured += r.registered && r.confidence_features.elsewhere != kElsewhereWhenUnknown;
  }
  EXPECT_GE(elsewhere_measured, 1) << "no registered pose had its inliers' votes";
  EXPECT_GE(voted_accurate, 2) << "of " << truth.size() << " queries, searching only the best-voted segment";
  // With one fallback segment: the two best-voted are candidates, and the
  // second is searched exactly when the first gives no registered pose
  // (every query, when nothing can register).
  LocalizerOptions with_fallback = one;
  with_fallback.fallback_segments = 1;
  for (const bool can_register : {true, false}) {
    if (!can_register) with_fallback.ransac.min_inliers = 1u << 30;
    Localizer fallback(dir / "map", with_fallback);
    int searched = 0;
    for (const auto& [name, pose] : truth) {
      const LocalizationResult r = fallback.localize_file(dir / "city" / "queries" / "images" / name, cams.at(name));
      ASSERT_GE(r.retrieval_segments.size(), 1u) << name;
      ASSERT_LE(r.retrieval_segments.size(), 2u) << name;
      ASSERT_FALSE(r.candidates.empty()) << name;
      EXPECT_EQ(r.candidates[0], r.retrieval_segments[0]) << name;
      const bool second_searched = r.candidates.size() == 2;
      searched += second_searched;
      EXPECT_EQ(r.fallback_segments_searched, second_searched) << name;
      if (r.retrieval_segments.size() == 2 && !r.registered) {
        EXPECT_TRUE(second_searched) << name;
        EXPECT_EQ(r.candidates[1], r.retrieval_segments[1]) << name;
      }
      if (!can_register) EXPECT_FALSE(r.registered) << name;
      // Registered in the first candidate without the fallback: not searched.
      if (can_register && registered_in_first.count(name)) EXPECT_FALSE(second_searched) << name;
      // Registered through the fallback: its pose is the second segment's.
      if (r.registered && second_searched) EXPECT_EQ(r.segment, r.candidates[1]) << name;
    }
    if (!can_register) EXPECT_GT(searched, 0) << "no query searched its fallback segment";
  }
  // Image votes alone need the retrieval index, which this map has not.
  one.segment_votes = SegmentVoteSource::kImages;
  EXPECT_THROW(Localizer(dir / "map", one), Error);
}

// A 16-byte map is not resumed as a 32-byte one: a clear refusal that names
// the option to give, and nothing changed (the next build reuses its
// segments). Without --pq-bytes a build keeps the map's code size.
void expect_other_pq_bytes_refused(const fs::path& map_dir, const MapBuildOptions& built) {
  MapBuildOptions finer = built;
  finer.pq.subvectors = 32;
  EXPECT_EQ(resolve_pq_code_bytes(map_dir, finer), 16);
  finer.pq_code_bytes = 32;
  try {
    build_map(map_dir, finer);
    ADD_FAILURE() << "a 16-byte map resumed with 32-byte codes";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--pq-bytes 16"), std::string::npos) << e.what();
  }
  EXPECT_EQ(Map::open(map_dir).codebook().subvectors(), 16);
  EXPECT_TRUE(build_map(map_dir, built).segments[0].reused);
}

// Another segment plan in the same directory: segments whose images differ
// are built again, never reused from the earlier plan; and back.
void expect_other_plan_rebuilt(const fs::path& map_dir, const MapBuildOptions& mb, size_t segments) {
  MapBuildOptions other = mb;
  other.plan.min_placemarks = other.plan.max_placemarks = 3;
  other.plan.overlap = 1;
  const MapBuildResult changed = build_map(map_dir, other);
  ASSERT_GT(changed.segments.size(), segments);
  EXPECT_FALSE(changed.segments[0].reused);
  const MapBuildResult back = build_map(map_dir, mb);
  ASSERT_EQ(back.segments.size(), segments);
  EXPECT_FALSE(back.segments[0].reused);
  EXPECT_EQ(back.failed(), 0u);
}

// Queries registered within 0.5 m of their true centre.
int accurate_queries(const Localizer& localizer, const fs::path& images, const std::map<std::string, CameraPose>& truth,
                     const std::map<std::string, PinholeCamera>& cams) {
  int accurate = 0;
  for (const auto& [name, pose] : truth) {
    const LocalizationResult r = localizer.localize_file(images / name, cams.at(name));
    EXPECT_TRUE(r.error.empty()) << r.error;
    accurate += r.registered && position_error(r.cam_from_segment, pose) < 0.5;
  }
  return accurate;
}

TEST(Localizer, EndToEndOnSyntheticStreet) {
  if (!program_exists("colmap")) GTEST_SKIP() << "colmap is not installed";
  const fs::path dir = unique_temp_path("visloc_pipeline_test_city");
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
  mb.hash_rotation = HashRotationScope::kSegment;  // one per segment first; the map's below
  MapBuildResult built = build_map(dir / "map", mb);
  ASSERT_EQ(built.failed(), 0u) << built.segments[0].error;
  ASSERT_GE(built.segments.size(), 1u);
  EXPECT_GT(built.segments[0].points, 500u);
  EXPECT_LT(built.segments[0].registration_max_m, 0.01);  // known poses are ENU exactly
  // A second run reuses the finished segments.
  MapBuildResult again = build_map(dir / "map", mb);
  EXPECT_TRUE(again.segments[0].reused);
  expect_other_plan_rebuilt(dir / "map", mb, built.segments.size());
  // One hash rotation for the map: segments made with their own are built
  // again (never searched with another rotation), then reused; an update with
  // the other scope is refused rather than dropping segments. The queries
  // below are localized on this map (a query hashed once for all segments).
  MapBuildOptions shared = mb;
  shared.hash_rotation = HashRotationScope::kMap;
  const MapBuildResult rotated = build_map(dir / "map", shared);
  EXPECT_FALSE(rotated.segments[0].reused);
  EXPECT_EQ(rotated.failed(), 0u);
  ASSERT_TRUE(fs::exists(dir / "map" / kHashRotationFileName));
  EXPECT_EQ(read_manifest(dir / "map").hash_rotation_file, kHashRotationFileName);
  EXPECT_TRUE(build_map(dir / "map", shared).segments[0].reused);
  expect_other_pq_bytes_refused(dir / "map", shared);
  if (rotated.segments.size() > 1) {
    MapBuildOptions update = mb;  // scope: segment
    update.only_segments = {0};
    EXPECT_THROW(build_map(dir / "map", update), Error);
  }
  EXPECT_TRUE(Map::open(dir / "map").open_segment(0)->uses_map_hasher());

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
    // Registered: enough confidence, with its inputs and a pose uncertainty
    // in metres and degrees (the map is geo-registered).
    EXPECT_GE(r.confidence, loc.options().min_confidence);
    EXPECT_EQ(r.confidence, ConfidenceModel::builtin().evaluate(r.confidence_features));
    EXPECT_EQ(r.confidence_features.inliers, static_cast<double>(r.inliers));
    // The guided confirmation ran on the pose: the photo shows some of the
    // map points it predicts (at least the inliers' own, mostly).
    ASSERT_TRUE(r.confidence_features.guided.has_value());
    EXPECT_GT(r.confidence_features.guided->examined, 0u);
    EXPECT_GT(r.confidence_features.guided->confirmed, 0u);
    ASSERT_TRUE(r.uncertainty.valid);
    ASSERT_TRUE(r.uncertainty.position_sigma_m && r.uncertainty.heading_sigma_deg);
    EXPECT_GT(*r.uncertainty.position_sigma_m, 0.0);
    EXPECT_LT(*r.uncertainty.position_sigma_m, 5.0);
    EXPECT_LE(*r.uncertainty.horizontal_sigma_m, *r.uncertainty.position_sigma_m);
    const nlohmann::json j = to_json(r);
    EXPECT_EQ(j.at("confidence").get<double>(), r.confidence);
    EXPECT_TRUE(j.at("uncertainty").contains("heading_sigma_deg"));
    // The same query with a confidence threshold of 1 registers only at 1.
    LocalizerOptions strict;
    strict.min_confidence = 1.0;
    const LocalizationResult s =
        Localizer(dir / "map", strict).localize_file(dir / "city" / "queries" / "images" / name, cams.at(name));
    EXPECT_EQ(s.registered, s.confidence >= 1.0) << s.confidence;
  }
  EXPECT_GE(accurate, 2) << "of " << truth.size() << " queries";
  // Query-directed probing (4 of a table's 16 one-bit neighbours) in the full
  // search (setting 1): the query hashed once with the map's rotation and its
  // bits' margins.
  LocalizerOptions directed;
  directed.setting = PaperSetting::k1;
  directed.search.lut_flips = 4;
  EXPECT_GE(accurate_queries(Localizer(dir / "map", directed), dir / "city" / "queries" / "images", truth, cams), 2)
      << "of " << truth.size() << " queries";

  expect_point_votes_choose_the_segment(dir, shared, truth, cams);
}

#include <zlib.h>

#include <charconv>

#include "visloc/colmap/bundler.h"
#include "visloc/colmap/colmap_model.h"
#include "visloc/util/file_io.h"
#include "visloc/util/timer.h"

namespace {

// Test-side writer: a COLMAP model + database as a Bundler reconstruction.
// bundle.out: camera i = model image i with R_b = diag(1,−1,−1) R, t_b the
// same flip of t, f = (fx + fy)/2, no distortion; then one unregistered
// camera (f = 0) with a view of every point, which the import must drop.
// Views are the model's 2D points centred on the image, y up; key files
// hold every database keypoint at (row, col) = (y − 0.5, x − 0.5) with
// Lowe-style descriptors: the database's RootSIFT squared (back to SIFT's
// proportions), L2-normalized, × 512, truncated, ≤ 255.
struct NumberWriter {
  std::string s;
  void add(double v) {
    char b[32];
    auto [p, ec] = std::to_chars(b, b + sizeof b, v);
    s.append(b, p);
  }
  void add(uint64_t v) {
    char b[24];
    auto [p, ec] = std::to_chars(b, b + sizeof b, v);
    s.append(b, p);
  }
  void sp() { s.push_back(' '); }
  void nl() { s.push_back('\n'); }
};

std::string lowe_key_text(const FeatureSet& f) {
  NumberWriter w;
  w.s.reserve(f.size() * 520);
  w.add(uint64_t(f.size()));
  w.s += " 128\n";
  for (size_t i = 0; i < f.size(); ++i) {
    const Keypoint& k = f.keypoints[i];
    w.add(double(k.y) - 0.5), w.sp(), w.add(double(k.x) - 0.5), w.sp(), w.add(double(k.scale)), w.sp();
    w.add(-double(k.orientation)), w.nl();
    const uint8_t* r = f.descriptors.row(i);
    double l2 = 0;
    for (int j = 0; j < kDescriptorDim; ++j) l2 += std::pow(double(r[j]), 4);
    const double inv = l2 > 0 ? 1.0 / std::sqrt(l2) : 0.0;
    for (int j = 0; j < kDescriptorDim; ++j) {
      w.add(uint64_t(std::min(255.0, std::floor(512.0 * double(r[j]) * r[j] * inv))));
      if (j % 20 == 19 || j == kDescriptorDim - 1) w.nl();
      else w.sp();
    }
  }
  return w.s;
}

void write_bundler_export(const ColmapModel& m, const ColmapDatabase& db, const fs::path& dir) {
  fs::create_directories(dir / "keys");
  NumberWriter b;
  b.s = "# Bundle file v0.3\n";
  b.add(uint64_t(m.images.size() + 1)), b.sp(), b.add(uint64_t(m.points.size())), b.nl();
  std::string list;
  const Eigen::Vector3d flip(1, -1, -1);
  for (size_t i = 0; i < m.images.size(); ++i) {
    const ColmapImage& im = m.images[i];
    const ColmapCamera& c = m.cameras[m.camera_index(im.camera_id)];
    ASSERT_EQ(c.model_id, 1) << "PINHOLE expected";
    const CameraPose pose = CameraPose::from_wxyz(im.cam_from_world_q_wxyz, Eigen::Vector3d(im.cam_from_world_t.data()));
    const Eigen::Matrix3d R = flip.asDiagonal() * pose.rotation_matrix();
    const Eigen::Vector3d t = flip.asDiagonal() * pose.translation;
    b.add(0.5 * (c.params[0] + c.params[1])), b.s += " 0 0\n";
    for (int r = 0; r < 3; ++r) b.add(R(r, 0)), b.sp(), b.add(R(r, 1)), b.sp(), b.add(R(r, 2)), b.nl();
    b.add(t.x()), b.sp(), b.add(t.y()), b.sp(), b.add(t.z()), b.nl();
    list += im.name + "\n";
    FeatureSet f = db.features(db.image_by_name(im.name)->image_id);
    const std::string text = lowe_key_text(f);
    fs::path key = dir / "keys" / im.name;
    key.replace_extension(".key");
    if (i == 1) {  // one gzip key file
      gzFile gz = gzopen((key.string() + ".gz").c_str(), "wb1");
      ASSERT_TRUE(gz);
      ASSERT_EQ(gzwrite(gz, text.data(), unsigned(text.size())), int(text.size()));
      ASSERT_EQ(gzclose(gz), Z_OK);
    } else {
      write_file_atomic(key, text);
    }
  }
  b.s += "0 0 0\n0 0 0\n0 0 0\n0 0 0\n0 0 0\n";  // the unregistered camera
  list += "unregistered.jpg 0 1000\n";
  for (const auto& p : m.points) {
    b.add(p.xyz[0]), b.sp(), b.add(p.xyz[1]), b.sp(), b.add(p.xyz[2]), b.nl();
    b.add(uint64_t(p.rgb[0])), b.sp(), b.add(uint64_t(p.rgb[1])), b.sp(), b.add(uint64_t(p.rgb[2])), b.nl();
    b.add(uint64_t(p.track.size() + 1));
    for (const auto& e : p.track) {
      const ColmapImage& im = m.images[m.image_index(e.image_id)];
      const ColmapCamera& c = m.cameras[m.camera_index(im.camera_id)];
      const auto& uv = im.points2d[e.point2d_idx];
      b.sp(), b.add(uint64_t(m.image_index(e.image_id))), b.sp(), b.add(uint64_t(e.point2d_idx)), b.sp();
      b.add(uv[0] - 0.5 * double(c.width)), b.sp(), b.add(0.5 * double(c.height) - uv[1]);
    }
    b.sp(), b.add(uint64_t(m.images.size())), b.s += " 0 1 1\n";
  }
  write_file_atomic(dir / "bundle.out", b.s);
  write_file_atomic(dir / "list.txt", list);
}

}  // namespace

// Bundler import on real data: fountain-P11's COLMAP model and database are
// written as bundle.out + list + Lowe key files, imported through the Bundler
// path with the queries held out, and the queries are localized from their
// key files (RootSIFT converted from Lowe's integers).
TEST(Localizer, LocalizesFromABundlerImportOfFountain) {
  const fs::path scene = fs::path(VISLOC_SHARED_DATA_DIR) / "strecha" / "fountain-P11";
  if (!fs::exists(scene / "colmap" / "database.db")) GTEST_SKIP() << "shared data absent: " << scene;
  const fs::path dir = unique_temp_path("visloc_pipeline_test_bundler");
  fs::remove_all(dir);
  const ColmapModel colmap = read_colmap_model(scene / "colmap" / "sparse");
  ColmapDatabase db(scene / "colmap" / "database.db");
  Timer timer;
  write_bundler_export(colmap, db, dir / "bundler");
  if (HasFatalFailure()) return;
  const double ms_export = timer.elapsed_ms();

  // The conversion gives back the COLMAP model's poses and points.
  BundlerConversionOptions bo;
  bo.keys_dir = dir / "bundler" / "keys";
  timer.reset();
  const BundlerModel bm = read_bundler_model(dir / "bundler" / "bundle.out", dir / "bundler" / "list.txt", bo);
  const double ms_convert = timer.elapsed_ms();
  EXPECT_EQ(bm.stats.cameras_unregistered, 1u);
  EXPECT_EQ(bm.stats.observations_dropped, colmap.points.size());
  EXPECT_EQ(bm.stats.observations_off_key, 0u);
  ASSERT_EQ(bm.model.images.size(), colmap.images.size());
  ASSERT_EQ(bm.model.points.size(), colmap.points.size());
  EXPECT_EQ(bm.model.num_observations(), colmap.num_observations());
  for (size_t i = 0; i < colmap.images.size(); ++i) {
    const auto& a = colmap.images[i];
    const auto& b = bm.model.images[i];
    EXPECT_EQ(a.name, b.name);
    const CameraPose pa = CameraPose::from_wxyz(a.cam_from_world_q_wxyz, Eigen::Vector3d(a.cam_from_world_t.data()));
    const CameraPose pb = CameraPose::from_wxyz(b.cam_from_world_q_wxyz, Eigen::Vector3d(b.cam_from_world_t.data()));
    EXPECT_LT(rotation_error_deg(pa, pb), 1e-6) << a.name;
    EXPECT_LT(position_error(pa, pb), 1e-9) << a.name;
    const auto& cam = bm.model.cameras[bm.model.camera_index(b.camera_id)];
    EXPECT_NEAR(cam.params[1], 768.0, 1e-3);  // 1536 × 1024: the centre, derived from the keys
    EXPECT_NEAR(cam.params[2], 512.0, 1e-3);
  }
  for (size_t p = 0; p < colmap.points.size(); p += 97)
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(bm.model.points[p].xyz[k], colmap.points[p].xyz[k], 1e-12);

  // Import with the queries held out: as many points as the COLMAP import keeps.
  const std::vector<std::string> queries = read_name_list(scene / "queries.txt");
  ColmapModel expected = colmap;
  const ColmapHoldoutStats expected_holdout = remove_images(expected, queries);
  ColmapImportOptions io;
  io.holdout_images = queries;
  io.itq.iterations = 10;
  io.pq.max_training = 20000;
  io.pq.iterations = 10;
  timer.reset();
  const BundlerImportResult r =
      import_bundler_map(dir / "bundler" / "bundle.out", dir / "bundler" / "list.txt", dir / "map", bo, io);
  const double ms_import = timer.elapsed_ms();
  EXPECT_EQ(r.map.points, expected.points.size());
  EXPECT_EQ(r.map.images, expected.images.size());
  EXPECT_EQ(r.map.holdout.points_dropped, expected_holdout.points_dropped);
  std::cout << "[ bundler  ] fountain-P11: " << bm.model.points.size() << " points, " << bm.stats.keys
            << " keys; export " << ms_export << " ms, conversion " << ms_convert << " ms, import " << ms_import
            << " ms (" << r.map.points << " points after holdout)\n";

  std::map<std::string, CameraPose> truth;
  for (const auto& p : read_pose_list(dir / "map" / "holdout.txt")) truth[p.name] = p.cam_from_world;
  ASSERT_EQ(truth.size(), queries.size());
  const auto cams = db.cameras();
  PinholeCamera cam = PinholeCamera::centered(static_cast<int>(cams[0].width), static_cast<int>(cams[0].height));
  cam.focal = 0.5 * (cams[0].params[0] + cams[0].params[1]);
  cam.cx = cams[0].params[2];
  cam.cy = cams[0].params[3];
  cam.has_focal = true;
  Localizer loc(dir / "map");
  for (const auto& [name, pose] : truth) {
    fs::path key = dir / "bundler" / "keys" / name;
    key.replace_extension(".key");
    const FeatureSet f = read_lowe_key_file(key);
    LocalizationResult lr = loc.localize_features(f, cam);
    EXPECT_TRUE(lr.registered) << name;
    EXPECT_GE(lr.inliers, 12u) << name;
    EXPECT_LT(position_error(lr.cam_from_segment, pose), 0.10) << name;
    EXPECT_LT(rotation_error_deg(lr.cam_from_segment, pose), 1.0) << name;
  }
}
