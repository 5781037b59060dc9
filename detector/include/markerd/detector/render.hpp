#pragma once
// The scene renderer: a printed marker at a pose in front of a camera model,
// over a cluttered background, the way a real camera would see it. It is the
// ground truth of the tests and benchmarks and the seed of the simulated
// camera. Deterministic for a given seed.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <optional>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/image.hpp"
#include "markerd/detector/pose.hpp"

namespace markerd::detector {

// What lies at a point of the printed marker: reflectance 0 (ink) .. 1
// (paper), or nothing (the frame8 hole when cut out, and outside the print).
class MarkerPattern {
 public:
  // frame8's hole is cut out when `cut_hole`, printed white otherwise.
  MarkerPattern(Family family, int id, bool cut_hole = false);
  // u, v in units of the family's size: the marker square spans [-0.5, 0.5]
  // (u to the right, v up); the quiet zone of ArUco and AprilTag lies
  // outside it and is printed white.
  [[nodiscard]] std::optional<float> reflectance(double u, double v) const;
  // Half-width of the printed area (marker plus quiet zone), in the same units.
  [[nodiscard]] double printed_half_extent() const { return half_extent_; }
  [[nodiscard]] Family family() const { return family_; }
  [[nodiscard]] int id() const { return id_; }

 private:
  Family family_;
  int id_;
  bool cut_hole_;
  double half_extent_ = 0.5;
  int grid_ = 10;                    // cells across the marker square
  std::vector<std::uint8_t> cells_;  // grid_ x grid_, row 0 at the top; 1 = white
};

struct Scene {
  Family family = Family::frame8;
  int id = 165;
  double marker_size_m = 0.08;
  bool cut_hole = false;
  MarkerPose pose;  // marker frame in the camera frame

  // Imaging: grey levels of ink and paper under the exposure.
  double exposure = 1.0;  // scales the whole image (1 = paper at ~225)
  double blur_sigma_px = 0.0;
  double noise_sigma = 0.0;  // grey levels, Gaussian
  int supersample = 4;       // samples per pixel along each axis
  bool clutter = true;       // random shapes in the background
  bool distort = true;       // apply the camera's lens distortion
  std::uint64_t seed = 1;
};

// A pose looking straight at the marker from `distance_m`, the marker turned
// by `yaw_deg` about its own vertical axis (as the rig's turntable does), and
// `roll_deg` in its plane; offset_px moves it off the optical axis.
MarkerPose facing_pose(double distance_m, double yaw_deg, double pitch_deg = 0, double roll_deg = 0,
                       double offset_x_m = 0, double offset_y_m = 0);

GreyImage render_scene(const CameraModel& camera, const Scene& scene);

// Pixel positions of the marker's outer corners (TL, TR, BR, BL) in the
// rendered image, through the same model as render_scene (truth for tests).
Quad project_marker_corners(const CameraModel& camera, const Scene& scene, double scale = 1.0);

// Clutter only (the same background render_scene draws), for false-positive tests.
GreyImage render_background(const CameraModel& camera, const Scene& scene);

}  // namespace markerd::detector
