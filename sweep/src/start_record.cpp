// What a run's start record says of the machine it ran on and of the rig
// (records.hpp's RunStart): enough to know, from the records alone, what
// measured them.

#include <unistd.h>

#include <array>

#include "runner_internal.hpp"

namespace markerd::sweep {

std::string this_hostname() {
  std::array<char, 256> name{};
  if (::gethostname(name.data(), name.size() - 1) != 0) return {};
  return name.data();
}

const char* backend_name(const rig::DriveSettings& drive) {
  switch (drive.index()) {
    case 0: return "sim";
    case 1: return "gpio";
    default: return "modbus";
  }
}

nlohmann::json axis_record(const rig::AxisConfig& axis) {
  const rig::AxisSettings& a = axis.axis;
  return {{"name", a.name},
          {"unit", a.unit},
          {"units_per_step", a.units_per_step},
          {"min_position", a.min_position},
          {"max_position", a.max_position},
          {"max_velocity", a.max_velocity},
          {"acceleration", a.acceleration},
          {"backlash", a.backlash},
          {"settle_ms", a.settle_time.count()},
          {"backend", backend_name(axis.drive)}};
}

namespace {

nlohmann::json geometry_record(const rig::RigGeometry& g) {
  return {{"d0_mm", g.d0_mm},
          {"yaw0_deg", g.yaw0_deg},
          {"rail_sign", g.rail_sign},
          {"camera_offset_x_mm", g.camera_offset_x_mm},
          {"camera_offset_y_mm", g.camera_offset_y_mm},
          {"marker_offset_normal_mm", g.marker_offset_normal_mm},
          {"marker_offset_lateral_mm", g.marker_offset_lateral_mm},
          {"rail_tilt_x_deg", g.rail_tilt_x_deg},
          {"rail_tilt_y_deg", g.rail_tilt_y_deg}};
}

}  // namespace

nlohmann::json rig_record(const rig::RigConfig& config) {
  nlohmann::json record{{"source", config.source},
                        {"geometry", geometry_record(config.geometry)},
                        {"sim_time_scale", config.sim.time_scale},
                        {"rail", axis_record(config.rail)},
                        {"turntable", axis_record(config.turntable)}};
  // Where the geometry's measured values came from, and (a simulated rig
  // whose world differs from its config) the truth a calibration is judged by.
  if (!config.geometry_calibration.empty()) record["geometry_calibration"] = config.geometry_calibration.string();
  if (config.sim.geometry) record["sim_geometry"] = geometry_record(*config.sim.geometry);
  return record;
}

}  // namespace markerd::sweep
