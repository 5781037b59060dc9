// The Axis: commands are checked and started on the caller's thread, and a
// supervisor thread per axis follows the drive (every kPollPeriod) through the
// rest of each command: the backlash approach, retries, timeouts, settling,
// and the fail-safe reactions to alarms and the e-stop input.
//
// Locking. Impl::command_mutex serialises every drive command and the state
// machine: callers and the supervisor take it for a whole command or poll step,
// so the Drive sees one thread at a time, as drive.hpp asks. Nobody waits for
// it longer than kCommandWait: a drive call that never returns must not hold
// up a stop (it becomes an emergency stop) nor the supervisor's shutdown. Axis::mutex_
// guards only the published AxisStatus and is never held across a drive call,
// so status() and wait_settled() never wait on a slow bus. emergency_stop()
// takes neither: it calls the drive at once and leaves a flag (an atomic) for
// the state machine.

#include "markerd/rig/axis.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <utility>

#include "markerd/rig/motion_profile.hpp"

namespace markerd::rig {

namespace {

using Clock = std::chrono::steady_clock;
constexpr auto kPollPeriod = std::chrono::milliseconds(2);
// The longest a command waits for the axis while another command or a poll
// step holds it. Normal holds are a drive command's round trip; beyond this
// the drive is not answering, and a stop becomes an emergency stop.
constexpr auto kCommandWait = std::chrono::seconds(5);
// A move's timeout is twice its planned duration plus this: room for a drive
// that starts late or runs a gentler ramp than planned.
constexpr auto kTimeoutMargin = std::chrono::seconds(2);
// A backend whose status lags its commands (a bus polled by its own thread)
// may report "not busy" for a moment after it accepted a move. A leg that was
// never seen busy and is not at its target counts as finished only after this.
constexpr auto kStartGrace = std::chrono::milliseconds(250);

bool same_inputs(const DriveInputs& a, const DriveInputs& b) {
  return a.limit_min == b.limit_min && a.limit_max == b.limit_max && a.home == b.home && a.estop == b.estop;
}

// Everything but the time stamp.
bool same_status(const AxisStatus& a, const AxisStatus& b) {
  return a.state == b.state && a.homed == b.homed && a.settled == b.settled && a.position == b.position &&
         a.target == b.target && same_inputs(a.inputs, b.inputs) && a.fault == b.fault;
}

// Closed-loop drives (a retry deadband) are in position within the deadband;
// open-loop ones report their commanded position, which is exact.
bool in_position(const AxisSettings& settings, std::int64_t position_steps, std::int64_t target_steps) {
  const double error = std::abs(static_cast<double>(position_steps - target_steps)) * settings.units_per_step;
  return settings.retry_deadband > 0 ? error <= settings.retry_deadband : position_steps == target_steps;
}

// Saturates at a day: a planned duration beyond that (a tiny velocity over a
// long travel) must not overflow the clock's nanosecond count.
Clock::duration seconds(double s) {
  constexpr double kMax = 86400;
  return std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(std::isnan(s) ? kMax : std::clamp(s, 0.0, kMax)));
}

}  // namespace

const char* to_string(AxisState state) {
  switch (state) {
    case AxisState::disabled: return "disabled";
    case AxisState::idle: return "idle";
    case AxisState::moving: return "moving";
    case AxisState::homing: return "homing";
    case AxisState::stopping: return "stopping";
    case AxisState::fault: return "fault";
  }
  return "unknown";
}

std::optional<AxisSettingsProblem> check_axis_settings(const AxisSettings& s) {
  auto problem = [](std::string key, std::string message) {
    return std::optional<AxisSettingsProblem>(AxisSettingsProblem{std::move(key), std::move(message)});
  };
  auto positive = [](double v) { return std::isfinite(v) && v > 0; };
  auto non_negative = [](double v) { return std::isfinite(v) && v >= 0; };
  if (s.name.empty()) return problem("name", "must not be empty");
  if (!positive(s.units_per_step))
    return problem("units_per_step", fmt::format("must be > 0, got {}", s.units_per_step));
  if (!std::isfinite(s.min_position)) return problem("min_position", "must be a finite number");
  if (!std::isfinite(s.max_position)) return problem("max_position", "must be a finite number");
  if (!(s.min_position < s.max_position)) {
    return problem("max_position",
                   fmt::format("must be above min_position ({} {}), got {}", s.min_position, s.unit, s.max_position));
  }
  // Steps travel as int64 and through doubles: keep every position exact.
  constexpr double kMaxSteps = 9007199254740992.0;  // 2^53
  if (std::max(std::abs(s.min_position), std::abs(s.max_position)) / s.units_per_step >= kMaxSteps) {
    return problem("units_per_step", "the soft limits are more than 2^53 steps away from 0");
  }
  if (!positive(s.max_velocity)) return problem("max_velocity", fmt::format("must be > 0, got {}", s.max_velocity));
  if (!positive(s.acceleration)) return problem("acceleration", fmt::format("must be > 0, got {}", s.acceleration));
  if (!non_negative(s.backlash)) return problem("backlash", fmt::format("must be >= 0, got {}", s.backlash));
  if (s.backlash >= s.max_position - s.min_position) {
    return problem("backlash",
                   fmt::format("must be shorter than the travel ({} {})", s.max_position - s.min_position, s.unit));
  }
  if (s.approach_direction != 1 && s.approach_direction != -1) {
    return problem("approach_direction", fmt::format("must be 1 or -1, got {}", s.approach_direction));
  }
  if (!non_negative(s.retry_deadband))
    return problem("retry_deadband", fmt::format("must be >= 0, got {}", s.retry_deadband));
  if (s.retry_deadband > 0 && s.retry_deadband < s.units_per_step / 2) {
    return problem("retry_deadband",
                   fmt::format("must be 0 (off) or at least half a step ({} {})", s.units_per_step / 2, s.unit));
  }
  if (s.max_retries < 0) return problem("max_retries", fmt::format("must be >= 0, got {}", s.max_retries));
  if (s.settle_time.count() < 0 || s.settle_time > kMaxSettleTime) {
    return problem("settle_ms",
                   fmt::format("must be from 0 to {} ms, got {}", kMaxSettleTime.count(), s.settle_time.count()));
  }
  const HomingSettings& h = s.homing;
  if (h.direction != 1 && h.direction != -1) {
    return problem("homing.direction", fmt::format("must be 1 or -1, got {}", h.direction));
  }
  if (!non_negative(h.search_velocity) || h.search_velocity > s.max_velocity) {
    return problem("homing.search_velocity", fmt::format("must be between 0 (default) and max_velocity ({}), got {}",
                                                         s.max_velocity, h.search_velocity));
  }
  if (!non_negative(h.latch_velocity) || h.latch_velocity > s.max_velocity) {
    return problem("homing.latch_velocity", fmt::format("must be between 0 (default) and max_velocity ({}), got {}",
                                                        s.max_velocity, h.latch_velocity));
  }
  if (!non_negative(h.backoff)) return problem("homing.backoff", fmt::format("must be >= 0, got {}", h.backoff));
  if (h.backoff / s.units_per_step >= kMaxSteps) return problem("homing.backoff", "is more than 2^53 steps");
  if (!std::isfinite(h.home_offset)) return problem("homing.home_offset", "must be a finite number");
  if (std::abs(h.home_offset) / s.units_per_step >= kMaxSteps) {
    return problem("homing.home_offset", "is more than 2^53 steps away from 0");
  }
  if (h.timeout.count() <= 0 || h.timeout > kMaxHomingTimeout) {
    return problem("homing.timeout_s",
                   fmt::format("must be > 0 and at most {} s, got {} s", kMaxHomingTimeout.count() / 1000,
                               std::chrono::duration<double>(h.timeout).count()));
  }
  return std::nullopt;
}

struct Axis::Impl {
  std::timed_mutex command_mutex;
  // The supervisor's sleep between polls; a stop request cuts it short.
  std::mutex wake_mutex;
  std::condition_variable_any wake;
  // Set by emergency_stop() (any thread, no lock); taken over by the state
  // machine at its next step or command.
  std::atomic<bool> estop_requested{false};

  // The state machine (command_mutex).
  AxisState state = AxisState::disabled;
  std::string fault;
  double target = 0;  // user units
  std::int64_t target_steps = 0;
  std::optional<std::int64_t> final_leg;  // backlash: the final approach, still to go
  std::int64_t leg_steps = 0;
  Clock::time_point leg_started{};
  Clock::time_point deadline{};
  bool leg_seen_busy = false;
  int retries = 0;
  // A move or homing ended at `target`, so settling counts; false after a
  // stop, an enable or a fault (wait_settled reports those as "stopped").
  bool target_reached = false;
  std::optional<Clock::time_point> in_position_since;
  DriveStatus last_drive_status;  // published when the drive cannot be read

  // Published (Axis::mutex_).
  AxisStatus published;
  bool published_target_reached = false;
  std::function<void(const AxisStatus&)> listener;
};

Axis::Axis(AxisSettings settings, std::unique_ptr<Drive> drive)
    : settings_(std::move(settings)), drive_(std::move(drive)), impl_(std::make_unique<Impl>()) {
  if (!drive_) throw AxisError(fmt::format("{}: no drive", settings_.name));
  if (auto p = check_axis_settings(settings_)) {
    throw AxisError(fmt::format("{}: invalid setting {}: {}", settings_.name, p->key, p->message));
  }
  {
    const std::lock_guard<std::timed_mutex> lock(impl_->command_mutex);
    publish(drive_->status(), Clock::now());
  }
  supervisor_ = std::jthread([this](const std::stop_token& stop) { run(stop); });
}

Axis::~Axis() {
  drive_->emergency_stop();
  supervisor_.request_stop();
  if (supervisor_.joinable()) supervisor_.join();
  // The supervisor may have been starting a leg when the first stop came.
  drive_->emergency_stop();
}

// --- Commands (caller's thread) ---

std::unique_lock<std::timed_mutex> Axis::lock_command(std::string_view command) {
  std::unique_lock<std::timed_mutex> lock(impl_->command_mutex, std::defer_lock);
  if (!lock.try_lock_for(kCommandWait)) {
    refuse(command, fmt::format("the axis has been busy with its drive for more than {} s (a drive that does not "
                                "answer?)",
                                std::chrono::duration<double>(kCommandWait).count()));
  }
  return lock;
}

void Axis::refuse(std::string_view command, std::string_view reason) const {
  throw AxisError(fmt::format("{}: {} refused: {}", settings_.name, command, reason));
}

void Axis::drive_failed(std::string_view command, const DriveError& error) {
  // A drive that failed a command is in doubt: turn it off.
  enter_fault(error.what(), FaultAction::disable);
  publish(drive_->status(), Clock::now());
  refuse(command, fmt::format("the drive failed: {}", error.what()));
}

DriveStatus Axis::read_drive_for_command() {
  if (impl_->estop_requested.exchange(false) && impl_->state != AxisState::fault) {
    enter_fault("emergency stop", FaultAction::none);
  }
  return drive_->status();
}

void Axis::enable() {
  const auto lock = lock_command("enable");
  const DriveStatus ds = read_drive_for_command();
  Impl& m = *impl_;
  if (m.state == AxisState::fault)
    refuse("enable", fmt::format("the axis is in fault ({}); clear_fault() first", m.fault));
  if (ds.inputs.estop) refuse("enable", "the e-stop input is active");
  if (m.state != AxisState::disabled) return;
  try {
    drive_->enable(true);
  } catch (const DriveError& e) {
    drive_failed("enable", e);
  }
  m.state = AxisState::idle;
  m.target_reached = false;
  publish(drive_->status(), Clock::now());
}

void Axis::disable() {
  const auto lock = lock_command("disable");
  (void)read_drive_for_command();
  Impl& m = *impl_;
  if (m.state == AxisState::moving || m.state == AxisState::homing || m.state == AxisState::stopping) {
    refuse("disable", fmt::format("the axis is {}; stop() and wait, or emergency_stop()", to_string(m.state)));
  }
  try {
    drive_->enable(false);
  } catch (const DriveError& e) {
    drive_failed("disable", e);
  }
  if (m.state != AxisState::fault) m.state = AxisState::disabled;
  m.target_reached = false;
  publish(drive_->status(), Clock::now());
}

void Axis::home() {
  const auto lock = lock_command("home");
  const DriveStatus ds = read_drive_for_command();
  Impl& m = *impl_;
  constexpr std::string_view command = "home";
  if (m.state == AxisState::fault)
    refuse(command, fmt::format("the axis is in fault ({}); clear_fault() first", m.fault));
  if (ds.inputs.estop) refuse(command, "the e-stop input is active");
  if (m.state == AxisState::disabled) refuse(command, "the axis is disabled; enable() first");
  if (m.state != AxisState::idle)
    refuse(command, fmt::format("the axis is busy ({}); wait or stop() first", to_string(m.state)));

  const HomingSettings& h = settings_.homing;
  const double ups = settings_.units_per_step;
  HomingSteps steps;
  steps.direction = h.direction;
  steps.target = h.target;
  steps.search_steps_per_s = (h.search_velocity > 0 ? h.search_velocity : settings_.max_velocity / 4) / ups;
  steps.latch_steps_per_s = (h.latch_velocity > 0 ? h.latch_velocity : settings_.max_velocity / 20) / ups;
  steps.accel_steps_per_s2 = settings_.acceleration / ups;
  steps.backoff_steps = std::llround(h.backoff / ups);
  steps.home_position_steps = std::llround(h.home_offset / ups);
  steps.timeout_s = std::chrono::duration<double>(h.timeout).count();
  try {
    drive_->start_homing(steps);
  } catch (const DriveError& e) {
    drive_failed(command, e);
  }
  const auto now = Clock::now();
  m.state = AxisState::homing;
  m.final_leg.reset();
  m.target_reached = false;
  m.in_position_since.reset();
  m.leg_started = now;
  m.leg_seen_busy = false;
  m.deadline = now + h.timeout + kTimeoutMargin;
  publish(drive_->status(), Clock::now());
}

void Axis::move_to(double position) {
  const std::string command = fmt::format("move to {} {}", position, settings_.unit);
  const auto lock = lock_command(command);
  const DriveStatus ds = read_drive_for_command();
  Impl& m = *impl_;
  if (!std::isfinite(position)) refuse(command, "the target is not a finite number");
  if (m.state == AxisState::fault)
    refuse(command, fmt::format("the axis is in fault ({}); clear_fault() first", m.fault));
  if (ds.inputs.estop) refuse(command, "the e-stop input is active");
  if (m.state == AxisState::disabled) refuse(command, "the axis is disabled; enable() first");
  if (m.state != AxisState::idle)
    refuse(command, fmt::format("the axis is busy ({}); wait or stop() first", to_string(m.state)));
  if (!ds.homed) refuse(command, "the axis is not homed; home() first");
  if (position < settings_.min_position || position > settings_.max_position) {
    refuse(command, fmt::format("outside the soft limits [{}, {}] {}", settings_.min_position, settings_.max_position,
                                settings_.unit));
  }
  m.retries = 0;
  try {
    begin_move(position, ds);
  } catch (const DriveError& e) {
    drive_failed(command, e);
  }
  publish(drive_->status(), Clock::now());
}

void Axis::stop() {
  std::unique_lock<std::timed_mutex> lock(impl_->command_mutex, std::defer_lock);
  if (!lock.try_lock_for(kCommandWait)) {
    // Something holds the axis (a drive call that blocks, a simulation that
    // spins): a controlled stop cannot be had, so the fail-safe one instead.
    emergency_stop();
    throw AxisError(
        fmt::format("{}: stop: the axis has been busy with its drive for more than {} s; emergency stop "
                    "instead (the axis is disabled)",
                    settings_.name, std::chrono::duration<double>(kCommandWait).count()));
  }
  (void)read_drive_for_command();
  Impl& m = *impl_;
  if (m.state != AxisState::moving && m.state != AxisState::homing) return;
  try {
    drive_->stop();
  } catch (const DriveError& e) {
    drive_failed("stop", e);
  }
  m.state = AxisState::stopping;
  m.final_leg.reset();
  m.target_reached = false;
  m.in_position_since.reset();
  m.leg_started = Clock::now();
  m.leg_seen_busy = false;
  publish(drive_->status(), Clock::now());
}

void Axis::emergency_stop() noexcept {
  impl_->estop_requested.store(true);
  drive_->emergency_stop();
  try {
    const std::lock_guard<std::mutex> lock(mutex_);
    AxisStatus& s = impl_->published;
    if (s.state != AxisState::fault) {
      s.state = AxisState::fault;
      s.fault = "emergency stop";
    }
    s.settled = false;
    impl_->published_target_reached = false;
    changed_.notify_all();
    if (impl_->listener) impl_->listener(s);
  } catch (...) {
    // The drive is stopped; the supervisor takes the flag over at its next step.
  }
}

void Axis::clear_fault() {
  const auto lock = lock_command("clear_fault");
  DriveStatus ds = read_drive_for_command();
  Impl& m = *impl_;
  if (m.state != AxisState::fault) return;
  if (ds.inputs.estop) refuse("clear_fault", "the e-stop input is still active");
  try {
    drive_->reset_alarm();
  } catch (const DriveError& e) {
    refuse("clear_fault", e.what());
  }
  ds = drive_->status();
  m.state = ds.enabled ? AxisState::idle : AxisState::disabled;
  m.fault.clear();
  m.target_reached = false;
  m.in_position_since.reset();
  publish(ds, Clock::now());
}

AxisStatus Axis::status() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return impl_->published;
}

bool Axis::wait_settled(std::chrono::milliseconds timeout) const {
  std::unique_lock<std::mutex> lock(mutex_);
  bool settled = false;
  changed_.wait_for(lock, timeout, [&] {
    const AxisStatus& s = impl_->published;
    if (s.settled) return settled = true;
    if (s.state == AxisState::fault || s.state == AxisState::disabled || s.state == AxisState::stopping) return true;
    // Idle without a target reached: stopped.
    return s.state == AxisState::idle && !impl_->published_target_reached;
  });
  return settled;
}

void Axis::set_status_listener(std::function<void(const AxisStatus&)> listener) {
  const std::lock_guard<std::mutex> lock(mutex_);
  impl_->listener = std::move(listener);
}

// --- The state machine (command_mutex held) ---

void Axis::begin_move(double target, const DriveStatus& ds) {
  Impl& m = *impl_;
  const double ups = settings_.units_per_step;
  m.target = target;
  m.target_steps = std::llround(target / ups);
  m.target_reached = false;
  m.in_position_since.reset();
  m.final_leg.reset();
  const std::int64_t from = ds.position_steps;
  const int approach = settings_.approach_direction;
  m.state = AxisState::moving;
  if (settings_.backlash > 0 && (m.target_steps - from) * approach < 0) {
    // Travelling against the approach direction: overshoot by the backlash
    // (within the soft limits), then come back from the approach side.
    const double overshoot =
        std::clamp(target - approach * settings_.backlash, settings_.min_position, settings_.max_position);
    m.final_leg = m.target_steps;
    start_leg(std::llround(overshoot / ups), from);
  } else {
    start_leg(m.target_steps, from);
  }
}

void Axis::start_leg(std::int64_t target_steps, std::int64_t from_steps) {
  Impl& m = *impl_;
  const double v = settings_.max_velocity / settings_.units_per_step;
  const double a = settings_.acceleration / settings_.units_per_step;
  const double distance = std::abs(static_cast<double>(target_steps - from_steps));
  const double planned_s = TrapezoidProfile(distance, v, a).duration();
  const auto now = Clock::now();
  m.leg_steps = target_steps;
  m.leg_started = now;
  m.leg_seen_busy = false;
  m.deadline = now + seconds(2 * planned_s) + kTimeoutMargin;
  drive_->start_move(target_steps, v, a);
}

void Axis::finish_move(const DriveStatus& ds, Clock::time_point now) {
  Impl& m = *impl_;
  const double ups = settings_.units_per_step;
  const double error = static_cast<double>(ds.position_steps - m.target_steps) * ups;
  if (settings_.retry_deadband > 0 && std::abs(error) > settings_.retry_deadband) {
    if (m.retries < settings_.max_retries) {
      ++m.retries;
      begin_move(m.target, ds);
      return;
    }
    enter_fault(fmt::format("did not reach {} {} after {} retries: at {} {} (retry deadband {} {})", m.target,
                            settings_.unit, m.retries, static_cast<double>(ds.position_steps) * ups, settings_.unit,
                            settings_.retry_deadband, settings_.unit),
                FaultAction::none);
    return;
  }
  m.state = AxisState::idle;
  m.target_reached = true;
  m.in_position_since = now;
}

void Axis::enter_fault(std::string cause, FaultAction action) {
  Impl& m = *impl_;
  m.state = AxisState::fault;
  // An emergency stop that came meanwhile is the cause of whatever failed
  // after it (a leg refused by a drive that is now off).
  m.fault = m.estop_requested.exchange(false) ? "emergency stop" : std::move(cause);
  m.final_leg.reset();
  m.target_reached = false;
  m.in_position_since.reset();
  if (action == FaultAction::disable) {
    drive_->emergency_stop();
  } else if (action == FaultAction::stop) {
    try {
      drive_->stop();
    } catch (const DriveError&) {
      drive_->emergency_stop();
    }
  }
}

void Axis::step() {
  Impl& m = *impl_;
  if (m.estop_requested.exchange(false) && m.state != AxisState::fault)
    enter_fault("emergency stop", FaultAction::none);
  const double ups = settings_.units_per_step;
  // One time for the whole step: an arrival is published with the time
  // settling counts from.
  const auto now = Clock::now();
  try {
    const DriveStatus ds = drive_->status();
    const bool at_target = in_position(settings_, ds.position_steps, m.target_steps);
    if (m.state == AxisState::fault) {
      // Latched until clear_fault().
    } else if (ds.inputs.estop) {
      enter_fault("e-stop input active", FaultAction::disable);
    } else if (ds.alarm) {
      enter_fault(fmt::format("drive alarm: {}", ds.alarm_cause.empty() ? "(no cause given)" : ds.alarm_cause),
                  FaultAction::disable);
    } else {
      if (ds.busy) m.leg_seen_busy = true;
      const bool ended = !ds.busy && (m.leg_seen_busy || now - m.leg_started >= kStartGrace);
      switch (m.state) {
        case AxisState::moving:
          if (ds.busy) {
            if (now > m.deadline) {
              enter_fault(fmt::format("did not reach position {} {} in time (at {} {} after {:.1f} s)", m.target,
                                      settings_.unit, static_cast<double>(ds.position_steps) * ups, settings_.unit,
                                      std::chrono::duration<double>(now - m.leg_started).count()),
                          FaultAction::stop);
            }
          } else if (ended || ds.position_steps == m.leg_steps) {
            if (m.final_leg) {
              const std::int64_t final_leg = *m.final_leg;
              m.final_leg.reset();
              start_leg(final_leg, ds.position_steps);
            } else {
              finish_move(ds, now);
            }
          }
          break;
        case AxisState::homing:
          if (ds.busy) {
            if (now > m.deadline) {
              enter_fault(fmt::format("homing did not finish within {:.1f} s",
                                      std::chrono::duration<double>(settings_.homing.timeout + kTimeoutMargin).count()),
                          FaultAction::stop);
            }
          } else if (ended || ds.homed) {
            if (!ds.homed) {
              enter_fault("homing ended without a position reference", FaultAction::none);
            } else {
              m.state = AxisState::idle;
              m.target = static_cast<double>(ds.position_steps) * ups;
              m.target_steps = ds.position_steps;
              m.target_reached = true;
              m.in_position_since = now;
            }
          }
          break;
        case AxisState::stopping:
          if (ended) m.state = AxisState::idle;
          break;
        case AxisState::idle:
          if (m.target_reached && at_target) {
            if (!m.in_position_since) m.in_position_since = now;
          } else {
            m.in_position_since.reset();
          }
          break;
        case AxisState::disabled:
        case AxisState::fault: break;
      }
    }
    m.last_drive_status = drive_->status();
  } catch (const std::exception& e) {
    // Whatever went wrong, the axis must not be left moving unsupervised.
    if (m.state != AxisState::fault) enter_fault(fmt::format("drive error: {}", e.what()), FaultAction::disable);
  }
  publish(m.last_drive_status, now);
}

void Axis::publish(const DriveStatus& ds, Clock::time_point now) {
  Impl& m = *impl_;
  const double ups = settings_.units_per_step;
  AxisStatus s;
  s.state = m.state;
  s.homed = ds.homed;
  s.position = static_cast<double>(ds.position_steps) * ups;
  s.target = m.target;
  s.inputs = ds.inputs;
  if (m.state == AxisState::fault) s.fault = m.fault;
  s.updated = now;
  s.settled = m.state == AxisState::idle && !ds.busy && m.target_reached &&
              in_position(settings_, ds.position_steps, m.target_steps) && m.in_position_since &&
              now - *m.in_position_since >= settings_.settle_time;

  const std::lock_guard<std::mutex> lock(mutex_);
  // emergency_stop() has published a fault the state machine has not taken
  // over yet: do not paint over it.
  if (m.estop_requested.load()) return;
  const bool changed = !same_status(s, m.published) || m.target_reached != m.published_target_reached;
  m.published = std::move(s);
  m.published_target_reached = m.target_reached;
  if (changed) {
    changed_.notify_all();
    if (m.listener) m.listener(m.published);
  }
}

void Axis::run(const std::stop_token& stop) {
  while (!stop.stop_requested()) {
    {
      // Bounded, so that a command stuck in its drive cannot keep the
      // supervisor (and the destructor's join) from seeing the stop request.
      std::unique_lock<std::timed_mutex> lock(impl_->command_mutex, std::defer_lock);
      if (!lock.try_lock_for(kCommandWait)) continue;
      try {
        step();
      } catch (...) {
        // step() handles drive errors itself; this is the last line (an
        // allocation failure, a throwing listener): stop the motor, keep
        // supervising.
        drive_->emergency_stop();
        impl_->state = AxisState::fault;
        impl_->fault = "internal error in the axis supervisor";
      }
    }
    std::unique_lock<std::mutex> lock(impl_->wake_mutex);
    impl_->wake.wait_for(lock, stop, kPollPeriod, [] { return false; });
  }
}

}  // namespace markerd::rig
