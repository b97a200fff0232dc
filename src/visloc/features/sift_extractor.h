// SiftExtractor: OpenCV's SIFT with COLMAP-compatible descriptors.
// Descriptors become uint8 the way COLMAP stores them: RootSIFT (L1
// normalization, element-wise square root) by default, or L2 normalization,
// then round(512 × value) clamped to 255. This lets our features query maps
// built from COLMAP's own SIFT. Output is deterministic: keypoints sorted by
// response (then position), truncated to max_features.
#pragma once

#include <filesystem>
#include <memory>
#include <string>

#include "visloc/features/feature_set.h"
#include "visloc/image/image_io.h"

namespace visloc {

struct SiftOptions {
  int max_image_side = 1600;        // downscale larger images before SIFT (0: never)
  int max_features = 8192;          // keep the strongest (COLMAP's default)
  double contrast_threshold = 0.02; // OpenCV's contrastThreshold; 0.02 ≈ COLMAP's peak threshold
  double edge_threshold = 10.0;
  double sigma = 1.6;
  int octave_layers = 3;
  bool root_sift = true;            // RootSIFT before uint8 scaling (COLMAP's default)
  ImageReadOptions image;

  void validate() const;
  std::string to_json() const;
};

class OptionTable;
// The options as command-line options: --max-side (unless !with_max_side),
// --max-features, --contrast-threshold, --no-root-sift, --threads, --max-pixels.
void add_options(OptionTable& table, SiftOptions& options, bool with_max_side = true);

class SiftExtractor {
 public:
  explicit SiftExtractor(const SiftOptions& options = {});
  ~SiftExtractor();
  SiftExtractor(const SiftExtractor&) = delete;
  SiftExtractor& operator=(const SiftExtractor&) = delete;

  const SiftOptions& options() const { return options_; }
  FeatureSet extract(const GrayImage& image) const;
  FeatureSet extract_file(const std::filesystem::path& path, ImageMetadata* metadata = nullptr) const;

 private:
  struct Impl;
  SiftOptions options_;
  std::unique_ptr<Impl> impl_;
};

// OpenCV's thread pool, which SIFT uses, is process-wide: the library never
// changes it. A program sets it once (the CLI: --threads, default 1 so that a
// query uses one core; the C API: options.threads; Python:
// visloc.set_opencv_threads). threads >= 1, else Error(kInvalidArgument).
void set_opencv_threads(int threads);

// Float SIFT descriptor (any positive scale) → COLMAP's uint8 encoding.
void sift_to_uint8(const float* in, bool root_sift, uint8_t* out);

}  // namespace visloc
