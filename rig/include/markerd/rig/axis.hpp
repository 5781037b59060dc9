#pragma once
// An Axis is one thing that moves (the rail, the turntable) in user units (mm,
// degrees). It owns a Drive (the backend) and adds what is the same for every
// backend: unit conversion, soft limits, the homed requirement, backlash
// compensation (the final approach always from one side), retries within a
// deadband for closed-loop drives, settling, and the fail-safe rules. Commands
// are asynchronous: they are checked and started, and status() tells how
// they go.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>

#include "markerd/rig/drive.hpp"

namespace markerd::rig {

// A command the axis refuses (not homed, outside the soft limits, in fault,
// e-stop active), naming the axis and the reason.
class AxisError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The longest settle time and homing timeout an axis takes: longer ones mean
// nothing physically, and every duration stays far from overflowing the
// clocks' nanosecond counts.
inline constexpr std::chrono::milliseconds kMaxSettleTime{60'000};
inline constexpr std::chrono::milliseconds kMaxHomingTimeout{3'600'000};

struct HomingSettings {
  int direction = -1;  // search direction: -1 towards min, +1 towards max
  HomingSteps::Switch target = HomingSteps::Switch::home;
  double search_velocity = 0;  // user units / s (0: a quarter of max_velocity)
  double latch_velocity = 0;   // user units / s (0: a twentieth of max_velocity)
  double backoff = 0;          // user units moved off the switch before the slow latch
  double home_offset = 0;      // user position assigned where the switch latched
  std::chrono::milliseconds timeout{60000};
};

struct AxisSettings {
  std::string name;           // "rail", "turntable"
  std::string unit;           // "mm", "deg": used in messages only
  double units_per_step = 0;  // user units per motor step (> 0)
  double min_position = 0;    // soft limits, user units
  double max_position = 0;
  double max_velocity = 0;  // user units / s (> 0)
  double acceleration = 0;  // user units / s^2 (> 0)
  // Backlash compensation: when > 0, every move ends with an approach of this
  // length from the side of approach_direction (+1: from below, -1: from above).
  double backlash = 0;
  int approach_direction = +1;
  // Closed-loop drives: after a move, if |actual - target| exceeds the deadband,
  // the move is reissued, at most max_retries times, then the axis faults.
  // 0 disables the check (open-loop steppers report their commanded position).
  double retry_deadband = 0;
  int max_retries = 2;
  std::chrono::milliseconds settle_time{200};  // in position this long = settled
  HomingSettings homing;
};

// What is wrong with a set of settings: `key` is the setting's name in the
// config's axis table ("max_velocity", "homing.backoff", "settle_ms"), so
// that the config loader and the Axis constructor report the same rule.
struct AxisSettingsProblem {
  std::string key;
  std::string message;
};
[[nodiscard]] std::optional<AxisSettingsProblem> check_axis_settings(const AxisSettings& settings);

enum class AxisState : std::uint8_t { disabled, idle, moving, homing, stopping, fault };
const char* to_string(AxisState state);

struct AxisStatus {
  AxisState state = AxisState::disabled;
  bool homed = false;
  bool settled = false;  // idle, in position, for at least settle_time
  double position = 0;   // user units
  double target = 0;     // the last commanded target, user units
  DriveInputs inputs;
  std::string fault;                                // the cause, when state == fault
  std::chrono::steady_clock::time_point updated{};  // when this was read from the drive
};

class Axis {
 public:
  Axis(AxisSettings settings, std::unique_ptr<Drive> drive);  // validates settings (AxisError)
  ~Axis();                                                    // emergency stop, then joins its thread
  Axis(const Axis&) = delete;
  Axis& operator=(const Axis&) = delete;

  [[nodiscard]] const AxisSettings& settings() const { return settings_; }
  [[nodiscard]] const Drive& drive() const { return *drive_; }
  // For fault injection into a simulated drive (SimDrive's inject_* are
  // thread-safe); commands go through the axis, never straight to the drive.
  [[nodiscard]] Drive& drive() { return *drive_; }

  void enable();
  void disable();
  void home();                    // async
  void move_to(double position);  // async; AxisError when refused
  // Controlled; the axis stays enabled and homed. When the axis cannot be
  // had within a bound (its drive does not answer), an emergency stop
  // instead, and AxisError saying so.
  void stop();
  void emergency_stop() noexcept;  // disables at once; an open-loop axis loses its home
  void clear_fault();              // resets the drive's alarm; the axis must be homed again if it lost its reference

  [[nodiscard]] AxisStatus status() const;
  // Blocks until the axis is settled (true), in fault or stopped (false), or the
  // timeout passes (false).
  bool wait_settled(std::chrono::milliseconds timeout) const;

  // Called with every changed status (the rig's snapshot follows its axes
  // through this). It runs on the thread that changed the status, with the
  // axis's status lock held: it must be brief, must not block and must not
  // call back into this axis. An empty function removes the listener.
  void set_status_listener(std::function<void(const AxisStatus&)> listener);

 private:
  AxisSettings settings_;
  std::unique_ptr<Drive> drive_;
  // The implementation's supervisor thread and state (src/axis.cpp).
  // mutex_ guards the published status (Impl::published) and the listener;
  // it is never held during a drive command, so status() never waits on I/O.
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::jthread supervisor_;

  // Supervisor and command helpers (src/axis.cpp); they run with
  // Impl::command_mutex held.
  void run(const std::stop_token& stop);
  void step();
  void publish(const DriveStatus& drive_status, std::chrono::steady_clock::time_point now);
  void begin_move(double target, const DriveStatus& drive_status);
  void start_leg(std::int64_t target_steps, std::int64_t from_steps);
  void finish_move(const DriveStatus& drive_status, std::chrono::steady_clock::time_point now);
  enum class FaultAction { none, stop, disable };
  void enter_fault(std::string cause, FaultAction action);
  [[nodiscard]] DriveStatus read_drive_for_command();
  // Impl::command_mutex for a command, or AxisError when it cannot be had in
  // bounded time.
  [[nodiscard]] std::unique_lock<std::timed_mutex> lock_command(std::string_view command);
  [[noreturn]] void refuse(std::string_view command, std::string_view reason) const;
  [[noreturn]] void drive_failed(std::string_view command, const DriveError& error);
};

}  // namespace markerd::rig
