// The SIFT options as command-line options (util/option_table.h).
#include <limits>

#include "visloc/features/sift_extractor.h"
#include "visloc/util/option_table.h"

namespace visloc {

void add_options(OptionTable& t, SiftOptions& o, bool with_max_side) {
  if (with_max_side)
    t.add("--max-side", o.max_image_side, "Downscale images whose longer side exceeds this (0: never)").non_negative();
  t.add("--max-features", o.max_features, "Keep at most this many features (strongest first)").positive();
  t.add("--contrast-threshold", o.contrast_threshold,
        "SIFT contrast threshold (OpenCV's; 0.02 is close to COLMAP's default)");
  t.flag("!--no-root-sift", o.root_sift, "Plain L2-normalized SIFT instead of RootSIFT");
  // OpenCV's pool is process-wide: set when the option is parsed (the CLI sets 1 first).
  t.text("--threads", "1",
         [](const std::string& text) {
           set_opencv_threads(static_cast<int>(parse_whole_number(text, "--threads", 1, std::numeric_limits<int>::max())));
         },
         "OpenCV threads for SIFT");
  t.add("--max-pixels", o.image.max_pixels, "Refuse images with more pixels than this");
}

}  // namespace visloc
