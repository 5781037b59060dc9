#pragma once
// Planar pose of a square marker: IPPE (Collins and Bartoli, 2014) from four
// corners, both solutions kept, each polished by Levenberg-Marquardt on the
// pixel reprojection error through the full distortion model. Written with
// Eigen because OpenCV 4.6's SOLVEPNP_IPPE_SQUARE returns wrong rotations near
// a half turn (a marker facing the camera and turned only in yaw, the rig's
// ground truth) and NaN for a frontal on-axis marker in float (see
// tests/test_pose.cpp).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <optional>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/geometry.hpp"

namespace markerd::detector {

struct MarkerPose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // marker frame -> camera frame
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();   // marker centre in the camera frame, metres
  double reprojection_error_px = 0;                        // RMS over the corners used

  [[nodiscard]] Eigen::Vector3d rvec() const;  // Rodrigues vector
  [[nodiscard]] Eigen::Quaterniond quaternion() const;
};

struct PoseEstimate {
  MarkerPose best;
  std::optional<MarkerPose> alternative;  // IPPE's second solution
  // True when the second solution explains the corners almost as well as the
  // first (the flip ambiguity of a small or frontal marker).
  bool ambiguous = false;
};

// The two IPPE solutions for a square of side `side` (model corners at
// (-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2)) seen at ideal normalized
// image points in the same order. Returns nothing for a degenerate quad.
std::optional<std::array<MarkerPose, 2>> ippe_square(const std::array<Eigen::Vector2d, 4>& normalized, double side);

// Pose from pixel corners (TL, TR, BR, BL) of a square of side `side` metres.
std::optional<PoseEstimate> estimate_square_pose(const CameraModel& camera, const Quad& corners_px, double side);
// The same from ideal normalized corners, when the caller has undistorted them already.
std::optional<PoseEstimate> estimate_square_pose_normalized(const CameraModel& camera,
                                                            const std::array<Eigen::Vector2d, 4>& normalized,
                                                            double side);

// How a square's image is squeezed by its tilt against the line of sight
// through its centre: the part of the plane-to-image Jacobian there (in
// IPPE's frame) that is not a similarity, relative to the part that is. Its
// length is tan^2(tilt / 2); its direction turns with the tilt's axis. It is
// linear in the corners' noise, where the tilt is not: near a frontal view
// the tilt grows as the square root of the squeeze. Nothing for a
// degenerate quad.
std::optional<Eigen::Vector2d> square_tilt_anisotropy(const std::array<Eigen::Vector2d, 4>& normalized);

// A tilt is a length: noise in the squeeze adds to its square on average,
// whatever the true tilt, so that a square facing the line of sight is
// always found tilted, and, to cover the same pixels tilted, nearer than it
// is (a far marker's distance came out 0.5 % short). Given the variance of
// the squeeze's noise (the sum over its two components, from the fit the
// corners came from), this takes the variance out of the squared length,
// turns the pose's normal towards the line of sight in proportion, and fits
// the translation again to the corners (ideal normalized, TL TR BR BL of a
// square of side `side`). A pose tilted well beyond the noise is changed by
// a fraction of the noise; one within it is turned to face the camera.
void shrink_tilt_by_noise(const CameraModel& camera, const std::array<Eigen::Vector2d, 4>& normalized, double side,
                          double anisotropy_variance, MarkerPose& pose);

// Projects a point of the marker frame through pose and camera, to pixels.
Point2 project(const CameraModel& camera, const MarkerPose& pose, const Eigen::Vector3d& marker_point);

}  // namespace markerd::detector
