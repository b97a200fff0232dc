// visloc bench pose: robust absolute pose on synthetic correspondence sets
// (bench/pose_benchmark.h); only binds options.
#include <iostream>
#include <memory>

#include "bench/pose_benchmark.h"
#include "visloc/cli/commands.h"
#include "visloc/util/error.h"

namespace visloc::cli {

void add_bench_pose(CLI::App& bench) {
  struct Args {
    PoseBenchmarkOptions options;
    bool skip_opencv = false;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  PoseBenchmarkOptions& o = args->options;
  CLI::App* cmd = bench.add_subcommand(
      "pose",
      "Pose estimation on synthetic 2D-3D correspondence sets: classical RANSAC, one-many RANSAC (fixed, SPRT)\n"
      "and OpenCV solvePnPRansac (P3P, USAC MAGSAC) in the same run");
  cmd->add_option("--family", o.families, "Families: calibrated, uncalibrated, facade")->capture_default_str();
  cmd->add_option("--features", o.features, "Numbers of query features")->capture_default_str();
  cmd->add_option("--inlier-ratio", o.inlier_ratios, "Inlier ratios of the 1-1 set")->capture_default_str();
  cmd->add_option("--trials", o.trials, "Trials per (family, features, inlier ratio)")->capture_default_str();
  cmd->add_option("--noise", o.noise_px, "Pixel noise (standard deviation)")->capture_default_str();
  cmd->add_option("--max-candidates", o.max_candidates, "Candidate list length M")->capture_default_str();
  cmd->add_option("--seed", o.seed, "Seed of the problems and the estimators")->capture_default_str();
  cmd->add_option("--threshold", o.ransac.threshold_px, "Reprojection threshold, pixels")->capture_default_str();
  cmd->add_option("--max-iterations", o.ransac.max_iterations, "Sample cap of the adaptive RANSACs")
      ->capture_default_str();
  cmd->add_option("--fixed-iterations", o.ransac.fixed_iterations, "Samples of 1-M fixed")->capture_default_str();
  cmd->add_option("--opencv-iterations", o.opencv_iterations, "Iteration cap of OpenCV's RANSACs")
      ->capture_default_str();
  cmd->add_flag("--no-opencv", args->skip_opencv, "Skip the OpenCV baselines");
  cmd->add_flag("--json", args->json, "Print JSON");
  cmd->callback([args] {
    if (args->options.trials <= 0) throw_error(ErrorCode::kInvalidArgument, "--trials must be positive");
    args->options.opencv = !args->skip_opencv;
    const PoseBenchmarkResult r = run_pose_benchmark(args->options);
    if (args->json) std::cout << r.report.dump(2) << "\n";
    else std::cout << r.table;
  });
}

}  // namespace visloc::cli
