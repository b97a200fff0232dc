#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_synth_command(CLI::App& app) {
  CLI::App* synth = app.add_subcommand("synth", "Generate synthetic data with exact ground truth");
  synth->require_subcommand(1);
  add_not_implemented(*synth, "city", "Render a synthetic street-view city", "issue #5");
}

}  // namespace visloc::cli
