#pragma once
// Pinhole camera with OpenCV's distortion model, as OpenCV's calibration
// and ROS's camera_info write it (camera_matrix, distortion_coefficients,
// image_width, image_height). Distortion: 4, 5, 8 or 12 coefficients (k1 k2 p1 p2 [k3
// [k4 k5 k6 [s1 s2 s3 s4]]]); 14 only with a zero sensor tilt.

#include <array>
#include <filesystem>
#include <stdexcept>
#include <string>

#include "markerd/detector/geometry.hpp"

namespace markerd::detector {

class CameraModelError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CameraModel {
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  // k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4; unused ones are zero.
  std::array<double, 12> dist{};

  // Reads a camera file in YAML: OpenCV's calibration output, ROS's
  // camera_info, or the same keys in JSON (XML is refused). Throws
  // CameraModelError naming the file, the line and the key that is
  // missing or wrong. save() writes OpenCV's format.
  static CameraModel load(const std::filesystem::path& path);
  void save(const std::filesystem::path& path) const;

  // The camera of the thesis (640x480, its calibration): the reference for
  // the renderer, the tests, the benchmarks and the demonstration.
  static CameraModel thesis_640x480();

  // The same lens at another resolution (intrinsics scale with the image).
  [[nodiscard]] CameraModel scaled_to(int new_width, int new_height) const;

  [[nodiscard]] bool has_distortion() const;
  // Ideal normalized coordinates (x/z, y/z) -> distorted normalized coordinates.
  [[nodiscard]] Point2 distort(Point2 normalized) const;
  // Distorted normalized -> ideal normalized, iteratively (as OpenCV's
  // undistortPoints, but allocation-free and to convergence).
  [[nodiscard]] Point2 undistort(Point2 distorted_normalized) const;
  // Pixel <-> ideal normalized, with distortion.
  [[nodiscard]] Point2 pixel_to_normalized(Point2 pixel) const;
  [[nodiscard]] Point2 normalized_to_pixel(Point2 normalized) const;
};

}  // namespace markerd::detector
