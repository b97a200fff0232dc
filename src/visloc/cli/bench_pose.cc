#include "visloc/cli/commands.h"

namespace visloc::cli {

void add_bench_pose(CLI::App& bench) {
  add_not_implemented(bench, "pose", "Pose estimation: 1-M RANSAC against classical and OpenCV", "issue #4");
}

}  // namespace visloc::cli
