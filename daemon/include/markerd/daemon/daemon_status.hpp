#pragma once
// The daemon's state as JSON, for the control socket's `status` and for
// markerctl: the camera and its capture loop, the pipeline's counters and
// latencies, the detection log, the rig.

#include <nlohmann/json.hpp>

#include "markerd/daemon/capture/capture_loop.hpp"
#include "markerd/daemon/detection_log_sink.hpp"
#include "markerd/daemon/stats.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

class Daemon;

[[nodiscard]] nlohmann::json to_json(const CaptureStatus& status);
[[nodiscard]] nlohmann::json to_json(const PipelineStats& stats);
[[nodiscard]] nlohmann::json to_json(const DetectionLogSinkStats& stats);
[[nodiscard]] nlohmann::json to_json(const rig::RigSnapshot& snapshot);
// All of the above for a running daemon.
[[nodiscard]] nlohmann::json status_json(const Daemon& daemon);

}  // namespace markerd::daemon
