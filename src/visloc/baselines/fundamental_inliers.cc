#include "visloc/baselines/fundamental_inliers.h"

#include <opencv2/calib3d.hpp>

#include "visloc/util/error.h"

namespace visloc {

std::vector<bool> fundamental_inliers(const std::vector<Keypoint>& points1, const std::vector<Keypoint>& points2,
                                      const std::vector<std::pair<uint32_t, uint32_t>>& matches,
                                      double threshold_px) {
  std::vector<bool> inlier(matches.size(), false);
  if (matches.size() < 8) return inlier;
  std::vector<cv::Point2f> a, b;
  for (auto [i, j] : matches) {
    VISLOC_CHECK(i < points1.size() && j < points2.size());
    a.emplace_back(points1[i].x, points1[i].y);
    b.emplace_back(points2[j].x, points2[j].y);
  }
  cv::Mat mask;
  cv::Mat F = cv::findFundamentalMat(a, b, cv::FM_RANSAC, threshold_px, 0.999, 10000, mask);
  if (F.empty() || mask.empty()) return inlier;
  for (size_t k = 0; k < matches.size(); ++k) inlier[k] = mask.at<uchar>(static_cast<int>(k)) != 0;
  return inlier;
}

}  // namespace visloc
