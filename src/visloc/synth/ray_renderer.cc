#include "visloc/synth/ray_renderer.h"

#include <algorithm>
#include <cmath>

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc::synth {
namespace {

enum class HitType : uint8_t { kNone, kGround, kBox, kSphere, kCylinder };

struct Hit {
  double t = 0;
  HitType type = HitType::kNone;
  const void* primitive = nullptr;
  int face = 0;            // box: 0 +x, 1 -x, 2 +y, 3 -y, 4 top
  double lx = 0, ly = 0;   // box: hit point in the box frame
};

// Ray against an upright rotated box (slab method in the box frame).
inline void intersect_box(const BoxPrimitive& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, Hit& hit) {
  const double px = o.x() - b.cx, py = o.y() - b.cy;
  const double lox = b.cos_yaw * px + b.sin_yaw * py, loy = -b.sin_yaw * px + b.cos_yaw * py;
  const double ldx = b.cos_yaw * d.x() + b.sin_yaw * d.y(), ldy = -b.sin_yaw * d.x() + b.cos_yaw * d.y();
  double tmin = 1e-9, tmax = hit.t;
  int face = -1;
  // x slab
  if (std::abs(ldx) < 1e-15) {
    if (std::abs(lox) > b.half_x) return;
  } else {
    const double inv = 1.0 / ldx;
    double t0 = (-b.half_x - lox) * inv, t1 = (b.half_x - lox) * inv;
    int f0 = 1;  // entering through -x
    if (t0 > t1) { std::swap(t0, t1); f0 = 0; }
    if (t0 > tmin) { tmin = t0; face = f0; }
    tmax = std::min(tmax, t1);
    if (tmin > tmax) return;
  }
  if (std::abs(ldy) < 1e-15) {
    if (std::abs(loy) > b.half_y) return;
  } else {
    const double inv = 1.0 / ldy;
    double t0 = (-b.half_y - loy) * inv, t1 = (b.half_y - loy) * inv;
    int f0 = 3;
    if (t0 > t1) { std::swap(t0, t1); f0 = 2; }
    if (t0 > tmin) { tmin = t0; face = f0; }
    tmax = std::min(tmax, t1);
    if (tmin > tmax) return;
  }
  if (std::abs(d.z()) < 1e-15) {
    if (o.z() < b.z_min || o.z() > b.z_max) return;
  } else {
    const double inv = 1.0 / d.z();
    double t0 = (b.z_min - o.z()) * inv, t1 = (b.z_max - o.z()) * inv;
    int f0 = 5;  // bottom
    if (t0 > t1) { std::swap(t0, t1); f0 = 4; }
    if (t0 > tmin) { tmin = t0; face = f0; }
    tmax = std::min(tmax, t1);
    if (tmin > tmax) return;
  }
  if (face < 0 || tmin >= hit.t) return;  // origin inside the box, or farther than the current hit
  hit.t = tmin;
  hit.type = HitType::kBox;
  hit.primitive = &b;
  hit.face = face;
  hit.lx = lox + tmin * ldx;
  hit.ly = loy + tmin * ldy;
}

inline void intersect_sphere(const SpherePrimitive& s, const Eigen::Vector3d& o, const Eigen::Vector3d& d, Hit& hit) {
  const Eigen::Vector3d oc = o - s.center;
  const double b = oc.dot(d), c = oc.squaredNorm() - s.radius * s.radius;
  const double disc = b * b - c;
  if (disc < 0) return;
  const double t = -b - std::sqrt(disc);
  if (t > 1e-9 && t < hit.t) {
    hit.t = t;
    hit.type = HitType::kSphere;
    hit.primitive = &s;
  }
}

inline void intersect_cylinder(const CylinderPrimitive& c, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                               Hit& hit) {
  const double ox = o.x() - c.cx, oy = o.y() - c.cy;
  const double a = d.x() * d.x() + d.y() * d.y();
  if (a < 1e-15) return;
  const double b = ox * d.x() + oy * d.y(), cc = ox * ox + oy * oy - c.radius * c.radius;
  const double disc = b * b - a * cc;
  if (disc < 0) return;
  const double t = (-b - std::sqrt(disc)) / a;
  if (t <= 1e-9 || t >= hit.t) return;
  const double z = o.z() + t * d.z();
  if (z < c.z_min || z > c.z_max) return;
  hit.t = t;
  hit.type = HitType::kCylinder;
  hit.primitive = &c;
}

inline void intersect_ground(const Eigen::Vector3d& o, const Eigen::Vector3d& d, Hit& hit) {
  if (d.z() < -1e-12 && o.z() > 0) {
    const double t = -o.z() / d.z();
    if (t < hit.t) {
      hit.t = t;
      hit.type = HitType::kGround;
    }
  }
}

Eigen::Vector4d bounding_sphere(const BoxPrimitive& b) {
  const double hz = (b.z_max - b.z_min) / 2;
  return {b.cx, b.cy, b.z_min + hz, std::sqrt(b.half_x * b.half_x + b.half_y * b.half_y + hz * hz)};
}
Eigen::Vector4d bounding_sphere(const SpherePrimitive& s) { return {s.center.x(), s.center.y(), s.center.z(), s.radius}; }
Eigen::Vector4d bounding_sphere(const CylinderPrimitive& c) {
  const double hz = (c.z_max - c.z_min) / 2;
  return {c.cx, c.cy, c.z_min + hz, std::sqrt(c.radius * c.radius + hz * hz)};
}

// Four inward side planes of a frustum through the camera centre, given its
// corner rays in order around the frustum (normals unit length).
struct Frustum {
  Eigen::Vector3d normals[4];
  Eigen::Vector3d origin;
  double max_distance = 0;
  void set(const Eigen::Vector3d& origin_, const Eigen::Vector3d corners[4], const Eigen::Vector3d& inside,
           double max_d) {
    origin = origin_;
    max_distance = max_d;
    for (int i = 0; i < 4; ++i) {
      Eigen::Vector3d n = corners[i].cross(corners[(i + 1) % 4]).normalized();
      if (n.dot(inside) < 0) n = -n;
      normals[i] = n;
    }
  }
  bool may_see(const Eigen::Vector4d& sphere) const {
    const Eigen::Vector3d v = sphere.head<3>() - origin;
    const double r = sphere.w();
    if (v.norm() - r > max_distance) return false;
    for (const auto& n : normals)
      if (n.dot(v) < -r) return false;
    return true;
  }
};

}  // namespace

void RenderOptions::validate() const {
  if (supersampling < 1 || supersampling > 8)
    throw_error(ErrorCode::kInvalidArgument, "render option supersampling: must be in [1, 8], got ", supersampling);
  if (!(max_distance_m > 1.0))
    throw_error(ErrorCode::kInvalidArgument, "render option max_distance_m: must be > 1 metre, got ", max_distance_m);
  if (!(haze_distance_m > 0.0))
    throw_error(ErrorCode::kInvalidArgument, "render option haze_distance_m: must be positive, got ", haze_distance_m);
  if (!(photo_fraction >= 0.0 && photo_fraction <= 1.0))
    throw_error(ErrorCode::kInvalidArgument, "render option photo_fraction: must be in [0, 1], got ", photo_fraction);
}

ViewRenderer::ViewRenderer(const CityScene& scene, const PhotoCropSet* photos, const RenderOptions& options)
    : scene_(scene), photos_(photos), options_(options) {
  options_.validate();
}

std::optional<double> ViewRenderer::cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& d,
                                             const SceneObjects* extras) const {
  Hit hit;
  hit.t = options_.max_distance_m;
  intersect_ground(origin, d, hit);
  for (const SceneObjects* objects : {&scene_.objects, extras}) {
    if (!objects) continue;
    for (const auto& b : objects->boxes) intersect_box(b, origin, d, hit);
    for (const auto& s : objects->spheres) intersect_sphere(s, origin, d, hit);
    for (const auto& c : objects->cylinders) intersect_cylinder(c, origin, d, hit);
  }
  if (hit.type == HitType::kNone) return std::nullopt;
  return hit.t;
}

RenderStats ViewRenderer::render(const PinholeCamera& camera, const CameraPose& cam_from_world, RgbImage& image,
                                 const SceneObjects* extras) {
  camera.validate();
  if (!camera.has_focal) throw_error(ErrorCode::kInvalidArgument, "render: the camera needs a focal length");
  Timer timer;
  RenderStats stats;
  const int W = camera.width, H = camera.height, ss = options_.supersampling;
  const double f = camera.focal, cx = camera.cx, cy = camera.cy, k1 = camera.k1;
  const Eigen::Matrix3d world_from_cam = cam_from_world.rotation_matrix().transpose();
  const Eigen::Vector3d C = cam_from_world.center();
  const auto pixel_ray = [&](double x, double y) {
    double nx = (x - cx) / f, ny = (y - cy) / f;
    if (k1 != 0.0) {  // invert p (1 + k1 |p|²) by fixed-point iteration
      const double dx = nx, dy = ny;
      for (int i = 0; i < 10; ++i) {
        const double s = 1.0 + k1 * (nx * nx + ny * ny);
        nx = dx / s;
        ny = dy / s;
      }
    }
    return Eigen::Vector3d(world_from_cam * Eigen::Vector3d(nx, ny, 1.0));
  };

  // --- View culling ---
  view_.clear();
  view_box_spheres_.clear();
  view_sphere_spheres_.clear();
  view_cylinder_spheres_.clear();
  Frustum view_frustum;
  {
    // With distortion the image border is not a straight frustum edge: widen.
    const double m = k1 != 0.0 ? 0.25 * std::max(W, H) : 1.0;
    const Eigen::Vector3d corners[4] = {pixel_ray(-m, -m), pixel_ray(W + m, -m), pixel_ray(W + m, H + m),
                                        pixel_ray(-m, H + m)};
    view_frustum.set(C, corners, pixel_ray(cx, cy), options_.max_distance_m);
  }
  for (const SceneObjects* objects : {&scene_.objects, extras}) {
    if (!objects) continue;
    for (const auto& b : objects->boxes) {
      const Eigen::Vector4d s = bounding_sphere(b);
      if (view_frustum.may_see(s)) { view_.boxes.push_back(&b); view_box_spheres_.push_back(s); }
    }
    for (const auto& sp : objects->spheres) {
      const Eigen::Vector4d s = bounding_sphere(sp);
      if (view_frustum.may_see(s)) { view_.spheres.push_back(&sp); view_sphere_spheres_.push_back(s); }
    }
    for (const auto& c : objects->cylinders) {
      const Eigen::Vector4d s = bounding_sphere(c);
      if (view_frustum.may_see(s)) { view_.cylinders.push_back(&c); view_cylinder_spheres_.push_back(s); }
    }
  }
  stats.candidate_primitives = view_.boxes.size() + view_.spheres.size() + view_.cylinders.size();
  view_roads_.clear();
  const double road_reach = options_.max_distance_m + scene_.road_half_width + scene_.sidewalk_width;
  for (const auto& r : scene_.road_segments) {
    const Eigen::Vector2d p(C.x() - r.a.x(), C.y() - r.a.y());
    const double t = std::clamp(p.dot(r.direction), 0.0, r.length);
    if ((p - t * r.direction).norm() < road_reach) view_roads_.push_back(&r);
  }
  ShadingContext ctx;
  ctx.scene = &scene_;
  ctx.photos = photos_;
  ctx.photo_fraction = options_.photo_fraction;
  ctx.roads = view_roads_.data();
  ctx.road_count = view_roads_.size();

  image.width = W;
  image.height = H;
  image.pixels.resize(static_cast<size_t>(W) * H * 3);
  const double inv_ss = 1.0 / ss, sample_angle = 1.0 / (f * ss);
  const Rgb horizon = horizon_colour();
  constexpr int kTile = 16;
  for (int ty = 0; ty < H; ty += kTile) {
    for (int tx = 0; tx < W; tx += kTile) {
      const int x1 = std::min(W, tx + kTile), y1 = std::min(H, ty + kTile);
      // Tile culling.
      Frustum tf;
      const double m = k1 != 0.0 ? 2.0 : 0.0;
      const Eigen::Vector3d corners[4] = {pixel_ray(tx - m, ty - m), pixel_ray(x1 + m, ty - m),
                                          pixel_ray(x1 + m, y1 + m), pixel_ray(tx - m, y1 + m)};
      tf.set(C, corners, pixel_ray((tx + x1) / 2.0, (ty + y1) / 2.0), options_.max_distance_m);
      tile_.clear();
      for (size_t i = 0; i < view_.boxes.size(); ++i)
        if (tf.may_see(view_box_spheres_[i])) tile_.boxes.push_back(view_.boxes[i]);
      for (size_t i = 0; i < view_.spheres.size(); ++i)
        if (tf.may_see(view_sphere_spheres_[i])) tile_.spheres.push_back(view_.spheres[i]);
      for (size_t i = 0; i < view_.cylinders.size(); ++i)
        if (tf.may_see(view_cylinder_spheres_[i])) tile_.cylinders.push_back(view_.cylinders[i]);

      for (int py = ty; py < y1; ++py) {
        for (int px = tx; px < x1; ++px) {
          float r = 0, g = 0, b = 0;
          for (int sy = 0; sy < ss; ++sy) {
            for (int sx = 0; sx < ss; ++sx) {
              const Eigen::Vector3d d = pixel_ray(px + (sx + 0.5) * inv_ss, py + (sy + 0.5) * inv_ss).normalized();
              Hit hit;
              hit.t = options_.max_distance_m;
              intersect_ground(C, d, hit);
              for (const BoxPrimitive* bx : tile_.boxes) intersect_box(*bx, C, d, hit);
              for (const SpherePrimitive* sp : tile_.spheres) intersect_sphere(*sp, C, d, hit);
              for (const CylinderPrimitive* cy_ : tile_.cylinders) intersect_cylinder(*cy_, C, d, hit);
              Rgb colour;
              if (hit.type == HitType::kNone) {
                colour = shade_sky(d);
              } else {
                const Eigen::Vector3d p = C + hit.t * d;
                Eigen::Vector3d normal(0, 0, 1);
                bool lit = true;
                switch (hit.type) {
                  case HitType::kGround: {
                    const double fp = hit.t * sample_angle / std::max(std::abs(d.z()), 0.1);
                    colour = shade_ground(ctx, p.x(), p.y(), fp);
                    break;
                  }
                  case HitType::kBox: {
                    const auto& bx = *static_cast<const BoxPrimitive*>(hit.primitive);
                    Eigen::Vector2d ln(0, 0);  // local normal
                    double u = 0, w = 0;
                    switch (hit.face) {
                      case 0: ln = {1, 0}; u = hit.ly + bx.half_y; w = 2 * bx.half_y; break;
                      case 1: ln = {-1, 0}; u = bx.half_y - hit.ly; w = 2 * bx.half_y; break;
                      case 2: ln = {0, 1}; u = bx.half_x - hit.lx; w = 2 * bx.half_x; break;
                      case 3: ln = {0, -1}; u = hit.lx + bx.half_x; w = 2 * bx.half_x; break;
                      default: break;
                    }
                    if (hit.face < 4)
                      normal = Eigen::Vector3d(bx.cos_yaw * ln.x() - bx.sin_yaw * ln.y(),
                                               bx.sin_yaw * ln.x() + bx.cos_yaw * ln.y(), 0.0);
                    const double fp = hit.t * sample_angle / std::max(std::abs(normal.dot(d)), 0.1);
                    const double v = p.z() - bx.z_min;
                    if (bx.kind == ObjectKind::kBuilding) {
                      colour = hit.face >= 4 ? shade_roof(scene_.styles[bx.style], p.x(), p.y(), fp)
                                             : shade_facade(ctx, scene_.styles[bx.style],
                                                            hash_keys(bx.seed, static_cast<uint64_t>(hit.face)), u, v,
                                                            w, bx.z_max - bx.z_min, fp);
                    } else if (bx.kind == ObjectKind::kCarCabin) {
                      colour = shade_car_cabin(bx, u, v, fp);
                    } else {
                      colour = shade_car_body(bx, u, v, fp);
                    }
                    break;
                  }
                  case HitType::kSphere: {
                    const auto& sp = *static_cast<const SpherePrimitive*>(hit.primitive);
                    normal = (p - sp.center) / sp.radius;
                    if (sp.kind == ObjectKind::kMarker) {
                      colour = sp.colour;
                      lit = false;
                    } else {
                      colour = shade_canopy(sp, p, hit.t * sample_angle);
                    }
                    break;
                  }
                  case HitType::kCylinder: {
                    const auto& c = *static_cast<const CylinderPrimitive*>(hit.primitive);
                    normal = Eigen::Vector3d(p.x() - c.cx, p.y() - c.cy, 0) / c.radius;
                    colour = shade_trunk(c, std::atan2(normal.y(), normal.x()) * c.radius, p.z(),
                                         hit.t * sample_angle);
                    break;
                  }
                  case HitType::kNone: break;
                }
                if (lit) {
                  colour = colour * sun_light(ctx, normal);
                  colour = mix(colour, horizon, 1.0f - static_cast<float>(std::exp(-hit.t / options_.haze_distance_m)));
                }
              }
              r += colour.r;
              g += colour.g;
              b += colour.b;
            }
          }
          const float scale = 255.0f / static_cast<float>(ss * ss);
          uint8_t* out = image.pixels.data() + (static_cast<size_t>(py) * W + px) * 3;
          out[0] = static_cast<uint8_t>(std::clamp(r * scale + 0.5f, 0.0f, 255.0f));
          out[1] = static_cast<uint8_t>(std::clamp(g * scale + 0.5f, 0.0f, 255.0f));
          out[2] = static_cast<uint8_t>(std::clamp(b * scale + 0.5f, 0.0f, 255.0f));
        }
      }
    }
  }
  stats.rays = static_cast<size_t>(W) * H * ss * ss;
  stats.milliseconds = timer.elapsed_ms();
  return stats;
}

std::vector<uint8_t> to_gray(const RgbImage& image) {
  std::vector<uint8_t> gray(static_cast<size_t>(image.width) * image.height);
  for (size_t i = 0; i < gray.size(); ++i) {
    const uint8_t* p = image.pixels.data() + 3 * i;
    gray[i] = static_cast<uint8_t>(std::clamp(0.299f * p[0] + 0.587f * p[1] + 0.114f * p[2] + 0.5f, 0.0f, 255.0f));
  }
  return gray;
}

}  // namespace visloc::synth
