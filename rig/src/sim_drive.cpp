#include "markerd/rig/sim_drive.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <utility>

#include "markerd/rig/motion_profile.hpp"

namespace markerd::rig {

std::optional<std::string> check_sim_drive_settings(const SimDriveSettings& s) {
  if (s.name.empty()) return "name must not be empty";
  if (s.limit_min_steps >= s.limit_max_steps) {
    return fmt::format("limit_min ({}) must be below limit_max ({})", s.limit_min_steps, s.limit_max_steps);
  }
  if (s.start_position_steps <= s.limit_min_steps || s.start_position_steps >= s.limit_max_steps) {
    return fmt::format("the start position ({}) must lie between the limit switches ({} .. {})", s.start_position_steps,
                       s.limit_min_steps, s.limit_max_steps);
  }
  return std::nullopt;
}

namespace {

// What the motor is doing. The homing phases follow HomingSteps: search the
// switch fast, brake, back off it, approach it slowly, latch, brake.
enum class Phase { idle, move, brake, search, search_brake, backoff, latch, latch_brake };

bool is_homing(Phase p) { return p >= Phase::search; }

const char* switch_name(SimSwitch s) {
  switch (s) {
    case SimSwitch::limit_min: return "limit_min";
    case SimSwitch::limit_max: return "limit_max";
    case SimSwitch::home: return "home";
  }
  return "?";
}

SimSwitch sim_switch(HomingSteps::Switch s) {
  switch (s) {
    case HomingSteps::Switch::limit_min: return SimSwitch::limit_min;
    case HomingSteps::Switch::limit_max: return SimSwitch::limit_max;
    case HomingSteps::Switch::home: return SimSwitch::home;
  }
  return SimSwitch::home;
}

// A search or latch runs until the switch stops it (or the homing timeout).
constexpr double kOpenEnded = 1e12;

enum class EventKind { alarm, homing_timeout, stall, switch_reached, segment_end };

struct Event {
  double time = 0;
  EventKind kind = EventKind::segment_end;
  SimSwitch which = SimSwitch::home;
};

// The longest chain of events without a command in between: a pending alarm,
// then a homing's search, its switch, brake, backoff, latch, switch, brake;
// with room to spare.
constexpr int kMaxChainedEvents = 32;

}  // namespace

class SimDrive::Model {
 public:
  Model(const SimDriveSettings& s, const SimClock& clock)
      : settings_(s),
        clock_(clock),
        commanded_(static_cast<double>(s.start_position_steps)),
        // The step count starts at 0 where the motor stands.
        offset_(-static_cast<double>(s.start_position_steps)),
        limit_min_(static_cast<double>(s.limit_min_steps)),
        limit_max_(static_cast<double>(s.limit_max_steps)) {
    if (s.home_switch_steps) home_ = static_cast<double>(*s.home_switch_steps);
    t_ = clock_.now();
  }

  std::timed_mutex mutex;
  // Set by emergency_stop() from any thread without the mutex, taken over by
  // the next update(): an e-stop never waits behind another caller.
  std::atomic<bool> estop_requested{false};

  // Brings the state up to the clock's present, event by event. Every event
  // ends a motion or moves a homing to its next phase, and without a new
  // command there are at most kMaxChainedEvents of them before the motor is
  // idle; the loop is bounded by that count whatever the clock says, and a
  // count beyond it is a simulation bug that fails safe (alarm, output off).
  void update() {
    const double now = std::max(clock_.now(), t_);
    for (int handled = 0;; ++handled) {
      const std::optional<Event> e = next_event();
      if (!e || !(e->time <= now)) break;
      if (handled == kMaxChainedEvents) {
        raise_alarm(fmt::format("simulation: more than {} events at once (at {} s); stopped", kMaxChainedEvents, t_));
        break;
      }
      advance_to(e->time);
      handle(*e);
    }
    advance_to(now);
    if (estop_requested.exchange(false)) output_off();
  }

  void require_reply() const {
    if (comm_lost_) throw DriveError(fmt::format("{}: no reply (communication lost)", settings_.name));
  }

  void require_ready(std::string_view what) const {
    require_reply();
    if (alarm_)
      throw DriveError(
          fmt::format("{}: cannot {}: alarm active ({}); reset it first", settings_.name, what, alarm_cause_));
    if (estop_input_) throw DriveError(fmt::format("{}: cannot {}: the e-stop input is active", settings_.name, what));
    if (!enabled_) throw DriveError(fmt::format("{}: cannot {}: the drive is not enabled", settings_.name, what));
    if (phase_ != Phase::idle) throw DriveError(fmt::format("{}: cannot {}: the drive is busy", settings_.name, what));
  }

  void enable(bool on) {
    require_reply();
    if (!on) {
      output_off();
      return;
    }
    if (estop_input_) throw DriveError(fmt::format("{}: cannot enable: the e-stop input is active", settings_.name));
    if (alarm_)
      throw DriveError(
          fmt::format("{}: cannot enable: alarm active ({}); reset it first", settings_.name, alarm_cause_));
    enabled_ = true;
  }

  void start_move(std::int64_t target, double v, double a) {
    require_ready("start a move");
    if (!(std::isfinite(v) && v > 0 && std::isfinite(a) && a > 0)) {
      throw DriveError(
          fmt::format("{}: invalid move: velocity {} and acceleration {} must be > 0", settings_.name, v, a));
    }
    if (settings_.encoder) restart_from_actual();
    // The drive's own count: it knows nothing of steps an open-loop motor lost.
    const double goal = static_cast<double>(target) - offset_;
    start_segment(Phase::move, goal >= commanded_ ? +1 : -1, TrapezoidProfile(std::abs(goal - commanded_), v, a), a);
  }

  void start_homing(const HomingSteps& h) {
    require_ready("start homing");
    if ((h.direction != 1 && h.direction != -1) || !(h.search_steps_per_s > 0) || !(h.latch_steps_per_s > 0) ||
        !(h.accel_steps_per_s2 > 0) || h.backoff_steps < 0 || !(h.timeout_s > 0)) {
      throw DriveError(
          fmt::format("{}: invalid homing: direction must be +-1; search, latch velocity, acceleration and timeout > "
                      "0; backoff >= 0",
                      settings_.name));
    }
    const SimSwitch target = sim_switch(h.target);
    if (target == SimSwitch::home && !home_) {
      throw DriveError(fmt::format("{}: cannot home on the home switch: this drive has none", settings_.name));
    }
    if (settings_.encoder) restart_from_actual();
    homing_ = h;
    homing_target_ = target;
    homing_started_ = t_;
    homed_ = false;
    if (switch_active(target)) {
      start_backoff();
    } else {
      start_segment(Phase::search, h.direction,
                    TrapezoidProfile(kOpenEnded, h.search_steps_per_s, h.accel_steps_per_s2), h.accel_steps_per_s2);
    }
  }

  void stop() {
    require_reply();
    switch (phase_) {
      case Phase::move:
      case Phase::search:
      case Phase::backoff:
      case Phase::latch: brake(Phase::brake); break;
      // Already braking: a homing that was braking is abandoned, the ramp goes on.
      case Phase::search_brake:
      case Phase::latch_brake: phase_ = Phase::brake; break;
      case Phase::idle:
      case Phase::brake: break;
    }
  }

  void reset_alarm() {
    require_reply();
    if (estop_input_)
      throw DriveError(fmt::format("{}: cannot reset the alarm: the e-stop input is still active", settings_.name));
    alarm_ = false;
    alarm_cause_.clear();
  }

  [[nodiscard]] DriveStatus status() const {
    if (comm_lost_) return frozen_;
    DriveStatus s;
    s.position_steps = std::llround((settings_.encoder ? actual() : commanded_) + offset_);
    s.enabled = enabled_;
    s.busy = phase_ != Phase::idle;
    s.homed = homed_;
    s.alarm = alarm_;
    s.alarm_cause = alarm_cause_;
    s.inputs.limit_min = switch_active(SimSwitch::limit_min);
    s.inputs.limit_max = switch_active(SimSwitch::limit_max);
    s.inputs.home = home_ && switch_active(SimSwitch::home);
    s.inputs.estop = estop_input_;
    return s;
  }

  void set_communication_lost(bool lost) {
    if (lost && !comm_lost_) {
      frozen_ = status();
      frozen_.alarm = true;
      frozen_.alarm_cause = fmt::format("{}: no reply (communication lost)", settings_.name);
    }
    comm_lost_ = lost;
  }

  void set_estop_input(bool active) {
    estop_input_ = active;
    if (active) output_off();
  }

  void inject_stall_at(double x) {
    clear_stall();
    stall_at_ = x;
  }

  void clear_stall() {
    if (pinned_) slip_ = *stall_at_ - commanded_;
    pinned_ = false;
    stall_at_.reset();
  }

  void inject_switch_at(SimSwitch which, double x) {
    switch (which) {
      case SimSwitch::limit_min: limit_min_ = x; break;
      case SimSwitch::limit_max: limit_max_ = x; break;
      case SimSwitch::home: home_ = x; break;
    }
  }

  void inject_alarm_at(double t, std::string cause) { pending_alarm_ = {t, std::move(cause)}; }

  [[nodiscard]] double actual_reported() const { return actual() + offset_; }
  [[nodiscard]] double commanded_reported() const { return commanded_ + offset_; }

 private:
  [[nodiscard]] double actual() const { return pinned_ ? *stall_at_ : commanded_ + slip_; }

  [[nodiscard]] bool switch_active(SimSwitch which) const {
    const double x = actual();
    switch (which) {
      case SimSwitch::limit_min: return x <= limit_min_;
      case SimSwitch::limit_max: return x >= limit_max_;
      case SimSwitch::home:
        if (!home_) return false;
        return settings_.home_active_above ? x >= *home_ : x <= *home_;
    }
    return false;
  }

  // The direction of motion that makes a switch active.
  [[nodiscard]] int activating_direction(SimSwitch which) const {
    switch (which) {
      case SimSwitch::limit_min: return -1;
      case SimSwitch::limit_max: return +1;
      case SimSwitch::home: return settings_.home_active_above ? +1 : -1;
    }
    return 0;
  }

  [[nodiscard]] double switch_position(SimSwitch which) const {
    switch (which) {
      case SimSwitch::limit_min: return limit_min_;
      case SimSwitch::limit_max: return limit_max_;
      case SimSwitch::home: return home_.value_or(0.0);
    }
    return 0;
  }

  // A closed-loop drive plans from where the motor is, not from where it
  // was told to be.
  void restart_from_actual() {
    commanded_ = actual();
    slip_ = 0;
  }

  void start_segment(Phase phase, int dir, const TrapezoidProfile& profile, double accel) {
    phase_ = phase;
    seg_dir_ = dir;
    seg_profile_ = profile;
    seg_accel_ = accel;
    seg_t0_ = t_;
    seg_p0_ = commanded_;
  }

  void brake(Phase phase) {
    const double v = seg_profile_.velocity_at(t_ - seg_t0_);
    start_segment(phase, seg_dir_, TrapezoidProfile::braking(v, seg_accel_), seg_accel_);
  }

  void start_backoff() {
    // Off the switch's edge by the backoff, and by at least a step: the slow
    // latch must start with the switch released.
    const double backoff = static_cast<double>(std::max<std::int64_t>(homing_.backoff_steps, 1));
    const double goal = switch_position(homing_target_) - homing_.direction * backoff - slip_;
    start_segment(Phase::backoff, goal >= commanded_ ? +1 : -1,
                  TrapezoidProfile(std::abs(goal - commanded_), homing_.search_steps_per_s, homing_.accel_steps_per_s2),
                  homing_.accel_steps_per_s2);
  }

  // The output stage off, at once: no ramp. An open-loop motor is free to
  // turn now, so its position reference is gone.
  void output_off() {
    phase_ = Phase::idle;
    enabled_ = false;
    if (!settings_.encoder) homed_ = false;
  }

  void raise_alarm(std::string cause) {
    output_off();
    alarm_ = true;
    alarm_cause_ = std::move(cause);
  }

  void advance_to(double t) {
    if (phase_ != Phase::idle) commanded_ = seg_p0_ + seg_dir_ * seg_profile_.position_at(t - seg_t0_);
    t_ = t;
  }

  // When the motor's actual position reaches x in this segment (not before t_).
  [[nodiscard]] double reach_time(double x) const {
    const double need = (x - slip_ - seg_p0_) * seg_dir_;
    if (need < 0 || need > seg_profile_.distance()) return std::numeric_limits<double>::infinity();
    return std::max(t_, seg_t0_ + seg_profile_.time_at(need));
  }

  static void consider(std::optional<Event>& best, double time, EventKind kind, SimSwitch which = SimSwitch::home) {
    // Ties go to the event listed first: a switch at the target trips before
    // the move ends. A time that is not finite is no event.
    if (std::isfinite(time) && (!best || time < best->time)) best = Event{time, kind, which};
  }

  // The earliest thing that will happen, or nothing when the motor stands
  // and no alarm is pending.
  [[nodiscard]] std::optional<Event> next_event() const {
    std::optional<Event> best;
    if (pending_alarm_) consider(best, std::max(t_, pending_alarm_->first), EventKind::alarm);
    if (phase_ == Phase::idle) return best;
    if (is_homing(phase_)) consider(best, homing_started_ + homing_.timeout_s, EventKind::homing_timeout);
    if (!pinned_) {
      if (stall_at_ && (*stall_at_ - actual()) * seg_dir_ >= 0)
        consider(best, reach_time(*stall_at_), EventKind::stall);
      for (SimSwitch which : {SimSwitch::limit_min, SimSwitch::limit_max, SimSwitch::home}) {
        if (which == SimSwitch::home && !home_) continue;
        if (activating_direction(which) != seg_dir_) continue;
        // Only a search or a latch looks for the homing switch; the home
        // switch means nothing to any other motion.
        const bool homing_switch = is_homing(phase_) && which == homing_target_;
        if (homing_switch && phase_ != Phase::search && phase_ != Phase::latch) continue;
        if (which == SimSwitch::home && !homing_switch) continue;
        consider(best, switch_active(which) ? t_ : reach_time(switch_position(which)), EventKind::switch_reached,
                 which);
      }
    }
    consider(best, seg_t0_ + seg_profile_.duration(), EventKind::segment_end);
    return best;
  }

  [[nodiscard]] std::int64_t reported_step(double physical) const { return std::llround(physical + offset_); }

  void handle(const Event& e) {
    switch (e.kind) {
      case EventKind::alarm: {
        std::string cause = std::move(pending_alarm_->second);
        pending_alarm_.reset();
        raise_alarm(std::move(cause));
        return;
      }
      case EventKind::homing_timeout:
        raise_alarm(fmt::format("homing: the {} switch was not found within {} s", switch_name(homing_target_),
                                homing_.timeout_s));
        return;
      case EventKind::stall: pinned_ = true; return;
      case EventKind::switch_reached: on_switch(e.which); return;
      case EventKind::segment_end: on_segment_end(); return;
    }
  }

  void on_switch(SimSwitch which) {
    const double edge = switch_position(which);
    if (is_homing(phase_) && which == homing_target_) {
      if (phase_ == Phase::latch) {
        // The reference: the edge of the switch is home_position_steps.
        offset_ = static_cast<double>(homing_.home_position_steps) - edge;
        homed_ = true;
        brake(Phase::latch_brake);
      } else {
        brake(Phase::search_brake);
      }
      return;
    }
    // A limit switch stops the motor where it trips.
    commanded_ = edge - slip_;
    const std::string context =
        is_homing(phase_) ? fmt::format("homing: before the {} switch, ", switch_name(homing_target_)) : "";
    raise_alarm(fmt::format("{}{} tripped at step {}", context, switch_name(which), reported_step(edge)));
  }

  void on_segment_end() {
    switch (phase_) {
      case Phase::move:
      case Phase::brake:
      case Phase::latch_brake:
      case Phase::idle: phase_ = Phase::idle; return;
      case Phase::search_brake: start_backoff(); return;
      case Phase::backoff:
        if (switch_active(homing_target_)) {
          raise_alarm(fmt::format(
              "homing: the {} switch is still active after backing off to step {} (homing direction wrong?)",
              switch_name(homing_target_), reported_step(actual())));
          return;
        }
        start_segment(Phase::latch, homing_.direction,
                      TrapezoidProfile(kOpenEnded, homing_.latch_steps_per_s, homing_.accel_steps_per_s2),
                      homing_.accel_steps_per_s2);
        return;
      case Phase::search:
      case Phase::latch:
        raise_alarm(fmt::format("homing: the {} switch was not found", switch_name(homing_target_)));
        return;
    }
  }

  SimDriveSettings settings_;
  const SimClock& clock_;
  double t_ = 0;          // simulated time the state describes
  double commanded_ = 0;  // physical steps
  double slip_ = 0;       // actual - commanded, for a motor that lost steps
  double offset_ = 0;     // reported steps = physical steps + offset
  bool enabled_ = false;
  bool homed_ = false;
  bool alarm_ = false;
  std::string alarm_cause_;
  bool estop_input_ = false;
  bool comm_lost_ = false;
  DriveStatus frozen_;  // what a lost drive last answered

  double limit_min_ = 0, limit_max_ = 0;
  std::optional<double> home_;
  std::optional<double> stall_at_;
  bool pinned_ = false;  // the motor is jammed at stall_at_
  std::optional<std::pair<double, std::string>> pending_alarm_;

  Phase phase_ = Phase::idle;
  int seg_dir_ = 1;
  TrapezoidProfile seg_profile_;
  double seg_accel_ = 1;
  double seg_t0_ = 0;
  double seg_p0_ = 0;

  HomingSteps homing_;
  SimSwitch homing_target_ = SimSwitch::home;
  double homing_started_ = 0;
};

SimDrive::SimDrive(SimDriveSettings settings, std::shared_ptr<const SimClock> clock)
    : settings_(std::move(settings)), clock_(std::move(clock)) {
  if (!clock_) throw std::invalid_argument(fmt::format("{}: SimDrive needs a SimClock", settings_.name));
  if (auto problem = check_sim_drive_settings(settings_)) {
    throw std::invalid_argument(fmt::format("{}: {}", settings_.name, *problem));
  }
  model_ = std::make_unique<Model>(settings_, *clock_);
}

SimDrive::~SimDrive() = default;

// Every entry point brings the model to the present first, so that a command
// acts on the motor where it is now.
namespace {
template <class Model, class F>
decltype(auto) locked(Model& model, F&& f) {
  const std::lock_guard<std::timed_mutex> lock(model.mutex);
  model.update();
  return std::forward<F>(f)(model);
}
}  // namespace

void SimDrive::enable(bool on) {
  locked(*model_, [&](Model& m) { m.enable(on); });
}

void SimDrive::start_move(std::int64_t target_steps, double max_steps_per_s, double accel_steps_per_s2) {
  locked(*model_, [&](Model& m) { m.start_move(target_steps, max_steps_per_s, accel_steps_per_s2); });
}

void SimDrive::start_homing(const HomingSteps& homing) {
  locked(*model_, [&](Model& m) { m.start_homing(homing); });
}

void SimDrive::stop() {
  locked(*model_, [](Model& m) { m.stop(); });
}

void SimDrive::reset_alarm() {
  locked(*model_, [](Model& m) { m.reset_alarm(); });
}

void SimDrive::emergency_stop() noexcept {
  // The flag first: whoever holds the model applies it at its next update,
  // so the e-stop acts even when the lock cannot be had at once.
  model_->estop_requested.store(true);
  try {
    std::unique_lock<std::timed_mutex> lock(model_->mutex, std::defer_lock);
    if (lock.try_lock_for(std::chrono::milliseconds(100))) model_->update();
  } catch (...) {
    // Only the mutex can throw here (std::system_error); the flag stays set.
  }
}

DriveStatus SimDrive::status() const {
  return locked(*model_, [](Model& m) { return m.status(); });
}

void SimDrive::inject_stall_at(std::int64_t physical_steps) {
  locked(*model_, [&](Model& m) { m.inject_stall_at(static_cast<double>(physical_steps)); });
}

void SimDrive::clear_stall() {
  locked(*model_, [](Model& m) { m.clear_stall(); });
}

void SimDrive::inject_switch_at(SimSwitch which, std::int64_t physical_steps) {
  locked(*model_, [&](Model& m) { m.inject_switch_at(which, static_cast<double>(physical_steps)); });
}

void SimDrive::inject_alarm_at(double sim_seconds, std::string cause) {
  locked(*model_, [&](Model& m) { m.inject_alarm_at(sim_seconds, std::move(cause)); });
}

void SimDrive::set_communication_lost(bool lost) {
  locked(*model_, [&](Model& m) { m.set_communication_lost(lost); });
}

void SimDrive::set_estop_input(bool active) {
  locked(*model_, [&](Model& m) { m.set_estop_input(active); });
}

double SimDrive::actual_position_steps() const {
  return locked(*model_, [](Model& m) { return m.actual_reported(); });
}

double SimDrive::commanded_position_steps() const {
  return locked(*model_, [](Model& m) { return m.commanded_reported(); });
}

}  // namespace markerd::rig
