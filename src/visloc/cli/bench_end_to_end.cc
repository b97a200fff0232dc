// visloc bench end-to-end: the whole localizer on a query set, once per paper
// setting (bench/end_to_end_benchmark.h); only binds options.
#include <unistd.h>

#include <iostream>
#include <memory>

#include "bench/end_to_end_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/util/error.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_bench_end_to_end(CLI::App& bench) {
  auto options = std::make_shared<EndToEndBenchmarkOptions>();
  auto json = std::make_shared<std::string>();
  CLI::App* cmd = bench.add_subcommand("end-to-end",
                                       "Whole localizer on a query set, once per paper setting on "
                                       "the same features (setting 1 is the baseline)");
  OptionTable t;
  add_options(t, *options);
  t.add("--json", *json, "Also write the table as JSON to this file");
  bind_options(cmd, t);
  cmd->callback([options, json] {
    if (options->repeat < 1) throw_error(ErrorCode::kInvalidArgument, "--repeat must be >= 1");
    if (options->settings.empty()) throw_error(ErrorCode::kInvalidArgument, "--settings lists no setting");
    if (options->query_features == QueryFeatureSource::kImages && options->images_dir.empty())
      throw_error(ErrorCode::kInvalidArgument, "bench end-to-end: --images is needed with --query-features images");
    const auto r =
        run_end_to_end_benchmark(*options, ::isatty(STDERR_FILENO) ? end_to_end_progress_printer(std::cerr) : nullptr);
    std::cout << r.table;
    if (!json->empty()) write_file_atomic(*json, r.report.dump(2));
  });
}

}  // namespace visloc::cli
