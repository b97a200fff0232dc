// Command-line options of `visloc match` and `visloc bench pairs` (util/option_table.h).
#include "visloc/twoview/image_pair.h"
#include "visloc/twoview/pair_benchmark.h"
#include "visloc/util/option_table.h"

namespace visloc {

void add_options(OptionTable& t, ImagePairTask& task) {
  ImagePairOptions& o = task.options;
  t.add("image1", task.image1, "First image").require();
  t.add("image2", task.image2, "Second image").require();
  t.choice("--model", task.model,
           {{"auto", std::nullopt},
            {"F", TwoViewModel::kFundamental},
            {"H", TwoViewModel::kHomography},
            {"E", TwoViewModel::kEssential}},
           "F (fundamental, 7-point), H (homography, 4-point), E (essential, 5-point; needs --focal or\n"
           "--intrinsics), auto: E when calibrated, else F");
  t.choice("--ransac", o.estimation.variant,
           {{"classic", RansacVariant::kClassic11},
            {"1m", RansacVariant::kOneManyFixed},
            {"1m-sprt", RansacVariant::kOneManySprt}},
           "classic (1-1 hypotheses and verification, adaptive), 1m (1-M verification, fixed iterations),\n"
           "1m-sprt (1-M with SPRT, adaptive)");
  t.add("--focal", task.focal, "Focal length of both images, pixels (principal point at the centre)")
      .positive()
      .no_default();
  t.add("--intrinsics", task.intrinsics,
        "Intrinsics file: 'name MODEL width height params...' per image (by file name; '*' for all)");
  t.add("--out", task.drawing, "Write the inliers drawn side by side (.png or .jpg)");
  t.add("--threshold", o.estimation.threshold_px,
        "Inlier threshold: Sampson distance (F, E) or transfer error (H), pixels")
      .positive();
  t.add("--iterations", o.estimation.fixed_iterations, "Samples of --ransac 1m");
  t.add("--max-candidates", o.matching.max_candidates, "M: candidates per feature of the 1-M set");
  t.choice("--rule", o.matching.rule, {{"group", OneToManyRule::kGroupRatio}, {"best", OneToManyRule::kBestRatio}},
           "1-M set: 'group' (the near-equal candidates before the first clearly worse one) or 'best'\n"
           "(the top M when d0/d1 < 0.9)");
  t.add("--max-features", o.sift.max_features, "SIFT features per image");
  t.add("--max-side", o.sift.max_image_side, "Downscale larger images before SIFT");
  t.add("--seed", o.estimation.seed, "RANSAC seed");
}

void add_options(OptionTable& t, PairBenchmarkOptions& o) {
  t.add("--data", o.strecha_dir, "The Strecha folder (scenes with images/ and cameras/)");
  t.add("--scenes", o.scenes, "Strecha scenes (none: --scenes '')");
  t.add("--max-pairs", o.max_pairs_per_scene, "Pairs per scene (0: all)");
  t.add("--threshold", o.threshold_px, "Inlier threshold, pixels (every method)");
  t.add("--iterations", o.fixed_iterations, "Samples of 1m");
  t.add("--max-features", o.sift.max_features, "SIFT features per image");
  t.flag("!--no-opencv", o.opencv, "Skip OpenCV's findFundamentalMat");
  t.add("--seed", o.seed, "RANSAC seed");
}

}  // namespace visloc
