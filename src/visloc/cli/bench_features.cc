// visloc bench features and visloc bench sift-colmap: SIFT time and features
// per image, our SIFT against COLMAP's (bench/feature_benchmark.h); only
// binds options.
#include <iostream>
#include <memory>

#include "bench/feature_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"

namespace visloc::cli {

void add_bench_features(CLI::App& bench) {
  struct Args {
    bool json = false;
    FeatureBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand("features", "SIFT time and features per image (medians, one thread)");
  cmd->add_option("images", args->options.inputs, "Image files or directories (searched recursively)")->required();
  cmd->add_option("--max-side", args->options.max_sides, "Maximum image sides to measure")->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON instead of a table");
  add_sift_options(cmd, args->options.sift, false);
  cmd->callback([args] {
    const FeatureBenchmarkResult r = run_feature_benchmark(args->options, [args](const std::string& part) {
      if (!args->json) std::cout << part;
    });
    if (args->json) std::cout << r.report.dump(2) << "\n";
  });
}

void add_bench_sift_colmap(CLI::App& bench) {
  struct Args {
    bool json = false;
    SiftColmapBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "sift-colmap",
      "Our SIFT against COLMAP's SIFT in a COLMAP database: verified matches per adjacent image pair\n"
      "(query image i+1 against reference image i; exact NN, ratio test, fundamental RANSAC)");
  cmd->add_option("--scene", args->options.scenes, "Scene directory with images/ and colmap/database.db")->required();
  cmd->add_option("--ratio", args->options.ratio, "Ratio test threshold")->capture_default_str();
  cmd->add_option("--threshold", args->options.threshold_px, "Fundamental matrix RANSAC threshold, pixels")
      ->capture_default_str();
  cmd->add_option("--max-side", args->options.max_image_side, "Maximum image side for our SIFT")->capture_default_str();
  cmd->add_flag("--json", args->json, "Print JSON");
  cmd->callback([args] {
    const SiftColmapBenchmarkResult r = run_sift_colmap_benchmark(args->options, [args](const std::string& part) {
      if (!args->json) std::cout << part;
    });
    if (args->json) std::cout << r.report.dump(2) << "\n";
  });
}

}  // namespace visloc::cli
