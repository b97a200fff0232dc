#include <gtest/gtest.h>

#include <filesystem>

#include "visloc/eval/evaluation.h"
#include "visloc/util/file_io.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(Evaluation, ErrorsRatesAndReportFiles) {
  std::map<std::string, QueryTruth> truth;
  std::vector<LocalizationResult> results;
  for (int i = 0; i < 4; ++i) {
    const std::string name = "q" + std::to_string(i) + ".jpg";
    CameraPose t = CameraPose::from_world_from_cam(Eigen::Matrix3d::Identity(), Eigen::Vector3d(i, 0, 0));
    truth[name].cam_from_world = t;
    LocalizationResult r;
    r.image = name;
    r.registered = i < 3;
    r.segment = r.registered ? 0 : -1;
    // Estimates off by i × 0.2 m along y.
    r.cam_from_segment = CameraPose::from_world_from_cam(Eigen::Matrix3d::Identity(), Eigen::Vector3d(i, 0.2 * i, 0));
    r.times.total = 10 + i;
    r.times.features = 4;
    results.push_back(r);
  }
  EvaluationReport rep = evaluate(results, truth);
  EXPECT_EQ(rep.queries, 4u);
  EXPECT_EQ(rep.registered, 3u);
  nlohmann::json j = rep.to_json(results, {{"map", "test"}});
  EXPECT_NEAR(j["position_error_m"]["median"].get<double>(), 0.2, 1e-9);
  EXPECT_EQ(j["count_under_m"]["0.25"].get<int>(), 2);
  EXPECT_NEAR(j["recall"]["0.25m_2deg"].get<double>(), 0.5, 1e-12);
  EXPECT_NEAR(j["recall"]["5m_10deg"].get<double>(), 0.75, 1e-12);
  EXPECT_EQ(j["map"], "test");
  fs::path dir = fs::temp_directory_path() / "visloc_eval_test_report";
  fs::remove_all(dir);
  write_report(dir, rep, results, {});
  for (const char* f : {"report.json", "report.md", "error_curve.svg", "error_curve.png", "top_view.svg", "top_view.png"})
    EXPECT_TRUE(fs::exists(dir / f)) << f;
  EXPECT_NE(read_file(dir / "report.md").find("| 4 | 3 |"), std::string::npos) << read_file(dir / "report.md");
}
