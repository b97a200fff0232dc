#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_bench_command(CLI::App& app) {
  CLI::App* bench = app.add_subcommand(
      "bench", "Benchmarks: quality and speed, with baselines measured in the same run");
  bench->require_subcommand(1);
  add_bench_features(*bench);
  add_bench_sift_colmap(*bench);
  add_bench_matching(*bench);
  add_bench_pose(*bench);
  add_bench_retrieval(*bench);
  add_bench_end_to_end(*bench);
  add_bench_city(*bench);
  add_bench_segments(*bench);
  add_bench_pairs(*bench);
  add_bench_confidence(*bench);
}

}  // namespace visloc::cli
