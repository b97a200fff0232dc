#include "visloc/pipeline/guided_confirmation.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "visloc/util/error.h"

namespace visloc {

namespace {
size_t count(const nlohmann::json& j, const char* key) {
  const auto it = j.find(key);
  if (it != j.end() && it->is_number_unsigned()) return it->get<size_t>();
  if (it == j.end() || !it->is_number_integer() || it->get<int64_t>() < 0)
    throw_error(ErrorCode::kFormat, "guided confirmation: '", key, "' must be a count (an integer >= 0)");
  return static_cast<size_t>(it->get<int64_t>());
}

// Squared L2 between a query descriptor and a decoded code, in eight partial
// sums (so that the compiler may vectorize it).
float squared_distance(const uint8_t* d, const float* c) {
  float s[8] = {};
  for (int j = 0; j < kDescriptorDim; j += 8)
    for (int l = 0; l < 8; ++l) {
      const float e = float(d[j + l]) - c[j + l];
      s[l] += e * e;
    }
  return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
}
}  // namespace

nlohmann::json GuidedConfirmation::to_json() const {
  return {{"predicted", predicted},
          {"examined", examined},
          {"confirmed", confirmed},
          {"examined_off_inliers", examined_off_inliers},
          {"confirmed_off_inliers", confirmed_off_inliers}};
}

GuidedConfirmation GuidedConfirmation::from_json(const nlohmann::json& j) {
  if (!j.is_object()) throw_error(ErrorCode::kFormat, "guided confirmation: expected an object");
  GuidedConfirmation g;
  g.predicted = count(j, "predicted");
  g.examined = count(j, "examined");
  g.confirmed = count(j, "confirmed");
  g.examined_off_inliers = count(j, "examined_off_inliers");
  g.confirmed_off_inliers = count(j, "confirmed_off_inliers");
  if (g.examined > g.predicted || g.confirmed > g.examined)
    throw_error(ErrorCode::kFormat, "guided confirmation: the counts do not nest (confirmed <= examined <= predicted)");
  if (g.examined_off_inliers > g.examined || g.confirmed_off_inliers > g.examined_off_inliers ||
      g.confirmed_off_inliers > g.confirmed ||
      g.confirmed - g.confirmed_off_inliers > g.examined - g.examined_off_inliers)
    throw_error(ErrorCode::kFormat,
                "guided confirmation: the off-inlier counts do not nest in the examined and confirmed ones");
  return g;
}

GuidedConfirmation GuidedConfirmer::measure(const GuidedConfirmationInput& in) {
  GuidedConfirmation out;
  VISLOC_CHECK(in.camera && in.descriptors && in.codebook, "guided confirmation: camera, descriptors and codebook");
  VISLOC_CHECK(in.descriptors->rows() == in.keypoints.size(), "one descriptor per keypoint");
  VISLOC_CHECK(in.max_examined > 0, "guided confirmation: max_examined must be positive");
  const PinholeCamera& camera = *in.camera;
  if (!(in.max_depth > 0) || !(in.focal > 0) || !std::isfinite(in.focal) || !(in.radius_px > 0) || in.xyz.size() < 3 ||
      camera.width <= 0 || camera.height <= 0 || !in.cam_from_segment.translation.allFinite() ||
      !in.cam_from_segment.rotation.coeffs().allFinite())
    return out;
  VISLOC_CHECK(in.codes != nullptr && !in.codebook->empty(), "guided confirmation: the points' codes");

  // The query's keypoints in a grid of cells at least radius_px wide
  // (compressed rows; at most ~1024 cells a side whatever the radius).
  const double cell = std::max(in.radius_px, std::max(camera.width, camera.height) / 1024.0);
  const int cols = static_cast<int>(std::ceil(camera.width / cell)) + 1;
  const int rows = static_cast<int>(std::ceil(camera.height / cell)) + 1;
  const size_t cells = size_t(cols) * size_t(rows);
  auto cell_of = [&](double x, double y) -> int64_t {
    const double gx = std::floor(x / cell), gy = std::floor(y / cell);
    if (!(gx >= 0 && gy >= 0 && gx < cols && gy < rows)) return -1;  // also NaN
    return int64_t(gy) * cols + int64_t(gx);
  };
  cell_start_.assign(cells + 1, 0);
  for (const Keypoint& k : in.keypoints) {
    const int64_t c = cell_of(k.x, k.y);
    if (c >= 0) ++cell_start_[size_t(c) + 1];
  }
  for (size_t c = 0; c < cells; ++c) cell_start_[c + 1] += cell_start_[c];
  cell_keypoints_.resize(cell_start_[cells]);
  // Filled back to front so that each cell's keypoints stay in index order.
  fill_.assign(cell_start_.begin() + 1, cell_start_.end());
  for (size_t i = in.keypoints.size(); i-- > 0;) {
    const int64_t c = cell_of(in.keypoints[i].x, in.keypoints[i].y);
    if (c >= 0) cell_keypoints_[--fill_[size_t(c)]] = {in.keypoints[i].x, in.keypoints[i].y, static_cast<uint32_t>(i)};
  }
  const Eigen::Matrix3d R = in.cam_from_segment.rotation_matrix();
  const Eigen::Vector3d& t = in.cam_from_segment.translation;
  // As the pose's solver sees the camera: calibrated, with fy = aspect · fx
  // and the radial distortion; with an estimated focal, square pixels and
  // no distortion (the keypoints are only centred).
  const double fx = in.focal, fy = in.focal * (camera.has_focal ? camera.aspect : 1.0);
  const double k1 = camera.has_focal ? camera.k1 : 0.0;
  // k1 < 0 folds the image back beyond r² = 1 / (3 |k1|): points past the
  // fold are not in view, whatever pixel the formula gives them.
  const double r2_fold = k1 < 0 ? 1.0 / (3.0 * -k1) : std::numeric_limits<double>::infinity();
  const double px = camera.cx + in.principal_point_offset.x(), py = camera.cy + in.principal_point_offset.y();
  // A point's pixel, if the pose predicts it in view.
  auto project = [&](size_t p, double& u, double& v) {
    const Eigen::Vector3d X = R * Eigen::Vector3d(in.xyz[3 * p], in.xyz[3 * p + 1], in.xyz[3 * p + 2]) + t;
    if (!(X.z() > 0) || X.z() > in.max_depth) return false;
    double x = X.x() / X.z(), y = X.y() / X.z();
    if (k1 != 0) {
      const double r2 = x * x + y * y;
      if (!(r2 < r2_fold)) return false;
      const double d = 1 + k1 * r2;
      x *= d;
      y *= d;
    }
    u = fx * x + px;
    v = fy * y + py;
    return u >= 0 && u < camera.width && v >= 0 && v < camera.height;
  };
  const size_t n = in.xyz.size() / 3;
  in_view_.clear();
  for (size_t p = 0; p < n; ++p) {
    double u, v;
    if (project(p, u, v)) in_view_.push_back({static_cast<uint32_t>(p), float(u), float(v)});
  }
  out.predicted = in_view_.size();
  // Every stride-th predicted point is looked for: at most max_examined.
  const size_t stride = std::max<size_t>(1, (out.predicted + in.max_examined - 1) / in.max_examined);
  const float d2_max = in.max_distance * in.max_distance;
  const double r2_max = in.radius_px * in.radius_px;
  const int code_bytes = in.codebook->code_bytes();
  decoded_.resize(kDescriptorDim);
  for (size_t i = 0; i < in_view_.size(); i += stride) {
    const size_t p = in_view_[i].point;
    const double u = in_view_[i].u, v = in_view_[i].v;
    ++out.examined;
    const int gx8 = std::clamp(static_cast<int>(u / camera.width * 8), 0, 7);
    const int gy8 = std::clamp(static_cast<int>(v / camera.height * 8), 0, 7);
    const bool off_inliers = ((in.inlier_cells >> (gy8 * 8 + gx8)) & 1) == 0;
    out.examined_off_inliers += off_inliers;
    // The keypoints within the radius, in the 3 × 3 cells around.
    const int cx = static_cast<int>(std::floor(u / cell)), cy = static_cast<int>(std::floor(v / cell));
    bool decoded = false, found = false;
    for (int gy = std::max(0, cy - 1); gy <= std::min(rows - 1, cy + 1) && !found; ++gy) {
      for (int gx = std::max(0, cx - 1); gx <= std::min(cols - 1, cx + 1) && !found; ++gx) {
        const size_t c = size_t(gy) * cols + gx;
        for (uint32_t k = cell_start_[c]; k < cell_start_[c + 1] && !found; ++k) {
          const CellKeypoint& q = cell_keypoints_[k];
          const double du = q.x - u, dv = q.y - v;
          if (du * du + dv * dv > r2_max) continue;
          if (!decoded) {
            in.codebook->decode(in.codes + p * size_t(code_bytes), decoded_.data());
            decoded = true;
          }
          found = squared_distance(in.descriptors->row(q.index), decoded_.data()) <= d2_max;
        }
      }
    }
    out.confirmed += found;
    out.confirmed_off_inliers += found && off_inliers;
  }
  return out;
}

}  // namespace visloc
