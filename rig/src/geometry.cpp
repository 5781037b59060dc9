#include "markerd/rig/geometry.hpp"

#include <Eigen/Geometry>
#include <numbers>

namespace markerd::rig {

MarkerGroundTruth ground_truth(const RigGeometry& g, double rail_mm, double turntable_deg) {
  MarkerGroundTruth truth;
  truth.distance_m = (g.d0_mm + g.rail_sign * rail_mm) / 1000.0;
  truth.yaw_deg = turntable_deg - g.yaw0_deg;
  // A marker facing the camera has its X along the camera's x, its Y up
  // (against the camera's y) and its Z towards the camera (against z).
  const Eigen::Matrix3d facing = Eigen::Vector3d(1, -1, -1).asDiagonal();
  const double yaw = truth.yaw_deg * std::numbers::pi / 180.0;
  truth.rotation = facing * Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d turntable_axis(-g.camera_offset_x_mm / 1000.0, -g.camera_offset_y_mm / 1000.0,
                                       truth.distance_m);
  const Eigen::Vector3d marker_offset(g.marker_offset_lateral_mm / 1000.0, 0.0, g.marker_offset_normal_mm / 1000.0);
  truth.translation = turntable_axis + truth.rotation * marker_offset;
  return truth;
}

PoseError pose_error(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                     const MarkerGroundTruth& truth) {
  const double offset_m = (translation - truth.translation).norm();
  const double truth_distance_m = truth.translation.norm();
  PoseError e;
  e.translation_mm = 1e3 * offset_m;
  e.translation_pct = 100 * offset_m / truth_distance_m;
  e.distance_mm = 1e3 * (translation.norm() - truth_distance_m);
  e.rotation_deg = Eigen::AngleAxisd(truth.rotation.transpose() * rotation).angle() * 180 / std::numbers::pi;
  return e;
}

}  // namespace markerd::rig
