// Colours of the synthetic city's surfaces, evaluated analytically at a
// surface point (no stored texture, except optional photo crops).
//
// Facades are in face coordinates: u metres along the face from its left end
// (seen from outside), v metres above the building's base. A facade has a
// shop-front or residential ground floor (doors, shop windows with displays,
// signs whose glyph-like lettering is unique per shop), upper floors on a
// regular window grid (frames, sills, mullions, balconies with railings:
// repetitive on purpose, like the paper's facades), and per-window variation
// (blinds, curtains, lights) so that repeated windows are not identical.
// Some faces are blank walls carrying posters (procedural or photo crops).
// Materials: plaster, brick, concrete panels, stone, with large-scale
// weathering. Ground: asphalt with lane markings and manhole covers, curbs,
// paved sidewalks, gravel between buildings. Sky: gradient with clouds.
// Lighting: a fixed sun (Lambertian with a high ambient term, no shadows),
// identical in every view.
#pragma once

#include <Eigen/Core>
#include <cstdint>

#include "visloc/synth/city_scene.h"
#include "visloc/synth/photo_crops.h"

namespace visloc::synth {

struct ShadingContext {
  const CityScene* scene = nullptr;
  const PhotoCropSet* photos = nullptr;  // may be null or empty
  double photo_fraction = 0.5;           // share of posters showing a photo crop
  const RoadSegment* const* roads = nullptr;  // road segments near the view
  size_t road_count = 0;
  Eigen::Vector3d sun = Eigen::Vector3d(0.45, -0.55, 0.70).normalized();
};

// Facade colour (before lighting). footprint: metres per render sample.
Rgb shade_facade(const ShadingContext& ctx, const BuildingStyle& style, uint64_t face_seed, double u, double v,
                 double face_width, double face_height, double footprint);
Rgb shade_roof(const BuildingStyle& style, double x, double y, double footprint);
Rgb shade_ground(const ShadingContext& ctx, double x, double y, double footprint);
Rgb shade_sky(const Eigen::Vector3d& direction);
// Occluders: cars (body, cabin with windows), trees (trunk, canopy).
Rgb shade_car_body(const BoxPrimitive& car, double u, double v, double footprint);
Rgb shade_car_cabin(const BoxPrimitive& car, double u, double v, double footprint);
Rgb shade_trunk(const CylinderPrimitive& trunk, double angle_m, double z, double footprint);
Rgb shade_canopy(const SpherePrimitive& canopy, const Eigen::Vector3d& point, double footprint);

// Lambertian factor for a surface normal.
float sun_light(const ShadingContext& ctx, const Eigen::Vector3d& normal);

// Horizon colour, also the colour of aerial perspective (haze).
Rgb horizon_colour();

}  // namespace visloc::synth
