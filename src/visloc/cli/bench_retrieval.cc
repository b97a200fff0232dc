// visloc bench retrieval (the retrieval stage's recall, time and memory) and
// visloc retrieval build|query (the retrieval stage on its own): both run in
// bench/retrieval_benchmark.h; this file only binds their options.
#include <iostream>
#include <memory>

#include "bench/retrieval_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"

namespace visloc::cli {

void add_bench_retrieval(CLI::App& bench) {
  auto options = std::make_shared<RetrievalBenchmarkOptions>();
  auto json = std::make_shared<bool>(false);
  CLI::App* cmd = bench.add_subcommand(
      "retrieval",
      "Image retrieval (T-embedding + IVF-PQ, candidate segments): recall at N_t = 1,5,10,20,50, time per\n"
      "query, memory; compared with exact search and VLAD in the same run, and timed on a synthetic 100K index");
  OptionTable t;
  add_options(t, *options);
  t.flag("--json", *json, "Print JSON");
  bind_options(cmd, t);
  cmd->callback([options, json] {
    const auto r = run_retrieval_benchmark(*options, [json](const std::string& line) {
      if (!*json) std::cerr << line << "\n";
    });
    std::cout << (*json ? r.report.dump(2) + "\n" : r.text);
  });
}

// Used by fuzz/make_seeds.sh (a small retrieval map) and to inspect the
// retrieval stage of a built map (retrieval query --map MAP/retrieval).
void add_retrieval_command(CLI::App& app) {
  CLI::App* retrieval = app.add_subcommand(
      "retrieval",
      "Image retrieval alone: build a retrieval map from a folder of images, or query one (e.g. MAP/retrieval)");
  retrieval->require_subcommand(1);
  auto build_options = std::make_shared<RetrievalMapBuildOptions>();
  CLI::App* build = retrieval->add_subcommand(
      "build", "Learn the T-embedding on the images, index them (IVF-PQ), write the image -> segment table");
  OptionTable build_table;
  add_options(build_table, *build_options);
  bind_options(build, build_table);
  build->callback([build_options] { std::cout << build_retrieval_map(*build_options).summary << "\n"; });

  auto query_options = std::make_shared<RetrievalMapQueryOptions>();
  CLI::App* query =
      retrieval->add_subcommand("query", "Candidate segments of query images; one JSON object per image and line");
  OptionTable query_table;
  add_options(query_table, *query_options);
  bind_options(query, query_table);
  query->callback([query_options] {
    query_retrieval_map(*query_options, [](const nlohmann::json& line) { std::cout << line.dump() << "\n"; });
  });
}

}  // namespace visloc::cli
