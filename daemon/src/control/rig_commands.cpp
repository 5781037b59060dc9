#include "markerd/daemon/control/rig_commands.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace markerd::daemon {

using nlohmann::json;
using rig::Axis;
using rig::AxisState;
using rig::AxisStatus;

namespace {

bool in_motion(AxisState state) {
  return state == AxisState::moving || state == AxisState::homing || state == AxisState::stopping;
}

json axis_json(const Axis& axis, const AxisStatus& status) {
  const rig::AxisSettings& settings = axis.settings();
  return {
      {"state", rig::to_string(status.state)},
      {"homed", status.homed},
      {"settled", status.settled},
      {"moving", in_motion(status.state)},
      {"fault", status.state == AxisState::fault ? json(status.fault) : json(nullptr)},
      {"position", status.position},
      {"target", status.target},
      {"unit", settings.unit},
      {"min_position", settings.min_position},
      {"max_position", settings.max_position},
      {"inputs",
       {{"limit_min", status.inputs.limit_min},
        {"limit_max", status.inputs.limit_max},
        {"home", status.inputs.home},
        {"estop", status.inputs.estop}}},
  };
}

// The axes an "axis" argument names (rail, turntable or both; both when absent).
std::vector<Axis*> chosen_axes(rig::Rig& rig, const json& request) {
  const std::string name = choice_argument(request, "axis", {"rail", "turntable", "both"}).value_or("both");
  if (name == "rail") return {&rig.rail()};
  if (name == "turntable") return {&rig.turntable()};
  return {&rig.rail(), &rig.turntable()};
}

std::string names_of(const std::vector<Axis*>& axes) {
  std::string text;
  for (const Axis* axis : axes) text += fmt::format("{}{}", text.empty() ? "" : " and ", axis->settings().name);
  return text;
}

json home(rig::Rig& rig, const json& request) {
  expect_arguments(request, {"axis"});
  const std::vector<Axis*> axes = chosen_axes(rig, request);
  for (const Axis* axis : axes) {
    const AxisStatus s = axis->status();
    if (in_motion(s.state)) {
      throw ControlError(fmt::format("{}: home refused: the axis is busy ({}); wait, or rig.stop first",
                                     axis->settings().name, rig::to_string(s.state)));
    }
  }
  spdlog::info("control: rig.home: {}", names_of(axes));
  std::vector<Axis*> started;
  try {
    for (Axis* axis : axes) {
      // Homing is how an axis gets its reference back after a fault (an
      // emergency stop, a drive alarm): clear it, enable, then home.
      const AxisStatus s = axis->status();
      if (s.state == AxisState::fault) {
        spdlog::info("control: rig.home: {}: clearing the fault ({})", axis->settings().name, s.fault);
        axis->clear_fault();
      }
      if (axis->status().state == AxisState::disabled) axis->enable();
      axis->home();
      started.push_back(axis);
    }
  } catch (const rig::AxisError& e) {
    for (Axis* axis : started) axis->stop();
    throw ControlError(e.what());
  }
  json homing = json::array();
  for (const Axis* axis : axes) homing.push_back(axis->settings().name);
  return {{"homing", homing}};
}

json move(rig::Rig& rig, const json& request) {
  expect_arguments(request, {"rail", "turntable", "relative"});
  const bool relative = bool_argument(request, "relative").value_or(false);
  struct Leg {
    Axis* axis;
    double value;   // as given
    double target;  // absolute, the axis's units
  };
  std::vector<Leg> legs;
  for (Axis* axis : {&rig.rail(), &rig.turntable()}) {
    if (const auto value = number_argument(request, axis->settings().name)) legs.push_back({axis, *value, *value});
  }
  if (legs.empty()) throw ControlError("rig.move needs a target: rail, turntable or both (numbers in the axes' units)");

  // Every axis is checked before any moves: a move of both that one of them
  // refuses must not leave the other one going. The reasons are the axis's
  // own, in the protocol's terms.
  for (Leg& leg : legs) {
    const Axis& axis = *leg.axis;
    const rig::AxisSettings& settings = axis.settings();
    const AxisStatus s = axis.status();
    if (relative) leg.target = s.position + leg.value;
    const std::string what = relative
                                 ? fmt::format("{}: move by {:+g} {} (to {:g} {}) refused", settings.name, leg.value,
                                               settings.unit, leg.target, settings.unit)
                                 : fmt::format("{}: move to {:g} {} refused", settings.name, leg.target, settings.unit);
    if (s.state == AxisState::fault) {
      throw ControlError(fmt::format("{}: the axis is in fault ({}); rig.home clears the fault", what, s.fault));
    }
    if (s.inputs.estop) throw ControlError(fmt::format("{}: the e-stop input is active", what));
    if (in_motion(s.state)) {
      throw ControlError(
          fmt::format("{}: the axis is busy ({}); wait, or rig.stop first", what, rig::to_string(s.state)));
    }
    if (!s.homed) throw ControlError(fmt::format("{}: the axis is not homed; rig.home first", what));
    if (leg.target < settings.min_position || leg.target > settings.max_position) {
      throw ControlError(fmt::format("{}: outside the soft limits [{:g}, {:g}] {}", what, settings.min_position,
                                     settings.max_position, settings.unit));
    }
  }
  std::string plan;
  for (const Leg& leg : legs) {
    plan += fmt::format("{}{} to {:g} {}", plan.empty() ? "" : ", ", leg.axis->settings().name, leg.target,
                        leg.axis->settings().unit);
  }
  spdlog::info("control: rig.move: {}", plan);
  std::vector<Axis*> started;
  try {
    for (const Leg& leg : legs) {
      if (leg.axis->status().state == AxisState::disabled) leg.axis->enable();
      leg.axis->move_to(leg.target);
      started.push_back(leg.axis);
    }
  } catch (const rig::AxisError& e) {
    // The state changed between the check and the command (a fault, an
    // e-stop): the axes already going stop too.
    for (Axis* axis : started) axis->stop();
    throw ControlError(e.what());
  }
  json targets = json::object();
  for (const Leg& leg : legs) targets[leg.axis->settings().name] = leg.target;
  return {{"moving", targets}};
}

json stop(rig::Rig& rig, const json& request) {
  expect_arguments(request, {"emergency"});
  if (bool_argument(request, "emergency").value_or(false)) {
    spdlog::warn("control: rig.stop: emergency stop");
    rig.emergency_stop();
    return {{"stopped", json::array({"rail", "turntable"})}, {"emergency", true}};
  }
  json stopping = json::array();
  std::string failures;
  for (Axis* axis : {&rig.rail(), &rig.turntable()}) {
    if (!in_motion(axis->status().state)) continue;
    try {
      axis->stop();
      stopping.push_back(axis->settings().name);
    } catch (const rig::AxisError& e) {
      // A drive that cannot be told to ramp down is stopped at once.
      axis->emergency_stop();
      failures += fmt::format("{}{} (emergency-stopped instead)", failures.empty() ? "" : "; ", e.what());
    }
  }
  spdlog::info("control: rig.stop: {}", stopping.empty() ? std::string("nothing was moving") : stopping.dump());
  if (!failures.empty()) throw ControlError(failures);
  return {{"stopping", stopping}, {"emergency", false}};
}

json enable(rig::Rig& rig, const json& request, bool on) {
  expect_arguments(request, {"axis"});
  const std::vector<Axis*> axes = chosen_axes(rig, request);
  spdlog::info("control: rig.{}: {}", on ? "enable" : "disable", names_of(axes));
  json done = json::array();
  for (Axis* axis : axes) {
    try {
      if (on) {
        axis->enable();
      } else {
        axis->disable();
      }
    } catch (const rig::AxisError& e) {
      throw ControlError(e.what());
    }
    done.push_back(axis->settings().name);
  }
  return {{on ? "enabled" : "disabled", done}};
}

}  // namespace

json rig_status_json(const rig::Rig& rig) {
  // The axes' own statuses, not the snapshot: a command updates them before
  // it returns, so a status asked for right after a rig.move already shows
  // the move (the snapshot follows a few milliseconds later, on the rig's
  // publishing thread). Its sequence and age are reported beside them.
  const AxisStatus rail = rig.rail().status();
  const AxisStatus turntable = rig.turntable().status();
  const rig::RigSnapshot snapshot = rig.snapshot();
  const rig::MarkerGroundTruth truth = rig::ground_truth(rig.geometry(), rail.position, turntable.position);
  const Eigen::Quaterniond q(truth.rotation);
  const double age_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - snapshot.time).count();
  return {
      {"rail", axis_json(rig.rail(), rail)},
      {"turntable", axis_json(rig.turntable(), turntable)},
      {"settled", rail.settled && turntable.settled},
      {"snapshot", {{"sequence", snapshot.sequence}, {"age_ms", age_ms}}},
      {"ground_truth",
       {{"distance_m", truth.distance_m},
        {"yaw_deg", truth.yaw_deg},
        {"tvec", {truth.translation.x(), truth.translation.y(), truth.translation.z()}},
        {"quaternion", {q.w(), q.x(), q.y(), q.z()}}}},
  };
}

void register_rig_commands(ControlServer& server, rig::Rig& rig) {
  server.register_command(
      "rig.status",
      [&rig](const json& request) {
        expect_arguments(request, {});
        return rig_status_json(rig);
      },
      "each axis's state, position, target and fault, and the ground truth of the positions");
  server.register_command(
      "rig.home", [&rig](const json& request) { return home(rig, request); },
      "start homing (axis: rail, turntable or both, the default); clears a fault and enables first");
  server.register_command(
      "rig.move", [&rig](const json& request) { return move(rig, request); },
      "start moves to rail and/or turntable (numbers in the axes' units; relative: true moves by them)");
  server.register_command(
      "rig.stop", [&rig](const json& request) { return stop(rig, request); },
      "stop both axes with a ramp; emergency: true stops them at once and disables them (they must be homed "
      "again)");
  server.register_command(
      "rig.enable", [&rig](const json& request) { return enable(rig, request, true); },
      "power the drives (axis: rail, turntable or both)");
  server.register_command(
      "rig.disable", [&rig](const json& request) { return enable(rig, request, false); },
      "unpower the drives of axes at rest (axis: rail, turntable or both)");
  // However many clients hold the socket, idle or busy, a stop gets
  // through, and so does the status that shows it took.
  server.serve_beyond_client_limit("rig.stop");
  server.serve_beyond_client_limit("rig.status");
}

}  // namespace markerd::daemon
