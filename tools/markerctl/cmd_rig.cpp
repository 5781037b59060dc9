// markerctl rig: bring-up of a rig without the daemon. Loads the rig config,
// locks its devices against every other process (markerd, another
// markerctl), builds the rig and runs one command: status, home, move, or
// jog (relative moves, or an interactive jog on a terminal). Without
// --config the same commands (and stop) go to a running markerd over its
// control socket instead (cmd_daemon.cpp).
//
// Fail safe: whatever way the command ends, the axes end disabled. An
// interrupt (SIGINT, SIGTERM, SIGHUP, SIGQUIT) stops the motion with a
// controlled ramp, then disables; a second one, or any error, stops it at
// once (emergency stop). The signals are blocked in every thread and read
// from a signalfd by the command's own wait loop, so that the stop runs on
// the main thread with the full rig at hand, not in a signal handler.

#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <termios.h>
#include <unistd.h>

#include <fmt/format.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <numbers>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "cmd_daemon.hpp"
#include "common.hpp"
#include "markerd/base/errno_text.hpp"
#include "markerd/base/unique_fd.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/rig_config.hpp"

namespace markerctl {
namespace {

using markerd::rig::Axis;
using markerd::rig::AxisError;
using markerd::rig::AxisSettings;
using markerd::rig::AxisState;
using markerd::rig::AxisStatus;
using Clock = std::chrono::steady_clock;
using markerd::errno_text;
using markerd::UniqueFd;
using namespace std::chrono_literals;

// ---------------------------------------------------------------- quantities

// Units a value may carry, scaled to the quantity's base unit (mm, deg).
struct UnitScale {
  std::string_view name;
  double scale;
};
constexpr std::array<UnitScale, 3> kLengthUnits{{{"mm", 1.0}, {"cm", 10.0}, {"m", 1000.0}}};
constexpr std::array<UnitScale, 2> kAngleUnits{{{"deg", 1.0}, {"rad", 180.0 / std::numbers::pi}}};

struct AxisKind {
  const char* name;                   // "rail", "turntable": the config's axis
  const char* option;                 // "--rail"
  std::span<const UnitScale> units;
  const char* examples;
};
constexpr AxisKind kRail{"rail", "--rail", kLengthUnits, "250mm, 25cm, 0.25m"};
constexpr AxisKind kTurntable{"turntable", "--turntable", kAngleUnits, "30deg, 0.5rad"};

std::string unit_list(std::span<const UnitScale> units) {
  std::string list;
  for (std::size_t i = 0; i < units.size(); ++i) {
    if (i > 0) list += i + 1 == units.size() ? " or " : ", ";
    list += units[i].name;
  }
  return list;
}

std::optional<double> scale_of(std::span<const UnitScale> units, std::string_view unit) {
  for (const auto& u : units) {
    if (u.name == unit) return u.scale;
  }
  return std::nullopt;
}

// A value with its unit, in the axis kind's base unit (mm, deg). A bare
// number is refused: "250" means millimetres to one person and metres to
// the next, and a rail moved by the wrong factor hits its end.
double parse_quantity(std::string_view text, const AxisKind& kind) {
  const auto parsed = split_number(text);
  if (!parsed) {
    throw usage_error(kind.option, fmt::format("'{}' is not a value with a unit (examples: {})", text, kind.examples));
  }
  if (parsed->unit.empty()) {
    throw usage_error(kind.option, fmt::format("'{}' needs a unit: {} (examples: {})", text, unit_list(kind.units),
                                               kind.examples));
  }
  const auto scale = scale_of(kind.units, parsed->unit);
  if (!scale) {
    throw usage_error(kind.option, fmt::format("'{}': unknown unit '{}' for the {} (use {})", text, parsed->unit,
                                               kind.name, unit_list(kind.units)));
  }
  return parsed->value * *scale;
}

// A base-unit value in the axis's own unit (its config's `unit`).
double to_axis_units(double base_value, const AxisKind& kind, const AxisSettings& axis, const std::string& context) {
  const auto scale = scale_of(kind.units, axis.unit);
  if (!scale) {
    throw runtime_error(context, fmt::format("the {}'s unit in the config is '{}'; markerctl rig converts to {} only",
                                             kind.name, axis.unit, unit_list(kind.units)));
  }
  return base_value / *scale;
}

// ---------------------------------------------------------------- signals

// SIGINT, SIGTERM, SIGHUP and SIGQUIT, blocked in this thread and in every
// thread started after it (the rig's), and read from a signalfd. They stay
// blocked until the process ends: a late one must not kill it half way
// through disabling the axes. SIGINT, SIGHUP and SIGQUIT stay ignored when
// the process was started with them ignored (a background job of a shell,
// nohup), as every Unix command does; SIGTERM is always taken.
class SignalWatch {
 public:
  SignalWatch() {
    sigemptyset(&set_);
    for (const int s : {SIGINT, SIGTERM, SIGHUP, SIGQUIT}) {
      struct sigaction current {};
      sigaction(s, nullptr, &current);
      if (s != SIGTERM && current.sa_handler == SIG_IGN) continue;
      // An ignored signal would be discarded even while blocked.
      if (current.sa_handler == SIG_IGN) ::signal(s, SIG_DFL);
      sigaddset(&set_, s);
    }
    if (const int error = pthread_sigmask(SIG_BLOCK, &set_, nullptr); error != 0) {
      throw std::runtime_error(fmt::format("cannot block the interrupt signals: {}", errno_text(error)));
    }
    fd_.reset(signalfd(-1, &set_, SFD_CLOEXEC | SFD_NONBLOCK));
    if (!fd_) throw std::runtime_error(fmt::format("signalfd: {}", errno_text(errno)));
  }
  SignalWatch(const SignalWatch&) = delete;
  SignalWatch& operator=(const SignalWatch&) = delete;

  struct Wake {
    int signal = 0;      // the signal received, or 0
    bool input = false;  // `input_fd` is readable
  };
  // Sleeps up to `timeout`, waking early for a signal or input.
  Wake wait(std::chrono::milliseconds timeout, int input_fd = -1) const {
    std::array<pollfd, 2> fds{{{fd_.get(), POLLIN, 0}, {input_fd, POLLIN, 0}}};
    const nfds_t count = input_fd >= 0 ? 2 : 1;
    Wake wake;
    if (::poll(fds.data(), count, static_cast<int>(timeout.count())) <= 0) return wake;
    if ((fds[0].revents & POLLIN) != 0) {
      signalfd_siginfo info{};
      if (::read(fd_.get(), &info, sizeof info) == static_cast<ssize_t>(sizeof info)) {
        wake.signal = static_cast<int>(info.ssi_signo);
      }
    }
    wake.input = count == 2 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR)) != 0;
    return wake;
  }

 private:
  sigset_t set_{};
  UniqueFd fd_;
};

std::string signal_name(int signal) {
  const char* abbrev = sigabbrev_np(signal);
  return abbrev != nullptr ? fmt::format("SIG{}", abbrev) : fmt::format("signal {}", signal);
}

// ---------------------------------------------------------------- formatting

bool in_motion(AxisState state) {
  return state == AxisState::moving || state == AxisState::homing || state == AxisState::stopping;
}

std::string position_text(const AxisSettings& axis, double value) { return fmt::format("{:.3f} {}", value, axis.unit); }

std::string inputs_text(const markerd::rig::DriveInputs& in) {
  std::string text;
  const std::pair<bool, const char*> inputs[] = {
      {in.limit_min, "limit_min"}, {in.limit_max, "limit_max"}, {in.home, "home"}, {in.estop, "estop"}};
  for (const auto& [active, name] : inputs) {
    if (!active) continue;
    if (!text.empty()) text += ' ';
    text += name;
  }
  return text.empty() ? "none active" : text + " active";
}

nlohmann::ordered_json axis_json(const AxisSettings& settings, const AxisStatus& s) {
  nlohmann::ordered_json j;
  j["state"] = markerd::rig::to_string(s.state);
  j["homed"] = s.homed;
  j["settled"] = s.settled;
  j["position"] = rounded(s.position, 6);
  j["target"] = rounded(s.target, 6);
  j["unit"] = settings.unit;
  j["inputs"] = {{"limit_min", s.inputs.limit_min},
                 {"limit_max", s.inputs.limit_max},
                 {"home", s.inputs.home},
                 {"estop", s.inputs.estop}};
  j["fault"] = s.state == AxisState::fault ? nlohmann::ordered_json(s.fault) : nlohmann::ordered_json(nullptr);
  return j;
}

// ---------------------------------------------------------------- the session

// One command's hold on the rig: the signal watch, the config, the device
// lock and the rig, in that order (the lock is released only after the rig
// has released the devices).
class Session {
 public:
  Session(const std::string& config_path, std::string context) : context_(std::move(context)) {
    try {
      config_ = markerd::rig::load_rig_config(config_path);
    } catch (const markerd::ConfigError& e) {
      throw runtime_error(context_, e.what());
    }
    try {
      lock_.emplace(markerd::rig::lock_rig_devices(config_));
    } catch (const markerd::rig::DeviceLockError& e) {
      throw runtime_error(context_, e.what());
    }
    try {
      rig_ = markerd::rig::make_rig(config_);
    } catch (const std::exception& e) {
      throw runtime_error(context_, fmt::format("cannot start the rig: {}", e.what()));
    }
    // The axes' first statuses come from the drives as constructed; wait for
    // their supervisors to have looked once (a drive alarm becomes a fault).
    const auto started = Clock::now();
    const auto looked = [&](const Axis& a) { return a.status().updated > started; };
    while (!(looked(rig_->rail()) && looked(rig_->turntable())) && Clock::now() - started < 2s) {
      if (const int s = signals_.wait(5ms).signal) interrupted(s);
    }
  }

  // Fail safe on every way out: axes in motion are emergency-stopped (a
  // normal exit has waited for them; this is an error's way out), the others
  // disabled.
  ~Session() {
    if (!rig_) return;
    for (Axis* axis : axes()) {
      const AxisStatus s = axis->status();
      if (in_motion(s.state)) {
        axis->emergency_stop();
      } else if (s.state == AxisState::idle) {
        try {
          axis->disable();
        } catch (const std::exception&) {
          axis->emergency_stop();
        }
      }
    }
    rig_.reset();
  }
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  [[nodiscard]] const std::string& context() const { return context_; }
  [[nodiscard]] const markerd::rig::RigConfig& config() const { return config_; }
  [[nodiscard]] markerd::rig::Rig& rig() { return *rig_; }
  [[nodiscard]] const SignalWatch& signals() const { return signals_; }
  [[nodiscard]] Axis& axis(const AxisKind& kind) { return &kind == &kRail ? rig_->rail() : rig_->turntable(); }
  [[nodiscard]] std::array<Axis*, 2> axes() { return {&rig_->rail(), &rig_->turntable()}; }

  // An axis ready to take a command: enabled, and, for a homing, out of
  // fault (homing is how an axis recovers its reference after one).
  void prepare(Axis& axis, bool for_homing) {
    const AxisStatus s = axis.status();
    if (s.state == AxisState::fault) {
      if (!for_homing) {
        throw runtime_error(context_, fmt::format("{} is in fault ({}); home it (--home) to clear the fault",
                                                  axis.settings().name, s.fault));
      }
      std::cout << fmt::format("{}: clearing the fault ({})\n", axis.settings().name, s.fault) << std::flush;
      axis.clear_fault();
    }
    if (axis.status().state == AxisState::disabled) axis.enable();
  }

  // Homes one axis and waits for it.
  void home(Axis& axis) {
    prepare(axis, true);
    std::cout << fmt::format("{}: homing\n", axis.settings().name) << std::flush;
    axis.home();
    follow({&axis}, "homing");
    const AxisStatus s = axis.status();
    std::cout << fmt::format("{}: homed at {}\n", axis.settings().name, position_text(axis.settings(), s.position))
              << std::flush;
  }

  // Waits until every axis in `axes` has settled, printing its progress
  // every second. A fault ends the wait with an error naming the axis and the
  // cause; a signal with a controlled stop (interrupted()).
  void follow(const std::vector<Axis*>& moving, std::string_view doing) {
    auto next_progress = Clock::now() + 1s;
    std::vector<std::optional<Clock::time_point>> idle_since(moving.size());
    for (;;) {
      bool all_settled = true;
      for (std::size_t i = 0; i < moving.size(); ++i) {
        const Axis& axis = *moving[i];
        const AxisSettings& settings = axis.settings();
        const AxisStatus s = axis.status();
        if (s.state == AxisState::fault) {
          throw runtime_error(context_, fmt::format("{}: {} failed: {}", settings.name, doing, s.fault));
        }
        if (s.state == AxisState::disabled) {
          throw runtime_error(context_, fmt::format("{}: disabled while {}", settings.name, doing));
        }
        if (s.settled) continue;
        all_settled = false;
        // Idle but not settled: in position and settling, or (a closed-loop
        // drive) drifting outside its deadband; the second must not hang.
        if (s.state != AxisState::idle) {
          idle_since[i].reset();
        } else if (!idle_since[i]) {
          idle_since[i] = Clock::now();
        } else if (Clock::now() - *idle_since[i] > settings.settle_time + 10s) {
          throw runtime_error(context_, fmt::format("{}: did not settle at {} (at {})", settings.name,
                                                    position_text(settings, s.target),
                                                    position_text(settings, s.position)));
        }
      }
      if (all_settled) return;
      if (Clock::now() >= next_progress) {
        next_progress += 1s;
        for (const Axis* axis : moving) {
          const AxisStatus s = axis->status();
          if (s.settled) continue;
          const char* state = s.state == AxisState::idle ? "settling" : markerd::rig::to_string(s.state);
          std::cout << fmt::format("{}: {}, at {}\n", axis->settings().name, state,
                                   position_text(axis->settings(), s.position))
                    << std::flush;
        }
      }
      if (const int signal = signals_.wait(20ms).signal) interrupted(signal);
    }
  }

  // The controlled way out of a motion: stop with a ramp, wait for rest (a
  // second signal, or a stop that does not end, turns it into an emergency
  // stop), disable, and fail the command.
  [[noreturn]] void interrupted(int signal) {
    std::cout << std::flush;
    std::cerr << fmt::format("markerctl: {}: {}: stopping the axes\n", context_, signal_name(signal)) << std::flush;
    bool emergency = false;
    for (Axis* axis : axes()) {
      if (!in_motion(axis->status().state)) continue;
      try {
        axis->stop();
      } catch (const std::exception&) {
        axis->emergency_stop();
      }
    }
    // Braking takes max_velocity / acceleration; a drive that does not come
    // to rest in far more than that is not to be waited for.
    auto longest_brake = 0s;
    for (Axis* axis : axes()) {
      const auto& s = axis->settings();
      longest_brake = std::max(longest_brake, std::chrono::seconds(static_cast<int>(s.max_velocity / s.acceleration) + 1));
    }
    const auto deadline = Clock::now() + 2 * longest_brake + 3s;
    const auto all = axes();
    while (std::any_of(all.begin(), all.end(), [](Axis* a) { return in_motion(a->status().state); })) {
      const int again = signals_.wait(20ms).signal;
      if (again != 0 || Clock::now() > deadline) {
        emergency = true;
        for (Axis* axis : axes()) axis->emergency_stop();
        break;
      }
    }
    for (Axis* axis : axes()) {
      if (axis->status().state != AxisState::idle) continue;
      try {
        axis->disable();
      } catch (const std::exception&) {
        axis->emergency_stop();
      }
    }
    throw runtime_error(context_, fmt::format("interrupted by {}: {}, axes disabled ({})", signal_name(signal),
                                              emergency ? "emergency stop" : "stopped", positions()));
  }

  // "rail at 250.000 mm, turntable at 30.000 deg"
  [[nodiscard]] std::string positions() {
    std::string text;
    for (Axis* axis : axes()) {
      if (!text.empty()) text += ", ";
      text += fmt::format("{} at {}", axis->settings().name, position_text(axis->settings(), axis->status().position));
    }
    return text;
  }

  void print_ground_truth() {
    const auto truth = markerd::rig::ground_truth(rig_->geometry(), rig_->rail().status().position,
                                                  rig_->turntable().status().position);
    std::cout << fmt::format("ground truth: distance {:.4f} m, yaw {:.3f} deg\n", truth.distance_m, truth.yaw_deg);
  }

 private:
  SignalWatch signals_;  // first: blocks the signals before the rig starts its threads
  std::string context_;
  markerd::rig::RigConfig config_;
  std::optional<markerd::rig::DeviceLock> lock_;
  std::unique_ptr<markerd::rig::Rig> rig_;
};

// ---------------------------------------------------------------- status

struct RigOptions {
  std::string config;
  bool json = false;
  std::string home_axis;  // home: "", "rail" or "turntable"
  std::string rail;       // move, jog
  std::string turntable;
  bool home = false;      // move, jog: home what is not homed first
  // markerd's rig (no --config):
  std::string socket;
  bool emergency = false;  // stop
  bool no_wait = false;    // home, move, jog, stop: return once the daemon has started it
};

int run_status(const RigOptions& o, const std::string& context) {
  Session session(o.config, context);
  auto& rig = session.rig();
  const AxisStatus rail = rig.rail().status();
  const AxisStatus turntable = rig.turntable().status();
  const auto truth = markerd::rig::ground_truth(rig.geometry(), rail.position, turntable.position);
  if (o.json) {
    nlohmann::ordered_json j;
    j["config"] = o.config;
    j["rail"] = axis_json(rig.rail().settings(), rail);
    j["turntable"] = axis_json(rig.turntable().settings(), turntable);
    const Eigen::Quaterniond q(truth.rotation);
    j["ground_truth"] = {
        {"distance_m", rounded(truth.distance_m, 9)},
        {"yaw_deg", rounded(truth.yaw_deg, 9)},
        {"tvec", {rounded(truth.translation.x(), 9), rounded(truth.translation.y(), 9), rounded(truth.translation.z(), 9)}},
        {"quaternion", {rounded(q.w(), 9), rounded(q.x(), 9), rounded(q.y(), 9), rounded(q.z(), 9)}}};
    std::cout << json_line(j) << '\n';
    return 0;
  }
  for (const Axis* axis : {&rig.rail(), &rig.turntable()}) {
    const AxisSettings& settings = axis->settings();
    const AxisStatus s = axis->status();
    std::cout << fmt::format("{:<10} {}, {}{}: position {}, target {}; inputs: {}\n", settings.name,
                             markerd::rig::to_string(s.state), s.homed ? "homed" : "not homed",
                             s.settled ? ", settled" : "", position_text(settings, s.position),
                             position_text(settings, s.target), inputs_text(s.inputs));
    if (s.state == AxisState::fault) std::cout << fmt::format("{:<10} fault: {}\n", "", s.fault);
  }
  std::cout << fmt::format("ground truth: distance {:.4f} m, yaw {:.3f} deg\n", truth.distance_m, truth.yaw_deg);
  return 0;
}

// ---------------------------------------------------------------- home

int run_home(const RigOptions& o, const std::string& context) {
  std::vector<const AxisKind*> kinds;
  if (o.home_axis.empty() || o.home_axis == "rail") kinds.push_back(&kRail);
  if (o.home_axis.empty() || o.home_axis == "turntable") kinds.push_back(&kTurntable);
  Session session(o.config, context);
  for (const AxisKind* kind : kinds) session.home(session.axis(*kind));
  session.print_ground_truth();
  return 0;
}

// ---------------------------------------------------------------- move, jog

// One axis's part of a move or jog: the value as given, in the axis's base unit.
struct Request {
  const AxisKind* kind;
  double base_value;
};

std::vector<Request> requests_of(const RigOptions& o) {
  std::vector<Request> requests;
  if (!o.rail.empty()) requests.push_back({&kRail, parse_quantity(o.rail, kRail)});
  if (!o.turntable.empty()) requests.push_back({&kTurntable, parse_quantity(o.turntable, kTurntable)});
  return requests;
}

void check_soft_limits(const Session& session, const AxisSettings& axis, double target, std::string_view what) {
  if (target < axis.min_position || target > axis.max_position) {
    throw runtime_error(session.context(), fmt::format("{}: {} to {} refused: outside the soft limits [{}, {}] {}",
                                                       axis.name, what, position_text(axis, target), axis.min_position,
                                                       axis.max_position, axis.unit));
  }
}

// Absolute (move) or relative (jog) moves of the requested axes, together.
int run_motion(const RigOptions& o, const std::vector<Request>& requests, bool relative, const std::string& context) {
  Session session(o.config, context);
  // Everything is checked before anything moves.
  std::vector<double> values;
  for (const Request& r : requests) {
    Axis& axis = session.axis(*r.kind);
    const AxisSettings& settings = axis.settings();
    values.push_back(to_axis_units(r.base_value, *r.kind, settings, context));
    if (!relative) check_soft_limits(session, settings, values.back(), "move");
    const AxisStatus s = axis.status();
    if (!o.home && !s.homed) {
      throw runtime_error(context, fmt::format("{} is not homed: home it first, or pass --home to home it before the "
                                               "{} (a new process starts unhomed: an open-loop stepper loses its "
                                               "reference when the process that homed it ends)",
                                               settings.name, relative ? "jog" : "move"));
    }
    if (!o.home && s.state == AxisState::fault) {
      throw runtime_error(context, fmt::format("{} is in fault ({}); pass --home to clear it and home again",
                                               settings.name, s.fault));
    }
  }
  for (const Request& r : requests) {
    Axis& axis = session.axis(*r.kind);
    const AxisStatus s = axis.status();
    if (!s.homed || s.state == AxisState::fault) session.home(axis);
  }
  std::vector<Axis*> moving;
  for (std::size_t i = 0; i < requests.size(); ++i) {
    Axis& axis = session.axis(*requests[i].kind);
    session.prepare(axis, false);
    double target = values[i];
    if (relative) {
      target += axis.status().position;
      check_soft_limits(session, axis.settings(), target,
                        fmt::format("jog by {:+g} {}", values[i], axis.settings().unit));
    }
    try {
      axis.move_to(target);
    } catch (const AxisError& e) {
      throw runtime_error(context, e.what());
    }
    std::cout << fmt::format("{}: moving to {}\n", axis.settings().name, position_text(axis.settings(), target))
              << std::flush;
    moving.push_back(&axis);
  }
  session.follow(moving, relative ? "jog" : "move");
  for (const Axis* axis : moving) {
    std::cout << fmt::format("{}: at {}\n", axis->settings().name,
                             position_text(axis->settings(), axis->status().position));
  }
  session.print_ground_truth();
  return 0;
}

// ---------------------------------------------------------------- markerd's rig

// The command for a running markerd: values keep their units until the
// daemon says which unit its axis counts in.
int run_on_daemon(const RigOptions& o, DaemonRigRequest::Action action, bool relative, const std::string& context,
                  const SignalWatch* signals) {
  DaemonRigRequest request;
  request.action = action;
  request.context = context;
  request.socket = o.socket;
  request.json = o.json;
  request.home_axis = o.home_axis;
  request.relative = relative;
  request.home_first = o.home;
  request.emergency = o.emergency;
  request.wait = !o.no_wait;
  for (const Request& r : requests_of(o)) {
    const AxisKind* kind = r.kind;
    const double base_value = r.base_value;
    request.targets.push_back({kind->name, [kind, base_value, context](const std::string& unit) {
                                 const auto scale = scale_of(kind->units, unit);
                                 if (!scale) {
                                   throw runtime_error(context, fmt::format("markerd's {} counts in '{}'; markerctl "
                                                                            "rig converts to {} only",
                                                                            kind->name, unit, unit_list(kind->units)));
                                 }
                                 return base_value / *scale;
                               }});
  }
  if (signals != nullptr) {
    request.wait_for_signal = [signals](std::chrono::milliseconds timeout) { return signals->wait(timeout).signal; };
  }
  return run_rig_on_daemon(request);
}

// ---------------------------------------------------------------- interactive jog

// The terminal in raw mode (no echo, no line editing, keys as they come, no
// signals from ^C: it arrives as a key), restored when this ends, including
// by an exception. Crashes (SIGSEGV, SIGABRT, ...) restore it from their
// signal handler before the default action; the interrupt signals end the
// jog loop through the SignalWatch, and the destructor restores it.
class RawTerminal {
 public:
  explicit RawTerminal(int fd) : fd_(fd) {
    if (tcgetattr(fd_, &saved_) != 0) throw std::runtime_error(fmt::format("tcgetattr: {}", errno_text(errno)));
    crash_fd_ = fd_;
    crash_saved_ = saved_;
    crash_armed_ = 1;
    struct sigaction action {};
    action.sa_handler = &RawTerminal::on_crash;
    sigemptyset(&action.sa_mask);
    action.sa_flags = SA_RESETHAND;
    for (std::size_t i = 0; i < kCrashSignals.size(); ++i) sigaction(kCrashSignals[i], &action, &previous_[i]);
    termios raw = saved_;
    raw.c_lflag &= ~static_cast<tcflag_t>(ICANON | ECHO | ISIG | IEXTEN);
    raw.c_iflag &= ~static_cast<tcflag_t>(IXON | ICRNL);
    raw.c_cc[VMIN] = 0;
    raw.c_cc[VTIME] = 0;
    if (tcsetattr(fd_, TCSANOW, &raw) != 0) {
      const int error = errno;
      restore();
      throw std::runtime_error(fmt::format("tcsetattr: {}", errno_text(error)));
    }
  }
  ~RawTerminal() { restore(); }
  RawTerminal(const RawTerminal&) = delete;
  RawTerminal& operator=(const RawTerminal&) = delete;

 private:
  static constexpr std::array<int, 5> kCrashSignals{SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT};

  void restore() {
    crash_armed_ = 0;
    tcsetattr(fd_, TCSANOW, &saved_);
    for (std::size_t i = 0; i < kCrashSignals.size(); ++i) sigaction(kCrashSignals[i], &previous_[i], nullptr);
  }

  // Async-signal-safe: tcsetattr, then the default action (SA_RESETHAND).
  static void on_crash(int signal) {
    if (crash_armed_ != 0) tcsetattr(crash_fd_, TCSANOW, &crash_saved_);
    raise(signal);
  }

  int fd_;
  termios saved_{};
  std::array<struct sigaction, kCrashSignals.size()> previous_{};
  static inline volatile sig_atomic_t crash_armed_ = 0;
  static inline int crash_fd_ = -1;
  static inline termios crash_saved_{};
};

enum class Key { none, rail_up, rail_down, turntable_up, turntable_down, bigger, smaller, home, stop, estop, quit, interrupt };

// Keys from the bytes read so far; an incomplete escape sequence stays in `pending`.
std::vector<Key> take_keys(std::string& pending) {
  std::vector<Key> keys;
  std::size_t i = 0;
  while (i < pending.size()) {
    const char c = pending[i];
    if (c == '\x1b') {
      if (i + 2 >= pending.size()) break;  // wait for the rest
      if (pending[i + 1] == '[' || pending[i + 1] == 'O') {
        switch (pending[i + 2]) {
          case 'A': keys.push_back(Key::turntable_up); break;
          case 'B': keys.push_back(Key::turntable_down); break;
          case 'C': keys.push_back(Key::rail_up); break;
          case 'D': keys.push_back(Key::rail_down); break;
          default: break;
        }
        i += 3;
      } else {
        i += 1;  // a lone escape
      }
      continue;
    }
    switch (c) {
      case '+': case '=': keys.push_back(Key::bigger); break;
      case '-': case '_': keys.push_back(Key::smaller); break;
      case 'h': case 'H': keys.push_back(Key::home); break;
      case 's': case 'S': keys.push_back(Key::stop); break;
      case ' ': keys.push_back(Key::estop); break;
      case 'q': case 'Q': case '\x04': keys.push_back(Key::quit); break;
      case '\x03': case '\x1c': keys.push_back(Key::interrupt); break;
      default: break;
    }
    ++i;
  }
  pending.erase(0, i);
  return keys;
}

// Step sizes, from fine to coarse: rail (mm) and turntable (deg) together.
constexpr std::array<std::pair<double, double>, 7> kJogSteps{
    {{0.1, 0.05}, {0.5, 0.1}, {1, 0.5}, {5, 1}, {10, 5}, {50, 10}, {100, 30}}};
constexpr std::size_t kInitialJogStep = 3;

class InteractiveJog {
 public:
  explicit InteractiveJog(Session& session) : session_(session) {}

  int run() {
    RawTerminal terminal(STDIN_FILENO);
    std::cout << "markerctl rig jog: left/right arrows jog the rail, up/down the turntable; + and - change the step;\n"
                 "h homes both axes; s stops; space is an EMERGENCY STOP; q quits (the axes are then disabled).\n"
              << std::flush;
    std::string pending;
    std::string shown;
    auto next_redraw = Clock::now();
    for (;;) {
      const auto wake = session_.signals().wait(50ms, STDIN_FILENO);
      if (wake.signal != 0) {
        end_line();
        session_.interrupted(wake.signal);
      }
      if (wake.input) {
        char buffer[64];
        const ssize_t n = ::read(STDIN_FILENO, buffer, sizeof buffer);
        if (n == 0) return quit();  // the terminal is gone
        if (n > 0) pending.append(buffer, static_cast<std::size_t>(n));
        for (const Key key : take_keys(pending)) {
          if (key == Key::quit) return quit();
          if (key == Key::interrupt) {
            end_line();
            session_.interrupted(SIGINT);
          }
          handle(key);
        }
      }
      advance();
      const std::string line = status_line();
      if (line != shown || Clock::now() >= next_redraw) {
        std::cout << "\r\x1b[K" << line << std::flush;
        shown = line;
        next_redraw = Clock::now() + 1s;
      }
    }
  }

 private:
  struct Jog {
    std::optional<double> goal;  // the target still to be commanded
  };

  Axis& axis(std::size_t i) { return *session_.axes()[i]; }

  void message(const std::string& text) { std::cout << "\r\x1b[K" << text << "\n" << std::flush; }
  void end_line() { std::cout << "\r\x1b[K" << std::flush; }

  void handle(Key key) {
    switch (key) {
      case Key::rail_up: jog(0, +1); break;
      case Key::rail_down: jog(0, -1); break;
      case Key::turntable_up: jog(1, +1); break;
      case Key::turntable_down: jog(1, -1); break;
      case Key::bigger: step_ = std::min(step_ + 1, kJogSteps.size() - 1); break;
      case Key::smaller: step_ = step_ > 0 ? step_ - 1 : 0; break;
      case Key::home:
        homing_.assign({0, 1});
        homing_started_ = false;
        for (auto& j : jogs_) j.goal.reset();
        break;
      case Key::stop:
        cancel();
        for (Axis* a : session_.axes()) {
          try {
            a->stop();
          } catch (const std::exception& e) {
            message(e.what());
          }
        }
        break;
      case Key::estop:
        cancel();
        for (Axis* a : session_.axes()) a->emergency_stop();
        message("EMERGENCY STOP: both axes disabled; press h to home them again");
        break;
      default: break;
    }
  }

  void cancel() {
    homing_.clear();
    homing_started_ = false;
    for (auto& j : jogs_) j.goal.reset();
  }

  void jog(std::size_t i, int direction) {
    Axis& a = axis(i);
    const AxisSettings& settings = a.settings();
    const AxisStatus s = a.status();
    if (!homing_.empty()) return message("homing in progress: wait, or press s to stop it");
    if (!s.homed) return message(fmt::format("{} is not homed: press h to home", settings.name));
    if (s.state == AxisState::fault) return message(fmt::format("{} is in fault ({}): press h to home", settings.name, s.fault));
    const double step = i == 0 ? kJogSteps[step_].first : kJogSteps[step_].second;
    const double base = jogs_[i].goal ? *jogs_[i].goal : (in_motion(s.state) ? s.target : s.position);
    const double wanted = base + direction * step;
    const double goal = std::clamp(wanted, settings.min_position, settings.max_position);
    if (goal != wanted) message(fmt::format("{}: at the soft limit ({})", settings.name, position_text(settings, goal)));
    jogs_[i].goal = goal;
  }

  // Carries the homing sequence and the jog goals forward.
  void advance() {
    if (!homing_.empty()) {
      Axis& a = axis(homing_.front());
      const AxisStatus s = a.status();
      if (!homing_started_) {
        try {
          session_.prepare(a, true);
          a.home();
          homing_started_ = true;
          message(fmt::format("{}: homing", a.settings().name));
        } catch (const std::exception& e) {
          message(e.what());
          cancel();
        }
      } else if (s.state != AxisState::homing) {
        homing_started_ = false;
        homing_.pop_front();
        if (s.homed && s.state == AxisState::idle) {
          message(fmt::format("{}: homed at {}", a.settings().name, position_text(a.settings(), s.position)));
        } else {
          message(fmt::format("{}: homing ended {}", a.settings().name,
                              s.state == AxisState::fault ? "in fault: " + s.fault : "without a reference"));
          cancel();
        }
      }
      return;
    }
    for (std::size_t i = 0; i < jogs_.size(); ++i) {
      if (!jogs_[i].goal) continue;
      Axis& a = axis(i);
      const AxisStatus s = a.status();
      if (s.state == AxisState::fault) {
        jogs_[i].goal.reset();
        continue;
      }
      if (in_motion(s.state)) continue;  // the goal follows when this leg ends
      const double goal = *jogs_[i].goal;
      jogs_[i].goal.reset();
      try {
        session_.prepare(a, false);
        a.move_to(goal);
      } catch (const std::exception& e) {
        message(e.what());
      }
    }
  }

  std::string status_line() {
    std::string line;
    for (Axis* a : session_.axes()) {
      const AxisStatus s = a->status();
      std::string flags = s.homed ? "homed" : "not homed";
      if (s.inputs.limit_min || s.inputs.limit_max || s.inputs.home || s.inputs.estop) {
        flags += ", " + inputs_text(s.inputs);
      }
      line += fmt::format("{} {} {} ({}) | ", a->settings().name, position_text(a->settings(), s.position),
                          markerd::rig::to_string(s.state), flags);
    }
    const auto truth = markerd::rig::ground_truth(session_.rig().geometry(), axis(0).status().position,
                                                  axis(1).status().position);
    line += fmt::format("step {:g} mm, {:g} deg | d {:.3f} m, yaw {:.2f} deg", kJogSteps[step_].first,
                        kJogSteps[step_].second, truth.distance_m, truth.yaw_deg);
    return line;
  }

  // q: a controlled stop, then the Session disables the axes.
  int quit() {
    cancel();
    for (Axis* a : session_.axes()) {
      if (in_motion(a->status().state)) a->stop();
    }
    const auto all = session_.axes();
    while (std::any_of(all.begin(), all.end(), [](Axis* a) { return in_motion(a->status().state); })) {
      if (const int s = session_.signals().wait(20ms).signal) {
        end_line();
        session_.interrupted(s);
      }
    }
    end_line();
    std::cout << session_.positions() << '\n';
    return 0;
  }

  Session& session_;
  std::array<Jog, 2> jogs_{};
  std::deque<std::size_t> homing_;  // axes (0 rail, 1 turntable) still to home, in order
  bool homing_started_ = false;
  std::size_t step_ = kInitialJogStep;
};

// ---------------------------------------------------------------- the command

// Routes the rig's and the drives' log lines to stderr, so that stdout holds
// only the command's output (status --json is one JSON line).
void log_to_stderr() {
  static std::once_flag once;
  std::call_once(once, [] {
    auto logger = spdlog::stderr_color_mt("markerctl-rig");
    logger->set_pattern("markerctl: rig: [%l] %v");
    spdlog::set_default_logger(std::move(logger));
  });
}

}  // namespace

void add_rig_command(CLI::App& parent, Commands& commands) {
  auto o = std::make_shared<RigOptions>();
  CLI::App* app = parent.add_subcommand(
      "rig", "Bring up a rig: status, homing, moves and jogging, from its config or through markerd");
  app->require_subcommand(1);
  app->footer(
      "Runs one command on the rig a config describes (config/rig-*.toml, docs/rig.md), then disables the axes.\n"
      "The rig's devices are locked first: a command refuses to run while another process (markerd, another\n"
      "markerctl rig) holds them, and names that process. Values take a unit: the rail mm, cm or m, the\n"
      "turntable deg or rad. A new process starts with the axes unhomed (an open-loop stepper loses its\n"
      "reference when the process that drove it ends): pass --home to move or jog to home what is not homed.\n"
      "An interrupt (Ctrl-C, SIGTERM) stops the motion with a ramp, disables the axes and exits with 1.\n"
      "Exit status: 0 done, 1 refused or failed (a fault, the devices in use, an interrupt), 2 bad usage.\n"
      "Without --config, status, home, move, jog --rail/--turntable and stop go to a running markerd (its\n"
      "rig, through the control socket: --socket, else $MARKERD_SOCKET, else /run/markerd/control.sock);\n"
      "the axes stay as markerd keeps them, and an interrupt while waiting stops the rig.");
  app->add_option("--config", o->config, "The rig config (TOML with a [rig] table); without it, markerd's rig")
      ->type_name("FILE");
  app->add_option("--socket", o->socket, "markerd's control socket, for markerd's rig (no --config)")
      ->type_name("PATH");

  CLI::App* status = app->add_subcommand("status", "Each axis's state, position and inputs, and the ground truth");
  status->add_flag("--json", o->json, "One JSON object instead of text");
  status->fallthrough();

  CLI::App* home = app->add_subcommand("home", "Home the axes (both by default, the rail first) and wait");
  home->add_option("--axis", o->home_axis, "Only this axis")
      ->type_name("rail|turntable")
      ->check(CLI::IsMember({"rail", "turntable"}));
  home->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the homing has started");
  home->fallthrough();

  CLI::App* move = app->add_subcommand("move", "Move the axes to absolute positions and wait until settled");
  move->add_option("--rail", o->rail, "Rail position (250mm, 25cm, 0.25m)")->type_name("LENGTH");
  move->add_option("--turntable", o->turntable, "Turntable angle (30deg, 0.5rad)")->type_name("ANGLE");
  move->add_flag("--home", o->home, "Home the axes that are not homed first");
  move->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the move has started");
  move->fallthrough();

  CLI::App* jog = app->add_subcommand(
      "jog", "Move the axes by relative steps; without --rail/--turntable on a terminal, jog interactively");
  jog->add_option("--rail", o->rail, "Rail step (+5mm, -1cm)")->type_name("LENGTH");
  jog->add_option("--turntable", o->turntable, "Turntable step (+2deg, -0.1rad)")->type_name("ANGLE");
  jog->add_flag("--home", o->home, "Home the axes that are not homed first");
  jog->add_flag("--no-wait", o->no_wait, "markerd's rig: return once the move has started");
  jog->footer(
      "Interactive keys: left/right arrows jog the rail, up/down the turntable; + and - change the step\n"
      "(0.1 mm / 0.05 deg up to 100 mm / 30 deg); h homes both axes; s stops; space is an emergency stop\n"
      "(the axes are disabled and must be homed again); q quits.");
  jog->fallthrough();

  CLI::App* stop = app->add_subcommand("stop", "markerd's rig: stop both axes (with a ramp) and wait until they rest");
  stop->add_flag("--emergency", o->emergency, "Stop at once and disable the axes (they must be homed again)");
  stop->add_flag("--no-wait", o->no_wait, "Return once the stop has been sent");
  stop->fallthrough();

  commands.push_back({app, [o, status, home, move, jog, stop] {
                        log_to_stderr();
                        if (o->config.empty()) {
                          // markerd's rig. Signals are watched only while a command waits for motion.
                          using Action = DaemonRigRequest::Action;
                          const bool waits = !o->no_wait && !status->parsed();
                          std::optional<SignalWatch> signals;
                          if (waits) signals.emplace();
                          const SignalWatch* watch = signals ? &*signals : nullptr;
                          if (status->parsed()) return run_on_daemon(*o, Action::status, false, "rig status", watch);
                          if (home->parsed()) return run_on_daemon(*o, Action::home, false, "rig home", watch);
                          if (stop->parsed()) return run_on_daemon(*o, Action::stop, false, "rig stop", watch);
                          const bool jogging = jog->parsed();
                          const std::string context = jogging ? "rig jog" : "rig move";
                          if (requests_of(*o).empty()) {
                            throw usage_error(context, jogging ? "give --rail or --turntable (the interactive jog "
                                                                 "needs --config: it drives the rig itself)"
                                                               : "give --rail, --turntable or both");
                          }
                          return run_on_daemon(*o, Action::move, jogging, context, watch);
                        }
                        if (o->no_wait) throw usage_error("rig", "--no-wait is for markerd's rig (without --config)");
                        if (stop->parsed()) {
                          throw usage_error("rig stop", "stop is for markerd's rig (without --config); a rig "
                                                        "driven with --config stops when its command ends");
                        }
                        if (status->parsed()) return run_status(*o, "rig status");
                        if (home->parsed()) return run_home(*o, "rig home");
                        if (move->parsed()) {
                          const auto requests = requests_of(*o);
                          if (requests.empty()) throw usage_error("rig move", "give --rail, --turntable or both");
                          return run_motion(*o, requests, false, "rig move");
                        }
                        if (jog->parsed()) {
                          const auto requests = requests_of(*o);
                          if (!requests.empty()) return run_motion(*o, requests, true, "rig jog");
                          if (o->home) throw usage_error("rig jog", "--home goes with --rail or --turntable");
                          if (isatty(STDIN_FILENO) == 0 || isatty(STDOUT_FILENO) == 0) {
                            throw usage_error("rig jog",
                                              "give --rail or --turntable, or run it on a terminal for the "
                                              "interactive jog");
                          }
                          Session session(o->config, "rig jog");
                          return InteractiveJog(session).run();
                        }
                        throw usage_error("rig", "no rig command given (status, home, move, jog or stop)");
                      }});
}

}  // namespace markerctl
