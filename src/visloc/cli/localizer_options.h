// Binds LocalizerOptions to command-line flags (shared by `localize` and `eval`).
#pragma once

#include <CLI/CLI.hpp>
#include <cmath>
#include <string>

#include "visloc/cli/sift_options.h"
#include "visloc/pipeline/localizer.h"

namespace visloc::cli {

// A number that is finite and > 0 (CLI::Range lets NaN through).
inline CLI::Validator positive_finite_number() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        try {
          size_t used = 0;
          const double v = std::stod(text, &used);
          if (used == text.size() && std::isfinite(v) && v > 0) return {};
        } catch (const std::exception&) {
        }
        return "'" + text + "' is not a positive finite number";
      },
      "POSITIVE");
}

// `setting` receives the --setting text; parse it with parse_paper_setting.
inline void add_localizer_options(CLI::App* cmd, LocalizerOptions& o, std::string& setting) {
  cmd->add_option("--setting", setting, "The paper's ablation setting: 1, 2, 3 or 3+")
      ->check(CLI::IsMember({"1", "2", "3", "3+"}))
      ->capture_default_str();
  cmd->add_option("--top-images", o.top_images, "Retrieval: images N_t")->capture_default_str();
  cmd->add_option("--max-segments", o.max_segments, "Candidate segments searched")->capture_default_str();
  cmd->add_option("--accept-inliers", o.accept_inliers,
                  "Stop searching further candidate segments once a pose has this many inliers (0: search all)")
      ->capture_default_str();
  cmd->add_option("--early-stop", o.search.early_stop,
                  "Settings 3, 3+: the prioritized search stops at this many 1-1 matches (N_early)")
      ->capture_default_str();
  cmd->add_flag("!--no-fallback", o.full_search_fallback,
                "Settings 3, 3+: do not search all features again when the prioritized search fails");
  cmd->add_option("--threshold", o.ransac.threshold_px, "RANSAC reprojection threshold (px)")->capture_default_str();
  cmd->add_option("--min-inliers", o.ransac.min_inliers, "Registered at this many inliers")->capture_default_str();
  cmd->add_option("--min-confidence", o.min_confidence,
                  "... and at this confidence in [0, 1] (the builtin model's probability that the pose is right; "
                  "the default is chosen for a precision of 99.5%; 0: inliers only, the paper's rule)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  cmd->add_flag("!--no-exif-focal", o.use_exif_focal, "Ignore EXIF focal lengths");
  add_sift_options(cmd, o.sift);
}

}  // namespace visloc::cli
