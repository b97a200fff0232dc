#include "visloc/eval/evaluation.h"

#include <sys/resource.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>

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
                          const std::map<std::string, QueryTruth>& truth) {
  EvaluationReport rep;
  for (const auto& r : results) {
    auto it = truth.find(r.image);
    if (it == truth.end()) continue;
    QueryEvaluation q;
    q.image = r.image;
    q.registered = r.registered;
    const QueryTruth& t = it->second;
    if (t.cam_from_world) q.true_center = t.cam_from_world->center();
    else q.true_center = t.center;
    if (r.registered) {
      if (t.cam_from_world) {
        q.estimated_center = r.cam_from_segment.center();
        q.position_error = position_error(r.cam_from_segment, *t.cam_from_world);
        q.rotation_error = rotation_error_deg(r.cam_from_segment, *t.cam_from_world);
      } else if (t.center && r.center_enu) {
        q.estimated_center = r.center_enu;
        q.position_error = (*r.center_enu - *t.center).norm();
      }
    }
    ++rep.queries;
    rep.registered += r.registered;
    rep.per_query.push_back(q);
  }
  return rep;
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
  nlohmann::json per = nlohmann::json::array();
  for (const auto& q : per_query)
    per.push_back({{"image", q.image}, {"registered", q.registered}, {"position_error_m", q.position_error},
                   {"rotation_error_deg", q.rotation_error}});
  j["per_query"] = per;
  return j;
}

void write_report(const std::filesystem::path& dir, const EvaluationReport& report,
                  const std::vector<LocalizationResult>& results, const nlohmann::json& context) {
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
     << j["peak_memory_bytes"].get<uint64_t>() / (1024 * 1024) << " MiB.\n\n"
     << "![cumulative error](error_curve.png) ![top view](top_view.png)\n";
  write_file_atomic(dir / "report.md", md.str());

  // Cumulative position error curve (fraction of all queries).
  std::vector<double> pos;
  for (const auto& q : report.per_query)
    if (q.position_error >= 0) pos.push_back(q.position_error);
  std::sort(pos.begin(), pos.end());
  const double xmax = pos.empty() ? 1.0 : std::max(0.1, quantile(pos, 0.95) * 1.2);
  Plot curve("Cumulative position error", "position error (m)", "fraction of queries", 0, xmax, 0, 1);
  double prev_x = 0, prev_y = 0;
  for (size_t i = 0; i < pos.size(); ++i) {
    const double x = std::min(pos[i], xmax), y = double(i + 1) / std::max<size_t>(1, report.queries);
    curve.line(prev_x, prev_y, x, prev_y, "#1f77b4", {180, 119, 31}, 2);
    curve.line(x, prev_y, x, y, "#1f77b4", {180, 119, 31}, 2);
    prev_x = x;
    prev_y = y;
  }
  curve.line(prev_x, prev_y, xmax, prev_y, "#1f77b4", {180, 119, 31}, 2);
  curve.save(dir / "error_curve");

  // Top view: truth (green) and estimate (red), x-y plane of the truth frame.
  double ax = INFINITY, bx = -INFINITY, ay = INFINITY, by = -INFINITY;
  for (const auto& q : report.per_query)
    for (const auto& c : {q.true_center, q.estimated_center})
      if (c) {
        ax = std::min(ax, c->x()), bx = std::max(bx, c->x());
        ay = std::min(ay, c->y()), by = std::max(by, c->y());
      }
  if (!std::isfinite(ax)) ax = ay = 0, bx = by = 1;
  const double span = std::max({bx - ax, by - ay, 1.0}) * 1.1;
  const double cx = 0.5 * (ax + bx), cy = 0.5 * (ay + by);
  Plot top("Top view: truth (green), estimate (red)", "x (m)", "y (m)", cx - span / 2, cx + span / 2, cy - span / 2,
           cy + span / 2);
  for (const auto& q : report.per_query) {
    if (q.true_center) top.point(q.true_center->x(), q.true_center->y(), "#2ca02c", {44, 160, 44});
    if (q.estimated_center) {
      top.point(q.estimated_center->x(), q.estimated_center->y(), "#d62728", {40, 39, 214}, 2);
      if (q.true_center)
        top.line(q.true_center->x(), q.true_center->y(), q.estimated_center->x(), q.estimated_center->y(), "#999",
                 {150, 150, 150});
    }
  }
  top.save(dir / "top_view");
}

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace visloc
