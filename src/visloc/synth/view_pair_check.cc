#include "visloc/synth/view_pair_check.h"

#include <cmath>
#include <iomanip>
#include <sstream>

#include "visloc/matching/exact_matcher.h"
#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc::synth {
namespace {

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Eigen::Matrix3d intrinsics(const PinholeCamera& c) {
  Eigen::Matrix3d K;
  K << c.focal, 0, c.cx, 0, c.focal, c.cy, 0, 0, 1;
  return K;
}

}  // namespace

void ViewPairCheckOptions::validate() const {
  if (!(ratio > 0 && ratio <= 1))
    throw_error(ErrorCode::kInvalidArgument, "pair check option ratio: must be in (0, 1], got ", ratio);
  if (!(reprojection_threshold_px > 0))
    throw_error(ErrorCode::kInvalidArgument, "pair check option reprojection_threshold_px: must be positive");
  if (!(epipolar_threshold_px > 0))
    throw_error(ErrorCode::kInvalidArgument, "pair check option epipolar_threshold_px: must be positive");
  if (!(depth_tolerance >= 0))
    throw_error(ErrorCode::kInvalidArgument, "pair check option depth_tolerance: must be >= 0");
}

void ViewPairCheck::add(const ViewPairCheck& o) {
  features_a += o.features_a;
  features_b += o.features_b;
  with_surface_a += o.with_surface_a;
  covisible_a += o.covisible_a;
  ratio_matches += o.ratio_matches;
  true_matches += o.true_matches;
  epipolar_inliers += o.epipolar_inliers;
}

double symmetric_epipolar_distance(const PinholeCamera& ca, const CameraPose& pa, const PinholeCamera& cb,
                                   const CameraPose& pb, const Eigen::Vector2d& xa, const Eigen::Vector2d& xb) {
  // b_from_a = pb * pa^-1; E = [t]x R; F = Kb^-T E Ka^-1.
  const CameraPose b_from_a = pb * pa.inverse();
  const Eigen::Matrix3d E = skew(b_from_a.translation) * b_from_a.rotation_matrix();
  const Eigen::Matrix3d F = intrinsics(cb).inverse().transpose() * E * intrinsics(ca).inverse();
  const Eigen::Vector3d ha = xa.homogeneous(), hb = xb.homogeneous();
  const Eigen::Vector3d lb = F * ha, la = F.transpose() * hb;
  const double e = hb.dot(lb);
  return 0.5 * (std::abs(e) / lb.head<2>().norm() + std::abs(e) / la.head<2>().norm());
}

ViewPairCheck check_view_pair(const ViewRenderer& renderer, const FeatureSet& fa, const PinholeCamera& ca,
                              const CameraPose& pa, const FeatureSet& fb, const PinholeCamera& cb,
                              const CameraPose& pb, const ViewPairCheckOptions& options) {
  options.validate();
  ViewPairCheck r;
  r.features_a = fa.size();
  r.features_b = fb.size();
  const Eigen::Vector3d center_a = pa.center(), center_b = pb.center();
  const Eigen::Matrix3d world_from_a = pa.rotation_matrix().transpose();
  // True 3D point and its projection in B for every keypoint of A.
  std::vector<Eigen::Vector2d> projected(fa.size());
  std::vector<uint8_t> covisible(fa.size(), 0);
  for (size_t i = 0; i < fa.size(); ++i) {
    const Eigen::Vector2d px(fa.keypoints[i].x, fa.keypoints[i].y);
    const Eigen::Vector3d d = (world_from_a * ca.ray(px)).normalized();
    const auto t = renderer.cast_ray(center_a, d);
    if (!t) continue;
    ++r.with_surface_a;
    const Eigen::Vector3d X = center_a + *t * d;
    const Eigen::Vector3d xb = pb.transform(X);
    if (xb.z() <= 1e-6) continue;
    projected[i] = cb.project(xb);
    if (!cb.contains(projected[i])) continue;
    const Eigen::Vector3d to = X - center_b;
    const double dist = to.norm();
    const auto tb = renderer.cast_ray(center_b, to / dist);
    if (!tb || std::abs(*tb - dist) > options.depth_tolerance * dist + 0.05) continue;
    covisible[i] = 1;
    ++r.covisible_a;
  }
  if (fa.size() == 0 || fb.size() < 2) return r;
  ExactMatcher matcher(fb.descriptors);
  ExactMatcherOptions mo;
  mo.ratio = options.ratio;
  for (const RatioMatch& m : matcher.match(fa.descriptors, mo)) {
    ++r.ratio_matches;
    const Eigen::Vector2d xa(fa.keypoints[m.query].x, fa.keypoints[m.query].y);
    const Eigen::Vector2d xb(fb.keypoints[m.database].x, fb.keypoints[m.database].y);
    if (symmetric_epipolar_distance(ca, pa, cb, pb, xa, xb) < options.epipolar_threshold_px) ++r.epipolar_inliers;
    if (covisible[m.query] && (projected[m.query] - xb).norm() < options.reprojection_threshold_px) ++r.true_matches;
  }
  return r;
}


AdjacentPairReport measure_adjacent_placemarks(const CityOptions& options, const std::filesystem::path& city_dir,
                                               int pairs, const SiftOptions& sift_options,
                                               const ViewPairCheckOptions& check) {
  options.validate();
  check.validate();
  if (pairs < 1) throw_error(ErrorCode::kInvalidArgument, "pair measurement option pairs: must be >= 1, got ", pairs);
  CityScene scene = generate_city_scene(options.layout);
  add_markers(options, scene);
  // Candidate k: placemarks k and k+1 on the same road.
  std::vector<size_t> starts;
  for (size_t k = 0; k + 1 < scene.placemarks.size(); ++k)
    if (scene.placemarks[k].road == scene.placemarks[k + 1].road) starts.push_back(k);
  if (starts.empty()) throw_error(ErrorCode::kInvalidArgument, city_dir.string(), ": no two adjacent placemarks");
  const size_t n = std::min(starts.size(), static_cast<size_t>(pairs));
  ViewRenderer renderer(scene, nullptr, options.render);
  SiftExtractor sift(sift_options);
  const PinholeCamera camera = camera_from_fov(options.views.width, options.views.height, options.views.fov_deg);
  const std::string ext = "." + options.image_format;
  AdjacentPairReport report;
  report.pairs = static_cast<int>(n);
  for (size_t p = 0; p < n; ++p) {
    const size_t k = starts[p * starts.size() / n];
    const Placemark& a = scene.placemarks[k];
    const Placemark& b = scene.placemarks[k + 1];
    for (int h = 0; h < options.views.headings; ++h) {
      const double heading = 360.0 * h / options.views.headings;
      const double rel = std::abs(std::sin((heading - a.road_heading_deg) * 3.14159265358979323846 / 180.0));
      for (size_t e = 0; e < options.views.elevations_deg.size(); ++e) {
        const std::string na = database_image_name(a.id, h, static_cast<int>(e)) + ext;
        const std::string nb = database_image_name(b.id, h, static_cast<int>(e)) + ext;
        Timer t;
        FeatureSet fa = sift.extract_file(city_dir / "images" / na);
        FeatureSet fb = sift.extract_file(city_dir / "images" / nb);
        report.sift_ms += t.elapsed_ms();
        const double elev = options.views.elevations_deg[e];
        const ViewPairCheck c = check_view_pair(renderer, fa, camera, street_view_pose(a.position, heading, elev), fb,
                                                camera, street_view_pose(b.position, heading, elev), check);
        (rel > std::sqrt(0.5) ? report.side : report.along).add(c);
        ++report.view_pairs;
      }
    }
  }
  return report;
}

namespace {

// Two lines: the counts, then the fractions; `label` left-aligned in 6 columns.
void write_check(std::ostream& out, const char* label, const ViewPairCheck& c) {
  out << "  " << std::left << std::setw(6) << label << std::right << " features A " << c.features_a << ", B "
      << c.features_b << "; A on a surface " << c.with_surface_a << ", covisible in B " << c.covisible_a
      << "; ratio matches " << c.ratio_matches << "; true (reprojection) " << c.true_matches << "; epipolar inliers "
      << c.epipolar_inliers << "\n";
  out << std::fixed << std::setprecision(3) << "         true / features A = " << c.true_fraction_of_features()
      << ", true / covisible A = " << c.true_fraction_of_covisible() << ", precision = " << c.precision()
      << ", epipolar precision = " << c.epipolar_precision() << "\n";
}

}  // namespace

std::string adjacent_pair_summary(const AdjacentPairReport& r) {
  std::ostringstream text;
  text << "adjacent placemarks: " << r.pairs << " pairs, " << r.view_pairs
       << " image pairs (same heading and elevation), SIFT " << std::fixed << std::setprecision(0) << r.sift_ms
       << " ms in total\n";
  write_check(text, "side", r.side);
  write_check(text, "along", r.along);
  write_check(text, "all", r.all());
  return text.str();
}

}  // namespace visloc::synth
