#include "visloc/baselines/opencv_pnp_baseline.h"

#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <vector>

#include "visloc/util/error.h"
#include "visloc/util/timer.h"

namespace visloc {

std::string_view to_string(OpenCvPnpMethod method) {
  switch (method) {
    case OpenCvPnpMethod::kP3pRansac: return "opencv-p3p-ransac";
    case OpenCvPnpMethod::kUsacMagsac: return "opencv-usac-magsac";
  }
  return "unknown";
}

void OpenCvPnpOptions::validate() const {
  if (!(threshold_px > 0)) throw_error(ErrorCode::kInvalidArgument, "opencv pnp: threshold_px must be positive");
  if (max_iterations <= 0) throw_error(ErrorCode::kInvalidArgument, "opencv pnp: max_iterations must be positive");
  if (!(confidence > 0 && confidence < 1))
    throw_error(ErrorCode::kInvalidArgument, "opencv pnp: confidence must be in (0, 1)");
}

OpenCvPnpResult estimate_pose_opencv(const CorrespondenceSet& corr, const PinholeCamera& camera, double focal_px,
                                     const OpenCvPnpOptions& options) {
  options.validate();
  corr.validate();
  OpenCvPnpResult result;
  Timer timer;
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t i = 0; i < corr.num_features(); ++i) {
    if (!corr.in_hypothesis_set[i]) continue;
    const Eigen::Vector3d& X = corr.candidates[corr.candidate_offsets[i]];
    object.emplace_back(X.x(), X.y(), X.z());
    image.emplace_back(corr.points2d[i].x(), corr.points2d[i].y());
  }
  if (object.size() < 4) {
    result.total_ms = timer.elapsed_ms();
    return result;
  }
  cv::Mat K = (cv::Mat_<double>(3, 3) << focal_px, 0, camera.cx, 0, focal_px * camera.aspect, camera.cy, 0, 0, 1);
  cv::Mat dist = (cv::Mat_<double>(1, 4) << camera.k1, 0, 0, 0);
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  bool ok = false;
  try {
    const int flags = options.method == OpenCvPnpMethod::kP3pRansac ? static_cast<int>(cv::SOLVEPNP_P3P)
                                                                     : static_cast<int>(cv::USAC_MAGSAC);
    ok = cv::solvePnPRansac(object, image, K, dist, rvec, tvec, false, options.max_iterations,
                            static_cast<float>(options.threshold_px), options.confidence, inliers, flags);
  } catch (const cv::Exception&) {
    ok = false;  // OpenCV throws on degenerate minimal samples in some versions: counts as no pose
  }
  result.total_ms = timer.elapsed_ms();
  if (!ok || rvec.empty() || tvec.empty()) return result;
  cv::Mat Rcv;
  cv::Rodrigues(rvec, Rcv);
  Eigen::Matrix3d R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R(r, c) = Rcv.at<double>(r, c);
  const Eigen::Vector3d t(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  if (!R.allFinite() || !t.allFinite()) return result;
  result.has_pose = true;
  result.cam_from_world = CameraPose::from_matrix(R, t);
  result.num_inliers = inliers.size();
  return result;
}

}  // namespace visloc
