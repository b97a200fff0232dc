// visloc bench pose: robust absolute pose on synthetic correspondence sets
// (bench/pose_benchmark.h); only binds options.
#include <iostream>
#include <memory>

#include "bench/pose_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/util/error.h"

namespace visloc::cli {

void add_bench_pose(CLI::App& bench) {
  auto options = std::make_shared<PoseBenchmarkOptions>();
  auto json = std::make_shared<bool>(false);
  CLI::App* cmd = bench.add_subcommand(
      "pose",
      "Pose estimation on synthetic 2D-3D correspondence sets: classical RANSAC, one-many RANSAC (fixed, SPRT)\n"
      "and OpenCV solvePnPRansac (P3P, USAC MAGSAC) in the same run");
  OptionTable t;
  add_options(t, *options);
  t.flag("--json", *json, "Print JSON");
  bind_options(cmd, t);
  cmd->callback([options, json] {
    if (options->trials <= 0) throw_error(ErrorCode::kInvalidArgument, "--trials must be positive");
    const PoseBenchmarkResult r = run_pose_benchmark(*options);
    std::cout << (*json ? r.report.dump(2) + "\n" : r.table);
  });
}

}  // namespace visloc::cli
