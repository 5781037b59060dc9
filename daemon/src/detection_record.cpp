#include "markerd/daemon/detection_record.hpp"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <iterator>
#include <numbers>

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
constexpr int kPixelDecimals = 4;     // corners: 1e-4 px
constexpr int kPoseDecimals = 7;      // rvec (rad), tvec (m), quaternion, distances in m: 1e-7
constexpr int kMmDecimals = 4;        // rail positions and translation errors: 1e-4 mm
constexpr int kDegreeDecimals = 5;    // angles in degrees: 1e-5 deg (2e-7 rad)
constexpr int kRatioDecimals = 5;     // margin, percentages
constexpr int kMillisecondDecimals = 6;  // times in ms: to the nanosecond

class JsonOut {
 public:
  explicit JsonOut(std::string& out) : out_(out) {}

  void raw(std::string_view text) { out_.append(text); }
  void key(std::string_view name) {
    out_.push_back('"');
    out_.append(name);
    out_.append("\":");
  }

  // JSON has no NaN or infinity: a non-finite value is written as null.
  void number(double value, int decimals) {
    if (!std::isfinite(value)) {
      out_.append("null");
      return;
    }
    fmt::format_to(std::back_inserter(out_), "{:.{}f}", value, decimals);
  }
  template <class Integer>
  void integer(Integer value) {
    fmt::format_to(std::back_inserter(out_), "{}", value);
  }
  // ISO 8601 in UTC with microseconds: "2024-05-01T12:00:00.123456Z".
  void utc(std::chrono::system_clock::time_point t) {
    using namespace std::chrono;
    const auto micros = floor<microseconds>(t);
    const auto day = floor<days>(micros);
    const year_month_day date{day};
    const hh_mm_ss time{micros - day};
    fmt::format_to(std::back_inserter(out_), "\"{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:06}Z\"",
                   static_cast<int>(date.year()), static_cast<unsigned>(date.month()),
                   static_cast<unsigned>(date.day()), time.hours().count(), time.minutes().count(),
                   time.seconds().count(), time.subseconds().count());
  }
  void boolean(bool value) { out_.append(value ? "true" : "false"); }
  void null() { out_.append("null"); }

  void numbers(std::span<const double> values, int decimals) {
    out_.push_back('[');
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (i > 0) out_.push_back(',');
      number(values[i], decimals);
    }
    out_.push_back(']');
  }
  void vector3(const Eigen::Vector3d& v) { numbers({v.data(), 3}, kPoseDecimals); }
  void quaternion(const Eigen::Quaterniond& q) {
    const std::array<double, 4> wxyz{q.w(), q.x(), q.y(), q.z()};
    numbers(wxyz, kPoseDecimals);
  }
  void quad(const Quad& quad) {
    out_.push_back('[');
    for (std::size_t i = 0; i < quad.size(); ++i) {
      if (i > 0) out_.push_back(',');
      const std::array<double, 2> xy{quad[i].x, quad[i].y};
      numbers(xy, kPixelDecimals);
    }
    out_.push_back(']');
  }

  // A JSON string of arbitrary bytes: control characters escaped (so no
  // newline can split the record), bytes that are not valid UTF-8 replaced by
  // U+FFFD (so every line parses as JSON, whatever a device name holds).
  void string(std::string_view text) {
    out_.push_back('"');
    std::size_t i = 0;
    while (i < text.size()) {
      const auto byte = static_cast<unsigned char>(text[i]);
      if (byte < 0x80) {
        escape_ascii(byte);
        ++i;
        continue;
      }
      const std::size_t length = utf8_sequence_length(text.substr(i));
      if (length == 0) {
        out_.append("\xEF\xBF\xBD");
        ++i;
      } else {
        out_.append(text.substr(i, length));
        i += length;
      }
    }
    out_.push_back('"');
  }

 private:
  void escape_ascii(unsigned char c) {
    switch (c) {
      case '"': out_.append("\\\""); return;
      case '\\': out_.append("\\\\"); return;
      case '\n': out_.append("\\n"); return;
      case '\r': out_.append("\\r"); return;
      case '\t': out_.append("\\t"); return;
      default: break;
    }
    if (c < 0x20) {
      fmt::format_to(std::back_inserter(out_), "\\u{:04x}", static_cast<unsigned>(c));
    } else {
      out_.push_back(static_cast<char>(c));
    }
  }

  // The length of the well-formed UTF-8 sequence at the start of `s` (RFC 3629:
  // no overlong forms, no surrogates, nothing above U+10FFFF), or 0.
  static std::size_t utf8_sequence_length(std::string_view s) {
    const auto at = [&](std::size_t i) { return static_cast<unsigned char>(s[i]); };
    const unsigned char lead = at(0);
    std::size_t length = 0;
    unsigned char second_min = 0x80;
    unsigned char second_max = 0xBF;
    if (lead >= 0xC2 && lead <= 0xDF) {
      length = 2;
    } else if (lead >= 0xE0 && lead <= 0xEF) {
      length = 3;
      if (lead == 0xE0) second_min = 0xA0;  // overlong
      if (lead == 0xED) second_max = 0x9F;  // surrogates
    } else if (lead >= 0xF0 && lead <= 0xF4) {
      length = 4;
      if (lead == 0xF0) second_min = 0x90;  // overlong
      if (lead == 0xF4) second_max = 0x8F;  // above U+10FFFF
    } else {
      return 0;
    }
    if (s.size() < length) return 0;
    if (at(1) < second_min || at(1) > second_max) return 0;
    for (std::size_t i = 2; i < length; ++i) {
      if (at(i) < 0x80 || at(i) > 0xBF) return 0;
    }
    return length;
  }

  std::string& out_;
};

std::int64_t nanoseconds_since_epoch(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
}

void axis(JsonOut& json, const rig::AxisSnapshot& a, std::string_view unit, int decimals) {
  json.raw("{");
  json.raw("\"position_");
  json.raw(unit);
  json.raw("\":");
  json.number(a.position, decimals);
  json.raw(",\"target_");
  json.raw(unit);
  json.raw("\":");
  json.number(a.target, decimals);
  json.raw(",");
  json.key("state");
  json.string(rig::to_string(a.state));
  json.raw(",");
  json.key("homed");
  json.boolean(a.homed);
  json.raw(",");
  json.key("settled");
  json.boolean(a.settled);
  json.raw(",");
  json.key("fault");
  json.boolean(a.fault);
  json.raw(",");
  json.key("moving");
  json.boolean(a.moving);
  json.raw("}");
}

void rig_snapshot(JsonOut& json, const rig::RigSnapshot& snapshot) {
  json.raw("{");
  json.key("sequence");
  json.integer(snapshot.sequence);
  json.raw(",");
  json.key("monotonic_ns");
  json.integer(nanoseconds_since_epoch(snapshot.time));
  json.raw(",");
  json.key("settled");
  json.boolean(snapshot.settled());
  json.raw(",");
  json.key("rail");
  axis(json, snapshot.rail, "mm", kMmDecimals);
  json.raw(",");
  json.key("turntable");
  axis(json, snapshot.turntable, "deg", kDegreeDecimals);
  json.raw("}");
}

// rvec, quaternion and tvec of a rotation and translation, through
// MarkerPose's conversions (stable at the half turn of the rig's poses).
void rotation_translation(JsonOut& json, const MarkerPose& pose) {
  json.key("rvec");
  json.vector3(pose.rvec());
  json.raw(",");
  json.key("quaternion");
  json.quaternion(pose.quaternion());
  json.raw(",");
  json.key("tvec");
  json.vector3(pose.translation);
}

void ground_truth(JsonOut& json, const rig::MarkerGroundTruth& truth) {
  MarkerPose pose;
  pose.rotation = truth.rotation;
  pose.translation = truth.translation;
  json.raw("{");
  rotation_translation(json, pose);
  json.raw(",");
  json.key("distance_m");
  json.number(truth.distance_m, kPoseDecimals);
  json.raw(",");
  json.key("yaw_deg");
  json.number(truth.yaw_deg, kDegreeDecimals);
  json.raw("}");
}

void pose_error(JsonOut& json, const MarkerPose& pose, const rig::MarkerGroundTruth& truth) {
  const rig::PoseError e = rig::pose_error(pose.rotation, pose.translation, truth);
  json.raw("{");
  json.key("translation_mm");
  json.number(e.translation_mm, kMmDecimals);
  json.raw(",");
  json.key("translation_pct");
  json.number(e.translation_pct, kRatioDecimals);  // a zero distance gives null, not a division error
  json.raw(",");
  json.key("distance_mm");
  json.number(e.distance_mm, kMmDecimals);
  json.raw(",");
  json.key("rotation_deg");
  json.number(e.rotation_deg, kDegreeDecimals);
  json.raw("}");
}

void marker_pose(JsonOut& json, const MarkerPose& pose, const std::optional<rig::MarkerGroundTruth>& truth) {
  json.raw("{");
  rotation_translation(json, pose);
  json.raw(",");
  json.key("reprojection_error_px");
  json.number(pose.reprojection_error_px, kPixelDecimals);
  json.raw(",");
  json.key("error");
  if (truth) {
    pose_error(json, pose, *truth);
  } else {
    json.null();
  }
  json.raw("}");
}

void detection(JsonOut& json, const Detection& d, const std::optional<rig::MarkerGroundTruth>& truth) {
  json.raw("{");
  json.key("family");
  json.string(family_info(d.family).name);
  json.raw(",");
  json.key("id");
  json.integer(d.id);
  json.raw(",");
  json.key("corners");
  json.quad(d.corners);
  json.raw(",");
  json.key("inner_corners");
  if (d.inner_corners) {
    json.quad(*d.inner_corners);
  } else {
    json.null();
  }
  json.raw(",");
  json.key("quarter_turns");
  json.integer(d.quarter_turns);
  json.raw(",");
  json.key("bits_corrected");
  json.integer(d.bits_corrected);
  json.raw(",");
  json.key("margin");
  json.number(d.margin, kRatioDecimals);
  json.raw(",");
  json.key("pose");
  if (!d.pose) {
    json.null();
  } else {
    json.raw("{");
    json.key("ambiguous");
    json.boolean(d.pose->ambiguous);
    json.raw(",");
    json.key("best");
    marker_pose(json, d.pose->best, truth);
    json.raw(",");
    json.key("alternative");
    if (d.pose->alternative) {
      marker_pose(json, *d.pose->alternative, truth);
    } else {
      json.null();
    }
    json.raw("}");
  }
  json.raw("}");
}

}  // namespace

DetectionRecordFormatter::DetectionRecordFormatter() {
  // A frame with a few posed detections; a busier one grows the buffer once.
  buffer_.reserve(8192);
}

std::string_view DetectionRecordFormatter::format(const FrameRecordInput& in) {
  buffer_.clear();
  JsonOut json(buffer_);
  json.raw("{");
  json.key("schema");
  json.integer(kDetectionLogSchema);
  json.raw(",");
  json.key("status");
  json.string(to_string(in.status));
  json.raw(",");
  json.key("cause");
  if (in.cause.empty()) {
    json.null();
  } else {
    json.string(in.cause);
  }

  json.raw(",");
  json.key("frame");
  json.raw("{");
  json.key("sequence");
  json.integer(in.sequence);
  json.raw(",");
  json.key("capture_monotonic_ns");
  json.integer(nanoseconds_since_epoch(in.capture_time));
  json.raw(",");
  json.key("capture_utc");
  json.utc(in.capture_utc);
  json.raw(",");
  json.key("source");
  json.string(in.source);
  json.raw(",");
  json.key("width");
  json.integer(in.width);
  json.raw(",");
  json.key("height");
  json.integer(in.height);
  json.raw("}");

  json.raw(",");
  json.key("detection_time_ms");
  json.number(std::chrono::duration<double, std::milli>(in.detection_time).count(), kMillisecondDecimals);

  json.raw(",");
  json.key("rig");
  if (in.rig) {
    rig_snapshot(json, *in.rig);
  } else {
    json.null();
  }
  json.raw(",");
  json.key("truth");
  if (in.truth) {
    ground_truth(json, *in.truth);
  } else {
    json.null();
  }

  json.raw(",");
  json.key("detections");
  json.raw("[");
  for (std::size_t i = 0; i < in.detections.size(); ++i) {
    if (i > 0) json.raw(",");
    detection(json, in.detections[i], in.truth);
  }
  json.raw("]}\n");
  return buffer_;
}

}  // namespace markerd::daemon
