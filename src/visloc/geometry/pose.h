// CameraPose: the rigid transform cam_from_world (world → camera):
// X_cam = R X_world + t. The quaternion is Hamilton, stored and printed in
// w, x, y, z order (COLMAP and visuallocalization.net use the same). The
// camera centre in world coordinates is C = -R^T t.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>

namespace visloc {

struct CameraPose {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();  // cam_from_world
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  static CameraPose from_matrix(const Eigen::Matrix3d& R, const Eigen::Vector3d& t);
  // From a camera-to-world rotation and a centre (Strecha, KITTI conventions).
  static CameraPose from_world_from_cam(const Eigen::Matrix3d& R_world_from_cam,
                                        const Eigen::Vector3d& center);
  static CameraPose from_wxyz(const std::array<double, 4>& q_wxyz, const Eigen::Vector3d& t);

  Eigen::Matrix3d rotation_matrix() const { return rotation.toRotationMatrix(); }
  Eigen::Vector3d center() const { return -(rotation.conjugate() * translation); }
  Eigen::Vector3d transform(const Eigen::Vector3d& world) const { return rotation * world + translation; }
  std::array<double, 4> q_wxyz() const { return {rotation.w(), rotation.x(), rotation.y(), rotation.z()}; }
  Eigen::Matrix<double, 3, 4> matrix() const;
  CameraPose inverse() const;  // world_from_cam
  // Viewing direction (camera +z) in world coordinates.
  Eigen::Vector3d viewing_direction() const { return rotation.conjugate() * Eigen::Vector3d::UnitZ(); }
};

// Composition: (a * b)(X) = a(b(X)).
CameraPose operator*(const CameraPose& a, const CameraPose& b);

// Angle of the relative rotation between two poses, degrees.
double rotation_error_deg(const CameraPose& a, const CameraPose& b);
// Distance between camera centres.
double position_error(const CameraPose& a, const CameraPose& b);

}  // namespace visloc
