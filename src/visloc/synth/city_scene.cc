#include "visloc/synth/city_scene.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "visloc/synth/random.h"
#include "visloc/util/error.h"

namespace visloc::synth {
namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;

void require(bool ok, const char* field, const std::string& why) {
  if (!ok) throw_error(ErrorCode::kInvalidArgument, "city layout option ", field, ": ", why);
}

// Footprint corners of a box, counter-clockwise.
std::array<Eigen::Vector2d, 4> corners(const BoxPrimitive& b) {
  const Eigen::Vector2d ex(b.cos_yaw * b.half_x, b.sin_yaw * b.half_x);
  const Eigen::Vector2d ey(-b.sin_yaw * b.half_y, b.cos_yaw * b.half_y);
  const Eigen::Vector2d c(b.cx, b.cy);
  return {c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey};
}

// Separating-axis test for two footprints, each grown by `margin` (a
// negative margin lets boxes touch).
bool footprints_overlap(const BoxPrimitive& a, const BoxPrimitive& b, double margin) {
  const std::array<Eigen::Vector2d, 4> axes = {
      Eigen::Vector2d(a.cos_yaw, a.sin_yaw), Eigen::Vector2d(-a.sin_yaw, a.cos_yaw),
      Eigen::Vector2d(b.cos_yaw, b.sin_yaw), Eigen::Vector2d(-b.sin_yaw, b.cos_yaw)};
  const auto ca = corners(a), cb = corners(b);
  for (const auto& axis : axes) {
    double amin = 1e300, amax = -1e300, bmin = 1e300, bmax = -1e300;
    for (const auto& p : ca) { const double d = p.dot(axis); amin = std::min(amin, d); amax = std::max(amax, d); }
    for (const auto& p : cb) { const double d = p.dot(axis); bmin = std::min(bmin, d); bmax = std::max(bmax, d); }
    if (amax + margin <= bmin - margin || bmax + margin <= amin - margin) return false;
  }
  return true;
}

double point_segment_distance(const Eigen::Vector2d& p, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// Whether the segment a-b crosses the footprint (Liang-Barsky clipping in
// the box's frame).
bool segment_crosses_footprint(const BoxPrimitive& box, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const auto local = [&](const Eigen::Vector2d& p) {
    const Eigen::Vector2d d(p.x() - box.cx, p.y() - box.cy);
    return Eigen::Vector2d(box.cos_yaw * d.x() + box.sin_yaw * d.y(), -box.sin_yaw * d.x() + box.cos_yaw * d.y());
  };
  const Eigen::Vector2d p0 = local(a), d = local(b) - p0;
  double t0 = 0, t1 = 1;
  const double h[2] = {box.half_x, box.half_y};
  for (int k = 0; k < 2; ++k) {
    if (std::abs(d[k]) < 1e-12) {
      if (std::abs(p0[k]) > h[k]) return false;
      continue;
    }
    double ta = (-h[k] - p0[k]) / d[k], tb = (h[k] - p0[k]) / d[k];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

double segment_footprint_distance(const BoxPrimitive& box, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  if (segment_crosses_footprint(box, a, b)) return 0.0;
  double d = std::min(footprint_distance(box, a), footprint_distance(box, b));
  for (const auto& c : corners(box)) d = std::min(d, point_segment_distance(c, a, b));
  return d;
}

BuildingStyle random_style(SplitMix64& rng) {
  BuildingStyle s;
  s.seed = rng.next();
  s.material = static_cast<FacadeMaterial>(rng.uniform_int(0, 3));
  const uint64_t h = rng.next();
  switch (s.material) {
    case FacadeMaterial::kPlaster:
      s.wall = hsv_to_rgb(static_cast<float>(rng.uniform()), static_cast<float>(rng.uniform(0.08, 0.35)),
                          static_cast<float>(rng.uniform(0.6, 0.92)));
      break;
    case FacadeMaterial::kBrick:
      s.wall = hsv_to_rgb(static_cast<float>(rng.uniform(0.0, 0.07)), static_cast<float>(rng.uniform(0.4, 0.7)),
                          static_cast<float>(rng.uniform(0.4, 0.68)));
      break;
    case FacadeMaterial::kConcretePanels:
      s.wall = hsv_to_rgb(static_cast<float>(rng.uniform()), static_cast<float>(rng.uniform(0.0, 0.08)),
                          static_cast<float>(rng.uniform(0.5, 0.78)));
      break;
    case FacadeMaterial::kStone:
      s.wall = hsv_to_rgb(static_cast<float>(rng.uniform(0.08, 0.14)), static_cast<float>(rng.uniform(0.12, 0.3)),
                          static_cast<float>(rng.uniform(0.62, 0.85)));
      break;
  }
  s.trim = rng.bernoulli(0.5) ? mix(s.wall, Rgb{0.95f, 0.95f, 0.93f}, 0.6f) : s.wall * 0.7f;
  const int frame_kind = rng.uniform_int(0, 3);
  s.frame = frame_kind == 0   ? Rgb{0.92f, 0.92f, 0.9f}
            : frame_kind == 1 ? Rgb{0.2f, 0.2f, 0.22f}
            : frame_kind == 2 ? Rgb{0.42f, 0.27f, 0.15f}
                              : hashed_colour(h, 0.3f, 0.6f, 0.3f, 0.6f);
  s.glass = hsv_to_rgb(static_cast<float>(rng.uniform(0.45, 0.62)), static_cast<float>(rng.uniform(0.1, 0.4)),
                       static_cast<float>(rng.uniform(0.18, 0.35)));
  s.door = hashed_colour(mix64(h), 0.3f, 0.7f, 0.2f, 0.5f);
  s.floor_height = static_cast<float>(rng.uniform(3.0, 3.6));
  s.ground_floor_height = static_cast<float>(rng.uniform(3.8, 4.6));
  s.bay_width = static_cast<float>(rng.uniform(2.4, 3.6));
  s.window_width = static_cast<float>(rng.uniform(0.35, 0.6) * s.bay_width);
  s.window_height = static_cast<float>(rng.uniform(1.2, 1.8));
  s.sill_height = static_cast<float>(rng.uniform(0.7, 1.0));
  s.shop_front = rng.bernoulli(0.7);
  s.balconies = rng.bernoulli(0.4);
  s.balcony_period = rng.bernoulli(0.5) ? 1 : 2;
  s.mullion = rng.bernoulli(0.6);
  s.blank_face_probability = 0.15f;
  return s;
}

}  // namespace

const char* to_string(RoadLayout layout) {
  switch (layout) {
    case RoadLayout::kLine: return "line";
    case RoadLayout::kGrid: return "grid";
    case RoadLayout::kRandom: return "random";
  }
  return "?";
}

RoadLayout parse_road_layout(const std::string& name) {
  if (name == "line") return RoadLayout::kLine;
  if (name == "grid") return RoadLayout::kGrid;
  if (name == "random") return RoadLayout::kRandom;
  throw_error(ErrorCode::kInvalidArgument, "city layout option layout: unknown value '", name,
              "' (expected line, grid or random)");
}

void CityLayoutOptions::validate() const {
  require(road_length_m >= 10.0 && road_length_m <= 1e6, "road_length_m", "must be in [10, 1e6] metres");
  require(grid_blocks_x >= 1 && grid_blocks_x <= 1000, "grid_blocks_x", "must be in [1, 1000]");
  require(grid_blocks_y >= 1 && grid_blocks_y <= 1000, "grid_blocks_y", "must be in [1, 1000]");
  require(block_size_m >= 40.0 && block_size_m <= 1e4, "block_size_m", "must be in [40, 1e4] metres");
  require(random_roads >= 1 && random_roads <= 10000, "random_roads", "must be in [1, 10000]");
  require(random_extent_m > 0.0, "random_extent_m", "must be positive");
  require(random_max_turn_deg >= 0.0 && random_max_turn_deg <= 90.0, "random_max_turn_deg", "must be in [0, 90]");
  require(road_half_width_m >= 2.0 && road_half_width_m <= 30.0, "road_half_width_m", "must be in [2, 30] metres");
  require(sidewalk_width_m >= 0.0 && sidewalk_width_m <= 20.0, "sidewalk_width_m", "must be in [0, 20] metres");
  require(building_width_min_m >= 3.0, "building_width_min_m", "must be at least 3 metres");
  require(building_width_max_m >= building_width_min_m, "building_width_max_m", "must be >= building_width_min_m");
  require(building_depth_min_m >= 3.0, "building_depth_min_m", "must be at least 3 metres");
  require(building_depth_max_m >= building_depth_min_m, "building_depth_max_m", "must be >= building_depth_min_m");
  require(floors_min >= 1 && floors_min <= 100, "floors_min", "must be in [1, 100]");
  require(floors_max >= floors_min && floors_max <= 100, "floors_max", "must be in [floors_min, 100]");
  require(building_gap_max_m >= 0.0, "building_gap_max_m", "must be >= 0");
  require(setback_max_m >= 0.0, "setback_max_m", "must be >= 0");
  require(wing_probability >= 0.0 && wing_probability <= 1.0, "wing_probability", "must be in [0, 1]");
  require(building_designs >= 0 && building_designs <= 100000, "building_designs", "must be in [0, 100000]");
  require(building_design_share >= 0.0 && building_design_share <= 1.0, "building_design_share", "must be in [0, 1]");
  require(building_designs > 0 || building_design_share == 1.0, "building_design_share",
          "applies only with building_designs > 0 (it would be ignored)");
  require(placemark_spacing_min_m >= 1.0, "placemark_spacing_min_m", "must be at least 1 metre");
  require(placemark_spacing_max_m >= placemark_spacing_min_m, "placemark_spacing_max_m",
          "must be >= placemark_spacing_min_m");
  require(camera_height_m > 0.2 && camera_height_m < 50.0, "camera_height_m", "must be in (0.2, 50) metres");
}

double Road::length() const {
  double l = 0;
  for (size_t i = 1; i < points.size(); ++i) l += (points[i] - points[i - 1]).norm();
  return l;
}

void Road::at(double s, Eigen::Vector2d& point, Eigen::Vector2d& direction) const {
  VISLOC_CHECK(points.size() >= 2);
  double remaining = std::max(0.0, s);
  for (size_t i = 1; i < points.size(); ++i) {
    const Eigen::Vector2d seg = points[i] - points[i - 1];
    const double len = seg.norm();
    if (remaining <= len || i + 1 == points.size()) {
      direction = seg / len;
      point = points[i - 1] + direction * std::min(remaining, len);
      return;
    }
    remaining -= len;
  }
}

double CityScene::total_road_length() const {
  double l = 0;
  for (const auto& r : roads) l += r.length();
  return l;
}

double footprint_distance(const BoxPrimitive& box, const Eigen::Vector2d& p) {
  const double dx = p.x() - box.cx, dy = p.y() - box.cy;
  const double lx = std::abs(box.cos_yaw * dx + box.sin_yaw * dy) - box.half_x;
  const double ly = std::abs(-box.sin_yaw * dx + box.cos_yaw * dy) - box.half_y;
  return std::hypot(std::max(lx, 0.0), std::max(ly, 0.0));
}

bool footprint_contains(const BoxPrimitive& box, const Eigen::Vector2d& p, double margin) {
  const double dx = p.x() - box.cx, dy = p.y() - box.cy;
  return std::abs(box.cos_yaw * dx + box.sin_yaw * dy) <= box.half_x + margin &&
         std::abs(-box.sin_yaw * dx + box.cos_yaw * dy) <= box.half_y + margin;
}

namespace {

// The roads of the layout, and their straight pieces (road_segments).
void add_roads(const CityLayoutOptions& options, SplitMix64& rng, CityScene& scene) {
  switch (options.layout) {
    case RoadLayout::kLine: {
      const double h = options.road_length_m / 2;
      scene.roads.push_back(Road{{Eigen::Vector2d(-h, 0), Eigen::Vector2d(h, 0)}});
      break;
    }
    case RoadLayout::kGrid: {
      const double bs = options.block_size_m;
      const double wx = options.grid_blocks_x * bs, wy = options.grid_blocks_y * bs;
      for (int j = 0; j <= options.grid_blocks_y; ++j)
        scene.roads.push_back(Road{{Eigen::Vector2d(-wx / 2, j * bs - wy / 2), Eigen::Vector2d(wx / 2, j * bs - wy / 2)}});
      for (int i = 0; i <= options.grid_blocks_x; ++i)
        scene.roads.push_back(Road{{Eigen::Vector2d(i * bs - wx / 2, -wy / 2), Eigen::Vector2d(i * bs - wx / 2, wy / 2)}});
      break;
    }
    case RoadLayout::kRandom: {
      for (int r = 0; r < options.random_roads; ++r) {
        Road road;
        Eigen::Vector2d p(rng.uniform(-0.5, 0.5) * options.random_extent_m,
                          rng.uniform(-0.5, 0.5) * options.random_extent_m);
        double angle = rng.uniform(0, 2 * std::numbers::pi);
        road.points.push_back(p);
        double left = options.road_length_m;
        while (left > 1e-6) {
          const double step = std::min(left, rng.uniform(40.0, 80.0));
          p += step * Eigen::Vector2d(std::cos(angle), std::sin(angle));
          road.points.push_back(p);
          left -= step;
          angle += rng.uniform(-1.0, 1.0) * options.random_max_turn_deg * kDegToRad;
        }
        scene.roads.push_back(std::move(road));
      }
      break;
    }
  }
  for (size_t r = 0; r < scene.roads.size(); ++r) {
    double arc = 0;
    const auto& pts = scene.roads[r].points;
    for (size_t i = 1; i < pts.size(); ++i) {
      RoadSegment seg;
      seg.a = pts[i - 1];
      seg.length = (pts[i] - pts[i - 1]).norm();
      seg.direction = (pts[i] - pts[i - 1]) / seg.length;
      seg.arc_start = arc;
      seg.road = static_cast<int>(r);
      arc += seg.length;
      scene.road_segments.push_back(seg);
    }
  }
}

// What a copied building takes from its design (CityLayoutOptions::building_designs).
struct BuildingDesign {
  double width = 0, depth = 0;
  int floors = 1;
  BuildingStyle style;
  uint64_t facade_seed = 0;
  bool wing = false;  // and the wing's shape, as add_buildings draws it
  double wing_frac = 0.5, wing_depth = 5;
  int wing_floors = 1;
  bool wing_left = false;
};

std::vector<BuildingDesign> random_designs(const CityLayoutOptions& options, SplitMix64& rng) {
  std::vector<BuildingDesign> designs(static_cast<size_t>(options.building_designs));
  for (auto& d : designs) {
    d.width = rng.uniform(options.building_width_min_m, options.building_width_max_m);
    d.depth = rng.uniform(options.building_depth_min_m, options.building_depth_max_m);
    d.floors = rng.uniform_int(options.floors_min, options.floors_max);
    d.style = random_style(rng);
    d.facade_seed = rng.next();
    d.wing = rng.bernoulli(options.wing_probability);
    d.wing_frac = rng.uniform(0.35, 0.65);
    d.wing_depth = rng.uniform(5.0, 10.0);
    d.wing_floors = rng.uniform_int(options.floors_min, options.floors_max);
    d.wing_left = rng.bernoulli(0.5);
  }
  return designs;
}

// Buildings along both sides of every road segment, some with a wing behind.
void add_buildings(const CityLayoutOptions& options, SplitMix64& rng, CityScene& scene) {
  const std::vector<BuildingDesign> designs = random_designs(options, rng);  // none by default
  const double corridor = options.road_half_width_m + options.sidewalk_width_m;
  std::vector<BoxPrimitive>& boxes = scene.objects.boxes;
  const auto fits = [&](const BoxPrimitive& b, size_t skip) {
    for (const auto& s : scene.road_segments)
      if (segment_footprint_distance(b, s.a, s.a + s.length * s.direction) < corridor - 1e-6) return false;
    for (size_t i = 0; i < boxes.size(); ++i)
      if (i != skip && footprints_overlap(b, boxes[i], -0.02)) return false;
    return true;
  };
  for (const auto& seg : scene.road_segments) {
    const Eigen::Vector2d d = seg.direction, n(-d.y(), d.x());
    for (const int side : {1, -1}) {
      double t = rng.uniform(0.0, options.building_gap_max_m);
      while (true) {
        const BuildingDesign* design = nullptr;
        if (!designs.empty() && rng.bernoulli(options.building_design_share))
          design = &designs[static_cast<size_t>(rng.uniform_int(0, options.building_designs - 1))];
        const double w =
            design ? design->width : rng.uniform(options.building_width_min_m, options.building_width_max_m);
        if (t + w > seg.length) break;
        const double depth =
            design ? design->depth : rng.uniform(options.building_depth_min_m, options.building_depth_max_m);
        const double setback = rng.uniform(0.0, options.setback_max_m);
        const Eigen::Vector2d c = seg.a + d * (t + w / 2) + side * n * (corridor + setback + depth / 2);
        BuildingStyle style = design ? design->style : random_style(rng);
        const int floors = design ? design->floors : rng.uniform_int(options.floors_min, options.floors_max);
        const double height = style.ground_floor_height + (floors - 1) * style.floor_height + 0.6;
        BoxPrimitive box;
        box.cx = c.x();
        box.cy = c.y();
        // Local +y points away from the road, so the -y face is the front.
        box.cos_yaw = side > 0 ? d.x() : -d.x();
        box.sin_yaw = side > 0 ? d.y() : -d.y();
        box.half_x = w / 2;
        box.half_y = depth / 2;
        box.z_min = 0;
        box.z_max = height;
        box.kind = ObjectKind::kBuilding;
        box.seed = rng.next();
        if (design) box.seed = design->facade_seed;  // the same facades
        bool wing = rng.bernoulli(options.wing_probability);
        double wing_frac = rng.uniform(0.35, 0.65), wing_depth = rng.uniform(5.0, 10.0);
        int wing_floors = rng.uniform_int(options.floors_min, options.floors_max);
        bool wing_left = rng.bernoulli(0.5);
        if (design) {  // the whole building, wing included
          wing = design->wing;
          wing_frac = design->wing_frac;
          wing_depth = design->wing_depth;
          wing_floors = design->wing_floors;
          wing_left = design->wing_left;
        }
        const double gap = rng.bernoulli(0.4) ? 0.0 : rng.uniform(0.5, std::max(0.5, options.building_gap_max_m));
        if (fits(box, SIZE_MAX)) {
          box.style = static_cast<uint32_t>(scene.styles.size());
          scene.styles.push_back(style);
          boxes.push_back(box);
          ++scene.buildings;
          if (wing) {
            // A wing behind the main box, overlapping it by 0.3 m: an L footprint.
            BoxPrimitive wb = box;
            const double ww = wing_frac * w;
            const Eigen::Vector2d along(box.cos_yaw, box.sin_yaw), back(-box.sin_yaw, box.cos_yaw);
            const Eigen::Vector2d wc = c + back * (depth / 2 + wing_depth / 2 - 0.3) +
                                       along * ((wing_left ? -1 : 1) * (w - ww) / 2);
            wb.cx = wc.x();
            wb.cy = wc.y();
            wb.half_x = ww / 2;
            wb.half_y = wing_depth / 2;
            wb.z_max = style.ground_floor_height + (wing_floors - 1) * style.floor_height + 0.6;
            wb.seed = mix64(box.seed);
            if (fits(wb, boxes.size() - 1)) boxes.push_back(wb);
          }
        }
        t += w + gap;
      }
    }
  }
}

// Placemarks every placemark_spacing_min_m to _max_m metres along each road.
void add_placemarks(const CityLayoutOptions& options, SplitMix64& rng, CityScene& scene) {
  int id = 0;
  for (size_t r = 0; r < scene.roads.size(); ++r) {
    const double len = scene.roads[r].length();
    for (double s = options.placemark_spacing_min_m / 2; s <= len;
         s += rng.uniform(options.placemark_spacing_min_m, options.placemark_spacing_max_m)) {
      Placemark pm;
      pm.id = id++;
      pm.road = static_cast<int>(r);
      pm.arc = s;
      Eigen::Vector2d p, d;
      scene.roads[r].at(s, p, d);
      pm.position = Eigen::Vector3d(p.x(), p.y(), options.camera_height_m);
      pm.road_heading_deg = std::fmod(std::atan2(d.x(), d.y()) / kDegToRad + 360.0, 360.0);
      scene.placemarks.push_back(pm);
    }
  }
}

}  // namespace

CityScene generate_city_scene(const CityLayoutOptions& options) {
  options.validate();
  CityScene scene;
  scene.layout = options;
  scene.road_half_width = options.road_half_width_m;
  scene.sidewalk_width = options.sidewalk_width_m;
  SplitMix64 rng(hash_keys(options.seed, 0x5c17));

  add_roads(options, rng, scene);
  add_buildings(options, rng, scene);
  add_placemarks(options, rng, scene);
  return scene;
}

}  // namespace visloc::synth
