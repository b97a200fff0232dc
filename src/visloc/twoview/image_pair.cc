#include "visloc/twoview/image_pair.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/matching/exact_matcher.h"
#include "visloc/pose/solvers/two_view.h"
#include "visloc/util/error.h"

namespace visloc {

void PairMatchingOptions::validate() const {
  auto bad = [](const char* field, const auto& value, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "pair matching option ", field, " = ", value, ": ", rule);
  };
  if (!(ratio_one_to_one > 0 && ratio_one_to_one <= 1)) bad("ratio_one_to_one", ratio_one_to_one, "must be in (0, 1]");
  if (!(ratio_one_to_many >= ratio_one_to_one && ratio_one_to_many <= 1))
    bad("ratio_one_to_many", ratio_one_to_many, "must be in [ratio_one_to_one, 1]");
  if (max_candidates < 1 || max_candidates > 64) bad("max_candidates", max_candidates, "must be in [1, 64]");
}

void ImagePairOptions::validate() const {
  sift.validate();
  matching.validate();
  estimation.validate();
}

TwoViewCorrespondences match_feature_sets(const FeatureSet& a, const FeatureSet& b, const PairMatchingOptions& o) {
  o.validate();
  a.check_consistent();
  b.check_consistent();
  TwoViewCorrespondences m;
  if (a.size() == 0 || b.size() < 2) return m;
  const ExactMatcher matcher(b.descriptors);
  const int k = o.max_candidates + 1;
  std::vector<int64_t> index;
  std::vector<float> sqdist;
  matcher.knn(a.descriptors, k, index, sqdist);
  for (size_t i = 0; i < a.size(); ++i) {
    const int64_t* idx = index.data() + i * k;
    const float* d2 = sqdist.data() + i * k;
    if (idx[0] < 0 || idx[1] < 0) continue;
    const double d0 = std::sqrt(std::max(0.0f, d2[0])), d1 = std::sqrt(std::max(0.0f, d2[1]));
    const bool one_to_one = d0 < o.ratio_one_to_one * d1;
    int keep = 0;
    if (o.rule == OneToManyRule::kBestRatio) {
      keep = d0 < o.ratio_one_to_many * d1 ? o.max_candidates : 0;
    } else {
      // The candidates before the first j ≥ 1 clearly worse than the best
      // (a missing candidate counts as infinitely far); a group of more than
      // M near-equal candidates finds no such j ≤ M and is dropped.
      for (int j = 1; j < k; ++j) {
        if (idx[j] < 0 || d0 < o.ratio_one_to_many * std::sqrt(std::max(0.0f, d2[j]))) {
          keep = j;
          break;
        }
      }
    }
    if (one_to_one) keep = std::max(keep, 1);
    if (keep == 0) continue;
    m.points1.emplace_back(a.keypoints[i].x, a.keypoints[i].y);
    m.feature1.push_back(static_cast<uint32_t>(i));
    m.in_hypothesis_set.push_back(one_to_one ? 1 : 0);
    for (int j = 0; j < keep && j < k && idx[j] >= 0; ++j) {
      const Keypoint& kp = b.keypoints[static_cast<size_t>(idx[j])];
      m.candidates.emplace_back(kp.x, kp.y);
      m.candidate_feature2.push_back(static_cast<uint32_t>(idx[j]));
    }
    m.candidate_offsets.push_back(static_cast<uint32_t>(m.candidates.size()));
  }
  return m;
}

size_t ImagePairResult::one_to_one_matches() const {
  return static_cast<size_t>(std::count(matches.in_hypothesis_set.begin(), matches.in_hypothesis_set.end(), 1));
}

nlohmann::json ImagePairResult::to_json() const {
  auto matrix = [](const Eigen::Matrix3d& M) {
    nlohmann::json rows = nlohmann::json::array();
    for (int r = 0; r < 3; ++r) rows.push_back({M(r, 0), M(r, 1), M(r, 2)});
    return rows;
  };
  nlohmann::json j = {{"image1", features1.image},
                      {"image2", features2.image},
                      {"features1", features1.size()},
                      {"features2", features2.size()},
                      {"one_to_one_matches", one_to_one_matches()},
                      {"one_to_many_features", matches.size()},
                      {"one_to_many_candidates", matches.candidates.size()},
                      {"model", std::string(to_string(estimate.model))},
                      {"found", estimate.found},
                      {"inliers", estimate.inliers},
                      {"one_to_one_inliers", estimate.one_to_one_inliers},
                      {"extra_one_to_many_inliers", estimate.extra_inliers},
                      {"ransac",
                       {{"iterations", estimate.stats.iterations},
                        {"models", estimate.stats.models},
                        {"rejected_by_sprt", estimate.stats.models_rejected_sprt},
                        {"verified", estimate.stats.models_verified},
                        {"hypothesis_ms", estimate.stats.hypothesis_ms},
                        {"verification_ms", estimate.stats.verification_ms}}},
                      {"times_ms",
                       {{"features", ms_features}, {"matching", ms_matching}, {"ransac", estimate.total_ms}}}};
  if (estimate.found) {
    j["matrix"] = matrix(estimate.matrix);
    if (estimate.model != TwoViewModel::kHomography) j["fundamental"] = matrix(estimate.fundamental);
  }
  return j;
}

void PairVerificationOptions::validate() const {
  matching.validate();
  estimation.validate();
  if (estimation.model == TwoViewModel::kHomography)  // a COLMAP two-view geometry of ours holds F (and E)
    throw_error(ErrorCode::kInvalidArgument, "pair verification: the model must be F or E, not H");
  if (min_inliers < 8)  // below the 7-point sample, a model fits any pair
    throw_error(ErrorCode::kInvalidArgument, "pair verification: min_inliers must be at least 8, got ", min_inliers);
  if (!(min_inlier_ratio >= 0 && min_inlier_ratio <= 1))
    throw_error(ErrorCode::kInvalidArgument, "pair verification: min_inlier_ratio must be in [0, 1], got ",
                min_inlier_ratio);
}

namespace {

// The model's inliers, one per feature of image 2 (COLMAP's matches are
// 1-1; a track must not see one image twice): when several features of
// image 1 chose the same feature of image 2, the 1-1 inlier wins, else the
// lowest Sampson error.
std::vector<std::pair<uint32_t, uint32_t>> unique_inliers(const TwoViewCorrespondences& m, const TwoViewEstimate& e) {
  struct Claim {
    uint32_t feature1 = 0, feature2 = 0;
    bool one_to_one = false;
    double error2 = 0;
  };
  std::vector<Claim> claims;
  claims.reserve(e.inliers);
  for (size_t i = 0; i < m.size(); ++i) {
    const int32_t chosen = e.chosen_candidate[i];
    if (chosen < 0) continue;
    const size_t c = m.candidate_offsets[i] + static_cast<size_t>(chosen);
    claims.push_back({m.feature1[i], m.candidate_feature2[c], e.one_to_one_inlier[i] != 0,
                      sampson_error2(e.fundamental, m.points1[i], m.candidates[c])});
  }
  std::sort(claims.begin(), claims.end(), [](const Claim& x, const Claim& y) {
    if (x.feature2 != y.feature2) return x.feature2 < y.feature2;
    if (x.one_to_one != y.one_to_one) return x.one_to_one;
    return x.error2 < y.error2 || (x.error2 == y.error2 && x.feature1 < y.feature1);
  });
  std::vector<std::pair<uint32_t, uint32_t>> inliers;
  for (size_t k = 0; k < claims.size(); ++k)
    if (k == 0 || claims[k].feature2 != claims[k - 1].feature2)
      inliers.emplace_back(claims[k].feature1, claims[k].feature2);
  std::sort(inliers.begin(), inliers.end());
  return inliers;
}

}  // namespace

VerifiedPair verify_image_pair(const FeatureSet& a, const FeatureSet& b, const PairVerificationOptions& options) {
  options.validate();
  VerifiedPair v;
  const TwoViewCorrespondences m = match_feature_sets(a, b, options.matching);
  v.matches.reserve(m.size());
  for (size_t i = 0; i < m.size(); ++i)
    v.matches.emplace_back(m.feature1[i], m.candidate_feature2[m.candidate_offsets[i]]);
  v.estimate = estimate_two_view(m, options.estimation);
  // The pair is verified by its 1-1 matches, as COLMAP's (min_num_inliers,
  // min_inlier_ratio): with up to M candidates per feature in a 4 px band, a
  // wrong model gathers 1-M inliers by chance, even between views that do
  // not overlap. The 1-M set then adds inliers to a verified pair only.
  const size_t one_to_one_matches =
      static_cast<size_t>(std::count(m.in_hypothesis_set.begin(), m.in_hypothesis_set.end(), uint8_t{1}));
  if (!v.estimate.found || v.estimate.one_to_one_inliers < options.min_inliers ||
      static_cast<double>(v.estimate.one_to_one_inliers) <
          options.min_inlier_ratio * static_cast<double>(one_to_one_matches))
    return v;
  v.inliers = unique_inliers(m, v.estimate);
  v.verified = true;
  return v;
}

ImagePairResult match_image_pair(const std::filesystem::path& image1, const std::filesystem::path& image2,
                                 const ImagePairOptions& options) {
  options.validate();
  ImagePairResult r;
  const auto t0 = std::chrono::steady_clock::now();
  const SiftExtractor sift(options.sift);
  r.features1 = sift.extract_file(image1);
  r.features2 = sift.extract_file(image2);
  const auto t1 = std::chrono::steady_clock::now();
  r.matches = match_feature_sets(r.features1, r.features2, options.matching);
  const auto t2 = std::chrono::steady_clock::now();
  r.estimate = estimate_two_view(r.matches, options.estimation);
  r.ms_features = std::chrono::duration<double, std::milli>(t1 - t0).count();
  r.ms_matching = std::chrono::duration<double, std::milli>(t2 - t1).count();
  return r;
}

void draw_pair_inliers(const std::filesystem::path& image1, const std::filesystem::path& image2,
                       const ImagePairResult& result, const std::filesystem::path& out, int max_height) {
  if (max_height < 16) throw_error(ErrorCode::kInvalidArgument, "draw_pair_inliers: max_height must be at least 16");
  const GrayImage a = read_gray_image(image1), b = read_gray_image(image2);
  const double sa = std::min(1.0, static_cast<double>(max_height) / a.height);
  const double sb = std::min(1.0, static_cast<double>(max_height) / b.height);
  cv::Mat ga(a.height, a.width, CV_8UC1, const_cast<uint8_t*>(a.pixels.data()));
  cv::Mat gb(b.height, b.width, CV_8UC1, const_cast<uint8_t*>(b.pixels.data()));
  cv::Mat ra, rb;
  cv::resize(ga, ra, cv::Size(), sa, sa, cv::INTER_AREA);
  cv::resize(gb, rb, cv::Size(), sb, sb, cv::INTER_AREA);
  const int height = std::max(ra.rows, rb.rows);
  cv::Mat canvas(height, ra.cols + rb.cols, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::cvtColor(ra, canvas(cv::Rect(0, 0, ra.cols, ra.rows)), cv::COLOR_GRAY2BGR);
  cv::cvtColor(rb, canvas(cv::Rect(ra.cols, 0, rb.cols, rb.rows)), cv::COLOR_GRAY2BGR);
  const TwoViewCorrespondences& m = result.matches;
  const auto& chosen = result.estimate.chosen_candidate;
  // Every inlier as a dot; lines for at most kMaxLines of each kind (evenly
  // spaced), so that the picture stays readable. 1-1 first, the extra 1-M
  // inliers over them.
  constexpr size_t kMaxLines = 120;
  size_t count[2] = {0, 0};
  for (size_t i = 0; i < m.size() && i < chosen.size(); ++i)
    if (chosen[i] >= 0) ++count[result.estimate.one_to_one_inlier[i] ? 0 : 1];
  size_t seen[2] = {0, 0};
  for (int pass = 0; pass < 2; ++pass)
    for (size_t i = 0; i < m.size() && i < chosen.size(); ++i) {
      if (chosen[i] < 0) continue;
      const bool one_to_one = result.estimate.one_to_one_inlier[i] != 0;
      if (one_to_one != (pass == 0)) continue;
      const int kind = one_to_one ? 0 : 1;
      const size_t stride = std::max<size_t>(1, count[kind] / kMaxLines);
      const bool draw_line = seen[kind]++ % stride == 0;
      const Eigen::Vector2d& p = m.points1[i];
      // A 1-1 inlier is drawn with its 1-1 match; an extra one with the candidate chosen.
      const uint32_t candidate = one_to_one ? 0u : static_cast<uint32_t>(chosen[i]);
      const Eigen::Vector2d& q = m.candidates[m.candidate_offsets[i] + candidate];
      const cv::Point pa(static_cast<int>(p.x() * sa), static_cast<int>(p.y() * sa));
      const cv::Point pb(static_cast<int>(q.x() * sb) + ra.cols, static_cast<int>(q.y() * sb));
      const cv::Scalar colour = one_to_one ? cv::Scalar(60, 200, 60) : cv::Scalar(0, 140, 255);  // BGR
      if (draw_line) cv::line(canvas, pa, pb, colour, 1, cv::LINE_AA);
      cv::circle(canvas, pa, 2, colour, cv::FILLED, cv::LINE_AA);
      cv::circle(canvas, pb, 2, colour, cv::FILLED, cv::LINE_AA);
    }
  const std::string legend = "green: 1-1 inliers (" + std::to_string(result.estimate.one_to_one_inliers) +
                             "), orange: extra 1-M inliers (" + std::to_string(result.estimate.extra_inliers) + ")";
  cv::putText(canvas, legend, {10, 24}, cv::FONT_HERSHEY_SIMPLEX, 0.7, {0, 0, 0}, 4, cv::LINE_AA);
  cv::putText(canvas, legend, {10, 24}, cv::FONT_HERSHEY_SIMPLEX, 0.7, {255, 255, 255}, 1, cv::LINE_AA);
  cv::Mat rgb;
  cv::cvtColor(canvas, rgb, cv::COLOR_BGR2RGB);
  write_image(out, rgb.cols, rgb.rows, 3, rgb.data);
}

namespace {

// The camera of `image` in an intrinsics list: its own line, else the '*' line; checked against the image.
PinholeCamera listed_camera(const CamerasByName& list, const std::filesystem::path& list_file,
                            const std::filesystem::path& image) {
  const std::string name = image.filename().string();
  const PinholeCamera* camera = find_listed_camera(list, name);
  if (!camera) throw_error(ErrorCode::kInvalidArgument, list_file.string(), ": no line for ", name, " (nor '*')");
  const ImageMetadata m = read_image_metadata(image);
  if (camera->width != m.width || camera->height != m.height)
    throw_error(ErrorCode::kInvalidArgument, list_file.string(), ": the line for ", name, " is for ", camera->width,
                "x", camera->height, " pixels, the image has ", m.width, "x", m.height);
  if (!camera->has_focal)
    throw_error(ErrorCode::kInvalidArgument, list_file.string(), ": the line for ", name, " has no focal length");
  return *camera;
}

// RANSAC variants as --ransac names them.
const char* ransac_option_name(RansacVariant variant) {
  switch (variant) {
    case RansacVariant::kClassic11:
      return "classic";
    case RansacVariant::kOneManyFixed:
      return "1m";
    case RansacVariant::kOneManySprt:
      return "1m-sprt";
  }
  return "?";
}

}  // namespace

ImagePairOptions resolve_image_pair_options(const ImagePairTask& task) {
  ImagePairOptions o = task.options;
  if (task.focal > 0 && !task.intrinsics.empty())
    throw_error(ErrorCode::kInvalidArgument, "match: give --focal or --intrinsics, not both");
  const std::filesystem::path images[2] = {task.image1, task.image2};
  std::optional<PinholeCamera> cameras[2];
  if (!task.intrinsics.empty()) {
    const CamerasByName list = read_intrinsics_by_name(task.intrinsics);
    for (int k = 0; k < 2; ++k) cameras[k] = listed_camera(list, task.intrinsics, images[k]);
  } else if (task.focal > 0) {
    for (int k = 0; k < 2; ++k) {
      const ImageMetadata m = read_image_metadata(images[k]);
      cameras[k] = PinholeCamera::centered(m.width, m.height, task.focal);
    }
  }
  const bool calibrated = cameras[0].has_value();
  o.estimation.model = task.model.value_or(calibrated ? TwoViewModel::kEssential : TwoViewModel::kFundamental);
  if (o.estimation.model != TwoViewModel::kEssential) return o;
  if (!calibrated) throw_error(ErrorCode::kInvalidArgument, "match: --model E needs --focal or --intrinsics");
  for (int k = 0; k < 2; ++k) {
    if (cameras[k]->k1 != 0)  // the solver and the errors use K⁻¹ x on the keypoints as they are
      throw_error(ErrorCode::kInvalidArgument, task.intrinsics.string(),
                  ": --model E needs undistorted cameras (k1 = 0); ", "use --model F for ", images[k].string());
    Eigen::Matrix3d K;
    K << cameras[k]->focal, 0, cameras[k]->cx, 0, cameras[k]->focal_y(), cameras[k]->cy, 0, 0, 1;
    (k == 0 ? o.estimation.calibration1 : o.estimation.calibration2) = K;
  }
  return o;
}

std::string image_pair_summary(const ImagePairResult& r, const TwoViewOptions& estimation,
                               const std::filesystem::path& drawing) {
  std::ostringstream s;
  const std::string_view model = to_string(estimation.model);
  s << r.features1.size() << " and " << r.features2.size() << " features; " << r.one_to_one_matches()
    << " 1-1 matches, " << r.matches.size() << " features with 1-M candidates\n";
  if (!r.estimate.found) {
    s << "no " << model << " found\n";
    return s.str();
  }
  s << model << " (" << ransac_option_name(estimation.variant) << "): " << r.estimate.inliers << " inliers ("
    << r.estimate.one_to_one_inliers << " 1-1, " << r.estimate.extra_inliers << " more through 1-M); "
    << r.estimate.stats.iterations << " samples, " << r.estimate.stats.models_rejected_sprt
    << " models rejected by SPRT\n";
  s << r.estimate.matrix << "\n";
  s << "times (ms): features " << r.ms_features << ", matching " << r.ms_matching << ", RANSAC " << r.estimate.total_ms
    << "\n";
  if (!drawing.empty()) s << "wrote " << drawing.string() << "\n";
  return s.str();
}

}  // namespace visloc
