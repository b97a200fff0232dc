// OpenCV's fundamental-matrix RANSAC as a yardstick for 2D-2D matches
// (bench features): a baseline, not part of the localizer.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "visloc/features/feature_set.h"

namespace visloc {

// Geometric verification of 2D-2D matches by a fundamental matrix (OpenCV
// RANSAC, threshold in pixels, confidence 0.999). OpenCV 4.6's RANSAC draws
// from its own fixed-seed generator (not cv::theRNG), so the result is
// reproducible and nothing global is touched. Returns the inlier mask.
std::vector<bool> fundamental_inliers(const std::vector<Keypoint>& points1,
                                      const std::vector<Keypoint>& points2,
                                      const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                      double threshold_px = 4.0);

}  // namespace visloc
