#include "visloc/map/map_overview.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>

#include "visloc/geometry/pose.h"
#include "visloc/map/map.h"
#include "visloc/map/segment_file.h"
#include "visloc/util/error.h"

namespace visloc {

OverviewFrame parse_overview_frame(const std::string& name) {
  if (name == "auto") return OverviewFrame::kAuto;
  if (name == "enu") return OverviewFrame::kEnu;
  if (name == "segment") return OverviewFrame::kSegment;
  throw_error(ErrorCode::kInvalidArgument, "frame '", name, "': must be auto, enu or segment");
}

const char* overview_frame_name(OverviewFrame frame) {
  switch (frame) {
    case OverviewFrame::kAuto: return "auto";
    case OverviewFrame::kEnu: return "enu";
    case OverviewFrame::kSegment: return "segment";
  }
  return "?";
}

void MapOverviewOptions::validate() const {
  if (max_points < 1) throw_error(ErrorCode::kInvalidArgument, "map overview option max_points = 0: must be at least 1");
}

std::vector<Eigen::Vector2d> convex_hull(std::vector<Eigen::Vector2d> p) {
  std::sort(p.begin(), p.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  p.erase(std::unique(p.begin(), p.end()), p.end());
  if (p.size() < 3) return p;
  auto cross = [](const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2d> hull(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {  // lower chain
    while (k >= 2 && cross(hull[k - 2], hull[k - 1], p[i]) <= 0) --k;
    hull[k++] = p[i];
  }
  for (size_t i = p.size() - 1, lower = k + 1; i-- > 0;) {  // upper chain
    while (k >= lower && cross(hull[k - 2], hull[k - 1], p[i]) <= 0) --k;
    hull[k++] = p[i];
  }
  hull.resize(k - 1);
  return hull;
}

namespace {

// The rotation taking `up` to +z by the shortest arc.
Eigen::Matrix3d rotation_to_z(const Eigen::Vector3d& up) {
  return Eigen::Quaterniond::FromTwoVectors(up.normalized(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

}  // namespace

MapOverview load_map_overview(const Map& map, const MapOverviewOptions& options) {
  options.validate();
  MapOverview out;
  const auto& entries = map.manifest().segments;
  std::vector<std::unique_ptr<Segment>> segments;
  bool all_enu = !entries.empty();
  for (size_t i = 0; i < entries.size(); ++i) {
    segments.push_back(map.open_segment(i));
    all_enu = all_enu && segments.back()->enu_from_segment().has_value();
    out.total_points += segments.back()->num_points();
  }
  out.georegistered = all_enu;
  if (options.frame == OverviewFrame::kEnu && !all_enu)
    throw_error(ErrorCode::kInvalidArgument, map.dir().string(),
                ": frame enu needs a georegistered map, and not every segment has enu_from_segment");
  out.frame = options.frame == OverviewFrame::kAuto ? (all_enu ? OverviewFrame::kEnu : OverviewFrame::kSegment)
                                                    : options.frame;
  const bool enu = out.frame == OverviewFrame::kEnu;

  // Cameras, in the chosen frame (before alignment).
  for (size_t s = 0; s < segments.size(); ++s) {
    const Segment& seg = *segments[s];
    for (const SegmentImage& im : seg.images()) {
      const CameraPose pose = CameraPose::from_wxyz(im.cam_from_world_q_wxyz, Eigen::Vector3d(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]));
      OverviewCamera c;
      c.name = im.name;
      c.segment = static_cast<uint32_t>(s);
      c.center = pose.center();
      c.world_from_camera = pose.rotation_matrix().transpose();
      if (enu) {
        const auto& e = *seg.enu_from_segment();
        c.center = e.apply(c.center);
        c.world_from_camera = e.rotation * c.world_from_camera;
      }
      c.width = static_cast<double>(im.width);
      c.height = static_cast<double>(im.height);
      c.focal = im.camera_params.empty() ? 0.0 : im.camera_params[0];
      out.cameras.push_back(c);
    }
  }
  if (!enu) {
    // Up: the mean of the cameras' −y axes (image rows run down the world).
    Eigen::Vector3d up = Eigen::Vector3d::Zero();
    for (const auto& c : out.cameras) up -= c.world_from_camera.col(1);
    if (up.norm() > 1e-9) out.aligned_from_frame = rotation_to_z(up);
  }
  const Eigen::Matrix3d& A = out.aligned_from_frame;
  for (auto& c : out.cameras) {
    c.center = A * c.center;
    c.world_from_camera = A * c.world_from_camera;
  }

  // Points: each segment keeps its share of max_points, evenly spaced.
  const double keep = out.total_points > options.max_points
                          ? static_cast<double>(options.max_points) / static_cast<double>(out.total_points)
                          : 1.0;
  for (size_t s = 0; s < segments.size(); ++s) {
    const Segment& seg = *segments[s];
    OverviewSegment o;
    o.id = seg.id();
    o.points = seg.num_points();
    const size_t shown = std::min(o.points, static_cast<size_t>(std::floor(keep * static_cast<double>(o.points))));
    o.points_shown = shown;
    std::vector<Eigen::Vector2d> footprint;
    std::vector<double> heights;
    const auto xyz = seg.xyz();
    for (size_t k = 0; k < shown; ++k) {
      const size_t i = shown == o.points ? k : static_cast<size_t>((static_cast<double>(k) + 0.5) * static_cast<double>(o.points) / static_cast<double>(shown));
      Eigen::Vector3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
      if (enu) p = seg.enu_from_segment()->apply(p);
      p = A * p;
      out.xyz.insert(out.xyz.end(), {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())});
      out.point_segment.push_back(static_cast<uint32_t>(s));
      footprint.emplace_back(p.x(), p.y());
      heights.push_back(p.z());
    }
    double ground = std::numeric_limits<double>::infinity();
    if (!heights.empty()) {  // the 1st percentile: a few stray points below the street do not sink it
      auto nth = heights.begin() + static_cast<std::ptrdiff_t>(heights.size() / 100);
      std::nth_element(heights.begin(), nth, heights.end());
      ground = *nth;
    }
    for (const auto& c : out.cameras) {
      if (c.segment != s) continue;
      ++o.cameras;
      footprint.emplace_back(c.center.x(), c.center.y());
      if (heights.empty()) ground = std::min(ground, c.center.z());
    }
    o.outline = convex_hull(std::move(footprint));
    o.ground_z = std::isfinite(ground) ? ground : 0.0;
    out.segments.push_back(std::move(o));
  }
  return out;
}

}  // namespace visloc
