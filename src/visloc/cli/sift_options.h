// Binds SiftOptions to command-line flags (shared by every command that
// extracts features).
#pragma once

#include <CLI/CLI.hpp>

#include "visloc/features/sift_extractor.h"

namespace visloc::cli {

inline void add_sift_options(CLI::App* cmd, SiftOptions& o, bool with_max_side = true) {
  if (with_max_side)
    cmd->add_option("--max-side", o.max_image_side, "Downscale images whose longer side exceeds this (0: never)")
        ->capture_default_str();
  cmd->add_option("--max-features", o.max_features, "Keep at most this many features (strongest first)")
      ->capture_default_str();
  cmd->add_option("--contrast-threshold", o.contrast_threshold,
                  "SIFT contrast threshold (OpenCV's; 0.02 is close to COLMAP's default)")
      ->capture_default_str();
  cmd->add_flag("!--no-root-sift", o.root_sift, "Plain L2-normalized SIFT instead of RootSIFT");
  // OpenCV's pool is process-wide: set when the option is parsed (main sets 1 first).
  cmd->add_option_function<int>("--threads", [](int n) { set_opencv_threads(n); },
                                "OpenCV threads for SIFT [1]")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--max-pixels", o.image.max_pixels, "Refuse images with more pixels than this")
      ->capture_default_str();
}

}  // namespace visloc::cli
