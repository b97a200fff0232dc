// visloc bench pairs: one-many RANSAC on image pairs (twoview/pair_benchmark.h); only binds options.
#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/twoview/pair_benchmark.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_bench_pairs(CLI::App& bench) {
  struct Args {
    std::string data = std::string(VISLOC_DEFAULT_SHARED_DATA) + "/strecha", out;
    std::vector<std::string> synthetic;
    PairBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  args->options.sift.max_image_side = 1600;
  CLI::App* cmd = bench.add_subcommand(
      "pairs",
      "Two-view RANSAC on neighbouring pairs of the Strecha scenes (castle-P30/P19: repeated windows) against\n"
      "the laser cameras' F: classic, 1m, 1m-sprt and OpenCV findFundamentalMat (USAC_MAGSAC, RANSAC).\n"
      "Writes report.json and report.md in --out (success, true inliers, times; the issue's expectations).");
  cmd->add_option("--data", args->data, "The Strecha folder (scenes with images/ and cameras/)")->capture_default_str();
  cmd->add_option("--out", args->out, "Report folder")->required();
  cmd->add_option("--scenes", args->options.scenes, "Strecha scenes (none: --scenes '')")->capture_default_str();
  cmd->add_option("--synthetic", args->synthetic,
                  "Folders written by `visloc synth city`: synthetic facade pairs (one heading from neighbouring\n"
                  "placemarks; truth from the rendered poses)");
  cmd->add_option("--max-pairs", args->options.max_pairs_per_scene, "Pairs per scene (0: all)")->capture_default_str();
  cmd->add_option("--threshold", args->options.threshold_px, "Inlier threshold, pixels (every method)")
      ->capture_default_str();
  cmd->add_option("--iterations", args->options.fixed_iterations, "Samples of 1m")->capture_default_str();
  cmd->add_option("--max-features", args->options.sift.max_features, "SIFT features per image")->capture_default_str();
  cmd->add_flag("--no-opencv", [args](int64_t) { args->options.opencv = false; }, "Skip OpenCV's findFundamentalMat");
  cmd->add_option("--seed", args->options.seed, "RANSAC seed")->capture_default_str();
  cmd->callback([args] {
    args->options.strecha_dir = args->data;
    for (const auto& s : args->synthetic) args->options.synthetic_cities.emplace_back(s);
    // `--scenes ''` leaves one empty name: no Strecha scene.
    args->options.scenes.erase(std::remove(args->options.scenes.begin(), args->options.scenes.end(), std::string()),
                               args->options.scenes.end());
    const PairBenchmarkResult r =
        run_pair_benchmark(args->options, [](const std::string& line) { std::cerr << "bench pairs: " << line << "\n"; });
    std::filesystem::create_directories(args->out);
    write_file_atomic(std::filesystem::path(args->out) / "report.json", r.report.dump(2));
    write_file_atomic(std::filesystem::path(args->out) / "report.md", r.markdown);
    std::cout << r.markdown;
  });
}

}  // namespace visloc::cli
