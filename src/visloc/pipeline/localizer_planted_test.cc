// The localizer's control flow on a map planted in the test, with no shared
// data and no COLMAP: segments of random 3D points with random descriptors,
// compressed like any map (ITQ, PQ), geo-registered by a known similarity,
// and queries made of those points' projections through a known camera.
// Covers: the right segment and pose, the ENU / heading output, the early
// accept after a registered pose, the "cannot win" skip, the full-search
// fallback, that a pose that is not registered never ends the search, and the
// confidence's ambiguity inputs (no ambiguous inliers on random descriptors;
// inliers seen elsewhere in a map with point votes).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "visloc/geometry/pose.h"
#include "visloc/map/map.h"
#include "visloc/map_building/planted_map.h"
#include "visloc/map_building/segment_builder.h"
#include "visloc/pipeline/localization_json.h"
#include "visloc/pipeline/localizer.h"
#include "visloc/util/crc32c.h"
#include "visloc/util/mapped_file.h"
#include "visloc/util/random.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

namespace {

constexpr int kWidth = 640, kHeight = 480;
constexpr double kFocal = 500;

PinholeCamera query_camera() { return PinholeCamera::centered(kWidth, kHeight, kFocal); }

// What the query camera sees of a segment: projections (with 0.3 px noise)
// and the points' descriptors (with ±2 of noise per byte).
FeatureSet view_of(const PlantedSegment& s, const CameraPose& cam_from_segment, RandomGenerator& rng) {
  const PinholeCamera cam = query_camera();
  FeatureSet f;
  f.image = "query.jpg";
  f.image_width = kWidth;
  f.image_height = kHeight;
  std::vector<uint8_t> bytes;
  for (size_t i = 0; i < s.xyz.size(); ++i) {
    const Eigen::Vector3d pc = cam_from_segment.transform(s.xyz[i]);
    if (pc.z() <= 0.1) continue;
    const Eigen::Vector2d px = cam.project(pc) + Eigen::Vector2d(rng.normal(), rng.normal()) * 0.3;
    if (px.x() < 0 || px.y() < 0 || px.x() >= kWidth || px.y() >= kHeight) continue;
    f.keypoints.push_back({static_cast<float>(px.x()), static_cast<float>(px.y()), 2.0f, 0.0f});
    for (uint8_t v : s.descriptors[i]) bytes.push_back(static_cast<uint8_t>(std::clamp<int>(v + int(rng.below(5)) - 2, 0, 255)));
  }
  f.descriptors = DescriptorMatrix(bytes.data(), f.keypoints.size());
  return f;
}

// The query's pose: 0.6 m right of the map cameras' line, 1 m forward,
// turned 4° to the right (yaw about the segment's down axis).
CameraPose query_pose() {
  const Eigen::Vector3d center(0.6, 0.0, 1.0);
  const Eigen::Matrix3d world_from_cam = Eigen::AngleAxisd(4.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return CameraPose::from_world_from_cam(world_from_cam, center);
}

struct Fixture {
  RandomGenerator rng{7};
  PlantedSegment a = random_planted_segment(600, rng);
  PlantedSegment b = random_planted_segment(600, rng);
};

LocalizerOptions options() {
  LocalizerOptions o;
  o.sift.max_image_side = 0;
  return o;
}

}  // namespace

TEST(LocalizerPlanted, RightSegmentPoseAndGeoRegistration) {
  Fixture fx;
  PlantedMap map("right", {fx.a, fx.b});
  LocalizerOptions o = options();
  o.accept_inliers = 0;  // search both
  Localizer loc(map.dir(), o);
  EXPECT_FALSE(loc.has_retrieval());
  for (int k : {0, 1}) {
    const CameraPose truth = query_pose();
    const LocalizationResult r = loc.localize_features(view_of(k == 0 ? fx.a : fx.b, truth, fx.rng), query_camera());
    ASSERT_TRUE(r.registered) << "segment " << k << ": " << r.inliers << " inliers, confidence " << r.confidence;
    EXPECT_EQ(r.segment, k);
    EXPECT_EQ(r.candidates, (std::vector<int>{0, 1}));
    EXPECT_GE(r.inliers, 90u);  // the prioritized search stops at N_early = 100 matches
    EXPECT_LT(position_error(r.cam_from_segment, truth), 0.02);
    EXPECT_LT(rotation_error_deg(r.cam_from_segment, truth), 0.1);
    // Random descriptors: no inlier's feature matched a distant point as well.
    EXPECT_LT(r.confidence_features.ambiguous, 0.05);
    // Two segments, all searched: no point votes, no evidence of elsewhere.
    EXPECT_EQ(r.confidence_features.elsewhere, kElsewhereWhenUnknown);
    // ENU: the segment's similarity applied to the camera centre; heading:
    // north (the segment's +z) turned 4° clockwise.
    ASSERT_TRUE(r.center_enu.has_value());
    const Eigen::Vector3d expected = planted_enu_from_segment(k).apply(truth.center());
    EXPECT_LT((*r.center_enu - expected).norm(), 0.05) << r.center_enu->transpose() << " vs " << expected.transpose();
    ASSERT_TRUE(r.heading_deg.has_value());
    EXPECT_NEAR(*r.heading_deg, 4.0, 0.2);
    ASSERT_TRUE(r.position.has_value());
    EXPECT_NEAR(r.position->lat, 55.7, 0.01);
    EXPECT_TRUE(r.uncertainty.valid);
    ASSERT_TRUE(r.uncertainty.position_sigma_m.has_value());
    EXPECT_LT(*r.uncertainty.position_sigma_m, 0.5);
    // The relative σ divides by the inliers' 90th-percentile depth, which
    // lies within the depths of the segment's points seen from the truth.
    ASSERT_GT(r.uncertainty.relative_position_sigma, 0);
    const double depth = r.uncertainty.position_sigma / r.uncertainty.relative_position_sigma;
    double nearest = INFINITY, farthest = 0;
    for (const Eigen::Vector3d& X : (k == 0 ? fx.a : fx.b).xyz) {
      const double z = truth.transform(X).z();
      if (z > 0) nearest = std::min(nearest, z), farthest = std::max(farthest, z);
    }
    EXPECT_GE(depth, nearest);
    EXPECT_LE(depth, farthest);
    EXPECT_DOUBLE_EQ(to_json(r)["uncertainty"]["relative_position_sigma"].get<double>(),
                     r.uncertainty.relative_position_sigma);
  }
}

// The cascade search's hash-blend weight: by default the one the map stores
// for its current segments (map fit-blend --store), 0 without one or when a
// segment changed since; a given weight wins.
TEST(LocalizerPlanted, TheMapsFittedHashBlendIsTheDefault) {
  Fixture fx;
  PlantedMap map("blend", {fx.a, fx.b});
  EXPECT_EQ(Localizer(map.dir(), options()).options().search.hash_blend_weight, 0.0f);
  MapManifest man = read_manifest(map.dir());
  man.hash_blend = MapHashBlend{0.35, {}, {}};
  for (const auto& s : man.segments) man.hash_blend->segment_crc32c.push_back(s.file_crc32c);
  write_manifest(map.dir(), man);
  Localizer loc(map.dir(), options());
  EXPECT_EQ(loc.options().search.hash_blend_weight, 0.35f);
  const LocalizationResult r = loc.localize_features(view_of(fx.b, query_pose(), fx.rng), query_camera());
  EXPECT_TRUE(r.registered);
  EXPECT_EQ(r.segment, 1);
  LocalizerOptions given = options();
  given.hash_blend_source = HashBlendSource::kGiven;
  given.search.hash_blend_weight = 0.1f;
  EXPECT_EQ(Localizer(map.dir(), given).options().search.hash_blend_weight, 0.1f);
  given.search.hash_blend_weight = 0;
  EXPECT_EQ(Localizer(map.dir(), given).options().search.hash_blend_weight, 0.0f);
  man.hash_blend->segment_crc32c[1] ^= 1u;  // fitted on another segment 1
  write_manifest(map.dir(), man);
  EXPECT_EQ(Localizer(map.dir(), options()).options().search.hash_blend_weight, 0.0f);
}

TEST(LocalizerOptions, ParsesTheHashBlend) {
  float w = 0.7f;
  EXPECT_EQ(parse_hash_blend("map", w), HashBlendSource::kMap);
  EXPECT_EQ(w, 0.7f);
  EXPECT_EQ(parse_hash_blend("0.25", w), HashBlendSource::kGiven);
  EXPECT_EQ(w, 0.25f);
  EXPECT_EQ(parse_hash_blend("1", w), HashBlendSource::kGiven);
  EXPECT_EQ(w, 1.0f);
  for (const char* bad : {"", "nan", "-0.1", "1.5", "0.5x", "MAP", " 0.5", "inf"}) {
    w = 0.7f;
    EXPECT_THROW(parse_hash_blend(bad, w), Error) << bad;
    EXPECT_EQ(w, 0.7f) << bad;
  }
  LocalizerOptions o;
  EXPECT_EQ(hash_blend_text(o), "map");
  o.hash_blend_source = HashBlendSource::kGiven;
  o.search.hash_blend_weight = 0.25f;
  EXPECT_EQ(hash_blend_text(o), "0.25");
}

TEST(LocalizerPlanted, EarlyAcceptEndsTheSearchAtARegisteredPose) {
  Fixture fx;
  PlantedMap map("accept", {fx.a, fx.b});
  LocalizerOptions o = options();
  o.accept_inliers = 50;
  Localizer loc(map.dir(), o);
  const LocalizationResult first = loc.localize_features(view_of(fx.a, query_pose(), fx.rng), query_camera());
  ASSERT_TRUE(first.registered);
  EXPECT_EQ(first.candidates, (std::vector<int>{0}));  // segment 1 is never searched
  const LocalizationResult second = loc.localize_features(view_of(fx.b, query_pose(), fx.rng), query_camera());
  ASSERT_TRUE(second.registered);
  EXPECT_EQ(second.segment, 1);
  EXPECT_EQ(second.candidates, (std::vector<int>{0, 1}));
}

TEST(LocalizerPlanted, APoseThatIsNotRegisteredNeverEndsTheSearch) {
  Fixture fx;
  PlantedMap map("unregistered", {fx.a, fx.b});
  LocalizerOptions o = options();
  o.accept_inliers = 50;
  o.min_confidence = 1.0;  // no pose can be registered
  Localizer loc(map.dir(), o);
  const LocalizationResult r = loc.localize_features(view_of(fx.a, query_pose(), fx.rng), query_camera());
  EXPECT_FALSE(r.registered);
  EXPECT_EQ(r.segment, 0);  // the pose is still reported
  EXPECT_GT(r.inliers, 300u);
  EXPECT_EQ(r.candidates, (std::vector<int>{0, 1}));  // past the 50 inliers of segment 0
  EXPECT_TRUE(r.full_search_fallback);  // and searched again in full before giving up
}

TEST(LocalizerPlanted, FullSearchFallbackAfterAFailedPrioritizedSearch) {
  Fixture fx;
  PlantedMap map("fallback", {fx.a});
  LocalizerOptions o = options();
  o.search.early_stop = 4;  // the prioritized search stops at 4 matches: too few for a pose
  const FeatureSet query = view_of(fx.a, query_pose(), fx.rng);
  {
    Localizer loc(map.dir(), o);
    const LocalizationResult r = loc.localize_features(query, query_camera());
    EXPECT_TRUE(r.full_search_fallback);
    EXPECT_TRUE(r.registered);
    EXPECT_GT(r.inliers, 300u);
  }
  o.full_search_fallback = false;
  {
    Localizer loc(map.dir(), o);
    const LocalizationResult r = loc.localize_features(query, query_camera());
    EXPECT_FALSE(r.full_search_fallback);
    EXPECT_FALSE(r.registered);
    EXPECT_LT(r.inliers, 12u);
  }
}

// A segment with no more matched features than the best pose's inliers
// cannot win and gets no RANSAC: its inliers do not enter the margin to the
// second-best segment. Segment "part" holds a third of segment A's points.
TEST(LocalizerPlanted, ASegmentThatCannotWinIsSkipped) {
  Fixture fx;
  PlantedSegment part;
  for (size_t i = 0; i < fx.a.xyz.size(); i += 3) {
    part.xyz.push_back(fx.a.xyz[i]);
    part.descriptors.push_back(fx.a.descriptors[i]);
  }
  LocalizerOptions o = options();
  o.accept_inliers = 0;
  const FeatureSet query = view_of(fx.a, query_pose(), fx.rng);
  // Full segment first: the part, searched second, cannot win.
  PlantedMap full_first("skip1", {fx.a, part});
  const LocalizationResult skipped = Localizer(full_first.dir(), o).localize_features(query, query_camera());
  // The part first: estimated (it could win then), then beaten.
  PlantedMap part_first("skip2", {part, fx.a});
  const LocalizationResult estimated = Localizer(part_first.dir(), o).localize_features(query, query_camera());
  ASSERT_TRUE(skipped.registered);
  ASSERT_TRUE(estimated.registered);
  EXPECT_EQ(skipped.segment, 0);
  EXPECT_EQ(estimated.segment, 1);
  EXPECT_EQ(skipped.candidates, (std::vector<int>{0, 1}));
  EXPECT_EQ(estimated.candidates, (std::vector<int>{0, 1}));
  // The part's pose has about a third of the inliers: it shows in the margin only when estimated.
  EXPECT_GT(estimated.confidence_features.margin, 0.2);
  EXPECT_LT(skipped.confidence_features.margin, 0.2);
}

// The `elsewhere` input on a map with point votes (one hash rotation, more
// segments than are searched first). The query views segment a; its first
// 300 features are copied exactly into an unrelated segment c, at other
// places (a building copied elsewhere in the map), and the query carries more
// descriptor noise than view_of's, so that a's own points are a few bits
// from those features' codes and c's copies none: about half the inliers of
// a's pose have their nearest map point in c. Without the copy, almost none.
// Segment ids start at 10, so ids and manifest positions differ.
TEST(LocalizerPlanted, InliersWhoseNearestMapPointIsInAnUnrelatedSegmentAreElsewhere) {
  RandomGenerator rng(11);
  const PlantedSegment a = random_planted_segment(600, rng);
  const PlantedSegment b = random_planted_segment(600, rng);
  const CameraPose truth = query_pose();
  FeatureSet query = view_of(a, truth, rng);
  for (size_t i = 0; i < query.descriptors.rows(); ++i)
    for (int j = 0; j < kDescriptorDim; ++j) {
      uint8_t& v = query.descriptors.row(i)[j];
      v = static_cast<uint8_t>(std::clamp<int>(v + int(rng.below(21)) - 10, 0, 255));
    }
  ASSERT_GE(query.size(), 400u);
  PlantedSegment copy = random_planted_segment(300, rng);
  for (size_t i = 0; i < copy.descriptors.size(); ++i)
    std::copy_n(query.descriptors.row(i), kDescriptorDim, copy.descriptors[i].begin());
  LocalizerOptions o = options();
  o.max_segments = 2;  // of 3: point votes choose them
  o.fallback_segments = 1;
  o.accept_inliers = 0;
  o.segment_votes = SegmentVoteSource::kPoints;
  const PlantedMapOptions layout{.map_hash_rotation = true, .first_segment_id = 10};
  double elsewhere_with_copy = -1;
  for (const bool with_copy : {true, false}) {
    SCOPED_TRACE(with_copy ? "a copy in c" : "no copy");
    PlantedMap map(with_copy ? "elsewhere" : "nowhere_else",
                   {a, b, with_copy ? copy : random_planted_segment(300, rng)}, {}, 4, layout);
    Localizer loc(map.dir(), o);
    ASSERT_TRUE(loc.has_point_votes());
    const LocalizationResult r = loc.localize_features(query, query_camera());
    ASSERT_EQ(r.segment, 10);
    EXPECT_LT(position_error(r.cam_from_segment, truth), 0.05);
    ASSERT_GE(r.inliers, 60u);
    const double elsewhere = r.confidence_features.elsewhere;
    if (with_copy) {
      elsewhere_with_copy = elsewhere;
      EXPECT_GT(elsewhere, 0.2);
      EXPECT_LT(elsewhere, 0.8);
    } else {
      EXPECT_LT(elsewhere, 0.05);
    }
  }
  EXPECT_NE(elsewhere_with_copy, kElsewhereWhenUnknown);
}
