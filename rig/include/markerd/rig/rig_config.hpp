#pragma once
// The rig's configuration: the [rig] tables of a TOML file (docs/rig.md has
// the reference), parsed once into typed structs whose errors name the file,
// the line and the key; and make_rig, the one place that turns a backend's
// settings into its Drive.

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <variant>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/axis.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/gpio_stepper.hpp"
#include "markerd/rig/modbus_bus.hpp"
#include "markerd/rig/modbus_drive.hpp"
#include "markerd/rig/register_map.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/sim_drive.hpp"

namespace markerd::rig {

struct SimSettings {
  // Simulated seconds per real second, for every simulated device of the rig.
  double time_scale = 1.0;
  // [rig.sim.geometry]: where the simulated camera and marker really stand,
  // when that is not what [rig.geometry] says (a test of a calibration).
  // Unset: the simulated world is the stated geometry.
  std::optional<RigGeometry> geometry;
};

// [rig.<axis>.modbus] with its register map, read when the config is loaded
// so that a mistake in the map is reported with the config's other errors.
struct ModbusAxisSettings {
  ModbusDriveSettings drive;
  RegisterMap map;
};

// One alternative per backend: "sim", "gpio", "modbus".
using DriveSettings = std::variant<SimDriveSettings, GpioStepperSettings, ModbusAxisSettings>;

struct AxisConfig {
  AxisSettings axis;
  DriveSettings drive;
};

struct RigConfig {
  std::string source;                // the file it was read from ("<string>" for parsed text)
  std::filesystem::path config_dir;  // relative paths in the config are relative to it
  // The geometry the ground truth is computed with: [rig.geometry], with a
  // calibration file's measured keys over it.
  RigGeometry geometry;
  RigGeometry configured_geometry;             // [rig.geometry]'s own keys
  std::filesystem::path geometry_calibration;  // the calibration file applied; empty: none
  SimSettings sim;
  // Every [rig.buses.<name>] (each used by at least one axis), by name.
  std::map<std::string, ModbusBusSettings> buses;
  AxisConfig rail;
  AxisConfig turntable;
};

// Reads the [rig] table of a file (other top-level tables are left to their
// owners). ConfigError on any mistake, naming file:line:key.
RigConfig load_rig_config(const std::filesystem::path& path);
RigConfig parse_rig_config(const ConfigTable& root);

// The [rig.<axis>.sim] table; positions in the axis's user units.
SimDriveSettings parse_sim_drive(const ConfigTable& sim_table, const AxisSettings& axis);

// What the config's drives share: one SimClock when any axis is simulated,
// one ModbusBus per bus (opened or connected here: DriveError when the device
// cannot be opened or the server not reached), one GPIO backend (libgpiod
// 1.6) when any axis is a GPIO stepper.
RigDevices make_rig_devices(const RigConfig& config);
// The drive of one axis, by its backend, on the rig's shared devices
// (std::invalid_argument when one it needs is missing). Constructing a
// drive requests its lines or attaches it to its bus: DriveError naming the
// axis and the device when that fails.
std::unique_ptr<Drive> make_drive(const AxisConfig& config, const RigDevices& devices);
// The whole rig: its devices, drives, axes and geometry.
std::unique_ptr<Rig> make_rig(const RigConfig& config);

}  // namespace markerd::rig
