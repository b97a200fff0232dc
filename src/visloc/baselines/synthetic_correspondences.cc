#include "visloc/baselines/synthetic_correspondences.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include "visloc/util/random.h"
#include "visloc/util/error.h"

namespace visloc {

std::string_view to_string(SyntheticFamily family) {
  switch (family) {
    case SyntheticFamily::kCalibrated: return "calibrated";
    case SyntheticFamily::kUncalibrated: return "uncalibrated";
    case SyntheticFamily::kFacade: return "facade";
  }
  return "unknown";
}

SyntheticFamily parse_synthetic_family(std::string_view name) {
  if (name == "calibrated") return SyntheticFamily::kCalibrated;
  if (name == "uncalibrated") return SyntheticFamily::kUncalibrated;
  if (name == "facade") return SyntheticFamily::kFacade;
  throw_error(ErrorCode::kInvalidArgument, "unknown synthetic family '", name,
              "' (expected calibrated, uncalibrated or facade)");
}

void SyntheticOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "synthetic options: ", field, " ", rule, ", got ", value);
  };
  if (num_features == 0) bad("num_features", num_features, "must be positive");
  if (!(inlier_ratio >= 0 && inlier_ratio <= 1)) bad("inlier_ratio", inlier_ratio, "must be in [0, 1]");
  if (hypothesis_fraction > 1) bad("hypothesis_fraction", hypothesis_fraction, "must be <= 1 (< 0 = default)");
  if (max_candidates < 2 || max_candidates > 25) bad("max_candidates", max_candidates, "must be in [2, 25]");
  if (!(noise_px >= 0) || !std::isfinite(noise_px)) bad("noise_px", noise_px, "must be >= 0");
  if (width <= 0) bad("width", width, "must be positive");
  if (height <= 0) bad("height", height, "must be positive");
  if (!(focal_px > 0) || !std::isfinite(focal_px)) bad("focal_px", focal_px, "must be positive");
  if (!(scene_depth > 6) || !std::isfinite(scene_depth)) bad("scene_depth", scene_depth, "must be > 6 m");
}

namespace {

Eigen::Matrix3d random_rotation(RandomGenerator& rng) {
  Eigen::Quaterniond q(rng.normal(), rng.normal(), rng.normal(), rng.normal());
  return q.normalized().toRotationMatrix();
}

// Chooses `count` distinct indices of [0, n) (partial Fisher-Yates); returns a flag per index.
std::vector<uint8_t> choose_subset(size_t n, size_t count, RandomGenerator& rng) {
  std::vector<uint32_t> idx(n);
  for (size_t i = 0; i < n; ++i) idx[i] = static_cast<uint32_t>(i);
  std::vector<uint8_t> flag(n, 0);
  for (size_t i = 0; i < count && i < n; ++i) {
    const size_t j = i + rng.below(static_cast<uint32_t>(n - i));
    std::swap(idx[i], idx[j]);
    flag[idx[i]] = 1;
  }
  return flag;
}

struct Scene {
  CameraPose cam_from_world;
  Eigen::Matrix3d world_from_cam_R;
  Eigen::Vector3d center;
  double focal;
  int width, height;
  double cx, cy;

  Eigen::Vector2d random_pixel(RandomGenerator& rng) const {
    return {rng.uniform(0, width), rng.uniform(0, height)};
  }
  Eigen::Vector3d ray_world(const Eigen::Vector2d& px) const {
    return world_from_cam_R * Eigen::Vector3d((px.x() - cx) / focal, (px.y() - cy) / focal, 1.0);
  }
  // A point seen at a random pixel at camera depth z.
  Eigen::Vector3d point_at_depth(const Eigen::Vector2d& px, double z) const { return center + z * ray_world(px); }
  bool project(const Eigen::Vector3d& X, Eigen::Vector2d* px) const {
    const Eigen::Vector3d p = cam_from_world.transform(X);
    if (p.z() <= 0.1) return false;
    *px = Eigen::Vector2d(focal * p.x() / p.z() + cx, focal * p.y() / p.z() + cy);
    return px->x() >= 0 && px->y() >= 0 && px->x() <= width && px->y() <= height;
  }
};

// The camera: for a facade, in front of the plane z = 0 (world; x along the
// street, y down) at z < 0, yaw ±30°, pitch ±8°, aimed at a point of the
// facade from `scene_depth`; otherwise a random rotation and centre.
Scene place_camera(const SyntheticOptions& options, const SyntheticProblem& problem, RandomGenerator& rng) {
  const bool facade = options.family == SyntheticFamily::kFacade;
  const double D = options.scene_depth;
  Scene scene;
  scene.focal = problem.true_focal;
  scene.width = options.width;
  scene.height = options.height;
  scene.cx = problem.camera.cx;
  scene.cy = problem.camera.cy;
  if (facade) {
    const double yaw = rng.uniform(-30, 30) * std::numbers::pi / 180;
    const double pitch = rng.uniform(-8, 8) * std::numbers::pi / 180;
    const Eigen::Matrix3d Rwc = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
    const Eigen::Vector3d target(rng.uniform(-10, 10), rng.uniform(2, 10), 0);
    scene.world_from_cam_R = Rwc;
    scene.center = target - D * (Rwc * Eigen::Vector3d::UnitZ());
  } else {
    scene.world_from_cam_R = random_rotation(rng);
    scene.center = Eigen::Vector3d(rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-10, 10));
  }
  scene.cam_from_world = CameraPose::from_world_from_cam(scene.world_from_cam_R, scene.center);
  return scene;
}

// Facade grid: 3 m cells, 3.2 m floors, 16 elements per cell at the same
// offsets in every cell (window corners recessed, balcony points in front).
// The offsets are drawn for every family (so that the draws after them do
// not depend on the family).
class FacadeGrid {
 public:
  static constexpr int kElements = 16;

  explicit FacadeGrid(RandomGenerator& rng) {
    for (int e = 0; e < kElements; ++e) {
      const double z = e < 8 ? 0.2 : (e < 12 ? 0.0 : -0.8);
      element_[e] = Eigen::Vector3d(rng.uniform(0.2, kCellWidth - 0.2), rng.uniform(0.2, kCellHeight - 0.2), z);
    }
  }

  // Element e of cell (cx, cy).
  Eigen::Vector3d point(int cx, int cy, int e) const {
    return Eigen::Vector3d(cx * kCellWidth, cy * kCellHeight, 0) + element_[e];
  }

  // A grid site visible in the image: samples pixels until the facade point is inside.
  bool visible_site(const Scene& scene, RandomGenerator& rng, int* gx, int* gy, int* ge) const {
    for (int attempt = 0; attempt < 1000; ++attempt) {
      const Eigen::Vector2d px = scene.random_pixel(rng);
      const Eigen::Vector3d ray = scene.ray_world(px);
      if (ray.z() <= 1e-6) continue;
      const Eigen::Vector3d hit = scene.center + (-scene.center.z() / ray.z()) * ray;
      const int cx = static_cast<int>(std::floor(hit.x() / kCellWidth));
      const int cy = static_cast<int>(std::floor(hit.y() / kCellHeight));
      const int e = static_cast<int>(rng.below(kElements));
      Eigen::Vector2d p;
      if (scene.project(point(cx, cy, e), &p)) {
        *gx = cx, *gy = cy, *ge = e;
        return true;
      }
    }
    return false;
  }

 private:
  static constexpr double kCellWidth = 3.0, kCellHeight = 3.2;
  std::array<Eigen::Vector3d, kElements> element_;
};

// Which features are hypothesis features (a fraction h of n) and which are
// correct (inlier_ratio of each group, drawn separately); a flag per feature.
void choose_feature_roles(size_t n, double h, double inlier_ratio, RandomGenerator& rng, std::vector<uint8_t>* in_hyp,
                          std::vector<uint8_t>* correct) {
  const size_t nh = static_cast<size_t>(std::llround(h * static_cast<double>(n)));
  *in_hyp = choose_subset(n, nh, rng);
  std::vector<uint32_t> hyp_ids, other_ids;
  for (size_t i = 0; i < n; ++i) ((*in_hyp)[i] ? hyp_ids : other_ids).push_back(static_cast<uint32_t>(i));
  const auto hyp_correct = choose_subset(hyp_ids.size(),
                                         static_cast<size_t>(std::llround(inlier_ratio * hyp_ids.size())), rng);
  const auto other_correct = choose_subset(
      other_ids.size(), static_cast<size_t>(std::llround(inlier_ratio * other_ids.size())), rng);
  correct->assign(n, 0);
  for (size_t k = 0; k < hyp_ids.size(); ++k) (*correct)[hyp_ids[k]] = hyp_correct[k];
  for (size_t k = 0; k < other_ids.size(); ++k) (*correct)[other_ids[k]] = other_correct[k];
}

// Draws one feature at a time: its pixel and its candidate list.
struct FeatureSampler {
  const SyntheticOptions& options;
  const Scene& scene;
  const FacadeGrid& grid;
  RandomGenerator& rng;
  bool facade;
  double D;  // scene depth

  // Distinctive / generic scene point seen at a random pixel.
  Eigen::Vector3d random_scene_point(Eigen::Vector2d* px) {
    *px = scene.random_pixel(rng);
    if (!facade) return scene.point_at_depth(*px, rng.uniform(0.5 * D, 1.5 * D));
    const Eigen::Vector3d ray = scene.ray_world(*px);
    const double z_plane = rng.uniform(-5.0, 1.0);  // street furniture in front of the facade
    const double s = ray.z() > 1e-3 ? (z_plane - scene.center.z()) / ray.z() : 1.5 * D;
    return Eigen::Vector3d(scene.center + std::clamp(s, 0.3 * D, 3.0 * D) * ray);
  }

  Eigen::Vector2d noisy(const Eigen::Vector2d& px) {
    return Eigen::Vector2d(px.x() + options.noise_px * rng.normal(), px.y() + options.noise_px * rng.normal());
  }

  // A feature with independent scene points as candidates (a hypothesis
  // feature has one candidate or more, the others two or more); returns the
  // rank of the true candidate (0 for a correct hypothesis feature), -1 when
  // none is.
  int scene_point_feature(bool hyp, bool correct, Eigen::Vector2d* pixel, std::vector<Eigen::Vector3d>* list) {
    const size_t M = options.max_candidates;
    const size_t L = hyp ? 1 + rng.below(static_cast<uint32_t>(M)) : 2 + rng.below(static_cast<uint32_t>(M - 1));
    int true_rank = -1;
    if (correct) {
      Eigen::Vector2d px = Eigen::Vector2d::Zero();
      Eigen::Vector3d X = random_scene_point(&px);
      while (!scene.project(X, &px)) X = random_scene_point(&px);
      *pixel = noisy(px);
      true_rank = hyp ? 0 : static_cast<int>(rng.below(static_cast<uint32_t>(L)));
      for (size_t r = 0; r < L; ++r) {
        Eigen::Vector2d other_px;
        list->push_back(static_cast<int>(r) == true_rank ? X : random_scene_point(&other_px));
      }
    } else {
      *pixel = scene.random_pixel(rng);
      for (size_t r = 0; r < L; ++r) {
        Eigen::Vector2d other_px;
        list->push_back(random_scene_point(&other_px));
      }
    }
    return true_rank;
  }

  // Grid feature: the same element in L distinct cells around a site; the
  // true cell is never ranked first. Returns the true rank (1..L-1) or -1.
  int grid_feature(bool correct, Eigen::Vector2d* pixel, std::vector<Eigen::Vector3d>* list) {
    const size_t M = options.max_candidates;
    const size_t L = 2 + rng.below(static_cast<uint32_t>(M - 1));
    int gx = 0, gy = 0, ge = 0;
    if (!grid.visible_site(scene, rng, &gx, &gy, &ge))
      throw_error(ErrorCode::kInternal, "synthetic facade: no visible grid site (camera misses the facade)");
    int cells[25][2];  // L ≤ 25 distinct cells of the 5×5 neighbourhood
    int num_cells = 0;
    cells[num_cells][0] = gx, cells[num_cells][1] = gy, ++num_cells;
    while (static_cast<size_t>(num_cells) < L) {
      const int dx = static_cast<int>(rng.below(5)) - 2, dy = static_cast<int>(rng.below(5)) - 2;
      bool dup = false;
      for (int k = 0; k < num_cells; ++k) dup |= cells[k][0] == gx + dx && cells[k][1] == gy + dy;
      if (dup) continue;
      cells[num_cells][0] = gx + dx, cells[num_cells][1] = gy + dy, ++num_cells;
    }
    int true_rank = -1;
    if (correct) {
      Eigen::Vector2d px = Eigen::Vector2d::Zero();
      scene.project(grid.point(gx, gy, ge), &px);
      *pixel = noisy(px);
      true_rank = 1 + static_cast<int>(rng.below(static_cast<uint32_t>(L - 1)));  // rank 2..L
      std::swap(cells[0], cells[true_rank]);
      for (size_t r = 0; r < L; ++r) list->push_back(grid.point(cells[r][0], cells[r][1], ge));
    } else {
      *pixel = scene.random_pixel(rng);
      // All wrong: a uniform pixel, the element of cells around an unrelated visible site.
      for (size_t r = 0; r < L; ++r) list->push_back(grid.point(cells[r][0], cells[r][1], ge));
    }
    return true_rank;
  }
};

}  // namespace

SyntheticProblem make_synthetic_problem(const SyntheticOptions& options) {
  options.validate();
  RandomGenerator rng(options.seed * 0x9E3779B97F4A7C15ull + 17);
  const bool facade = options.family == SyntheticFamily::kFacade;
  const size_t n = options.num_features;
  const double h = options.hypothesis_fraction >= 0 ? options.hypothesis_fraction : (facade ? 0.3 : 0.5);
  const double D = options.scene_depth;

  SyntheticProblem out;
  out.scene_depth = D;
  out.true_focal = options.focal_px;
  if (options.family == SyntheticFamily::kUncalibrated) out.true_focal = options.focal_px * rng.uniform(0.7, 1.4);
  out.camera = PinholeCamera::centered(options.width, options.height);
  if (options.family != SyntheticFamily::kUncalibrated) {
    out.camera.focal = out.true_focal;
    out.camera.has_focal = true;
  }

  // The random draws, in this order: camera, grid offsets, feature roles, then feature by feature.
  const Scene scene = place_camera(options, out, rng);
  out.true_cam_from_world = scene.cam_from_world;
  const FacadeGrid grid(rng);
  std::vector<uint8_t> in_hyp, correct;
  choose_feature_roles(n, h, options.inlier_ratio, rng, &in_hyp, &correct);

  FeatureSampler sampler{options, scene, grid, rng, facade, D};
  out.true_candidate.assign(n, -1);
  std::vector<Eigen::Vector3d> list;
  for (size_t i = 0; i < n; ++i) {
    list.clear();
    Eigen::Vector2d pixel;
    const bool hyp = in_hyp[i] != 0;
    if (!facade || hyp) {
      out.true_candidate[i] = sampler.scene_point_feature(hyp, correct[i] != 0, &pixel, &list);
    } else {
      out.true_candidate[i] = sampler.grid_feature(correct[i] != 0, &pixel, &list);
    }
    out.correspondences.add_feature(pixel, list, hyp);
    if (out.true_candidate[i] >= 0) ++out.num_correct_features;
    if (hyp && out.true_candidate[i] == 0) ++out.num_correct_hypothesis_features;
  }
  return out;
}

}  // namespace visloc
