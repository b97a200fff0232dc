#include "visloc/eval/city_benchmark.h"
#include "visloc/eval/segment_study.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <limits>
#include <map>
#include <set>

#include "visloc/geo/gps_csv.h"
#include "visloc/sfm/process.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"
#include "visloc/util/test_support.h"

namespace fs = std::filesystem;
using namespace visloc;

TEST(CityBenchmark, OptionsAreValidated) {
  CityBenchmarkOptions o;
  o.leave_out_roads = -1;
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.leave_out_road_end_m = -1;
  EXPECT_THROW(o.validate(), Error);
  o.leave_out_road_end_m = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.negative_min_distance_m = 5;  // below the positive distance
  EXPECT_THROW(o.validate(), Error);
  o = {};
  o.shared_data = "/nonexistent/shared";
  EXPECT_THROW(o.validate(), Error);
}

// With the last placemark of each mapped road left out (leave_out_road_end_m
// under the placemark spacing): the map's images are those of every
// placemark of a mapped road but its last one.
void expect_road_ends_left_out(const fs::path& dir, const nlohmann::json& r) {
  const auto city = nlohmann::json::parse(read_file(dir / "city" / "city.json"));
  const int road_left_out = r["city"]["roads_left_out"][0].get<int>();
  std::map<int, std::pair<double, int>> last_on_road;  // road → (arc, placemark)
  for (const auto& p : city["placemarks"]) {
    auto& last = last_on_road[p["road"].get<int>()];
    last = std::max(last, {p["arc_m"].get<double>(), p["id"].get<int>()});
  }
  std::set<int> expected, mapped;
  for (const auto& p : city["placemarks"])
    if (p["road"].get<int>() != road_left_out && last_on_road[p["road"].get<int>()].second != p["id"].get<int>())
      expected.insert(p["id"].get<int>());
  for (const auto& g : read_gps_csv(dir / "map_gps.csv")) mapped.insert(g.placemark.value_or(-1));
  EXPECT_EQ(mapped, expected);
  EXPECT_EQ(r["city"]["placemarks_mapped"].get<size_t>(), expected.size());
}

// The benchmark's small configuration: one grid block (4 roads, one left
// out), two segments, a few queries and foreign photos. Checks that every
// stage runs, that the queries are classified and scored, and that a second
// run resumes (the city is not rendered again, the map is reused).
TEST(CityBenchmark, SmallCityRunsAndResumes) {
  if (!program_exists("colmap")) GTEST_SKIP() << "colmap is not installed";
  const fs::path dir = unique_temp_path("visloc_city_benchmark_test");
  fs::remove_all(dir);
  CityBenchmarkOptions o;
  o.city.layout.layout = synth::RoadLayout::kGrid;
  o.city.layout.grid_blocks_x = o.city.layout.grid_blocks_y = 1;
  o.city.layout.block_size_m = 50;
  o.city.views.headings = 8;
  o.city.views.elevations_deg = {10};
  o.city.views.width = o.city.views.height = 400;
  o.city.queries.count = 16;
  o.city.queries.resolutions = {{640, 480}};
  o.city.jobs = 2;
  o.leave_out_roads = 1;
  o.leave_out_road_end_m = 1;  // placemarks are 10-12 m apart: the last one of each mapped road
  o.map.jobs = 2;
  o.map.itq.iterations = 10;
  o.map.pq.iterations = 10;
  o.map.pq_training_descriptors = 20000;
  o.map.build_retrieval = false;
  o.foreign_photos = 4;
  if (fs::is_directory(VISLOC_SHARED_DATA_DIR)) o.shared_data = VISLOC_SHARED_DATA_DIR;
  const nlohmann::json r = run_city_benchmark(dir, o);
  ASSERT_TRUE(fs::exists(dir / "report.json"));
  ASSERT_TRUE(fs::exists(dir / "report.md"));
  EXPECT_TRUE(fs::exists(dir / "retrieval_ranks.png") && fs::exists(dir / "error_curve.svg"));  // the plots
  EXPECT_EQ(r["city"]["roads"].get<int>(), 4);
  EXPECT_EQ(r["city"]["roads_left_out"].size(), 1u);
  EXPECT_EQ(r["city"]["road_end_placemarks_left_out"].get<int>(), 3);
  expect_road_ends_left_out(dir, r);
  EXPECT_GE(r["map"]["segments"].get<int>(), 1);
  const size_t positives = r["positives"]["queries"].get<size_t>();
  const size_t scored = positives + r["negatives_unmapped_streets"]["queries"].get<size_t>() +
                        r["between_not_scored"]["queries"].get<size_t>() +
                        r["near_but_unseen_not_scored"]["queries"].get<size_t>();
  EXPECT_EQ(scored, 16u);
  // A positive sees the map: some segment shows it enough points, and that
  // segment is among its true ones.
  for (const auto& q : r["per_query"])
    if (q["kind"] == "positive") {
      EXPECT_GE(q["most_visible_points"].get<double>(), o.positive_min_visible_points) << q["image"];
      EXPECT_FALSE(q["true_segments"].empty()) << q["image"];
    }
  ASSERT_GE(positives, 8u);
  EXPECT_GE(r["positives"]["registered"].get<size_t>(), positives / 2);
  EXPECT_EQ(r["per_query"].size(), 16u + r["foreign_photos"]["queries"].get<size_t>());
  if (!o.shared_data.empty()) {
    EXPECT_EQ(r["foreign_photos"]["queries"].get<size_t>(), 4u);
  }
  // Wrong poses are the sum of their kinds.
  EXPECT_EQ(r["wrong_poses"].get<size_t>(), r["positives"]["wrong_poses"].get<size_t>() +
                                                r["negatives_unmapped_streets"]["wrong_poses"].get<size_t>() +
                                                r["foreign_photos"]["registered"].get<size_t>());

  // Resume: nothing is rendered or built again. The localize stage alone
  // (what `bench city` runs in a fresh process) reads the build summary.
  const auto city_time = fs::last_write_time(dir / "city" / "city.json");
  o.stage = CityBenchmarkStage::kLocalize;
  o.localizer.point_votes.probe_radius = 0;  // the report records the point-vote options
  const nlohmann::json again = run_city_benchmark(dir, o);
  EXPECT_TRUE(again["localized_in_separate_process"].get<bool>());
  EXPECT_EQ(r["segment_votes"]["probe_radius"].get<int>(), 1);
  EXPECT_EQ(again["segment_votes"]["probe_radius"].get<int>(), 0);
  EXPECT_EQ(again["segment_votes"]["points_per_segment"].get<int>(), o.localizer.point_votes.points_per_segment);
  EXPECT_GT(again["peak_memory_bytes_city_queries"].get<uint64_t>(), 0u);
  EXPECT_LE(again["peak_memory_bytes_city_queries"].get<uint64_t>(),
            again["peak_memory_bytes_of_localizing_process"].get<uint64_t>());
  EXPECT_EQ(fs::last_write_time(dir / "city" / "city.json"), city_time);
  EXPECT_EQ(again["map"]["points"], r["map"]["points"]);
  EXPECT_EQ(again["positives"]["registered"], r["positives"]["registered"]);
  // The localize stage refuses a city made with other options.
  CityBenchmarkOptions other = o;
  other.city.layout.seed += 1;
  EXPECT_THROW(run_city_benchmark(dir, other), Error);

  // The segment design study on this city: two layouts, resumable.
  const StudyDataset data = city_study_dataset(dir);
  EXPECT_EQ(data.queries.size(), r["positives"]["queries"].get<size_t>() +
                                     r["negatives_unmapped_streets"]["queries"].get<size_t>());
  SegmentStudyOptions so;
  so.placemarks = {4};
  so.overlaps = {0, 1, 5};  // 5 >= 4: skipped
  so.map = o.map;
  so.map.build_retrieval = false;
  so.localizer.max_segments = 16;  // no retrieval index: every segment is searched
  const fs::path study = dir / "study";
  const nlohmann::json rows = run_segment_study(study, data, so);
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0]["overlap"].get<int>(), 0);
  EXPECT_EQ(rows[1]["overlap"].get<int>(), 1);
  // More overlap: more segments.
  EXPECT_GT(rows[1]["segments"].get<int>(), rows[0]["segments"].get<int>());
  for (const auto& row : rows) {
    EXPECT_GT(row["registered"].get<size_t>(), 0u);
    EXPECT_GT(row["segment_bytes"].get<uint64_t>(), 0u);
    EXPECT_FALSE(fs::exists(study / "city" / "p4_o0" / "map"));  // maps are not kept by default
  }
  // Features were extracted once: the second map linked them.
  EXPECT_TRUE(fs::exists(study / "city" / "shared" / "pq_codebook.vlpq"));
  EXPECT_EQ(run_segment_study(study, data, so), rows);  // resumes from result.json
  EXPECT_EQ(collect_segment_study_rows(study, "city"), rows);
  {
    // Residual codes are another study: its results and codebook are not reused.
    SegmentStudyOptions residual = so;
    residual.map.pq.quantizer = PqQuantizer::kResidual;
    try {
      run_segment_study(study, data, residual);
      ADD_FAILURE() << "a product study resumed as a residual one";
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument);
      EXPECT_NE(std::string(e.what()).find("study.json"), std::string::npos) << e.what();
    }
  }
  write_segment_study_report(study, {{"city", rows}});
  EXPECT_TRUE(fs::exists(study / "report.md"));
  EXPECT_TRUE(fs::exists(study / "segments_city_registration.svg"));
  EXPECT_TRUE(fs::exists(study / "segments_city_bytes.png"));
  fs::remove_all(dir);
}
