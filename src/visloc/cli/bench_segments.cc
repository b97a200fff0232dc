// visloc bench segments: the paper's segment design study (eval/segment_study.h).
#include <unistd.h>

#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/eval/segment_study.h"

namespace visloc::cli {

void add_bench_segments(CLI::App& bench) {
  struct Args {
    SegmentStudyOptions options;
    std::filesystem::path out, city, kitti;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = bench.add_subcommand(
      "segments",
      "The paper's segment design study: build the same map with P placemarks per segment and O shared with "
      "neighbours, for every P and O (O < P), localize the same queries on each; report registration, median "
      "error, wrong poses, map bytes and build time as report.md and plots in --out (every configuration measured "
      "there so far). Resumes per configuration");
  OptionTable t;
  t.add("--out", a->out, "Study directory (DATASET/pP_oO/result.json, report.md, plots)").require();
  t.add("--city", a->city, "A 'visloc bench city' directory: its map images, positives and negatives (run that first)");
  t.add("--kitti", a->kitti, "KITTI directory (map = even frames with known poses, queries = odd frames)");
  add_options(t, a->options);
  bind_options(cmd, t);
  cmd->callback([a] {
    std::cout << run_segment_studies(a->out, a->city, a->kitti, a->options, std::cerr, ::isatty(STDERR_FILENO));
  });
}

}  // namespace visloc::cli
