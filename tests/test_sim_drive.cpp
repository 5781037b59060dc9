// The simulated drive, stepped through exact instants by a manual SimClock:
// positions follow the trapezoidal profile, homing latches on the switch edge,
// and each injected fault does what a real drive would show.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>

#include "markerd/rig/motion_profile.hpp"
#include "markerd/rig/sim_drive.hpp"

using namespace markerd::rig;

namespace {

struct Sim {
  std::shared_ptr<SimClock> clock = std::make_shared<SimClock>(SimClock::Manual{});
  std::unique_ptr<SimDrive> drive;

  explicit Sim(SimDriveSettings s = defaults()) : drive(std::make_unique<SimDrive>(std::move(s), clock)) {}

  static SimDriveSettings defaults() {
    SimDriveSettings s;
    s.name = "rail (sim)";
    s.start_position_steps = 0;
    s.limit_min_steps = -100;
    s.limit_max_steps = 100000;
    return s;
  }

  DriveStatus at(double sim_seconds) {
    clock->advance(sim_seconds - clock->now());
    return drive->status();
  }

  // Steps the clock until the drive is no longer busy; returns the sim time.
  double run_until_idle(double limit_s = 600, double dt = 0.005) {
    while (drive->status().busy) {
      if (clock->now() > limit_s) {
        ADD_FAILURE() << "still busy at " << clock->now() << " s";
        break;
      }
      clock->advance(dt);
    }
    return clock->now();
  }
};

std::string drive_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const DriveError& e) {
    return e.what();
  }
  return "(no error)";
}

HomingSteps homing_on(HomingSteps::Switch target, int direction, std::int64_t home_position) {
  HomingSteps h;
  h.direction = direction;
  h.target = target;
  h.search_steps_per_s = 2000;
  h.latch_steps_per_s = 100;
  h.accel_steps_per_s2 = 10000;
  h.backoff_steps = 200;
  h.home_position_steps = home_position;
  h.timeout_s = 60;
  return h;
}

}  // namespace

TEST(SimClock, ScalesRealTimeAndMapsToSteadyClock) {
  const SimClock clock(50.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GE(clock.now(), 50 * 0.020);  // at least 20 ms of real time went by
  const auto t = clock.epoch() + std::chrono::milliseconds(300);
  EXPECT_NEAR(clock.to_sim(t), 15.0, 1e-9);
  EXPECT_EQ(clock.to_steady(15.0), t);
  EXPECT_THROW(SimClock(0.0), std::invalid_argument);
  EXPECT_THROW(SimClock(50.0).advance(1), std::logic_error);

  SimClock manual(SimClock::Manual{});
  EXPECT_EQ(manual.now(), 0.0);
  manual.advance(2.5);
  EXPECT_DOUBLE_EQ(manual.now(), 2.5);
}

// Beyond kMaxTimeScale a poll spans so much simulated time that events can no
// longer be told apart (1e308 gave a false "not found within 150 s" and a loop
// that never ended); beyond kMaxAdvance the nanosecond count would overflow.
TEST(SimClock, RefusesTimeScalesAndStepsThatBreakTheSimulation) {
  EXPECT_NO_THROW(SimClock(SimClock::kMaxTimeScale));
  EXPECT_THROW(SimClock(1e308), std::invalid_argument);
  EXPECT_THROW(SimClock(SimClock::kMaxTimeScale * 1.001), std::invalid_argument);
  EXPECT_THROW(SimClock(std::numeric_limits<double>::infinity()), std::invalid_argument);
  EXPECT_THROW(SimClock(std::nan("")), std::invalid_argument);
  EXPECT_THROW(SimClock(-1.0), std::invalid_argument);

  SimClock manual(SimClock::Manual{});
  EXPECT_THROW(manual.advance(1e300), std::invalid_argument);
  EXPECT_THROW(manual.advance(std::nan("")), std::invalid_argument);
  manual.advance(SimClock::kMaxAdvance - 1);
  EXPECT_THROW(manual.advance(2), std::invalid_argument);
  EXPECT_DOUBLE_EQ(manual.now(), SimClock::kMaxAdvance - 1);

  // A time far outside any run maps to a clamped real time, not an overflow.
  const SimClock running(1.0);
  EXPECT_GT(running.to_steady(1e300), running.epoch());
  EXPECT_LT(running.to_steady(-1e300), running.epoch());
}

// A whole homing in one update, late in simulated time: what one poll of the
// axes spans at the highest time scale after years of uptime. Every event is
// taken in order, the reference is the switch edge, and the update ends.
TEST(SimDrive, HomesInOneLongUpdateLateInSimulatedTime) {
  SimDriveSettings settings = Sim::defaults();
  settings.start_position_steps = 5000;
  Sim sim(settings);
  sim.clock->advance(1e8);  // a running clock at 1000x after three years
  sim.drive->enable(true);
  sim.drive->start_homing(homing_on(HomingSteps::Switch::limit_min, -1, -100));
  sim.clock->advance(60);
  const DriveStatus s = sim.drive->status();
  ASSERT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_FALSE(s.busy);
  EXPECT_TRUE(s.homed);
  EXPECT_NEAR(sim.drive->actual_position_steps(), -100.5, 1e-3);
}

// An emergency stop does not wait for the model's lock: it leaves a flag that
// the next update applies, and applies it at once when the lock is free.
TEST(SimDrive, EmergencyStopStopsAMoveInProgress) {
  Sim sim;
  sim.drive->enable(true);
  sim.drive->start_move(50000, 2000, 10000);
  sim.clock->advance(1);
  sim.drive->emergency_stop();
  const double at = sim.drive->actual_position_steps();
  sim.clock->advance(1);
  const DriveStatus s = sim.drive->status();
  EXPECT_FALSE(s.enabled);
  EXPECT_FALSE(s.busy);
  EXPECT_EQ(sim.drive->actual_position_steps(), at);
  EXPECT_GT(at, 0);
}

TEST(SimDrive, MovesAlongTheTrapezoidProfile) {
  Sim sim;
  sim.drive->enable(true);
  sim.drive->start_move(4000, 1000, 2000);
  const TrapezoidProfile profile(4000, 1000, 2000);
  ASSERT_DOUBLE_EQ(profile.duration(), 4.5);
  for (double t : {0.1, 0.25, 0.5, 1.7, 3.9, 4.2}) {
    const DriveStatus s = sim.at(t);
    EXPECT_TRUE(s.busy) << t;
    EXPECT_EQ(s.position_steps, std::llround(profile.position_at(t))) << t;
  }
  const DriveStatus end = sim.at(4.5);
  EXPECT_FALSE(end.busy);
  EXPECT_EQ(end.position_steps, 4000);
  EXPECT_FALSE(end.homed);
  EXPECT_FALSE(end.alarm);
  // Back again: the same profile, mirrored.
  sim.drive->start_move(0, 1000, 2000);
  EXPECT_EQ(sim.at(4.5 + 1.7).position_steps, 4000 - std::llround(profile.position_at(1.7)));
  EXPECT_EQ(sim.at(9.0).position_steps, 0);
}

TEST(SimDrive, RefusesMovesWhileDisabledOrBusy) {
  Sim sim;
  EXPECT_EQ(drive_error([&] { sim.drive->start_move(10, 100, 100); }),
            "rail (sim): cannot start a move: the drive is not enabled");
  sim.drive->enable(true);
  sim.drive->start_move(1000, 100, 100);
  EXPECT_EQ(drive_error([&] { sim.drive->start_move(10, 100, 100); }),
            "rail (sim): cannot start a move: the drive is busy");
}

TEST(SimDrive, StopBrakesAtTheMoveAcceleration) {
  Sim sim;
  sim.drive->enable(true);
  sim.drive->start_move(50000, 1000, 2000);
  EXPECT_EQ(sim.at(2.0).position_steps, 1750);  // 250 accelerating + 1.5 s at 1000
  sim.drive->stop();
  EXPECT_TRUE(sim.at(2.25).busy);
  const DriveStatus s = sim.at(2.6);
  EXPECT_FALSE(s.busy);
  EXPECT_EQ(s.position_steps, 1750 + 250);  // 1000^2 / (2 * 2000)
  EXPECT_TRUE(s.enabled);
}

TEST(SimDrive, HomesOnLimitMinWithBackoffAndSlowLatch) {
  SimDriveSettings settings = Sim::defaults();
  settings.start_position_steps = 5000;  // the count starts at 0 here
  Sim sim(settings);
  sim.drive->enable(true);
  EXPECT_EQ(sim.drive->status().position_steps, 0);
  sim.drive->start_homing(homing_on(HomingSteps::Switch::limit_min, -1, -100));
  EXPECT_FALSE(sim.drive->status().homed);
  double lowest = 1e9;
  while (sim.drive->status().busy && sim.clock->now() < 60) {
    sim.clock->advance(0.001);
    lowest = std::min(lowest, sim.drive->actual_position_steps());
  }
  const DriveStatus s = sim.drive->status();
  ASSERT_FALSE(s.busy);
  ASSERT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_TRUE(s.homed);
  // The switch edge (physical -100) became -100: the reported count is now
  // physical. The latch brakes 100^2 / (2 * 10000) = 0.5 steps past the edge.
  EXPECT_NEAR(sim.drive->actual_position_steps(), -100.5, 1e-6);
  EXPECT_TRUE(s.inputs.limit_min);
  // The fast search overshot the edge by its braking distance, 2000^2 / 20000.
  // (The count was re-referenced afterwards: compare in the new coordinates.)
  EXPECT_NEAR(lowest, -5100 - 200, 1.0);
}

TEST(SimDrive, HomesOnAHomeSwitchThatIsAlreadyActive) {
  SimDriveSettings settings = Sim::defaults();
  settings.start_position_steps = 500;
  settings.home_switch_steps = 1000;  // active at and below 1000
  Sim sim(settings);
  sim.drive->enable(true);
  ASSERT_TRUE(sim.drive->status().inputs.home);
  sim.drive->start_homing(homing_on(HomingSteps::Switch::home, -1, 1000));
  sim.run_until_idle(60, 0.001);
  const DriveStatus s = sim.drive->status();
  ASSERT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_TRUE(s.homed);
  // Backed off upwards past the edge, latched coming down onto it.
  EXPECT_NEAR(sim.drive->actual_position_steps(), 1000 - 0.5, 1e-6);
  EXPECT_TRUE(s.inputs.home);
}

TEST(SimDrive, HomingThatRunsIntoTheOtherLimitOrTimesOutRaisesAnAlarm) {
  {
    SimDriveSettings settings = Sim::defaults();
    settings.home_switch_steps = 1000;
    settings.home_active_above = true;  // so searching downwards never finds it
    Sim sim(settings);
    sim.drive->enable(true);
    sim.drive->start_homing(homing_on(HomingSteps::Switch::home, -1, 0));
    sim.run_until_idle(60, 0.001);
    const DriveStatus s = sim.drive->status();
    EXPECT_TRUE(s.alarm);
    EXPECT_EQ(s.alarm_cause, "homing: before the home switch, limit_min tripped at step -100");
    EXPECT_FALSE(s.homed);
    EXPECT_NEAR(sim.drive->actual_position_steps(), -100, 1e-9);
  }
  {
    SimDriveSettings settings = Sim::defaults();
    settings.limit_min_steps = -10'000'000;
    Sim sim(settings);
    sim.drive->enable(true);
    HomingSteps h = homing_on(HomingSteps::Switch::limit_min, -1, 0);
    h.timeout_s = 2;
    sim.drive->start_homing(h);
    EXPECT_TRUE(sim.at(1.99).busy);
    const DriveStatus s = sim.at(2.01);
    EXPECT_FALSE(s.busy);
    EXPECT_TRUE(s.alarm);
    EXPECT_EQ(s.alarm_cause, "homing: the limit_min switch was not found within 2 s");
  }
}

TEST(SimDrive, ALimitSwitchStopsAMoveAtOnceWithAnAlarm) {
  Sim sim;
  sim.drive->inject_switch_at(SimSwitch::limit_max, 3000);  // trips early
  sim.drive->enable(true);
  sim.drive->start_move(6000, 1000, 2000);
  const double end = sim.run_until_idle();
  EXPECT_LT(end, TrapezoidProfile(6000, 1000, 2000).duration());
  DriveStatus s = sim.drive->status();
  EXPECT_EQ(s.position_steps, 3000);
  EXPECT_TRUE(s.alarm);
  EXPECT_EQ(s.alarm_cause, "limit_max tripped at step 3000");
  EXPECT_TRUE(s.inputs.limit_max);
  EXPECT_FALSE(s.enabled);  // the output stage is off
  EXPECT_EQ(drive_error([&] { sim.drive->start_move(0, 1000, 2000); }),
            "rail (sim): cannot start a move: alarm active (limit_max tripped at step 3000); reset it first");

  sim.drive->reset_alarm();
  sim.drive->enable(true);
  // Further into the switch: refused with the alarm at once; away from it: fine.
  sim.drive->start_move(3500, 1000, 2000);
  s = sim.drive->status();
  EXPECT_TRUE(s.alarm);
  EXPECT_EQ(s.position_steps, 3000);
  sim.drive->reset_alarm();
  sim.drive->enable(true);
  sim.drive->start_move(2000, 1000, 2000);
  sim.run_until_idle();
  s = sim.drive->status();
  EXPECT_FALSE(s.alarm) << s.alarm_cause;
  EXPECT_EQ(s.position_steps, 2000);
  EXPECT_FALSE(s.inputs.limit_max);
}

TEST(SimDrive, AStalledMotorShowsOnlyWithAnEncoder) {
  for (bool encoder : {false, true}) {
    SCOPED_TRACE(encoder ? "closed loop" : "open loop");
    SimDriveSettings settings = Sim::defaults();
    settings.encoder = encoder;
    Sim sim(settings);
    sim.drive->inject_stall_at(600);
    sim.drive->enable(true);
    sim.drive->start_move(1000, 1000, 2000);
    sim.run_until_idle();
    EXPECT_DOUBLE_EQ(sim.drive->actual_position_steps(), 600);
    EXPECT_DOUBLE_EQ(sim.drive->commanded_position_steps(), 1000);
    EXPECT_EQ(sim.drive->status().position_steps, encoder ? 600 : 1000);
    // Jammed: a second try gets nowhere.
    sim.drive->start_move(encoder ? 1000 : 1400, 1000, 2000);
    sim.run_until_idle();
    EXPECT_DOUBLE_EQ(sim.drive->actual_position_steps(), 600);
    // Freed: a closed loop reaches the target; an open loop carries its lost steps.
    sim.drive->clear_stall();
    sim.drive->start_move(encoder ? 1000 : 1800, 1000, 2000);
    sim.run_until_idle();
    EXPECT_DOUBLE_EQ(sim.drive->actual_position_steps(), 1000);
    EXPECT_EQ(sim.drive->status().position_steps, encoder ? 1000 : 1800);
  }
}

TEST(SimDrive, AnAlarmAtASimulatedTimeStopsTheMotorWhereItIs) {
  Sim sim;
  sim.drive->enable(true);
  sim.drive->start_move(4000, 1000, 2000);
  sim.drive->inject_alarm_at(1.0, "overcurrent");
  EXPECT_FALSE(sim.at(0.999).alarm);
  const DriveStatus s = sim.at(3.0);  // observed late: the motor stopped at 1.0 s all the same
  EXPECT_TRUE(s.alarm);
  EXPECT_EQ(s.alarm_cause, "overcurrent");
  EXPECT_FALSE(s.busy);
  EXPECT_EQ(s.position_steps, 750);  // 250 accelerating + 0.5 s at 1000
}

TEST(SimDrive, LostCommunicationFreezesTheStatusAndFailsCommands) {
  Sim sim;
  sim.drive->enable(true);
  sim.drive->start_move(4000, 1000, 2000);
  const std::int64_t last = sim.at(1.0).position_steps;
  sim.drive->set_communication_lost(true);
  const DriveStatus s = sim.at(2.0);
  EXPECT_EQ(s.position_steps, last);
  EXPECT_TRUE(s.busy);
  EXPECT_TRUE(s.alarm);
  EXPECT_EQ(s.alarm_cause, "rail (sim): no reply (communication lost)");
  EXPECT_EQ(drive_error([&] { sim.drive->stop(); }), "rail (sim): no reply (communication lost)");
  EXPECT_EQ(drive_error([&] { sim.drive->start_move(0, 1, 1); }), "rail (sim): no reply (communication lost)");
  EXPECT_EQ(drive_error([&] { sim.drive->enable(false); }), "rail (sim): no reply (communication lost)");
  // The motor went on meanwhile; the hard-wired e-stop still acts.
  sim.drive->emergency_stop();
  sim.drive->set_communication_lost(false);
  const DriveStatus back = sim.at(2.5);
  EXPECT_FALSE(back.alarm);
  EXPECT_FALSE(back.busy);
  EXPECT_FALSE(back.enabled);
  EXPECT_EQ(back.position_steps, 1750);  // where the e-stop caught it, at 2.0 s
}

TEST(SimDrive, TheEstopInputStopsDisablesAndRefusesEnable) {
  SimDriveSettings settings = Sim::defaults();
  settings.limit_min_steps = -10;
  Sim sim(settings);
  sim.drive->enable(true);
  sim.drive->start_homing(homing_on(HomingSteps::Switch::limit_min, -1, -10));
  sim.run_until_idle();
  ASSERT_TRUE(sim.drive->status().homed);
  const double t0 = sim.clock->now();
  sim.drive->start_move(4000, 1000, 2000);
  sim.at(t0 + 1.0);
  sim.drive->set_estop_input(true);
  const DriveStatus s = sim.at(t0 + 2.0);
  EXPECT_TRUE(s.inputs.estop);
  EXPECT_FALSE(s.busy);
  EXPECT_FALSE(s.enabled);
  EXPECT_FALSE(s.homed);  // open loop: the shaft was free
  EXPECT_EQ(drive_error([&] { sim.drive->enable(true); }), "rail (sim): cannot enable: the e-stop input is active");
  sim.drive->set_estop_input(false);
  sim.drive->enable(true);
  EXPECT_TRUE(sim.drive->status().enabled);
}

TEST(SimDrive, AClosedLoopDriveKeepsItsReferenceWhenDisabled) {
  SimDriveSettings settings = Sim::defaults();
  settings.encoder = true;
  Sim sim(settings);
  sim.drive->enable(true);
  sim.drive->start_homing(homing_on(HomingSteps::Switch::limit_min, -1, -100));
  sim.run_until_idle();
  ASSERT_TRUE(sim.drive->status().homed);
  sim.drive->emergency_stop();
  EXPECT_TRUE(sim.drive->status().homed);
}

TEST(SimDrive, TheSameCommandsAtTheSameTimesGiveTheSamePositions) {
  auto run = [] {
    Sim sim;
    sim.drive->inject_stall_at(2500);
    sim.drive->inject_alarm_at(3.3, "overheat");
    sim.drive->enable(true);
    sim.drive->start_move(4000, 1000, 2000);
    std::vector<double> trace;
    for (int i = 0; i < 500; ++i) {
      sim.clock->advance(0.01);
      trace.push_back(sim.drive->actual_position_steps());
    }
    return trace;
  };
  EXPECT_EQ(run(), run());
}
