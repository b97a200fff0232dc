// visloc match A B [--model auto|F|H|E] [--ransac classic|1m|1m-sprt] [--focal PX | --intrinsics FILE]
//                  [--out matches.png] [--json]
#include <iostream>
#include <memory>

#include "visloc/cli/commands.h"
#include "visloc/geometry/pose_list.h"
#include "visloc/image/image_io.h"
#include "visloc/twoview/image_pair.h"
#include "visloc/util/error.h"

namespace visloc::cli {

void add_match_command(CLI::App& app) {
  struct Args {
    std::string image1, image2, model = "auto", ransac = "1m-sprt", intrinsics, out, rule = "group";
    double focal = 0;
    bool json = false;
    ImagePairOptions options;
  };
  auto args = std::make_shared<Args>();
  args->options.sift.max_image_side = 1600;
  CLI::App* cmd = app.add_subcommand(
      "match",
      "Two-view geometry of an image pair with the paper's one-many RANSAC: SIFT, exact nearest neighbours,\n"
      "hypotheses from the 1-1 matches (ratio 0.8), verification on the 1-M matches (ratio 0.9, up to 5\n"
      "candidates: repeated windows), SPRT. Writes F, H or E, inlier counts and times, and with --out the\n"
      "inliers side by side: 1-1 in green, the extra inliers 1-M verification found in orange.");
  cmd->add_option("image1", args->image1, "First image")->required()->check(CLI::ExistingFile);
  cmd->add_option("image2", args->image2, "Second image")->required()->check(CLI::ExistingFile);
  cmd->add_option("--model", args->model,
                  "F (fundamental, 7-point), H (homography, 4-point), E (essential, 5-point; needs --focal or\n"
                  "--intrinsics), auto: E when calibrated, else F")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "F", "H", "E"}));
  cmd->add_option("--ransac", args->ransac,
                  "classic (1-1 hypotheses and verification, adaptive), 1m (1-M verification, fixed iterations),\n"
                  "1m-sprt (1-M with SPRT, adaptive)")
      ->capture_default_str()
      ->check(CLI::IsMember({"classic", "1m", "1m-sprt"}));
  cmd->add_option("--focal", args->focal, "Focal length of both images, pixels (principal point at the centre)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--intrinsics", args->intrinsics,
                  "Intrinsics file: 'name MODEL width height params...' per image (by file name; '*' for all)");
  cmd->add_option("--out", args->out, "Write the inliers drawn side by side (.png or .jpg)");
  cmd->add_option("--threshold", args->options.estimation.threshold_px,
                  "Inlier threshold: Sampson distance (F, E) or transfer error (H), pixels")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--iterations", args->options.estimation.fixed_iterations, "Samples of --ransac 1m")
      ->capture_default_str();
  cmd->add_option("--max-candidates", args->options.matching.max_candidates, "M: candidates per feature of the 1-M set")
      ->capture_default_str();
  cmd->add_option("--rule", args->rule,
                  "1-M set: 'group' (the near-equal candidates before the first clearly worse one) or 'best'\n"
                  "(the top M when d0/d1 < 0.9)")
      ->capture_default_str()
      ->check(CLI::IsMember({"group", "best"}));
  cmd->add_option("--max-features", args->options.sift.max_features, "SIFT features per image")->capture_default_str();
  cmd->add_option("--max-side", args->options.sift.max_image_side, "Downscale larger images before SIFT")
      ->capture_default_str();
  cmd->add_option("--seed", args->options.estimation.seed, "RANSAC seed")->capture_default_str();
  cmd->add_flag("--json", args->json, "Print the result as JSON");
  cmd->callback([args] {
    namespace fs = std::filesystem;
    ImagePairOptions o = args->options;
    o.estimation.variant = args->ransac == "classic" ? RansacVariant::kClassic11
                           : args->ransac == "1m"    ? RansacVariant::kOneManyFixed
                                                     : RansacVariant::kOneManySprt;
    o.matching.rule = args->rule == "best" ? OneToManyRule::kBestRatio : OneToManyRule::kGroupRatio;
    if (args->focal > 0 && !args->intrinsics.empty())
      throw_error(ErrorCode::kInvalidArgument, "match: give --focal or --intrinsics, not both");
    std::optional<PinholeCamera> cams[2];
    const std::string paths[2] = {args->image1, args->image2};
    if (!args->intrinsics.empty()) {
      const auto list = read_intrinsics_list(args->intrinsics);
      for (int k = 0; k < 2; ++k) {
        const std::string name = fs::path(paths[k]).filename().string();
        for (const auto& c : list)  // the image's own line first, then '*'
          if (c.name == name) cams[k] = c.camera;
        if (!cams[k])
          for (const auto& c : list)
            if (c.name == "*") cams[k] = c.camera;
        if (!cams[k])
          throw_error(ErrorCode::kInvalidArgument, args->intrinsics, ": no line for ", name, " (nor '*')");
        const ImageMetadata m = read_image_metadata(paths[k]);
        if (cams[k]->width != m.width || cams[k]->height != m.height)
          throw_error(ErrorCode::kInvalidArgument, args->intrinsics, ": the line for ", name, " is for ", cams[k]->width,
                      "x", cams[k]->height, " pixels, the image has ", m.width, "x", m.height);
        if (!cams[k]->has_focal)
          throw_error(ErrorCode::kInvalidArgument, args->intrinsics, ": the line for ", name, " has no focal length");
      }
    } else if (args->focal > 0) {
      for (int k = 0; k < 2; ++k) {
        const ImageMetadata m = read_image_metadata(paths[k]);
        cams[k] = PinholeCamera::centered(m.width, m.height, args->focal);
      }
    }
    const bool calibrated = cams[0].has_value();
    const std::string model = args->model == "auto" ? (calibrated ? "E" : "F") : args->model;
    o.estimation.model = parse_two_view_model(model);
    if (o.estimation.model == TwoViewModel::kEssential) {
      if (!calibrated) throw_error(ErrorCode::kInvalidArgument, "match: --model E needs --focal or --intrinsics");
      for (int k = 0; k < 2; ++k) {
        if (cams[k]->k1 != 0)  // the solver and the errors use K⁻¹ x on the keypoints as they are
          throw_error(ErrorCode::kInvalidArgument, args->intrinsics, ": --model E needs undistorted cameras (k1 = 0); ",
                      "use --model F for ", paths[k]);
        Eigen::Matrix3d K;
        K << cams[k]->focal, 0, cams[k]->cx, 0, cams[k]->focal, cams[k]->cy, 0, 0, 1;
        (k == 0 ? o.estimation.calibration1 : o.estimation.calibration2) = K;
      }
    }
    const ImagePairResult r = match_image_pair(args->image1, args->image2, o);
    if (!args->out.empty()) draw_pair_inliers(args->image1, args->image2, r, args->out);
    if (args->json) {
      std::cout << r.to_json().dump() << "\n";
      return;
    }
    std::cout << r.features1.size() << " and " << r.features2.size() << " features; " << r.one_to_one_matches()
              << " 1-1 matches, " << r.matches.size() << " features with 1-M candidates\n";
    if (!r.estimate.found) {
      std::cout << "no " << model << " found\n";
      return;
    }
    std::cout << model << " (" << args->ransac << "): " << r.estimate.inliers << " inliers (" << r.estimate.one_to_one_inliers
              << " 1-1, " << r.estimate.extra_inliers << " more through 1-M); " << r.estimate.stats.iterations
              << " samples, " << r.estimate.stats.models_rejected_sprt << " models rejected by SPRT\n";
    std::cout << r.estimate.matrix << "\n";
    std::cout << "times (ms): features " << r.ms_features << ", matching " << r.ms_matching << ", RANSAC "
              << r.estimate.total_ms << "\n";
    if (!args->out.empty()) std::cout << "wrote " << args->out << "\n";
  });
}

}  // namespace visloc::cli
