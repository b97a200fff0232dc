#include "visloc/pipeline/confidence.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <string_view>

#include "visloc/util/error.h"

namespace visloc {

namespace {
constexpr std::array<const char*, kConfidenceInputs> kNames = {
    "log_inliers",     "inlier_ratio",    "coverage",
    "residual",        "margin",          "vote_share",
    "camera_distance", "height_excess",   "tilt_excess_beyond_10deg",
    "log_explained",   "ambiguous_share", "elsewhere_share"};
constexpr std::array<int, kConfidenceInputs> kSigns = {+1, +1, +1, -1, -1, +1, -1, -1, -1, +1, -1, -1};

double number(const nlohmann::json& j, const char* key) {
  const auto it = j.find(key);
  if (it == j.end() || !it->is_number())
    throw_error(ErrorCode::kFormat, "confidence features: '", key, "' must be a number");
  const double v = it->get<double>();
  if (!std::isfinite(v)) throw_error(ErrorCode::kFormat, "confidence features: '", key, "' is not finite");
  return v;
}
}  // namespace

nlohmann::json ConfidenceFeatures::to_json() const {
  nlohmann::json j = {{"inliers", inliers},
                      {"inlier_ratio", inlier_ratio},
                      {"coverage", coverage},
                      {"residual", residual},
                      {"margin", margin},
                      {"vote_share", vote_share},
                      {"camera_distance", camera_distance},
                      {"height_excess", height_excess},
                      {"tilt_excess_deg", tilt_excess_deg},
                      {"explained", explained},
                      {"ambiguous", ambiguous},
                      {"elsewhere", elsewhere}};
  if (guided) j["guided"] = guided->to_json();
  return j;
}

ConfidenceFeatures ConfidenceFeatures::from_json(const nlohmann::json& j) {
  if (!j.is_object()) throw_error(ErrorCode::kFormat, "confidence features: expected an object");
  ConfidenceFeatures f;
  f.inliers = number(j, "inliers");
  f.inlier_ratio = number(j, "inlier_ratio");
  f.coverage = number(j, "coverage");
  f.residual = number(j, "residual");
  f.margin = number(j, "margin");
  f.vote_share = number(j, "vote_share");
  f.camera_distance = number(j, "camera_distance");
  f.height_excess = number(j, "height_excess");
  f.tilt_excess_deg = number(j, "tilt_excess_deg");
  // Reports written before the input existed lack it: they get the value
  // that neither raises nor lowers a confidence against a typical right pose.
  f.explained = j.contains("explained") ? number(j, "explained") : kExplainedWhenUnknown;
  f.ambiguous = j.contains("ambiguous") ? number(j, "ambiguous") : kAmbiguousWhenUnknown;
  f.elsewhere = j.contains("elsewhere") ? number(j, "elsewhere") : kElsewhereWhenUnknown;
  if (j.contains("guided")) f.guided = GuidedConfirmation::from_json(j["guided"]);
  return f;
}

std::array<double, kConfidenceInputs> confidence_inputs(const ConfidenceFeatures& f) {
  return {std::log(std::max(1.0, f.inliers)), std::clamp(f.inlier_ratio, 0.0, 1.0), std::clamp(f.coverage, 0.0, 1.0),
          std::clamp(f.residual, 0.0, 1.0), std::clamp(f.margin, 0.0, 1.0), std::clamp(f.vote_share, 0.0, 1.0),
          std::clamp(f.camera_distance, 0.0, 10.0), std::clamp(f.height_excess, 0.0, 10.0),
          // Phones tilt more than street-view rigs: 10° beyond the map's
          // cameras is tolerated, the rest counts (per 10°).
          std::clamp(f.tilt_excess_deg - 10.0, 0.0, 80.0) / 10.0, std::log(std::clamp(f.explained, 1e-3, 1.0)),
          std::clamp(f.ambiguous, 0.0, 1.0), std::clamp(f.elsewhere, 0.0, 1.0)};
}

static_assert(std::string_view(kNames[kExplainedInput]) == "log_explained");
static_assert(std::string_view(kNames[kAmbiguousInput]) == "ambiguous_share");
static_assert(std::string_view(kNames[kElsewhereInput]) == "elsewhere_share");

const std::array<const char*, kConfidenceInputs>& confidence_input_names() { return kNames; }
const std::array<int, kConfidenceInputs>& confidence_input_signs() { return kSigns; }

double ConfidenceModel::evaluate(const ConfidenceFeatures& f) const {
  const auto x = confidence_inputs(f);
  double z = bias;
  for (int k = 0; k < kConfidenceInputs; ++k) z += weights[k] * x[k];
  if (!std::isfinite(z)) return 0;
  return 1.0 / (1.0 + std::exp(-z));
}

nlohmann::json ConfidenceModel::to_json() const {
  nlohmann::json w = nlohmann::json::object();
  for (int k = 0; k < kConfidenceInputs; ++k) w[kNames[k]] = weights[k];
  return {{"bias", bias},
          {"weights", w},
          {"threshold", threshold},
          {"sigma_scale", sigma_scale},
          {"sigma_scale_with_point_uncertainty", sigma_scale_with_point_uncertainty}};
}

ConfidenceModel ConfidenceModel::from_json(const nlohmann::json& j) {
  if (!j.is_object() || !j.contains("weights") || !j["weights"].is_object())
    throw_error(ErrorCode::kFormat, "confidence model: expected {bias, weights: {...}, threshold}");
  ConfidenceModel m;
  m.bias = number(j, "bias");
  m.threshold = number(j, "threshold");
  if (m.threshold < 0 || m.threshold > 1)
    throw_error(ErrorCode::kFormat, "confidence model: threshold must be in [0, 1], got ", m.threshold);
  if (j.contains("sigma_scale")) {  // a model written before it: 1
    m.sigma_scale = number(j, "sigma_scale");
    if (!(m.sigma_scale > 0) || !std::isfinite(m.sigma_scale))
      throw_error(ErrorCode::kFormat, "confidence model: sigma_scale must be a positive number, got ", m.sigma_scale);
  }
  m.sigma_scale_with_point_uncertainty = 1;  // a model written before it: unscaled, as the builtin one
  if (j.contains("sigma_scale_with_point_uncertainty")) {
    m.sigma_scale_with_point_uncertainty = number(j, "sigma_scale_with_point_uncertainty");
    if (!(m.sigma_scale_with_point_uncertainty > 0))
      throw_error(ErrorCode::kFormat,
                  "confidence model: sigma_scale_with_point_uncertainty must be a positive number, got ",
                  m.sigma_scale_with_point_uncertainty);
  }
  for (int k = 0; k < kConfidenceInputs; ++k) {
    // A model written before log_explained, ambiguous_share or
    // elsewhere_share existed did not weigh it.
    if ((k == kExplainedInput || k == kAmbiguousInput || k == kElsewhereInput) && !j["weights"].contains(kNames[k]))
      continue;
    m.weights[k] = number(j["weights"], kNames[k]);
  }
  return m;
}

MapCameraRange::MapCameraRange(const std::vector<SegmentImage>& images, const std::optional<Eigen::Vector3d>& up) {
  std::vector<Eigen::Vector3d> centers, ups, views;
  for (const SegmentImage& im : images) {
    const auto& q = im.cam_from_world_q_wxyz;
    const Eigen::Quaterniond rot(q[0], q[1], q[2], q[3]);
    if (!(rot.norm() > 0.5)) continue;
    const Eigen::Matrix3d R = rot.normalized().toRotationMatrix();
    const Eigen::Vector3d t(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]);
    const Eigen::Vector3d c = -R.transpose() * t;
    if (!c.allFinite()) continue;
    centers.push_back(c);
    ups.push_back(-R.row(1).transpose());  // image y points down
    views.push_back(R.row(2).transpose());
  }
  if (centers.size() < 2) return;
  Eigen::Vector3d u = Eigen::Vector3d::Zero();
  if (up && up->allFinite() && up->norm() > 0) {
    u = up->normalized();
  } else {
    for (const auto& a : ups) u += a;
    if (!(u.norm() > 1e-9)) return;
    u.normalize();
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& c : centers) mean += c;
  mean /= static_cast<double>(centers.size());
  double extent = 0;
  for (const auto& c : centers) extent = std::max(extent, (c - mean).norm());
  if (!(extent > 0) || !std::isfinite(extent)) return;
  up_ = u;
  extent_ = extent;
  height_min_ = INFINITY;
  height_max_ = -INFINITY;
  for (size_t i = 0; i < centers.size(); ++i) {
    const double h = u.dot(centers[i]);
    height_min_ = std::min(height_min_, h);
    height_max_ = std::max(height_max_, h);
    const double tilt = std::asin(std::clamp(u.dot(views[i]), -1.0, 1.0)) * 180.0 / std::numbers::pi;
    max_abs_tilt_deg_ = std::max(max_abs_tilt_deg_, std::abs(tilt));
  }
  centers_ = std::move(centers);
}

void MapCameraRange::assess(const CameraPose& pose, ConfidenceFeatures* f) const {
  if (!valid()) return;
  const Eigen::Vector3d c = pose.center();
  if (!c.allFinite()) {
    f->camera_distance = f->height_excess = 10;
    f->tilt_excess_deg = 90;
    return;
  }
  double nearest = INFINITY;
  for (const auto& m : centers_) nearest = std::min(nearest, (c - m).norm());
  f->camera_distance = nearest / extent_;
  const double h = up_.dot(c);
  f->height_excess = std::max({0.0, h - height_max_, height_min_ - h}) / extent_;
  const double tilt =
      std::asin(std::clamp(up_.dot(pose.viewing_direction()), -1.0, 1.0)) * 180.0 / std::numbers::pi;
  f->tilt_excess_deg = std::max(0.0, std::abs(tilt) - max_abs_tilt_deg_);
}

void UnderStreetOptions::validate() const {
  const auto check = [](bool ok, const char* field, double value) {
    if (!ok) throw_error(ErrorCode::kInvalidArgument, "under_street.", field, " out of range: ", value);
  };
  check(max_drop_m >= 0 && std::isfinite(max_drop_m), "max_drop_m", max_drop_m);
  check(max_slope >= 0 && std::isfinite(max_slope), "max_slope", max_slope);
  check(max_below_ground_m >= 0 && std::isfinite(max_below_ground_m), "max_below_ground_m", max_below_ground_m);
  check(ground_radius_m > 0 && std::isfinite(ground_radius_m), "ground_radius_m", ground_radius_m);
  check(ground_quantile >= 0 && ground_quantile <= 1, "ground_quantile", ground_quantile);
}

UnderStreetAssessment assess_under_street(const CameraPose& cam_from_segment, const std::vector<SegmentImage>& images,
                                          std::span<const float> xyz, const Similarity3d& enu_from_segment,
                                          const UnderStreetOptions& options, std::vector<float>& heights,
                                          bool measure_ground) {
  UnderStreetAssessment a;
  const Eigen::Vector3d c = cam_from_segment.center();
  const double scale = enu_from_segment.scale;
  if (!c.allFinite() || !(scale > 0) || !std::isfinite(scale)) return a;
  // The ENU up in the segment frame; metres = segment units × scale.
  const Eigen::Vector3d up = enu_from_segment.rotation.transpose() * Eigen::Vector3d::UnitZ();
  const auto plan_distance_m = [&](const Eigen::Vector3d& d) { return (d - up.dot(d) * up).norm() * scale; };
  double nearest = INFINITY;
  for (const SegmentImage& im : images) {
    const auto& q = im.cam_from_world_q_wxyz;
    const Eigen::Quaterniond rot(q[0], q[1], q[2], q[3]);
    if (!(rot.norm() > 0.5)) continue;
    const Eigen::Vector3d t(im.cam_from_world_t[0], im.cam_from_world_t[1], im.cam_from_world_t[2]);
    const Eigen::Vector3d m = -(rot.normalized().toRotationMatrix().transpose() * t);
    if (!m.allFinite()) continue;
    const double d = plan_distance_m(c - m);
    if (d < nearest) {
      nearest = d;
      a.camera_plan_distance_m = d;
      a.drop_below_camera_m = up.dot(m - c) * scale;
    }
  }
  if (!std::isfinite(nearest)) return a;
  a.assessed = true;
  a.below_camera_bound = a.drop_below_camera_m > options.max_drop_m + options.max_slope * a.camera_plan_distance_m;
  if (!a.below_camera_bound && !measure_ground) return a;
  heights.clear();
  const double radius_sq = options.ground_radius_m * options.ground_radius_m;
  for (size_t i = 0; i + 2 < xyz.size(); i += 3) {
    const Eigen::Vector3d d = Eigen::Vector3d(xyz[i], xyz[i + 1], xyz[i + 2]) - c;
    const double plan = plan_distance_m(d);
    if (plan * plan <= radius_sq && std::isfinite(plan)) heights.push_back(static_cast<float>(up.dot(d) * scale));
  }
  if (heights.empty()) return a;
  const size_t k = std::min(heights.size() - 1, static_cast<size_t>(options.ground_quantile * double(heights.size())));
  std::nth_element(heights.begin(), heights.begin() + static_cast<std::ptrdiff_t>(k), heights.end());
  a.above_ground_m = -double(heights[k]);  // the ground's height relative to the camera, negated
  a.under_street = a.below_camera_bound && *a.above_ground_m < -options.max_below_ground_m;
  return a;
}

const double kDefaultMinConfidence = 0.66897996067596854;

double explained_fraction(std::span<const float> xyz, const CameraPose& cam_from_segment, const PinholeCamera& camera,
                          double focal, const Eigen::Vector2d& principal_point_offset, double max_depth,
                          size_t inliers) {
  if (!(max_depth > 0) || !(focal > 0)) return 0;
  const Eigen::Matrix3d R = cam_from_segment.rotation_matrix();
  const Eigen::Vector3d& t = cam_from_segment.translation;
  // Image bounds in coordinates centred on the assumed principal point, as
  // the pose's projection gives them.
  const double u_min = -camera.cx - principal_point_offset.x(),
               u_max = camera.width - camera.cx - principal_point_offset.x();
  const double v_min = -camera.cy - principal_point_offset.y(),
               v_max = camera.height - camera.cy - principal_point_offset.y();
  size_t in_view = 0;
  for (size_t i = 0; i + 2 < xyz.size(); i += 3) {
    const Eigen::Vector3d X = R * Eigen::Vector3d(xyz[i], xyz[i + 1], xyz[i + 2]) + t;
    if (!(X.z() > 0) || X.z() > max_depth) continue;
    const double u = focal * X.x() / X.z(), v = focal * camera.aspect * X.y() / X.z();
    in_view += u >= u_min && u < u_max && v >= v_min && v < v_max;
  }
  if (in_view == 0) return 0;
  return std::min(1.0, static_cast<double>(inliers) / static_cast<double>(in_view));
}

double ambiguous_inlier_share(std::span<const uint32_t> candidate_offsets, std::span<const Eigen::Vector3d> candidates,
                              std::span<const float> distances, std::span<const int32_t> chosen, double min_separation,
                              double ratio) {
  VISLOC_CHECK(!candidate_offsets.empty() && chosen.size() + 1 == candidate_offsets.size() &&
               candidate_offsets.back() == candidates.size() && distances.size() == candidates.size());
  VISLOC_CHECK(ratio > 0 && min_separation >= 0);
  const double min_separation_sq = min_separation * min_separation;
  size_t inliers = 0, ambiguous = 0;
  for (size_t i = 0; i < chosen.size(); ++i) {
    if (chosen[i] < 0) continue;
    const uint32_t begin = candidate_offsets[i], end = candidate_offsets[i + 1];
    const uint32_t c = begin + static_cast<uint32_t>(chosen[i]);
    VISLOC_CHECK(c < end, "chosen candidate out of its feature's list");
    ++inliers;
    const double bound = double(distances[c]) / ratio;
    for (uint32_t k = begin; k < end; ++k) {
      if (k == c || !(double(distances[k]) <= bound)) continue;
      if ((candidates[k] - candidates[c]).squaredNorm() > min_separation_sq) {
        ++ambiguous;
        break;
      }
    }
  }
  return inliers ? double(ambiguous) / double(inliers) : 0.0;
}

std::optional<double> elsewhere_inlier_share(const SegmentPointVoteResult& votes,
                                             std::span<const uint32_t> query_feature, std::span<const int32_t> chosen,
                                             uint32_t segment, std::span<const uint32_t> related) {
  VISLOC_CHECK(query_feature.size() == chosen.size());
  VISLOC_CHECK(!votes.feature_offsets.empty() && votes.feature_offsets.back() == votes.feature_segments.size());
  const size_t features = votes.feature_offsets.size() - 1;
  size_t voted = 0, elsewhere = 0;
  for (size_t i = 0; i < chosen.size(); ++i) {
    if (chosen[i] < 0) continue;
    VISLOC_CHECK(query_feature[i] < features, "query feature out of the votes' range");
    const std::span<const uint32_t> nearest = votes.segments_of_feature(query_feature[i]);
    if (nearest.empty()) continue;
    ++voted;
    const bool here = std::any_of(nearest.begin(), nearest.end(), [&](uint32_t s) {
      return s == segment || std::find(related.begin(), related.end(), s) != related.end();
    });
    elsewhere += !here;
  }
  if (voted == 0) return std::nullopt;
  return double(elsewhere) / double(voted);
}

const ConfidenceModel& ConfidenceModel::builtin() {
  static const ConfidenceModel model = [] {
    ConfidenceModel m;
    // Fitted by `visloc bench confidence --fit --reports T5/report.json
    // T7/report.json T11/report.json` on three synthetic cities that no
    // evaluation uses, each with the last 60 m of every mapped road left out
    // so that some queries stand past a mapped street's end (the KITTI hard
    // split's failure):
    //   `visloc bench city --out T5 --seed 7 --layout random --random-roads 5
    //   --road-length 180 --leave-out-roads 2 --leave-out-road-end 60
    //   --queries 500 --negatives 0 --min-confidence 0`,
    //   T7 the same with --random-roads 8, T11 with --seed 11 --random-roads 8
    // (4, 8 and 8 segments; 1,498 poses: 958 right, 540 wrong; 958 with
    // >= 12 inliers: 930 right, 28 wrong). L2 penalty 0.01 by 5-fold
    // cross-validation; dropped (its weight came out with the wrong sign):
    // camera_distance. Threshold: precision >= 99.5% on the poses with >= 12
    // inliers (918 right kept, 12 right lost, 4 wrong kept). sigma_scale: the
    // 68th percentile of error / σ over those 918 right poses.
    m.bias = 11.088367353308479;
    m.weights[0] = 0.81205842313418641;  // log_inliers
    m.weights[1] = 0.50922511899925837;  // inlier_ratio
    m.weights[2] = 8.0122029780741073;   // coverage
    m.weights[3] = -6.7419156220250951;  // residual
    m.weights[4] = -9.7471176880699897;  // margin
    m.weights[5] = 0.22627003626770067;  // vote_share
    m.weights[6] = 0;  // camera_distance
    m.weights[7] = -18.571942447523945;  // height_excess
    m.weights[8] = -4.0486852615759856;  // tilt_excess_beyond_10deg
    m.weights[9] = 0.84207998546062945;  // log_explained
    m.weights[10] = 0;                   // ambiguous_share (reported, not yet fitted)
    m.weights[11] = 0;                   // elsewhere_share (reported, not yet fitted)
    m.sigma_scale = 1.4366960119136487;
    // Not fitted: the first-order covariance with the map points' uncertainty
    // as it is. Fitted on T5 re-localized with it (`visloc bench confidence
    // --fit-sigma --reports T5/report.json`, session 39) it would be 0.60,
    // while the KITTI maps' errors need about 1.4 (68th percentile of error /
    // σ: 1.39 on the odd frames, 2.16 on the hard split): the synthetic
    // cities' points come out better than their triangulation covariance says,
    // KITTI's worse, and no one factor serves both. At 1: KITTI odd 44% / 80%
    // of errors within 1σ / 2σ (44% / 79% without the points' uncertainty at
    // sigma_scale), the hard split 10% / 50% (0% / 3%), T5 90% / 100%.
    m.sigma_scale_with_point_uncertainty = 1;
    m.threshold = kDefaultMinConfidence;
    return m;
  }();
  return model;
}

}  // namespace visloc
