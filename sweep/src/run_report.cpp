// What a run reports: its state's name, the frames it keeps for a point, its
// progress as markerctl and the control socket show it, and the state a stop
// record's exit status stands for.

#include <Eigen/Geometry>

#include "markerd/rig/geometry.hpp"
#include "runner_internal.hpp"

namespace markerd::sweep {

std::string_view to_string(RunState state) {
  switch (state) {
    case RunState::idle: return "idle";
    case RunState::running: return "running";
    case RunState::paused: return "paused";
    case RunState::suspended: return "suspended";
    case RunState::done: return "done";
    case RunState::aborted: return "aborted";
    case RunState::failed: return "failed";
  }
  return "?";
}

FrameSample make_frame_sample(const FrameObservation& frame, const PlanMarker& marker, double detector_marker_size_m) {
  FrameSample sample;
  sample.sequence = frame.sequence;
  const detector::Detection* found = nullptr;
  for (const detector::Detection& d : frame.detections) {
    if (found == nullptr && d.family == marker.family && d.id == marker.id) {
      found = &d;
    } else {
      ++sample.other_markers;
    }
  }
  if (found == nullptr) return sample;
  sample.detected = true;
  if (!found->pose) return sample;
  detector::MarkerPose pose = found->pose->best;
  if (detector_marker_size_m > 0) pose.translation *= marker.size_m / detector_marker_size_m;
  sample.has_pose = true;
  const Eigen::Vector3d rvec = pose.rvec();
  for (int i = 0; i < 3; ++i) {
    sample.tvec_m[static_cast<std::size_t>(i)] = pose.translation[i];
    sample.rvec[static_cast<std::size_t>(i)] = rvec[i];
  }
  sample.reprojection_error_px = pose.reprojection_error_px;
  if (frame.truth) {
    // The same errors as the detection log's (docs/detection-log.md).
    const rig::PoseError error = rig::pose_error(pose.rotation, pose.translation, *frame.truth);
    sample.has_error = true;
    sample.translation_error_mm = error.translation_mm;
    sample.distance_error_mm = error.distance_mm;
    sample.rotation_error_deg = error.rotation_deg;
  }
  return sample;
}

nlohmann::json to_json(const SweepProgress& p) {
  nlohmann::json j{{"state", to_string(p.state)},
                   {"run_id", p.run_id},
                   {"run_directory", p.run_directory.string()},
                   {"plan", p.plan_name},
                   {"steps_done", p.steps_done},
                   {"steps_total", p.steps_total},
                   {"phase", p.phase},
                   {"frames_collected", p.frames_collected},
                   {"frames_per_point", p.frames_per_point},
                   {"reason", p.reason},
                   {"elapsed_s", p.elapsed.count()}};
  j["last_rate"] = p.last_rate ? nlohmann::json(*p.last_rate) : nlohmann::json(nullptr);
  j["remaining_s"] = p.remaining ? nlohmann::json(p.remaining->count()) : nlohmann::json(nullptr);
  if (p.step) {
    j["step"] = {{"index", p.step->index}, {"point", p.step->point},           {"repeat", p.step->repeat},
                 {"grid", p.step->grid},   {"distance_m", p.step->distance_m}, {"angle_deg", p.step->angle_deg}};
  } else {
    j["step"] = nullptr;
  }
  return j;
}

ExitStatus exit_status(RunState state) {
  return state == RunState::done      ? ExitStatus::done
         : state == RunState::aborted ? ExitStatus::aborted
                                      : ExitStatus::failed;
}

RunState run_state(ExitStatus status) {
  switch (status) {
    case ExitStatus::done: return RunState::done;
    case ExitStatus::aborted: return RunState::aborted;
    case ExitStatus::failed: return RunState::failed;
  }
  return RunState::failed;
}

}  // namespace markerd::sweep
