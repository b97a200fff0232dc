#pragma once
// What a map looks like from outside: its points (subsampled), its cameras
// and the ground outline of each segment, in one frame with z up. The web
// viewer (viewer/) and the evaluation report's top view draw from it.
//
// Frame. kEnu puts every segment through its enu_from_segment (east, north,
// up; needs a georegistered map). kSegment keeps the segments' own
// coordinates: right for imported models and known-pose maps, whose segments
// share one world frame (the frame of pose truth). kAuto is kEnu when every
// segment is georegistered, else kSegment. A segment frame has no known up:
// it is estimated from the cameras (their image y axes point down in the
// world, COLMAP's convention) and everything is rotated so that it is +z;
// Segments are opened one at a time (only the kept points stay in memory).
// `aligned_from_frame` is that rotation, to apply to anything else drawn in
// the same frame (query centres).

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace visloc {

class Map;

enum class OverviewFrame { kAuto, kEnu, kSegment };

// "auto", "enu", "segment"; throws kInvalidArgument naming the option otherwise.
OverviewFrame parse_overview_frame(const std::string& name);
const char* overview_frame_name(OverviewFrame frame);

struct MapOverviewOptions {
  size_t max_points = 1'000'000;  // points kept over the whole map, spread over the segments by their sizes
  OverviewFrame frame = OverviewFrame::kAuto;
  void validate() const;
};

struct OverviewCamera {
  std::string name;
  uint32_t segment = 0;
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  Eigen::Matrix3d world_from_camera = Eigen::Matrix3d::Identity();  // columns: the camera's x, y, z axes
  double width = 0, height = 0, focal = 0;                           // pixels
};

struct OverviewSegment {
  uint32_t id = 0;
  size_t points = 0;        // in the segment
  size_t points_shown = 0;  // kept in the overview
  size_t cameras = 0;
  // Convex hull in x-y of the cameras and the kept points within the 90th
  // percentile of distance from the segment's median, counter-clockwise.
  std::vector<Eigen::Vector2d> outline;
  double ground_z = 0;                   // 5th percentile of the kept points' heights (no points: the lowest camera)
};

struct MapOverview {
  OverviewFrame frame = OverviewFrame::kSegment;  // kEnu or kSegment (never kAuto)
  bool georegistered = false;                     // every segment has enu_from_segment
  Eigen::Matrix3d aligned_from_frame = Eigen::Matrix3d::Identity();
  // North in the aligned frame (unit, horizontal): +y in ENU; in a segment
  // frame, when every segment is georegistered and they agree within 5°.
  std::optional<Eigen::Vector3d> north;
  // `xyz` is relative to this point of the aligned frame (the mean camera
  // centre), so that floats keep millimetres in UTM-sized coordinates.
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  std::vector<float> xyz;                 // kept points, N × 3, aligned frame minus origin
  std::vector<uint32_t> point_segment;    // index into `segments` per kept point
  std::vector<OverviewCamera> cameras;    // aligned frame
  std::vector<OverviewSegment> segments;  // manifest order
  size_t total_points = 0;
  size_t num_points() const { return point_segment.size(); }
};

MapOverview load_map_overview(const Map& map, const MapOverviewOptions& options = {});

// Convex hull (Andrew's monotone chain), counter-clockwise, no repeated first point.
std::vector<Eigen::Vector2d> convex_hull(std::vector<Eigen::Vector2d> points);

}  // namespace visloc
