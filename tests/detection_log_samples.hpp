#pragma once
// Frame outcomes for the detection log's tests and benchmark: a full record
// (every optional part present) and a deterministic stream of them.

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <vector>

#include "markerd/daemon/detection_record.hpp"
#include "markerd/detector/detection.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"

namespace markerd::daemon::samples {

inline rig::RigSnapshot snapshot(double rail_mm, double turntable_deg) {
  rig::RigSnapshot s;
  s.sequence = 4711;
  s.time = std::chrono::steady_clock::time_point(std::chrono::nanoseconds(123'456'789'012));
  s.rail = {rail_mm, rail_mm, rig::AxisState::idle, true, true, false, false};
  s.turntable = {turntable_deg, turntable_deg + 0.5, rig::AxisState::moving, true, false, false, true};
  return s;
}

// A pose near `truth`: `offset_m` away, turned `angle_rad` further about the marker's Y.
inline detector::MarkerPose near(const rig::MarkerGroundTruth& truth, const Eigen::Vector3d& offset_m, double angle_rad,
                                 double reprojection_px) {
  detector::MarkerPose p;
  p.rotation = truth.rotation * Eigen::AngleAxisd(angle_rad, Eigen::Vector3d::UnitY()).toRotationMatrix();
  p.translation = truth.translation + offset_m;
  p.reprojection_error_px = reprojection_px;
  return p;
}

inline detector::Quad quad(double x0, double y0, double side) {
  return {detector::Point2{x0 + 0.12345678, y0 + 0.98765432}, detector::Point2{x0 + side, y0 + 0.5},
          detector::Point2{x0 + side - 0.25, y0 + side}, detector::Point2{x0 - 0.75, y0 + side + 0.0625}};
}

// A frame8 detection with inner corners and both pose solutions, and an
// ArUco detection without inner corners or pose.
inline std::vector<detector::Detection> detections(const rig::MarkerGroundTruth& truth) {
  detector::Detection frame8;
  frame8.family = detector::Family::frame8;
  frame8.id = 165;
  frame8.corners = quad(301.5, 201.25, 80.0);
  frame8.inner_corners = quad(313.5, 213.25, 56.0);
  frame8.quarter_turns = 1;
  frame8.orientation_ambiguous = true;
  frame8.bits_corrected = 2;
  frame8.margin = 0.8765432;
  detector::PoseEstimate pose;
  pose.best = near(truth, {0.001234567, -0.000654321, 0.0041}, 0.0123, 0.1834567);
  pose.alternative = near(truth, {-0.002, 0.003, -0.01}, -0.35, 0.4567891);
  pose.ambiguous = true;
  frame8.pose = pose;

  detector::Detection aruco;
  aruco.family = detector::Family::aruco4x4_50;
  aruco.id = 7;
  aruco.corners = quad(10.0, 20.0, 30.0);
  aruco.margin = 1.0;
  return {frame8, aruco};
}

struct FullRecord {
  rig::MarkerGroundTruth truth = rig::ground_truth(rig::RigGeometry{}, 500.0, 30.0);
  std::vector<detector::Detection> found = detections(truth);
  FrameRecordInput input;

  FullRecord() {
    input.status = FrameStatus::ok;
    input.sequence = 9'000'000'001ULL;
    input.capture_time = std::chrono::steady_clock::time_point(std::chrono::nanoseconds(123'460'000'000));
    input.capture_utc = std::chrono::sys_days(std::chrono::year{2024} / 2 / 29) + std::chrono::hours(23) +
                        std::chrono::minutes(59) + std::chrono::seconds(58) + std::chrono::microseconds(123456);
    input.source = "v4l2:/dev/v4l/by-id/usb-Camera-video-index0";
    input.width = 1920;
    input.height = 1080;
    input.detection_time = std::chrono::nanoseconds(3'456'789);
    input.detections = found;
    input.rig = snapshot(500.0, 30.0);
    input.truth = truth;
  }
};

// The record of frame `sequence` in a deterministic stream: one to four
// detections, so that lines vary in length and cross page boundaries.
struct Stream {
  FullRecord base;
  std::vector<detector::Detection> many;

  Stream() {
    for (int i = 0; i < 4; ++i) many.insert(many.end(), base.found.begin(), base.found.end());
  }
  FrameRecordInput at(std::uint64_t sequence) const {
    FrameRecordInput in = base.input;
    in.sequence = sequence;
    in.capture_time += std::chrono::microseconds(16'667 * sequence);
    in.capture_utc += std::chrono::microseconds(16'667 * sequence);
    in.detections = std::span<const detector::Detection>(many).first(1 + 2 * (sequence % 4));
    return in;
  }
};

}  // namespace markerd::daemon::samples
