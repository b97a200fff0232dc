// visloc bench city: the city benchmark (eval/city_benchmark.h).
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/eval/city_benchmark.h"
#include "visloc/util/file_io.h"
#include "visloc/util/option_table.h"

namespace visloc::cli {

void add_bench_city(CLI::App& bench) {
  struct Args {
    CityBenchmarkOptions options = default_city_benchmark_options();
    std::string out, stage = "auto";
  };
  auto a = std::make_shared<Args>();
  a->options.shared_data = VISLOC_DEFAULT_SHARED_DATA;
  CLI::App* cmd = bench.add_subcommand(
      "city",
      "The city benchmark: render a synthetic city, map all its streets but a few, localize queries near mapped "
      "streets (positives), on the unmapped streets and foreign photos (negatives); count wrong poses apart from "
      "misses, score retrieval. Resumes at every stage; writes report.json and report.md in --out");
  OptionTable t;
  t.add("--out", a->out, "Benchmark directory (city/, map/, report.json, report.md)").require();
  add_options(t, a->options);
  t.add("--stage", a->stage,
        "auto: render and build here, then localize in a fresh process (so that the report's peak memory is the "
        "localizer's); all: everything in this process; prepare: render and build only; localize: localize and "
        "report only (after prepare, same options)")
      .one_of({"auto", "all", "prepare", "localize"})
      .last_wins();  // the fresh process appends "--stage localize"
  bind_options(cmd, t);
  cmd->callback([a] {
    CityBenchmarkOptions& o = a->options;
    skip_absent_shared_data(o, std::cerr);
    record_slurm_city_build(a->out, o.map);
    o.map.plan.validate();  // before hours of rendering
    o.stage = a->stage == "all"        ? CityBenchmarkStage::kAll
              : a->stage == "localize" ? CityBenchmarkStage::kLocalize
                                       : CityBenchmarkStage::kPrepare;  // auto localizes in a fresh process
    CityBenchmarkProgressPrinter progress(std::cerr, ::isatty(STDERR_FILENO) != 0);
    run_city_benchmark(a->out, o, std::ref(progress), std::ref(progress));
    if (a->stage == "auto") {
      if (const int status = run_localize_stage_in_new_process(std::cerr)) std::exit(status);  // it printed the report
    } else if (o.stage != CityBenchmarkStage::kPrepare) {
      std::cout << read_file(std::filesystem::path(a->out) / "report.md");
    }
  });
}

}  // namespace visloc::cli
