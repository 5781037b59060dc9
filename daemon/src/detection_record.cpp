#include "markerd/daemon/detection_record.hpp"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <numbers>

#include "markerd/base/json_writer.hpp"
#include "markerd/detector/family.hpp"
#include "markerd/detector/pose.hpp"

namespace markerd::daemon {

std::string_view to_string(FrameStatus status) {
  switch (status) {
    case FrameStatus::ok: return "ok";
    case FrameStatus::corrupt_frame: return "corrupt_frame";
    case FrameStatus::detector_error: return "detector_error";
  }
  return "unknown";
}

namespace {

// Decimal places per quantity (docs/detection-log.md states the same): at
// least ten times finer than what the measurement can resolve, so that
// rounding never shows in an analysis.
constexpr int kPixelDecimals = 4;        // corners: 1e-4 px
constexpr int kPoseDecimals = 7;         // rvec (rad), tvec (m), quaternion, distances in m: 1e-7
constexpr int kMmDecimals = 4;           // rail positions and translation errors: 1e-4 mm
constexpr int kDegreeDecimals = 5;       // angles in degrees: 1e-5 deg (2e-7 rad)
constexpr int kRatioDecimals = 5;        // margin, percentages
constexpr int kMillisecondDecimals = 6;  // times in ms: to the nanosecond

std::int64_t nanoseconds_since_epoch(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

void vector3(JsonWriter& json, const Eigen::Vector3d& v) { json.numbers({v.data(), 3}, kPoseDecimals); }

void quad(JsonWriter& json, const detector::Quad& quad) {
  json.begin_array();
  for (const auto& corner : quad) {
    const std::array<double, 2> xy{corner.x, corner.y};
    json.numbers(xy, kPixelDecimals);
  }
  json.end_array();
}

void axis(JsonWriter& json, const rig::AxisSnapshot& a, std::string_view position_key, std::string_view target_key,
          int decimals) {
  json.begin_object();
  json.key(position_key).number(a.position, decimals);
  json.key(target_key).number(a.target, decimals);
  json.key("state").string(rig::to_string(a.state));
  json.key("homed").boolean(a.homed);
  json.key("settled").boolean(a.settled);
  json.key("fault").boolean(a.fault);
  json.key("moving").boolean(a.moving);
  json.end_object();
}

void rig_snapshot(JsonWriter& json, const rig::RigSnapshot& snapshot) {
  json.begin_object();
  json.key("sequence").integer(snapshot.sequence);
  json.key("monotonic_ns").integer(nanoseconds_since_epoch(snapshot.time));
  json.key("settled").boolean(snapshot.settled());
  json.key("rail");
  axis(json, snapshot.rail, "position_mm", "target_mm", kMmDecimals);
  json.key("turntable");
  axis(json, snapshot.turntable, "position_deg", "target_deg", kDegreeDecimals);
  json.end_object();
}

// rvec, quaternion and tvec of a rotation and translation, through
// MarkerPose's conversions (stable at the half turn of the rig's poses).
void rotation_translation(JsonWriter& json, const detector::MarkerPose& pose) {
  json.key("rvec");
  vector3(json, pose.rvec());
  const Eigen::Quaterniond q = pose.quaternion();
  const std::array<double, 4> wxyz{q.w(), q.x(), q.y(), q.z()};
  json.key("quaternion").numbers(wxyz, kPoseDecimals);
  json.key("tvec");
  vector3(json, pose.translation);
}

void ground_truth(JsonWriter& json, const rig::MarkerGroundTruth& truth) {
  detector::MarkerPose pose;
  pose.rotation = truth.rotation;
  pose.translation = truth.translation;
  json.begin_object();
  rotation_translation(json, pose);
  json.key("distance_m").number(truth.distance_m, kPoseDecimals);
  json.key("yaw_deg").number(truth.yaw_deg, kDegreeDecimals);
  json.end_object();
}

void pose_error(JsonWriter& json, const detector::MarkerPose& pose, const rig::MarkerGroundTruth& truth) {
  const rig::PoseError e = rig::pose_error(pose.rotation, pose.translation, truth);
  json.begin_object();
  json.key("translation_mm").number(e.translation_mm, kMmDecimals);
  // A zero distance gives null, not a division error.
  json.key("translation_pct").number(e.translation_pct, kRatioDecimals);
  json.key("distance_mm").number(e.distance_mm, kMmDecimals);
  json.key("rotation_deg").number(e.rotation_deg, kDegreeDecimals);
  json.end_object();
}

void marker_pose(JsonWriter& json, const detector::MarkerPose& pose,
                 const std::optional<rig::MarkerGroundTruth>& truth) {
  json.begin_object();
  rotation_translation(json, pose);
  json.key("reprojection_error_px").number(pose.reprojection_error_px, kPixelDecimals);
  json.key("error");
  if (truth) {
    pose_error(json, pose, *truth);
  } else {
    json.null();
  }
  json.end_object();
}

void detection(JsonWriter& json, const detector::Detection& d, const std::optional<rig::MarkerGroundTruth>& truth) {
  json.begin_object();
  json.key("family").string(detector::family_info(d.family).name);
  json.key("id").integer(d.id);
  json.key("corners");
  quad(json, d.corners);
  json.key("inner_corners");
  if (d.inner_corners) {
    quad(json, *d.inner_corners);
  } else {
    json.null();
  }
  json.key("quarter_turns").integer(d.quarter_turns);
  json.key("orientation_ambiguous").boolean(d.orientation_ambiguous);
  json.key("bits_corrected").integer(d.bits_corrected);
  json.key("margin").number(d.margin, kRatioDecimals);
  json.key("pose");
  if (!d.pose) {
    json.null();
  } else {
    json.begin_object();
    json.key("ambiguous").boolean(d.pose->ambiguous);
    json.key("best");
    marker_pose(json, d.pose->best, truth);
    json.key("alternative");
    if (d.pose->alternative) {
      marker_pose(json, *d.pose->alternative, truth);
    } else {
      json.null();
    }
    json.end_object();
  }
  json.end_object();
}

}  // namespace

DetectionRecordFormatter::DetectionRecordFormatter() {
  // A frame with a few posed detections; a busier one grows the buffer once.
  buffer_.reserve(8192);
}

std::string_view DetectionRecordFormatter::format(const FrameRecordInput& in) {
  buffer_.clear();
  JsonWriter json(buffer_);
  json.begin_object();
  json.key("schema").integer(kDetectionLogSchema);
  json.key("status").string(to_string(in.status));
  json.key("cause");
  if (in.cause.empty()) {
    json.null();
  } else {
    json.string(in.cause);
  }

  json.key("frame").begin_object();
  json.key("sequence").integer(in.sequence);
  json.key("capture_monotonic_ns").integer(nanoseconds_since_epoch(in.capture_time));
  json.key("capture_utc").utc(in.capture_utc, UtcForm::microseconds);
  json.key("source").string(in.source);
  json.key("width").integer(in.width);
  json.key("height").integer(in.height);
  json.end_object();

  json.key("detection_time_ms")
      .number(std::chrono::duration<double, std::milli>(in.detection_time).count(), kMillisecondDecimals);

  json.key("rig");
  if (in.rig) {
    rig_snapshot(json, *in.rig);
  } else {
    json.null();
  }
  json.key("truth");
  if (in.truth) {
    ground_truth(json, *in.truth);
  } else {
    json.null();
  }

  json.key("detections").begin_array();
  for (const detector::Detection& d : in.detections) detection(json, d, in.truth);
  json.end_array();
  json.end_object();
  buffer_.push_back('\n');
  return buffer_;
}

}  // namespace markerd::daemon
