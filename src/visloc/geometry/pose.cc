#include "visloc/geometry/pose.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace visloc {

CameraPose CameraPose::from_matrix(const Eigen::Matrix3d& R, const Eigen::Vector3d& t) {
  CameraPose p;
  p.rotation = Eigen::Quaterniond(R).normalized();
  p.translation = t;
  return p;
}

CameraPose CameraPose::from_world_from_cam(const Eigen::Matrix3d& R_world_from_cam,
                                           const Eigen::Vector3d& center) {
  const Eigen::Matrix3d R = R_world_from_cam.transpose();
  return from_matrix(R, -R * center);
}

CameraPose CameraPose::from_wxyz(const std::array<double, 4>& q, const Eigen::Vector3d& t) {
  CameraPose p;
  p.rotation = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
  p.translation = t;
  return p;
}

Eigen::Matrix<double, 3, 4> CameraPose::matrix() const {
  Eigen::Matrix<double, 3, 4> m;
  m.leftCols<3>() = rotation_matrix();
  m.col(3) = translation;
  return m;
}

CameraPose CameraPose::inverse() const {
  CameraPose p;
  p.rotation = rotation.conjugate();
  p.translation = -(p.rotation * translation);
  return p;
}

CameraPose operator*(const CameraPose& a, const CameraPose& b) {
  CameraPose p;
  p.rotation = (a.rotation * b.rotation).normalized();
  p.translation = a.rotation * b.translation + a.translation;
  return p;
}

double rotation_error_deg(const CameraPose& a, const CameraPose& b) {
  const double c = std::abs((a.rotation.conjugate() * b.rotation).normalized().w());
  return 2.0 * std::acos(std::min(1.0, c)) * 180.0 / std::numbers::pi;
}

double position_error(const CameraPose& a, const CameraPose& b) {
  return (a.center() - b.center()).norm();
}

}  // namespace visloc
