#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_bench_retrieval(CLI::App& bench) {
  add_not_implemented(bench, "retrieval", "Image retrieval recall and time", "issue #7");
}

void add_retrieval_command(CLI::App& app) {}

}  // namespace visloc::cli
