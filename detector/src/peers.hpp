#pragma once
// The comparison detectors: OpenCV's ArUco (aruco4x4_50) and libapriltag
// (tag36h11), behind the same interface as frame8 so that the benchmarks and
// the daemon can swap them in. Internal to the library; make_detector() is
// the public way in.

#include <memory>

#include "markerd/detector/detector.hpp"

namespace markerd::detector {

std::unique_ptr<MarkerDetector> make_aruco_detector(const DetectorConfig& config);
std::unique_ptr<MarkerDetector> make_apriltag_detector(const DetectorConfig& config);

}  // namespace markerd::detector
