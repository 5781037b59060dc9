#pragma once
// A stepper motor driven through GPIO lines (step, direction, enable), with
// limit, home and e-stop switch inputs: the Drive of [rig.<axis>.gpio].
//
// Two threads per drive. The step thread times every step from the exact step
// times of the trapezoidal profile (TrapezoidProfile::time_at), sleeping to
// absolute CLOCK_MONOTONIC deadlines, SCHED_FIFO and with memory locked where
// the system allows. The input thread waits on the inputs' edge events,
// debounces them and publishes their levels, which the step thread checks
// before every step. See docs/rig-gpio.md for wiring, timing and fail-safe
// behaviour.

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "markerd/base/config_table.hpp"
#include "markerd/rig/drive.hpp"
#include "markerd/rig/gpio_lines.hpp"

namespace markerd::rig {

// The highest step rate a configuration may ask of this backend, in steps/s.
// User-space step timing is set by the kernel's wake-up latency, not by the
// GPIO write: a step more than a quarter of its interval late counts as a
// missed deadline and slips the profile. At 2500 steps/s that quarter is
// 100 us, about the p99 wake-up latency of a SCHED_FIFO thread that
// bench_step_timing measured here; at 5000 steps/s it is 50 us, under the
// median (about 60 us), and most steps miss. docs/rig-gpio.md has the figures.
inline constexpr double kGpioStepperMaxStepRate = 2500;

struct GpioStepperSettings {
  GpioLineSpec step;    // one pulse per step, active for step_pulse
  GpioLineSpec dir;     // active = positive direction
  GpioLineSpec enable;  // active = driver powered; inactive on any stop that is not controlled
  std::optional<GpioLineSpec> limit_min, limit_max, home, estop;  // active = switch tripped
  std::chrono::nanoseconds step_pulse{std::chrono::microseconds(5)};
  std::chrono::nanoseconds dir_setup{std::chrono::microseconds(5)};       // dir stable before the next step
  std::chrono::nanoseconds enable_settle{std::chrono::milliseconds(50)};  // enable before the first step
  std::chrono::nanoseconds debounce{std::chrono::milliseconds(5)};        // an input must stay released this long
  double max_step_rate = 2000;                                            // steps/s, <= kGpioStepperMaxStepRate
  int rt_priority = 0;               // SCHED_FIFO priority of both threads, 1..99; 0 = normal scheduling
  std::string consumer = "markerd";  // the name other processes see on the lines (gpioinfo)
};

// Parses [rig.<axis>.gpio] (keys in docs/rig-gpio.md); ConfigError naming the
// file, line and key for unknown keys, missing lines and values out of range,
// including a max_step_rate above what this backend supports.
GpioStepperSettings parse_gpio_stepper(const ConfigTable& gpio_table);

struct GpioStepperStats {
  std::uint64_t missed_deadlines = 0;        // since start: steps issued later than due + a quarter of their interval
  std::chrono::nanoseconds max_lateness{0};  // the latest move's latest step, against its (slipped) due time
  // CLOCK_MONOTONIC time of t = 0 of the latest move's profile: step n of that
  // move was planned at move_origin + time_at(n) (a braking ramp or a missed
  // deadline re-plans from where the move is).
  std::chrono::nanoseconds move_origin{0};
  bool realtime = false;  // the step thread runs SCHED_FIFO
};

class GpioStepperDrive final : public Drive {
 public:
  // Checks the settings as parse_gpio_stepper does, except the supported-rate
  // cap (which only configurations must respect: the benchmark measures
  // beyond it). Requests every line from `backend` (DriveError naming the line
  // when one is missing or busy) and starts the threads. The backend is used here only:
  // the lines it returns do not depend on it. The drive starts disabled, with
  // position 0 and not homed.
  GpioStepperDrive(std::string axis_name, GpioStepperSettings settings, GpioBackend& backend);
  ~GpioStepperDrive() override;  // disables, then joins both threads

  [[nodiscard]] std::string_view name() const override { return name_; }
  void enable(bool on) override;
  void start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) override;
  void start_homing(const HomingSteps& homing) override;
  void stop() override;
  void reset_alarm() override;
  void emergency_stop() noexcept override;
  [[nodiscard]] DriveStatus status() const override;

  [[nodiscard]] GpioStepperStats stats() const;
  [[nodiscard]] const GpioStepperSettings& settings() const { return settings_; }

 private:
  enum Input : std::size_t { limit_min, limit_max, home, estop, input_count };
  enum class End : std::uint8_t;
  struct Command;
  struct Segment;
  struct InputChannel;

  void step_thread_main(const std::stop_token& stop);
  void input_thread_main(const std::stop_token& stop);
  void run(const Command& command);
  void run_homing(const HomingSteps& homing);
  End run_segment(const Segment& segment);
  bool sleep_until(std::int64_t due_ns) const;
  void set_direction(int direction);
  // What a fault does besides latching its alarm, in the same step as seen by status().
  enum class AlarmAction : std::uint8_t { none, lose_home, disable };
  void raise_alarm(std::string cause, AlarmAction action = AlarmAction::none);
  // Enable inactive, steps aborted; the line's error, if writing it failed.
  // Callers hold alarm_mutex_.
  std::optional<std::string> switch_off(bool lose_home) noexcept;
  void disable_now(bool lose_home) noexcept;
  void check_can_move(int direction, double steps_per_s, const char* what) const;
  void on_input_active(Input input);
  void wait_until_idle();
  [[nodiscard]] bool input_active(Input input) const;

  std::string name_;
  GpioStepperSettings settings_;
  std::unique_ptr<GpioOutput> step_;         // step thread only
  std::unique_ptr<GpioOutput> dir_;          // step thread only
  std::unique_ptr<GpioOutput> enable_line_;  // under enable_mutex_
  std::array<std::unique_ptr<InputChannel>, input_count> inputs_;
  int shutdown_fd_ = -1;  // eventfd: wakes the input thread to exit

  // Published state, read by status() from any thread.
  std::atomic<std::int64_t> position_{0};
  std::atomic<bool> enabled_{false};
  std::atomic<bool> busy_{false};
  std::atomic<bool> homed_{false};
  std::atomic<bool> alarm_{false};
  std::atomic<bool> realtime_{false};
  std::atomic<bool> step_thread_ready_{false};  // its scheduling is set up: stats().realtime is final
  std::atomic<bool> inputs_failed_{false};      // the input thread stopped on an error: no motion until restart
  std::atomic<std::uint64_t> missed_deadlines_{0};
  std::atomic<std::int64_t> max_lateness_ns_{0};
  std::atomic<std::int64_t> move_origin_ns_{0};
  // Requests to the step thread, checked before every step.
  std::atomic<bool> stop_requested_{false};  // controlled stop: brake
  std::atomic<bool> abort_{false};           // disabled: no further step, set until enable(true)

  // Serialises writers of the enable line and of enabled_/abort_ together,
  // so that an emergency stop cannot interleave with enable(true).
  mutable std::mutex enable_mutex_;
  std::atomic<std::int64_t> enabled_at_ns_{0};  // when enable went active: motion waits for the settle time

  // Guards the alarm, and makes every change of enabled_/homed_ by a disable
  // or a fault one step for status(), which reads them under it: a fault
  // shows disabled (or home lost) and its alarm together. Taken before
  // enable_mutex_.
  mutable std::mutex alarm_mutex_;
  std::string alarm_cause_;  // under alarm_mutex_

  // Command hand-off to the idle step thread; never held while stepping.
  std::mutex command_mutex_;
  std::condition_variable_any command_ready_;
  std::unique_ptr<Command> pending_;  // under command_mutex_

  int direction_ = 0;                  // step thread: the dir line's current direction (0 = not yet set)
  std::int64_t direction_set_ns_ = 0;  // step thread: when it was set

  std::jthread input_thread_;
  std::jthread step_thread_;  // declared last: stopped and joined first
};

// A drive on the system's GPIO chips through libgpiod 1.6.
std::unique_ptr<Drive> make_gpio_stepper_drive(std::string axis_name, const GpioStepperSettings& settings);

}  // namespace markerd::rig
