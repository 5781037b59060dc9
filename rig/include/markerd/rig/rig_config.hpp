#pragma once
// The rig's configuration: the [rig] tables of a TOML file (docs/rig.md has
// the reference), parsed once into typed structs whose errors name the file,
// the line and the key; and make_rig, the one place that turns a backend's
// settings into its Drive.

#include <filesystem>
#include <memory>
#include <variant>

#include "markerd/rig/axis.hpp"
#include "markerd/rig/config_table.hpp"
#include "markerd/rig/geometry.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/sim_drive.hpp"

namespace markerd::rig {

struct SimSettings {
  // Simulated seconds per real second, for every simulated device of the rig.
  double time_scale = 1.0;
};

// One alternative per backend ("sim" now; "gpio" and "modbus" join here).
using DriveSettings = std::variant<SimDriveSettings>;

struct AxisConfig {
  AxisSettings axis;
  DriveSettings drive;
};

struct RigConfig {
  std::filesystem::path config_dir;  // relative paths in the config are relative to it
  RigGeometry geometry;
  SimSettings sim;
  AxisConfig rail;
  AxisConfig turntable;
};

// Reads the [rig] table of a file (other top-level tables are left to their
// owners). ConfigError on any mistake, naming file:line:key.
RigConfig load_rig_config(const std::filesystem::path& path);
RigConfig parse_rig_config(const ConfigTable& root);

// The [rig.<axis>.sim] table; positions in the axis's user units.
SimDriveSettings parse_sim_drive(const ConfigTable& sim_table, const AxisSettings& axis);

// The drive of one axis, by its backend. `sim_clock` is the rig's simulated
// clock (used by simulated backends only).
std::unique_ptr<Drive> make_drive(const AxisConfig& config, const std::shared_ptr<SimClock>& sim_clock);
// The whole rig: drives, axes, geometry; one SimClock when any axis is simulated.
std::unique_ptr<Rig> make_rig(const RigConfig& config);

}  // namespace markerd::rig
