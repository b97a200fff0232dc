// The feature benchmarks behind `visloc bench features` and `visloc bench
// sift-colmap`:
//   features     SIFT time and features per image at several maximum image
//                sides (medians over the set, one thread);
//   sift-colmap  how well our OpenCV SIFT matches COLMAP's SIFT of the same
//                images, compared with COLMAP matched to itself: verified
//                matches per adjacent image pair (query image i+1 against
//                reference image i; exact NN, ratio test, fundamental RANSAC).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "visloc/features/sift_extractor.h"

namespace visloc {

struct FeatureBenchmarkOptions {
  std::vector<std::string> inputs;         // image files or directories (searched recursively, sorted)
  std::vector<int> max_sides{1024, 1600};  // one measurement per maximum image side
  SiftOptions sift;                        // its max_image_side is replaced by each of max_sides
  // Throws Error(kInvalidArgument) naming the bad option.
  void validate() const;
};

struct FeatureBenchmarkResult {
  nlohmann::json report;  // {"features": [{"max_side", "images", "median_ms", "median_features", "min_ms", "max_ms"}]}
  std::string text;       // the number of images and a table, a row per maximum side
};

// Runs in the caller's thread (OpenCV's thread count is the caller's).
// `progress` (may be empty) receives each part of `text` as soon as it is
// known: the header, then a row per maximum side.
FeatureBenchmarkResult run_feature_benchmark(const FeatureBenchmarkOptions& options,
                                             const std::function<void(const std::string&)>& progress = {});

struct SiftColmapBenchmarkOptions {
  std::vector<std::string> scenes;  // scene folders with images/ and colmap/database.db
  double ratio = 0.8;               // ratio test threshold, in (0, 1]
  double threshold_px = 4.0;        // fundamental matrix RANSAC threshold, pixels (given to OpenCV as is)
  int max_image_side = 1600;        // of our SIFT
  // Throws Error(kInvalidArgument) naming the bad option.
  void validate() const;
};

struct SiftColmapBenchmarkResult {
  // {"scenes": [{"scene", "pairs", "colmap_median_features", "colmap_median_verified",
  // "methods": [{"name", "median_features", "median_verified", "median_ratio_to_colmap"}]}]}
  nlohmann::json report;
  std::string text;  // a paragraph per scene
};

// Our SIFT in four configurations (RootSIFT with contrast threshold 0.02, the
// same with 16384 features, 0.04, plain L2 SIFT). `progress` (may be empty)
// receives each scene's part of `text` as soon as it is known.
SiftColmapBenchmarkResult run_sift_colmap_benchmark(const SiftColmapBenchmarkOptions& options,
                                                    const std::function<void(const std::string&)>& progress = {});

class OptionTable;
// The options as command-line options (bench/option_tables.cc). Features: the images, --max-side (a list), the
// SIFT options but --max-side. Sift-colmap: --scene, --ratio, --threshold, --max-side.
void add_options(OptionTable& table, FeatureBenchmarkOptions& options);
void add_options(OptionTable& table, SiftColmapBenchmarkOptions& options);

}  // namespace visloc
