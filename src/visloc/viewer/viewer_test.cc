// The viewer page on a planted map (no shared data, no COLMAP): what it
// embeds, the errors it gives, and, where Debian's chromium is installed,
// what a real browser draws from it.
#include <gtest/gtest.h>
#include <unistd.h>

#include <opencv2/imgcodecs.hpp>
#include <set>
#include <string>

#include "visloc/map_building/planted_map.h"
#include "visloc/sfm/process.h"
#include "visloc/util/base64.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"
#include "visloc/viewer/viewer.h"
#include "visloc/viewer/viewer_assets.h"

namespace visloc {
namespace {

namespace fs = std::filesystem;

constexpr size_t kPointsPerSegment = 300;

std::vector<PlantedSegment> planted_segments() {
  RandomGenerator rng(11);
  std::vector<PlantedSegment> segments;
  for (int k = 0; k < 3; ++k) segments.push_back(random_planted_segment(kPointsPerSegment, rng));
  return segments;
}

const std::vector<PlantedSegment>& segments() {
  static const std::vector<PlantedSegment> s = planted_segments();
  return s;
}

const PlantedMap& planted() {
  static const PlantedMap map("viewer", segments());
  return map;
}

// A report as `visloc eval` writes it (ENU centres, GPS truth): one right
// pose, one wrong pose, one miss, one registered negative.
fs::path write_report_dir(const std::string& frame = "enu") {
  const fs::path dir = unique_temp_path("visloc_viewer_report");
  fs::create_directories(dir);
  const nlohmann::json times = {{"features", 40.0}, {"retrieval", 1.0}, {"matching", 3.0}, {"ransac", 2.0}, {"total", 46.0}};
  nlohmann::json per = nlohmann::json::array();
  per.push_back({{"image", "right.jpg"}, {"registered", true}, {"wrong", false}, {"inliers", 80}, {"confidence", 0.99},
                 {"position_error_m", 0.05}, {"rotation_error_deg", -1}, {"true_center", {5, 30, 1.5}},
                 {"estimated_center", {5.03, 30.04, 1.5}}, {"segment", 0}, {"times_ms", times}});
  per.push_back({{"image", "wrong.jpg"}, {"registered", true}, {"wrong", true}, {"inliers", 14}, {"confidence", 0.6},
                 {"position_error_m", 40.0}, {"rotation_error_deg", -1}, {"true_center", {105, 30, 1.5}},
                 {"estimated_center", {145, 30, 1.5}}, {"segment", 1}, {"times_ms", times}});
  per.push_back({{"image", "miss.jpg"}, {"registered", false}, {"wrong", false}, {"inliers", 3}, {"confidence", 0.0},
                 {"position_error_m", -1}, {"rotation_error_deg", -1}, {"true_center", {205, 30, 1.5}},
                 {"segment", -1}, {"times_ms", times}});
  per.push_back({{"image", "negative.jpg"}, {"registered", true}, {"wrong", true}, {"negative", true}, {"inliers", 13},
                 {"confidence", 0.5}, {"position_error_m", -1}, {"rotation_error_deg", -1}, {"segment", 2},
                 {"times_ms", times}});
  const nlohmann::json report = {{"queries", 3}, {"registered", 2}, {"frame", frame}, {"per_query", per}};
  write_file_atomic(dir / "report.json", report.dump(2));
  return dir;
}

// The JSON block the page carries.
nlohmann::json page_data(const fs::path& html) {
  const std::string page = read_file(html);
  const std::string open = "<script type=\"application/json\" id=\"visloc-data\">";
  const size_t a = page.find(open);
  const size_t b = page.find("</script>", a);
  EXPECT_NE(a, std::string::npos);
  EXPECT_NE(b, std::string::npos);
  return nlohmann::json::parse(page.substr(a + open.size(), b - a - open.size()));
}

template <typename T>
std::vector<T> decode_array(const nlohmann::json& base64) {
  const auto bytes = base64_decode(base64.get<std::string>());
  EXPECT_TRUE(bytes.has_value());
  EXPECT_EQ(bytes->size() % sizeof(T), 0u);
  std::vector<T> out(bytes->size() / sizeof(T));
  std::memcpy(out.data(), bytes->data(), out.size() * sizeof(T));
  return out;
}

TEST(Viewer, PageCarriesTheMapInEnuAndTheReport) {
  if (!viewer_assets::available()) GTEST_SKIP() << "built without three.js (npm ci --prefix src/visloc/viewer)";
  const fs::path report = write_report_dir();
  const fs::path html = unique_temp_path("visloc_viewer_page.html");
  const ViewerSummary s = write_viewer(planted().dir(), report, html);
  EXPECT_EQ(s.points_drawn, 3 * kPointsPerSegment);
  EXPECT_EQ(s.points_in_map, 3 * kPointsPerSegment);
  EXPECT_EQ(s.cameras, 12u);
  EXPECT_EQ(s.segments, 3u);
  EXPECT_EQ(s.queries, 4u);
  EXPECT_EQ(s.frame, "enu");
  EXPECT_EQ(s.file_bytes, fs::file_size(html));
  EXPECT_EQ(s.three_version, "0.187.0");

  const nlohmann::json d = page_data(html);
  ASSERT_TRUE(d["north"].is_array());  // ENU: north is +y
  EXPECT_DOUBLE_EQ(d["north"][1].get<double>(), 1.0);
  EXPECT_TRUE(d["has_report"].get<bool>());
  // Every point comes back, within the 16-bit quantization, at its ENU position.
  const Eigen::Vector3d origin(d["origin_in_frame"][0], d["origin_in_frame"][1], d["origin_in_frame"][2]);
  const auto q = decode_array<uint16_t>(d["points"]["xyz_u16"]);
  const auto seg = decode_array<uint16_t>(d["points"]["segment_u16"]);
  ASSERT_EQ(q.size(), 3 * 3 * kPointsPerSegment);
  ASSERT_EQ(seg.size(), 3 * kPointsPerSegment);
  double worst = 0;
  for (size_t i = 0; i < seg.size(); ++i) {
    const size_t k = seg[i], j = i - k * kPointsPerSegment;
    ASSERT_LT(k, 3u);
    const Eigen::Vector3d expected = planted_enu_from_segment(static_cast<int>(k)).apply(segments()[k].xyz[j]);
    Eigen::Vector3d got;
    for (int a = 0; a < 3; ++a)
      got[a] = d["points"]["min"][a].get<double>() + q[3 * i + a] * d["points"]["step"][a].get<double>() + origin[a];
    worst = std::max(worst, (got - expected).norm());
  }
  EXPECT_LT(worst, 0.01);  // metres: a 200 m map over 65,536 steps
  // Cameras: 16 floats each, centres in ENU.
  const auto cams = decode_array<float>(d["cameras"]["data_f32"]);
  ASSERT_EQ(cams.size(), 16u * 12);
  const Eigen::Vector3d c0 = planted_enu_from_segment(0).apply(Eigen::Vector3d(-3, 0, 0));  // first camera of segment 0
  EXPECT_NEAR(cams[0] + origin.x(), c0.x(), 1e-3);
  EXPECT_NEAR(cams[1] + origin.y(), c0.y(), 1e-3);
  EXPECT_NEAR(cams[2] + origin.z(), c0.z(), 1e-3);
  // The queries keep their fields, centres relative to the origin.
  ASSERT_EQ(d["queries"].size(), 4u);
  EXPECT_EQ(d["queries"][1]["image"], "wrong.jpg");
  EXPECT_NEAR(d["queries"][1]["estimated_center"][0].get<double>() + origin.x(), 145, 1e-9);
  EXPECT_FALSE(d["queries"][2].contains("estimated_center"));
  EXPECT_EQ(d["segments"].size(), 3u);
  EXPECT_GE(d["segments"][0]["outline"].size(), 3u);
  fs::remove(html);
  fs::remove_all(report);
}

TEST(Viewer, SubsamplesToMaxPointsAndDrawsTheSegmentFrame) {
  if (!viewer_assets::available()) GTEST_SKIP() << "built without three.js (npm ci --prefix src/visloc/viewer)";
  const fs::path html = unique_temp_path("visloc_viewer_small.html");
  ViewerOptions o;
  o.max_points = 100;
  o.frame = OverviewFrame::kSegment;
  const ViewerSummary s = write_viewer(planted().dir(), {}, html, o);
  EXPECT_LE(s.points_drawn, 100u);
  EXPECT_GE(s.points_drawn, 96u);  // each segment keeps floor(its share)
  EXPECT_EQ(s.frame, "segment");
  const nlohmann::json d = page_data(html);
  // The segment frame of this planted map: its segments agree on north
  // (segment +z is north; after the up alignment, still horizontal).
  ASSERT_TRUE(d["north"].is_array());
  EXPECT_NEAR(d["north"][2].get<double>(), 0.0, 1e-9);
  EXPECT_FALSE(d["has_report"].get<bool>());
  fs::remove(html);
}

TEST(Viewer, BadInputNamesTheProblem) {
  if (!viewer_assets::available()) GTEST_SKIP() << "built without three.js (npm ci --prefix src/visloc/viewer)";
  const fs::path html = unique_temp_path("visloc_viewer_bad.html");
  const fs::path empty = unique_temp_path("visloc_viewer_noreport");
  fs::create_directories(empty);
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), empty, html); }).find("no report.json"), std::string::npos);
  write_file_atomic(empty / "report.json", "{not json");
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), empty, html); }).find((empty / "report.json").string()),
            std::string::npos);
  write_file_atomic(empty / "report.json", R"({"per_query": []})");
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), empty, html); }).find("run `visloc eval` again"),
            std::string::npos);
  write_file_atomic(empty / "report.json", R"({"frame": "enu", "per_query": [{"image": "a", "true_center": [1, 2]}]})");
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), empty, html); }).find("true_center is not 3 finite numbers"),
            std::string::npos);
  const fs::path report = write_report_dir();
  ViewerOptions o;
  o.frame = OverviewFrame::kSegment;
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), report, html, o); }).find("report's centres are in the enu"),
            std::string::npos);
  o = {};
  o.max_points = 0;
  EXPECT_NE(error_of([&] { write_viewer(planted().dir(), {}, html, o); }).find("max_points"), std::string::npos);
  EXPECT_FALSE(fs::exists(html));
  fs::remove_all(empty);
  fs::remove_all(report);
}

// Headless Debian chromium on the page: the scene's counts match the map and
// the report, no JavaScript error, and a screenshot that shows points.
TEST(Viewer, RealBrowserDrawsTheMap) {
  if (!viewer_assets::available()) GTEST_SKIP() << "built without three.js (npm ci --prefix src/visloc/viewer)";
  const std::string chromium = VISLOC_CHROMIUM;
  if (chromium.empty() || access(chromium.c_str(), X_OK) != 0)
    GTEST_SKIP() << "chromium is not installed (apt-get install chromium; scripts/setup.sh does it)";
  const fs::path report = write_report_dir();
  const fs::path html = unique_temp_path("visloc_viewer_browser.html");
  const ViewerSummary s = write_viewer(planted().dir(), report, html);
  const fs::path profile = unique_temp_path("visloc_viewer_chromium_profile");
  const std::vector<std::string> common = {chromium, "--headless", "--no-sandbox", "--disable-gpu",
                                           "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                                           "--user-data-dir=" + profile.string(), "--window-size=900,700"};
  // The DOM after load: the page writes what it drew into #visloc-stats.
  const fs::path dom_log = unique_temp_path("visloc_viewer_dom.log");
  std::vector<std::string> argv = common;
  argv.insert(argv.end(), {"--dump-dom", "file://" + html.string()});
  run_process(argv, dom_log);
  const std::string dom = read_file(dom_log);
  const std::string open = "<pre id=\"visloc-stats\">";
  const size_t a = dom.find(open);
  ASSERT_NE(a, std::string::npos) << "no DOM dumped:\n" << tail_of_file(dom_log, 30);
  const size_t b = dom.find("</pre>", a);
  const std::string text = dom.substr(a + open.size(), b - a - open.size());
  ASSERT_FALSE(text.empty()) << "#visloc-stats is empty: the page's script did not run:\n" << tail_of_file(dom_log, 30);
  const nlohmann::json stats = nlohmann::json::parse(text);
  EXPECT_EQ(stats["points"].get<size_t>(), s.points_drawn);
  EXPECT_EQ(stats["cameras"].get<size_t>(), s.cameras);
  EXPECT_EQ(stats["queries"].get<size_t>(), s.queries);
  EXPECT_EQ(stats["segments"].get<size_t>(), s.segments);
  EXPECT_TRUE(stats["errors"].empty()) << stats["errors"].dump();
  EXPECT_GT(stats["load_ms"].get<double>(), 0);
  EXPECT_EQ(dom.find("Uncaught"), std::string::npos) << tail_of_file(dom_log, 30);
  // What WebGL drew (read back on the canvas, without the HTML panels).
  EXPECT_GT(stats["canvas"]["drawn_fraction"].get<double>(), 0.005) << stats.dump();
  EXPECT_GT(stats["canvas"]["coloured_pixels"].get<double>(), 100) << stats.dump();
  // A query's details, opened as a click opens them (#select=N): the wrong pose.
  const fs::path select_log = unique_temp_path("visloc_viewer_select.log");
  argv = common;
  argv.insert(argv.end(), {"--dump-dom", "file://" + html.string() + "#select=1"});
  run_process(argv, select_log);
  const std::string selected = read_file(select_log);
  const size_t info = selected.find("id=\"info\"");
  ASSERT_NE(info, std::string::npos);
  const std::string panel = selected.substr(info, selected.find("</div>", info) - info);
  EXPECT_NE(panel.find("wrong.jpg"), std::string::npos) << panel;
  EXPECT_NE(panel.find("WRONG pose"), std::string::npos) << panel;
  EXPECT_NE(panel.find("inliers 14"), std::string::npos) << panel;
  // A screenshot of the canvas alone (#noui hides the panels): not blank,
  // and points in the segments' colours.
  const fs::path png = unique_temp_path("visloc_viewer_shot.png");
  argv = common;
  argv.insert(argv.end(),
              {"--screenshot=" + png.string(), "--virtual-time-budget=3000", "file://" + html.string() + "#noui"});
  run_process(argv, unique_temp_path("visloc_viewer_shot.log"));
  const cv::Mat shot = cv::imread(png.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(shot.empty()) << "no screenshot";
  const cv::Vec3b background(0x1d, 0x18, 0x16);  // #16181d, BGR
  size_t differing = 0, saturated = 0;
  std::set<int> colours;
  for (int y = 0; y < shot.rows; ++y)
    for (int x = 0; x < shot.cols; ++x) {
      const cv::Vec3b p = shot.at<cv::Vec3b>(y, x);
      if (p == background) continue;
      ++differing;
      const int hi = std::max({p[0], p[1], p[2]}), lo = std::min({p[0], p[1], p[2]});
      if (hi - lo > 60) ++saturated;
      colours.insert(p[0] << 16 | p[1] << 8 | p[2]);
    }
  const double total = static_cast<double>(shot.total());
  EXPECT_GT(differing / total, 0.02) << "the screenshot is nearly blank";
  EXPECT_GT(saturated, 200u) << "no coloured points in the screenshot";
  EXPECT_GT(colours.size(), 50u);
  fs::remove_all(profile);
  fs::remove(html);
  fs::remove(png);
  fs::remove_all(report);
}

}  // namespace
}  // namespace visloc
