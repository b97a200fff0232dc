#include "visloc/eval/evaluation.h"

#include "visloc/map/map.h"
#include "visloc/map/map_overview.h"

#include <sys/resource.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>

#include "visloc/eval/confidence_fit.h"
#include "visloc/eval/plot.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc {
namespace {

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const double pos = q * (v.size() - 1);
  const size_t lo = static_cast<size_t>(std::floor(pos));
  const size_t hi = std::min(v.size() - 1, lo + 1);
  return v[lo] + (pos - lo) * (v[hi] - v[lo]);
}

nlohmann::json stats(const std::vector<double>& v) {
  if (v.empty()) return nullptr;
  return {{"q25", quantile(v, 0.25)}, {"median", quantile(v, 0.5)}, {"q75", quantile(v, 0.75)}};
}

// The query's pose, registered or not, is within the rule (never for a negative).
bool pose_is_right(const QueryEvaluation& q, const WrongPoseRule& rule) {
  return !q.negative && q.pose_position_error >= 0 && q.pose_position_error <= rule.position_m &&
         q.pose_rotation_error <= rule.rotation_deg;
}

// What the confidence threshold turned away among the poses with enough
// inliers, and what the under-street check turned away above the threshold.
void add_gate_counts(const std::vector<QueryEvaluation>& per_query, const WrongPoseRule& rule, double min_confidence,
                     size_t min_inliers, nlohmann::json& j) {
  size_t gated_right = 0, gated_wrong = 0, under_right = 0, under_wrong = 0;
  for (const auto& q : per_query) {
    if (!q.confidence_features || q.inliers < min_inliers || q.registered) continue;
    const bool right = pose_is_right(q, rule);
    if (q.under_street && q.confidence >= min_confidence)
      (right ? under_right : under_wrong)++;
    else
      (right ? gated_right : gated_wrong)++;
  }
  j["confidence"] = {{"min_confidence", min_confidence},
                     {"min_inliers", min_inliers},
                     {"rejected_right_poses", gated_right},
                     {"rejected_wrong_poses", gated_wrong}};
  j["under_street"] = {{"rejected_right_poses", under_right}, {"rejected_wrong_poses", under_wrong}};
}

}  // namespace

uint64_t peak_memory_bytes() {
  // VmHWM: the resident high-water mark of this process's address space,
  // which starts afresh at exec (ru_maxrss does not: it keeps the peak of the
  // process image before an exec, e.g. a parent's memory after posix_spawn).
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmHWM:", 0) == 0) {
      std::istringstream in(line.substr(6));
      uint64_t kib = 0;
      if (in >> kib) return kib * 1024;
    }
  struct rusage u {};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<uint64_t>(u.ru_maxrss) * 1024;
}

EvaluationReport evaluate(const std::vector<LocalizationResult>& results,
                          const std::map<std::string, QueryTruth>& truth,
                          const std::vector<LocalizationResult>& negative_results, const LocalizerOptions& localizer,
                          const WrongPoseRule& rule) {
  EvaluationReport rep;
  rep.rule = rule;
  rep.min_inliers = localizer.ransac.min_inliers;
  rep.min_confidence = localizer.min_confidence;
  auto common = [](const LocalizationResult& r, QueryEvaluation* q) {
    q->image = r.image;
    q->registered = r.registered;
    q->inliers = r.inliers;
    q->confidence = r.confidence;
    // (Peers' results, e.g. COLMAP's, have a pose but no confidence inputs.)
    if (r.segment >= 0 && r.confidence_features.inliers > 0) q->confidence_features = r.confidence_features;
    q->uncertainty = r.uncertainty;
    q->segment = r.segment;
    q->under_street = r.under_street.under_street;
    q->times = r.times;
  };
  auto note_frame = [&rep](const char* frame) {
    if (rep.frame.empty()) rep.frame = frame;
    else if (rep.frame != frame) rep.frame = "mixed";
  };
  for (const auto& r : results) {
    auto it = truth.find(r.image);
    if (it == truth.end()) continue;
    QueryEvaluation q;
    common(r, &q);
    const QueryTruth& t = it->second;
    const Eigen::Vector3d kViewAxis = Eigen::Vector3d::UnitZ();
    if (t.cam_from_world) {
      q.true_center = t.cam_from_world->center();
      q.true_view_direction = t.cam_from_world->rotation.conjugate() * kViewAxis;
      note_frame("segment");
    } else {
      q.true_center = t.center;
      note_frame("enu");
    }
    if (r.segment >= 0) {
      if (t.cam_from_world) {
        q.pose_position_error = position_error(r.cam_from_segment, *t.cam_from_world);
        q.pose_rotation_error = rotation_error_deg(r.cam_from_segment, *t.cam_from_world);
      } else if (t.center && r.center_enu) {
        q.pose_position_error = (*r.center_enu - *t.center).norm();
        q.uncertainty_in_metres = true;
      }
    }
    if (r.registered) {
      q.estimated_center = t.cam_from_world ? std::optional<Eigen::Vector3d>(r.cam_from_segment.center()) : r.center_enu;
      if (t.cam_from_world) q.estimated_view_direction = r.cam_from_segment.rotation.conjugate() * kViewAxis;
      q.position_error = q.pose_position_error;
      q.rotation_error = q.pose_rotation_error;
      q.wrong = q.position_error > rule.position_m || q.rotation_error > rule.rotation_deg;
      rep.wrong_positives += q.wrong;
    }
    ++rep.queries;
    rep.registered += r.registered;
    rep.per_query.push_back(q);
  }
  for (const auto& r : negative_results) {
    QueryEvaluation q;
    common(r, &q);
    q.negative = true;
    q.wrong = r.registered;
    ++rep.negatives;
    rep.negatives_registered += r.registered;
    rep.per_query.push_back(q);
  }
  return rep;
}

std::vector<PrecisionRecallPoint> EvaluationReport::confidence_curve() const {
  std::vector<double> scores;
  std::vector<bool> right;
  for (const auto& q : per_query) {
    if (!q.confidence_features || q.inliers < min_inliers) continue;
    scores.push_back(q.confidence);
    right.push_back(pose_is_right(q, rule));
  }
  return precision_recall_curve(scores, right, queries);
}

nlohmann::json EvaluationReport::to_json(const std::vector<LocalizationResult>& results,
                                         const nlohmann::json& context) const {
  std::vector<double> pos, rot;
  for (const auto& q : per_query) {
    if (q.position_error >= 0) pos.push_back(q.position_error);
    if (q.rotation_error >= 0) rot.push_back(q.rotation_error);
  }
  auto count_under = [&](double m) {
    return std::count_if(pos.begin(), pos.end(), [m](double e) { return e < m; });
  };
  nlohmann::json recall = nlohmann::json::object();
  for (auto [m, d] : std::vector<std::pair<double, double>>{{0.25, 2}, {0.5, 5}, {5, 10}}) {
    size_t n = 0;
    for (const auto& q : per_query)
      if (q.position_error >= 0 && q.position_error < m && (q.rotation_error < 0 || q.rotation_error < d)) ++n;
    recall[Plot::fmt(m) + "m_" + Plot::fmt(d) + "deg"] = queries ? double(n) / queries : 0.0;
  }
  std::vector<double> t_feat, t_ret, t_match, t_ransac, t_total;
  for (const auto& r : results) {
    t_feat.push_back(r.times.features);
    t_ret.push_back(r.times.retrieval);
    t_match.push_back(r.times.matching);
    t_ransac.push_back(r.times.ransac);
    t_total.push_back(r.times.total);
  }
  nlohmann::json j = context;
  j["queries"] = queries;
  j["registered"] = registered;
  j["registration_rate"] = queries ? double(registered) / queries : 0.0;
  j["position_error_m"] = stats(pos);
  j["rotation_error_deg"] = stats(rot);
  j["count_under_m"] = {{"0.25", count_under(0.25)}, {"0.5", count_under(0.5)}, {"1", count_under(1)},
                        {"5", count_under(5)},       {"9", count_under(9)},     {"18.3", count_under(18.3)},
                        {"400", count_under(400)}};
  j["recall"] = recall;
  j["median_times_ms"] = {{"features", quantile(t_feat, 0.5)},  {"retrieval", quantile(t_ret, 0.5)},
                          {"matching", quantile(t_match, 0.5)}, {"ransac", quantile(t_ransac, 0.5)},
                          {"total", quantile(t_total, 0.5)}};
  j["median_ms_excluding_features"] = quantile(
      [&] {
        std::vector<double> v;
        for (const auto& r : results) v.push_back(r.times.total - r.times.features);
        return v;
      }(),
      0.5);
  j["peak_memory_bytes"] = peak_memory_bytes();
  // Wrong poses apart from misses.
  j["wrong_poses"] = {{"positives", wrong_positives},
                      {"negatives", negatives_registered},
                      {"total", wrong_positives + negatives_registered},
                      {"rule", {{"position_m", rule.position_m}, {"rotation_deg", rule.rotation_deg}}}};
  j["negatives"] = {{"queries", negatives}, {"registered", negatives_registered}};
  add_gate_counts(per_query, rule, min_confidence, min_inliers, j);
  // Uncertainty: the fraction of the registered positives' errors within 1σ and 2σ.
  {
    size_t n = 0, in1 = 0, in2 = 0;
    std::vector<double> sigmas;
    for (const auto& q : per_query) {
      if (q.negative || !q.registered || !q.uncertainty.valid || q.position_error < 0) continue;
      const double sigma = q.uncertainty_in_metres ? q.uncertainty.position_sigma_m.value_or(-1)
                                                   : q.uncertainty.position_sigma;
      if (!(sigma >= 0)) continue;
      ++n;
      in1 += q.position_error <= sigma;
      in2 += q.position_error <= 2 * sigma;
      sigmas.push_back(sigma);
    }
    j["uncertainty"] = {
        {"sigma_scale", ConfidenceModel::builtin().sigma_scale},
        {"sigma_scale_with_point_uncertainty", ConfidenceModel::builtin().sigma_scale_with_point_uncertainty},
        {"registered_with_sigma", n},
        {"within_1_sigma", n ? double(in1) / n : 0.0},
        {"within_2_sigma", n ? double(in2) / n : 0.0},
        {"median_position_sigma", stats(sigmas).is_null() ? nlohmann::json() : stats(sigmas)["median"]}};
  }
  nlohmann::json per = nlohmann::json::array();
  for (const auto& q : per_query) {
    nlohmann::json e = {{"image", q.image},
                        {"registered", q.registered},
                        {"wrong", q.wrong},
                        {"inliers", q.inliers},
                        {"confidence", q.confidence},
                        {"position_error_m", q.position_error},
                        {"rotation_error_deg", q.rotation_error}};
    if (q.negative) e["negative"] = true;
    if (q.under_street) e["under_street"] = true;
    auto vec = [](const Eigen::Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); };
    if (q.true_center) e["true_center"] = vec(*q.true_center);
    if (q.estimated_center) e["estimated_center"] = vec(*q.estimated_center);
    if (q.true_view_direction) e["true_view_direction"] = vec(*q.true_view_direction);
    if (q.estimated_view_direction) e["estimated_view_direction"] = vec(*q.estimated_view_direction);
    e["segment"] = q.segment;
    e["times_ms"] = {{"features", q.times.features}, {"retrieval", q.times.retrieval},
                     {"matching", q.times.matching}, {"ransac", q.times.ransac}, {"total", q.times.total}};
    if (q.confidence_features) e["confidence_features"] = q.confidence_features->to_json();
    if (q.pose_position_error >= 0) e["pose_position_error_m"] = q.pose_position_error;
    if (q.uncertainty_in_metres) e["error_frame"] = "enu";  // else the segment's (pose truth)
    if (q.pose_rotation_error >= 0) e["pose_rotation_error_deg"] = q.pose_rotation_error;
    if (q.uncertainty.valid) {
      e["position_sigma"] = q.uncertainty.position_sigma;
      e["rotation_sigma_deg"] = q.uncertainty.rotation_sigma_deg;
      if (q.uncertainty.position_sigma_m) e["position_sigma_m"] = *q.uncertainty.position_sigma_m;
      if (q.uncertainty.relative_position_sigma > 0)
        e["relative_position_sigma"] = q.uncertainty.relative_position_sigma;
      e["sigma_scale"] = q.uncertainty.sigma_scale;
      e["map_point_uncertainty"] = q.uncertainty.map_point_uncertainty;
    }
    per.push_back(e);
  }
  j["per_query"] = per;
  j["frame"] = frame;
  return j;
}

namespace {

// The part of segment a-b inside the plot's axes (Liang-Barsky), if any.
std::optional<std::pair<Eigen::Vector2d, Eigen::Vector2d>> clip_to(const Plot& plot, const Eigen::Vector2d& a,
                                                                   const Eigen::Vector2d& b) {
  double t0 = 0, t1 = 1;
  const Eigen::Vector2d d = b - a;
  const double p[4] = {-d.x(), d.x(), -d.y(), d.y()};
  const double q[4] = {a.x() - plot.x0, plot.x1 - a.x(), a.y() - plot.y0, plot.y1 - a.y()};
  for (int i = 0; i < 4; ++i) {
    if (p[i] == 0) {
      if (q[i] < 0) return std::nullopt;
      continue;
    }
    const double r = q[i] / p[i];
    if (p[i] < 0) t0 = std::max(t0, r);
    else t1 = std::min(t1, r);
    if (t0 > t1) return std::nullopt;
  }
  return std::make_pair(Eigen::Vector2d(a + t0 * d), Eigen::Vector2d(a + t1 * d));
}

// Top view (x-y; z up) of the queries: truth (green), estimate (red), wrong
// poses (magenta ring), misses (black cross at the truth); over the map's
// points and segment outlines when the map can be drawn in the report's frame.
// Returns why the map is not drawn ("" when it is, or when no map was given).
std::string write_top_view(const std::filesystem::path& stem, const EvaluationReport& report,
                           const std::filesystem::path& map_dir) {
  std::optional<MapOverview> overview;
  std::string map_note;
  if (!map_dir.empty() && (report.frame == "segment" || report.frame == "enu")) {
    try {
      MapOverviewOptions o;
      o.max_points = 20000;
      o.frame = report.frame == "enu" ? OverviewFrame::kEnu : OverviewFrame::kSegment;
      overview = load_map_overview(Map::open(map_dir), o);
    } catch (const Error& ex) {
      map_note = ex.what();
    }
  } else if (!map_dir.empty()) {
    map_note = "the report mixes or lacks truth frames (" + (report.frame.empty() ? std::string("none") : report.frame) + ")";
  }
  const Eigen::Matrix3d A = overview ? overview->aligned_from_frame : Eigen::Matrix3d::Identity();
  std::vector<Eigen::Vector2d> extent;
  for (const auto& q : report.per_query)
    for (const auto& c : {q.true_center, q.estimated_center})
      if (c) extent.push_back((A * *c).head<2>());
  if (overview) {
    // The map's 5th-95th percentile box, so that stray points do not shrink the streets.
    std::vector<double> xs, ys;
    for (size_t i = 0; i < overview->num_points(); ++i) {
      xs.push_back(overview->xyz[3 * i] + overview->origin.x());
      ys.push_back(overview->xyz[3 * i + 1] + overview->origin.y());
    }
    for (const auto& c : overview->cameras) {
      xs.push_back(c.center.x());
      ys.push_back(c.center.y());
    }
    if (!xs.empty()) {
      std::sort(xs.begin(), xs.end());
      std::sort(ys.begin(), ys.end());
      extent.emplace_back(quantile(xs, 0.05), quantile(ys, 0.05));
      extent.emplace_back(quantile(xs, 0.95), quantile(ys, 0.95));
    }
  }
  double ax = INFINITY, bx = -INFINITY, ay = INFINITY, by = -INFINITY;
  for (const auto& p : extent) {
    ax = std::min(ax, p.x()), bx = std::max(bx, p.x());
    ay = std::min(ay, p.y()), by = std::max(by, p.y());
  }
  if (!std::isfinite(ax)) ax = ay = 0, bx = by = 1;
  const double span = std::max({bx - ax, by - ay, 1.0}) * 1.1;
  const double cx = 0.5 * (ax + bx), cy = 0.5 * (ay + by);
  const std::string frame_name = report.frame == "enu" ? "east, north (m)" : "x, y (m; z up)";
  Plot top(overview ? "Top view over the map (grey points, segment outlines)" : "Top view", frame_name, "",
           cx - span / 2, cx + span / 2, cy - span / 2, cy + span / 2);
  auto inside = [&](double x, double y) {
    return x >= top.x0 && x <= top.x1 && y >= top.y0 && y <= top.y1;
  };
  if (overview) {
    for (size_t i = 0; i < overview->num_points(); ++i) {
      const double x = overview->xyz[3 * i] + overview->origin.x(), y = overview->xyz[3 * i + 1] + overview->origin.y();
      if (inside(x, y)) top.point(x, y, "#ccc", {204, 204, 204}, 1);
    }
    static const char* kColors[] = {"#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#17becf", "#bcbd22"};
    static const cv::Scalar kBgr[] = {{180, 119, 31}, {14, 127, 255}, {189, 103, 148},
                                      {75, 86, 140},  {207, 190, 23}, {34, 189, 188}};
    for (size_t s = 0; s < overview->segments.size(); ++s) {
      const auto& outline = overview->segments[s].outline;
      if (outline.empty()) continue;
      Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
      for (size_t k = 0; k < outline.size(); ++k) {
        const auto& a = outline[k];
        const auto& b = outline[(k + 1) % outline.size()];
        if (auto clipped = clip_to(top, a, b)) top.line(clipped->first.x(), clipped->first.y(), clipped->second.x(),
                                                         clipped->second.y(), kColors[s % 6], kBgr[s % 6]);
        centroid += a;
      }
      centroid /= static_cast<double>(outline.size());
      if (inside(centroid.x(), centroid.y()))
        top.label(centroid.x(), centroid.y(), std::to_string(overview->segments[s].id), -4, 4);
    }
  }
  for (const auto& q : report.per_query) {
    const std::optional<Eigen::Vector3d> t = q.true_center ? std::optional<Eigen::Vector3d>(A * *q.true_center) : std::nullopt;
    const std::optional<Eigen::Vector3d> e =
        q.estimated_center ? std::optional<Eigen::Vector3d>(A * *q.estimated_center) : std::nullopt;
    if (t) top.point(t->x(), t->y(), "#2ca02c", {44, 160, 44});
    if (e) {
      if (t) top.line(t->x(), t->y(), e->x(), e->y(), "#999", {150, 150, 150});
      top.point(e->x(), e->y(), "#d62728", {40, 39, 214}, 2);
      if (q.wrong) {
        top.svg << "<circle cx='" << top.px(e->x()) << "' cy='" << top.py(e->y())
                << "' r='7' fill='none' stroke='#e377c2' stroke-width='2'/>\n";
        cv::circle(top.png, {int(top.px(e->x())), int(top.py(e->y()))}, 7, {194, 119, 227}, 2, cv::LINE_AA);
      }
    } else if (t && !q.negative) {  // a miss
      const double d = span / 120;
      top.line(t->x() - d, t->y() - d, t->x() + d, t->y() + d, "#000", {0, 0, 0});
      top.line(t->x() - d, t->y() + d, t->x() + d, t->y() - d, "#000", {0, 0, 0});
    }
  }
  top.label(top.x0, top.y0, "green: truth, red: estimate, ring: wrong pose, x: miss", 6, -8);
  top.save(stem);
  return map_note;
}

}  // namespace

void write_report(const std::filesystem::path& dir, const EvaluationReport& report,
                  const std::vector<LocalizationResult>& results, const nlohmann::json& context,
                  const std::filesystem::path& map_dir) {
  std::filesystem::create_directories(dir);
  const nlohmann::json j = report.to_json(results, context);
  write_file_atomic(dir / "report.json", j.dump(2));

  std::ostringstream md;
  auto num = [](const nlohmann::json& v, int prec = 3) {
    if (v.is_null()) return std::string("–");
    std::ostringstream s;
    s << std::setprecision(prec) << v.get<double>();
    return s.str();
  };
  md << "# visloc evaluation\n\n"
     << "| queries | registered | rate | median pos. error (m) | q25–q75 (m) | median rot. error (°) |\n"
     << "|---|---|---|---|---|---|\n"
     << "| " << j["queries"] << " | " << j["registered"] << " | " << num(j["registration_rate"]) << " | "
     << (j["position_error_m"].is_null() ? "–" : num(j["position_error_m"]["median"])) << " | "
     << (j["position_error_m"].is_null() ? "–"
                                          : num(j["position_error_m"]["q25"]) + "–" + num(j["position_error_m"]["q75"]))
     << " | " << (j["rotation_error_deg"].is_null() ? "–" : num(j["rotation_error_deg"]["median"])) << " |\n\n"
     << "Recall: ";
  for (auto& [k, v] : j["recall"].items()) md << k << " " << num(v) << "; ";
  md << "\n\nCounts under: ";
  for (auto& [k, v] : j["count_under_m"].items()) md << k << " m: " << v << "; ";
  md << "\n\nMedian times (ms): ";
  for (auto& [k, v] : j["median_times_ms"].items()) md << k << " " << num(v, 4) << "; ";
  md << "excluding features " << num(j["median_ms_excluding_features"], 4) << ".\n\nPeak memory: "
     << j["peak_memory_bytes"].get<uint64_t>() / (1024 * 1024) << " MiB.\n\n";
  if (j.contains("queries_with_given_intrinsics"))
    md << "Intrinsics from the --intrinsics list for " << j["queries_with_given_intrinsics"] << " of " << j["queries"]
       << " queries.\n\n";
  md << "Wrong poses (registered more than " << num(j["wrong_poses"]["rule"]["position_m"]) << " m or "
     << num(j["wrong_poses"]["rule"]["rotation_deg"])
     << "° from the truth, or a registered negative): " << j["wrong_poses"]["total"] << " ("
     << j["wrong_poses"]["positives"] << " of the queries, " << j["wrong_poses"]["negatives"] << " of "
     << j["negatives"]["queries"] << " negatives); misses: " << (report.queries - report.registered) << ".\n\n"
     << "Confidence threshold " << num(j["confidence"]["min_confidence"]) << ": it turned away "
     << j["confidence"]["rejected_wrong_poses"] << " wrong and " << j["confidence"]["rejected_right_poses"]
     << " right poses that had at least " << j["confidence"]["min_inliers"] << " inliers; the under-street check "
     << j["under_street"]["rejected_wrong_poses"] << " wrong and " << j["under_street"]["rejected_right_poses"]
     << " right ones above the threshold.\n\n"
     << "Uncertainty: of " << j["uncertainty"]["registered_with_sigma"] << " registered queries, "
     << num(j["uncertainty"]["within_1_sigma"]) << " have their position error within 1σ and "
     << num(j["uncertainty"]["within_2_sigma"]) << " within 2σ (median σ "
     << num(j["uncertainty"]["median_position_sigma"]) << ").\n\n"
     << "![cumulative error](error_curve.png) ![top view](top_view.png) "
        "![precision-recall of the confidence](precision_recall.png)\n";
  write_file_atomic(dir / "report.md", md.str());

  // Cumulative position error curve (fraction of all queries), with the
  // thresholds the report counts under: 0.25 / 0.5 / 5 m (the recall
  // thresholds) and the paper's 18.3 m, where they fall on the axis.
  std::vector<double> pos;
  for (const auto& q : report.per_query)
    if (q.position_error >= 0) pos.push_back(q.position_error);
  std::sort(pos.begin(), pos.end());
  const double xmax = pos.empty() ? 1.0 : std::max(0.1, quantile(pos, 0.95) * 1.2);
  Plot curve("Cumulative position error", "position error (m)", "fraction of queries", 0, xmax, 0, 1);
  int shown = 0;
  std::string under_text = "under";
  for (const double threshold : {0.25, 0.5, 5.0, 18.3}) {
    const double under = static_cast<double>(std::count_if(pos.begin(), pos.end(), [&](double e) { return e < threshold; })) /
                         static_cast<double>(std::max<size_t>(1, report.queries));
    under_text += " " + Plot::fmt(threshold) + " m: " + Plot::fmt(100 * under) + "%" + (threshold < 18 ? ";" : "");
    if (threshold > xmax) continue;  // off the axis: in the text line only
    curve.line(threshold, 0, threshold, 1, "#bbb", {187, 187, 187});
    curve.label(threshold, 1, Plot::fmt(threshold) + " m", 3, 12 + 14 * (shown++ % 3));
  }
  curve.label(0, 0.06, under_text, 8, 0);
  curve.cumulative_steps(pos, double(std::max<size_t>(1, report.queries)), xmax);
  curve.save(dir / "error_curve");
  const std::string top_view_note = write_top_view(dir / "top_view", report, map_dir);
  if (!top_view_note.empty()) {
    md << "\nTop view: the map is not drawn under the queries (" << top_view_note << ").\n";
    write_file_atomic(dir / "report.md", md.str());
  }

  plot_precision_recall(dir / "precision_recall", "Confidence: precision-recall (threshold marked)",
                        report.confidence_curve(), report.min_confidence);
}

}  // namespace visloc
