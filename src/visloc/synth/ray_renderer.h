// ViewRenderer: renders pinhole views of a CityScene by CPU ray casting
// against the ground plane (z = 0), upright boxes (buildings, cars), spheres
// (tree canopies, markers) and vertical cylinders (trunks), with procedural
// textures (surface_shading.h) and s×s supersampling per pixel.
//
// Camera conventions are those of visloc::PinholeCamera and CameraPose: the
// camera looks along +z, x right, y down; pixel (i, j) covers
// [i, i+1] × [j, j+1] and its centre is (i + 0.5, j + 0.5), so a world point
// X appears at camera.project(cam_from_world.transform(X)). Samples sit at
// (i + (a + 0.5)/s, j + (b + 0.5)/s) for a, b in [0, s).
//
// Acceleration: primitives are culled once per view against the view
// frustum and range, then per 16×16-pixel tile against the tile's frustum
// (bounding spheres), so a ray tests only the few primitives its tile can
// see. Output is a pure function of (scene, extras, photos, camera, pose,
// options): the renderer holds no randomness and no global state.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <vector>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/synth/city_scene.h"
#include "visloc/synth/photo_crops.h"
#include "visloc/synth/surface_shading.h"

namespace visloc::synth {

struct RenderOptions {
  int supersampling = 2;          // s: s×s rays per pixel, box-filtered
  double max_distance_m = 400.0;  // rays end here; beyond is sky
  double haze_distance_m = 800.0; // aerial perspective: colour → horizon by 1 - exp(-d / haze)
  double photo_fraction = 0.5;    // share of posters showing a photo crop (when crops are given)
  void validate() const;           // throws naming the bad field
};

// 8-bit RGB, interleaved, rows top to bottom.
struct RgbImage {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> pixels;
  const uint8_t* at(int x, int y) const { return pixels.data() + (static_cast<size_t>(y) * width + x) * 3; }
};

// Counters of one render.
struct RenderStats {
  size_t rays = 0;
  size_t candidate_primitives = 0;  // after view culling
  double milliseconds = 0;
};

class ViewRenderer {
 public:
  // `photos` may be null; scene and photos must outlive the renderer.
  ViewRenderer(const CityScene& scene, const PhotoCropSet* photos, const RenderOptions& options);

  // Renders the view into `image` (resized to the camera's size). `extras`
  // are objects present in this view only (query occluders); may be null.
  RenderStats render(const PinholeCamera& camera, const CameraPose& cam_from_world, RgbImage& image,
                     const SceneObjects* extras = nullptr);

  // Distance along the unit ray to the first surface within max_distance,
  // empty when the ray reaches the sky.
  std::optional<double> cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& unit_direction,
                                 const SceneObjects* extras = nullptr) const;

  const RenderOptions& options() const { return options_; }

 private:
  struct Candidates {
    std::vector<const BoxPrimitive*> boxes;
    std::vector<const SpherePrimitive*> spheres;
    std::vector<const CylinderPrimitive*> cylinders;
    void clear() { boxes.clear(); spheres.clear(); cylinders.clear(); }
  };

  const CityScene& scene_;
  const PhotoCropSet* photos_;
  RenderOptions options_;
  // Workspace reused across renders (no allocation per tile or ray).
  Candidates view_, tile_;
  std::vector<Eigen::Vector4d> view_box_spheres_, view_sphere_spheres_, view_cylinder_spheres_;
  std::vector<const RoadSegment*> view_roads_;
};

// Luma (ITU-R BT.601, as OpenCV's RGB→grey) of an RGB image.
std::vector<uint8_t> to_gray(const RgbImage& image);

}  // namespace visloc::synth
