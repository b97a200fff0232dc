// map_overview: hulls, frames, the up alignment and subsampling, on a
// planted map (planted_map.h: segment frames are camera frames, y down).
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "visloc/map/map.h"
#include "visloc/map/map_overview.h"
#include "visloc/map_building/planted_map.h"
#include "visloc/util/error.h"
#include "visloc/util/test_support.h"

namespace visloc {
namespace {

TEST(ConvexHull, SquareCollinearDuplicatesAndDegenerate) {
  using V = Eigen::Vector2d;
  // A square with an inner point, a point on an edge and a duplicate corner.
  const auto hull = convex_hull({V(0, 0), V(2, 0), V(2, 2), V(0, 2), V(1, 1), V(1, 0), V(2, 2)});
  ASSERT_EQ(hull.size(), 4u);
  EXPECT_EQ(hull[0], V(0, 0));  // counter-clockwise from the lowest-leftmost point
  EXPECT_EQ(hull[1], V(2, 0));
  EXPECT_EQ(hull[2], V(2, 2));
  EXPECT_EQ(hull[3], V(0, 2));
  EXPECT_EQ(convex_hull({V(0, 0), V(1, 1), V(2, 2), V(3, 3)}).size(), 2u);  // collinear: the two ends
  EXPECT_EQ(convex_hull({V(5, 5), V(5, 5)}).size(), 1u);
  EXPECT_TRUE(convex_hull({}).empty());
}

class MapOverviewTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    RandomGenerator rng(3);
    std::vector<PlantedSegment> segments;
    for (int k = 0; k < 2; ++k) segments.push_back(random_planted_segment(200, rng));
    segments_ = new std::vector<PlantedSegment>(segments);
    map_ = new PlantedMap("overview", segments);
  }
  static void TearDownTestSuite() {
    delete map_;
    delete segments_;
  }
  static std::vector<PlantedSegment>* segments_;
  static PlantedMap* map_;
};
std::vector<PlantedSegment>* MapOverviewTest::segments_ = nullptr;
PlantedMap* MapOverviewTest::map_ = nullptr;

TEST_F(MapOverviewTest, EnuFrameIsEveryPointThroughItsSegmentsSimilarity) {
  const MapOverview ov = load_map_overview(Map::open(map_->dir()));
  EXPECT_EQ(ov.frame, OverviewFrame::kEnu);
  EXPECT_TRUE(ov.georegistered);
  EXPECT_TRUE(ov.aligned_from_frame.isIdentity());
  ASSERT_EQ(ov.num_points(), 400u);
  for (size_t i = 0; i < ov.num_points(); i += 37) {
    const uint32_t k = ov.point_segment[i];
    const Eigen::Vector3d expected = planted_enu_from_segment(static_cast<int>(k)).apply((*segments_)[k].xyz[i - 200 * k]);
    const Eigen::Vector3d got = Eigen::Vector3d(ov.xyz[3 * i], ov.xyz[3 * i + 1], ov.xyz[3 * i + 2]) + ov.origin;
    EXPECT_LT((got - expected).norm(), 1e-4);
  }
  ASSERT_EQ(ov.cameras.size(), 8u);
  // Planted cameras look along the segment's +z, which is north in ENU.
  EXPECT_LT((ov.cameras[0].world_from_camera.col(2) - Eigen::Vector3d::UnitY()).norm(), 1e-9);
  ASSERT_TRUE(ov.north.has_value());
  EXPECT_LT((*ov.north - Eigen::Vector3d::UnitY()).norm(), 1e-12);
  EXPECT_EQ(ov.segments[1].cameras, 4u);
  EXPECT_GE(ov.segments[1].outline.size(), 3u);
}

TEST_F(MapOverviewTest, SegmentFrameIsRotatedSoThatTheCamerasUpIsZ) {
  MapOverviewOptions o;
  o.frame = OverviewFrame::kSegment;
  const MapOverview ov = load_map_overview(Map::open(map_->dir()), o);
  EXPECT_EQ(ov.frame, OverviewFrame::kSegment);
  // The planted cameras' image y axis is the segment's +y (down): up is −y,
  // and the alignment takes it to +z.
  EXPECT_LT((ov.aligned_from_frame * Eigen::Vector3d(0, -1, 0) - Eigen::Vector3d::UnitZ()).norm(), 1e-9);
  EXPECT_NEAR(ov.aligned_from_frame.determinant(), 1.0, 1e-12);
  for (const auto& c : ov.cameras) EXPECT_LT((c.world_from_camera.col(1) + Eigen::Vector3d::UnitZ()).norm(), 1e-9);
  // North (segment +z here) survives the alignment: the rotation about x
  // that lifts −y to +z takes +z to +y.
  ASSERT_TRUE(ov.north.has_value());
  EXPECT_LT((*ov.north - Eigen::Vector3d::UnitY()).norm(), 1e-9);
  const Eigen::Vector3d raw = (*segments_)[0].xyz[5];
  const Eigen::Vector3d got = Eigen::Vector3d(ov.xyz[15], ov.xyz[16], ov.xyz[17]) + ov.origin;
  EXPECT_LT((got - ov.aligned_from_frame * raw).norm(), 1e-4);
}

TEST_F(MapOverviewTest, SubsamplesBySegmentShareAndRefusesEnuWithoutGeoregistration) {
  MapOverviewOptions o;
  o.max_points = 101;
  const MapOverview ov = load_map_overview(Map::open(map_->dir()), o);
  EXPECT_EQ(ov.total_points, 400u);
  EXPECT_EQ(ov.segments[0].points_shown, 50u);  // floor(200 × 101/400)
  EXPECT_EQ(ov.num_points(), 100u);
  o.max_points = 0;
  EXPECT_THROW(load_map_overview(Map::open(map_->dir()), o), Error);
  EXPECT_THROW(parse_overview_frame("north"), Error);
}

}  // namespace
}  // namespace visloc
