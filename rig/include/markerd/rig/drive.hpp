#pragma once
// A Drive is what differs between motion backends (GPIO stepper, Modbus drive,
// simulation). It works in motor steps (or the drive's own position counts) and
// knows nothing of user units, soft limits, backlash or settling: those are the
// same for every backend and live once, in Axis.

#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markerd::rig {

// A hardware or communication failure, naming the device and the cause.
class DriveError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct DriveInputs {
  bool limit_min = false;  // true = switch active (tripped), after active-level mapping
  bool limit_max = false;
  bool home = false;
  bool estop = false;
};

struct DriveStatus {
  std::int64_t position_steps = 0;  // measured where the drive measures it, else commanded
  bool enabled = false;
  bool busy = false;        // a move, stop ramp or homing sequence is in progress
  bool homed = false;       // the drive holds a valid position reference
  bool alarm = false;       // latched fault: the drive will not move until reset_alarm()
  std::string alarm_cause;  // set with alarm: what happened, in words (e.g. "limit_max tripped at step 41230")
  DriveInputs inputs;
};

// Homing, in the drive's steps. Drives that home by themselves (a Modbus
// drive's home command) may ignore the fields they cannot express.
struct HomingSteps {
  int direction = -1;  // -1: search towards negative positions, +1: positive
  enum class Switch { home, limit_min, limit_max } target = Switch::home;
  double search_steps_per_s = 0;  // fast search towards the switch
  double latch_steps_per_s = 0;   // slow approach that latches the position
  double accel_steps_per_s2 = 0;
  std::int64_t backoff_steps = 0;        // distance moved off the switch before the latch
  std::int64_t home_position_steps = 0;  // position assigned where the switch latched
  double timeout_s = 60;
};

class Drive {
 public:
  virtual ~Drive() = default;
  Drive() = default;
  Drive(const Drive&) = delete;
  Drive& operator=(const Drive&) = delete;

  // Names the device in every error and log line ("rail (gpio /dev/gpiochip0)").
  [[nodiscard]] virtual std::string_view name() const = 0;

  // The following may block on I/O and throw DriveError. They are called from
  // one thread at a time (the owning Axis's).
  virtual void enable(bool on) = 0;
  // Starts a rest-to-rest trapezoidal move to an absolute position; returns once
  // the drive has accepted it. A move while busy is an error.
  virtual void start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) = 0;
  virtual void start_homing(const HomingSteps& homing) = 0;
  // Controlled stop: decelerate at the move's acceleration, stay enabled.
  virtual void stop() = 0;
  virtual void reset_alarm() = 0;

  // Immediately disables the output stage, no ramp. Callable from any thread,
  // at any time, never throws, never blocks on a slow peer for long: it is the
  // fail-safe path.
  virtual void emergency_stop() noexcept = 0;

  // The drive's latest known state. Never blocks on I/O (backends keep it
  // current from their own thread); callable from any thread.
  [[nodiscard]] virtual DriveStatus status() const = 0;
};

}  // namespace markerd::rig
