// visloc bench end-to-end: the whole localizer on a query set, once per paper
// setting (bench/end_to_end_benchmark.h); only binds options.
#include <unistd.h>

#include <iostream>
#include <memory>

#include "bench/end_to_end_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/localizer_options.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_bench_end_to_end(CLI::App& bench) {
  struct Args {
    std::string map, queries, images, truth, intrinsics, query_features = "images", json, setting = "3+";
    EndToEndBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand("end-to-end",
                                       "Whole localizer on a query set, once per paper setting on "
                                       "the same features (setting 1 is the baseline)");
  cmd->add_option("--map", args->map, "Map directory")->required();
  cmd->add_option("--queries", args->queries, "Query image names, one per line")->required();
  cmd->add_option("--images", args->images, "Directory of the query images (with --query-features images)");
  cmd->add_option("--truth", args->truth, "Reference poses 'name qw qx qy qz tx ty tz' (the map's frame)")->required();
  cmd->add_option("--intrinsics", args->intrinsics, "Per-image intrinsics 'name MODEL w h params...'");
  cmd->add_option("--query-features", args->query_features, "'images' (our SIFT) or 'database' (the model's own)")
      ->check(CLI::IsMember({"images", "database"}))
      ->capture_default_str();
  cmd->add_option("--settings", args->options.settings, "Settings to run, in order")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--repeat", args->options.repeat,
                  "Localize each query this many times per setting (times: median)")
      ->capture_default_str();
  cmd->add_option("--json", args->json, "Also write the table as JSON to this file");
  add_localizer_options(cmd, args->options.localizer, args->setting);
  cmd->callback([args] {
    EndToEndBenchmarkOptions& o = args->options;
    if (o.repeat < 1) throw_error(ErrorCode::kInvalidArgument, "--repeat must be >= 1");
    if (o.settings.empty()) throw_error(ErrorCode::kInvalidArgument, "--settings lists no setting");
    o.query_features = parse_query_feature_source(args->query_features);
    if (o.query_features == QueryFeatureSource::kImages && args->images.empty())
      throw_error(ErrorCode::kInvalidArgument, "bench end-to-end: --images is needed with --query-features images");
    o.map = args->map;
    o.queries = args->queries;
    o.images_dir = args->images;
    o.truth = args->truth;
    o.intrinsics = args->intrinsics;
    const bool tty = ::isatty(STDERR_FILENO);
    const EndToEndBenchmarkResult r = run_end_to_end_benchmark(o, [tty](size_t done, size_t total) {
      if (!tty) return;
      std::cerr << "\rbench end-to-end: features " << done << "/" << total << std::flush;
      if (done == total) std::cerr << "\n";
    });
    std::cout << r.table;
    if (!args->json.empty()) write_file_atomic(args->json, r.report.dump(2));
  });
}

}  // namespace visloc::cli
