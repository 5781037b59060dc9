#pragma once
#include <memory>

#include "markerd/detector/detector.hpp"

namespace markerd::detector {
std::unique_ptr<MarkerDetector> make_frame8_detector(const DetectorConfig& config);
}
