// The rig's config: the shipped simulated rig loads into the expected typed
// settings, and each mistake is reported with the file, the line and the key.

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>

#include "markerd/rig/rig_config.hpp"

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
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() / fmt::format("markerd-rig-config-{}", ::getpid());
    std::filesystem::create_directories(dir_);
    path_ = dir_ / "rig.toml";
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

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

  std::filesystem::path dir_;
  std::filesystem::path path_;
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
    EXPECT_EQ(error, where + ": rig.rail.settle_ms: must be >= 0, got -5");
  }
  {
    const auto [error, where] = error_with("switch = \"limit_min\"", "switch = \"limit_mid\"");
    EXPECT_EQ(error, where + ": rig.rail.homing.switch: unknown switch 'limit_mid' (known: home, limit_min, limit_max)");
  }
  {
    const auto [error, where] = error_with("max_velocity = 50.0", "max_velocty = 50.0");
    const std::string expected = where + ": rig.rail.max_velocty: unknown key (known here: backend, unit,";
    EXPECT_EQ(error.substr(0, expected.size()), expected);
  }
  {
    const auto [error, where] = error_with("time_scale = 10.0", "time_scale = 0.5");
    EXPECT_EQ(error, where + ": rig.sim.time_scale: must be a finite number >= 1 (the axes' timeouts run in real time), got 0.5");
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
    const auto [error, where] = error_with("direction = -1\nswitch = \"limit_min\"", "direction = 0\nswitch = \"limit_min\"");
    EXPECT_EQ(error, where + ": rig.rail.homing.direction: must be 1 or -1, got 0");
  }
  {
    const auto [error, where] = error_with("switch = \"limit_min\"", "switch = \"home\"");
    EXPECT_EQ(error, where + ": rig.rail.homing.switch: the simulated rail has no home switch (set home_switch_at in [rig.rail.sim])");
  }
  {
    const auto [error, where] = error_with("d0_mm = 300.0", "d0_mm = 300.0\nrail_sign = -1");
    EXPECT_EQ(error, where + ": rig.geometry.d0_mm: puts the camera at d = -2200 mm from the turntable axis at rail position 2500 mm "
                    "(must be > 0 over the rail's soft limits)");
  }
}

TEST_F(RigConfigFile, BackendsNotYetBuiltInAreNamedAtTheirLine) {
  const std::string gpio_rail = "backend = \"sim\"\nunit = \"mm\"";
  std::string text = kBase;
  text.replace(text.find(gpio_rail), gpio_rail.size(), "backend = \"gpio\"\nunit = \"mm\"");
  text.replace(text.find("[rig.rail.sim]"), 14, "[rig.rail.gpio]");
  std::ofstream(path_) << text;
  try {
    load_rig_config(path_);
    FAIL() << "no error";
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), path_.string() + ":8: rig.rail.backend: the 'gpio' backend is not built into this loader yet");
  }
  {
    const auto [error, where] = error_with("backend = \"sim\"", "backend = \"steam\"");
    EXPECT_EQ(error, where + ": rig.rail.backend: unknown backend 'steam' (known: sim, gpio, modbus)");
  }
  // The table of another backend than the one chosen is a mistake too.
  {
    const auto [error, where] = error_with("[rig.rail.sim]", "[rig.rail.modbus]\nunit_id = 1\n[rig.rail.sim]");
    EXPECT_EQ(error, where + ": rig.rail.modbus: unknown key (known here: backend, unit, units_per_step, min_position, "
                    "max_position, max_velocity, acceleration, backlash, approach_direction, retry_deadband, "
                    "max_retries, settle_ms, homing, sim)");
  }
}

TEST_F(RigConfigFile, MisspelledTablesAndSyntaxErrorsAreReported) {
  EXPECT_NE(error_with("[rig.turntable]", "[rig.turntabel]").error.find("rig.turntabel: unknown key"), std::string::npos);
  const auto [syntax, where] = error_with("acceleration = 60.0", "acceleration = ");
  EXPECT_EQ(syntax.rfind(where + ":", 0), 0U) << syntax;
}
