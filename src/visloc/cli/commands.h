// The visloc command line: one function per subcommand, each a thin layer
// that binds options to a library call. Errors are visloc::Error exceptions;
// main() maps them to a message and an exit status.
#pragma once

#include <CLI/CLI.hpp>

#include "visloc/cli/option_binding.h"

namespace visloc::cli {

// Exit statuses.
inline constexpr int kExitOk = 0;
inline constexpr int kExitUserError = 1;   // bad input, bad file, failed external tool
inline constexpr int kExitUsage = 2;       // bad command line (CLI11)
inline constexpr int kExitNotImplemented = 3;
inline constexpr int kExitInternal = 4;

void add_features_command(CLI::App& app);
void add_map_command(CLI::App& app);
void add_map_build_commands(CLI::App& map);  // map build, map update
void add_localize_command(CLI::App& app);
void add_eval_command(CLI::App& app);
void add_synth_command(CLI::App& app);
void add_view_command(CLI::App& app);
void add_match_command(CLI::App& app);
void add_bench_command(CLI::App& app);
// `visloc retrieval build|query`: the retrieval stage on its own (bench_retrieval.cc).
void add_retrieval_command(CLI::App& app);

// `visloc bench` kinds, one file each.
void add_bench_features(CLI::App& bench);
void add_bench_sift_colmap(CLI::App& bench);
void add_bench_matching(CLI::App& bench);
void add_bench_pose(CLI::App& bench);
void add_bench_retrieval(CLI::App& bench);
void add_bench_end_to_end(CLI::App& bench);
void add_bench_city(CLI::App& bench);
void add_bench_segments(CLI::App& bench);
void add_bench_confidence(CLI::App& bench);
void add_bench_pairs(CLI::App& bench);

}  // namespace visloc::cli
