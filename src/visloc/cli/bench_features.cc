// visloc bench features and visloc bench sift-colmap: SIFT time and features
// per image, our SIFT against COLMAP's (bench/feature_benchmark.h); only binds options.
#include <iostream>
#include <memory>

#include "bench/feature_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"

namespace visloc::cli {
namespace {

// Binds the benchmark's options and --json; `run` prints its text as it goes, or the report as JSON at the end.
template <class Options, class Run>
void bind_feature_bench(CLI::App* cmd, Run run, const char* json_help) {
  auto options = std::make_shared<Options>();
  auto json = std::make_shared<bool>(false);
  OptionTable t;
  add_options(t, *options);
  t.flag("--json", *json, json_help);
  bind_options(cmd, t);
  cmd->callback([options, json, run] {
    const auto r = run(*options, [json](const std::string& part) {
      if (!*json) std::cout << part;
    });
    if (*json) std::cout << r.report.dump(2) << "\n";
  });
}

}  // namespace

void add_bench_features(CLI::App& bench) {
  bind_feature_bench<FeatureBenchmarkOptions>(
      bench.add_subcommand("features", "SIFT time and features per image (medians, one thread)"), run_feature_benchmark,
      "Print JSON instead of a table");
}

void add_bench_sift_colmap(CLI::App& bench) {
  bind_feature_bench<SiftColmapBenchmarkOptions>(
      bench.add_subcommand(
          "sift-colmap",
          "Our SIFT against COLMAP's SIFT in a COLMAP database: verified matches per adjacent image "
          "pair\n(query image i+1 against reference image i; exact NN, ratio test, fundamental RANSAC)"),
      run_sift_colmap_benchmark, "Print JSON");
}

}  // namespace visloc::cli
