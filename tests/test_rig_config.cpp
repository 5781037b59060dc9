// The rig's config: the shipped simulated rig loads into the expected typed
// settings, and each mistake is reported with the file, the line and the key.

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <unistd.h>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "markerd/rig/rig_config.hpp"
#include "markerd/rig/testing/modbus_drive_sim.hpp"
#include "support/files.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

using namespace markerd::rig;
using markerd::ConfigError;

namespace {

const char* kBase = R"([rig.geometry]
d0_mm = 300.0

[rig.sim]
time_scale = 10.0

[rig.rail]
backend = "sim"
unit = "mm"
units_per_step = 0.025
min_position = 0.0
max_position = 2500.0
max_velocity = 50.0
acceleration = 100.0
settle_ms = 200

[rig.rail.homing]
direction = -1
switch = "limit_min"
home_offset = -3.0

[rig.rail.sim]
limit_min_at = -3.0
limit_max_at = 2503.0

[rig.turntable]
backend = "sim"
unit = "deg"
units_per_step = 0.01
min_position = -90.0
max_position = 90.0
max_velocity = 30.0
acceleration = 60.0

[rig.turntable.homing]
direction = -1
switch = "home"

[rig.turntable.sim]
limit_min_at = -95.0
limit_max_at = 95.0
home_switch_at = 0.0
)";

class RigConfigFile : public testing::Test {
 protected:
  RigConfig load(const std::string& text) {
    std::ofstream(path_) << text;
    return load_rig_config(path_);
  }

  struct Outcome {
    std::string error;  // the ConfigError's text
    std::string where;  // "file:N", N the replaced line's number
  };

  // Loads the base with its first `line` replaced.
  Outcome error_with(const std::string& line, const std::string& replacement) {
    std::string text = kBase;
    const auto at = text.find(line);
    EXPECT_NE(at, std::string::npos) << line;
    if (at == std::string::npos) return {};
    text.replace(at, line.size(), replacement);
    const auto number = 1 + std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n');
    Outcome outcome{"(no error)", fmt::format("{}:{}", path_.string(), number)};
    try {
      load(text);
    } catch (const ConfigError& e) {
      outcome.error = e.what();
    }
    return outcome;
  }

  const markerd::test_support::TempDir temp_{"markerd-rig-config"};
  const std::filesystem::path dir_ = temp_.path();
  const std::filesystem::path path_ = dir_ / "rig.toml";
};

}  // namespace

TEST_F(RigConfigFile, TheBaseIsValid) {
  const RigConfig c = load(kBase);
  EXPECT_EQ(c.config_dir, dir_);
  EXPECT_EQ(c.sim.time_scale, 10.0);
  // Defaults for what the base leaves out.
  EXPECT_EQ(c.rail.axis.max_retries, 2);
  EXPECT_EQ(c.rail.axis.approach_direction, 1);
  EXPECT_EQ(c.turntable.axis.settle_time, std::chrono::milliseconds(200));
  EXPECT_EQ(c.turntable.axis.homing.timeout, std::chrono::milliseconds(60000));
  const auto& sim = std::get<SimDriveSettings>(c.rail.drive);
  EXPECT_EQ(sim.start_position_steps, 50000);  // the middle of the soft limits
}

TEST(RigConfig, TheShippedSimulatedRigLoads) {
  const RigConfig c = load_rig_config(MARKERD_SOURCE_DIR "/config/rig-sim.toml");
  EXPECT_EQ(c.geometry.d0_mm, 300.0);
  EXPECT_EQ(c.geometry.yaw0_deg, 0.0);
  EXPECT_EQ(c.sim.time_scale, 1.0);

  const AxisSettings& rail = c.rail.axis;
  EXPECT_EQ(rail.name, "rail");
  EXPECT_EQ(rail.unit, "mm");
  EXPECT_DOUBLE_EQ(1.0 / rail.units_per_step * 10, 400);  // steps per cm
  EXPECT_EQ(rail.min_position, 0);
  EXPECT_EQ(rail.max_position, 2500);
  EXPECT_EQ(rail.settle_time, std::chrono::milliseconds(200));
  EXPECT_EQ(rail.homing.target, markerd::rig::HomingSteps::Switch::limit_min);
  EXPECT_EQ(rail.homing.direction, -1);
  EXPECT_EQ(rail.homing.home_offset, -3.0);
  EXPECT_EQ(rail.homing.timeout, std::chrono::milliseconds(150000));
  const auto& rail_sim = std::get<SimDriveSettings>(c.rail.drive);
  EXPECT_EQ(rail_sim.name, "rail (sim)");
  EXPECT_EQ(rail_sim.limit_min_steps, -120);
  EXPECT_EQ(rail_sim.limit_max_steps, 100120);
  EXPECT_EQ(rail_sim.start_position_steps, 48000);
  EXPECT_FALSE(rail_sim.home_switch_steps.has_value());

  const AxisSettings& turntable = c.turntable.axis;
  EXPECT_EQ(turntable.unit, "deg");
  EXPECT_EQ(turntable.min_position, -90);
  EXPECT_EQ(turntable.max_position, 90);
  EXPECT_EQ(turntable.backlash, 0.2);
  EXPECT_EQ(turntable.homing.target, markerd::rig::HomingSteps::Switch::home);
  const auto& turntable_sim = std::get<SimDriveSettings>(c.turntable.drive);
  EXPECT_EQ(turntable_sim.home_switch_steps, 0);
  EXPECT_FALSE(turntable_sim.home_active_above);
  EXPECT_EQ(turntable_sim.start_position_steps, 2500);
}

TEST_F(RigConfigFile, ErrorsNameTheFileTheLineAndTheKey) {
  {
    const auto [error, where] = error_with("max_position = 2500.0", "max_position = -10.0");
    EXPECT_EQ(error, where + ": rig.rail.max_position: must be above min_position (0 mm), got -10");
  }
  {
    const auto [error, where] = error_with("settle_ms = 200", "settle_ms = -5");
    EXPECT_EQ(error, where + ": rig.rail.settle_ms: must be from 0 to 60000 ms, got -5");
  }
  {
    const auto [error, where] = error_with("switch = \"limit_min\"", "switch = \"limit_mid\"");
    EXPECT_EQ(error,
              where + ": rig.rail.homing.switch: unknown switch 'limit_mid' (known: home, limit_min, limit_max)");
  }
  {
    const auto [error, where] = error_with("max_velocity = 50.0", "max_velocty = 50.0");
    const std::string expected = where + ": rig.rail.max_velocty: unknown key (known here: backend, unit,";
    EXPECT_EQ(error.substr(0, expected.size()), expected);
  }
  {
    const auto [error, where] = error_with("time_scale = 10.0", "time_scale = 0.5");
    EXPECT_EQ(error, where + ": rig.sim.time_scale: must be from 1 to 1000 simulated seconds per second, got 0.5");
  }
  {
    const auto [error, where] = error_with("limit_min_at = -3.0", "limit_min_at = 5.0");
    EXPECT_EQ(error, where + ": rig.rail.sim.limit_min_at: must be below min_position (0 mm), got 5");
  }
  {
    const auto [error, where] = error_with("units_per_step = 0.025", "units_per_step = \"0.025\"");
    EXPECT_EQ(error, where + ": rig.rail.units_per_step: must be a number");
  }
  {
    const auto [error, where] =
        error_with("direction = -1\nswitch = \"limit_min\"", "direction = 0\nswitch = \"limit_min\"");
    EXPECT_EQ(error, where + ": rig.rail.homing.direction: must be 1 or -1, got 0");
  }
  {
    // Caught here rather than by an alarm at the other end of the rail.
    const auto [error, where] =
        error_with("direction = -1\nswitch = \"limit_min\"", "direction = 1\nswitch = \"limit_min\"");
    EXPECT_EQ(
        error,
        where + ": rig.rail.homing.direction: homing on limit_min searches towards it: direction must be -1, got 1");
  }
  {
    const auto [error, where] = error_with("switch = \"limit_min\"", "switch = \"home\"");
    EXPECT_EQ(
        error,
        where +
            ": rig.rail.homing.switch: the simulated rail has no home switch (set home_switch_at in [rig.rail.sim])");
  }
  {
    const auto [error, where] = error_with("d0_mm = 300.0", "d0_mm = 300.0\nrail_sign = -1");
    EXPECT_EQ(
        error,
        where +
            ": rig.geometry.d0_mm: puts the camera at d = -2200 mm from the turntable axis at rail position 2500 mm "
            "(must be > 0 over the rail's soft limits)");
  }
}

// A calibration file over [rig.geometry], and the simulated world's own
// geometry beside it: each key missing from either is [rig.geometry]'s.
TEST_F(RigConfigFile, ACalibrationFileAndTheSimulatedWorldsGeometry) {
  std::ofstream(dir_ / "calibrated.toml") << "[rig.geometry]\nd0_mm = 311.5\nrail_tilt_x_deg = 0.4\n";
  std::string text = kBase;
  text.replace(text.find("d0_mm = 300.0"), 13,
               "d0_mm = 300.0\nyaw0_deg = 1.0\nrail_tilt_y_deg = -0.5\ncalibration = \"calibrated.toml\"");
  text.replace(text.find("time_scale = 10.0"), 17,
               "time_scale = 10.0\n\n[rig.sim.geometry]\nd0_mm = 312.0\nmarker_offset_normal_mm = 5.0");
  const RigConfig c = load(text);
  EXPECT_EQ(c.geometry_calibration, dir_ / "calibrated.toml");
  EXPECT_EQ(c.geometry.d0_mm, 311.5);
  EXPECT_EQ(c.geometry.rail_tilt_x_deg, 0.4);
  EXPECT_EQ(c.geometry.rail_tilt_y_deg, -0.5);  // the config's: the file does not say
  EXPECT_EQ(c.geometry.yaw0_deg, 1.0);
  EXPECT_EQ(c.configured_geometry.d0_mm, 300.0);
  EXPECT_EQ(c.configured_geometry.rail_tilt_x_deg, 0.0);
  ASSERT_TRUE(c.sim.geometry.has_value());
  EXPECT_EQ(c.sim.geometry->d0_mm, 312.0);
  EXPECT_EQ(c.sim.geometry->marker_offset_normal_mm, 5.0);
  EXPECT_EQ(c.sim.geometry->yaw0_deg, 1.0);         // [rig.geometry]'s
  EXPECT_EQ(c.sim.geometry->rail_tilt_x_deg, 0.0);  // not the calibration file's
  EXPECT_EQ(c.sim.geometry->rail_tilt_y_deg, -0.5);

  {
    const auto [error, where] = error_with("d0_mm = 300.0", "calibration = \"missing.toml\"\nd0_mm = 300.0");
    EXPECT_EQ(error, fmt::format("{}: rig.geometry.calibration: no such calibration file: {}", where,
                                 (dir_ / "missing.toml").string()));
  }
  std::ofstream(dir_ / "calibrated.toml") << "[rig.geometry]\nd0_mm = 311.5\nrail_sign = -1\n";
  {
    const auto [error, where] = error_with("d0_mm = 300.0", "d0_mm = 300.0\ncalibration = \"calibrated.toml\"");
    EXPECT_NE(error.find((dir_ / "calibrated.toml").string() + ":3: rig.geometry.rail_sign: unknown key"),
              std::string::npos)
        << error;
  }
  {
    const auto [error, where] = error_with("d0_mm = 300.0", "rail_tilt_x_deg = 50\nd0_mm = 300.0");
    EXPECT_EQ(error, where + ": rig.geometry.rail_tilt_x_deg: must be from -45 to 45 deg, got 50");
  }
}

// Every number has a range it means something in; a value outside it is
// refused where it stands instead of overflowing a conversion at run time
// (a settle time of INT64_MAX ms was "settled" at once) or spinning the
// simulation (time_scale 1e308).
TEST_F(RigConfigFile, NumbersOutsideTheirPhysicalRangesAreRefused) {
  const struct {
    const char* line;
    const char* replacement;
    const char* expected;
  } cases[] = {
      {"settle_ms = 200", "settle_ms = 9223372036854775807",
       "rig.rail.settle_ms: must be from 0 to 60000 ms, got 9223372036854775807"},
      {"settle_ms = 200", "settle_ms = 100000000", "rig.rail.settle_ms: must be from 0 to 60000 ms, got 100000000"},
      {"time_scale = 10.0", "time_scale = 1e308",
       "rig.sim.time_scale: must be from 1 to 1000 simulated seconds per second, got 1e+308"},
      {"time_scale = 10.0", "time_scale = nan", "rig.sim.time_scale: must be a finite number, got nan"},
      {"home_offset = -3.0", "home_offset = -3.0\ntimeout_s = 1e300",
       "rig.rail.homing.timeout_s: must be from 0.1 to 3600 s, got 1e+300"},
      {"home_offset = -3.0", "home_offset = -3e300",
       "rig.rail.homing.home_offset: must be from -1000000 to 1000000 mm, got -3e+300"},
      {"units_per_step = 0.025", "units_per_step = 1e-300",
       "rig.rail.units_per_step: must be from 1e-09 to 1000 mm, got 1e-300"},
      {"max_velocity = 50.0", "max_velocity = inf", "rig.rail.max_velocity: must be a finite number, got inf"},
      {"acceleration = 60.0", "acceleration = 1e12",
       "rig.turntable.acceleration: must be from 1e-06 to 100000000 deg/s^2, got 1000000000000"},
      {"d0_mm = 300.0", "d0_mm = 1e200", "rig.geometry.d0_mm: must be from -100000 to 100000 mm, got 1e+200"},
      {"limit_max_at = 95.0", "limit_max_at = 1e20",
       "rig.turntable.sim.limit_max_at: must be from -1000000 to 1000000 deg, got 1e+20"},
      {"settle_ms = 200", "settle_ms = 200\nmax_retries = 2147483648",
       "rig.rail.max_retries: must be from 0 to 100, got 2147483648"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.replacement);
    const auto [error, where] = error_with(c.line, c.replacement);
    const auto key_line = std::string(c.replacement).find('\n') == std::string::npos
                              ? where
                              : fmt::format("{}:{}", where.substr(0, where.rfind(':')),
                                            std::stoi(where.substr(where.rfind(':') + 1)) + 1);
    EXPECT_EQ(error, key_line + ": " + c.expected);
  }
}

TEST_F(RigConfigFile, EachAxisTableBelongsToItsBackend) {
  {
    const auto [error, where] = error_with("backend = \"sim\"", "backend = \"steam\"");
    EXPECT_EQ(error, where + ": rig.rail.backend: unknown backend 'steam' (known: sim, gpio, modbus)");
  }
  // The table of another backend than the one chosen is a mistake, whichever backend.
  {
    const auto [error, where] = error_with("[rig.rail.sim]", "[rig.rail.modbus]\nunit_id = 1\n[rig.rail.sim]");
    EXPECT_EQ(error, where +
                         ": rig.rail.modbus: unknown key (known here: backend, unit, units_per_step, min_position, "
                         "max_position, max_velocity, acceleration, backlash, approach_direction, retry_deadband, "
                         "max_retries, settle_ms, homing, sim)");
  }
  {
    const std::string sim_rail = "backend = \"sim\"\nunit = \"mm\"";
    std::string text = kBase;
    text.replace(text.find(sim_rail), sim_rail.size(), "backend = \"gpio\"\nunit = \"mm\"");
    std::ofstream(path_) << text;
    try {
      load_rig_config(path_);
      FAIL() << "no error";
    } catch (const ConfigError& e) {
      EXPECT_EQ(std::string(e.what()).rfind(path_.string() + ":22: rig.rail.sim: unknown key (known here: backend,", 0),
                0u)
          << e.what();
      EXPECT_NE(std::string(e.what()).find("homing, gpio)"), std::string::npos) << e.what();
    }
  }
}

TEST_F(RigConfigFile, MisspelledTablesAndSyntaxErrorsAreReported) {
  EXPECT_NE(error_with("[rig.turntable]", "[rig.turntabel]").error.find("rig.turntabel: unknown key"),
            std::string::npos);
  const auto [syntax, where] = error_with("acceleration = 60.0", "acceleration = ");
  EXPECT_EQ(syntax.rfind(where + ":", 0), 0U) << syntax;
}

// ---------------------------------------------------------------- every backend through the loader

namespace {

const std::filesystem::path kSourceDir = MARKERD_SOURCE_DIR;

using markerd::test_support::read_file;

void replace_once(std::string& text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  text.replace(at, from.size(), to);
}

// Shipped configs rewritten by a test, in a directory of their own; their
// relative map paths made absolute.
class WrittenConfig : public testing::Test {
 protected:
  std::filesystem::path write(std::string text) {
    while (text.find("map = \"drives/") != std::string::npos) {
      replace_once(text, "map = \"drives/", "map = \"" + (kSourceDir / "config/drives/").string());
    }
    const auto path = dir_.path() / "rig.toml";
    std::ofstream(path) << text;
    return path;
  }

  // The ConfigError of `text`, and "file:N" for the line holding `marker`.
  std::pair<std::string, std::string> error_at(const std::string& text, const std::string& marker) {
    const auto path = write(text);
    std::string rewritten = read_file(path);
    const auto at = rewritten.find(marker);
    EXPECT_NE(at, std::string::npos) << marker;
    const auto line = 1 + std::count(rewritten.begin(), rewritten.begin() + static_cast<std::ptrdiff_t>(at), '\n');
    std::string error = "(no error)";
    try {
      (void)load_rig_config(path);
    } catch (const ConfigError& e) {
      error = e.what();
    }
    return {error, fmt::format("{}:{}", path.string(), line)};
  }

  const markerd::test_support::TempDir dir_{"markerd-rig-config"};
};

}  // namespace

TEST(RigConfig, EveryShippedConfigLoads) {
  const RigConfig sim = load_rig_config(kSourceDir / "config/rig-sim.toml");
  EXPECT_TRUE(std::holds_alternative<SimDriveSettings>(sim.rail.drive));
  EXPECT_TRUE(sim.buses.empty());

  const RigConfig gpio = load_rig_config(kSourceDir / "config/rig-gpio.toml");
  const auto& rail_gpio = std::get<GpioStepperSettings>(gpio.rail.drive);
  const auto& turntable_gpio = std::get<GpioStepperSettings>(gpio.turntable.drive);
  EXPECT_EQ(rail_gpio.step.chip, "gpiochip0");
  EXPECT_EQ(rail_gpio.step.line, "GPIO17");
  EXPECT_EQ(rail_gpio.consumer, "markerd-rail");
  EXPECT_EQ(turntable_gpio.estop->line, "GPIO19");
  EXPECT_DOUBLE_EQ(1.0 / gpio.rail.axis.units_per_step * 10, 400);  // the thesis rail: 400 steps per cm
  EXPECT_TRUE(gpio.buses.empty());

  const RigConfig rtu = load_rig_config(kSourceDir / "config/rig-modbus-rtu.toml");
  ASSERT_EQ(rtu.buses.size(), 1u);
  EXPECT_EQ(rtu.buses.at("rtu0").device, "/dev/ttyUSB0");
  const auto& rail_rtu = std::get<ModbusAxisSettings>(rtu.rail.drive);
  const auto& turntable_rtu = std::get<ModbusAxisSettings>(rtu.turntable.drive);
  EXPECT_EQ(rail_rtu.drive.bus, "rtu0");
  EXPECT_EQ(turntable_rtu.drive.bus, "rtu0");  // two drives on one line, by unit id
  EXPECT_EQ(rail_rtu.drive.unit_id, 1);
  EXPECT_EQ(turntable_rtu.drive.unit_id, 2);
  EXPECT_EQ(rail_rtu.map.source, (kSourceDir / "config/drives/generic.toml").string());
  EXPECT_EQ(rail_rtu.map.target_position.address, 0x0000);

  const RigConfig tcp = load_rig_config(kSourceDir / "config/rig-modbus-tcp.toml");
  ASSERT_EQ(tcp.buses.size(), 2u);
  EXPECT_EQ(tcp.buses.at("rail").transport, ModbusTransport::tcp);
  EXPECT_EQ(tcp.buses.at("turntable").host, "192.168.10.22");
  EXPECT_EQ(std::get<ModbusAxisSettings>(tcp.turntable.drive).drive.bus, "turntable");
}

TEST(RigConfig, TheGpioRigNamesTheMissingChip) {
  if (std::filesystem::exists("/dev/gpiochip0")) GTEST_SKIP() << "this machine has a gpiochip0";
  const RigConfig config = load_rig_config(kSourceDir / "config/rig-gpio.toml");
  try {
    (void)make_rig(config);
    FAIL() << "a rig without its GPIO chip";
  } catch (const DriveError& e) {
    const std::string error = e.what();
    EXPECT_EQ(
        error.rfind("rail (gpio gpiochip0): GPIO chip 'gpiochip0' (/dev/gpiochip0): No such file or directory", 0), 0u)
        << error;
  }
}

TEST_F(WrittenConfig, TheModbusTcpRigHomesAndMovesBothAxes) {
  // One simulated drive server per bus, as the config has one drive (or
  // gateway) per connection, on the shared simulated clock at 20x.
  const auto clock = std::make_shared<SimClock>(20.0);
  const auto unit = [](double start_steps) {
    ModbusSimUnit u;
    u.unit_id = 1;
    u.map = load_register_map(kSourceDir / "config/drives/generic.toml");
    u.start_position_steps = start_steps;
    return u;
  };
  ModbusDriveSim rail_drive({unit(30000)}, ModbusSimTcp{}, clock);
  ModbusDriveSim turntable_drive({unit(-800)}, ModbusSimTcp{}, clock);
  rail_drive.start();
  turntable_drive.start();

  const RigConfig config = load_rig_config(markerd::test_support::write_modbus_tcp_rig_config(
      dir_.path() / "rig.toml", rail_drive.port(), turntable_drive.port()));
  const std::unique_ptr<Rig> rig = make_rig(config);
  ASSERT_EQ(rig->devices().buses.size(), 2u);
  EXPECT_EQ(rig->sim_clock(), nullptr) << "no simulated axis in this rig";

  for (Axis* axis : {&rig->rail(), &rig->turntable()}) {
    axis->enable();
    axis->home();
    ASSERT_TRUE(axis->wait_settled(std::chrono::seconds(60))) << axis->settings().name << ": " << axis->status().fault;
    EXPECT_TRUE(axis->status().homed);
  }
  rig->rail().move_to(250.0);
  rig->turntable().move_to(30.0);
  ASSERT_TRUE(rig->rail().wait_settled(std::chrono::seconds(60))) << rig->rail().status().fault;
  ASSERT_TRUE(rig->turntable().wait_settled(std::chrono::seconds(60))) << rig->turntable().status().fault;
  EXPECT_NEAR(rig->rail().status().position, 250.0, 0.05);
  EXPECT_NEAR(rig->turntable().status().position, 30.0, 0.05);
  // What the drives did, seen from the servers.
  EXPECT_EQ(rail_drive.state(1).target_steps, 25000);     // 250 mm at 0.01 mm per step
  EXPECT_EQ(turntable_drive.state(1).target_steps, 833);  // 30 deg at 0.036 deg per step
  EXPECT_EQ(rail_drive.state(1).homings, 1);
  EXPECT_EQ(turntable_drive.state(1).homings, 1);
  const RigSnapshot snapshot = rig->snapshot();
  EXPECT_NEAR(rig->ground_truth(snapshot).distance_m, 0.55, 1e-3);
}

TEST_F(WrittenConfig, BusesAndModbusAxesAreCheckedTogether) {
  const std::string rtu = read_file(kSourceDir / "config/rig-modbus-rtu.toml");
  {
    std::string text = rtu;
    replace_once(text, "bus = \"rtu0\"\nunit_id = 2", "bus = \"rtu1\"\nunit_id = 2");
    const auto [error, where] = error_at(text, "bus = \"rtu1\"");
    EXPECT_EQ(error, where + ": rig.turntable.modbus.bus: no bus 'rtu1' (buses in [rig.buses]: rtu0)");
  }
  {
    std::string text = rtu;
    replace_once(text, "[rig.rail]", "[rig.buses.spare]\ntype = \"tcp\"\nhost = \"10.0.0.9\"\n\n[rig.rail]");
    const auto [error, where] = error_at(text, "[rig.buses.spare]");
    EXPECT_EQ(error, where +
                         ": rig.buses.spare: no axis uses bus 'spare' (check the bus keys of [rig.rail.modbus] "
                         "and [rig.turntable.modbus], or remove the bus)");
  }
  {
    std::string text = rtu;
    replace_once(text, "bus = \"rtu0\"\nunit_id = 2", "bus = \"rtu0\"\nunit_id = 1");
    const auto [error, table_at] = error_at(text, "[rig.turntable.modbus]");
    const auto colon = table_at.rfind(':');
    const std::string where =
        fmt::format("{}:{}", table_at.substr(0, colon), std::stoi(table_at.substr(colon + 1)) + 2);
    EXPECT_EQ(error, where +
                         ": rig.turntable.modbus.unit_id: unit 1 on bus 'rtu0' is the rail's drive already "
                         "(drives sharing a bus need their own unit ids)");
  }
  {
    // A mistake in the drive's map is a config error too, naming the map's line.
    const auto map = dir_.path() / "broken-map.toml";
    std::string map_text = read_file(kSourceDir / "config/drives/generic.toml");
    replace_once(map_text, "[velocity]\naddress = 0x0002", "[velocity]\naddress = 0x0002\nsacle = 2");
    std::ofstream(map) << map_text;
    std::string text = rtu;
    replace_once(text, "map = \"drives/generic.toml\"", fmt::format("map = \"{}\"", map.string()));
    const auto [error, where] = error_at(text, "[rig.geometry]");
    (void)where;
    EXPECT_NE(error.find(map.string() + ":"), std::string::npos) << error;
    EXPECT_NE(error.find("velocity.sacle: unknown key"), std::string::npos) << error;
  }
}

TEST_F(WrittenConfig, GpioAxesAreCheckedAgainstTheirLines) {
  const std::string gpio = read_file(kSourceDir / "config/rig-gpio.toml");
  {
    std::string text = gpio;
    replace_once(text, "max_velocity = 50.0 ", "max_velocity = 70.0 ");
    const auto [error, where] = error_at(text, "max_velocity = 70.0");
    EXPECT_EQ(error, where +
                         ": rig.rail.max_velocity: 70 mm/s is 2800 steps/s at 0.025 mm per step, above the GPIO "
                         "stepper's max_step_rate of 2500 steps/s in [rig.rail.gpio]");
  }
  {
    std::string text = gpio;
    replace_once(text, "home = { line = \"GPIO16\", active_low = true }", "");
    const auto [error, where] = error_at(text, "switch = \"home\"\nsearch_velocity = 5.0");
    EXPECT_EQ(error, where +
                         ": rig.turntable.homing.switch: homing on home needs the home input, and "
                         "[rig.turntable.gpio] has no home line");
  }
  {
    std::string text = gpio;
    replace_once(text, "estop = { line = \"GPIO19\" }", "estop = { line = \"GPIO26\" }");
    const auto [error, where] = error_at(text, "estop = { line = \"GPIO26\" }                       # pin 35");
    EXPECT_EQ(error, where +
                         ": rig.turntable.gpio.estop.line: line 'GPIO26' of gpiochip0 is also the rail's estop "
                         "line (a GPIO line has one user: wire a shared switch to one input per axis)");
  }
}
