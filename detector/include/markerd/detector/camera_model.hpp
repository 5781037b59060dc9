#pragma once
// Pinhole camera with OpenCV's distortion model, as OpenCV's calibration
// and ROS's camera_info write it (camera_matrix, distortion_coefficients,
// image_width, image_height). Distortion: 4, 5, 8 or 12 coefficients (k1 k2 p1 p2 [k3
// [k4 k5 k6 [s1 s2 s3 s4]]]); 14 only with a zero sensor tilt.

#include <array>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

#include "markerd/detector/geometry.hpp"

namespace markerd::detector {

class CameraModelError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The two formats of a camera file: OpenCV's calibration YAML (cv::FileStorage)
// and ROS's camera_info YAML.
enum class CameraFileFormat { opencv, ros };

struct CameraModel {
  int width = 0;
  int height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  // k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4; unused ones are zero.
  std::array<double, 12> dist{};

  // Reads a camera file in YAML: OpenCV's calibration output, ROS's
  // camera_info, or the same keys in JSON (XML is refused). Throws
  // CameraModelError naming the file, the line and the key that is
  // missing or wrong.
  static CameraModel load(const std::filesystem::path& path);
  // Writes OpenCV's format, or ROS's camera_info under `camera_name`: its
  // distortion_model plumb_bob (5 coefficients) or rational_polynomial (8;
  // a lens with thin-prism terms has no camera_info and is refused), the
  // rectification the identity and the projection [K | 0] (markerd works on
  // the raw image; rectified by image_proc it keeps the raw focal length).
  // Either reads back through load() to the same doubles.
  void save(const std::filesystem::path& path, CameraFileFormat format = CameraFileFormat::opencv,
            std::string_view camera_name = "camera") const;
  // The camera names save() writes into camera_info, as ROS names cameras
  // (head_camera): letters, digits and _, then also - . and /.
  static bool is_ros_camera_name(std::string_view name);

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
