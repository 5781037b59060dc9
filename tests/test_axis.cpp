// The Axis over a simulated drive in scaled real time: refusals, settling,
// backlash, retries, timeouts and the fail-safe reactions. The drive is
// wrapped to record the targets it was sent.

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <future>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "markerd/rig/axis.hpp"
#include "markerd/rig/sim_drive.hpp"

using namespace markerd::rig;
using namespace std::chrono_literals;

namespace {

// What the recording wrapper saw, shared with the test.
struct DriveLog {
  std::mutex mutex;
  std::vector<std::int64_t> targets;
  std::atomic<bool> hold_busy{false};     // report busy forever: a drive that never arrives
  std::atomic<bool> refuse_moves{false};  // start_move fails as on a dead bus
  // status() blocks while set: a drive whose update is stuck (a simulation
  // that spins, a read that hangs) with the axis's supervisor inside it.
  std::atomic<bool> block_status{false};
  std::atomic<int> blocked_in_status{0};
  std::atomic<int> emergency_stops{0};

  std::size_t size() {
    const std::lock_guard<std::mutex> lock(mutex);
    return targets.size();
  }
  std::vector<std::int64_t> take() {
    const std::lock_guard<std::mutex> lock(mutex);
    return std::exchange(targets, {});
  }
};

class RecordingDrive final : public Drive {
 public:
  RecordingDrive(std::unique_ptr<SimDrive> sim, std::shared_ptr<DriveLog> log)
      : sim_(std::move(sim)), log_(std::move(log)) {}
  std::string_view name() const override { return sim_->name(); }
  void enable(bool on) override { sim_->enable(on); }
  void start_move(std::int64_t target, double v, double a) override {
    if (log_->refuse_moves) throw DriveError("rail (sim): no reply");
    {
      const std::lock_guard<std::mutex> lock(log_->mutex);
      log_->targets.push_back(target);
    }
    sim_->start_move(target, v, a);
  }
  void start_homing(const HomingSteps& h) override { sim_->start_homing(h); }
  void stop() override { sim_->stop(); }
  void reset_alarm() override { sim_->reset_alarm(); }
  void emergency_stop() noexcept override {
    ++log_->emergency_stops;
    sim_->emergency_stop();
  }
  DriveStatus status() const override {
    if (log_->block_status) {
      ++log_->blocked_in_status;
      while (log_->block_status) std::this_thread::sleep_for(1ms);
      --log_->blocked_in_status;
    }
    DriveStatus s = sim_->status();
    if (log_->hold_busy) s.busy = true;
    return s;
  }

 private:
  std::unique_ptr<SimDrive> sim_;
  std::shared_ptr<DriveLog> log_;
};

// A rail of 0..100 mm at 400 steps per cm, homed on limit_min (2 mm below 0).
AxisSettings rail_settings() {
  AxisSettings s;
  s.name = "rail";
  s.unit = "mm";
  s.units_per_step = 0.025;
  s.min_position = 0;
  s.max_position = 100;
  s.max_velocity = 50;
  s.acceleration = 200;
  s.settle_time = 100ms;
  s.homing.direction = -1;
  s.homing.target = HomingSteps::Switch::limit_min;
  s.homing.search_velocity = 20;
  s.homing.latch_velocity = 2;
  s.homing.backoff = 1;
  s.homing.home_offset = -2;
  s.homing.timeout = 30s;
  return s;
}

SimDriveSettings rail_sim(bool encoder = false) {
  SimDriveSettings s;
  s.name = "rail (sim)";
  s.limit_min_steps = -80;        // -2 mm
  s.limit_max_steps = 4080;       // 102 mm
  s.start_position_steps = 1600;  // 40 mm
  s.encoder = encoder;
  return s;
}

struct TestAxis {
  std::shared_ptr<SimClock> clock;
  std::shared_ptr<DriveLog> log = std::make_shared<DriveLog>();
  SimDrive* sim = nullptr;
  std::unique_ptr<Axis> axis;

  explicit TestAxis(AxisSettings settings = rail_settings(), SimDriveSettings sim_settings = rail_sim(),
                    double time_scale = 20)
      : clock(std::make_shared<SimClock>(time_scale)) {
    auto drive = std::make_unique<SimDrive>(std::move(sim_settings), clock);
    sim = drive.get();
    axis = std::make_unique<Axis>(std::move(settings), std::make_unique<RecordingDrive>(std::move(drive), log));
  }

  void home() {
    axis->enable();
    axis->home();
    ASSERT_TRUE(axis->wait_settled(30s)) << axis->status().fault;
    ASSERT_TRUE(axis->status().homed);
    log->take();
  }
};

std::string axis_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const AxisError& e) {
    return e.what();
  }
  return "(no error)";
}

// Polls until pred holds or the timeout passes.
bool eventually(const std::function<bool()>& pred, std::chrono::milliseconds timeout = 20s) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(1ms);
  }
  return pred();
}

}  // namespace

TEST(Axis, ConstructorRejectsBadSettingsNamingTheAxisAndTheSetting) {
  auto make = [](AxisSettings s) {
    return axis_error(
        [&] { Axis axis(std::move(s), std::make_unique<SimDrive>(rail_sim(), std::make_shared<SimClock>())); });
  };
  AxisSettings s = rail_settings();
  s.units_per_step = 0;
  EXPECT_EQ(make(s), "rail: invalid setting units_per_step: must be > 0, got 0");
  s = rail_settings();
  s.max_position = -5;
  EXPECT_EQ(make(s), "rail: invalid setting max_position: must be above min_position (0 mm), got -5");
  s = rail_settings();
  s.approach_direction = 0;
  EXPECT_EQ(make(s), "rail: invalid setting approach_direction: must be 1 or -1, got 0");
  s = rail_settings();
  s.settle_time = -1ms;
  EXPECT_EQ(make(s), "rail: invalid setting settle_ms: must be from 0 to 60000 ms, got -1");
  // Longer would overflow steady_clock's nanoseconds into a settle time in the past.
  s.settle_time = std::chrono::milliseconds(std::numeric_limits<std::int64_t>::max());
  EXPECT_EQ(make(s), "rail: invalid setting settle_ms: must be from 0 to 60000 ms, got 9223372036854775807");
  s = rail_settings();
  s.homing.timeout = std::chrono::hours(1000);
  EXPECT_EQ(make(s), "rail: invalid setting homing.timeout_s: must be > 0 and at most 3600 s, got 3600000 s");
  s = rail_settings();
  s.homing.search_velocity = 80;
  EXPECT_EQ(make(s),
            "rail: invalid setting homing.search_velocity: must be between 0 (default) and max_velocity (50), got 80");
}

TEST(Axis, RefusesMovesWhileDisabledBeforeHomingAndOutsideTheLimits) {
  TestAxis t;
  EXPECT_EQ(t.axis->status().state, AxisState::disabled);
  EXPECT_EQ(axis_error([&] { t.axis->move_to(50); }),
            "rail: move to 50 mm refused: the axis is disabled; enable() first");
  t.axis->enable();
  EXPECT_EQ(axis_error([&] { t.axis->move_to(50); }),
            "rail: move to 50 mm refused: the axis is not homed; home() first");
  t.home();
  EXPECT_EQ(axis_error([&] { t.axis->move_to(150); }),
            "rail: move to 150 mm refused: outside the soft limits [0, 100] mm");
  EXPECT_EQ(axis_error([&] { t.axis->move_to(-0.5); }),
            "rail: move to -0.5 mm refused: outside the soft limits [0, 100] mm");
  EXPECT_EQ(axis_error([&] { t.axis->move_to(std::nan("")); }),
            "rail: move to nan mm refused: the target is not a finite number");
  EXPECT_TRUE(t.log->take().empty());  // nothing reached the drive
  t.axis->move_to(80);
  EXPECT_EQ(axis_error([&] { t.axis->move_to(10); }),
            "rail: move to 10 mm refused: the axis is busy (moving); wait or stop() first");
}

TEST(Axis, HomesMovesAndSettlesOnlyAfterTheSettleTime) {
  AxisSettings settings = rail_settings();
  settings.settle_time = 300ms;
  TestAxis t(settings);
  t.home();
  // Homing latched the switch edge (-2 mm) and braked 0.4 steps past it.
  EXPECT_DOUBLE_EQ(t.axis->status().position, -2.0);

  std::mutex mutex;
  std::vector<AxisStatus> seen;
  t.axis->set_status_listener([&](const AxisStatus& s) {
    const std::lock_guard<std::mutex> lock(mutex);
    seen.push_back(s);
  });
  t.axis->move_to(62.5);
  EXPECT_FALSE(t.axis->status().settled);
  ASSERT_TRUE(t.axis->wait_settled(30s)) << t.axis->status().fault;
  t.axis->set_status_listener({});
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::idle);
  EXPECT_DOUBLE_EQ(s.position, 62.5);
  EXPECT_DOUBLE_EQ(s.target, 62.5);
  EXPECT_EQ(t.log->take(), std::vector<std::int64_t>{2500});

  const std::lock_guard<std::mutex> lock(mutex);
  std::size_t arrived = 0;
  while (arrived < seen.size() && seen[arrived].state != AxisState::idle) ++arrived;
  ASSERT_LT(arrived, seen.size());
  std::size_t settled = arrived;
  while (settled < seen.size() && !seen[settled].settled) ++settled;
  ASSERT_LT(settled, seen.size());
  for (std::size_t i = 0; i < settled; ++i) EXPECT_FALSE(seen[i].settled) << i;
  EXPECT_GT(settled, arrived);  // idle and in position first, settled later
  EXPECT_GE(seen[settled].updated - seen[arrived].updated, 300ms);
}

TEST(Axis, BacklashMakesTheFinalApproachFromTheConfiguredSide) {
  for (int approach : {+1, -1}) {
    SCOPED_TRACE(approach);
    AxisSettings settings = rail_settings();
    settings.backlash = 2;
    settings.approach_direction = approach;
    TestAxis t(settings);
    t.home();
    auto go = [&](double mm) {
      t.axis->move_to(mm);
      ASSERT_TRUE(t.axis->wait_settled(30s)) << t.axis->status().fault;
      EXPECT_DOUBLE_EQ(t.axis->status().position, mm);
    };
    go(50);
    go(20);
    go(30);
    go(25);
    const std::vector<std::int64_t> targets = t.log->take();
    if (approach > 0) {
      // Up: straight there. Down: 2 mm below first, then up onto the target.
      EXPECT_EQ(targets, (std::vector<std::int64_t>{2000, 720, 800, 1200, 920, 1000}));
    } else {
      // Every move here from below ends travelling up: overshoot 2 mm above, come down.
      EXPECT_EQ(targets, (std::vector<std::int64_t>{2080, 2000, 800, 1280, 1200, 1000}));
    }
  }
}

TEST(Axis, RetriesWithinTheDeadbandOnAStalledClosedLoopDriveThenFaults) {
  AxisSettings settings = rail_settings();
  settings.retry_deadband = 0.05;
  settings.max_retries = 2;
  TestAxis t(settings, rail_sim(/*encoder=*/true));
  t.home();
  t.sim->inject_stall_at(1200);  // 30 mm
  t.axis->move_to(50);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_EQ(s.fault, "did not reach 50 mm after 2 retries: at 30 mm (retry deadband 0.05 mm)");
  EXPECT_EQ(t.log->take(), (std::vector<std::int64_t>{2000, 2000, 2000}));  // the move and two retries
  EXPECT_EQ(axis_error([&] { t.axis->move_to(10); }),
            "rail: move to 10 mm refused: the axis is in fault (did not reach 50 mm after 2 retries: at 30 mm "
            "(retry deadband 0.05 mm)); clear_fault() first");

  // The jam cleared, the same axis gets there (a closed loop keeps its reference).
  t.sim->clear_stall();
  t.axis->clear_fault();
  EXPECT_EQ(t.axis->status().state, AxisState::idle);
  t.axis->move_to(50);
  EXPECT_TRUE(t.axis->wait_settled(30s)) << t.axis->status().fault;
  EXPECT_DOUBLE_EQ(t.axis->status().position, 50);
}

TEST(Axis, ARetryThatArrivesSettles) {
  AxisSettings settings = rail_settings();
  settings.retry_deadband = 0.05;
  settings.max_retries = 3;
  TestAxis t(settings, rail_sim(/*encoder=*/true));
  t.home();
  t.sim->inject_stall_at(1200);
  t.axis->move_to(50);
  ASSERT_TRUE(eventually([&] { return t.log->size() >= 2 || t.axis->status().state == AxisState::fault; }));
  t.sim->clear_stall();  // the jam frees itself during the retries
  EXPECT_TRUE(t.axis->wait_settled(30s)) << t.axis->status().fault;
  // Within the deadband is in position: the motor freed mid-move carries its
  // lost steps into the retry that was running.
  EXPECT_NEAR(t.axis->status().position, 50, settings.retry_deadband);
  EXPECT_EQ(t.axis->status().state, AxisState::idle);
}

TEST(Axis, TheEstopInputFaultsTheAxisAndMovesAreRefusedUntilClearFault) {
  TestAxis t;
  t.home();
  t.axis->move_to(95);
  t.sim->set_estop_input(true);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_EQ(s.fault, "e-stop input active");
  EXPECT_TRUE(s.inputs.estop);
  EXPECT_FALSE(t.axis->drive().status().enabled);
  EXPECT_EQ(axis_error([&] { t.axis->move_to(10); }),
            "rail: move to 10 mm refused: the axis is in fault (e-stop input active); clear_fault() first");
  EXPECT_EQ(axis_error([&] { t.axis->clear_fault(); }), "rail: clear_fault refused: the e-stop input is still active");

  t.sim->set_estop_input(false);
  t.axis->clear_fault();
  s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::disabled);
  EXPECT_FALSE(s.homed);  // an open-loop stepper lost its reference when its output went off
  t.axis->enable();
  EXPECT_EQ(axis_error([&] { t.axis->move_to(10); }),
            "rail: move to 10 mm refused: the axis is not homed; home() first");
  t.home();
  t.axis->move_to(10);
  EXPECT_TRUE(t.axis->wait_settled(30s));
}

TEST(Axis, AnInjectedDriveAlarmFaultsTheAxisWithItsCause) {
  TestAxis t;
  t.home();
  t.sim->inject_alarm_at(t.clock->now() + 0.5, "overcurrent");
  t.axis->move_to(95);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_EQ(s.fault, "drive alarm: overcurrent");
  EXPECT_LT(s.position, 95);
  EXPECT_EQ(axis_error([&] { t.axis->home(); }),
            "rail: home refused: the axis is in fault (drive alarm: overcurrent); clear_fault() first");
  t.axis->clear_fault();
  EXPECT_FALSE(t.axis->drive().status().alarm);
  t.home();
  t.axis->move_to(95);
  EXPECT_TRUE(t.axis->wait_settled(30s));
}

TEST(Axis, ALimitSwitchTrippingDuringAMoveFaultsTheAxis) {
  TestAxis t;
  t.home();
  t.sim->inject_switch_at(SimSwitch::limit_max, 2400);  // 60 mm, inside the soft limits
  t.axis->move_to(95);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.fault, "drive alarm: limit_max tripped at step 2400");
  EXPECT_DOUBLE_EQ(s.position, 60);
  EXPECT_TRUE(s.inputs.limit_max);
}

TEST(Axis, EmergencyStopActsAtOnceFromTheCallersThread) {
  TestAxis t;
  t.home();
  t.axis->move_to(95);
  t.axis->emergency_stop();
  // No waiting: the drive is off and the fault published before the call returns.
  EXPECT_FALSE(t.axis->drive().status().enabled);
  EXPECT_FALSE(t.axis->drive().status().busy);
  EXPECT_EQ(t.axis->status().state, AxisState::fault);
  EXPECT_EQ(t.axis->status().fault, "emergency stop");
  EXPECT_FALSE(t.axis->wait_settled(1s));
  std::this_thread::sleep_for(20ms);  // the supervisor has taken it over since
  EXPECT_EQ(t.axis->status().fault, "emergency stop");
  t.axis->clear_fault();
  EXPECT_EQ(t.axis->status().state, AxisState::disabled);
}

TEST(Axis, StopIsControlledAndKeepsTheAxisHomed) {
  TestAxis t;
  t.home();
  t.axis->move_to(95);
  ASSERT_TRUE(eventually([&] { return t.axis->status().position > 10; }));
  t.axis->stop();
  EXPECT_FALSE(t.axis->wait_settled(30s));  // stopped, not settled
  ASSERT_TRUE(eventually([&] { return t.axis->status().state == AxisState::idle; }));
  const AxisStatus s = t.axis->status();
  EXPECT_TRUE(s.homed);
  EXPECT_GT(s.position, 10);
  EXPECT_LT(s.position, 95);
  EXPECT_TRUE(t.axis->drive().status().enabled);
  t.axis->move_to(5);
  EXPECT_TRUE(t.axis->wait_settled(30s));
}

TEST(Axis, FaultsWhenTheDriveNeverReachesThePosition) {
  TestAxis t;
  t.home();
  t.log->hold_busy = true;
  t.axis->move_to(10);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_NE(s.fault.find("did not reach position 10 mm in time"), std::string::npos) << s.fault;
}

TEST(Axis, ADriveThatFailsACommandFaultsTheAxisAndIsDisabled) {
  TestAxis t;
  t.home();
  t.log->refuse_moves = true;
  EXPECT_EQ(axis_error([&] { t.axis->move_to(10); }),
            "rail: move to 10 mm refused: the drive failed: rail (sim): no reply");
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_EQ(s.fault, "rail (sim): no reply");
  EXPECT_FALSE(t.axis->drive().status().enabled);
}

TEST(Axis, ADriveThatStopsAnsweringFaultsTheAxis) {
  TestAxis t;
  t.home();
  t.axis->move_to(95);
  t.sim->set_communication_lost(true);
  EXPECT_FALSE(t.axis->wait_settled(30s));
  const AxisStatus s = t.axis->status();
  EXPECT_EQ(s.state, AxisState::fault);
  EXPECT_EQ(s.fault, "drive alarm: rail (sim): no reply (communication lost)");
  t.sim->set_communication_lost(false);
  // The e-stop reached the drive over its hard-wired line.
  EXPECT_FALSE(t.sim->status().enabled);
  EXPECT_FALSE(t.sim->status().busy);
}

TEST(Axis, ATimeScaledSimFinishesALongMoveFast) {
  AxisSettings settings = rail_settings();
  settings.max_position = 2500;
  SimDriveSettings sim = rail_sim();
  sim.limit_max_steps = 2502 * 40;
  sim.start_position_steps = 40;  // 1 mm: a short homing
  TestAxis t(settings, sim, /*time_scale=*/200);
  t.home();
  const double start = t.clock->now();
  t.axis->move_to(2400);
  ASSERT_TRUE(t.axis->wait_settled(60s)) << t.axis->status().fault;
  EXPECT_DOUBLE_EQ(t.axis->status().position, 2400);
  // 2402 mm at 50 mm/s (and 0.25 s of each ramp): 48.29 simulated seconds,
  // a quarter of a second of real time at this scale.
  EXPECT_GE(t.clock->now() - start, 48.29);
}

// At the highest time scale a poll of the axis spans seconds of simulated
// time: every switch, brake and latch of the homing still happens in order,
// at the right place.
TEST(Axis, HomesAndMovesExactlyAtTheHighestTimeScale) {
  TestAxis t(rail_settings(), rail_sim(), SimClock::kMaxTimeScale);
  t.home();
  EXPECT_DOUBLE_EQ(t.axis->status().position, -2.0);
  EXPECT_EQ(t.axis->status().fault, "");
  t.axis->move_to(87.5);
  ASSERT_TRUE(t.axis->wait_settled(30s)) << t.axis->status().fault;
  EXPECT_DOUBLE_EQ(t.axis->status().position, 87.5);
}

// A stop must not wait behind a supervisor stuck in its drive (the SIGTERM
// that never completed): within a bound it gives up on the controlled stop,
// stops the drive the fail-safe way, and says so.
TEST(Axis, StopReturnsWithinABoundWhileTheDrivesUpdateIsStuck) {
  AxisSettings settings = rail_settings();
  TestAxis t(settings);
  t.home();
  t.axis->move_to(90);
  ASSERT_TRUE(eventually([&] { return t.axis->status().state == AxisState::moving; }));
  t.log->block_status = true;
  ASSERT_TRUE(eventually([&] { return t.log->blocked_in_status.load() > 0; }));
  const int stops_before = t.log->emergency_stops.load();
  auto stopped = std::async(std::launch::async, [&] { return axis_error([&] { t.axis->stop(); }); });
  const bool returned = stopped.wait_for(30s) == std::future_status::ready;
  // Let the supervisor go either way, so that a failure does not hang the test.
  t.log->block_status = false;
  ASSERT_TRUE(returned) << "stop() still waits for the axis";
  EXPECT_EQ(stopped.get(),
            "rail: stop: the axis has been busy with its drive for more than 5 s; emergency stop instead (the axis is "
            "disabled)");
  EXPECT_GT(t.log->emergency_stops.load(), stops_before);
  EXPECT_FALSE(t.sim->status().enabled);
  ASSERT_TRUE(eventually([&] { return t.axis->status().state == AxisState::fault; }));
  EXPECT_EQ(t.axis->status().fault, "emergency stop");
  // Other commands are refused the same way rather than waiting.
  t.log->block_status = true;
  ASSERT_TRUE(eventually([&] { return t.log->blocked_in_status.load() > 0; }));
  auto cleared = std::async(std::launch::async, [&] { return axis_error([&] { t.axis->clear_fault(); }); });
  const bool cleared_returned = cleared.wait_for(30s) == std::future_status::ready;
  t.log->block_status = false;
  ASSERT_TRUE(cleared_returned);
  EXPECT_EQ(cleared.get(),
            "rail: clear_fault refused: the axis has been busy with its drive for more than 5 s (a drive that does not "
            "answer?)");
}
