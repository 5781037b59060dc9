#pragma once
// A simulated drive: a motor that moves along the same TrapezoidProfile as the
// real backends, in the simulated time of a SimClock, with limit and home
// switches at fixed positions and faults that tests and the demo inject
// (stall, a switch tripping early, an alarm at a time, lost communication,
// the e-stop input).
//
// It has no thread: its state is a function of the commands it was given and
// of the clock, brought up to date (event by event, in simulated-time order)
// whenever it is asked. With a manual SimClock a test steps it through exact
// instants, and the same commands at the same simulated times always give the
// same positions.
//
// Positions. The drive counts in steps. The motor lives in "physical" step
// coordinates: the switches and injected obstacles are placed there, and they
// equal the drive's reported coordinates after a homing whose
// home_position_steps is the physical position of the switch it latched on (as
// the shipped configs do). Before homing the count starts at 0 wherever the
// motor stands (start_position_steps).

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "markerd/rig/drive.hpp"
#include "markerd/rig/sim_clock.hpp"

namespace markerd::rig {

struct SimDriveSettings {
  std::string name = "sim";  // names the device in errors, e.g. "rail (sim)"
  // Where the motor stands at power-on, physical steps.
  std::int64_t start_position_steps = 0;
  // Limit switches: limit_min is active at and below its position, limit_max
  // at and above it.
  std::int64_t limit_min_steps = -1'000'000;
  std::int64_t limit_max_steps = 1'000'000;
  // An optional home switch, active at and below its position (or at and
  // above it when home_active_above).
  std::optional<std::int64_t> home_switch_steps;
  bool home_active_above = false;
  // Closed loop: an encoder reads the motor's actual position. status()
  // reports it (else the commanded position, as an open-loop stepper does),
  // new moves start from it, and the drive keeps its reference when
  // disabled. An open-loop drive loses its reference whenever its output stage
  // is off (the shaft is free).
  bool encoder = false;
};

// Checks the settings; returns what is wrong (naming the field), or nothing.
[[nodiscard]] std::optional<std::string> check_sim_drive_settings(const SimDriveSettings& settings);

enum class SimSwitch { limit_min, limit_max, home };

class SimDrive final : public Drive {
 public:
  // std::invalid_argument for settings check_sim_drive_settings rejects.
  SimDrive(SimDriveSettings settings, std::shared_ptr<const SimClock> clock);
  ~SimDrive() override;

  [[nodiscard]] std::string_view name() const override { return settings_.name; }
  void enable(bool on) override;
  void start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) override;
  void start_homing(const HomingSteps& homing) override;
  void stop() override;
  void reset_alarm() override;
  void emergency_stop() noexcept override;
  [[nodiscard]] DriveStatus status() const override;

  // --- Fault injection (any thread) ---
  // The motor jams when it reaches this physical position and stays there,
  // whatever it is commanded, until clear_stall(). The commanded position
  // goes on (a stepper losing steps); status() shows the difference only
  // with an encoder.
  void inject_stall_at(std::int64_t physical_steps);
  void clear_stall();
  // Moves a switch to a physical position: a limit switch that trips early,
  // a home switch that is not where it should be.
  void inject_switch_at(SimSwitch which, std::int64_t physical_steps);
  // A drive alarm at simulated time `sim_seconds` (immediately when in the
  // past): the motor stops at once, the output stage turns off, and status()
  // reports the alarm with `cause`.
  void inject_alarm_at(double sim_seconds, std::string cause);
  // Lost communication: every command throws DriveError ("no reply"), and
  // status() stays frozen at the last reply with an alarm, as a bus master
  // reports a drive that stopped answering. The motor itself carries on with
  // what it was doing. emergency_stop() still acts: it models the hard-wired
  // enable line, not a bus message.
  void set_communication_lost(bool lost);
  // The e-stop input (safe torque off): while active the motor stops at once,
  // the output stage is off, and enabling is refused.
  void set_estop_input(bool active);

  // --- Introspection for tests ---
  // The motor's true position and the commanded one, in reported steps
  // (unrounded), whatever the drive would report.
  [[nodiscard]] double actual_position_steps() const;
  [[nodiscard]] double commanded_position_steps() const;
  [[nodiscard]] const SimClock& clock() const { return *clock_; }

 private:
  class Model;
  SimDriveSettings settings_;
  std::shared_ptr<const SimClock> clock_;
  std::unique_ptr<Model> model_;  // all mutable state, behind its own mutex
};

}  // namespace markerd::rig
