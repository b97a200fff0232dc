// visloc match A B [--model auto|F|H|E] [--ransac classic|1m|1m-sprt] [--focal PX | --intrinsics FILE]
//                  [--out matches.png] [--json]
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/cli/option_binding.h"
#include "visloc/twoview/image_pair.h"

namespace visloc::cli {

void add_match_command(CLI::App& app) {
  struct Args {
    ImagePairTask task;
    bool json = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "match",
      "Two-view geometry of an image pair with the paper's one-many RANSAC: SIFT, exact nearest neighbours,\n"
      "hypotheses from the 1-1 matches (ratio 0.8), verification on the 1-M matches (ratio 0.9, up to 5\n"
      "candidates: repeated windows), SPRT. Writes F, H or E, inlier counts and times, and with --out the\n"
      "inliers side by side: 1-1 in green, the extra inliers 1-M verification found in orange.");
  OptionTable t;
  add_options(t, args->task);
  t.flag("--json", args->json, "Print the result as JSON");
  bind_options(cmd, t);
  for (const char* image : {"image1", "image2"}) cmd->get_option(image)->check(CLI::ExistingFile);
  cmd->callback([args] {
    const ImagePairTask& task = args->task;
    const ImagePairOptions options = resolve_image_pair_options(task);
    const ImagePairResult r = match_image_pair(task.image1, task.image2, options);
    if (!task.drawing.empty()) draw_pair_inliers(task.image1, task.image2, r, task.drawing);
    if (args->json)
      std::cout << r.to_json().dump() << "\n";
    else
      std::cout << image_pair_summary(r, options.estimation, task.drawing);
  });
}

}  // namespace visloc::cli
