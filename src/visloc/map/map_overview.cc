#include "visloc/map/map_overview.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>

#include "visloc/geo/similarity_transform.h"
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

// North (ENU +y) in the aligned frame: +y in ENU; in a segment frame, as
// seen from each georegistered segment, when they agree within 5°.
std::optional<Eigen::Vector3d> north_of(bool enu, bool all_enu,
                                        const std::vector<std::optional<Similarity3d>>& enu_from_segment,
                                        const Eigen::Matrix3d& A) {
  if (enu) return Eigen::Vector3d::UnitY();
  if (!all_enu) return std::nullopt;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> each;
  for (const auto& e : enu_from_segment) {
    Eigen::Vector3d n = A * (e->rotation.transpose() * Eigen::Vector3d::UnitY());
    n.z() = 0;
    if (n.norm() < 1e-6) continue;
    each.push_back(n.normalized());
    sum += each.back();
  }
  const bool agree = !each.empty() && std::all_of(each.begin(), each.end(), [&](const Eigen::Vector3d& n) {
    return n.dot(sum.normalized()) > std::cos(5.0 * M_PI / 180.0);
  });
  if (!agree) return std::nullopt;
  return sum.normalized();
}

// A segment's outline and ground from its kept points' footprint and heights
// (aligned frame) and its cameras' footprint (last in `footprint`).
void finish_segment(MapOverview& out, size_t s, std::vector<Eigen::Vector2d> footprint, std::vector<double> heights) {
  OverviewSegment& o = out.segments[s];
  double ground = std::numeric_limits<double>::infinity();
  if (!heights.empty()) {  // the 5th percentile: stray points below the street do not sink it
    auto nth = heights.begin() + static_cast<std::ptrdiff_t>(heights.size() / 20);
    std::nth_element(heights.begin(), nth, heights.end());
    ground = *nth;
  } else {
    for (const auto& c : out.cameras)
      if (c.segment == s) ground = std::min(ground, c.center.z());
  }
  for (const auto& c : out.cameras) o.cameras += c.segment == s;
  // The outline leaves out the 10% of points farthest from the segment's
  // median (in x-y): stray triangulations would stretch it far off the street.
  std::vector<Eigen::Vector2d>& f = footprint;
  const size_t num_point_footprints = f.size() - static_cast<size_t>(o.cameras);
  if (num_point_footprints >= 20) {
    std::vector<double> xs, ys;
    for (size_t i = 0; i < num_point_footprints; ++i) {
      xs.push_back(f[i].x());
      ys.push_back(f[i].y());
    }
    std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
    std::nth_element(ys.begin(), ys.begin() + static_cast<std::ptrdiff_t>(ys.size() / 2), ys.end());
    const Eigen::Vector2d centre(xs[xs.size() / 2], ys[ys.size() / 2]);
    std::vector<double> dist;
    for (size_t i = 0; i < num_point_footprints; ++i) dist.push_back((f[i] - centre).norm());
    std::vector<double> sorted = dist;
    const auto q90 = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() * 9 / 10);
    std::nth_element(sorted.begin(), q90, sorted.end());
    std::vector<Eigen::Vector2d> kept;
    for (size_t i = 0; i < f.size(); ++i)
      if (i >= num_point_footprints || dist[i] <= *q90) kept.push_back(f[i]);
    f = std::move(kept);
  }
  o.outline = convex_hull(std::move(f));
  o.ground_z = std::isfinite(ground) ? ground : 0.0;
}

}  // namespace

MapOverview load_map_overview(const Map& map, const MapOverviewOptions& options) {
  options.validate();
  MapOverview out;
  const auto& entries = map.manifest().segments;
  for (const auto& e : entries) out.total_points += e.points;
  // Each segment keeps its share of max_points, evenly spaced.
  const double keep = out.total_points > options.max_points
                          ? static_cast<double>(options.max_points) / static_cast<double>(out.total_points)
                          : 1.0;
  // One pass, one segment open at a time: the kept points and the cameras in
  // each segment's own frame, with its enu_from_segment.
  std::vector<std::optional<Similarity3d>> enu_from_segment;
  std::vector<Eigen::Vector3d> raw_points;  // segment frame
  bool all_enu = !entries.empty();
  for (size_t s = 0; s < entries.size(); ++s) {
    const std::unique_ptr<Segment> seg = map.open_segment(s);
    enu_from_segment.push_back(seg->enu_from_segment());
    all_enu = all_enu && seg->enu_from_segment().has_value();
    for (const SegmentImage& im : seg->images()) {
      const CameraPose pose = CameraPose::from_wxyz(
          im.cam_from_world_q_wxyz,
          Eigen::Vector3d(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]));
      OverviewCamera c;
      c.name = im.name;
      c.segment = static_cast<uint32_t>(s);
      c.center = pose.center();
      c.world_from_camera = pose.rotation_matrix().transpose();
      c.width = static_cast<double>(im.width);
      c.height = static_cast<double>(im.height);
      c.focal = im.camera_params.empty() ? 0.0 : im.camera_params[0];
      out.cameras.push_back(c);
    }
    OverviewSegment o;
    o.id = seg->id();
    o.points = seg->num_points();
    o.points_shown = std::min(o.points, static_cast<size_t>(std::floor(keep * static_cast<double>(o.points))));
    const auto xyz = seg->xyz();
    for (size_t k = 0; k < o.points_shown; ++k) {
      const size_t i = o.points_shown == o.points
                           ? k
                           : static_cast<size_t>((static_cast<double>(k) + 0.5) * static_cast<double>(o.points) /
                                                 static_cast<double>(o.points_shown));
      raw_points.emplace_back(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
      out.point_segment.push_back(static_cast<uint32_t>(s));
    }
    out.segments.push_back(std::move(o));
  }
  out.georegistered = all_enu;
  if (options.frame == OverviewFrame::kEnu && !all_enu)
    throw_error(ErrorCode::kInvalidArgument, map.dir().string(),
                ": frame enu needs a georegistered map, and not every segment has enu_from_segment");
  out.frame = options.frame == OverviewFrame::kAuto ? (all_enu ? OverviewFrame::kEnu : OverviewFrame::kSegment)
                                                    : options.frame;
  const bool enu = out.frame == OverviewFrame::kEnu;
  if (enu)
    for (auto& c : out.cameras) {
      const Similarity3d& e = *enu_from_segment[c.segment];
      c.center = e.apply(c.center);
      c.world_from_camera = e.rotation * c.world_from_camera;
    }
  else {
    // Up: the mean of the cameras' −y axes (image rows run down the world).
    Eigen::Vector3d up = Eigen::Vector3d::Zero();
    for (const auto& c : out.cameras) up -= c.world_from_camera.col(1);
    if (up.norm() > 1e-9) out.aligned_from_frame = rotation_to_z(up);
  }
  const Eigen::Matrix3d& A = out.aligned_from_frame;
  out.north = north_of(enu, all_enu, enu_from_segment, A);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (auto& c : out.cameras) {
    c.center = A * c.center;
    c.world_from_camera = A * c.world_from_camera;
    mean += c.center;
  }
  if (!out.cameras.empty()) out.origin = mean / static_cast<double>(out.cameras.size());

  // Points to the aligned frame, relative to the origin; footprints and ground.
  out.xyz.reserve(3 * raw_points.size());
  std::vector<std::vector<Eigen::Vector2d>> footprint(out.segments.size());
  std::vector<std::vector<double>> heights(out.segments.size());
  for (size_t i = 0; i < raw_points.size(); ++i) {
    const uint32_t s = out.point_segment[i];
    Eigen::Vector3d p = raw_points[i];
    if (enu) p = enu_from_segment[s]->apply(p);
    p = A * p;
    footprint[s].emplace_back(p.x(), p.y());
    heights[s].push_back(p.z());
    p -= out.origin;
    out.xyz.insert(out.xyz.end(), {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())});
  }
  for (const auto& c : out.cameras) footprint[c.segment].emplace_back(c.center.x(), c.center.y());
  for (size_t s = 0; s < out.segments.size(); ++s) finish_segment(out, s, std::move(footprint[s]), std::move(heights[s]));
  return out;
}

}  // namespace visloc
