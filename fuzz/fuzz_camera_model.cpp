// A camera model file (YAML: OpenCV's calibration, ROS's camera_info, JSON; XML is refused unparsed),
// as a markerd config's camera.model names them. CameraModel reads only
// from a path, so each input is written to a file in memory (/dev/shm)
// first. CameraModelError is the one error it may raise. A model it
// accepts must survive save and load unchanged, in OpenCV's format and in
// ROS's camera_info (unless it has thin-prism terms, which that refuses),
// and its distortion functions must run on it.

#include <algorithm>
#include <cmath>
#include <string>

#include <fmt/format.h>

#include "fuzz_support.hpp"
#include "markerd/detector/camera_model.hpp"

namespace {

bool same(const markerd::detector::CameraModel& a, const markerd::detector::CameraModel& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx && a.cy == b.cy &&
         a.dist == b.dist;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path input = markerd::fuzz::scratch_dir() / "camera.yaml";
  static const std::filesystem::path saved = markerd::fuzz::scratch_dir() / "camera-saved.yaml";
  markerd::fuzz::write_file(input, markerd::fuzz::as_text(data, size));
  markerd::detector::CameraModel model;
  try {
    model = markerd::detector::CameraModel::load(input);
  } catch (const markerd::detector::CameraModelError& e) {
    markerd::fuzz::expected_error(e);
    return 0;
  }
  for (const double v : {model.fx, model.fy, model.cx, model.cy}) {
    if (!std::isfinite(v)) markerd::fuzz::finding(fmt::format("a camera_matrix holding {} is accepted", v));
  }
  model.save(saved);
  const markerd::detector::CameraModel again = markerd::detector::CameraModel::load(saved);
  if (!same(model, again)) markerd::fuzz::finding("a camera model changes when saved and loaded again");
  // ROS's camera_info too, where the lens has one (no thin-prism terms).
  static const std::filesystem::path ros = markerd::fuzz::scratch_dir() / "camera-ros.yaml";
  const bool prism = std::any_of(model.dist.begin() + 8, model.dist.end(), [](double v) { return v != 0.0; });
  try {
    model.save(ros, markerd::detector::CameraFileFormat::ros);
    if (prism) markerd::fuzz::finding("a lens with thin-prism terms is written as ROS's camera_info");
    if (!same(model, markerd::detector::CameraModel::load(ros))) {
      markerd::fuzz::finding("a camera model changes when saved as ROS's camera_info and loaded again");
    }
  } catch (const markerd::detector::CameraModelError& e) {
    if (!prism) markerd::fuzz::finding(fmt::format("ROS's camera_info cannot be written: {}", e.what()));
  }

  const markerd::detector::CameraModel half =
      model.scaled_to(std::max(1, model.width / 2), std::max(1, model.height / 2));
  for (const auto& m : {model, half}) {
    for (const markerd::detector::Point2 pixel :
         {markerd::detector::Point2{0, 0}, markerd::detector::Point2{m.cx, m.cy},
          markerd::detector::Point2{static_cast<double>(m.width - 1), static_cast<double>(m.height - 1)}}) {
      const markerd::detector::Point2 normalized = m.pixel_to_normalized(pixel);
      (void)m.normalized_to_pixel(normalized);
    }
  }
  return 0;
}
