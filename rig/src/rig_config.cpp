#include "markerd/rig/rig_config.hpp"

#include <fmt/format.h>

#include <cmath>
#include <string>
#include <string_view>
#include <utility>

#include "markerd/base/read_file.hpp"

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

// The ranges a rig's numbers mean something in. User units are mm or
// degrees: a kilometre of rail or a thousand turns is beyond any rig, and
// within these a position is at most 2^50 steps from 0 (exact in a double,
// far from overflowing the int64 step counts).
using Range = ConfigTable::Range<double>;
constexpr double kMaxPosition = 1e6;

// The ranges of one axis's numbers, in its own unit ("mm", "deg").
struct AxisRanges {
  explicit AxisRanges(std::string_view unit)
      : unit_(unit), per_s_(fmt::format("{}/s", unit)), per_s2_(fmt::format("{}/s^2", unit)) {}
  AxisRanges(const AxisRanges&) = delete;  // the ranges point into the strings
  AxisRanges& operator=(const AxisRanges&) = delete;

  [[nodiscard]] Range position() const { return {-kMaxPosition, kMaxPosition, unit_}; }
  [[nodiscard]] Range length() const { return {0, 2 * kMaxPosition, unit_}; }
  [[nodiscard]] Range units_per_step() const { return {1e-9, 1e3, unit_}; }
  [[nodiscard]] Range velocity() const { return {1e-6, 1e6, per_s_}; }
  [[nodiscard]] Range homing_velocity() const { return {0, 1e6, per_s_}; }  // 0: the default
  [[nodiscard]] Range acceleration() const { return {1e-6, 1e8, per_s2_}; }

 private:
  std::string unit_, per_s_, per_s2_;
};

constexpr Range kGeometryMm{-1e5, 1e5, "mm"};  // 100 m

// Reads the calibrated keys present in `t` over `g`, leaving the others as
// they are: [rig.geometry] over the defaults, a calibration file and
// [rig.sim.geometry] over [rig.geometry].
void read_calibrated_keys(const ConfigTable& t, RigGeometry& g) {
  g.d0_mm = t.optional<double>("d0_mm", g.d0_mm, kGeometryMm);
  g.yaw0_deg = t.optional<double>("yaw0_deg", g.yaw0_deg, {-360, 360, "deg"});
  g.camera_offset_x_mm = t.optional<double>("camera_offset_x_mm", g.camera_offset_x_mm, kGeometryMm);
  g.camera_offset_y_mm = t.optional<double>("camera_offset_y_mm", g.camera_offset_y_mm, kGeometryMm);
  g.marker_offset_normal_mm = t.optional<double>("marker_offset_normal_mm", g.marker_offset_normal_mm, kGeometryMm);
  g.marker_offset_lateral_mm = t.optional<double>("marker_offset_lateral_mm", g.marker_offset_lateral_mm, kGeometryMm);
  // Beyond a few degrees a rail is not tilted but misassembled; 45 leaves
  // room for any rig while keeping cos(tilt), which divides rail positions, far from 0.
  g.rail_tilt_x_deg = t.optional<double>("rail_tilt_x_deg", g.rail_tilt_x_deg, {-45, 45, "deg"});
  g.rail_tilt_y_deg = t.optional<double>("rail_tilt_y_deg", g.rail_tilt_y_deg, {-45, 45, "deg"});
}

int read_rail_sign(const ConfigTable& t, int fallback) {
  const int sign = t.optional<int>("rail_sign", fallback);
  if (sign != 1 && sign != -1) t.fail("rail_sign", fmt::format("must be 1 or -1, got {}", sign));
  return sign;
}

// `calibration = "FILE"`: markerctl calibrate --rig's output, a [rig.geometry]
// table of the measured keys, which override this table's.
void apply_calibration_file(const ConfigTable& t, const std::filesystem::path& config_dir, RigConfig& config) {
  const auto name = t.required<std::string>("calibration");
  std::filesystem::path file(name);
  if (file.is_relative() && !name.empty()) file = config_dir / file;
  try {
    (void)check_regular_file(file, ConfigTable::kMaxFileBytes, "the rig's calibration file");
  } catch (const FileError& e) {
    if (e.missing()) t.fail("calibration", fmt::format("no such calibration file: {}", file.string()));
    t.fail("calibration", e.what());
  }
  const ConfigTable root = ConfigTable::load_file(file);
  root.allow_only({"rig"});
  const ConfigTable rig = root.table("rig");
  rig.allow_only({"geometry"});
  const ConfigTable geometry = rig.table("geometry");
  // What a calibration measures: everything but rail_sign, which is how the
  // rail is wired, not a length.
  geometry.allow_only({"d0_mm", "yaw0_deg", "camera_offset_x_mm", "camera_offset_y_mm", "marker_offset_normal_mm",
                       "marker_offset_lateral_mm", "rail_tilt_x_deg", "rail_tilt_y_deg"});
  read_calibrated_keys(geometry, config.geometry);
  config.geometry_calibration = file;
}

void parse_geometry(const ConfigTable& t, RigConfig& config) {
  t.allow_only({"d0_mm", "yaw0_deg", "rail_sign", "camera_offset_x_mm", "camera_offset_y_mm", "marker_offset_normal_mm",
                "marker_offset_lateral_mm", "rail_tilt_x_deg", "rail_tilt_y_deg", "calibration"});
  RigGeometry& g = config.geometry;
  g.d0_mm = t.required<double>("d0_mm", kGeometryMm);
  read_calibrated_keys(t, g);
  g.rail_sign = read_rail_sign(t, 1);
  config.configured_geometry = g;
  if (t.contains("calibration")) apply_calibration_file(t, config.config_dir, config);
}

// [rig.sim.geometry]: the simulated world's own geometry, where it differs
// from what [rig.geometry] states (a calibration's test); the keys it lacks
// are [rig.geometry]'s own, before any calibration file.
RigGeometry parse_sim_geometry(const ConfigTable& t, const RigGeometry& stated) {
  t.allow_only({"d0_mm", "yaw0_deg", "rail_sign", "camera_offset_x_mm", "camera_offset_y_mm", "marker_offset_normal_mm",
                "marker_offset_lateral_mm", "rail_tilt_x_deg", "rail_tilt_y_deg"});
  RigGeometry g = stated;
  read_calibrated_keys(t, g);
  g.rail_sign = read_rail_sign(t, stated.rail_sign);
  return g;
}

SimSettings parse_sim(const ConfigTable& t, const RigGeometry& stated) {
  t.allow_only({"time_scale", "geometry"});
  SimSettings s;
  // Slower than real time would make the axes' timeouts (real time) fire on
  // moves that are merely slow; faster than SimClock::kMaxTimeScale and the
  // simulation can no longer tell its events apart.
  s.time_scale = t.optional<double>("time_scale", 1.0, {1, SimClock::kMaxTimeScale, "simulated seconds per second"});
  if (auto geometry = t.maybe_table("geometry")) s.geometry = parse_sim_geometry(*geometry, stated);
  return s;
}

HomingSettings parse_homing(const ConfigTable& h, const AxisRanges& r) {
  h.allow_only({"direction", "switch", "search_velocity", "latch_velocity", "backoff", "home_offset", "timeout_s"});
  HomingSettings s;
  s.direction = h.required<int>("direction");
  s.target = parse_switch(h);
  s.search_velocity = h.optional<double>("search_velocity", 0.0, r.homing_velocity());
  s.latch_velocity = h.optional<double>("latch_velocity", 0.0, r.homing_velocity());
  s.backoff = h.optional<double>("backoff", 0.0, r.length());
  s.home_offset = h.optional<double>("home_offset", 0.0, r.position());
  // Converted only once in range: a huge double does not fit milliseconds.
  const double max_s = std::chrono::duration<double>(kMaxHomingTimeout).count();
  const double timeout_s = h.optional<double>("timeout_s", 60.0, {0.1, max_s, "s"});
  s.timeout = std::chrono::milliseconds(std::llround(timeout_s * 1000));
  return s;
}

const GpioLineSpec* gpio_input(const GpioStepperSettings& gpio, HomingSteps::Switch target) {
  const std::optional<GpioLineSpec>& line = target == HomingSteps::Switch::home        ? gpio.home
                                            : target == HomingSteps::Switch::limit_min ? gpio.limit_min
                                                                                       : gpio.limit_max;
  return line ? &*line : nullptr;
}

const char* switch_key(HomingSteps::Switch target) {
  switch (target) {
    case HomingSteps::Switch::home: return "home";
    case HomingSteps::Switch::limit_min: return "limit_min";
    case HomingSteps::Switch::limit_max: return "limit_max";
  }
  return "home";
}

// What parse_axis needs from the rest of the [rig] table.
struct AxisContext {
  std::filesystem::path config_dir;
  const std::map<std::string, ModbusBusSettings>* buses = nullptr;
};

AxisConfig parse_axis(const ConfigTable& rig, std::string_view name, const AxisContext& context) {
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
  const AxisRanges r(a.unit);
  a.units_per_step = t.required<double>("units_per_step", r.units_per_step());
  a.min_position = t.required<double>("min_position", r.position());
  a.max_position = t.required<double>("max_position", r.position());
  a.max_velocity = t.required<double>("max_velocity", r.velocity());
  a.acceleration = t.required<double>("acceleration", r.acceleration());
  a.backlash = t.optional<double>("backlash", 0.0, r.length());
  a.approach_direction = t.optional<int>("approach_direction", 1);
  a.retry_deadband = t.optional<double>("retry_deadband", 0.0, r.length());
  a.max_retries = static_cast<int>(t.optional<std::int64_t>("max_retries", 2, {0, 100}));
  a.settle_time = std::chrono::milliseconds(
      t.optional<std::int64_t>("settle_ms", 200, {0, std::int64_t{kMaxSettleTime.count()}, "ms"}));
  const ConfigTable homing = t.table("homing");
  a.homing = parse_homing(homing, r);
  if (auto problem = check_axis_settings(a)) {
    constexpr std::string_view kHoming = "homing.";
    if (problem->key.starts_with(kHoming)) homing.fail(problem->key.substr(kHoming.size()), problem->message);
    t.fail(problem->key, problem->message);
  }
  // A limit switch sits at its end of the travel: a search the other way can
  // only end at the other limit, with an alarm, at run time.
  if ((a.homing.target == HomingSteps::Switch::limit_min && a.homing.direction != -1) ||
      (a.homing.target == HomingSteps::Switch::limit_max && a.homing.direction != 1)) {
    const bool min = a.homing.target == HomingSteps::Switch::limit_min;
    homing.fail("direction", fmt::format("homing on {} searches towards it: direction must be {}, got {}",
                                         min ? "limit_min" : "limit_max", min ? -1 : 1, a.homing.direction));
  }

  if (backend == "sim") {
    SimDriveSettings sim = parse_sim_drive(t.table("sim"), a);
    if (a.homing.target == HomingSteps::Switch::home && !sim.home_switch_steps) {
      homing.fail("switch", fmt::format("the simulated {} has no home switch (set home_switch_at in [{}.sim])", name,
                                        t.key_path()));
    }
    config.drive = std::move(sim);
  } else if (backend == "gpio") {
    GpioStepperSettings gpio = parse_gpio_stepper(t.table("gpio"));
    if (gpio_input(gpio, a.homing.target) == nullptr) {
      const char* key = switch_key(a.homing.target);
      homing.fail("switch", fmt::format("homing on {} needs the {} input, and [{}.gpio] has no {} line", key, key,
                                        t.key_path(), key));
    }
    // Homing velocities are at most max_velocity (checked above): this bounds them all.
    const double steps_per_s = a.max_velocity / a.units_per_step;
    if (steps_per_s > gpio.max_step_rate * (1 + 1e-9)) {
      t.fail("max_velocity", fmt::format("{} {}/s is {:.0f} steps/s at {} {} per step, above the GPIO stepper's "
                                         "max_step_rate of {} steps/s in [{}.gpio]",
                                         a.max_velocity, a.unit, steps_per_s, a.units_per_step, a.unit,
                                         gpio.max_step_rate, t.key_path()));
    }
    config.drive = std::move(gpio);
  } else {
    const ConfigTable table = t.table("modbus");
    ModbusAxisSettings modbus{parse_modbus_drive(table, context.config_dir), {}};
    if (!context.buses->contains(modbus.drive.bus)) {
      std::string known;
      for (const auto& [bus_name, bus] : *context.buses) known += (known.empty() ? "" : ", ") + bus_name;
      table.fail("bus", fmt::format("no bus '{}' ({})", modbus.drive.bus,
                                    known.empty() ? "the config has no [rig.buses.<name>] table"
                                                  : "buses in [rig.buses]: " + known));
    }
    modbus.map = load_register_map(modbus.drive.map);
    config.drive = std::move(modbus);
  }
  return config;
}

// Mistakes that only show between the two axes.
void check_axes_together(const ConfigTable& rig, const RigConfig& config) {
  const auto* rail_gpio = std::get_if<GpioStepperSettings>(&config.rail.drive);
  const auto* turntable_gpio = std::get_if<GpioStepperSettings>(&config.turntable.drive);
  if (rail_gpio != nullptr && turntable_gpio != nullptr) {
    // A line has one consumer: the second request would fail at start.
    const std::pair<const char*, const std::optional<GpioLineSpec>> rail_lines[] = {
        {"step", rail_gpio->step},           {"dir", rail_gpio->dir},
        {"enable", rail_gpio->enable},       {"limit_min", rail_gpio->limit_min},
        {"limit_max", rail_gpio->limit_max}, {"home", rail_gpio->home},
        {"estop", rail_gpio->estop}};
    const std::pair<const char*, const std::optional<GpioLineSpec>> turntable_lines[] = {
        {"step", turntable_gpio->step},           {"dir", turntable_gpio->dir},
        {"enable", turntable_gpio->enable},       {"limit_min", turntable_gpio->limit_min},
        {"limit_max", turntable_gpio->limit_max}, {"home", turntable_gpio->home},
        {"estop", turntable_gpio->estop}};
    for (const auto& [key, line] : turntable_lines) {
      if (!line) continue;
      for (const auto& [rail_key, rail_line] : rail_lines) {
        if (rail_line && rail_line->chip == line->chip && rail_line->line == line->line) {
          rig.table("turntable")
              .table("gpio")
              .table(key)
              .fail("line", fmt::format("line '{}' of {} is also the rail's {} line (a GPIO line has one user: wire a "
                                        "shared switch to one input per axis)",
                                        line->line, line->chip, rail_key));
        }
      }
    }
  }
  const auto* rail_modbus = std::get_if<ModbusAxisSettings>(&config.rail.drive);
  const auto* turntable_modbus = std::get_if<ModbusAxisSettings>(&config.turntable.drive);
  if (rail_modbus != nullptr && turntable_modbus != nullptr && rail_modbus->drive.bus == turntable_modbus->drive.bus &&
      rail_modbus->drive.unit_id == turntable_modbus->drive.unit_id) {
    rig.table("turntable")
        .table("modbus")
        .fail("unit_id",
              fmt::format("unit {} on bus '{}' is the rail's drive already (drives sharing a bus need their own "
                          "unit ids)",
                          turntable_modbus->drive.unit_id, turntable_modbus->drive.bus));
  }
  // A bus no axis names is a typo in one of the axes' `bus` keys (or a leftover).
  if (!config.buses.empty()) {
    const ConfigTable buses = rig.table("buses");
    for (const auto& [name, bus] : config.buses) {
      const bool used = (rail_modbus != nullptr && rail_modbus->drive.bus == name) ||
                        (turntable_modbus != nullptr && turntable_modbus->drive.bus == name);
      if (!used) {
        buses.fail(name, fmt::format("no axis uses bus '{}' (check the bus keys of [rig.rail.modbus] and "
                                     "[rig.turntable.modbus], or remove the bus)",
                                     name));
      }
    }
  }
}

}  // namespace

SimDriveSettings parse_sim_drive(const ConfigTable& t, const AxisSettings& axis) {
  t.allow_only({"start_position", "limit_min_at", "limit_max_at", "home_switch_at", "home_switch_active", "encoder"});
  const double ups = axis.units_per_step;
  // In range (positions, and units_per_step checked with the axis): the step
  // count fits.
  auto steps = [&](std::string_view key, double value) {
    const double count = value / ups;
    if (!(std::abs(count) < 9007199254740992.0)) t.fail(key, "is more than 2^53 steps away from 0");
    return std::llround(count);
  };
  const AxisRanges r(axis.unit);
  SimDriveSettings s;
  s.name = fmt::format("{} (sim)", axis.name);
  const double limit_min = t.required<double>("limit_min_at", r.position());
  const double limit_max = t.required<double>("limit_max_at", r.position());
  // Tripping a switch is an alarm: the whole soft range must lie between them.
  if (!(limit_min < axis.min_position)) {
    t.fail("limit_min_at",
           fmt::format("must be below min_position ({} {}), got {}", axis.min_position, axis.unit, limit_min));
  }
  if (!(limit_max > axis.max_position)) {
    t.fail("limit_max_at",
           fmt::format("must be above max_position ({} {}), got {}", axis.max_position, axis.unit, limit_max));
  }
  const double start = t.optional<double>("start_position", (axis.min_position + axis.max_position) / 2, r.position());
  if (!(start > limit_min && start < limit_max)) {
    t.fail("start_position", fmt::format("must lie between the limit switches ({} .. {} {}), got {}", limit_min,
                                         limit_max, axis.unit, start));
  }
  s.limit_min_steps = steps("limit_min_at", limit_min);
  s.limit_max_steps = steps("limit_max_at", limit_max);
  s.start_position_steps = steps("start_position", start);
  if (auto home = t.maybe<double>("home_switch_at", r.position())) s.home_switch_steps = steps("home_switch_at", *home);
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
  config.source = root.source();
  config.config_dir = std::filesystem::path(root.source()).parent_path();
  const ConfigTable rig = root.table("rig");
  rig.allow_only({"geometry", "sim", "buses", "rail", "turntable"});
  parse_geometry(rig.table("geometry"), config);
  if (auto sim = rig.maybe_table("sim")) config.sim = parse_sim(*sim, config.configured_geometry);
  if (auto buses = rig.maybe_table("buses")) {
    for (const auto& [key, node] : buses->raw()) {
      const std::string name(key.str());
      if (!node.is_table()) buses->fail(name, "must be a table: [rig.buses.<name>] with the bus's keys");
      config.buses.emplace(name, parse_modbus_bus(buses->table(name)));
    }
  }
  const AxisContext context{config.config_dir, &config.buses};
  config.rail = parse_axis(rig, "rail", context);
  config.turntable = parse_axis(rig, "turntable", context);
  check_axes_together(rig, config);

  // The camera must stay in front of the marker's axis over the whole rail.
  const ConfigTable geometry = rig.table("geometry");
  for (double rail : {config.rail.axis.min_position, config.rail.axis.max_position}) {
    const double d = axis_distance_mm(config.geometry, rail);
    if (!(d > 0)) {
      geometry.fail("d0_mm", fmt::format("puts the camera at d = {} mm from the turntable axis at rail position {} mm "
                                         "(must be > 0 over the rail's soft limits)",
                                         d, rail));
    }
  }
  return config;
}

RigConfig load_rig_config(const std::filesystem::path& path) { return parse_rig_config(ConfigTable::load_file(path)); }

RigDevices make_rig_devices(const RigConfig& config) {
  RigDevices devices;
  const auto uses = [&](auto backend) {
    return std::holds_alternative<decltype(backend)>(config.rail.drive) ||
           std::holds_alternative<decltype(backend)>(config.turntable.drive);
  };
  if (uses(SimDriveSettings{})) devices.sim_clock = std::make_shared<SimClock>(config.sim.time_scale);
  if (uses(GpioStepperSettings{})) devices.gpio = make_gpiod1_backend();
  // Every bus is used (the loader refuses the others); two drives on one
  // bus share its thread and its line.
  for (const auto& [name, settings] : config.buses) devices.buses.emplace(name, std::make_shared<ModbusBus>(settings));
  return devices;
}

std::unique_ptr<Drive> make_drive(const AxisConfig& config, const RigDevices& devices) {
  // One branch per backend: a new DriveSettings alternative without one here
  // does not compile.
  return std::visit(
      Overloaded{
          [&](const SimDriveSettings& s) -> std::unique_ptr<Drive> {
            if (!devices.sim_clock) throw std::invalid_argument(fmt::format("{}: no simulated clock", s.name));
            return std::make_unique<SimDrive>(s, devices.sim_clock);
          },
          [&](const GpioStepperSettings& s) -> std::unique_ptr<Drive> {
            if (!devices.gpio) throw std::invalid_argument(fmt::format("{}: no GPIO backend", config.axis.name));
            return std::make_unique<GpioStepperDrive>(config.axis.name, s, *devices.gpio);
          },
          [&](const ModbusAxisSettings& s) -> std::unique_ptr<Drive> {
            const auto bus = devices.buses.find(s.drive.bus);
            if (bus == devices.buses.end() || !bus->second) {
              throw std::invalid_argument(fmt::format("{}: no Modbus bus '{}'", config.axis.name, s.drive.bus));
            }
            return std::make_unique<ModbusDrive>(config.axis.name, bus->second, s.drive.unit_id, s.map,
                                                 s.drive.completion_margin);
          },
      },
      config.drive);
}

std::unique_ptr<Rig> make_rig(const RigConfig& config) {
  RigDevices devices = make_rig_devices(config);
  auto rail = std::make_unique<Axis>(config.rail.axis, make_drive(config.rail, devices));
  auto turntable = std::make_unique<Axis>(config.turntable.axis, make_drive(config.turntable, devices));
  return std::make_unique<Rig>(std::move(rail), std::move(turntable), config.geometry, std::move(devices));
}

}  // namespace markerd::rig
