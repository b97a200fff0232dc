// visloc bench matching: 2D-3D matching of held-out queries, every method on
// the same queries (bench/matching_benchmark.h); only binds options.
#include <iostream>
#include <memory>

#include "bench/matching_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/sift_options.h"
#include "visloc/util/error.h"

namespace visloc::cli {

void add_bench_matching(CLI::App& bench) {
  struct Args {
    std::vector<std::string> maps, query_lists;
    bool json = false;
    MatchingBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  MatchingBenchmarkOptions& o = args->options;
  CLI::App* cmd = bench.add_subcommand(
      "matching",
      "2D-3D matching: CCS against exact, FAISS IVFADC/IMI and an LSH cascade, on maps imported with\n"
      "their query images held out (repeat --map/--queries for several scenes; one thread)");
  cmd->add_option("--map", args->maps, "Map directory (from `map import --holdout`)")->required();
  cmd->add_option("--queries", args->query_lists, "Query image list, one per --map")->required();
  cmd->add_option("--database", o.database,
                  "COLMAP database with the queries' features (default: the map's source database)");
  cmd->add_flag("--extract", o.extract, "Extract query features from image files with our SIFT instead");
  cmd->add_option("--images", o.images, "Image directory for --extract");
  cmd->add_option("--max-queries", o.max_queries, "Use at most this many queries per map (0: all)");
  cmd->add_option("--ratio", o.ratio, "Ratio test of the 1-1 sets (ν_h)")->capture_default_str();
  cmd->add_option("--inlier-px", o.inlier_px, "Reprojection threshold with the reference pose, pixels")
      ->capture_default_str();
  cmd->add_option("--method", o.methods, "Only methods whose name starts with this (repeatable)");
  cmd->add_flag("--json", args->json, "Print JSON");
  add_sift_options(cmd, o.sift, true);
  cmd->callback([args] {
    if (args->maps.size() != args->query_lists.size())
      throw_error(ErrorCode::kInvalidArgument, "give one --queries per --map (", args->maps.size(), " maps, ",
                  args->query_lists.size(), " query lists)");
    args->options.scenes.clear();
    for (size_t i = 0; i < args->maps.size(); ++i)
      args->options.scenes.push_back({args->maps[i], args->query_lists[i]});
    const MatchingBenchmarkResult r = run_matching_benchmark(args->options);
    if (args->json)
      std::cout << r.report.dump(2) << "\n";
    else
      std::cout << r.text;
  });
}

}  // namespace visloc::cli
