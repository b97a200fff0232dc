// Baseline for `visloc bench pose`: OpenCV's solvePnPRansac on the 1-1
// matches (hypothesis-set features, first candidate), with known intrinsics.
// Methods: SOLVEPNP_P3P inside OpenCV's classical RANSAC, and USAC_MAGSAC
// (MAGSAC++ scoring with local optimization). OpenCV types stay in the .cc.
#pragma once

#include <cstdint>
#include <string_view>

#include "visloc/geometry/camera.h"
#include "visloc/geometry/pose.h"
#include "visloc/geometry/correspondence_set.h"

namespace visloc {

enum class OpenCvPnpMethod { kP3pRansac, kUsacMagsac };
std::string_view to_string(OpenCvPnpMethod method);

struct OpenCvPnpOptions {
  OpenCvPnpMethod method = OpenCvPnpMethod::kUsacMagsac;
  double threshold_px = 4.0;
  int max_iterations = 10000;
  double confidence = 0.9999;
  void validate() const;
};

struct OpenCvPnpResult {
  bool has_pose = false;
  CameraPose cam_from_world;
  size_t num_inliers = 0;  // OpenCV's inlier list
  double total_ms = 0;
};

// `focal_px` is the focal length to give OpenCV (the camera's, or the true
// one when the camera has none). OpenCV 4.6's RANSAC (P3P) and USAC (MAGSAC)
// draw from their own fixed-seed generators, not cv::theRNG(): the result is
// reproducible without a seed, and nothing global is touched.
OpenCvPnpResult estimate_pose_opencv(const CorrespondenceSet& correspondences, const PinholeCamera& camera,
                                     double focal_px, const OpenCvPnpOptions& options);

}  // namespace visloc
