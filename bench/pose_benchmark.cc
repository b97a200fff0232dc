#include "bench/pose_benchmark.h"

#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>
#include <utility>

#include "visloc/baselines/opencv_pnp_baseline.h"
#include "visloc/baselines/synthetic_correspondences.h"
#include "visloc/util/error.h"
#include "visloc/util/statistics.h"
#include "visloc/util/timer.h"

namespace visloc {

namespace {

const char* const kOpenCvNote =
    "OpenCV baselines see only the 1-1 matches (hypothesis set, first candidate) and are given the focal "
    "length; for the uncalibrated family that is the TRUE focal length (our estimators are not given it).";

struct Method {
  std::string name;
  bool ours;
  RansacVariant variant;
  OpenCvPnpMethod cv;
};

std::vector<Method> methods_of(const PoseBenchmarkOptions& o) {
  std::vector<Method> methods{{"classic-ransac", true, RansacVariant::kClassic11, {}},
                              {"1m-fixed", true, RansacVariant::kOneManyFixed, {}},
                              {"1m-sprt", true, RansacVariant::kOneManySprt, {}}};
  if (o.opencv) {
    methods.push_back({"opencv-p3p-ransac", false, {}, OpenCvPnpMethod::kP3pRansac});
    methods.push_back({"opencv-usac-magsac", false, {}, OpenCvPnpMethod::kUsacMagsac});
  }
  return methods;
}

// The problem of one (family, features, inlier ratio, trial); its seed is
// also the seed of our estimators on it.
SyntheticOptions problem_options(const PoseBenchmarkOptions& o, SyntheticFamily family, size_t features,
                                 double ratio, int trial) {
  SyntheticOptions so;
  so.family = family;
  so.num_features = features;
  so.inlier_ratio = ratio;
  so.noise_px = o.noise_px;
  so.max_candidates = o.max_candidates;
  so.seed = o.seed * 1000003ull + static_cast<uint64_t>(family) * 7919ull + features * 131ull +
            static_cast<uint64_t>(std::llround(ratio * 1000)) * 17ull + static_cast<uint64_t>(trial);
  return so;
}

OpenCvPnpOptions opencv_options(const PoseBenchmarkOptions& o, OpenCvPnpMethod method) {
  OpenCvPnpOptions co;
  co.method = method;
  co.threshold_px = o.ransac.threshold_px;
  co.max_iterations = o.opencv_iterations;
  co.confidence = o.ransac.confidence;
  return co;
}

struct Trial {
  bool success = false;
  double rot_err_deg = std::numeric_limits<double>::infinity();
  double pos_err = std::numeric_limits<double>::infinity();
  double inliers = 0;
  double ms = 0;
};

Trial run_trial(const PoseBenchmarkOptions& o, const Method& m, const SyntheticProblem& p, uint64_t seed) {
  Trial t;
  bool has_pose = false, registered = false;
  CameraPose pose;
  if (m.ours) {
    RansacOptions ro = o.ransac;
    ro.variant = m.variant;
    ro.seed = seed;
    Timer timer;
    const PoseEstimate r = estimate_pose(p.correspondences, p.camera, ro);
    t.ms = timer.elapsed_ms();
    has_pose = r.has_pose;
    registered = r.registered;
    pose = r.cam_from_world;
    t.inliers = static_cast<double>(r.num_inliers);
  } else {
    const OpenCvPnpResult r =
        estimate_pose_opencv(p.correspondences, p.camera, p.true_focal, opencv_options(o, m.cv));
    t.ms = r.total_ms;
    has_pose = r.has_pose;
    registered = r.has_pose && r.num_inliers >= o.ransac.min_inliers;
    pose = r.cam_from_world;
    t.inliers = static_cast<double>(r.num_inliers);
  }
  if (has_pose) {
    t.rot_err_deg = rotation_error_deg(pose, p.true_cam_from_world);
    t.pos_err = position_error(pose, p.true_cam_from_world);
  }
  t.success = registered && t.rot_err_deg < 2.0 && t.pos_err < 0.05 * p.scene_depth;
  return t;
}

PoseMethodSummary summarize(const std::string& method, const std::string& family, double ratio,
                            const std::vector<Trial>& t) {
  PoseMethodSummary s{method, family, ratio, t.size()};
  std::vector<double> rot, pos, inl, ms;
  size_t ok = 0;
  for (const auto& x : t) {
    ok += x.success ? 1 : 0;
    rot.push_back(x.rot_err_deg);
    pos.push_back(x.pos_err);
    inl.push_back(x.inliers);
    ms.push_back(x.ms);
  }
  s.success_rate = t.empty() ? 0 : static_cast<double>(ok) / static_cast<double>(t.size());
  s.median_rotation_error_deg = median(rot);
  s.median_position_error = median(pos);
  s.median_inliers = median(inl);
  s.median_ms = median(ms);
  return s;
}

// Every method on every problem of one family; appends its summaries.
void run_family(const PoseBenchmarkOptions& o, const std::string& family_name, const std::vector<Method>& methods,
                const std::function<void(const std::string&)>& progress, PoseBenchmarkResult* out) {
  const SyntheticFamily family = parse_synthetic_family(family_name);
  std::map<std::string, std::vector<Trial>> all;
  std::map<std::pair<std::string, double>, std::vector<Trial>> per_ratio;
  for (size_t nf : o.features) {
    if (progress) progress(family_name + ": " + std::to_string(nf) + " features");
    for (double ratio : o.inlier_ratios)
      for (int trial = 0; trial < o.trials; ++trial) {
        const SyntheticOptions so = problem_options(o, family, nf, ratio, trial);
        const SyntheticProblem p = make_synthetic_problem(so);
        for (const auto& m : methods) {
          const Trial t = run_trial(o, m, p, so.seed);
          all[m.name].push_back(t);
          per_ratio[{m.name, ratio}].push_back(t);
        }
      }
  }
  for (const auto& m : methods) {
    out->overall.push_back(summarize(m.name, family_name, -1, all[m.name]));
    for (double ratio : o.inlier_ratios)
      out->by_inlier_ratio.push_back(summarize(m.name, family_name, ratio, per_ratio[{m.name, ratio}]));
  }
}

nlohmann::json number_or_null(double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(); }

nlohmann::json to_json(const PoseMethodSummary& s, bool with_ratio) {
  nlohmann::json j = {{"name", s.method},
                      {"family", s.family},
                      {"success_rate", s.success_rate},
                      {"median_rot_err_deg", number_or_null(s.median_rotation_error_deg)},
                      {"median_pos_err", number_or_null(s.median_position_error)},
                      {"median_inliers", s.median_inliers},
                      {"ms_median", s.median_ms}};
  if (with_ratio) {
    j["inlier_ratio"] = s.inlier_ratio;
    j["trials"] = s.trials;
  }
  return j;
}

nlohmann::json report_json(const PoseBenchmarkOptions& o, const PoseBenchmarkResult& r) {
  nlohmann::json out;
  for (const auto& s : r.overall) out["methods"].push_back(to_json(s, false));
  for (const auto& s : r.by_inlier_ratio) out["by_inlier_ratio"].push_back(to_json(s, true));
  out["expectations"] = nlohmann::json::array();
  for (const auto& e : r.expectations)
    out["expectations"].push_back({{"expectation", e.expectation}, {"holds", e.holds}, {"measured", e.measured}});
  out["config"] = {{"families", o.families},
                   {"features", o.features},
                   {"inlier_ratios", o.inlier_ratios},
                   {"trials", o.trials},
                   {"noise_px", o.noise_px},
                   {"max_candidates", o.max_candidates},
                   {"threshold_px", o.ransac.threshold_px},
                   {"max_iterations", o.ransac.max_iterations},
                   {"fixed_iterations", o.ransac.fixed_iterations},
                   {"opencv_iterations", o.opencv_iterations},
                   {"seed", o.seed},
                   {"scene_depth_m", SyntheticOptions{}.scene_depth},
                   {"wall_s", r.wall_s}};
  out["notes"] = {kOpenCvNote};
  return out;
}

std::string fmt(double x, int prec) {
  if (!std::isfinite(x)) return "inf";
  std::ostringstream o;
  o << std::fixed << std::setprecision(prec) << x;
  return o.str();
}

void table_header(std::ostream& out, bool ratio) {
  out << std::left << std::setw(14) << "family" << (ratio ? std::string("ratio  ") : std::string("")) << std::setw(20)
      << "method" << std::right << std::setw(9) << "success" << std::setw(11) << "rot deg" << std::setw(10) << "pos m"
      << std::setw(9) << "inliers" << std::setw(10) << "ms" << "\n";
}

void table_row(std::ostream& out, const PoseMethodSummary& s, bool ratio) {
  out << std::left << std::setw(14) << s.family;
  if (ratio) out << std::setw(7) << fmt(s.inlier_ratio, 2);
  out << std::setw(20) << s.method << std::right << std::setw(8) << fmt(100 * s.success_rate, 1) << "%"
      << std::setw(11) << fmt(s.median_rotation_error_deg, 3) << std::setw(10) << fmt(s.median_position_error, 3)
      << std::setw(9) << fmt(s.median_inliers, 0) << std::setw(10) << fmt(s.median_ms, 2) << "\n";
}

std::string report_table(const PoseBenchmarkOptions& o, const PoseBenchmarkResult& r) {
  std::ostringstream out;
  const size_t per_family = o.features.size() * o.inlier_ratios.size() * static_cast<size_t>(o.trials);
  out << "visloc bench pose: " << per_family << " problems per family (features";
  for (auto n : o.features) out << " " << n;
  out << "; 1-1 inlier ratios";
  for (auto ratio : o.inlier_ratios) out << " " << ratio;
  out << "; " << o.trials << " trials each), noise " << o.noise_px << " px, M = " << o.max_candidates
      << ", threshold " << o.ransac.threshold_px << " px, scene depth " << SyntheticOptions{}.scene_depth
      << " m\nsuccess: >= " << o.ransac.min_inliers
      << " inliers, rotation < 2 deg, position < 5% of the scene depth; medians over all trials\n\n";
  table_header(out, false);
  for (const auto& s : r.overall) table_row(out, s, false);
  out << "\nby inlier ratio of the 1-1 set:\n";
  table_header(out, true);
  for (const auto& s : r.by_inlier_ratio) table_row(out, s, true);
  out << "\nexpectations (issue #4), on these figures:\n";
  for (const auto& e : r.expectations)
    out << "  " << (e.holds ? "[holds]     " : "[not held]  ") << e.expectation << ": " << e.measured << "\n";
  out << "\nnote: " << kOpenCvNote << "\nwall time " << fmt(r.wall_s, 1) << " s\n";
  return out.str();
}

const PoseMethodSummary* find_summary(const std::vector<PoseMethodSummary>& summaries, const std::string& method,
                                      const std::string& family, double ratio) {
  for (const auto& s : summaries)
    if (s.method == method && s.family == family && (ratio < 0 || s.inlier_ratio == ratio)) return &s;
  return nullptr;
}

}  // namespace

void PoseBenchmarkOptions::validate() const {
  auto bad = [](const char* field, const char* rule) {
    throw_error(ErrorCode::kInvalidArgument, "bench pose options: ", field, " ", rule);
  };
  if (families.empty()) bad("families", "must not be empty");
  if (features.empty()) bad("features", "must not be empty");
  if (inlier_ratios.empty()) bad("inlier_ratios", "must not be empty");
  if (trials <= 0) throw_error(ErrorCode::kInvalidArgument, "bench pose options: trials must be positive, got ", trials);
  ransac.validate();
  // The problems' and OpenCV's own checks (their messages), in the order a run meets them.
  parse_synthetic_family(families.front());
  for (size_t nf : features)
    for (double ratio : inlier_ratios) problem_options(*this, SyntheticFamily::kCalibrated, nf, ratio, 0).validate();
  for (const auto& family : families) parse_synthetic_family(family);
  if (opencv) opencv_options(*this, OpenCvPnpMethod::kP3pRansac).validate();
}

const PoseMethodSummary* PoseBenchmarkResult::find(const std::string& method, const std::string& family,
                                                   double inlier_ratio) const {
  return find_summary(inlier_ratio < 0 ? overall : by_inlier_ratio, method, family, inlier_ratio);
}

std::vector<PoseExpectation> pose_expectations(const std::vector<PoseMethodSummary>& overall,
                                               const std::vector<std::string>& families, size_t fixed_iterations) {
  std::vector<PoseExpectation> out;
  auto find = [&](const char* method, const std::string& family) {
    return find_summary(overall, method, family, -1);
  };
  auto check = [&](const std::string& what, bool holds, const std::string& measured) {
    out.push_back({what, holds, measured});
  };
  if (const PoseMethodSummary *c = find("classic-ransac", "facade"), *s = find("1m-sprt", "facade"); c && s) {
    const double ratio = c->median_inliers > 0 ? s->median_inliers / c->median_inliers
                                               : std::numeric_limits<double>::infinity();
    check("facade: 1-M SPRT median inliers >= 1.5x classical", ratio >= 1.5,
          fmt(s->median_inliers, 0) + " vs " + fmt(c->median_inliers, 0) + " (" + fmt(ratio, 2) + "x)");
    check("facade: 1-M SPRT succeeds more often than classical", s->success_rate > c->success_rate,
          fmt(100 * s->success_rate, 1) + "% vs " + fmt(100 * c->success_rate, 1) + "%");
  }
  for (const auto& family : families) {
    const PoseMethodSummary *f = find("1m-fixed", family), *s = find("1m-sprt", family),
                            *c = find("classic-ransac", family);
    if (!f || !s || !c) continue;
    check(family + ": 1-M SPRT >= 10x faster than 1-M fixed-" + std::to_string(fixed_iterations),
          s->median_ms * 10 <= f->median_ms,
          fmt(s->median_ms, 2) + " ms vs " + fmt(f->median_ms, 2) + " ms (" + fmt(f->median_ms / s->median_ms, 1) +
              "x)");
    check(family + ": 1-M SPRT success within 1 point of 1-M fixed", s->success_rate >= f->success_rate - 0.01,
          fmt(100 * s->success_rate, 1) + "% vs " + fmt(100 * f->success_rate, 1) + "%");
    check(family + ": 1-M SPRT within 2x of classical RANSAC's time", s->median_ms <= 2 * c->median_ms,
          fmt(s->median_ms, 2) + " ms vs " + fmt(c->median_ms, 2) + " ms (" + fmt(s->median_ms / c->median_ms, 2) +
              "x)");
  }
  return out;
}

PoseBenchmarkResult run_pose_benchmark(const PoseBenchmarkOptions& options,
                                       const std::function<void(const std::string&)>& progress) {
  options.validate();
  const std::vector<Method> methods = methods_of(options);
  PoseBenchmarkResult r;
  Timer wall;
  for (const auto& family : options.families) run_family(options, family, methods, progress, &r);
  r.wall_s = wall.elapsed_ms() / 1000.0;
  r.expectations = pose_expectations(r.overall, options.families, options.ransac.fixed_iterations);
  r.report = report_json(options, r);
  r.table = report_table(options, r);
  return r;
}

}  // namespace visloc
