// Camera controls at run time: the checks of a value against a control's
// description (pure functions), setting several all or none on a scripted
// source (refusals, the device's own, controls an automatic mode holds), the
// simulated camera's controls in its frames, and camera.get / camera.set
// through a running markerd on the simulated rig, also through markerctl.
// The V4L2 controls on a real driver: tests/hil/test_v4l2_hil.cpp.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "markerd/daemon/capture/camera_controls.hpp"
#include "markerd/daemon/capture/sim_camera.hpp"
#include "markerd/daemon/control/control_client.hpp"
#include "markerd/daemon/daemon.hpp"
#include "markerd/daemon/daemon_config.hpp"
#include "markerd/daemon/frame_pool.hpp"
#include "markerd/sweep/plan.hpp"
#include "markerd/sweep/records.hpp"
#include "support/files.hpp"
#include "support/markerd_dir.hpp"
#include "support/process.hpp"
#include "support/temp_dir.hpp"
#include "support/toml_config.hpp"

namespace markerd::daemon {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;
using nlohmann::json;

// ---------------------------------------------------------------- the checks

CameraControlInfo integer_control() {
  CameraControlInfo c;
  c.name = "gain";
  c.type = "int";
  c.kind = ControlKind::integer;
  c.minimum = std::int64_t{25};
  c.maximum = std::int64_t{400};
  c.step = 25;
  c.default_value = std::int64_t{100};
  c.value = std::int64_t{100};
  return c;
}

CameraControlInfo menu_control() {
  CameraControlInfo c;
  c.name = "power_line_frequency";
  c.type = "menu";
  c.kind = ControlKind::menu;
  c.minimum = std::int64_t{0};
  c.maximum = std::int64_t{2};
  c.menu = {{0, "Disabled"}, {1, "50 Hz"}, {2, "60 Hz"}};
  return c;
}

CameraControlInfo real_control() {
  CameraControlInfo c;
  c.name = "exposure";
  c.type = "float";
  c.kind = ControlKind::real;
  c.minimum = 0.01;
  c.maximum = 4.0;
  return c;
}

std::string refusal(const CameraControlInfo& c, const ControlInput& input) {
  try {
    const ControlValue v = check_control_value(c, input);
    return "(taken: " + to_text(v) + ")";
  } catch (const ControlValueError& e) {
    return e.what();
  }
}

TEST(CameraControlCheck, AnIntegerControlTakesWholeNumbersInItsRangeOnItsSteps) {
  const CameraControlInfo c = integer_control();
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::int64_t{200})), 200);
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, 25.0)), 25) << "2.0 is a whole number";
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::int64_t{400})), 400);
  EXPECT_EQ(refusal(c, std::int64_t{500}), "500 is out of its range 25 to 400 in steps of 25");
  EXPECT_EQ(refusal(c, std::int64_t{0}), "0 is out of its range 25 to 400 in steps of 25");
  EXPECT_EQ(refusal(c, std::int64_t{110}), "110 is not on its steps: 25 + a multiple of 25 (100 or 125 are)");
  EXPECT_EQ(refusal(c, 100.5), "100.5 is not a whole number: an integer control, 25 to 400 in steps of 25");
  EXPECT_EQ(refusal(c, std::string("high")), "'high' is not a number: an integer control, 25 to 400 in steps of 25");
  EXPECT_EQ(refusal(c, true), "true is not a number: an integer control, 25 to 400 in steps of 25");
  EXPECT_EQ(describe_range(c), "25 to 400 in steps of 25");

  CameraControlInfo any_step = integer_control();
  any_step.step = 1;
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(any_step, std::int64_t{111})), 111);
  EXPECT_EQ(describe_range(any_step), "25 to 400");
}

TEST(CameraControlCheck, ABooleanTakesTrueFalseOneOrZero) {
  CameraControlInfo c;
  c.name = "auto_gain";
  c.type = "bool";
  c.kind = ControlKind::boolean;
  EXPECT_EQ(std::get<bool>(check_control_value(c, true)), true);
  EXPECT_EQ(std::get<bool>(check_control_value(c, std::int64_t{0})), false);
  EXPECT_EQ(std::get<bool>(check_control_value(c, std::int64_t{1})), true);
  EXPECT_EQ(refusal(c, std::int64_t{2}), "2 is not a boolean: give true or false");
  EXPECT_EQ(refusal(c, std::string("yes")), "'yes' is not a boolean: give true or false");
  EXPECT_EQ(describe_range(c), "true or false");
}

TEST(CameraControlCheck, AMenuTakesAnItemByIndexOrByNameAndListsThemOtherwise) {
  const CameraControlInfo c = menu_control();
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::int64_t{2})), 2);
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::string("50 Hz"))), 1);
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::string("50_hz"))), 1) << "as v4l2-ctl writes it";
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(c, std::string("DISABLED"))), 0);
  EXPECT_EQ(refusal(c, std::int64_t{3}), "3 is not one of its items (0: Disabled, 1: 50 Hz, 2: 60 Hz)");
  EXPECT_EQ(refusal(c, std::string("70 Hz")), "'70 Hz' is not one of its items (0: Disabled, 1: 50 Hz, 2: 60 Hz)");
  EXPECT_EQ(refusal(c, true), "a menu: give an item's number or name (0: Disabled, 1: 50 Hz, 2: 60 Hz)");
  EXPECT_EQ(value_text(c, std::int64_t{1}), "1 (50 Hz)");
}

TEST(CameraControlCheck, ARealControlTakesAnyNumberInItsRangeAndAnEnumeratedOneOnlyItsValues) {
  CameraControlInfo c = real_control();
  EXPECT_DOUBLE_EQ(std::get<double>(check_control_value(c, 0.5)), 0.5);
  EXPECT_DOUBLE_EQ(std::get<double>(check_control_value(c, std::int64_t{2})), 2.0);
  EXPECT_EQ(refusal(c, 5.0), "5 is out of its range 0.01 to 4");
  EXPECT_EQ(refusal(c, 0.0), "0 is out of its range 0.01 to 4");
  EXPECT_EQ(refusal(c, std::string("bright")), "'bright' is not a number: a real control, 0.01 to 4");
  c.maximum.reset();
  EXPECT_EQ(describe_range(c), "at least 0.01");

  // libcamera's enumerated controls (AeMeteringMode, ...) list their values.
  CameraControlInfo modes;
  modes.name = "AeMeteringMode";
  modes.type = "int32";
  modes.kind = ControlKind::integer;
  modes.minimum = std::int64_t{0};
  modes.maximum = std::int64_t{3};
  modes.allowed = {std::int64_t{0}, std::int64_t{1}, std::int64_t{3}};
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(modes, std::int64_t{3})), 3);
  EXPECT_EQ(refusal(modes, std::int64_t{2}), "2 is not one of its values: one of 0, 1, 3");
}

TEST(CameraControlCheck, ReadOnlyButtonsAndBitsOutsideAMaskAreRefusedSayingWhy) {
  CameraControlInfo c = integer_control();
  c.flags = {"read-only"};
  EXPECT_EQ(refusal(c, std::int64_t{100}), "read-only: it can be read, not set");

  CameraControlInfo button;
  button.name = "pan_reset";
  button.type = "button";
  button.why_not_settable = "a button (an action, not a setting)";
  EXPECT_EQ(refusal(button, std::int64_t{1}), "a button (an action, not a setting)");

  CameraControlInfo mask;
  mask.name = "bits";
  mask.type = "bitmask";
  mask.kind = ControlKind::bitmask;
  mask.maximum = std::int64_t{0x0f};
  EXPECT_EQ(std::get<std::int64_t>(check_control_value(mask, std::int64_t{0x05})), 5);
  EXPECT_EQ(refusal(mask, std::int64_t{0x15}), "0x15 has bits outside the mask 0xf");
}

TEST(CameraControlCheck, JsonValuesBecomeInputsAndAnythingElseIsNamed) {
  EXPECT_EQ(std::get<std::int64_t>(control_input_from_json(json(200))), 200);
  EXPECT_DOUBLE_EQ(std::get<double>(control_input_from_json(json(0.5))), 0.5);
  EXPECT_EQ(std::get<bool>(control_input_from_json(json(true))), true);
  EXPECT_EQ(std::get<std::string>(control_input_from_json(json("50 Hz"))), "50 Hz");
  try {
    (void)control_input_from_json(json::array({1, 2}));
    ADD_FAILURE() << "an array was taken";
  } catch (const ControlValueError& e) {
    EXPECT_STREQ(e.what(), "give a number, true or false, or a menu item's name; got [1,2]");
  }
}

TEST(CameraControlCheck, AutomaticModesAreKnownByTheirNames) {
  for (const char* name : {"auto_exposure", "white_balance_automatic", "autogain", "auto_gain", "AeEnable", "AwbEnable",
                           "focus_automatic_continuous"}) {
    EXPECT_TRUE(is_automatic_mode(name)) << name;
  }
  for (const char* name : {"exposure_time_absolute", "gain", "brightness", "ExposureTime", "AnalogueGain"}) {
    EXPECT_FALSE(is_automatic_mode(name)) << name;
  }
}

// ---------------------------------------------------------------- all or none

// A source with two controls: `auto`, an automatic mode, and `level`, which
// it holds (inactive) while on; and `other`. It writes what it is told,
// unless told to refuse a control.
class ScriptedSource final : public CaptureSource {
 public:
  ScriptedSource() { values_ = {{"auto", 0}, {"level", 10}, {"other", 1}}; }

  [[nodiscard]] const std::string& name() const override { return name_; }
  [[nodiscard]] CaptureGeometry geometry() const override { return {}; }
  void open() override {}
  void close() noexcept override {}
  [[nodiscard]] bool is_open() const noexcept override { return true; }
  [[nodiscard]] bool wait_frame(std::chrono::milliseconds /*timeout*/) override { return false; }
  void fill(Frame& /*frame*/) override {}
  void skip() noexcept override {}

  [[nodiscard]] std::vector<CameraControlInfo> read_controls() override {
    std::vector<CameraControlInfo> controls;
    CameraControlInfo automatic;
    automatic.name = "auto";
    automatic.type = "bool";
    automatic.kind = ControlKind::boolean;
    automatic.value = values_["auto"] != 0;
    controls.push_back(automatic);
    CameraControlInfo level;
    level.name = "level";
    level.type = "int";
    level.kind = ControlKind::integer;
    level.minimum = std::int64_t{0};
    level.maximum = std::int64_t{20};
    level.value = values_["level"];
    if (values_["auto"] != 0) level.flags.emplace_back("inactive");
    controls.push_back(level);
    CameraControlInfo other = level;
    other.name = "other";
    other.flags.clear();
    other.value = values_["other"];
    controls.push_back(other);
    return controls;
  }

  void write_control(const CameraControlInfo& control, const ControlValue& value) override {
    if (refuse_.count(control.name) != 0) throw CaptureError(CaptureError::Kind::config, "EINVAL (scripted)");
    const std::int64_t number =
        std::holds_alternative<bool>(value) ? (std::get<bool>(value) ? 1 : 0) : std::get<std::int64_t>(value);
    writes.push_back(fmt::format("{}={}", control.name, number));
    values_[control.name] = number;
  }

  void refuse(const std::string& control) { refuse_.insert(control); }
  std::int64_t value(const std::string& control) { return values_[control]; }

  std::vector<std::string> writes;

 private:
  std::string name_ = "scripted";
  std::map<std::string, std::int64_t> values_;
  std::set<std::string> refuse_;
};

std::vector<ControlChange> set(CaptureSource& source, const std::vector<ControlAssignment>& assignments) {
  return set_camera_controls(source, assignments);
}

std::string set_refusal(CaptureSource& source, const std::vector<ControlAssignment>& assignments) {
  try {
    (void)set_camera_controls(source, assignments);
    return "(set)";
  } catch (const ControlValueError& e) {
    return e.what();
  }
}

TEST(SetCameraControls, EveryValueIsCheckedBeforeAnyIsWritten) {
  ScriptedSource source;
  EXPECT_EQ(set_refusal(source, {{"other", std::int64_t{5}}, {"level", std::int64_t{99}}}),
            "level: 99 is out of its range 0 to 20; nothing was changed");
  EXPECT_TRUE(source.writes.empty());
  EXPECT_EQ(set_refusal(source, {{"other", std::int64_t{5}}, {"levle", std::int64_t{3}}}),
            "scripted has no control 'levle' (its controls: auto, level, other); nothing was changed");
  EXPECT_EQ(set_refusal(source, {{"Level", std::int64_t{3}}}),
            "scripted has no control 'Level': did you mean 'level'? Nothing was changed");
  EXPECT_EQ(set_refusal(source, {{"level", std::int64_t{3}}, {"level", std::int64_t{4}}}),
            "level is given twice; nothing was changed");
  EXPECT_EQ(set_refusal(source, {}), "no controls given");
  EXPECT_TRUE(source.writes.empty());

  const auto changes = set(source, {{"other", std::int64_t{5}}, {"level", std::int64_t{7}}});
  ASSERT_EQ(changes.size(), 2U);
  EXPECT_EQ(changes[0].control.name, "other");
  EXPECT_EQ(std::get<std::int64_t>(*changes[0].old_value), 1);
  EXPECT_EQ(std::get<std::int64_t>(changes[0].new_value), 5);
  EXPECT_EQ(source.writes, (std::vector<std::string>{"other=5", "level=7"}));
}

TEST(SetCameraControls, TheDeviceRefusingOnePutsBackThoseWrittenBefore) {
  ScriptedSource source;
  source.refuse("level");
  const std::string error = set_refusal(source, {{"other", std::int64_t{5}}, {"level", std::int64_t{7}}});
  EXPECT_EQ(error, "level: 7 refused: EINVAL (scripted); nothing was changed");
  EXPECT_EQ(source.writes, (std::vector<std::string>{"other=5", "other=1"}));
  EXPECT_EQ(source.value("other"), 1);
}

TEST(SetCameraControls, AutomaticModesGoFirstAndWhatTheyHoldIsRefusedWithThem) {
  ScriptedSource source;
  // Given after the control it holds, the automatic mode is written first
  // (on: `level` would be refused) ...
  EXPECT_EQ(set_refusal(source, {{"level", std::int64_t{3}}, {"auto", true}}),
            "level: inactive now (an automatic mode holds it: auto = true; set that first, in the same command or "
            "before); nothing was changed");
  EXPECT_EQ(source.writes, (std::vector<std::string>{"auto=1", "auto=0"})) << "auto put back";
  EXPECT_EQ(source.value("auto"), 0);
  EXPECT_EQ(source.value("level"), 10);

  // ... and turned off in the same command, it lets the control through.
  source.writes.clear();
  (void)set(source, {{"auto", true}});
  EXPECT_EQ(set_refusal(source, {{"level", std::int64_t{3}}}).rfind("level: inactive now", 0), 0U);
  (void)set(source, {{"level", std::int64_t{3}}, {"auto", false}});
  EXPECT_EQ(source.writes, (std::vector<std::string>{"auto=1", "auto=0", "level=3"}));
}

// ---------------------------------------------------------------- the simulated camera

SimCameraSettings quiet_settings() {
  SimCameraSettings s;
  s.fps = 1000;
  s.noise_sigma = 0;
  s.supersample = 1;
  s.clutter = false;
  return s;
}

// Frames of the simulated camera at its fixed positions; the last frame's mean grey level.
double next_frames_mean(SimCamera& sim, FramePool& pool, int frames = 2) {
  for (int i = 0; i < frames; ++i) {
    EXPECT_TRUE(sim.wait_frame(5s));
    Frame* frame = pool.try_acquire();
    EXPECT_NE(frame, nullptr);
    if (frame == nullptr) return 0;
    sim.fill(*frame);
    pool.release(*frame);
  }
  return sim.mean_grey();
}

TEST(SimCameraControls, GainAndExposureScaleTheFramesAndAutoGainBringsThemToMidGrey) {
  SimCamera sim(quiet_settings(), detector::CameraModel::thesis_640x480(), {});
  FramePool pool({1, 640 * 480, 4});
  sim.open();

  const auto controls = sim.read_controls();
  ASSERT_EQ(controls.size(), 4U);
  EXPECT_EQ(controls[0].name, "auto_gain");
  EXPECT_EQ(controls[1].name, "exposure");
  EXPECT_EQ(controls[2].name, "gain");
  EXPECT_EQ(describe_range(controls[2]), "25 to 400 in steps of 25");
  EXPECT_EQ(controls[3].name, "noise_sigma");
  EXPECT_TRUE(has_flag(controls[3], "read-only"));

  const double plain = next_frames_mean(sim, pool);
  ASSERT_GT(plain, 60) << "a grey background and a white paper";
  (void)set(sim, {{"gain", std::int64_t{50}}});
  const double halved = next_frames_mean(sim, pool);
  EXPECT_NEAR(halved, plain / 2, 1.0);

  const std::uint64_t renders = sim.renders();
  (void)set(sim, {{"gain", std::int64_t{100}}, {"exposure", 0.5}});
  const double darker = next_frames_mean(sim, pool);
  EXPECT_EQ(sim.renders(), renders + 1) << "a new exposure renders the scene again, once";
  EXPECT_LT(darker, plain * 0.75);

  (void)set(sim, {{"auto_gain", true}});
  EXPECT_NEAR(next_frames_mean(sim, pool), 128, 3) << "the gain that brings the image to mid-grey";
  EXPECT_TRUE(has_flag(sim.read_controls()[2], "inactive"));

  // Refused: nothing changes, in the controls or the frames.
  const double before = next_frames_mean(sim, pool);
  EXPECT_THROW((void)set(sim, {{"noise_sigma", 3.0}}), ControlValueError);
  EXPECT_THROW((void)set(sim, {{"gain", std::int64_t{200}}}), ControlValueError);
  EXPECT_EQ(next_frames_mean(sim, pool), before);
  EXPECT_EQ(std::get<std::int64_t>(*sim.read_controls()[2].value), 100);
}

// ---------------------------------------------------------------- through markerd

class CameraCommandsTest : public testing::Test {
 protected:
  void SetUp() override {
    test_support::prepare_markerd_dir(dir_);
    test_support::write_sim_rig_config(dir_ / "rig.toml", 100.0);
    test_support::TomlConfig::load(test_support::kSourceTree / "tests/data/markerd-sweep.toml")
        .set("camera.model", (test_support::kSourceTree / "config/cameras/thesis-640x480.yaml").string())
        .write(dir_ / "markerd.toml");
    daemon_ = std::make_unique<Daemon>(load_daemon_config(dir_ / "markerd.toml"));
    daemon_->start();
  }

  SimCamera& sim() { return dynamic_cast<SimCamera&>(daemon_->source()); }

  json call(const json& request) {
    ControlClient client(dir_ / "control.sock");
    return client.call(request, 20s);
  }

  // The mean grey level of a frame captured after now.
  double fresh_mean() {
    const std::uint64_t after = daemon_->capture().status().frames + 2;
    const auto deadline = std::chrono::steady_clock::now() + 30s;
    while (daemon_->capture().status().frames < after && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(10ms);
    }
    EXPECT_GE(daemon_->capture().status().frames, after) << "no frames";
    return sim().mean_grey();
  }

  json control(const std::string& name) {
    const json reply = call({{"cmd", "camera.get"}, {"names", {name}}});
    EXPECT_EQ(reply["ok"], true) << reply.dump();
    return reply["controls"][0];
  }

  test_support::Outcome markerctl(std::vector<std::string> args) {
    args.insert(args.begin(), {MARKERCTL_PATH, "camera"});
    args.insert(args.end(), {"--socket", (dir_ / "control.sock").string()});
    return test_support::run_program(args, {}, 60s);
  }

  const test_support::TempDir temp_{"markerd-camera"};
  const fs::path dir_ = temp_.path();
  std::unique_ptr<Daemon> daemon_;
};

TEST_F(CameraCommandsTest, GetListsTheRangesAndSetChangesTheValueAndTheFrames) {
  json reply = call({{"cmd", "camera.get"}});
  ASSERT_EQ(reply["ok"], true) << reply.dump();
  EXPECT_EQ(reply["source"], "sim 640x480@30");
  ASSERT_EQ(reply["controls"].size(), 4U) << reply.dump();
  const json& gain = reply["controls"][2];
  EXPECT_EQ(gain["name"], "gain");
  EXPECT_EQ(gain["type"], "int");
  EXPECT_EQ(gain["value"], 100);
  EXPECT_EQ(gain["min"], 25);
  EXPECT_EQ(gain["max"], 400);
  EXPECT_EQ(gain["step"], 25);
  EXPECT_EQ(gain["default"], 100);
  EXPECT_EQ(gain["range"], "25 to 400 in steps of 25");
  EXPECT_EQ(gain["settable"], true);
  EXPECT_EQ(reply["controls"][3]["name"], "noise_sigma");
  EXPECT_EQ(reply["controls"][3]["flags"], json::array({"read-only"}));
  EXPECT_EQ(reply["controls"][3]["settable"], false);

  reply = call({{"cmd", "camera.get"}, {"names", {"exposure"}}});
  ASSERT_EQ(reply["controls"].size(), 1U);
  EXPECT_EQ(reply["controls"][0]["name"], "exposure");
  EXPECT_EQ(reply["controls"][0]["min"], 0.01);
  reply = call({{"cmd", "camera.get"}, {"names", {"exposre"}}});
  EXPECT_EQ(reply["ok"], false);
  EXPECT_EQ(reply["error"],
            "sim 640x480@30 has no control 'exposre' (its controls: auto_gain, exposure, gain, noise_sigma)");
  reply = call({{"cmd", "camera.get"}, {"names", "gain"}});
  EXPECT_EQ(reply["error"], "argument 'names' must be a list of control names, got a string (\"gain\")");

  const double plain = fresh_mean();
  reply = call({{"cmd", "camera.set"}, {"controls", {{"gain", 50}}}});
  ASSERT_EQ(reply["ok"], true) << reply.dump();
  EXPECT_EQ(reply["changed"], json::parse(R"([{"name":"gain","old":100,"new":50}])"));
  EXPECT_EQ(reply["controls"][0]["value"], 50);
  const double halved = fresh_mean();
  EXPECT_NEAR(halved, plain / 2, 3) << "the frames show the gain";

  // Refused, each naming the control and what it takes, and nothing changes.
  const std::map<std::string, json> refused{
      {"gain: 500 is out of its range 25 to 400 in steps of 25; nothing was changed", {{"gain", 500}}},
      {"gain: 110 is not on its steps: 25 + a multiple of 25 (100 or 125 are); nothing was changed", {{"gain", 110}}},
      {"exposure: 9 is out of its range 0.01 to 4; nothing was changed", {{"gain", 75}, {"exposure", 9}}},
      {"sim 640x480@30 has no control 'gian' (its controls: auto_gain, exposure, gain, noise_sigma); nothing was "
       "changed",
       {{"gian", 75}}},
      {"gain: give a number, true or false, or a menu item's name; got [75]; nothing was changed",
       {{"gain", json::array({75})}}},
      {"noise_sigma: read-only: it can be read, not set; nothing was changed", {{"noise_sigma", 3}}},
      {"gain: inactive now (an automatic mode holds it: auto_gain = true; set that first, in the same command or "
       "before); nothing was changed",
       {{"auto_gain", true}, {"gain", 75}}},
  };
  for (const auto& [error, controls] : refused) {
    reply = call({{"cmd", "camera.set"}, {"controls", controls}});
    EXPECT_EQ(reply["ok"], false) << reply.dump();
    EXPECT_EQ(reply.value("error", ""), error) << controls.dump();
  }
  reply = call({{"cmd", "camera.set"}, {"controls", json::object()}});
  EXPECT_EQ(reply["error"], R"(argument 'controls' must be an object of control names and values, e.g. {"gain": 200}, )"
                            R"(got an object ({}))");
  reply = call({{"cmd", "camera.set"}});
  EXPECT_EQ(reply["error"], R"(argument 'controls' is missing: the controls to set, e.g. {"gain": 200})");
  EXPECT_EQ(control("gain")["value"], 50);
  EXPECT_EQ(control("auto_gain")["value"], false);
  EXPECT_EQ(control("exposure")["value"], 1.0);
  EXPECT_NEAR(fresh_mean(), halved, 3) << "the frames as they were";
}

TEST_F(CameraCommandsTest, EverySetIsLoggedAndRecordedInTheEventsOfTheRunGoingOn) {
  std::ostringstream log;
  const auto sink = std::make_shared<spdlog::sinks::ostream_sink_mt>(log);
  spdlog::default_logger()->sinks().push_back(sink);
  const fs::path run = daemon_->sweep()->start(sweep::parse_plan(
      test_support::read_file(test_support::kSourceTree / "tests/data/plans/small.toml"), "small.toml"));
  json reply = call({{"cmd", "camera.set"}, {"controls", {{"gain", 75}, {"exposure", 0.5}}}});
  ASSERT_EQ(reply["ok"], true) << reply.dump();
  daemon_->sweep()->abort("the test is done");
  EXPECT_EQ(daemon_->sweep()->wait_finished(60s), sweep::RunState::aborted);
  spdlog::default_logger()->sinks().pop_back();

  const std::string text = log.str();
  EXPECT_NE(text.find("camera sim 640x480@30: control gain 100 -> 75 (camera.set)"), std::string::npos) << text;
  EXPECT_NE(text.find("camera sim 640x480@30: control exposure 1 -> 0.5 (camera.set)"), std::string::npos) << text;
  std::vector<std::string> changes;
  for (const auto& e : sweep::read_run(run).events) {
    if (e.kind == "camera_control") changes.push_back(e.reason);
  }
  EXPECT_EQ(changes, (std::vector<std::string>{"exposure 1 -> 0.5", "gain 100 -> 75"}));

  // With no run going, a set is logged only.
  const std::size_t events = sweep::read_run(run).events.size();
  reply = call({{"cmd", "camera.set"}, {"controls", {{"gain", 100}}}});
  ASSERT_EQ(reply["ok"], true) << reply.dump();
  EXPECT_EQ(sweep::read_run(run).events.size(), events) << "an ended run's records stay as they ended";
}

TEST_F(CameraCommandsTest, MarkerctlCameraGetAndSet) {
  test_support::Outcome r = markerctl({"get"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out.rfind("sim 640x480@30\n", 0), 0U) << r.out;
  EXPECT_NE(r.out.find("  gain                           int     100                25 to 400 in steps of 25; "
                       "default 100\n"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("[read-only]"), std::string::npos) << r.out;

  r = markerctl({"set", "gain=150", "auto_gain=false"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(r.out, "auto_gain: false -> false\ngain: 100 -> 150\n");
  EXPECT_EQ(control("gain")["value"], 150);

  r = markerctl({"set", "gain=1000"});
  EXPECT_EQ(r.code, 1) << r.describe();
  EXPECT_EQ(r.err,
            "markerctl: camera set: gain: 1000 is out of its range 25 to 400 in steps of 25; nothing was "
            "changed\n");
  r = markerctl({"set", "gain"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: camera set: 'gain' is not NAME=VALUE (e.g. gain=200)\n");
  r = markerctl({"set", "gain=100", "gain=125"});
  EXPECT_EQ(r.code, 2) << r.describe();
  EXPECT_EQ(r.err, "markerctl: camera set: gain is given twice\n");
  EXPECT_EQ(control("gain")["value"], 150);

  r = markerctl({"get", "gain", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  const json got = json::parse(r.out);
  EXPECT_EQ(got["controls"][0]["value"], 150);
  r = markerctl({"set", "exposure=0.75", "--json"});
  ASSERT_EQ(r.code, 0) << r.describe();
  EXPECT_EQ(json::parse(r.out)["changed"], json::parse(R"([{"name":"exposure","old":1.0,"new":0.75}])"));
}

}  // namespace
}  // namespace markerd::daemon
