// The GPIO stepper drive on the recording line backend: the pulse train
// (count, direction setup, width, the profile's shape), limits, e-stop,
// emergency stop, controlled stop, homing against a simulated switch, and
// missed deadlines. A small machine model, driven by the recorded outputs,
// counts the motor's real position and closes the switches at positions.
//
// Timing checks are on shapes and ratios with generous tolerances, never on
// absolute latency: the machine running them is shared and loaded.

#include <gtest/gtest.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "markerd/rig/gpio_stepper.hpp"
#include "markerd/rig/motion_profile.hpp"
#include "markerd/rig/testing/gpio_recording.hpp"

#ifndef MARKERD_SOURCE_DIR
#error "MARKERD_SOURCE_DIR must be defined"
#endif

namespace {

using namespace markerd::rig;
using namespace std::chrono_literals;
using markerd::ConfigError;
using markerd::ConfigTable;

constexpr std::int64_t kNever = std::numeric_limits<std::int64_t>::min();

template <class Predicate>
bool eventually(Predicate predicate, std::chrono::milliseconds timeout = 30s) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!predicate()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

std::vector<double> rising_times_s(const std::vector<RecordedEdge>& edges) {
  std::vector<double> times;
  for (const auto& e : edges) {
    if (e.active) times.push_back(std::chrono::duration<double>(e.time).count());
  }
  return times;
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The motor and its switches: the step pulses move it, and its position
// operates the switches. They are normally closed and wired active-low: a
// released switch reads high, an operated (open) one low. Runs on the step
// thread, through the backend's output hook.
struct Machine {
  RecordingGpioBackend* gpio = nullptr;
  std::atomic<std::int64_t> position{0};
  std::atomic<bool> positive{false};
  std::atomic<std::int64_t> lowest{0};
  // A switch is active at or beyond its position.
  std::int64_t home_at = kNever;       // active at positions <= home_at
  std::int64_t limit_min_at = kNever;  // active at positions <= limit_min_at
  std::function<void(std::int64_t)> on_step;

  void on_output(std::string_view line, bool active) {
    if (line == "DIR") positive = active;
    if (line != "STEP" || !active) return;
    const std::int64_t p = position += positive ? 1 : -1;
    if (p < lowest) lowest = p;
    gpio->set_level("HOME", !(p <= home_at));
    gpio->set_level("LIMIT_MIN", !(p <= limit_min_at));
    if (on_step) on_step(p);
  }
};

GpioStepperSettings test_settings() {
  GpioStepperSettings s;
  s.step = {"gpiosim", "STEP"};
  s.dir = {"gpiosim", "DIR"};
  s.enable = {"gpiosim", "ENABLE", true};
  s.limit_min = GpioLineSpec{"gpiosim", "LIMIT_MIN", true};
  s.limit_max = GpioLineSpec{"gpiosim", "LIMIT_MAX", true};
  s.home = GpioLineSpec{"gpiosim", "HOME", true};
  s.estop = GpioLineSpec{"gpiosim", "ESTOP", true};
  s.step_pulse = 20us;
  s.dir_setup = 200us;
  s.enable_settle = 10ms;
  s.debounce = 2ms;
  s.max_step_rate = 5000;
  s.consumer = "test-rail";
  return s;
}

class GpioStepper : public ::testing::Test {
 protected:
  GpioStepper() {
    machine.gpio = &gpio;
    gpio.set_output_hook([this](std::string_view line, bool active) { machine.on_output(line, active); });
    for (const char* input : {"LIMIT_MIN", "LIMIT_MAX", "HOME", "ESTOP"}) gpio.set_level(input, true);  // released
  }

  GpioStepperDrive& make(const GpioStepperSettings& settings = test_settings()) {
    drive = std::make_unique<GpioStepperDrive>("rail", settings, gpio);
    return *drive;
  }
  GpioStepperDrive& make_enabled() {
    make().enable(true);
    return *drive;
  }
  bool idle(std::chrono::milliseconds timeout = 30s) {
    return eventually([&] { return !drive->status().busy; }, timeout);
  }
  std::size_t pulses() const { return rising_times_s(gpio.edges("STEP")).size(); }

  RecordingGpioBackend gpio{"gpiosim", {"STEP", "DIR", "ENABLE", "LIMIT_MIN", "LIMIT_MAX", "HOME", "ESTOP"}};
  Machine machine;
  std::unique_ptr<GpioStepperDrive> drive;  // last: destroyed first
};

TEST_F(GpioStepper, StartsDisabledAndNamesItself) {
  auto& d = make();
  EXPECT_EQ(d.name(), "rail (gpio gpiosim)");
  const auto s = d.status();
  EXPECT_FALSE(s.enabled);
  EXPECT_FALSE(s.homed);
  EXPECT_FALSE(s.busy);
  EXPECT_FALSE(s.alarm);
  EXPECT_FALSE(s.inputs.limit_min || s.inputs.limit_max || s.inputs.home || s.inputs.estop);
  EXPECT_TRUE(gpio.level("ENABLE")) << "active-low enable held inactive (high)";
  EXPECT_EQ(gpio.consumer("STEP"), "test-rail");
  EXPECT_EQ(gpio.consumer("ESTOP"), "test-rail");
}

TEST_F(GpioStepper, OnePulsePerStepDirectionSetUpFirstAndFullWidth) {
  const auto settings = test_settings();
  auto& d = make_enabled();
  d.start_move(400, 2000, 20000);
  ASSERT_TRUE(idle());
  d.start_move(150, 2000, 20000);  // back: the direction changes
  ASSERT_TRUE(idle());
  EXPECT_EQ(d.status().position_steps, 150);
  EXPECT_EQ(machine.position, 150);

  const auto steps = gpio.edges("STEP");
  ASSERT_EQ(pulses(), 400U + 250U);
  for (std::size_t i = 0; i + 1 < steps.size(); i += 2) {
    ASSERT_TRUE(steps[i].active && !steps[i + 1].active) << "edge " << i;
    EXPECT_GE(steps[i + 1].time - steps[i].time, settings.step_pulse) << "pulse " << i / 2;
  }
  const auto dirs = gpio.edges("DIR");
  ASSERT_EQ(dirs.size(), 2U);
  const auto enables = gpio.edges("ENABLE");
  ASSERT_EQ(enables.size(), 1U);
  EXPECT_GE(steps.front().time - enables.front().time, settings.enable_settle);
  EXPECT_TRUE(dirs[0].active);
  EXPECT_GE(steps[0].time - dirs[0].time, settings.dir_setup);
  EXPECT_FALSE(dirs[1].active);
  const auto first_back = steps[2 * 400];
  EXPECT_GE(first_back.time - dirs[1].time, settings.dir_setup);
  EXPECT_GT(dirs[1].time, steps[2 * 400 - 1].time) << "direction changed only after the last step forward";
}

TEST_F(GpioStepper, StepTimesFollowTheTrapezoidalProfile) {
  // 600 steps, 400 steps/s, 800 steps/s^2: 100 steps of ramp up, 400 of
  // cruise, 100 of ramp down. Intervals of milliseconds, so that the shape
  // stands far above the wake-up jitter of a loaded machine.
  constexpr double v = 400, a = 800;
  auto& d = make_enabled();
  d.start_move(600, v, a);
  ASSERT_TRUE(idle());
  const auto t = rising_times_s(gpio.edges("STEP"));
  ASSERT_EQ(t.size(), 600U);
  const TrapezoidProfile plan(600, v, a);
  // t[k] is step k + 1, planned at time_at(k + 1). Each measured interval is
  // compared with its planned one; medians over windows of steps keep the
  // check on the profile's shape, not on the few steps a loaded machine
  // delays (a delayed step is a missed deadline: the profile slips, once).
  auto ratios = [&](int from, int to) {
    std::vector<double> r;
    for (int k = from; k < to; ++k) r.push_back((t[k + 1] - t[k]) / (plan.time_at(k + 2) - plan.time_at(k + 1)));
    return r;
  };
  auto share_within = [](const std::vector<double>& r, double tolerance) {
    const auto near = std::count_if(r.begin(), r.end(), [&](double x) { return std::abs(x - 1) <= tolerance; });
    return static_cast<double>(near) / static_cast<double>(r.size());
  };
  const std::vector<double> ramp_start = ratios(0, 10);  // intervals of 21 down to 7 ms
  const std::vector<double> cruise = ratios(150, 450);   // 2.5 ms
  const std::pair<const char*, std::vector<double>> windows[] = {
      {"ramp start", ramp_start}, {"ramp up", ratios(0, 99)}, {"cruise", cruise}, {"ramp down", ratios(501, 599)}};
  for (const auto& [window, r] : windows) {
    EXPECT_NEAR(median(r), 1.0, 0.15) << window;
    EXPECT_GE(share_within(r, 0.3), 0.6) << window;
  }
  // The shape: the ramp's first intervals against the cruise's, as planned
  // (the first is 8.3 cruise intervals long).
  EXPECT_NEAR(median(ramp_start) / median(cruise), 1.0, 0.25);
  EXPECT_EQ(d.status().position_steps, 600);
}

TEST_F(GpioStepper, LimitSwitchStopsAMoveTowardsItAndAllowsMovingAway) {
  auto& d = make_enabled();
  d.start_move(100000, 200, 2000);
  ASSERT_TRUE(eventually([&] { return d.status().position_steps >= 100; }));
  const auto tripped = std::chrono::steady_clock::now();
  gpio.set_level("LIMIT_MAX", false);  // the switch opens
  ASSERT_TRUE(eventually([&] { return d.status().inputs.limit_max; }));
  const std::size_t pulses_when_seen = pulses();
  ASSERT_TRUE(idle());
  EXPECT_LE(pulses() - pulses_when_seen, 1U) << "at most the step in flight after the input is seen";
  const auto tripped_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(tripped.time_since_epoch());
  std::size_t after_trip = 0;
  for (const auto& e : gpio.edges("STEP")) after_trip += e.active && e.time > tripped_ns ? 1 : 0;
  EXPECT_LE(after_trip, 20U) << "steps issued after the switch opened (200 steps/s)";

  const auto s = d.status();
  const auto stopped_at = s.position_steps;
  EXPECT_EQ(stopped_at, machine.position);
  EXPECT_TRUE(s.alarm);
  EXPECT_NE(s.alarm_cause.find("limit_max tripped at step " + std::to_string(stopped_at)), std::string::npos)
      << s.alarm_cause;
  EXPECT_FALSE(s.homed);
  EXPECT_TRUE(s.enabled) << "a limit stops the motion; the driver keeps holding";

  d.reset_alarm();
  try {
    d.start_move(stopped_at + 10, 200, 2000);
    FAIL() << "moved towards an active limit";
  } catch (const DriveError& e) {
    EXPECT_NE(std::string(e.what()).find("limit_max active: cannot move towards it"), std::string::npos) << e.what();
  }
  d.start_move(stopped_at - 50, 200, 2000);  // away from it
  ASSERT_TRUE(idle());
  EXPECT_EQ(d.status().position_steps, stopped_at - 50);
  EXPECT_FALSE(d.status().alarm);
}

TEST_F(GpioStepper, EStopInputDisablesAtOnceAndAlarms) {
  auto& d = make_enabled();
  d.start_move(100000, 1000, 5000);
  ASSERT_TRUE(eventually([&] { return d.status().position_steps >= 50; }));
  gpio.set_level("ESTOP", false);
  ASSERT_TRUE(eventually([&] { return d.status().alarm; }));
  EXPECT_TRUE(gpio.level("ENABLE")) << "enable inactive (high) by the time the alarm shows";
  ASSERT_TRUE(idle());
  const auto s = d.status();
  EXPECT_FALSE(s.enabled);
  EXPECT_FALSE(s.homed);
  EXPECT_TRUE(s.inputs.estop);
  EXPECT_NE(s.alarm_cause.find("e-stop input active"), std::string::npos) << s.alarm_cause;
  const auto stopped = pulses();
  EXPECT_THROW(d.enable(true), DriveError);
  EXPECT_THROW(d.reset_alarm(), DriveError);

  gpio.set_level("ESTOP", true);
  ASSERT_TRUE(eventually([&] { return !d.status().inputs.estop; }));
  d.reset_alarm();
  d.enable(true);
  EXPECT_FALSE(gpio.level("ENABLE"));
  EXPECT_EQ(pulses(), stopped);
}

// A log sink that reads the drive's status on the thread that logs, at the
// moment the e-stop's alarm is logged: the earliest the fault is announced.
class StatusAtAlarmLog : public spdlog::sinks::base_sink<std::mutex> {
 public:
  std::atomic<const GpioStepperDrive*> drive{nullptr};

  [[nodiscard]] std::vector<DriveStatus> seen() {
    const std::lock_guard lock(mutex_);
    return seen_;
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    const std::string_view text(msg.payload.data(), msg.payload.size());
    const GpioStepperDrive* d = drive.load();
    if (d != nullptr && msg.level == spdlog::level::err && text.find("e-stop input active at step") != text.npos) {
      seen_.push_back(d->status());
    }
  }
  void flush_() override {}

 private:
  std::vector<DriveStatus> seen_;  // under the sink's mutex_
};

// The e-stop disables the driver, then raises the alarm; status() must never
// show the step between (disabled, no alarm: a drive merely switched off).
// The alarm is logged after both are published, so a status read from the
// log line itself, on the input thread, sees what every later reader sees.
TEST_F(GpioStepper, EStopPublishesDisabledAndAlarmTogether) {
  auto sink = std::make_shared<StatusAtAlarmLog>();
  auto& d = make_enabled();
  // Attached while no other thread logs (the drive is idle), detached the same way.
  const auto logger = spdlog::default_logger();
  logger->sinks().push_back(sink);
  sink->drive = &d;
  struct Detach {
    std::unique_ptr<GpioStepperDrive>& drive;
    std::shared_ptr<spdlog::logger> logger;
    ~Detach() {
      drive.reset();  // its threads are joined: nothing logs any more
      logger->sinks().pop_back();
    }
  } detach{drive, logger};
  d.start_move(100000, 1000, 5000);
  ASSERT_TRUE(eventually([&] { return d.status().position_steps >= 20; }));
  gpio.set_level("ESTOP", false);
  ASSERT_TRUE(eventually([&] { return !sink->seen().empty(); }));
  ASSERT_TRUE(idle());
  const DriveStatus at_log = sink->seen().front();
  EXPECT_FALSE(at_log.enabled);
  EXPECT_FALSE(at_log.homed);
  EXPECT_TRUE(at_log.alarm) << "disabled by the e-stop, but its alarm not yet published";
  EXPECT_NE(at_log.alarm_cause.find("e-stop input active"), std::string::npos) << at_log.alarm_cause;
}

TEST_F(GpioStepper, EmergencyStopFromAnyThreadDisablesImmediately) {
  auto& d = make_enabled();
  d.start_move(100000, 1000, 5000);
  ASSERT_TRUE(eventually([&] { return d.status().position_steps >= 50; }));
  bool enable_inactive_on_return = false;
  std::jthread operator_thread([&] {
    d.emergency_stop();
    enable_inactive_on_return = gpio.level("ENABLE");
  });
  operator_thread.join();
  EXPECT_TRUE(enable_inactive_on_return);
  ASSERT_TRUE(idle());
  const auto stopped = pulses();
  const auto s = d.status();
  EXPECT_FALSE(s.enabled);
  EXPECT_FALSE(s.homed);
  EXPECT_FALSE(s.alarm) << "a commanded stop, not a fault";
  EXPECT_EQ(s.position_steps, machine.position);
  std::this_thread::sleep_for(20ms);
  EXPECT_EQ(pulses(), stopped);
  EXPECT_THROW(d.start_move(0, 1000, 5000), DriveError) << "not enabled";
}

TEST_F(GpioStepper, ControlledStopBrakesAtTheMoveAcceleration) {
  constexpr double v = 1000, a = 4000;  // braking distance v^2 / 2a = 125 steps
  auto& d = make_enabled();
  d.start_move(100000, v, a);
  ASSERT_TRUE(eventually([&] { return d.status().position_steps >= 400; }));  // cruising after 125
  d.stop();
  const auto at_stop = d.status().position_steps;
  ASSERT_TRUE(idle());
  const auto s = d.status();
  EXPECT_FALSE(s.alarm);
  EXPECT_TRUE(s.enabled);
  const auto braked = s.position_steps - at_stop;
  EXPECT_GE(braked, 100) << "not an abrupt halt";
  EXPECT_LE(braked, 135);
  const auto t = rising_times_s(gpio.edges("STEP"));
  ASSERT_GE(t.size(), 50U);
  const double last_interval = t[t.size() - 1] - t[t.size() - 2];
  EXPECT_GT(last_interval, 4.0 / v) << "the ramp slows down to the last step";
}

TEST_F(GpioStepper, HomingLatchesOnTheSwitch) {
  machine.home_at = -300;
  auto& d = make_enabled();
  HomingSteps homing;
  homing.direction = -1;
  homing.target = HomingSteps::Switch::home;
  homing.search_steps_per_s = 1000;
  homing.latch_steps_per_s = 40;
  homing.accel_steps_per_s2 = 5000;
  homing.backoff_steps = 40;
  homing.home_position_steps = 1000;
  homing.timeout_s = 60;
  d.start_homing(homing);
  ASSERT_TRUE(idle(90s));
  const auto s = d.status();
  ASSERT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_TRUE(s.homed);
  EXPECT_EQ(s.position_steps, 1000);
  EXPECT_LT(machine.lowest, -310) << "the search braked past the switch";
  // Latched on the switch's first step, give or take what the input thread
  // lets through at 40 steps/s.
  EXPECT_LE(machine.position, -300);
  EXPECT_GE(machine.position, -305);
  const auto dirs = gpio.edges("DIR");  // the search went down, the way DIR starts
  ASSERT_EQ(dirs.size(), 2U);
  EXPECT_TRUE(dirs[0].active) << "back off up";
  EXPECT_FALSE(dirs[1].active) << "latch down";

  // The reference holds: 1100 is 100 steps above the latch point.
  const std::int64_t latched_at = machine.position;
  d.start_move(1100, 1000, 5000);
  ASSERT_TRUE(idle());
  EXPECT_EQ(machine.position, latched_at + 100);
  EXPECT_TRUE(d.status().homed);
}

TEST_F(GpioStepper, HomingOnALimitSwitchStopsAtOnce) {
  machine.limit_min_at = -200;
  auto& d = make_enabled();
  HomingSteps homing;
  homing.direction = -1;
  homing.target = HomingSteps::Switch::limit_min;
  homing.search_steps_per_s = 200;
  homing.latch_steps_per_s = 40;
  homing.accel_steps_per_s2 = 4000;
  homing.backoff_steps = 20;
  homing.home_position_steps = 0;
  d.start_homing(homing);
  ASSERT_TRUE(idle(90s));
  const auto s = d.status();
  ASSERT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_TRUE(s.homed);
  EXPECT_EQ(s.position_steps, 0);
  EXPECT_GE(machine.lowest, -210) << "no braking ramp into the end of travel";
  EXPECT_LE(machine.position, -200);
  EXPECT_GE(machine.position, -205);
}

TEST_F(GpioStepper, HomingWithoutASwitchTimesOutWithItsCause) {
  auto& d = make_enabled();
  HomingSteps homing;
  homing.search_steps_per_s = 500;
  homing.latch_steps_per_s = 50;
  homing.accel_steps_per_s2 = 5000;
  homing.timeout_s = 0.3;
  d.start_homing(homing);
  ASSERT_TRUE(idle());
  const auto s = d.status();
  EXPECT_TRUE(s.alarm);
  EXPECT_FALSE(s.homed);
  EXPECT_NE(s.alarm_cause.find("homing (search): home did not activate within the timeout of 0.3 s"), std::string::npos)
      << s.alarm_cause;
}

TEST_F(GpioStepper, HomingIntoTheWrongLimitAlarms) {
  machine.limit_min_at = -100;  // the home switch never closes: the search reaches the end of travel
  auto& d = make_enabled();
  HomingSteps homing;
  homing.search_steps_per_s = 400;
  homing.latch_steps_per_s = 40;
  homing.accel_steps_per_s2 = 4000;
  d.start_homing(homing);
  ASSERT_TRUE(idle());
  const auto s = d.status();
  EXPECT_TRUE(s.alarm);
  EXPECT_NE(s.alarm_cause.find("a limit switch tripped"), std::string::npos) << s.alarm_cause;
  EXPECT_NE(s.alarm_cause.find("check the home switch"), std::string::npos) << s.alarm_cause;
}

TEST_F(GpioStepper, AMissedDeadlineSlipsTheProfileInsteadOfBursting) {
  // The machine stalls the step thread for 30 ms at step 100 of a 1000
  // steps/s cruise: the steps after it keep their interval.
  machine.on_step = [](std::int64_t p) {
    if (p == 100) std::this_thread::sleep_for(30ms);
  };
  auto& d = make_enabled();
  d.start_move(200, 1000, 20000);
  ASSERT_TRUE(idle());
  EXPECT_GE(d.stats().missed_deadlines, 1U);
  EXPECT_GE(d.stats().max_lateness, 25ms);
  const auto t = rising_times_s(gpio.edges("STEP"));
  ASSERT_EQ(t.size(), 200U);
  EXPECT_GE(t[100] - t[99], 0.025) << "the stall itself";
  for (int k = 100; k < 103; ++k) EXPECT_GE(t[k + 1] - t[k], 0.5e-3) << "interval after step " << k + 1;
}

TEST_F(GpioStepper, RefusesWhatItCannotDoSafely) {
  auto& d = make();
  auto error_of = [](const auto& action) {
    try {
      action();
    } catch (const DriveError& e) {
      return std::string(e.what());
    }
    return std::string("(no DriveError)");
  };
  EXPECT_NE(error_of([&] { d.start_move(10, 100, 1000); }).find("rail (gpio gpiosim): not enabled"), std::string::npos);
  d.enable(true);
  EXPECT_NE(error_of([&] { d.start_move(10, 6000, 1000); }).find("at most max_step_rate = 5000"), std::string::npos);
  EXPECT_NE(error_of([&] { d.start_move(10, 100, 0); }).find("acceleration"), std::string::npos);
  d.start_move(100000, 500, 5000);
  EXPECT_NE(error_of([&] { d.start_move(0, 500, 5000); }).find("busy"), std::string::npos);
  d.stop();
  ASSERT_TRUE(idle());

  auto no_home = test_settings();
  no_home.home.reset();
  drive.reset();
  auto& d2 = make(no_home);
  d2.enable(true);
  HomingSteps homing;
  homing.search_steps_per_s = 100;
  homing.latch_steps_per_s = 10;
  homing.accel_steps_per_s2 = 1000;
  EXPECT_NE(error_of([&] { d2.start_homing(homing); }).find("homing needs the home input"), std::string::npos);
}

TEST_F(GpioStepper, LineErrorsNameTheAxisAndTheLine) {
  auto settings = test_settings();
  settings.home = GpioLineSpec{"gpiosim", "HOEM", true};
  try {
    make(settings);
    FAIL();
  } catch (const DriveError& e) {
    EXPECT_NE(std::string(e.what()).find("rail (gpio gpiosim): GPIO gpiosim [recording]: no line named 'HOEM'"),
              std::string::npos)
        << e.what();
  }
  settings = test_settings();
  settings.dir = {"gpiosim", "0"};  // offset 0 is STEP: busy, held by ourselves
  try {
    make(settings);
    FAIL();
  } catch (const DriveError& e) {
    EXPECT_NE(std::string(e.what()).find("busy, held by consumer 'test-rail'"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(gpio.consumer("STEP")) << "lines of a failed construction are released";
}

TEST(GpioStepperOnGpiod1, AMissingChipNamesTheAxisAndTheChip) {
  auto settings = test_settings();
  for (auto* spec : {&settings.step, &settings.dir, &settings.enable}) spec->chip = "gpiochip977";
  settings.limit_min.reset();
  settings.limit_max.reset();
  settings.home.reset();
  settings.estop.reset();
  try {
    (void)make_gpio_stepper_drive("turntable", settings);
    FAIL();
  } catch (const DriveError& e) {
    EXPECT_NE(std::string(e.what()).find("turntable (gpio gpiochip977): GPIO chip 'gpiochip977' (/dev/gpiochip977)"),
              std::string::npos)
        << e.what();
  }
}

// ---------------------------------------------------------------- config

ConfigTable gpio_table(const std::string& body) {
  return ConfigTable::parse("[rig.rail.gpio]\n" + body, "rig.toml").table("rig").table("rail").table("gpio");
}

const std::string kMinimal = R"(chip = "gpiochip0"
step = { line = 17 }
dir = { line = "GPIO27" }
enable = { line = "GPIO22", active_low = true }
)";

std::string config_error(const std::string& body) {
  try {
    (void)parse_gpio_stepper(gpio_table(body));
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no ConfigError)";
}

TEST(GpioStepperConfig, MinimalTableTakesTheDefaults) {
  const auto s = parse_gpio_stepper(gpio_table(kMinimal));
  EXPECT_EQ(s.step.chip, "gpiochip0");
  EXPECT_EQ(s.step.line, "17");
  EXPECT_FALSE(s.step.active_low);
  EXPECT_EQ(s.dir.line, "GPIO27");
  EXPECT_TRUE(s.enable.active_low);
  EXPECT_EQ(s.enable.chip, "gpiochip0");
  EXPECT_FALSE(s.limit_min || s.limit_max || s.home || s.estop);
  EXPECT_EQ(s.step_pulse, GpioStepperSettings{}.step_pulse);
  EXPECT_EQ(s.rt_priority, 0);
}

TEST(GpioStepperConfig, EveryKey) {
  const auto s = parse_gpio_stepper(gpio_table(kMinimal + R"(limit_min = { line = "GPIO5", active_low = true }
limit_max = { line = 6 }
home = { line = "GPIO13" }
estop = { line = "GPIO26", active_low = true }
step_pulse_us = 2.5
dir_setup_us = 10
enable_settle_ms = 100
debounce_ms = 3
max_step_rate = 2400
rt_priority = 60
consumer = "markerd-rail"
)"));
  ASSERT_TRUE(s.limit_min && s.limit_max && s.home && s.estop);
  EXPECT_EQ(s.limit_max->line, "6");
  EXPECT_TRUE(s.estop->active_low);
  EXPECT_EQ(s.step_pulse, 2500ns);
  EXPECT_EQ(s.dir_setup, 10us);
  EXPECT_EQ(s.enable_settle, 100ms);
  EXPECT_EQ(s.debounce, 3ms);
  EXPECT_EQ(s.max_step_rate, 2400);
  EXPECT_EQ(s.rt_priority, 60);
  EXPECT_EQ(s.consumer, "markerd-rail");
}

TEST(GpioStepperConfig, ErrorsNameTheLineAndKey) {
  EXPECT_NE(config_error(kMinimal + "step_pulse = 5\n").find("rig.toml:6: rig.rail.gpio.step_pulse: unknown key"),
            std::string::npos);
  EXPECT_NE(config_error(kMinimal + "max_step_rate = 20000\n")
                .find("rig.toml:6: rig.rail.gpio.max_step_rate: 20000 steps/s is above what this backend supports "
                      "(2500 steps/s"),
            std::string::npos)
      << config_error(kMinimal + "max_step_rate = 20000\n");
  EXPECT_NE(config_error(R"(chip = "gpiochip0"
step = { line = 17 }
enable = { line = 22 }
)")
                .find("missing table 'dir'"),
            std::string::npos);
  EXPECT_NE(
      config_error(kMinimal + "home = { line = 17 }\n").find("rig.rail.gpio.home: line '17' is already used by step"),
      std::string::npos)
      << config_error(kMinimal + "home = { line = 17 }\n");
  EXPECT_NE(
      config_error(kMinimal + "home = { line = 12, pull = \"up\" }\n").find("rig.rail.gpio.home.pull: unknown key"),
      std::string::npos);
  EXPECT_NE(config_error(kMinimal + "step_pulse_us = 300\nmax_step_rate = 2000\n").find("does not fit a step period"),
            std::string::npos);
  EXPECT_NE(config_error(kMinimal + "rt_priority = 120\n").find("rig.rail.gpio.rt_priority: must be 0"),
            std::string::npos);
  EXPECT_NE(config_error(kMinimal + "debounce_ms = -1\n")
                .find("rig.rail.gpio.debounce_ms: must be from 0 to 1000 ms, got -1"),
            std::string::npos);
  // Durations are checked before they are converted: no overflow into a short one.
  EXPECT_NE(config_error(kMinimal + "enable_settle_ms = 1e300\n")
                .find("rig.rail.gpio.enable_settle_ms: must be from 0 to 10000 ms, got 1e+300"),
            std::string::npos)
      << config_error(kMinimal + "enable_settle_ms = 1e300\n");
  EXPECT_NE(config_error("chip = \"gpiochip0\"\nstep = { line = 9223372036854775807 }\ndir = { line = 27 }\n"
                         "enable = { line = 22 }\n")
                .find("rig.rail.gpio.step.line: must be from 0 to 65535, got 9223372036854775807"),
            std::string::npos);
}

TEST(GpioStepperConfig, TheShippedGpioRigParses) {
  const auto root = ConfigTable::load_file(std::string(MARKERD_SOURCE_DIR) + "/config/rig-gpio.toml");
  for (const char* axis : {"rail", "turntable"}) {
    SCOPED_TRACE(axis);
    const auto s = parse_gpio_stepper(root.table("rig").table(axis).table("gpio"));
    EXPECT_TRUE(s.limit_min || s.limit_max || s.home);
    EXPECT_TRUE(s.estop);
    EXPECT_LE(s.max_step_rate, kGpioStepperMaxStepRate);
    EXPECT_GT(s.rt_priority, 0);
  }
  // The rail: 0.025 mm per step (400 steps per cm) at up to 50 mm/s is 2000 steps/s.
  const auto rail = root.table("rig").table("rail");
  EXPECT_DOUBLE_EQ(rail.required<double>("units_per_step"), 0.025);
  EXPECT_LE(rail.required<double>("max_velocity") / rail.required<double>("units_per_step"),
            parse_gpio_stepper(rail.table("gpio")).max_step_rate);
}

}  // namespace
