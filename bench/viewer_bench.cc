// How fast the viewer's page opens in headless Debian chromium, and how big
// it is, on a planted map (planted_map.h: no shared data, no COLMAP).
//   build/bench/visloc_viewer_bench [SEGMENTS=10] [POINTS_PER_SEGMENT=10000] [RUNS=5]
// Prints one JSON object: the page's bytes, and per run the page's own
// load_ms (navigation start to the first frame drawn, performance.now()),
// when three.js had loaded and the scene was built (same clock), and the wall
// time of the whole chromium process (start-up included); medians. Chromium
// renders with SwiftShader (software WebGL) here: a GPU draws faster.
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <string>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "visloc/map_building/planted_map.h"
#include "visloc/sfm/process.h"
#include "visloc/util/file_io.h"
#include "visloc/util/statistics.h"
#include "visloc/util/test_support.h"
#include "visloc/viewer/viewer.h"

int main(int argc, char** argv) {
  using namespace visloc;
  namespace fs = std::filesystem;
  const int segments = argc > 1 ? std::atoi(argv[1]) : 10;
  const int points = argc > 2 ? std::atoi(argv[2]) : 10000;
  const int runs = argc > 3 ? std::atoi(argv[3]) : 5;
  if (segments < 1 || points < 1 || runs < 1) {
    std::cerr << "usage: visloc_viewer_bench [SEGMENTS] [POINTS_PER_SEGMENT] [RUNS] (all positive)\n";
    return 2;
  }
  const char* chromium = "/usr/bin/chromium";
  if (access(chromium, X_OK) != 0) {
    std::cerr << "visloc_viewer_bench: " << chromium << " is missing (apt-get install chromium)\n";
    return 1;
  }
  try {
    RandomGenerator rng(5);
    std::vector<PlantedSegment> planted;
    for (int k = 0; k < segments; ++k) planted.push_back(random_planted_segment(static_cast<size_t>(points), rng));
    const auto t0 = std::chrono::steady_clock::now();
    const PlantedMap map("viewer_bench", planted);
    const auto t1 = std::chrono::steady_clock::now();
    const fs::path html = unique_temp_path("visloc_viewer_bench.html");
    const ViewerSummary summary = write_viewer(map.dir(), {}, html);
    const auto t2 = std::chrono::steady_clock::now();
    std::vector<double> load_ms, wall_ms, app_start_ms, scene_built_ms;
    for (int r = 0; r < runs; ++r) {
      const fs::path profile = unique_temp_path("visloc_viewer_bench_profile_" + std::to_string(r));
      const fs::path log = unique_temp_path("visloc_viewer_bench_" + std::to_string(r) + ".log");
      const auto a = std::chrono::steady_clock::now();
      run_process({chromium, "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader",
                   "--enable-unsafe-swiftshader", "--user-data-dir=" + profile.string(), "--window-size=1280,800",
                   "--dump-dom", "file://" + html.string()},
                  log);
      wall_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count());
      const std::string dom = read_file(log);
      const std::string open = "<pre id=\"visloc-stats\">";
      const size_t at = dom.find(open);
      const std::string text =
          at == std::string::npos ? "" : dom.substr(at + open.size(), dom.find("</pre>", at) - at - open.size());
      if (text.empty()) {
        std::cerr << "run " << r << ": the page did not finish (#visloc-stats empty or missing); log " << log << "\n";
        return 1;
      }
      const auto stats = nlohmann::json::parse(text);
      if (!stats["errors"].empty()) {
        std::cerr << "run " << r << ": JavaScript errors " << stats["errors"].dump() << "\n";
        return 1;
      }
      load_ms.push_back(stats["load_ms"].get<double>());
      app_start_ms.push_back(stats["timings"]["app_start"].get<double>());
      scene_built_ms.push_back(stats["timings"]["scene_built"].get<double>());
      fs::remove_all(profile);
    }
    nlohmann::json out = {{"segments", segments},
                          {"points", summary.points_in_map},
                          {"points_drawn", summary.points_drawn},
                          {"cameras", summary.cameras},
                          {"file_bytes", summary.file_bytes},
                          {"file_mib", static_cast<double>(summary.file_bytes) / (1 << 20)},
                          {"seconds_planting_map", std::chrono::duration<double>(t1 - t0).count()},
                          {"seconds_writing_page", std::chrono::duration<double>(t2 - t1).count()},
                          {"load_ms", load_ms},
                          {"median_load_ms", median(load_ms)},
                          {"median_three_js_loaded_ms", median(app_start_ms)},
                          {"median_scene_built_ms", median(scene_built_ms)},
                          {"chromium_wall_ms", wall_ms},
                          {"median_chromium_wall_ms", median(wall_ms)}};
    std::cout << out.dump(2) << "\n";
    fs::remove(html);
  } catch (const std::exception& ex) {
    std::cerr << "visloc_viewer_bench: " << ex.what() << "\n";
    return 1;
  }
  return 0;
}
