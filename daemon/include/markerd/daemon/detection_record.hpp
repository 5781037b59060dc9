#pragma once
// One frame outcome as one line of JSON: the record of the detection log
// (schema: docs/detection-log.md). The pipeline's log stage fills a
// FrameRecordInput from plain values and formats it into a buffer the
// formatter keeps, so a record costs no allocation once the buffer has grown.

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "markerd/detector/detection.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon {

// Raised whenever a key changes meaning, is renamed or removed (adding a key
// is no change: readers ignore keys they do not know).
inline constexpr int kDetectionLogSchema = 1;

enum class FrameStatus : std::uint8_t {
  ok,              // the detector ran; `detections` holds what it found (maybe nothing)
  corrupt_frame,   // the source delivered a frame that cannot be read (a broken MJPEG, a short buffer)
  detector_error,  // the detector refused the frame (an image size the camera model does not fit, ...)
};
[[nodiscard]] std::string_view to_string(FrameStatus status);

struct FrameRecordInput {
  FrameStatus status = FrameStatus::ok;
  std::string_view cause;  // why, when status is not ok (logged as null when empty)

  std::uint64_t sequence = 0;  // the source's frame sequence number
  // When the frame was captured: on the CLOCK_MONOTONIC timeline (libstdc++'s
  // steady_clock is CLOCK_MONOTONIC, as are V4L2's buffer timestamps and the
  // rig snapshot's time) and as wall-clock UTC.
  std::chrono::steady_clock::time_point capture_time{};
  std::chrono::system_clock::time_point capture_utc{};
  std::string_view source;  // the capture source's name
  int width = 0;            // image size, pixels
  int height = 0;

  std::chrono::nanoseconds detection_time{0};  // the detector's wall time on this frame
  std::span<const detector::Detection> detections;

  // The rig at capture time and the marker pose its positions imply; absent
  // when the daemon runs without a rig. With a truth, every detection with a
  // pose carries its error against it.
  std::optional<rig::RigSnapshot> rig;
  std::optional<rig::MarkerGroundTruth> truth;
};

// Formats records into a buffer it reuses. One per thread (the log stage);
// the returned view is valid until the next format().
class DetectionRecordFormatter {
 public:
  DetectionRecordFormatter();

  // One complete line: a JSON object and a '\n', no other newline (strings
  // are escaped). Non-finite numbers appear as null.
  [[nodiscard]] std::string_view format(const FrameRecordInput& input);

 private:
  std::string buffer_;
};

}  // namespace markerd::daemon
