#include "markerd/rig/rig_config.hpp"

#include <fmt/format.h>

#include <cmath>
#include <string>
#include <string_view>
#include <utility>

namespace markerd::rig {

namespace {

template <class... F>
struct Overloaded : F... {
  using F::operator()...;
};
template <class... F>
Overloaded(F...) -> Overloaded<F...>;

HomingSteps::Switch parse_switch(const ConfigTable& homing) {
  const auto name = homing.required<std::string>("switch");
  if (name == "home") return HomingSteps::Switch::home;
  if (name == "limit_min") return HomingSteps::Switch::limit_min;
  if (name == "limit_max") return HomingSteps::Switch::limit_max;
  homing.fail("switch", fmt::format("unknown switch '{}' (known: home, limit_min, limit_max)", name));
}

double finite(const ConfigTable& t, std::string_view key, double value) {
  if (!std::isfinite(value)) t.fail(key, "must be a finite number");
  return value;
}

RigGeometry parse_geometry(const ConfigTable& t) {
  t.allow_only({"d0_mm", "yaw0_deg", "rail_sign", "camera_offset_x_mm", "camera_offset_y_mm", "marker_offset_normal_mm",
                "marker_offset_lateral_mm"});
  RigGeometry g;
  g.d0_mm = finite(t, "d0_mm", t.required<double>("d0_mm"));
  g.yaw0_deg = finite(t, "yaw0_deg", t.optional<double>("yaw0_deg", 0.0));
  g.rail_sign = t.optional<int>("rail_sign", 1);
  if (g.rail_sign != 1 && g.rail_sign != -1) t.fail("rail_sign", fmt::format("must be 1 or -1, got {}", g.rail_sign));
  g.camera_offset_x_mm = finite(t, "camera_offset_x_mm", t.optional<double>("camera_offset_x_mm", 0.0));
  g.camera_offset_y_mm = finite(t, "camera_offset_y_mm", t.optional<double>("camera_offset_y_mm", 0.0));
  g.marker_offset_normal_mm = finite(t, "marker_offset_normal_mm", t.optional<double>("marker_offset_normal_mm", 0.0));
  g.marker_offset_lateral_mm =
      finite(t, "marker_offset_lateral_mm", t.optional<double>("marker_offset_lateral_mm", 0.0));
  return g;
}

SimSettings parse_sim(const ConfigTable& t) {
  t.allow_only({"time_scale"});
  SimSettings s;
  s.time_scale = t.optional<double>("time_scale", 1.0);
  // Slower than real time would make the axes' timeouts (real time) fire on
  // moves that are merely slow.
  if (!std::isfinite(s.time_scale) || s.time_scale < 1) {
    t.fail("time_scale", fmt::format("must be a finite number >= 1 (the axes' timeouts run in real time), got {}",
                                     s.time_scale));
  }
  return s;
}

HomingSettings parse_homing(const ConfigTable& h) {
  h.allow_only({"direction", "switch", "search_velocity", "latch_velocity", "backoff", "home_offset", "timeout_s"});
  HomingSettings s;
  s.direction = h.required<int>("direction");
  s.target = parse_switch(h);
  s.search_velocity = h.optional<double>("search_velocity", 0.0);
  s.latch_velocity = h.optional<double>("latch_velocity", 0.0);
  s.backoff = h.optional<double>("backoff", 0.0);
  s.home_offset = h.optional<double>("home_offset", 0.0);
  const double timeout_s = h.optional<double>("timeout_s", 60.0);
  if (!std::isfinite(timeout_s) || !(timeout_s > 0)) h.fail("timeout_s", fmt::format("must be > 0, got {}", timeout_s));
  s.timeout = std::chrono::milliseconds(std::llround(timeout_s * 1000));
  return s;
}

AxisConfig parse_axis(const ConfigTable& rig, std::string_view name) {
  const ConfigTable t = rig.table(name);
  const auto backend = t.required<std::string>("backend");
  if (backend != "sim" && backend != "gpio" && backend != "modbus") {
    t.fail("backend", fmt::format("unknown backend '{}' (known: sim, gpio, modbus)", backend));
  }
  // The backend's own table is named after it; the others' tables are typos.
  t.allow_only({"backend", "unit", "units_per_step", "min_position", "max_position", "max_velocity", "acceleration",
                "backlash", "approach_direction", "retry_deadband", "max_retries", "settle_ms", "homing",
                std::string_view(backend)});

  AxisConfig config;
  AxisSettings& a = config.axis;
  a.name = std::string(name);
  a.unit = t.required<std::string>("unit");
  a.units_per_step = t.required<double>("units_per_step");
  a.min_position = t.required<double>("min_position");
  a.max_position = t.required<double>("max_position");
  a.max_velocity = t.required<double>("max_velocity");
  a.acceleration = t.required<double>("acceleration");
  a.backlash = t.optional<double>("backlash", 0.0);
  a.approach_direction = t.optional<int>("approach_direction", 1);
  a.retry_deadband = t.optional<double>("retry_deadband", 0.0);
  a.max_retries = t.optional<int>("max_retries", 2);
  a.settle_time = std::chrono::milliseconds(t.optional<std::int64_t>("settle_ms", 200));
  const ConfigTable homing = t.table("homing");
  a.homing = parse_homing(homing);
  if (auto problem = check_axis_settings(a)) {
    constexpr std::string_view kHoming = "homing.";
    if (problem->key.starts_with(kHoming)) homing.fail(problem->key.substr(kHoming.size()), problem->message);
    t.fail(problem->key, problem->message);
  }

  if (backend == "sim") {
    SimDriveSettings sim = parse_sim_drive(t.table("sim"), a);
    if (a.homing.target == HomingSteps::Switch::home && !sim.home_switch_steps) {
      homing.fail("switch", fmt::format("the simulated {} has no home switch (set home_switch_at in [{}.sim])", name,
                                        t.key_path()));
    }
    config.drive = std::move(sim);
  } else {
    t.fail("backend", fmt::format("the '{}' backend is not built into this loader yet", backend));
  }
  return config;
}

}  // namespace

SimDriveSettings parse_sim_drive(const ConfigTable& t, const AxisSettings& axis) {
  t.allow_only({"start_position", "limit_min_at", "limit_max_at", "home_switch_at", "home_switch_active", "encoder"});
  const double ups = axis.units_per_step;
  auto steps = [&](std::string_view key, double value) {
    finite(t, key, value);
    return std::llround(value / ups);
  };
  SimDriveSettings s;
  s.name = fmt::format("{} (sim)", axis.name);
  const double limit_min = t.required<double>("limit_min_at");
  const double limit_max = t.required<double>("limit_max_at");
  // Tripping a switch is an alarm: the whole soft range must lie between them.
  if (!(limit_min < axis.min_position)) {
    t.fail("limit_min_at", fmt::format("must be below min_position ({} {}), got {}", axis.min_position, axis.unit, limit_min));
  }
  if (!(limit_max > axis.max_position)) {
    t.fail("limit_max_at", fmt::format("must be above max_position ({} {}), got {}", axis.max_position, axis.unit, limit_max));
  }
  const double start = t.optional<double>("start_position", (axis.min_position + axis.max_position) / 2);
  if (!(start > limit_min && start < limit_max)) {
    t.fail("start_position", fmt::format("must lie between the limit switches ({} .. {} {}), got {}", limit_min, limit_max,
                                         axis.unit, start));
  }
  s.limit_min_steps = steps("limit_min_at", limit_min);
  s.limit_max_steps = steps("limit_max_at", limit_max);
  s.start_position_steps = steps("start_position", start);
  if (auto home = t.maybe<double>("home_switch_at")) s.home_switch_steps = steps("home_switch_at", *home);
  const auto active = t.optional<std::string>("home_switch_active", "below");
  if (active != "below" && active != "above") {
    t.fail("home_switch_active", fmt::format("must be \"below\" or \"above\", got \"{}\"", active));
  }
  s.home_active_above = active == "above";
  s.encoder = t.optional<bool>("encoder", false);
  if (auto problem = check_sim_drive_settings(s)) t.fail(*problem);
  return s;
}

RigConfig parse_rig_config(const ConfigTable& root) {
  RigConfig config;
  config.config_dir = std::filesystem::path(root.source()).parent_path();
  const ConfigTable rig = root.table("rig");
  rig.allow_only({"geometry", "sim", "buses", "rail", "turntable"});
  if (rig.contains("buses")) rig.fail("buses", "Modbus buses are not built into this loader yet");
  config.geometry = parse_geometry(rig.table("geometry"));
  if (auto sim = rig.maybe_table("sim")) config.sim = parse_sim(*sim);
  config.rail = parse_axis(rig, "rail");
  config.turntable = parse_axis(rig, "turntable");

  // The camera must stay in front of the marker's axis over the whole rail.
  const ConfigTable geometry = rig.table("geometry");
  for (double rail : {config.rail.axis.min_position, config.rail.axis.max_position}) {
    const double d = config.geometry.d0_mm + config.geometry.rail_sign * rail;
    if (!(d > 0)) {
      geometry.fail("d0_mm", fmt::format("puts the camera at d = {} mm from the turntable axis at rail position {} mm "
                                         "(must be > 0 over the rail's soft limits)",
                                         d, rail));
    }
  }
  return config;
}

RigConfig load_rig_config(const std::filesystem::path& path) { return parse_rig_config(ConfigTable::load_file(path)); }

std::unique_ptr<Drive> make_drive(const AxisConfig& config, const std::shared_ptr<SimClock>& sim_clock) {
  // One branch per backend: a new DriveSettings alternative without one here
  // does not compile.
  return std::visit(Overloaded{
                        [&](const SimDriveSettings& s) -> std::unique_ptr<Drive> {
                          if (!sim_clock) throw std::invalid_argument(fmt::format("{}: no simulated clock", s.name));
                          return std::make_unique<SimDrive>(s, sim_clock);
                        },
                    },
                    config.drive);
}

std::unique_ptr<Rig> make_rig(const RigConfig& config) {
  const bool simulated = std::holds_alternative<SimDriveSettings>(config.rail.drive) ||
                         std::holds_alternative<SimDriveSettings>(config.turntable.drive);
  auto clock = simulated ? std::make_shared<SimClock>(config.sim.time_scale) : nullptr;
  auto rail = std::make_unique<Axis>(config.rail.axis, make_drive(config.rail, clock));
  auto turntable = std::make_unique<Axis>(config.turntable.axis, make_drive(config.turntable, clock));
  return std::make_unique<Rig>(std::move(rail), std::move(turntable), config.geometry, std::move(clock));
}

}  // namespace markerd::rig
