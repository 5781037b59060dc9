#pragma once
// Detector evaluation on rendered scenes: for each (distance, yaw) point,
// render frames with the scene model (noise, blur, clutter), detect them and
// compare against the truth. The numbers the figures are stated in.

#include <cstdint>
#include <functional>
#include <vector>

#include "markerd/detector/camera_model.hpp"
#include "markerd/detector/detector.hpp"
#include "markerd/detector/render.hpp"

namespace markerd::detector {

struct EvalPoint {
  double distance_m = 1;
  double yaw_deg = 0;
};

struct EvalSettings {
  Scene scene;  // family, id, size, imaging; pose is set per frame
  int frames_per_point = 50;
  // Each frame jitters the pose so frames are not copies: the marker centre
  // moves within this many pixels of the principal point, rolls within
  // +-roll_jitter_deg and the id is drawn at random when random_ids.
  double position_jitter_px = 40;
  double roll_jitter_deg = 5;
  bool random_ids = true;
  std::uint64_t seed = 1;
  // Occluders that take turns: frame i adds set i % size to the scene's
  // own (for example each side of the marker covered in turn).
  std::vector<std::vector<Occluder>> occluder_turns;
  // Backgrounds that take turns the same way (frame i draws kind i % size,
  // when the scene has clutter); empty: the scene's own.
  std::vector<Background> background_turns;
  // Called for each frame with a detection of another id than the scene's:
  // the image, its scene and what was found, to look at afterwards.
  std::function<void(const GreyImage&, const Scene&, const std::vector<Detection>&)> on_wrong_id;
  // Called for each frame in which the scene's marker was not found.
  std::function<void(const GreyImage&, const Scene&)> on_miss;
};

struct EvalResult {
  EvalPoint point;
  int frames = 0;
  int detected = 0;                      // the right id, once
  int wrong_id = 0;                      // detections with another id (false positives)
  double median_corner_error_px = 0;     // over detected frames, all four corners
  double median_distance_error_rel = 0;  // |t| against truth, relative; with a camera
  double median_distance_bias_rel = 0;   // the same signed (positive: farther than it is): a bias, not a spread
  double median_time_ms = 0;
  [[nodiscard]] double rate() const { return frames ? static_cast<double>(detected) / frames : 0; }
};

EvalResult evaluate_point(MarkerDetector& detector, const CameraModel& camera, const EvalSettings& settings,
                          const EvalPoint& point);

}  // namespace markerd::detector
