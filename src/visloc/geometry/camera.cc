#include "visloc/geometry/camera.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "visloc/util/error.h"

namespace visloc {

PinholeCamera PinholeCamera::from_colmap(const std::string& model, int width, int height,
                                         const std::vector<double>& p) {
  auto need = [&](size_t n) {
    if (p.size() != n)
      throw_error(ErrorCode::kInvalidArgument, "camera model ", model, " takes ", n, " parameters, found ", p.size());
  };
  PinholeCamera k = centered(width, height);
  if (model == "SIMPLE_PINHOLE") {
    need(3);
    k.focal = p[0], k.cx = p[1], k.cy = p[2];
  } else if (model == "PINHOLE") {
    need(4);
    if (!(p[0] > 0 && std::isfinite(p[0]) && p[1] > 0 && std::isfinite(p[1])))
      throw_error(ErrorCode::kInvalidArgument, "camera model PINHOLE: fx and fy must be positive numbers, got ", p[0],
                  " and ", p[1]);
    k.focal = p[0], k.aspect = p[1] / p[0], k.cx = p[2], k.cy = p[3];
  } else if (model == "SIMPLE_RADIAL") {
    need(4);
    k.focal = p[0], k.cx = p[1], k.cy = p[2], k.k1 = p[3];
  } else if (model == "OPENCV") {
    need(8);
    if (p[5] != 0.0 || p[6] != 0.0 || p[7] != 0.0)
      throw_error(ErrorCode::kInvalidArgument,
                  "camera model OPENCV with k2, p1 or p2 != 0 is not supported (fx fy cx cy k1 0 0 0 is)");
    if (!(p[0] > 0 && std::isfinite(p[0]) && p[1] > 0 && std::isfinite(p[1])))
      throw_error(ErrorCode::kInvalidArgument, "camera model OPENCV: fx and fy must be positive numbers, got ", p[0],
                  " and ", p[1]);
    k.focal = p[0], k.aspect = p[1] / p[0], k.cx = p[2], k.cy = p[3], k.k1 = p[4];
  } else if (model == "RADIAL") {
    need(5);
    if (p[4] != 0.0) throw_error(ErrorCode::kInvalidArgument, "camera model RADIAL with k2 != 0 is not supported");
    k.focal = p[0], k.cx = p[1], k.cy = p[2], k.k1 = p[3];
  } else {
    throw_error(ErrorCode::kInvalidArgument, "camera model '", model,
                "' is not supported (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)");
  }
  k.has_focal = true;
  k.validate();
  return k;
}

std::pair<std::string, std::vector<double>> PinholeCamera::colmap_model() const {
  if (aspect == 1.0) {
    if (k1 == 0.0) return {"SIMPLE_PINHOLE", {focal, cx, cy}};
    return {"SIMPLE_RADIAL", {focal, cx, cy, k1}};
  }
  if (k1 == 0.0) return {"PINHOLE", {focal, focal_y(), cx, cy}};
  return {"OPENCV", {focal, focal_y(), cx, cy, k1, 0.0, 0.0, 0.0}};
}

PinholeCamera PinholeCamera::centered(int width, int height, std::optional<double> focal_px) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.cx = width / 2.0;
  c.cy = height / 2.0;
  if (focal_px) {
    c.focal = *focal_px;
    c.has_focal = true;
  }
  return c;
}

void PinholeCamera::validate() const {
  if (width <= 0 || height <= 0)
    throw_error(ErrorCode::kInvalidArgument, "camera: width and height must be positive, got ",
                width, "x", height);
  if (has_focal && !(focal > 0 && std::isfinite(focal)))
    throw_error(ErrorCode::kInvalidArgument, "camera: focal must be a positive number, got ", focal);
  if (!(cx >= 0 && cx <= width && cy >= 0 && cy <= height))
    throw_error(ErrorCode::kInvalidArgument, "camera: principal point (", cx, ", ", cy, ") must lie inside the ", width,
                "x", height, " image");
  if (!(aspect >= kMinAspect && aspect <= kMaxAspect))
    throw_error(ErrorCode::kInvalidArgument, "camera: the pixel aspect fy / fx must be in [", kMinAspect, ", ",
                kMaxAspect, "], got ", aspect);
  if (!std::isfinite(k1) || std::abs(k1) > 10)
    throw_error(ErrorCode::kInvalidArgument, "camera: k1 must be finite and |k1| <= 10, got ", k1);
}

Eigen::Vector2d PinholeCamera::project(const Eigen::Vector3d& p) const {
  Eigen::Vector2d n = p.head<2>() / p.z();
  if (k1 != 0.0) n *= 1.0 + k1 * n.squaredNorm();
  return {focal * n.x() + cx, focal_y() * n.y() + cy};
}

Eigen::Vector2d PinholeCamera::normalize(const Eigen::Vector2d& pixel) const {
  Eigen::Vector2d d((pixel.x() - cx) / focal, (pixel.y() - cy) / focal_y());
  if (k1 == 0.0) return d;
  // Invert d = u (1 + k1 |u|^2) by Newton's method on the radius.
  const double rd = d.norm();
  if (rd == 0.0) return d;
  double r = rd;
  for (int i = 0; i < 20; ++i) {
    const double f = r * (1 + k1 * r * r) - rd;
    const double df = 1 + 3 * k1 * r * r;
    const double step = f / df;
    r -= step;
    if (std::abs(step) < 1e-14) break;
  }
  return d * (r / rd);
}

double PinholeCamera::horizontal_fov_deg() const {
  return 2.0 * std::atan2(width / 2.0, focal) * 180.0 / std::numbers::pi;
}

double focal_px_from_35mm(double focal_35mm, int width, int height) {
  return focal_35mm / 36.0 * std::max(width, height);
}

}  // namespace visloc
