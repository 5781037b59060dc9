#include "frame8_detector.hpp"
#include "markerd/detector/detector.hpp"
#include "peers.hpp"

namespace markerd::detector {

std::unique_ptr<MarkerDetector> make_detector(const DetectorConfig& config) {
  if (config.camera.has_value() != (config.marker_size_m > 0)) {
    throw DetectorError("a pose needs both a camera model and a marker size");
  }
  switch (config.family) {
    case Family::frame8: return make_frame8_detector(config);
    case Family::aruco4x4_50: return make_aruco_detector(config);
    case Family::tag36h11: return make_apriltag_detector(config);
  }
  throw DetectorError("make_detector: unknown family");
}

}  // namespace markerd::detector
