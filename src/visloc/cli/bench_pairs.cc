// visloc bench pairs: one-many RANSAC on image pairs (twoview/pair_benchmark.h); only binds options.
#include <algorithm>
#include <filesystem>
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/twoview/pair_benchmark.h"
#include "visloc/util/file_io.h"

namespace visloc::cli {

void add_bench_pairs(CLI::App& bench) {
  struct Args {
    std::filesystem::path out;
    std::vector<std::string> synthetic;
    PairBenchmarkOptions options;
  };
  auto args = std::make_shared<Args>();
  args->options.strecha_dir = std::string(VISLOC_DEFAULT_SHARED_DATA) + "/strecha";
  CLI::App* cmd = bench.add_subcommand(
      "pairs",
      "Two-view RANSAC on neighbouring pairs of the Strecha scenes (castle-P30/P19: repeated windows) against\n"
      "the laser cameras' F: classic, 1m, 1m-sprt and OpenCV findFundamentalMat (USAC_MAGSAC, RANSAC).\n"
      "Writes report.json and report.md in --out (success, true inliers, times; the issue's expectations).");
  OptionTable t;
  t.add("--out", args->out, "Report folder").require();
  t.add("--synthetic", args->synthetic,
        "Folders written by `visloc synth city`: synthetic facade pairs (one heading from neighbouring\n"
        "placemarks; truth from the rendered poses)");
  add_options(t, args->options);
  bind_options(cmd, t);
  cmd->callback([args] {
    PairBenchmarkOptions& o = args->options;
    o.synthetic_cities.assign(args->synthetic.begin(), args->synthetic.end());
    // `--scenes ''` leaves one empty name: no Strecha scene.
    o.scenes.erase(std::remove(o.scenes.begin(), o.scenes.end(), std::string()), o.scenes.end());
    const PairBenchmarkResult r =
        run_pair_benchmark(o, [](const std::string& line) { std::cerr << "bench pairs: " << line << "\n"; });
    std::filesystem::create_directories(args->out);
    write_file_atomic(args->out / "report.json", r.report.dump(2));
    write_file_atomic(args->out / "report.md", r.markdown);
    std::cout << r.markdown;
  });
}

}  // namespace visloc::cli
