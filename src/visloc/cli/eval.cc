#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_eval_command(CLI::App& app) {
  add_not_implemented(app, "eval", "Evaluate localization against ground truth and write a report", "issue #8");
}

}  // namespace visloc::cli
