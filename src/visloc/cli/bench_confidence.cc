// visloc bench confidence: fit the localizer's confidence model on reports
// (eval/confidence_fit.h), or check a model (the builtin one by default) on
// them: precision, recall and the precision-recall curve.
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/eval/confidence_fit.h"

namespace visloc::cli {

void add_bench_confidence(CLI::App& bench) {
  auto options = std::make_shared<ConfidenceBenchmarkOptions>();
  CLI::App* cmd = bench.add_subcommand(
      "confidence",
      "The localizer's confidence on the poses of benchmark reports (report.json of 'bench city' or 'eval', run "
      "with --min-confidence 0 to see every pose): with --fit, fit the logistic model, its threshold and its σ scale "
      "(the "
      "builtin model in pipeline/confidence.cc came from this, on synthetic cities only); without, check a model "
      "(the builtin one, or --model) on them. Writes model.json / check.json and a precision-recall plot to --out");
  OptionTable t;
  add_options(t, *options);
  bind_options(cmd, t);
  cmd->callback([options] { run_confidence_benchmark(*options, std::cout, std::cerr); });
}

}  // namespace visloc::cli
