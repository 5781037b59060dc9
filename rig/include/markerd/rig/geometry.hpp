#pragma once
// The rig's geometry: where the marker is in the camera's frame for a pair of
// axis positions, the ground truth every detected pose is logged beside.
//
// Frames (docs/frame-marker.md): the camera frame is OpenCV's (x right, y
// down, z forward along the optical axis); the marker frame has X right, Y up
// and Z out of the printed face towards the viewer. The rail moves the camera
// along its optical axis; the turntable turns the marker about a vertical axis
// (the marker's Y). With no mount offsets and no rail tilt this is exactly
// the detector's facing_pose(d, yaw): t = (0, 0, d), R = diag(1, -1, -1) *
// Ry(yaw), so a positive yaw turns the marker's right edge away from the
// camera.

#include <Eigen/Core>

namespace markerd::rig {

struct RigGeometry {
  // Distance along the optical axis from the camera centre to the turntable
  // axis at rail position 0: d = d0 + rail_sign * rail. It is the distance to
  // the marker centre when the marker sits on the turntable axis.
  double d0_mm = 300.0;
  // The turntable angle at which the marker faces the camera: yaw = turntable - yaw0.
  double yaw0_deg = 0.0;
  // +1: a positive rail position moves the camera away from the marker; -1: towards it.
  int rail_sign = +1;
  // Where the camera's optical centre sits beside the rail's line through the
  // turntable axis, along the camera's x (right) and y (down).
  double camera_offset_x_mm = 0.0;
  double camera_offset_y_mm = 0.0;
  // Where the marker centre sits relative to the turntable axis, in the
  // marker's own frame (so the offset turns with it): along its normal
  // (+: in front of the axis, towards the viewer) and sideways (+: to the
  // marker's right).
  double marker_offset_normal_mm = 0.0;
  double marker_offset_lateral_mm = 0.0;
  // The rail's direction in the camera frame, which a camera clamped to its
  // carriage at a slight angle does not share with the optical axis: as
  // rail_sign * rail grows the turntable axis moves, in the camera frame,
  // along (sin a cos b, sin b, cos a cos b) with a = rail_tilt_x_deg
  // (towards the camera's x, right) and b = rail_tilt_y_deg (towards its y,
  // down). Zero: along the optical axis.
  double rail_tilt_x_deg = 0.0;
  double rail_tilt_y_deg = 0.0;
};

// The distance along the optical axis from the camera centre to the
// turntable axis at a rail position (mm), and the rail position at which it
// is `distance_mm`: d = d0 + rail_sign * rail * cos a cos b.
[[nodiscard]] double axis_distance_mm(const RigGeometry& geometry, double rail_mm);
[[nodiscard]] double rail_for_distance_mm(const RigGeometry& geometry, double distance_mm);

// The marker frame in the camera frame: x_camera = rotation * x_marker + translation.
struct MarkerGroundTruth {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();  // metres
  double distance_m = 0;                                  // d, camera centre to turntable axis along the optical axis
  double yaw_deg = 0;                                     // turntable - yaw0
};

[[nodiscard]] MarkerGroundTruth ground_truth(const RigGeometry& geometry, double rail_mm, double turntable_deg);

// How far an estimated marker pose (x_camera = rotation * x_marker +
// translation, metres) is from the truth: what the detection log and the
// sweep records report for every pose.
struct PoseError {
  double translation_mm = 0;   // |t - t_truth|
  double translation_pct = 0;  // of |t_truth| (inf or nan for a zero truth distance)
  double distance_mm = 0;      // |t| - |t_truth|, signed
  double rotation_deg = 0;     // the angle of R_truth^T R
};
[[nodiscard]] PoseError pose_error(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                                   const MarkerGroundTruth& truth);

}  // namespace markerd::rig
