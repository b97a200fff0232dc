#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_bench_matching(CLI::App& bench) {
  add_not_implemented(bench, "matching", "2D-3D matching: CCS against exact, FAISS and LSH", "issue #3");
}

}  // namespace visloc::cli
