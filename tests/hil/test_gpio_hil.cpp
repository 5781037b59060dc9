// The GPIO line backend and the GPIO stepper against the kernel's GPIO
// character device, with gpio-sim standing in for the wiring. Runs inside
// Debian's kernel under qemu (ctest's hil_gpio, tools/hil/hil-run), as root,
// after the harness made one simulated chip labelled "rig":
//   HIL_GPIO_SIM_RIG_CHIP   its character device
//   HIL_GPIO_SIM_RIG_SYSFS  gpio-sim's directory: sim_gpio<K>/value is the
//                           level line K drives, sim_gpio<K>/pull the level
//                           the outside world puts on an input
// Outside such a guest every test skips.
//
// The tests find lines by name (tests/hil/CMakeLists.txt names them) and use
// libgpiod directly only to learn a name's offset, so the simulator side is
// observed independently of the backend under test.

#include <gpiod.h>
#include <poll.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "markerd/rig/drive.hpp"
#include "markerd/rig/gpio_lines.hpp"
#include "markerd/rig/gpio_stepper.hpp"

namespace {

using markerd::rig::DriveError;
using markerd::rig::DriveStatus;
using markerd::rig::GpioBackend;
using markerd::rig::GpioEdgeEvent;
using markerd::rig::GpioInput;
using markerd::rig::GpioLineSpec;
using markerd::rig::GpioStepperDrive;
using markerd::rig::GpioStepperSettings;
using markerd::rig::HomingSteps;
using markerd::rig::make_gpiod1_backend;
using namespace std::chrono_literals;

// Generous: the guest is emulated (TCG) on a loaded 2-core host.
constexpr auto kTimeout = 20s;

const char* env(const char* name) {
  const char* value = std::getenv(name);
  return value != nullptr && *value != '\0' ? value : nullptr;
}

// The far side of the simulated chip's lines, through gpio-sim's sysfs.
class SimulatedChip {
 public:
  SimulatedChip(std::string chip, std::string sysfs) : chip_(std::move(chip)), sysfs_(std::move(sysfs)) {}

  [[nodiscard]] const std::string& chip() const { return chip_; }

  [[nodiscard]] unsigned offset(const std::string& line_name) const {
    gpiod_chip* chip = gpiod_chip_open(chip_.c_str());
    if (chip == nullptr) throw std::runtime_error(chip_ + ": " + std::strerror(errno));
    gpiod_line* line = gpiod_chip_find_line(chip, line_name.c_str());
    const unsigned result = line != nullptr ? gpiod_line_offset(line) : ~0U;
    gpiod_chip_close(chip);
    if (result == ~0U) throw std::runtime_error(chip_ + " has no line named " + line_name);
    return result;
  }

  // The electrical level on the line as the simulator sees it.
  [[nodiscard]] bool high(const std::string& line_name) const {
    const std::string path = line_dir(line_name) + "/value";
    std::ifstream file(path);
    char level = '?';
    file >> level;
    if (!file || (level != '0' && level != '1')) throw std::runtime_error("cannot read " + path);
    return level == '1';
  }

  // Drives an input line from outside, as a switch and its resistor would.
  void pull(const std::string& line_name, bool up) const {
    const std::string path = line_dir(line_name) + "/pull";
    std::ofstream file(path);
    file << (up ? "pull-up" : "pull-down") << std::flush;
    if (!file) throw std::runtime_error("cannot write " + path);
  }

 private:
  [[nodiscard]] std::string line_dir(const std::string& line_name) const {
    return sysfs_ + "/sim_gpio" + std::to_string(offset(line_name));
  }

  std::string chip_;
  std::string sysfs_;
};

bool wait_until(const std::function<bool()>& condition, std::chrono::milliseconds timeout = kTimeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

// The next edge event, waiting for it on the input's file descriptor.
std::optional<GpioEdgeEvent> next_event(GpioInput& input, std::chrono::milliseconds timeout = kTimeout) {
  if (auto event = input.read_event()) return event;
  pollfd fd{input.event_fd(), POLLIN, 0};
  if (poll(&fd, 1, static_cast<int>(timeout.count())) != 1) return std::nullopt;
  return input.read_event();
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const DriveError& e) {
    return e.what();
  }
  return "(no error)";
}

// The input lines of the chip, all returned to released (pull-down) after
// every test so that each test starts from the same wiring.
const char* const kInputLines[] = {"IN", "LIMIT_MIN", "LIMIT_MAX", "HOME", "ESTOP"};

class GpioHil : public ::testing::Test {
 protected:
  void SetUp() override {
    const char* chip = env("HIL_GPIO_SIM_RIG_CHIP");
    const char* sysfs = env("HIL_GPIO_SIM_RIG_SYSFS");
    if (chip == nullptr || sysfs == nullptr) {
      GTEST_SKIP() << "no simulated GPIO chip: run through ctest -R hil_gpio (tools/hil/hil-run)";
    }
    sim_.emplace(chip, sysfs);
    for (const char* line : kInputLines) sim_->pull(line, false);
  }

  void TearDown() override {
    if (!sim_) return;
    for (const char* line : kInputLines) sim_->pull(line, false);
  }

  [[nodiscard]] GpioLineSpec line(const std::string& name, bool active_low = false) const {
    return GpioLineSpec{sim_->chip(), name, active_low};
  }

  std::optional<SimulatedChip> sim_;
  std::unique_ptr<GpioBackend> backend_ = make_gpiod1_backend();
};

TEST_F(GpioHil, OutputSetThroughTheBackendIsSeenBySimulator) {
  auto out = backend_->request_output(line("OUT"), false, "hil-test");
  EXPECT_FALSE(sim_->high("OUT"));
  out->set(true);
  EXPECT_TRUE(sim_->high("OUT"));
  out->set(false);
  EXPECT_FALSE(sim_->high("OUT"));
  // The initial level is applied by the request itself.
  out.reset();
  auto initially_active = backend_->request_output(line("OUT"), true, "hil-test");
  EXPECT_TRUE(sim_->high("OUT"));
}

TEST_F(GpioHil, LinesAreFoundByChipLabelAndByOffset) {
  const std::string offset = std::to_string(sim_->offset("OUT"));
  auto out = backend_->request_output(GpioLineSpec{"rig", offset, false}, true, "hil-test");
  EXPECT_TRUE(sim_->high("OUT"));
}

TEST_F(GpioHil, ActiveLowOutputInverts) {
  auto out = backend_->request_output(line("OUT", true), false, "hil-test");
  EXPECT_TRUE(sim_->high("OUT"));
  out->set(true);
  EXPECT_FALSE(sim_->high("OUT"));
  out->set(false);
  EXPECT_TRUE(sim_->high("OUT"));
}

TEST_F(GpioHil, PullOnAnInputGivesEdgeEvents) {
  auto in = backend_->request_input(line("IN"), true, "hil-test");
  ASSERT_GE(in->event_fd(), 0);
  EXPECT_FALSE(in->get());
  EXPECT_FALSE(in->read_event().has_value()) << "an event before any edge";

  sim_->pull("IN", true);
  const auto rising = next_event(*in);
  ASSERT_TRUE(rising.has_value()) << "no edge event within the timeout after pull-up";
  EXPECT_TRUE(rising->active);
  EXPECT_TRUE(in->get());

  sim_->pull("IN", false);
  const auto falling = next_event(*in);
  ASSERT_TRUE(falling.has_value()) << "no edge event within the timeout after pull-down";
  EXPECT_FALSE(falling->active);
  EXPECT_GT(falling->timestamp, rising->timestamp);
  EXPECT_FALSE(in->get());
  EXPECT_FALSE(in->read_event().has_value()) << "more events than edges";
}

TEST_F(GpioHil, ActiveLowInputInverts) {
  sim_->pull("IN", true);
  auto in = backend_->request_input(line("IN", true), true, "hil-test");
  EXPECT_FALSE(in->get()) << "pulled up means released on an active-low input";

  sim_->pull("IN", false);
  const auto event = next_event(*in);
  ASSERT_TRUE(event.has_value()) << "no edge event within the timeout after pull-down";
  EXPECT_TRUE(event->active);
  EXPECT_TRUE(in->get());
}

TEST_F(GpioHil, InputWithoutEventsReadsLevels) {
  auto in = backend_->request_input(line("IN"), false, "hil-test");
  EXPECT_LT(in->event_fd(), 0);
  EXPECT_FALSE(in->read_event().has_value());
  sim_->pull("IN", true);
  EXPECT_TRUE(wait_until([&] { return in->get(); }));
}

TEST_F(GpioHil, BusyLineNamesItsHolder) {
  auto held = backend_->request_output(line("OUT"), false, "hil-holder");
  const std::string error = error_of([&] { (void)backend_->request_output(line("OUT"), false, "hil-test"); });
  EXPECT_NE(error.find("busy"), std::string::npos) << error;
  EXPECT_NE(error.find("hil-holder"), std::string::npos) << error;
  EXPECT_NE(error.find("OUT"), std::string::npos) << error;
  EXPECT_NE(error_of([&] { (void)backend_->request_input(line("OUT"), true, "hil-test"); }).find("busy"),
            std::string::npos);
  // Released, the line can be requested again.
  held.reset();
  EXPECT_NO_THROW((void)backend_->request_input(line("OUT"), true, "hil-test"));
}

TEST_F(GpioHil, MissingLinesAndChipsAreNamed) {
  const std::string no_line = error_of([&] { (void)backend_->request_output(line("NO_SUCH_LINE"), false, "hil"); });
  EXPECT_NE(no_line.find("NO_SUCH_LINE"), std::string::npos) << no_line;
  EXPECT_NE(no_line.find("rig"), std::string::npos) << no_line;
  const std::string no_chip = error_of([&] {
    (void)backend_->request_output(GpioLineSpec{"no-such-chip", "0", false}, false, "hil");
  });
  EXPECT_NE(no_chip.find("no-such-chip"), std::string::npos) << no_chip;
  EXPECT_NE(no_chip.find("[rig]"), std::string::npos) << "the error should list the chips there are: " << no_chip;
}

// ---------------------------------------------------------------- the stepper

// The wiring of the stepper tests: the enable input of the motor driver and
// the e-stop are active-low, as on common drivers and normally-closed e-stop
// loops; the rest active-high.
class GpioStepperHil : public GpioHil {
 protected:
  void SetUp() override {
    GpioHil::SetUp();
    if (IsSkipped()) return;
    sim_->pull("ESTOP", true);  // released
    // The board's pull-up: a line nobody drives leaves the driver disabled.
    sim_->pull("ENABLE", true);
  }

  void TearDown() override {
    if (sim_) sim_->pull("ENABLE", false);
    GpioHil::TearDown();
  }

  [[nodiscard]] GpioStepperSettings settings() const {
    GpioStepperSettings s;
    s.step = line("STEP");
    s.dir = line("DIR");
    s.enable = line("ENABLE", true);
    s.limit_min = line("LIMIT_MIN");
    s.limit_max = line("LIMIT_MAX");
    s.home = line("HOME");
    s.estop = line("ESTOP", true);
    s.enable_settle = 10ms;
    s.max_step_rate = 2000;
    s.consumer = "hil-stepper";
    return s;
  }

  std::unique_ptr<GpioStepperDrive> make_drive() {
    return std::make_unique<GpioStepperDrive>("rail", settings(), *backend_);
  }

  // The driver's enable input as the simulator sees it (active-low).
  [[nodiscard]] bool driver_enabled() const { return !sim_->high("ENABLE"); }

  static bool wait_idle(const GpioStepperDrive& drive) {
    return wait_until([&] { return !drive.status().busy; });
  }
};

TEST_F(GpioStepperHil, DirectionAndEnableLinesReachTheDriver) {
  auto drive = make_drive();
  EXPECT_FALSE(driver_enabled()) << "the drive must start disabled";
  EXPECT_FALSE(sim_->high("STEP"));

  drive->enable(true);
  EXPECT_TRUE(driver_enabled());
  EXPECT_TRUE(drive->status().enabled);

  drive->start_move(60, 1000, 10000);
  ASSERT_TRUE(wait_idle(*drive));
  EXPECT_TRUE(sim_->high("DIR")) << "positive moves drive DIR active";
  EXPECT_FALSE(sim_->high("STEP")) << "STEP rests inactive between pulses";
  EXPECT_EQ(drive->status().position_steps, 60);

  drive->start_move(-40, 1000, 10000);
  ASSERT_TRUE(wait_idle(*drive));
  EXPECT_FALSE(sim_->high("DIR"));
  EXPECT_EQ(drive->status().position_steps, -40);
  EXPECT_FALSE(drive->status().alarm) << drive->status().alarm_cause;

  drive->enable(false);
  EXPECT_FALSE(driver_enabled());
}

TEST_F(GpioStepperHil, LimitSwitchStopsTheMoveAndRaisesTheAlarm) {
  auto drive = make_drive();
  drive->enable(true);
  constexpr std::int64_t far = 1'000'000;
  drive->start_move(far, 1000, 10000);
  ASSERT_TRUE(wait_until([&] { return drive->status().position_steps >= 100; }));

  sim_->pull("LIMIT_MAX", true);
  ASSERT_TRUE(wait_idle(*drive)) << "the limit switch did not stop the move";
  const DriveStatus tripped = drive->status();
  EXPECT_TRUE(tripped.alarm);
  EXPECT_NE(tripped.alarm_cause.find("limit_max"), std::string::npos) << tripped.alarm_cause;
  EXPECT_TRUE(tripped.inputs.limit_max);
  EXPECT_FALSE(tripped.homed);
  EXPECT_LT(tripped.position_steps, far);
  EXPECT_EQ(driver_enabled(), tripped.enabled) << "the enable line and the reported state disagree";
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(drive->status().position_steps, tripped.position_steps) << "steps after the stop";

  // Latched: no move until reset, and never further into the limit.
  EXPECT_NE(error_of([&] { drive->start_move(tripped.position_steps - 10, 1000, 10000); }).find("alarm"),
            std::string::npos);
  drive->reset_alarm();
  if (!drive->status().enabled) drive->enable(true);
  EXPECT_NE(error_of([&] { drive->start_move(far, 1000, 10000); }).find("limit_max"), std::string::npos);

  // Moving away from the tripped switch is allowed.
  drive->start_move(tripped.position_steps - 50, 1000, 10000);
  ASSERT_TRUE(wait_idle(*drive));
  EXPECT_EQ(drive->status().position_steps, tripped.position_steps - 50);
  EXPECT_FALSE(drive->status().alarm) << drive->status().alarm_cause;

  sim_->pull("LIMIT_MAX", false);
  EXPECT_TRUE(wait_until([&] { return !drive->status().inputs.limit_max; })) << "release not seen";
}

// The mechanics of the rail: a home switch that is closed while the carriage
// is at or below `switch_at`, in the drive's step count before homing. Homing
// moves the count to `home_position`, far from the travel of this test, which
// tells the two frames apart.
class HomeSwitch {
 public:
  HomeSwitch(const GpioStepperDrive& drive, const SimulatedChip& sim, std::int64_t switch_at,
             std::int64_t home_position)
      : thread_([&drive, &sim, switch_at, home_position, this](const std::stop_token& stop) {
          bool closed = false;
          while (!stop.stop_requested()) {
            std::int64_t carriage = drive.status().position_steps;
            if (carriage > home_position / 2)
              carriage += switch_at - home_position;
            else
              last_count_before_homing_.store(carriage);
            if ((carriage <= switch_at) != closed) {
              closed = !closed;
              sim.pull("HOME", closed);
              if (closed) closures_.fetch_add(1);
            }
            std::this_thread::sleep_for(200us);
          }
        }) {}

  [[nodiscard]] int closures() const { return closures_.load(); }
  [[nodiscard]] std::int64_t last_count_before_homing() const { return last_count_before_homing_.load(); }

 private:
  std::atomic<int> closures_{0};
  std::atomic<std::int64_t> last_count_before_homing_{0};
  std::jthread thread_;  // last: stopped before the counters go
};

TEST_F(GpioStepperHil, HomingLatchesOnTheHomeSwitch) {
  auto drive = make_drive();
  constexpr std::int64_t switch_at = -300;
  constexpr std::int64_t home_position = 1'000'000;
  HomeSwitch home_switch(*drive, *sim_, switch_at, home_position);

  HomingSteps homing;
  homing.direction = -1;
  homing.target = HomingSteps::Switch::home;
  homing.search_steps_per_s = 1500;
  homing.latch_steps_per_s = 100;
  homing.accel_steps_per_s2 = 10000;
  homing.backoff_steps = 40;
  homing.home_position_steps = home_position;
  homing.timeout_s = 60;
  drive->enable(true);
  drive->start_homing(homing);
  ASSERT_TRUE(wait_until([&] { return !drive->status().busy; }, 90s));

  const DriveStatus homed = drive->status();
  EXPECT_FALSE(homed.alarm) << homed.alarm_cause;
  EXPECT_TRUE(homed.homed);
  EXPECT_EQ(homed.position_steps, home_position) << "the latch step is the reference";
  EXPECT_TRUE(homed.inputs.home);
  EXPECT_GE(home_switch.closures(), 2) << "expected the search to close the switch, the back-off to open it and the "
                                          "latch to close it again";
  // The latch stopped where the switch closed, give or take the reaction of
  // this test's switch model and the input thread on an emulated machine.
  EXPECT_NEAR(static_cast<double>(home_switch.last_count_before_homing()), static_cast<double>(switch_at), 20.0);
}

TEST_F(GpioStepperHil, HomingTimesOutWhenTheSwitchNeverCloses) {
  auto drive = make_drive();
  HomingSteps homing;
  homing.direction = -1;
  homing.target = HomingSteps::Switch::home;
  homing.search_steps_per_s = 1000;
  homing.latch_steps_per_s = 100;
  homing.accel_steps_per_s2 = 10000;
  homing.timeout_s = 0.5;
  drive->enable(true);
  drive->start_homing(homing);
  ASSERT_TRUE(wait_idle(*drive));
  const DriveStatus status = drive->status();
  EXPECT_TRUE(status.alarm);
  EXPECT_NE(status.alarm_cause.find("timeout"), std::string::npos) << status.alarm_cause;
  EXPECT_FALSE(status.homed);
}

TEST_F(GpioStepperHil, EStopInputDisablesTheDriver) {
  auto drive = make_drive();
  drive->enable(true);
  drive->start_move(1'000'000, 1000, 10000);
  ASSERT_TRUE(wait_until([&] { return drive->status().position_steps >= 50; }));

  sim_->pull("ESTOP", false);  // the normally-closed loop opens
  ASSERT_TRUE(wait_until([&] { return !driver_enabled(); })) << "the e-stop did not disable the driver";
  // The alarm is published with the disable: a status read once the driver
  // saw its enable drop already shows it (the step thread ends within its
  // sleep slice, so busy may still be set).
  const DriveStatus at_disable = drive->status();
  EXPECT_TRUE(at_disable.alarm) << "disabled by the e-stop without its alarm";
  EXPECT_FALSE(at_disable.enabled);
  ASSERT_TRUE(wait_idle(*drive));
  const DriveStatus stopped = drive->status();
  EXPECT_FALSE(stopped.enabled);
  EXPECT_TRUE(stopped.alarm);
  EXPECT_NE(stopped.alarm_cause.find("e-stop"), std::string::npos) << stopped.alarm_cause;
  EXPECT_TRUE(stopped.inputs.estop);
  EXPECT_FALSE(stopped.homed);

  // While the e-stop is held nothing re-enables the driver.
  EXPECT_NE(error_of([&] { drive->enable(true); }).find("e-stop"), std::string::npos);
  EXPECT_NE(error_of([&] { drive->reset_alarm(); }).find("e-stop"), std::string::npos);
  EXPECT_FALSE(driver_enabled());

  sim_->pull("ESTOP", true);
  ASSERT_TRUE(wait_until([&] { return !drive->status().inputs.estop; })) << "release not seen";
  drive->reset_alarm();
  drive->enable(true);
  EXPECT_TRUE(driver_enabled());
}

TEST_F(GpioStepperHil, EStopActiveAtStartKeepsTheDriverDisabled) {
  sim_->pull("ESTOP", false);
  auto drive = make_drive();
  EXPECT_TRUE(drive->status().alarm);
  EXPECT_NE(error_of([&] { drive->enable(true); }).find("e-stop"), std::string::npos);
  EXPECT_FALSE(driver_enabled());
}

TEST_F(GpioStepperHil, EmergencyStopDisablesAtOnce) {
  auto drive = make_drive();
  drive->enable(true);
  drive->start_move(1'000'000, 1000, 10000);
  ASSERT_TRUE(wait_until([&] { return drive->status().position_steps >= 50; }));
  drive->emergency_stop();
  EXPECT_FALSE(driver_enabled()) << "emergency_stop() returned with the driver still enabled";
  ASSERT_TRUE(wait_idle(*drive));
  const std::int64_t position = drive->status().position_steps;
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(drive->status().position_steps, position) << "steps after the emergency stop";
  EXPECT_FALSE(drive->status().enabled);
  EXPECT_FALSE(drive->status().homed);
}

TEST_F(GpioStepperHil, DriveRefusesLinesHeldByAnotherConsumer) {
  auto held = backend_->request_output(line("ENABLE"), false, "other-consumer");
  const std::string error = error_of([&] { (void)make_drive(); });
  EXPECT_NE(error.find("rail"), std::string::npos) << error;
  EXPECT_NE(error.find("busy"), std::string::npos) << error;
  EXPECT_NE(error.find("other-consumer"), std::string::npos) << error;
}

}  // namespace
