#include "visloc/viewer/viewer.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "visloc/map/map.h"
#include "visloc/util/base64.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/viewer/viewer_assets.h"

namespace visloc {
namespace fs = std::filesystem;

void ViewerOptions::validate() const {
  if (max_points < 1) throw_error(ErrorCode::kInvalidArgument, "viewer option max_points = 0: must be at least 1");
}

nlohmann::json ViewerSummary::to_json() const {
  return {{"points_drawn", points_drawn}, {"points_in_map", points_in_map}, {"points_far", points_far}, {"cameras", cameras},
          {"segments", segments},         {"queries", queries},             {"file_bytes", file_bytes},
          {"frame", frame},               {"three_version", three_version}};
}

std::string ViewerSummary::to_text(const fs::path& out, bool with_report) const {
  std::string text = "wrote " + out.string() + ": " + std::to_string(points_drawn) + " of " +
                     std::to_string(points_in_map) + " points, " + std::to_string(cameras) + " cameras, " +
                     std::to_string(segments) + " segments";
  if (with_report) text += ", " + std::to_string(queries) + " queries";
  return text + " (" + frame + " frame; " + std::to_string(file_bytes / 1024) + " KiB, three.js " + three_version + ")";
}

namespace {

struct ReportQueries {
  std::string frame;  // "segment", "enu", "mixed" or "" (no positives)
  std::vector<nlohmann::json> queries;
};

ReportQueries read_report(const fs::path& report_dir) {
  const fs::path path = fs::is_directory(report_dir) ? report_dir / "report.json" : report_dir;
  if (!fs::is_regular_file(path))
    throw_error(ErrorCode::kNotFound, path.string(), ": no report.json (give the folder `visloc eval --out` wrote)");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(read_file(path));
  } catch (const nlohmann::json::exception& ex) {
    throw_error(ErrorCode::kFormat, path.string(), ": not valid JSON (", ex.what(), ")");
  }
  if (!j.is_object() || !j.contains("per_query") || !j["per_query"].is_array())
    throw_error(ErrorCode::kFormat, path.string(), ": no per_query array (is it a `visloc eval` report?)");
  if (!j.contains("frame") || !j["frame"].is_string())
    throw_error(ErrorCode::kFormat, path.string(),
                ": no frame and no query centres: not a `visloc eval` report (a `bench city` report has its own "
                "format), or one written before `visloc view` existed (run `visloc eval` again)");
  ReportQueries out;
  out.frame = j["frame"].get<std::string>();
  for (size_t i = 0; i < j["per_query"].size(); ++i) {
    const nlohmann::json& q = j["per_query"][i];
    const std::string where = "per_query[" + std::to_string(i) + "]";
    if (!q.is_object() || !q.contains("image") || !q["image"].is_string())
      throw_error(ErrorCode::kFormat, path.string(), ": ", where, " has no image name");
    for (const char* key : {"true_center", "estimated_center", "true_view_direction", "estimated_view_direction"}) {
      if (!q.contains(key)) continue;
      const auto& v = q[key];
      if (!v.is_array() || v.size() != 3 || !std::all_of(v.begin(), v.end(), [](const nlohmann::json& x) {
            return x.is_number() && std::isfinite(x.get<double>());
          }))
        throw_error(ErrorCode::kFormat, path.string(), ": ", where, ".", key, " is not 3 finite numbers");
    }
    out.queries.push_back(q);
  }
  return out;
}

Eigen::Vector3d vec3(const nlohmann::json& v) { return {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()}; }
nlohmann::json json3(const Eigen::Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); }

// 1, 2 or 5 × 10^k, the smallest not below x.
double round_up_nice(double x) {
  const double p = std::pow(10.0, std::floor(std::log10(std::max(x, 1e-6))));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * p >= x * (1 - 1e-9)) return m * p;
  return 10 * p;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

std::string html_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '&': out += "&amp;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

// JSON inside <script>: no '<', '>' or '&' at all ("</script>" would close
// the element, "<!--" with "<script" would keep it open), written as JSON's
// \u escapes; they occur only inside strings.
std::string script_safe(const std::string& json) {
  std::string out;
  out.reserve(json.size());
  for (char c : json) {
    if (c == '<') out += "\\u003c";
    else if (c == '>') out += "\\u003e";
    else if (c == '&') out += "\\u0026";
    else out += c;
  }
  return out;
}

std::string data_url(std::string_view javascript) {
  return "data:text/javascript;base64," + base64_encode(javascript.data(), javascript.size());
}

// Fills @NAME@ placeholders in one pass over the template (what is inserted
// is never scanned again).
std::string fill(std::string_view tpl, const std::vector<std::pair<std::string, std::string>>& values) {
  std::string out;
  size_t at = 0;
  while (at < tpl.size()) {
    const size_t open = tpl.find('@', at);
    if (open == std::string_view::npos) break;
    bool replaced = false;
    for (const auto& [name, value] : values) {
      const std::string key = "@" + name + "@";
      if (tpl.substr(open, key.size()) == key) {
        out.append(tpl.substr(at, open - at));
        out += value;
        at = open + key.size();
        replaced = true;
        break;
      }
    }
    if (!replaced) {
      out.append(tpl.substr(at, open + 1 - at));
      at = open + 1;
    }
  }
  out.append(tpl.substr(std::min(at, tpl.size())));
  return out;
}

}  // namespace

namespace {

OverviewFrame choose_frame(OverviewFrame asked, const std::optional<ReportQueries>& report, const fs::path& report_dir) {
  if (report && (report->frame == "segment" || report->frame == "enu")) {
    const OverviewFrame report_frame = report->frame == "enu" ? OverviewFrame::kEnu : OverviewFrame::kSegment;
    if (asked == OverviewFrame::kAuto) return report_frame;
    if (asked != report_frame)
      throw_error(ErrorCode::kInvalidArgument, "visloc view: frame ", overview_frame_name(asked),
                  " was asked, but the report's centres are in the ", report->frame, " frame");
  } else if (report && report->frame == "mixed") {
    throw_error(ErrorCode::kFormat, report_dir.string(),
                ": the report mixes pose truth (segment frame) and GPS truth (ENU); it cannot be drawn in one frame");
  }
  return asked;
}

// The report's queries in the aligned frame (absolute; made relative later).
nlohmann::json aligned_queries(const std::optional<ReportQueries>& report, const Eigen::Matrix3d& A) {
  nlohmann::json queries = nlohmann::json::array();
  if (!report) return queries;
  for (nlohmann::json q : report->queries) {
    for (const char* key : {"true_center", "estimated_center", "true_view_direction", "estimated_view_direction"})
      if (q.contains(key)) q[key] = json3(A * vec3(q[key]));
    q.erase("confidence_features");
    queries.push_back(std::move(q));
  }
  return queries;
}

Eigen::Vector3d overview_point(const MapOverview& ov, size_t i) {
  return Eigen::Vector3d(ov.xyz[3 * i], ov.xyz[3 * i + 1], ov.xyz[3 * i + 2]) + ov.origin;
}

// What the page is framed on: the 5th-95th percentiles of the points, every
// camera and query (stray points do not shrink the view), the origin at the
// centre; the view turns around the cameras and queries (the streets).
struct SceneBox {
  Eigen::Vector3d lo, hi, origin, view_centre;
  double lowest_camera = std::numeric_limits<double>::infinity();  // absolute z; ∞ without cameras
  double extent = 1;
};

SceneBox scene_box(const MapOverview& ov, const nlohmann::json& queries) {
  SceneBox b;
  b.lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  b.hi = -b.lo;
  auto grow = [&](const Eigen::Vector3d& p) {
    b.lo = b.lo.cwiseMin(p);
    b.hi = b.hi.cwiseMax(p);
  };
  if (ov.num_points() > 0) {
    std::vector<double> axis(ov.num_points());
    Eigen::Vector3d robust_lo, robust_hi;
    for (int k = 0; k < 3; ++k) {
      for (size_t i = 0; i < ov.num_points(); ++i) axis[i] = overview_point(ov, i)[k];
      robust_lo[k] = percentile(axis, 0.05);
      robust_hi[k] = percentile(axis, 0.95);
    }
    grow(robust_lo);
    grow(robust_hi);
  }
  Eigen::Vector3d cam_lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), cam_hi = -cam_lo;
  auto grow_cameras = [&](const Eigen::Vector3d& p) {
    grow(p);
    cam_lo = cam_lo.cwiseMin(p);
    cam_hi = cam_hi.cwiseMax(p);
  };
  for (const auto& c : ov.cameras) grow_cameras(c.center);
  for (const auto& c : ov.cameras) b.lowest_camera = std::min(b.lowest_camera, c.center.z());
  for (const auto& q : queries)
    for (const char* key : {"true_center", "estimated_center"})
      if (q.contains(key)) grow_cameras(vec3(q[key]));
  if (!std::isfinite(b.lo.x())) b.lo = b.hi = Eigen::Vector3d::Zero();
  b.origin = 0.5 * (b.lo + b.hi);
  b.view_centre = std::isfinite(cam_lo.x()) ? Eigen::Vector3d(0.5 * (cam_lo + cam_hi)) : b.origin;
  b.extent = std::max({b.hi.x() - b.lo.x(), b.hi.y() - b.lo.y(), 1.0});
  return b;
}

// Points, quantized to 16 bits per axis over the view's box widened by its
// own size on every side (and at least 10 m): a stray point kilometres away
// (SfM outliers) would otherwise make the step metres. Points beyond that
// box are not drawn (`far_not_drawn` counts them).
nlohmann::json encode_points(const MapOverview& ov, const SceneBox& b, size_t* drawn, size_t* far) {
  const Eigen::Vector3d margin = (b.hi - b.lo).cwiseMax(Eigen::Vector3d::Constant(10.0));
  const Eigen::Vector3d box_lo = b.lo - margin, box_hi = b.hi + margin;
  const Eigen::Vector3d step = ((box_hi - box_lo) / 65535.0).cwiseMax(Eigen::Vector3d::Constant(1e-6));
  std::vector<uint16_t> quantized, segment;
  quantized.reserve(ov.xyz.size());
  segment.reserve(ov.num_points());
  *far = 0;
  for (size_t i = 0; i < ov.num_points(); ++i) {
    const Eigen::Vector3d p = overview_point(ov, i);
    if ((p.array() < box_lo.array()).any() || (p.array() > box_hi.array()).any()) {
      ++*far;
      continue;
    }
    for (int k = 0; k < 3; ++k)
      quantized.push_back(static_cast<uint16_t>(std::clamp(std::round((p[k] - box_lo[k]) / step[k]), 0.0, 65535.0)));
    segment.push_back(static_cast<uint16_t>(ov.point_segment[i]));
  }
  *drawn = segment.size();
  return {{"count", segment.size()},
          {"far_not_drawn", *far},
          {"in_map", ov.total_points},
          {"min", json3(box_lo - b.origin)},
          {"step", json3(step)},
          {"xyz_u16", base64_encode(quantized.data(), quantized.size() * sizeof(uint16_t))},
          {"segment_u16", base64_encode(segment.data(), segment.size() * sizeof(uint16_t))}};
}

// Cameras: centre (3), world_from_camera columns (9), width, height, focal,
// segment index: 16 floats each.
nlohmann::json encode_cameras(const MapOverview& ov, const Eigen::Vector3d& origin) {
  std::vector<float> cameras;
  cameras.reserve(16 * ov.cameras.size());
  for (const auto& c : ov.cameras) {
    const Eigen::Vector3d p = c.center - origin;
    for (int k = 0; k < 3; ++k) cameras.push_back(static_cast<float>(p[k]));
    for (int col = 0; col < 3; ++col)
      for (int k = 0; k < 3; ++k) cameras.push_back(static_cast<float>(c.world_from_camera(k, col)));
    cameras.insert(cameras.end(), {static_cast<float>(c.width), static_cast<float>(c.height),
                                   static_cast<float>(c.focal), static_cast<float>(c.segment)});
  }
  return {{"count", ov.cameras.size()}, {"data_f32", base64_encode(cameras.data(), cameras.size() * sizeof(float))}};
}

// The grid's height (relative to the origin): the segments' ground, kept
// within a tenth of the extent below the lowest camera (triangulations below
// the street would sink it) and not above it.
double grid_height(const MapOverview& ov, const SceneBox& b) {
  double ground = std::numeric_limits<double>::infinity();
  for (const auto& s : ov.segments) ground = std::min(ground, s.ground_z - b.origin.z());
  if (!std::isfinite(ground)) ground = b.lo.z() - b.origin.z();
  if (std::isfinite(b.lowest_camera)) {
    const double lowest = b.lowest_camera - b.origin.z();
    ground = std::clamp(ground, lowest - 0.1 * b.extent, lowest);
  }
  return ground;
}

nlohmann::json encode_segments(const MapOverview& ov, const Eigen::Vector3d& origin, double ground) {
  nlohmann::json segments = nlohmann::json::array();
  for (const auto& s : ov.segments) {
    nlohmann::json outline = nlohmann::json::array();
    for (const auto& p : s.outline) outline.push_back({p.x() - origin.x(), p.y() - origin.y()});
    segments.push_back({{"id", s.id},
                        {"points", s.points},
                        {"points_shown", s.points_shown},
                        {"cameras", s.cameras},
                        {"outline", outline},
                        {"ground_z", ground}});  // outlines on the grid
  }
  return segments;
}

// The page: the template filled with the title, three.js and the data.
std::string assemble_page(const std::string& title, const nlohmann::json& data) {
  std::string module = std::string(viewer_assets::three_module());
  for (size_t at = 0; (at = module.find("'./three.core.js'", at)) != std::string::npos;)
    module.replace(at, 17, "'three/core'");
  return fill(viewer_assets::page_template(),
              {{"TITLE", html_escape(title)},
               {"THREE_MODULE", data_url(module)},
               {"THREE_CORE", data_url(viewer_assets::three_core())},
               {"DATA", script_safe(data.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace))},
               {"APP", std::string(viewer_assets::app_script())}});
}

}  // namespace

ViewerSummary write_viewer(const fs::path& map_dir, const fs::path& report_dir, const fs::path& out,
                           const ViewerOptions& options) {
  options.validate();
  if (!viewer_assets::available())
    throw_error(ErrorCode::kNotImplemented,
                "visloc view: this build has no three.js. Run `npm ci --prefix src/visloc/viewer` (scripts/setup.sh "
                "does it), then configure and build again");
  if (out.empty()) throw_error(ErrorCode::kInvalidArgument, "visloc view: an output file (--out) is needed");
  std::optional<ReportQueries> report;
  if (!report_dir.empty()) report = read_report(report_dir);
  MapOverviewOptions mo;
  mo.max_points = options.max_points;
  mo.frame = choose_frame(options.frame, report, report_dir);
  const MapOverview ov = load_map_overview(Map::open(map_dir), mo);
  if (ov.segments.size() > 65536)
    throw_error(ErrorCode::kInvalidArgument, "visloc view: ", ov.segments.size(), " segments; at most 65,536 can be drawn");

  nlohmann::json queries = aligned_queries(report, ov.aligned_from_frame);
  const SceneBox box = scene_box(ov, queries);
  for (auto& q : queries)
    for (const char* key : {"true_center", "estimated_center"})
      if (q.contains(key)) q[key] = json3(vec3(q[key]) - box.origin);
  ViewerSummary summary;
  const nlohmann::json points = encode_points(ov, box, &summary.points_drawn, &summary.points_far);
  const double ground = grid_height(ov, box);
  const double spacing = round_up_nice(box.extent / 12);
  const Eigen::Vector3d lo = box.lo - box.origin, hi = box.hi - box.origin;

  std::string map_name = map_dir.filename().string();
  if (map_name.empty()) map_name = map_dir.parent_path().filename().string();  // "maps/city/"
  std::string title = options.title;
  if (title.empty()) title = "visloc: " + map_name + (report ? " + report" : "");
  const nlohmann::json data = {
      {"title", title},
      {"frame", overview_frame_name(ov.frame)},
      {"north", ov.north ? json3(*ov.north) : nlohmann::json()},
      {"origin_in_frame", json3(ov.aligned_from_frame.transpose() * box.origin)},
      {"extent", box.extent},
      {"view_target", json3(box.view_centre - box.origin)},
      {"ground_z", ground},
      {"grid_spacing", spacing},
      {"grid_box",
       {std::floor(lo.x() / spacing - 1) * spacing, std::floor(lo.y() / spacing - 1) * spacing,
        std::ceil(hi.x() / spacing + 1) * spacing, std::ceil(hi.y() / spacing + 1) * spacing}},
      {"camera_depth", std::clamp(box.extent * 0.025, 0.1, 8.0)},
      {"query_marker_radius", std::clamp(box.extent * 0.008, 0.05, 5.0)},
      {"points", points},
      {"cameras", encode_cameras(ov, box.origin)},
      {"segments", encode_segments(ov, box.origin, ground)},
      {"has_report", report.has_value()},
      {"queries", queries}};
  const std::string page = assemble_page(title, data);
  if (out.has_parent_path()) fs::create_directories(out.parent_path());
  write_file_atomic(out, page);

  summary.points_in_map = ov.total_points;
  summary.cameras = ov.cameras.size();
  summary.segments = ov.segments.size();
  summary.queries = queries.size();
  summary.file_bytes = page.size();
  summary.frame = overview_frame_name(ov.frame);
  summary.three_version = viewer_assets::three_version();
  return summary;
}

}  // namespace visloc
