#pragma once
// One markerctl rig command's hold on a rig built from its config, and how
// the rig's state is shown.

#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common.hpp"
#include "markerd/rig/device_lock.hpp"
#include "markerd/rig/rig.hpp"
#include "markerd/rig/rig_config.hpp"
#include "rig_units.hpp"
#include "signal_watch.hpp"

namespace markerctl {

bool in_motion(markerd::rig::AxisState state);
std::string position_text(const markerd::rig::AxisSettings& axis, double value);
std::string inputs_text(const markerd::rig::DriveInputs& in);
nlohmann::ordered_json axis_json(const markerd::rig::AxisSettings& settings, const markerd::rig::AxisStatus& s);

// One command's hold on the rig: the signal watch, the config, the device
// lock and the rig, in that order (the lock is released only after the rig
// has released the devices).
class Session {
 public:
  Session(const std::string& config_path, std::string context);

  // Fail safe on every way out: axes in motion are emergency-stopped (a
  // normal exit has waited for them; this is an error's way out), the others
  // disabled.
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  [[nodiscard]] const std::string& context() const { return context_; }
  // Where the command's lines in words go (progress, positions, the ground
  // truth): standard output, or standard error when standard output is the
  // command's JSON.
  [[nodiscard]] std::ostream& text() const { return *text_; }
  void text_to_stderr() {
    text_ = &std::cerr;
    text_fd_ = STDERR_FILENO;
  }
  [[nodiscard]] const markerd::rig::RigConfig& config() const { return config_; }
  [[nodiscard]] markerd::rig::Rig& rig() { return *rig_; }
  [[nodiscard]] const SignalWatch& signals() const { return signals_; }
  [[nodiscard]] markerd::rig::Axis& axis(const AxisKind& kind) {
    return &kind == &kRail ? rig_->rail() : rig_->turntable();
  }
  [[nodiscard]] std::array<markerd::rig::Axis*, 2> axes() { return {&rig_->rail(), &rig_->turntable()}; }

  // An axis ready to take a command: enabled, and, for a homing, out of
  // fault (homing is how an axis recovers its reference after one).
  void prepare(markerd::rig::Axis& axis, bool for_homing);

  // Homes one axis and waits for it.
  void home(markerd::rig::Axis& axis);

  // Waits until every axis in `axes` has settled, its progress on a live
  // line on a terminal. A fault ends the wait with an error naming the axis and the
  // cause; a signal with a controlled stop (interrupted()).
  void follow(const std::vector<markerd::rig::Axis*>& moving, std::string_view doing);

  // The controlled way out of a motion: stop with a ramp, wait for rest (a
  // second signal, or a stop that does not end, turns it into an emergency
  // stop), disable, and fail the command.
  [[noreturn]] void interrupted(int signal);

  // "rail at 250.000 mm, turntable at 30.000 deg"
  [[nodiscard]] std::string positions();

  void print_ground_truth();

 private:
  SignalWatch signals_;  // first: blocks the signals before the rig starts its threads
  std::string context_;
  std::ostream* text_ = &std::cout;
  int text_fd_ = STDOUT_FILENO;
  markerd::rig::RigConfig config_;
  std::optional<markerd::rig::DeviceLock> lock_;
  std::unique_ptr<markerd::rig::Rig> rig_;
};

}  // namespace markerctl
