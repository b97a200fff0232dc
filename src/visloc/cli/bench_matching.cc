// visloc bench matching: 2D-3D matching of held-out queries, every method on
// the same queries (bench/matching_benchmark.h); only binds options.
#include <iostream>
#include <memory>

#include "bench/matching_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/util/error.h"

namespace visloc::cli {

void add_bench_matching(CLI::App& bench) {
  struct Args {
    std::vector<std::string> maps, query_lists;  // paired into options.scenes
    bool json = false;
    MatchingBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "matching",
      "2D-3D matching: CCS against exact, FAISS IVFADC/IMI and an LSH cascade, on maps imported with\n"
      "their query images held out (repeat --map/--queries for several scenes; one thread). Opt-in with\n"
      "--method rerank: the full search's short lists (L_R 40 and 64) ranked by its own PQ (repeats\n"
      "ccs-full-r1), exact L2, FAISS PQ 16 or 32 bytes, OPQ + PQ 16, 256 coarse centroids + PQ 16 of\n"
      "the residual, FAISS's residual quantizer 16 bytes: the recall each ranking would buy, and its\n"
      "bytes per point");
  OptionTable t;
  t.add("--map", args->maps, "Map directory (from `map import --holdout`)").require();
  t.add("--queries", args->query_lists, "Query image list, one per --map").require();
  add_options(t, args->options);
  t.flag("--json", args->json, "Print JSON");
  bind_options(cmd, t);
  cmd->callback([args] {
    if (args->maps.size() != args->query_lists.size())
      throw_error(ErrorCode::kInvalidArgument, "give one --queries per --map (", args->maps.size(), " maps, ",
                  args->query_lists.size(), " query lists)");
    args->options.scenes.clear();
    for (size_t i = 0; i < args->maps.size(); ++i)
      args->options.scenes.push_back({args->maps[i], args->query_lists[i]});
    const MatchingBenchmarkResult r = run_matching_benchmark(args->options);
    std::cout << (args->json ? r.report.dump(2) + "\n" : r.text);
  });
}

}  // namespace visloc::cli
