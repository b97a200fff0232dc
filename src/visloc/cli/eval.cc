// visloc eval: localize a query list against a map and report against the
// truth; or, for an imported COLMAP model, leave-one-out over its images;
// optionally with COLMAP's image_registrator on the same queries.
#include <unistd.h>

#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/eval/evaluation_run.h"

namespace visloc::cli {

void add_eval_command(CLI::App& app) {
  struct Args {
    EvaluationRunOptions run;
    EvaluationListFiles lists;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand("eval",
                                     "Localize a query list against a map and write report.json, "
                                     "report.md and plots.\n"
                                     "With --leave-one-out (a map imported from a COLMAP model): "
                                     "every image of the model in turn is removed,\n"
                                     "the map rebuilt without it, and the image localized (truth: its "
                                     "pose in the model).\n"
                                     "With --compare colmap: COLMAP's image_registrator registers the "
                                     "same queries into the same model\n"
                                     "(report in OUT/colmap/, side by side in OUT/comparison.md).");
  OptionTable t;
  add_options(t, args->run, args->lists);
  bind_options(cmd, t);
  cmd->callback([args] {
    EvaluationRunOptions o = args->run;
    read_list_files(args->lists, o);
    if (const std::string w = unlisted_intrinsics_warning(args->lists, o); !w.empty())
      std::cerr << "eval: " << w << "\n";
    o.progress = evaluation_progress_printer(std::cerr, ::isatty(STDERR_FILENO));
    const EvaluationRunResult r = run_evaluation(o);
    std::cout << r.report_markdown;
    if (r.colmap_report) std::cout << "\n" << r.comparison_markdown;
  });
}

}  // namespace visloc::cli
