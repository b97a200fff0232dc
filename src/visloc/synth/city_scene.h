// The synthetic city's geometry: a street network lined with buildings, in a
// local east-north-up frame (metres, x east, y north, z up, ground at z = 0).
//
// Roads are polylines with a carriageway and sidewalks; buildings are boxes
// standing on the ground, rotated about z to follow their road (an L-shaped
// footprint is a main box plus a wing box); every face of a building carries
// a procedural facade (docs in surface_shading.h). Placemarks sit on the road
// centre line every 10-12 m, as Google Street View's do in the paper
// (Tran et al., Sec. IV-A: "the distance between two placemarks is about
// 10-12 m"). Generation is a pure function of CityLayoutOptions (seed
// included).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "visloc/synth/procedural_texture.h"

namespace visloc::synth {

enum class RoadLayout { kLine, kGrid, kRandom };
const char* to_string(RoadLayout layout);
RoadLayout parse_road_layout(const std::string& name);  // throws naming the value

struct CityLayoutOptions {
  RoadLayout layout = RoadLayout::kLine;
  double road_length_m = 200.0;      // line: the street's length; random: each road's length
  int grid_blocks_x = 2;             // grid: blocks east-west
  int grid_blocks_y = 2;             // grid: blocks north-south
  double block_size_m = 90.0;        // grid: distance between parallel streets
  int random_roads = 3;              // random: number of polyline roads
  double random_extent_m = 300.0;    // random: roads start inside this square
  double random_max_turn_deg = 35.0; // random: largest turn at a polyline vertex
  double road_half_width_m = 5.0;    // carriageway half width
  double sidewalk_width_m = 3.0;
  double building_width_min_m = 8.0;  // frontage along the road
  double building_width_max_m = 22.0;
  double building_depth_min_m = 8.0;
  double building_depth_max_m = 16.0;
  int floors_min = 2;
  int floors_max = 8;
  double building_gap_max_m = 3.0;    // gap between neighbours (0 = terraced rows possible)
  double setback_max_m = 1.5;         // distance from the sidewalk's edge
  double wing_probability = 0.3;      // chance of an L-shaped footprint
  // 0: every building is its own design. N > 0: a building copies one of N
  // designs (frontage, depth, floors, style, facade and wing), drawn at
  // random, with probability building_design_share, else it is its own:
  // identical houses here and there, the repetition that can mislead a
  // localizer (only the setback from the road, the roof, and a wing that
  // has no room behind a copy differ).
  int building_designs = 0;
  double building_design_share = 1.0;
  double placemark_spacing_min_m = 10.0;
  double placemark_spacing_max_m = 12.0;
  double camera_height_m = 2.5;       // street-view camera above the road
  uint64_t seed = 1;

  // Throws Error(kInvalidArgument) naming the bad field.
  void validate() const;
};

enum class FacadeMaterial : uint8_t { kPlaster, kBrick, kConcretePanels, kStone };

// The look of one building: materials, colours and the window grid.
struct BuildingStyle {
  FacadeMaterial material = FacadeMaterial::kPlaster;
  Rgb wall, trim, frame, glass, door;
  float floor_height = 3.2f;         // metres per upper floor
  float ground_floor_height = 4.0f;
  float bay_width = 3.0f;            // horizontal window period
  float window_width = 1.3f;
  float window_height = 1.6f;
  float sill_height = 0.9f;          // window bottom above the floor
  float blank_face_probability = 0.15f;  // a face without windows (posters, murals)
  bool shop_front = true;            // ground floor of shops with signs
  bool balconies = false;
  int balcony_period = 1;            // balconies on every n-th floor
  bool mullion = true;               // a vertical bar splitting each window
  uint64_t seed = 0;
};

enum class ObjectKind : uint8_t {
  kBuilding,      // box: facades on the sides, roof on top
  kCarBody,       // box
  kCarCabin,      // box
  kTreeTrunk,     // vertical cylinder
  kTreeCanopy,    // sphere
  kMarker,        // sphere, flat unlit colour (tests, calibration)
};

// A box standing upright: centre (cx, cy), rotated by yaw about z, half
// extents along its own x and y, vertical extent [z_min, z_max].
struct BoxPrimitive {
  double cx = 0, cy = 0, cos_yaw = 1, sin_yaw = 0;
  double half_x = 1, half_y = 1, z_min = 0, z_max = 1;
  ObjectKind kind = ObjectKind::kBuilding;
  uint32_t style = 0;  // index into CityScene::styles (buildings)
  uint64_t seed = 0;   // per-object randomness (faces, colours)
  Rgb colour;          // cars
};

struct SpherePrimitive {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  double radius = 1.0;
  ObjectKind kind = ObjectKind::kMarker;
  uint64_t seed = 0;
  Rgb colour;
};

struct CylinderPrimitive {  // vertical
  double cx = 0, cy = 0, radius = 0.2, z_min = 0, z_max = 1;
  ObjectKind kind = ObjectKind::kTreeTrunk;
  uint64_t seed = 0;
  Rgb colour;
};

struct SceneObjects {
  std::vector<BoxPrimitive> boxes;
  std::vector<SpherePrimitive> spheres;
  std::vector<CylinderPrimitive> cylinders;
  size_t size() const { return boxes.size() + spheres.size() + cylinders.size(); }
};

// One straight piece of a road, for ground shading.
struct RoadSegment {
  Eigen::Vector2d a = Eigen::Vector2d::Zero();
  Eigen::Vector2d direction = Eigen::Vector2d::UnitX();  // unit
  double length = 0;
  double arc_start = 0;  // arc length of `a` along its road (dashed lines)
  int road = 0;
};

struct Road {
  std::vector<Eigen::Vector2d> points;  // polyline vertices
  double length() const;
  // Point and unit direction at arc length s (clamped to the ends).
  void at(double s, Eigen::Vector2d& point, Eigen::Vector2d& direction) const;
};

struct Placemark {
  int id = 0;          // 0-based, consecutive along each road
  int road = 0;
  double arc = 0;      // arc length along the road, metres
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // camera centre, ENU
  double road_heading_deg = 0;  // road direction, clockwise from north
};

struct CityScene {
  CityLayoutOptions layout;
  std::vector<Road> roads;
  std::vector<RoadSegment> road_segments;
  std::vector<BuildingStyle> styles;
  SceneObjects objects;  // static: buildings (and markers added by the caller)
  std::vector<Placemark> placemarks;
  int buildings = 0;     // a building may be two boxes
  double road_half_width = 5.0;
  double sidewalk_width = 3.0;

  double total_road_length() const;
};

CityScene generate_city_scene(const CityLayoutOptions& options);

// Distance from the rectangle of `box` (its footprint) to a 2D point.
double footprint_distance(const BoxPrimitive& box, const Eigen::Vector2d& p);
// Whether a point (x, y) lies inside the footprint of `box`, grown by `margin`.
bool footprint_contains(const BoxPrimitive& box, const Eigen::Vector2d& p, double margin = 0.0);

}  // namespace visloc::synth
