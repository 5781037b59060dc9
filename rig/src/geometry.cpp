#include "markerd/rig/geometry.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <numbers>

namespace markerd::rig {

namespace {

double radians(double degrees) { return degrees * std::numbers::pi / 180.0; }

// The unit vector along which the turntable axis moves in the camera frame
// as rail_sign * rail grows; exactly (0, 0, 1) without a tilt.
Eigen::Vector3d rail_direction(const RigGeometry& g) {
  const double a = radians(g.rail_tilt_x_deg);
  const double b = radians(g.rail_tilt_y_deg);
  return {std::sin(a) * std::cos(b), std::sin(b), std::cos(a) * std::cos(b)};
}

}  // namespace

double axis_distance_mm(const RigGeometry& g, double rail_mm) {
  return g.d0_mm + g.rail_sign * rail_mm * rail_direction(g).z();
}

double rail_for_distance_mm(const RigGeometry& g, double distance_mm) {
  // rail_sign is +-1: its own inverse.
  return (distance_mm - g.d0_mm) * g.rail_sign / rail_direction(g).z();
}

MarkerGroundTruth ground_truth(const RigGeometry& g, double rail_mm, double turntable_deg) {
  MarkerGroundTruth truth;
  const Eigen::Vector3d along = g.rail_sign * rail_mm * rail_direction(g);
  truth.distance_m = (g.d0_mm + along.z()) / 1000.0;
  truth.yaw_deg = turntable_deg - g.yaw0_deg;
  // A marker facing the camera has its X along the camera's x, its Y up
  // (against the camera's y) and its Z towards the camera (against z).
  const Eigen::Matrix3d facing = Eigen::Vector3d(1, -1, -1).asDiagonal();
  const double yaw = radians(truth.yaw_deg);
  truth.rotation = facing * Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d turntable_axis((along.x() - g.camera_offset_x_mm) / 1000.0,
                                       (along.y() - g.camera_offset_y_mm) / 1000.0, truth.distance_m);
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
