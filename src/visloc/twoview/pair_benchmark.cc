#include "visloc/twoview/pair_benchmark.h"

#include <opencv2/calib3d.hpp>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>

#include "visloc/colmap/colmap_model.h"
#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/pose/solvers/two_view.h"
#include "visloc/twoview/image_pair.h"
#include "visloc/util/error.h"
#include "visloc/util/statistics.h"

namespace visloc {
namespace fs = std::filesystem;

StrechaCamera read_strecha_camera(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw_error(ErrorCode::kIo, path.string(), ": cannot open");
  std::vector<double> v;
  double x;
  while (in >> x) v.push_back(x);
  // K (9), distortion (3), R (9), C (3), width and height (2).
  if (v.size() != 26) throw_error(ErrorCode::kFormat, path.string(), ": ", v.size(), " numbers, a Strecha camera has 26");
  for (double d : v)
    if (!std::isfinite(d)) throw_error(ErrorCode::kFormat, path.string(), ": a number is not finite");
  StrechaCamera c;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) {
      c.K(r, k) = v[static_cast<size_t>(3 * r + k)];
      c.world_from_camera(r, k) = v[static_cast<size_t>(12 + 3 * r + k)];
    }
  c.center = Eigen::Vector3d(v[21], v[22], v[23]);
  c.width = static_cast<int>(v[24]);
  c.height = static_cast<int>(v[25]);
  if (!(c.K(0, 0) > 0 && c.K(1, 1) > 0) || c.width < 1 || c.height < 1)
    throw_error(ErrorCode::kFormat, path.string(), ": focal or image size not positive");
  if ((c.world_from_camera.transpose() * c.world_from_camera - Eigen::Matrix3d::Identity()).norm() > 1e-3)
    throw_error(ErrorCode::kFormat, path.string(), ": R is not a rotation");
  return c;
}

Eigen::Matrix3d fundamental_between(const StrechaCamera& a, const StrechaCamera& b) {
  // Camera coordinates: Rᵀ(X − C). Camera 2 from camera 1: R21 = R2ᵀ R1, t21 = R2ᵀ(C1 − C2).
  const Eigen::Matrix3d R = b.world_from_camera.transpose() * a.world_from_camera;
  const Eigen::Vector3d t = b.world_from_camera.transpose() * (a.center - b.center);
  Eigen::Matrix3d tx;
  tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
  const Eigen::Matrix3d F = b.K.inverse().transpose() * tx * R * a.K.inverse();
  return F / F.norm();
}

void PairBenchmarkOptions::validate() const {
  sift.validate();
  if (strecha_dir.empty() && !scenes.empty())
    throw_error(ErrorCode::kInvalidArgument, "bench pairs: the Strecha folder is needed");
  if (scenes.empty() && synthetic_cities.empty()) throw_error(ErrorCode::kInvalidArgument, "bench pairs: no scene");
  if (max_pairs_per_scene < 0) throw_error(ErrorCode::kInvalidArgument, "bench pairs: max_pairs_per_scene must be >= 0");
  for (double v : {threshold_px, truth_px, success_px})
    if (!(v > 0) || !std::isfinite(v)) throw_error(ErrorCode::kInvalidArgument, "bench pairs: thresholds must be positive");
  if (fixed_iterations == 0) throw_error(ErrorCode::kInvalidArgument, "bench pairs: fixed_iterations must be positive");
}

namespace {

double ms_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

// Evaluation of an estimated F (or none) on a pair.
void score(const Eigen::Matrix3d* F, const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>>& truth,
           const PairBenchmarkOptions& o, PairBenchmarkRow* row) {
  row->truth_correspondences = truth.size();
  if (!F || truth.empty()) return;
  std::vector<double> e;
  for (const auto& [a, b] : truth) e.push_back(symmetric_epipolar_distance(*F, a, b));
  row->median_error_px = median(e);
  row->success = row->median_error_px <= o.success_px;
}

// Every method on one pair (features, true F), rows appended to `out`.
void evaluate_pair(const std::string& scene, const std::string& pair, const FeatureSet& f1, const FeatureSet& f2,
                   const Eigen::Matrix3d& F_true, const PairBenchmarkOptions& o, std::vector<PairBenchmarkRow>* out,
                   size_t* candidates_out, size_t* truth_out) {
  const TwoViewCorrespondences m = match_feature_sets(f1, f2, PairMatchingOptions{});
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> truth;
  for (size_t k = 0; k < m.size(); ++k)
    for (uint32_t j = m.candidate_offsets[k]; j < m.candidate_offsets[k + 1]; ++j)
      if (symmetric_epipolar_distance(F_true, m.points1[k], m.candidates[j]) <= o.truth_px) {
        truth.emplace_back(m.points1[k], m.candidates[j]);
        break;
      }
  auto true_inliers_of = [&](const std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>>& inliers) {
    size_t n = 0;
    for (const auto& [a, b] : inliers) n += symmetric_epipolar_distance(F_true, a, b) <= o.success_px;
    return n;
  };
  // This library's three variants.
  for (const auto& [name, variant] : std::vector<std::pair<std::string, RansacVariant>>{
           {"classic", RansacVariant::kClassic11},
           {"1m", RansacVariant::kOneManyFixed},
           {"1m-sprt", RansacVariant::kOneManySprt}}) {
    TwoViewOptions to;
    to.variant = variant;
    to.threshold_px = o.threshold_px;
    to.fixed_iterations = o.fixed_iterations;
    to.seed = o.seed;
    PairBenchmarkRow row{scene, pair, name};
    const auto t = std::chrono::steady_clock::now();
    const TwoViewEstimate est = estimate_two_view(m, to);
    row.ms = ms_since(t);
    row.found = est.found;
    row.inliers = est.inliers;
    std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> inliers;
    for (size_t k = 0; k < m.size(); ++k)
      if (est.chosen_candidate[k] >= 0)
        inliers.emplace_back(m.points1[k], m.candidates[m.candidate_offsets[k] + static_cast<uint32_t>(est.chosen_candidate[k])]);
    row.true_inliers = true_inliers_of(inliers);
    score(est.found ? &est.fundamental : nullptr, truth, o, &row);
    out->push_back(row);
  }
  // OpenCV on the same 1-1 matches.
  if (o.opencv) {
    std::vector<cv::Point2f> a, b;
    for (size_t k = 0; k < m.size(); ++k)
      if (m.in_hypothesis_set[k]) {
        a.emplace_back(static_cast<float>(m.points1[k].x()), static_cast<float>(m.points1[k].y()));
        const Eigen::Vector2d& q = m.candidates[m.candidate_offsets[k]];
        b.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
      }
    for (const auto& [name, method] : std::vector<std::pair<std::string, int>>{{"opencv-magsac", cv::USAC_MAGSAC},
                                                                               {"opencv-ransac", cv::FM_RANSAC}}) {
      PairBenchmarkRow row{scene, pair, name};
      cv::Mat mask;
      const auto t = std::chrono::steady_clock::now();
      // OpenCV's RANSAC keeps a match when both point-line distances are
      // below its threshold; the Sampson distance of ours is about a line
      // distance / √2: √2 × threshold accepts the same matches.
      const double cv_threshold = o.threshold_px * std::sqrt(2.0);
      cv::Mat F = a.size() >= 8 ? cv::findFundamentalMat(a, b, method, cv_threshold, 0.9999, 10000, mask) : cv::Mat();
      row.ms = ms_since(t);
      Eigen::Matrix3d Fe;
      if (F.rows == 3 && F.cols == 3) {
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) Fe(r, c) = F.at<double>(r, c);
        row.found = true;
        std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> inliers;
        for (size_t k = 0; k < a.size(); ++k)
          if (mask.at<uchar>(static_cast<int>(k)))
            inliers.emplace_back(Eigen::Vector2d(a[k].x, a[k].y), Eigen::Vector2d(b[k].x, b[k].y));
        row.inliers = inliers.size();
        row.true_inliers = true_inliers_of(inliers);
      }
      score(row.found ? &Fe : nullptr, truth, o, &row);
      out->push_back(row);
    }
  }
  *candidates_out = m.size();
  *truth_out = truth.size();
}

// Summaries per scene group (castle: repeated windows; synthetic; other)
// and method, the expectations on the castle pairs, and the markdown.
void summarize(const std::vector<PairBenchmarkRow>& result_rows, const PairBenchmarkOptions& o, nlohmann::json* rows_out,
               nlohmann::json* summary_out, nlohmann::json* expectations_out, std::string* markdown) {
  // Summaries: castle scenes (repeated windows) and the others, per method.
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& r : result_rows)
    rows.push_back({{"scene", r.scene}, {"pair", r.pair}, {"method", r.method}, {"found", r.found},
                    {"success", r.success}, {"median_error_px", r.median_error_px}, {"inliers", r.inliers},
                    {"true_inliers", r.true_inliers}, {"truth_correspondences", r.truth_correspondences}, {"ms", r.ms}});
  auto group_of = [](const std::string& scene) {
    return scene.rfind("castle", 0) == 0 ? "castle" : scene.rfind("synthetic:", 0) == 0 ? "synthetic" : "other";
  };
  std::map<std::string, std::map<std::string, std::vector<const PairBenchmarkRow*>>> groups;
  for (const auto& r : result_rows) groups[group_of(r.scene)][r.method].push_back(&r);
  nlohmann::json summary = nlohmann::json::object();
  std::ostringstream md;
  md << "# visloc bench pairs\n\nNeighbouring pairs of the Strecha scenes (truth: the laser cameras' F) and of "
        "synthetic cities (one heading from neighbouring placemarks; truth: the rendered poses). Success: the "
        "truth correspondences' median symmetric epipolar distance under the estimated F <= "
     << o.success_px << " px. True inliers: inliers within " << o.success_px << " px of the true F's epipolar lines.\n\n"
     << "| scenes | method | pairs | success | median true inliers | median inliers | median ms |\n|---|---|---|---|---|---|---|\n";
  const std::vector<std::string> order = {"classic", "1m", "1m-sprt", "opencv-magsac", "opencv-ransac"};
  for (const auto& [group, methods] : groups)
    for (const std::string& method : order) {
      auto it = methods.find(method);
      if (it == methods.end()) continue;
      std::vector<double> true_inliers, inliers, ms;
      size_t success = 0;
      for (const PairBenchmarkRow* r : it->second) {
        true_inliers.push_back(static_cast<double>(r->true_inliers));
        inliers.push_back(static_cast<double>(r->inliers));
        ms.push_back(r->ms);
        success += r->success;
      }
      const double rate = static_cast<double>(success) / static_cast<double>(it->second.size());
      summary[group][method] = {{"pairs", it->second.size()}, {"success_rate", rate},
                                {"median_true_inliers", median(true_inliers)}, {"median_inliers", median(inliers)},
                                {"median_ms", median(ms)}};
      md << "| " << group << " | " << method << " | " << it->second.size() << " | " << std::fixed << std::setprecision(3)
         << rate << " | " << std::setprecision(0) << median(true_inliers) << " | " << median(inliers) << " | "
         << std::setprecision(2) << median(ms) << " |\n";
    }
  // The expectations on the castle pairs, measured.
  nlohmann::json expectations = nlohmann::json::array();
  if (summary.contains("castle") && summary["castle"].contains("classic") && summary["castle"].contains("1m-sprt")) {
    const auto& c = summary["castle"]["classic"];
    const auto& s = summary["castle"]["1m-sprt"];
    const double inlier_ratio = s["median_true_inliers"].get<double>() / std::max(1.0, c["median_true_inliers"].get<double>());
    const double time_ratio = s["median_ms"].get<double>() / std::max(1e-9, c["median_ms"].get<double>());
    expectations.push_back({{"expectation", "castle: 1m-sprt true inliers >= 1.5x classic"}, {"measured", inlier_ratio},
                            {"holds", inlier_ratio >= 1.5}});
    expectations.push_back({{"expectation", "castle: 1m-sprt time <= 2x classic"}, {"measured", time_ratio},
                            {"holds", time_ratio <= 2.0}});
    expectations.push_back({{"expectation", "castle: 1m-sprt success >= classic"},
                            {"measured", {s["success_rate"], c["success_rate"]}},
                            {"holds", s["success_rate"].get<double>() >= c["success_rate"].get<double>()}});
    if (summary["castle"].contains("opencv-magsac")) {
      const auto& g = summary["castle"]["opencv-magsac"];
      expectations.push_back({{"expectation", "castle: 1m-sprt success >= OpenCV MAGSAC"},
                              {"measured", {s["success_rate"], g["success_rate"]}},
                              {"holds", s["success_rate"].get<double>() >= g["success_rate"].get<double>()}});
    }
  }
  md << std::defaultfloat << "\n";
  for (const auto& e : expectations)
    md << "- " << e["expectation"].get<std::string>() << ": measured " << e["measured"].dump() << ", "
       << (e["holds"].get<bool>() ? "holds" : "does NOT hold") << "\n";
  *rows_out = std::move(rows);
  *summary_out = std::move(summary);
  *expectations_out = std::move(expectations);
  *markdown = md.str();
}

}  // namespace

PairBenchmarkResult run_pair_benchmark(const PairBenchmarkOptions& o,
                                       const std::function<void(const std::string&)>& progress) {
  o.validate();
  PairBenchmarkResult out;
  const SiftExtractor sift(o.sift);
  for (const std::string& scene : o.scenes) {
    const fs::path dir = o.strecha_dir / scene;
    if (!fs::is_directory(dir / "images"))
      throw_error(ErrorCode::kNotFound, (dir / "images").string(), ": no such scene folder");
    std::vector<fs::path> images;
    for (const auto& e : fs::directory_iterator(dir / "images"))
      if (e.path().extension() == ".jpg") images.push_back(e.path());
    std::sort(images.begin(), images.end());
    std::map<std::string, FeatureSet> features;
    auto features_of = [&](const fs::path& p) -> const FeatureSet& {
      auto it = features.find(p.string());
      if (it == features.end()) it = features.emplace(p.string(), sift.extract_file(p)).first;
      return it->second;
    };
    int pairs = 0;
    for (size_t i = 0; i + 1 < images.size(); ++i) {
      if (o.max_pairs_per_scene > 0 && pairs >= o.max_pairs_per_scene) break;
      ++pairs;
      const fs::path &p1 = images[i], &p2 = images[i + 1];
      const std::string pair = p1.filename().string() + "-" + p2.filename().string();
      const Eigen::Matrix3d F_true =
          fundamental_between(read_strecha_camera(dir / "cameras" / (p1.filename().string() + ".camera")),
                              read_strecha_camera(dir / "cameras" / (p2.filename().string() + ".camera")));
      const FeatureSet& f1 = features_of(p1);
      const FeatureSet& f2 = features_of(p2);
      size_t candidates = 0, truth_count = 0;
      evaluate_pair(scene, pair, f1, f2, F_true, o, &out.rows, &candidates, &truth_count);
      if (progress) progress(scene + " " + pair + ": " + std::to_string(candidates) + " features with candidates, " +
                             std::to_string(truth_count) + " truth correspondences");
    }
  }

  // Synthetic facade pairs: one heading from two neighbouring placemarks.
  for (const fs::path& city : o.synthetic_cities) {
    const std::string scene = "synthetic:" + city.filename().string();
    const ColmapModel model = read_colmap_model(city / "sparse");
    std::map<uint32_t, PinholeCamera> cameras;
    for (const auto& c : model.cameras)
      cameras[c.camera_id] = PinholeCamera::from_colmap(colmap_camera_model_name(c.model_id), static_cast<int>(c.width),
                                                        static_cast<int>(c.height), c.params);
    std::map<std::string, const ColmapImage*> by_name;
    for (const auto& im : model.images) by_name[im.name] = &im;
    auto calibration = [&](const ColmapImage& im) {
      const PinholeCamera& c = cameras.at(im.camera_id);
      Eigen::Matrix3d K;
      K << c.focal, 0, c.cx, 0, c.focal_y(), c.cy, 0, 0, 1;
      return K;
    };
    std::map<std::string, FeatureSet> features;
    auto features_of = [&](const std::string& name) -> const FeatureSet& {
      auto it = features.find(name);
      if (it == features.end()) it = features.emplace(name, sift.extract_file(city / "images" / name)).first;
      return it->second;
    };
    int pairs = 0;
    for (const auto& [name, im] : by_name) {
      // pPPPPP_hHH_eE.jpg → the same heading and elevation at placemark PPPPP + 1.
      if (name.size() < 7 || name[0] != 'p') continue;
      const int placemark = std::atoi(name.substr(1, 5).c_str());
      if (placemark < 0 || placemark >= 99999) continue;
      std::string next = std::to_string(placemark + 1);
      next.insert(0, 5 - next.size(), '0');
      const std::string other = "p" + next + name.substr(6);
      auto it = by_name.find(other);
      if (it == by_name.end()) continue;
      if (o.max_pairs_per_scene > 0 && pairs >= o.max_pairs_per_scene) break;
      ++pairs;
      const ColmapImage& a = *im;
      const ColmapImage& b = *it->second;
      // Camera b from camera a (cam_from_world poses): R = Rb Raᵀ, t = tb − R ta.
      const CameraPose pa = colmap_image_pose(a), pb = colmap_image_pose(b);
      const Eigen::Matrix3d R = pb.rotation_matrix() * pa.rotation_matrix().transpose();
      const Eigen::Vector3d t = pb.translation - R * pa.translation;
      Eigen::Matrix3d tx;
      tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
      Eigen::Matrix3d F_true = calibration(b).inverse().transpose() * tx * R * calibration(a).inverse();
      F_true /= F_true.norm();
      size_t candidates = 0, truth_count = 0;
      evaluate_pair(scene, name + "-" + other, features_of(name), features_of(other), F_true, o, &out.rows, &candidates,
                    &truth_count);
      if (progress) progress(scene + " " + name + "-" + other + ": " + std::to_string(candidates) +
                             " features with candidates, " + std::to_string(truth_count) + " truth correspondences");
    }
  }

  nlohmann::json rows, summary, expectations;
  summarize(out.rows, o, &rows, &summary, &expectations, &out.markdown);
  out.report = {{"config",
                 {{"scenes", o.scenes}, {"synthetic_cities", [&] {
                    nlohmann::json a = nlohmann::json::array();
                    for (const auto& c : o.synthetic_cities) a.push_back(c.string());
                    return a;
                  }()}, {"threshold_px", o.threshold_px}, {"truth_px", o.truth_px},
                  {"success_px", o.success_px}, {"fixed_iterations", o.fixed_iterations}, {"seed", o.seed},
                  {"sift", nlohmann::json::parse(o.sift.to_json())}}},
                {"summary", summary},
                {"expectations", expectations},
                {"rows", rows}};
  return out;
}

}  // namespace visloc
